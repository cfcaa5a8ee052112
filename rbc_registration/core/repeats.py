"""The rule for a repeated measurement of one fiducial that lies far from its siblings, shared
by the node's accumulator (``outlier_distance``, metres) and the CSV reader of ``register``
(``--outlier-distance``, or a fraction of the fiducial spacing, in the file's unit)."""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree


def repeat_outlier(fiducial_id: str, frame: str, point: Sequence[float],
                   earlier_mean: Sequence[float], n_earlier: int, limit: float,
                   limit_name: str = "outlier_distance", kind: str = "fiducial",
                   others: str = "earlier") -> Optional[str]:
    """Whether ``point`` is farther than ``limit`` from the mean of the fiducial's (or target's)
    earlier (accepted) repeats.

    :param frame: ``working`` or ``destination`` (named in the message).
    :param limit: the distance; 0 (or no earlier repeat) switches the check off.
    :param limit_name: how the message names the limit.
    :param kind: what the id names in the message (``fiducial``, ``target``).
    :param others: how the message names the repeats compared with (``earlier``; ``accepted``
        where they were not taken in the order measured).
    :return: ``None`` when the point is fine, else the message naming the fiducial, the
        distance and the limit.
    """
    if limit <= 0 or n_earlier <= 0:
        return None
    dist = math.dist(point, earlier_mean)
    if dist <= limit:
        return None
    return (f"{kind} {fiducial_id!r}: {frame} point is {dist:.6g} from the mean of its "
            f"{n_earlier} {others} repeat(s), more than {limit_name} {limit:g}")


def typical_spacing(points: ArrayLike) -> float:
    """The median distance from each distinct point to its nearest distinct neighbour.

    Coinciding points (two ids at one place) count once and a few odd points do not move the
    median, so the value depends neither on how ids are laid out nor on a handful of ids.

    :return: 0 when fewer than two distinct points are given.
    """
    unique = np.unique(np.asarray(points, dtype=float), axis=0)
    if len(unique) < 2:
        return 0.0
    dist, _ = cKDTree(unique).query(unique, k=2)
    return float(np.median(dist[:, 1]))


#: Two fiducials closer than this fraction of the spacing (:func:`twin_groups`) in both frames
#: are one point under two ids (``F01`` and ``f01``, two sheets merged): a real pair of holes
#: that close is rare (1.5 mm on a 150 mm grid), a measured twin differs by its noise (~1e-4).
TWIN_FRACTION = 0.01


#: The neighbour whose median distance is the spacing of :func:`twin_groups` (the fourth: up to
#: four ids at one place do not shrink it).
TWIN_NEIGHBOUR = 4


def same_place_limit(points: ArrayLike, fraction: float = TWIN_FRACTION) -> float:
    """The distance below which two of ``points`` are one place: ``fraction`` x the median
    distance from a point to its :data:`TWIN_NEIGHBOUR`-th nearest neighbour (0 for fewer than
    3 points)."""
    p = np.asarray(points, dtype=float)
    if len(p) < 3:
        return 0.0
    k = min(TWIN_NEIGHBOUR, len(p) - 1)
    dist, _ = cKDTree(p).query(p, k=k + 1)
    return fraction * float(np.median(dist[:, k]))


def twin_groups(working: ArrayLike, destination: ArrayLike,
                fraction: float = TWIN_FRACTION) -> list[list[int]]:
    """Groups (two or more indices, ascending) of fiducials closer than ``fraction`` x the
    spacing to one another in both frames: one point under several ids.

    The spacing of each frame is the median distance from a point to its fourth-nearest
    neighbour, which twins (up to four ids at one place) do not shrink even when every
    fiducial has them (the nearest are then the twins). Cross-validation holds a group out
    together (else each twin predicts the other and the held-out errors look far better than
    the corrections are).

    :return: the groups, in order of their first index; empty when there are none.
    """
    x = np.asarray(working, dtype=float)
    y = np.asarray(destination, dtype=float)
    if len(x) < 3:
        return []
    limits = [same_place_limit(p, fraction) for p in (x, y)]
    if not min(limits) > 0:
        return []
    parent = list(range(len(x)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, k in cKDTree(x).query_pairs(limits[0], output_type="ndarray"):
        if np.linalg.norm(y[i] - y[k]) <= limits[1]:
            parent[max(root(i), root(k))] = min(root(i), root(k))
    groups: dict[int, list[int]] = {}
    for i in range(len(x)):
        groups.setdefault(root(i), []).append(i)
    return [g for g in groups.values() if len(g) > 1]


def describe_twins(ids: Sequence[str], working: ArrayLike, groups: Sequence[Sequence[int]],
                   unit: str = "") -> str:
    """One line naming the :func:`twin_groups` (at most three), or ``""`` when none. In 2D
    (``working`` with two columns) points one above the other are one place too, which the
    line says."""
    if not groups:
        return ""
    x = np.asarray(working, dtype=float)
    unit = f" {unit}" if unit else ""
    shown = "; ".join(
        " and ".join(repr(ids[i]) for i in g) + f" ({float(np.ptp(x[g], axis=0).max()):.3g}"
        f"{unit} apart)" for g in groups[:3])
    more = f"; and {len(groups) - 3} more" if len(groups) > 3 else ""
    flat = " (in x, y: a 2D registration does not see z)" if x.shape[1] == 2 else ""
    return (f"{len(groups)} point(s) measured under two or more ids, the same place in both "
            f"frames{flat}: {shown}{more}: one hole under two names (a case or a space apart, "
            f"two sheets merged)? then merge them under one id; cross-validation holds each "
            f"group out together")
