"""Fiducials that share one error: groups, held out together.

Several points measured at one robot pose (three reflectors on the end effector), the balls of
one probe or the features of one fixture share that pose's or that part's error. Cross-validation
that leaves one fiducial out then leaks: the held-out fiducial's siblings stay in the model and
tell it the answer, so the held-out errors, the decision and the 95 % bound look better than the
targets will be. A ``group`` label per fiducial (empty: its own group) makes everything that
holds fiducials out hold out whole groups (:mod:`.crossval`), the paired test compare groups
(one mean error per group, :func:`unit_means`) and the conformal bound weigh every group alike
(:func:`weighted_quantile`).

:func:`undeclared_groups` names the common case where groups exist but were not given: several
fiducials read at one stamp (one pose), or ids that enumerate points of one pose
(``pose07_N1``, ``pose07_N2``), close together against the spacing of the cell.
"""

from __future__ import annotations

import math
import re
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

#: Most points a group of the detection rule holds (a robot pose carries 2-6 reflectors).
MAX_DETECTED_GROUP = 8
#: The detection names groups only when they cover at least this share of the fiducials.
DETECTED_SHARE = 0.3
#: An id read as ``<stem><separator><member>``: the stem holds a digit, the member is short.
_ID_PARTS = re.compile(r"^(?P<stem>.*\d.*?)[_\-.:/ ](?P<member>[A-Za-z]{0,3}\d{1,2}|[A-Za-z])$")


def group_labels(groups: Optional[Sequence[str]], count: int) -> Optional[NDArray[np.intp]]:
    """Integer labels (J,) of the groups, numbered in order of first appearance; an empty
    label is a group of its own. ``None`` when no group has two fiducials (every fiducial its
    own group: the behaviour without groups).

    :param groups: one label per fiducial, or ``None``.
    :param count: the number of fiducials J.
    :raises ValueError: when the labels are not ``count`` strings.
    """
    if groups is None:
        return None
    if len(groups) != count:
        raise ValueError(f"got {len(groups)} group labels for {count} fiducials")
    if not all(isinstance(g, str) for g in groups):
        raise TypeError("group labels must be strings")
    numbers: dict[str, int] = {}
    labels = np.empty(count, dtype=np.intp)
    for k, g in enumerate(groups):
        key = g if g else f"\0{k}"          # '' is its own group
        labels[k] = numbers.setdefault(key, len(numbers))
    if len(numbers) == count:
        return None
    return labels


def merge_labels(labels: Optional[NDArray[np.intp]], sets: Sequence[Sequence[int]],
                 count: int) -> Optional[NDArray[np.intp]]:
    """``labels`` with each of ``sets`` (index sets held out together, e.g. one point under two
    ids) joined into one group: labels numbered by first member, ``None`` when every fiducial
    is still its own group."""
    if labels is None and not sets:
        return None
    parent = np.arange(count) if labels is None else first_members(labels)
    for s in sets:
        members = np.asarray(s, dtype=np.intp)
        roots = np.unique(parent[members])
        for r in roots:
            parent[parent == r] = roots[0]
    out = first_members(parent)
    if len(np.unique(out)) == count:
        return None
    _, numbered = np.unique(out, return_inverse=True)
    return numbered.astype(np.intp)


def first_members(labels: NDArray[np.intp]) -> NDArray[np.intp]:
    """Each fiducial's label replaced by the index of its group's first member."""
    first: dict[int, int] = {}
    return np.array([first.setdefault(int(g), k) for k, g in enumerate(labels)], dtype=np.intp)


def unit_means(values: NDArray[np.float64], labels: Optional[NDArray[np.intp]]
               ) -> NDArray[np.float64]:
    """The mean of ``values`` per group (groups in label order); ``values`` unchanged without
    groups. The paired test of the decision compares these: one independent unit per group."""
    if labels is None:
        return values
    sums = np.bincount(labels, weights=values)
    return sums / np.bincount(labels)


def weighted_quantile(values: ArrayLike, level: float,
                      labels: Optional[NDArray[np.intp]] = None) -> float:
    """The conformal ``level`` quantile of ``values``, every group weighing alike.

    Without groups: the value at rank ceil(level (n + 1)) of the n values (their maximum when n
    is too small). With G groups each value weighs 1 / (G |g|): the smallest value whose
    cumulative weight reaches level (G + 1) / G (the largest when it is never reached), which
    without groups is that same rank. NaN for no values.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return math.nan
    order = np.argsort(v, kind="stable")
    if labels is None:
        rank = min(v.size, math.ceil(level * (v.size + 1)))
        return float(v[order][rank - 1])
    sizes = np.bincount(labels)
    n_groups = int(np.count_nonzero(sizes))
    weight = 1.0 / (n_groups * sizes[labels[order]])
    cumulative = np.cumsum(weight)
    need = level * (n_groups + 1) / n_groups
    reached = np.flatnonzero(cumulative >= need * (1.0 - 1e-12))
    return float(v[order][reached[0] if reached.size else -1])


def undeclared_groups(ids: Sequence[str], working: ArrayLike,
                      stamps: Optional[Sequence[float]] = None) -> str:
    """One warning line when fiducials look grouped but no groups were given, else ``""``.

    Two signs, each needing sets of 2..:data:`MAX_DETECTED_GROUP` fiducials that together hold
    at least :data:`DETECTED_SHARE` of them, each set's points closer to its centre than the
    median distance between the centres of neighbouring sets
    (a plate's row ``H12-01`` ... ``H12-21`` spans the plate and is no pose):

    - fiducials whose first measurement has one stamp (not 0): several reflectors read at one
      robot pose;
    - ids that differ only in a short last member after a stem with a digit (``pose07_N1``,
      ``pose07_N2``).

    Never changes anything: the line suggests the ``group`` column (or ``FiducialPair.group``).

    :param ids: fiducial ids (J).
    :param working: (J, d) their working-frame points.
    :param stamps: the stamp of each fiducial's first measurement [s], or ``None``.
    """
    x = np.asarray(working, dtype=np.float64)
    if len(ids) < 4:
        return ""
    found = []
    if stamps is not None:
        by_stamp: dict[float, list[int]] = {}
        for k, s in enumerate(stamps):
            if s:
                by_stamp.setdefault(float(s), []).append(k)
        sets = _tight_sets(list(by_stamp.values()), x)
        if sets:
            found.append((sets, "measured at one stamp"))
    by_stem: dict[str, list[int]] = {}
    for k, fid in enumerate(ids):
        m = _ID_PARTS.match(fid)
        if m:
            by_stem.setdefault(m.group("stem"), []).append(k)
    sets = _tight_sets(list(by_stem.values()), x)
    if sets:
        found.append((sets, "named as points of one pose"))
    if not found:
        return ""
    sets, how = max(found, key=lambda f: sum(len(s) for s in f[0]))
    shown = "; ".join(", ".join(repr(ids[k]) for k in s) for s in sets[:2])
    return (f"{sum(len(s) for s in sets)} fiducials come in {len(sets)} sets {how} ({shown}"
            f"{'; ...' if len(sets) > 2 else ''}): if the points of a set share an error (one "
            f"robot pose, one probe), give them one `group` so cross-validation and the bound "
            f"hold them out together")


def _tight_sets(candidates: list[list[int]], x: NDArray[np.float64]) -> list[list[int]]:
    """The candidate sets that look like groups, or [] when they do not cover enough."""
    sets = [s for s in candidates if 2 <= len(s) <= MAX_DETECTED_GROUP]
    if not sets or sum(len(s) for s in sets) < DETECTED_SHARE * len(x):
        return []
    if any(len(s) > MAX_DETECTED_GROUP for s in candidates):
        return []                            # one stamp on every point: a driver's clock
    centres = np.array([x[s].mean(axis=0) for s in sets])
    if len(centres) < 2:
        return []
    dist, _ = cKDTree(centres).query(centres, k=2)
    spacing = float(np.median(dist[:, 1]))
    spread = np.array([np.linalg.norm(x[s] - x[s].mean(axis=0), axis=1).max() for s in sets])
    tight = [s for s, r in zip(sets, spread) if r < spacing]
    if sum(len(s) for s in tight) < DETECTED_SHARE * len(x):
        return []
    return tight
