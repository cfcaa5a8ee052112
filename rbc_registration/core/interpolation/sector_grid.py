"""The grid path of the 2D sector rule (:mod:`.sectors`), for batches.

:class:`SectorIndex` gives exactly the same weights for most targets of a batch at a fraction of
the cost, from a uniform grid of cells over the fiducials' bounding box. For a cell C (centre c,
half-diagonal rho) and a sector s it keeps the few fiducials that can win sector s for some
target in C:

- when some fiducial F* lies in sector s of every point of C (the 4 corners suffice: the set of
  targets that see F* in sector s is a convex cone), every winner lies within
  U = |c - F*| + rho of the target, hence within U + rho of c; if that is less than R65(c), the
  distance from c to its 65th nearest fiducial, at most 64 fiducials are that close to any target
  in C, so the 64-candidate cap of the rule never removes the winner;
- otherwise every fiducial that can be among the 64 nearest of a target in C and in its sector s
  (within R64(c) + 2 rho of c, in the cone of directions sector s takes from C) is kept; a target's
  winner w among them is certain when |T - w| + rho < R65(c) (same argument), else the target
  takes the general path.

Targets outside the grid, in cells where a list would be long, on a fiducial, with two fiducials at
exactly the same distance in one sector (the rule then depends on the order of the neighbour
query), with a fiducial within 1e-9 of a sector boundary, or with an uncertain winner take the
general path, :func:`~.sectors.staged_sector_weights` (the rule from smaller neighbour queries
first, the same weights as :func:`~.sectors.sector_weights`). Every float that enters a weight
(distance, sector) is computed as the general path computes it, so the weights are identical,
not just close.

A cell is prepared when :data:`PREPARE_AFTER` targets have fallen in it (in one batch or across
batches: preparing a cell costs about as much as 10 targets on the staged path) and kept: targets
that come back, as a cell's holes do, take the grid path from their 8th call on (the call that
prepares the cells); targets new in every call mostly take the staged path.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .sectors import (AMBIGUOUS, CHUNK, SECTOR_CANDIDATES, SECTORS, EmptySectors,
                      on_fiducial_tolerance, staged_sector_weights)

#: A cell is prepared when this many targets have fallen in it, in one batch or across batches:
#: preparing one costs about as much as 10 targets on the staged path.
PREPARE_AFTER = 8
#: Batches smaller than this take the general path (the grid pays off from a few dozen targets).
GRID_MIN_TARGETS = 32
#: Fiducials kept per cell and sector at most; a cell needing more is left to the general path.
MAX_PER_SECTOR = 6
#: Nearest fiducials of a cell centre examined when preparing the cell.
CELL_NEIGHBOURS = 96
#: Cells of the grid: about this many per fiducial, within the bounds below.
CELLS_PER_FIDUCIAL = 128
MIN_CELLS, MAX_CELLS = 4096, 1 << 22


class SectorIndex:
    """:func:`~.sectors.sector_weights` for batches, exactly, from a grid of prepared cells (module
    docstring). Safe to share between threads: cells are prepared under a lock (once each), and
    a hit count lost to a race only delays a cell's preparation."""

    def __init__(self, points: NDArray[np.float64], tree: cKDTree) -> None:
        """:param points: fiducials (J, 2) spanning an area. :param tree: their k-d tree."""
        self.points, self.tree = points, tree
        self.lo = points.min(axis=0)
        extent = points.max(axis=0) - self.lo
        cells = int(np.clip(CELLS_PER_FIDUCIAL * len(points), MIN_CELLS, MAX_CELLS))
        self.h = float(np.sqrt(extent[0] * extent[1] / cells)) or float(extent.max())
        while np.prod(np.ceil(extent / self.h)) > MAX_CELLS:
            self.h *= 1.5
        self.n = np.maximum(1, np.ceil(extent / self.h)).astype(np.intp)
        scale = float(np.abs(points).max() + extent.max())
        self.tol = 1e-9 * scale            # slack for rounding in every bound below
        self.near = 1e-5 * scale           # closer than this, a direction is not trusted
        self.half = self.h / 2 + self.tol  # half a cell's side, with rounding of the cell index
        self.rho = self.half * math.sqrt(2)
        # Prepared cells: a row each in the arrays of _cells, _slot maps a cell to its row (-1: not
        # yet). Writers hold the lock; readers read _slot first, then _cells, which is replaced
        # whole, so any row a reader finds in _slot is in the arrays it then reads.
        self._slot = np.full(int(np.prod(self.n)), -1, dtype=np.int32)
        self._hits = np.zeros(len(self._slot), dtype=np.uint8)    # targets seen, capped
        self._index = np.int16 if len(points) + SECTORS <= np.iinfo(np.int16).max else np.int32
        self._cells = _Cells(np.empty((0, SECTORS, MAX_PER_SECTOR), dtype=self._index),
                             np.empty(0, dtype=np.intp), np.empty(0, dtype=bool), np.empty(0))
        self._used = 0
        self._lock = threading.Lock()
        # Rows J + s: padding of slot s, far behind sector s (never in it, never near its
        # boundaries) as seen from anywhere near the fiducials.
        behind = -1e3 * scale * np.c_[np.cos(np.arange(SECTORS) * np.pi / 4),
                                      np.sin(np.arange(SECTORS) * np.pi / 4)]
        self._padded = np.vstack([points, behind])
        self._px, self._py = self._padded[:, 0].copy(), self._padded[:, 1].copy()
        self._on = on_fiducial_tolerance(points)
        self._empty = EmptySectors(points)

    def _cells_of(self, targets: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
        cell = np.floor((targets - self.lo) / self.h)
        inside = ((cell >= 0) & (cell < self.n)).all(axis=1)
        cid = np.where(inside, cell[:, 0] * self.n[1] + cell[:, 1], 0).astype(np.intp)
        return cid, inside

    def _prepare(self, ids: NDArray[np.intp]) -> None:
        """Prepare cells ``ids`` (unique) that are not prepared yet."""
        with self._lock:
            ids = ids[self._slot[ids] < 0]
            if not ids.size:
                return
            parts = [self._cell_data(ids[a:a + _PREP_CHUNK])
                     for a in range(0, len(ids), _PREP_CHUNK)]
            new = _Cells(*(np.concatenate(col) for col in zip(*parts)))
            old, used = self._cells, self._used
            if used + len(ids) > len(old.safe):                   # grow, amortised
                size = max(2 * len(old.safe), used + len(ids), 256)
                grown = []
                for arr in old:
                    g = np.empty((size,) + arr.shape[1:], dtype=arr.dtype)
                    g[:used] = arr[:used]
                    grown.append(g)
                old = _Cells(*grown)
            for arr, part in zip(old, new):
                arr[used:used + len(ids)] = part
            self._cells = old
            self._used = used + len(ids)
            self._slot[ids] = np.arange(used, used + len(ids), dtype=np.int32)

    def _cell_data(self, ids: NDArray[np.intp]) -> "_Cells":
        """Candidate lists of cells ``ids`` (module docstring for the bounds)."""
        j, n = len(self.points), len(ids)
        c = self.lo + (np.column_stack(np.divmod(ids, self.n[1])) + 0.5) * self.h
        k = min(j, CELL_NEIGHBOURS)
        dc, ic = self.tree.query(c, k=k)
        dc, ic = dc.reshape(n, k), ic.reshape(n, k)
        rel = self.points[ic] - c[:, None, :]
        none = np.full(n, np.inf)
        r64 = dc[:, SECTOR_CANDIDATES - 1] if j >= SECTOR_CANDIDATES else none
        r65 = dc[:, SECTOR_CANDIDATES] if j > SECTOR_CANDIDATES else none
        reach = r64 + 2 * self.rho + self.tol     # the 64 nearest of any target in the cell
        covered = dc[:, -1] > reach if j > k else np.ones(n, dtype=bool)
        # The directions from the cell to a fiducial outside it span the angles at which its
        # corners see it; sector s_lo + o, o = 0..span, is every sector the formula of sector_of
        # can give from a point of the cell (with a margin for rounding).
        theta0 = np.arctan2(rel[..., 1] + self.half, rel[..., 0] + self.half)
        lo = hi = np.zeros_like(theta0)
        for corner in ((-1, 1), (1, -1), (1, 1)):
            t = np.arctan2(rel[..., 1] - corner[1] * self.half, rel[..., 0] - corner[0] * self.half)
            d = np.remainder(t - theta0 + np.pi, 2 * np.pi) - np.pi
            lo, hi = np.minimum(lo, d), np.maximum(hi, d)
        s_lo = np.floor((theta0 + lo + np.pi / 8) / (np.pi / 4) - AMBIGUOUS).astype(np.intp)
        span = np.floor((theta0 + hi + np.pi / 8) / (np.pi / 4) + AMBIGUOUS).astype(np.intp) - s_lo
        close = (np.abs(rel) <= self.half + self.near).all(axis=2)
        span[close] = SECTORS - 1
        # Fiducials in one sector from every point of the cell bound its winner (sorted by dc:
        # the first per sector is the nearest).
        rows = np.arange(n)[:, None]
        key = (rows * SECTORS + s_lo % SECTORS)[span == 0]
        first_key, first = np.unique(key, return_index=True)
        bound_a = np.full(n * SECTORS, np.inf)
        bound_a[first_key] = dc[span == 0][first] + self.rho
        bound_a = bound_a.reshape(n, SECTORS)
        certain = bound_a + self.rho + self.tol < r65[:, None]
        bound = np.where(certain, bound_a + self.rho + self.tol, reach[:, None])
        # Entries (cell, sector, fiducial): the fiducial can win that sector for some target.
        cell_i, cand_i = np.nonzero(dc <= bound.max(axis=1)[:, None])
        cells, sectors, cands = [], [], []
        for o in range(SECTORS):
            sec = (s_lo[cell_i, cand_i] + o) % SECTORS
            ok = (o <= span[cell_i, cand_i]) & (dc[cell_i, cand_i] <= bound[cell_i, sec])
            cells.append(cell_i[ok])
            sectors.append(sec[ok])
            cands.append(ic[cell_i[ok], cand_i[ok]])
        key = np.concatenate(cells) * SECTORS + np.concatenate(sectors)
        order = np.argsort(key, kind="stable")
        key, cand = key[order], np.concatenate(cands)[order]
        count = np.bincount(key, minlength=n * SECTORS)
        pos = np.arange(len(key)) - (np.cumsum(count) - count)[key]
        fits = pos < MAX_PER_SECTOR
        table = np.repeat(j + np.tile(np.arange(SECTORS), n), MAX_PER_SECTOR).reshape(
            n * SECTORS, MAX_PER_SECTOR).astype(self._index)                  # padding J + s
        table[key[fits], pos[fits]] = cand[fits]
        count = count.reshape(n, SECTORS)
        safe = (certain | covered[:, None]).all(axis=1) & (count <= MAX_PER_SECTOR).all(axis=1)
        return _Cells(table.reshape(n, SECTORS, MAX_PER_SECTOR),
                      np.maximum(1, count.max(axis=1)), safe, r65 - self.rho - self.tol)

    def weights(self, targets: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Same as :func:`~.sectors.sector_weights` (``targets`` validated, (K, 2))."""
        cid, inside = self._cells_of(targets)
        slot = self._slot[cid]
        missing = inside & (slot < 0)
        if missing.any():
            # A cell is prepared once PREPARE_AFTER targets fell in it (this batch or earlier
            # ones): preparing costs more than the staged path for a few targets.
            ids, hits = np.unique(cid[missing], return_counts=True)
            seen = self._hits[ids] + hits
            self._hits[ids] = np.minimum(seen, PREPARE_AFTER)
            if (seen >= PREPARE_AFTER).any():
                self._prepare(ids[seen >= PREPARE_AFTER])
                slot = self._slot[cid]
        cells = self._cells                       # after _slot: holds every row slot names
        fast = np.flatnonzero(inside & (slot >= 0))
        fast = fast[cells.safe[slot[fast]]]
        general = np.ones(len(targets), dtype=bool)
        general[fast] = False
        idx = np.empty((len(targets), SECTORS), dtype=np.intp)
        w = np.empty((len(targets), SECTORS))
        if fast.size:
            idx[fast], w[fast], unsure = self._fast(targets[fast], slot[fast], cells)
            general[fast[unsure]] = True
        slow = np.flatnonzero(general)
        if slow.size:
            idx[slow], w[slow] = staged_sector_weights(self.tree, self.points, self._empty,
                                                       targets[slow])
        return idx, w

    def _fast(self, t: NDArray[np.float64], row: NDArray[np.intp], cells: "_Cells"
              ) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.bool_]]:
        """Weights of targets in safe cells, in chunks that stay in cache; also returns which
        targets the grid cannot decide (they must take the general path)."""
        idx = np.empty((len(t), SECTORS), dtype=np.intp)
        w = np.empty((len(t), SECTORS))
        unsure = np.empty(len(t), dtype=bool)
        # Grouped by the cell's longest list, so little work goes into padding.
        width = cells.width[row]
        for m in np.unique(width):
            group = np.flatnonzero(width == m)
            step = max(1, CHUNK // int(m))
            for a in range(0, len(group), step):
                g = group[a:a + step]
                idx[g], w[g], unsure[g] = self._fast_chunk(t[g], cells, row[g], int(m))
        return idx, w, unsure

    def _fast_chunk(self, t: NDArray[np.float64], cells: "_Cells", row: NDArray[np.intp],
                    width: int) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.bool_]]:
        cand = np.take(cells.table, row, axis=0)[:, :, :width]       # (K, 8, M), slot = sector
        dx = np.take(self._px, cand) - t[:, None, None, 0]            # as sector_weights: F - T
        dy = np.take(self._py, cand) - t[:, None, None, 1]
        dist = np.sqrt(dx * dx + dy * dy)                             # as the k-d tree computes it
        low = _LOW_X * dy - _LOW_Y * dx          # > 0: counter-clockwise of the lower boundary
        high = _HIGH_X * dy - _HIGH_Y * dx       # < 0: clockwise of the upper boundary
        dm = np.where((low > 0) & (high < 0), dist, np.inf)          # padding: never inside
        first = dm.argmin(axis=2)
        best = np.take_along_axis(dm, first[..., None], axis=2)[..., 0]    # (K, 8)
        filled = best < np.inf
        rows = np.arange(len(t))
        near = best.argmin(axis=1)
        tie = (dm == best[..., None]).sum(axis=2) > 1           # two fiducials at one distance
        unsure = (filled & (tie | ~(best < cells.limit[row][:, None]))).any(axis=1)
        unsure |= (best[rows, near] <= self._on) | ~filled.any(axis=1)
        # A fiducial within 1e-9 of a sector boundary: sector_of would use the formula there,
        # so the general path decides.
        unsure |= (np.minimum(np.abs(low), np.abs(high)) <= AMBIGUOUS * dist).any(axis=(1, 2))
        sel = np.take_along_axis(cand, first[..., None], axis=2)[..., 0].astype(np.intp)
        idx = np.where(filled, sel, sel[rows, near][:, None])
        w = np.where(filled, 1.0 / np.maximum(best, 1e-300), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):          # unsure rows are redone
            w = w / w.sum(axis=1, keepdims=True)
        return idx, w, unsure


# Boundary directions of each sector s: from s pi/4 - pi/8 (included) to s pi/4 + pi/8.
_LOW = np.arange(SECTORS) * (np.pi / 4) - np.pi / 8
_LOW_X, _LOW_Y = np.cos(_LOW)[:, None], np.sin(_LOW)[:, None]
_HIGH_X, _HIGH_Y = np.cos(_LOW + np.pi / 4)[:, None], np.sin(_LOW + np.pi / 4)[:, None]
#: Cells prepared at once.
_PREP_CHUNK = 256


class _Cells(NamedTuple):
    """Prepared cells, one row each: candidate fiducials per sector (padded with J + s), the longest
    list, whether the grid decides the cell, and the distance a winner must stay below."""

    table: NDArray[np.integer]
    width: NDArray[np.intp]
    safe: NDArray[np.bool_]
    limit: NDArray[np.float64]
