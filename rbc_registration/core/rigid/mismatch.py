"""Pairwise distance mismatch L_ij (paper eq. 1), its standard deviation sigma_L (eq. 7) and
histograms of L.

sigma_L is an O(J^2) pass over the pairs. Beyond :data:`ONE_BLOCK_PAIRS` pairs it is computed in
blocks of :data:`ROWS_PER_BLOCK` rows of the pair matrix, so its temporary memory is O(J) (about
``3 ROWS_PER_BLOCK J`` floats), and :func:`sigma_l_stages` evaluates several working-frame sets
against one destination set in the same pass, computing the destination distances once.
"""

from __future__ import annotations

from typing import NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.distance import cdist, pdist

from ..validation import as_point_pairs

#: Rows i of the pair matrix (pairs (i, j), j > i) handled per block by :func:`sigma_l_stages`.
ROWS_PER_BLOCK = 32
#: Up to this many pairs (J <= 362) :func:`sigma_l_stages` takes them in one block (512 KB).
ONE_BLOCK_PAIRS = 1 << 16


class _Moments:
    """Count, mean and sum of squared deviations of a stream of chunks (Chan et al. merge)."""

    __slots__ = ("n", "mean", "m2")

    def __init__(self) -> None:
        self.n, self.mean, self.m2 = 0, 0.0, 0.0

    def add(self, chunk: NDArray[np.float64]) -> None:
        """Merge the values of ``chunk`` (1-D, overwritten: it is centred in place)."""
        n_b = chunk.size
        if n_b == 0:
            return
        mean_b = float(chunk.sum()) / n_b
        chunk -= mean_b
        m2_b = float(chunk @ chunk)
        total = self.n + n_b
        delta = mean_b - self.mean
        self.mean += delta * n_b / total
        self.m2 += m2_b + delta * delta * self.n * n_b / total
        self.n = total

    def std(self) -> float:
        return float(np.sqrt(max(self.m2, 0.0) / self.n))


def pairwise_mismatch(working: ArrayLike, destination: ArrayLike) -> NDArray[np.float64]:
    """Return L_ij = ||X_i - X_j|| - ||Y_i - Y_j|| (paper eq. 1) for all pairs i < j.

    :param working: fiducials in the working frame, shape (J, d).
    :param destination: the same fiducials in the destination frame, shape (J, d).
    :return: array of J(J-1)/2 mismatches in row-major pair order (0,1), (0,2), ..., (J-2,J-1).
    """
    x, y = as_point_pairs(working, destination, min_count=2)
    out = pdist(x)
    out -= pdist(y)
    return out


def sigma_l_stages(stages: Sequence[ArrayLike], destination: ArrayLike) -> tuple[float, ...]:
    """sigma_L (paper eq. 7, 1/J_p) of each working-frame set in ``stages`` against ``destination``.

    One pass over the pairs: the destination distances of a block are computed once and shared
    by every stage (e.g. the fiducials after each restoration step). Temporary memory is O(J).

    :param stages: working-frame fiducial sets, each of shape (J, d) like ``destination``.
    :param destination: the same fiducials in the destination frame, shape (J, d).
    :return: sigma_L of each stage, in the order given.
    :raises ValueError: on fewer than 2 points, mismatched shapes or non-finite values.
    """
    pairs = [as_point_pairs(s, destination, min_count=2) for s in stages]
    if not pairs:
        return ()
    y = pairs[0][1]
    xs = [p[0] for p in pairs]
    j = len(y)
    acc = [_Moments() for _ in xs]
    if j * (j - 1) // 2 <= ONE_BLOCK_PAIRS:         # small J: all pairs at once
        dy = pdist(y)
        for x, m in zip(xs, acc):
            chunk = pdist(x)
            chunk -= dy                             # L_ij, eq. 1
            m.add(chunk)
        return tuple(m.std() for m in acc)
    rows = ROWS_PER_BLOCK
    inner = np.triu_indices(rows, k=1)              # pairs inside a full block, i < k
    buf_y, buf_x = np.empty(rows * j), np.empty(rows * j)
    for a in range(0, j - 1, rows):
        b = min(j, a + rows)
        tri = inner if b - a == rows else np.triu_indices(b - a, k=1)
        n = _block_distances(y, a, b, tri, buf_y)
        for x, m in zip(xs, acc):
            _block_distances(x, a, b, tri, buf_x)
            chunk = buf_x[:n]
            chunk -= buf_y[:n]                      # L_ij, eq. 1
            m.add(chunk)
    return tuple(m.std() for m in acc)


def _block_distances(points: NDArray[np.float64], a: int, b: int,
                     tri: tuple[NDArray[np.intp], NDArray[np.intp]], out: NDArray[np.float64]
                     ) -> int:
    """Write |P_i - P_k| for the pairs a <= i < b, k > i into ``out``: those with k >= b, then
    those inside the block (``tri``: its upper triangle); return how many."""
    n_cross = (b - a) * (len(points) - b)
    cdist(points[a:b], points[b:], out=out[:n_cross].reshape(b - a, len(points) - b))
    n = n_cross + len(tri[0])
    out[n_cross:n] = cdist(points[a:b], points[a:b])[tri]
    return n


def sigma_l(working: ArrayLike, destination: ArrayLike) -> float:
    """Standard deviation of the pairwise mismatch L over all J_p pairs (paper eq. 7, 1/J_p).

    Accumulated block by block (see :func:`sigma_l_stages`): it never holds all J(J-1)/2 values.
    """
    return sigma_l_stages([working], destination)[0]


class Histogram(NamedTuple):
    """Histogram of L: ``counts[k]`` values fall in ``[edges[k], edges[k+1])``."""

    counts: NDArray[np.int64]
    edges: NDArray[np.float64]


def mismatch_histogram(working: ArrayLike, destination: ArrayLike, bins: int = 50,
                       value_range: Optional[tuple[float, float]] = None) -> Histogram:
    """Histogram counts of the pairwise mismatch L (the paper's Figs 2-3)."""
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    values = pairwise_mismatch(working, destination)
    counts, edges = np.histogram(values, bins=bins, range=value_range)
    return Histogram(counts.astype(np.int64), edges)
