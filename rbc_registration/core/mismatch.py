"""Pairwise distance mismatch L_ij (paper eq. 1), its standard deviation sigma_L (eq. 7) and
histograms of L. Computed in row blocks so J up to ~10^4 stays within memory."""

from __future__ import annotations

from typing import Iterator, NamedTuple, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.distance import cdist, pdist

from .validation import as_point_pairs

_BLOCK_PAIRS = 2_000_000  # pairs per block: bounds the temporary memory to ~100 MB


def _blocks(x: NDArray[np.float64], y: NDArray[np.float64]) -> Iterator[NDArray[np.float64]]:
    """Yield L_ij for i < j in row-major pair order, in blocks of about ``_BLOCK_PAIRS``."""
    j = len(x)
    if j * (j - 1) // 2 <= _BLOCK_PAIRS:
        yield pdist(x) - pdist(y)
        return
    rows = max(1, _BLOCK_PAIRS // j)
    for start in range(0, j - 1, rows):
        stop = min(j - 1, start + rows)
        mask = np.arange(start + 1, j)[None, :] > np.arange(start, stop)[:, None]
        dx = cdist(x[start:stop], x[start + 1:])
        dy = cdist(y[start:stop], y[start + 1:])
        yield (dx - dy)[mask]


def pairwise_mismatch(working: ArrayLike, destination: ArrayLike) -> NDArray[np.float64]:
    """Return L_ij = ||X_i - X_j|| - ||Y_i - Y_j|| (paper eq. 1) for all pairs i < j.

    :param working: fiducials in the working frame, shape (J, d).
    :param destination: the same fiducials in the destination frame, shape (J, d).
    :return: array of J(J-1)/2 mismatches in row-major pair order (0,1), (0,2), ..., (J-2,J-1).
    """
    x, y = as_point_pairs(working, destination, min_count=2)
    return np.concatenate(list(_blocks(x, y)))


def sigma_l(working: ArrayLike, destination: ArrayLike) -> float:
    """Standard deviation of the pairwise mismatch L over all J_p pairs (paper eq. 7, 1/J_p).

    Accumulated block by block (shifted sums), so it never holds all J(J-1)/2 values.
    """
    x, y = as_point_pairs(working, destination, min_count=2)
    n = 0
    shift = None
    s1 = s2 = 0.0
    for block in _blocks(x, y):
        if shift is None:
            shift = float(block.mean())
        b = block - shift
        n += b.size
        s1 += float(b.sum())
        s2 += float(b @ b)
    mean = s1 / n
    return float(np.sqrt(max(s2 / n - mean * mean, 0.0)))


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
