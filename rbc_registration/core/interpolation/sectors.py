"""The 2D sector rule of the paper's interpolation (eq. 5), as stated.

The rule: around a target T, the plane is cut into 8 sectors of 45 degrees centred on the axes and
diagonals (sector of a fiducial F: ``floor((atan2(F - T) + pi/8) / (pi/4)) mod 8``); in each
sector the nearest fiducial among the :data:`SECTOR_CANDIDATES` nearest to T is used, weighted by
inverse distance (a target on a fiducial takes that fiducial alone). :func:`sector_weights` is the
rule as stated, from a k-nearest-neighbour query of k = :data:`SECTOR_CANDIDATES`.

:func:`staged_sector_weights` gives exactly the same weights for a batch from smaller queries
first (:data:`STAGES`): a sector's nearest fiducial among the k nearest is its nearest among the
64 (a closer one would be among the k, and the 64 include the k), so it is settled unless
another fiducial of the sector is at the same distance (among the k, or beyond them when the
winner is as far as the k-th: the rule then depends on the order of the neighbour query); a
sector that holds no fiducial at all (:class:`EmptySectors`) is empty whatever the cap. Only
targets with a sector settled by neither take the next query, and the last is the rule itself;
so does a target on a fiducial.

:func:`one_target_weights` is the rule for one target (the node's ``~/correct_target``), the same
weights in floats instead of (64, 8) arrays.

:class:`.sector_grid.SectorIndex` gives exactly the same weights for most targets of a batch
at a fraction of the cost (the grid path; its module docstring says how), and the staged path for
the others.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

#: Fiducials looked at around a 2D target when filling the 8 sectors (the rule's cap).
SECTOR_CANDIDATES = 64
SECTORS = 8
#: Targets per chunk on the general path (on the grid path: targets x list length).
CHUNK = 4096
#: A direction this close (relative) to a sector boundary is classified with atan2 itself.
AMBIGUOUS = 1e-9
#: Neighbours queried by :func:`staged_sector_weights` before the rule's own query (most
#: targets inside a cell are settled by the first).
STAGES = (16, 32)
_TAN8 = math.tan(math.pi / 8)
# Sector by (kind, dx > 0, dy > 0); kind 0: within 22.5 deg of the x axis, 1: of the y axis,
# 2: diagonal.
_SECTOR_LUT = np.array([4, 4, 0, 0, 6, 2, 6, 2, 5, 3, 7, 1], dtype=np.intp)


def _sector_formula(dx: NDArray[np.float64], dy: NDArray[np.float64]) -> NDArray[np.intp]:
    return np.floor((np.arctan2(dy, dx) + np.pi / 8) / (np.pi / 4)).astype(np.intp) % SECTORS


def sector_of(dx: NDArray[np.float64], dy: NDArray[np.float64]) -> NDArray[np.intp]:
    """Sector 0..7 of the directions (dx, dy): ``floor((atan2(dy, dx) + pi/8) / (pi/4)) mod 8``.

    Classified by comparisons with tan(pi/8); directions within a relative 1e-9 of a sector
    boundary (and the zero vector) are evaluated with the formula itself, so the result is the
    formula's, bit for bit.
    """
    au, av = np.abs(dx), np.abs(dy)
    a = av - _TAN8 * au                  # < 0: within 22.5 degrees of the x axis
    b = au - _TAN8 * av                  # < 0: within 22.5 degrees of the y axis
    kind = np.where(a < 0, 0, np.where(b < 0, 1, 2))
    sector = _SECTOR_LUT[kind * 4 + (dx > 0) * 2 + (dy > 0)]
    margin = AMBIGUOUS * (au + av)
    unsure = (np.abs(a) <= margin) | (np.abs(b) <= margin)
    if unsure.any():
        sector[unsure] = _sector_formula(dx[unsure], dy[unsure])
    return sector


def _in_chunks(weights: Callable[[NDArray[np.float64]], tuple[NDArray[np.intp],
                                                                NDArray[np.float64]]],
               targets: NDArray[np.float64], size: int
               ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """``weights`` of ``targets`` by chunks of ``size``, concatenated."""
    parts = [weights(targets[a:a + size]) for a in range(0, len(targets), size)]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def on_fiducial_tolerance(points: NDArray[np.float64]) -> float:
    """Distance below which a target counts as on a fiducial."""
    return 1e-12 * max(1.0, float(np.abs(points).max()))


def sector_weights(tree: cKDTree, points: NDArray[np.float64], targets: NDArray[np.float64]
                   ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The sector rule (module docstring) for targets (K, 2): fiducial indices and normalised
    weights, both (K, 8), slot k for sector k; empty sectors have weight 0 (and, as index, the
    nearest fiducial)."""
    if len(targets) > CHUNK:            # bounded temporaries: (K, 64, 8) per chunk
        return _in_chunks(lambda t: sector_weights(tree, points, t), targets, CHUNK)
    k = min(SECTOR_CANDIDATES, len(points))
    dist, cand = tree.query(targets, k=k)
    dist, cand = dist.reshape(len(targets), k), cand.reshape(len(targets), k)
    delta = points[cand] - targets[:, None, :]
    sector = sector_of(delta[..., 0], delta[..., 1])
    in_sector = sector[:, :, None] == np.arange(SECTORS)          # (K, k, 8)
    filled = in_sector.any(axis=1)                                # (K, 8)
    first = in_sector.argmax(axis=1)                              # candidates sorted by distance
    rows = np.arange(len(targets))[:, None]
    idx = cand[rows, first]
    w = np.where(filled, 1.0 / np.maximum(dist[rows, first], 1e-300), 0.0)
    # A target on a fiducial takes that fiducial's correction.
    on = dist[:, 0] <= on_fiducial_tolerance(points)
    idx[on] = cand[on, :1]
    w[on] = np.eye(SECTORS)[0]
    return idx, w / w.sum(axis=1, keepdims=True)


def one_target_weights(tree: cKDTree, points: NDArray[np.float64], target: NDArray[np.float64],
                       on_tolerance: float) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """:func:`sector_weights` of one target (1, 2), bit for bit, in about half the time (the
    node's single target: the rule's 64-neighbour query, then the sectors by the formula itself
    and each sector's first candidate in query order, in floats instead of (64, 8) arrays).
    ``on_tolerance``: :func:`on_fiducial_tolerance` of ``points``."""
    k = min(SECTOR_CANDIDATES, len(points))
    if k < 2:                               # one fiducial: the query gives scalars
        return sector_weights(tree, points, target)
    dist, cand = tree.query(target[0], k=k)
    delta = points[cand] - target[0]
    sector = _sector_formula(delta[:, 0], delta[:, 1]).tolist()
    fiducials, near = cand.tolist(), dist.tolist()
    idx = [fiducials[0]] * SECTORS          # an empty sector: the nearest fiducial, weight 0
    if near[0] <= on_tolerance:             # on a fiducial: that fiducial alone
        return np.array([idx], dtype=np.intp), np.eye(1, SECTORS)
    w = [0.0] * SECTORS
    left = SECTORS
    for i, s in enumerate(sector):          # candidates sorted by distance: the first wins
        if not w[s]:
            w[s] = 1.0 / max(near[i], 1e-300)
            idx[s] = fiducials[i]
            left -= 1
            if not left:
                break
    w = np.array(w)
    return np.array([idx], dtype=np.intp), (w / w.sum())[None, :]


# Boundary directions of each sector s: from s pi/4 - pi/8 (included) to s pi/4 + pi/8.
_LOW = np.arange(SECTORS) * (np.pi / 4) - np.pi / 8
_LOW_X, _LOW_Y = np.cos(_LOW), np.sin(_LOW)
_HIGH_X, _HIGH_Y = np.cos(_LOW + np.pi / 4), np.sin(_LOW + np.pi / 4)


class EmptySectors:
    """Which sectors around a target hold no fiducial at all, certainly.

    F lies in sector s of T when the direction F - T is counter-clockwise of the sector's lower
    boundary and clockwise of its upper one: a(F) >= a(T) and b(F) < b(T), with a, b the cross
    products of a point with the two boundary directions (one pair per sector). So sector s of T
    is empty when the smallest b over the fiducials with a >= a(T) is not below b(T): a binary
    search in the fiducials sorted by a, and a suffix minimum of b. Both tests are widened by a
    margin of 1e-9 of the cell's scale plus 1e-9 of the target's own coordinates (the rounding of
    ``sector_of``'s F - T and of T's cross products grows with T: a target 1e6 cells away would
    otherwise see a fiducial along a sector boundary in an "empty" sector), far above those
    roundings, so a sector called empty is empty for the formula as well.
    """

    def __init__(self, points: NDArray[np.float64]) -> None:
        """:param points: the fiducials (J, 2)."""
        self.margin = 1e-9 * float(np.abs(points).max() + np.ptp(points, axis=0).max())
        self._a, self._min_b = [], []
        for s in range(SECTORS):
            a = _LOW_X[s] * points[:, 1] - _LOW_Y[s] * points[:, 0]
            b = _HIGH_X[s] * points[:, 1] - _HIGH_Y[s] * points[:, 0]
            order = np.argsort(a)
            self._a.append(a[order])
            self._min_b.append(np.append(np.minimum.accumulate(b[order][::-1])[::-1], np.inf))

    def __call__(self, targets: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(K, 8): sector s of target k holds no fiducial."""
        out = np.empty((len(targets), SECTORS), dtype=bool)
        margin = self.margin + 1e-9 * np.abs(targets).sum(axis=1)
        for s in range(SECTORS):
            a = _LOW_X[s] * targets[:, 1] - _LOW_Y[s] * targets[:, 0]
            b = _HIGH_X[s] * targets[:, 1] - _HIGH_Y[s] * targets[:, 0]
            first = np.searchsorted(self._a[s], a - margin, side="left")
            out[:, s] = self._min_b[s][first] >= b + margin
        return out


def staged_sector_weights(tree: cKDTree, points: NDArray[np.float64], empty: EmptySectors,
                          targets: NDArray[np.float64]
                          ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """:func:`sector_weights`, bit for bit, from the queries of :data:`STAGES` first (module
    docstring); ``empty``: the :class:`EmptySectors` of ``points``."""
    if len(targets) > 4 * CHUNK:        # bounded temporaries: (K, 32) per chunk
        return _in_chunks(lambda t: staged_sector_weights(tree, points, empty, t), targets,
                          4 * CHUNK)
    idx = np.empty((len(targets), SECTORS), dtype=np.intp)
    w = np.empty((len(targets), SECTORS))
    left = np.arange(len(targets))
    cap = min(SECTOR_CANDIDATES, len(points))
    none = empty(targets) if STAGES[0] < cap else None
    for k in STAGES:
        if k >= cap or not left.size:
            break
        done, idx_k, w_k = _settled(tree, points, none[left], targets[left], k)
        idx[left[done]], w[left[done]] = idx_k, w_k
        left = left[~done]
    if left.size:
        idx[left], w[left] = sector_weights(tree, points, targets[left])
    return idx, w


def _settled(tree: cKDTree, points: NDArray[np.float64], empty: NDArray[np.bool_],
             targets: NDArray[np.float64], k: int
             ) -> tuple[NDArray[np.bool_], NDArray[np.intp], NDArray[np.float64]]:
    """Which targets the k nearest fiducials settle, and their indices and weights (``empty``:
    (K, 8) the sectors :class:`EmptySectors` found empty)."""
    n = len(targets)
    dist, cand = tree.query(targets, k=k)
    delta = points[cand] - targets[:, None, :]
    sector = sector_of(delta[..., 0], delta[..., 1])
    rows = np.arange(n)
    first = np.full((n, SECTORS), k, dtype=np.intp)
    for col in range(k - 1, -1, -1):          # the nearest candidate of each sector
        first[rows, sector[:, col]] = col
    filled = first < k
    pick = np.minimum(first, k - 1)
    best = np.where(filled, dist[rows[:, None], pick], np.inf)
    # Settled: every sector filled by a winner closer than the k-th neighbour (no tie beyond
    # the k), or empty; no other candidate of a winner's sector at its distance; not on a
    # fiducial.
    done = (filled & (best < dist[:, -1:]) | ~filled & empty).all(axis=1)
    done &= (dist == best[rows[:, None], sector]).sum(axis=1) == filled.sum(axis=1)
    done &= dist[:, 0] > on_fiducial_tolerance(points)
    rows = np.flatnonzero(done)
    chosen = cand[rows[:, None], pick[rows]]
    idx = np.where(filled[rows], chosen, cand[rows, :1])
    w = np.where(filled[rows], 1.0 / np.maximum(best[rows], 1e-300), 0.0)
    return done, idx, w / w.sum(axis=1, keepdims=True)
