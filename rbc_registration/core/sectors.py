"""The 2D sector rule of the paper's interpolation (eq. 5), as stated.

The rule: around a target T, the plane is cut into 8 sectors of 45 degrees centred on the axes and
diagonals (sector of a fiducial F: ``floor((atan2(F - T) + pi/8) / (pi/4)) mod 8``); in each
sector the nearest fiducial among the :data:`SECTOR_CANDIDATES` nearest to T is used, weighted by
inverse distance (a target on a fiducial takes that fiducial alone). :func:`sector_weights` is the
rule as stated, from a k-nearest-neighbour query of k = :data:`SECTOR_CANDIDATES`.

:class:`.sector_grid.SectorIndex` gives exactly the same weights for most targets of a batch
at a fraction of the cost (the grid path; its module docstring says how).
"""

from __future__ import annotations

import math

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


def on_fiducial_tolerance(points: NDArray[np.float64]) -> float:
    """Distance below which a target counts as on a fiducial."""
    return 1e-12 * max(1.0, float(np.abs(points).max()))


def sector_weights(tree: cKDTree, points: NDArray[np.float64], targets: NDArray[np.float64]
                   ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The sector rule (module docstring) for targets (K, 2): fiducial indices and normalised
    weights, both (K, 8), slot k for sector k; empty sectors have weight 0 (and, as index, the
    nearest fiducial)."""
    if len(targets) > CHUNK:            # bounded temporaries: (K, 64, 8) per chunk
        parts = [sector_weights(tree, points, targets[a:a + CHUNK])
                 for a in range(0, len(targets), CHUNK)]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
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
