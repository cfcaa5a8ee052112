"""Dense linear algebra by blocks, with the flops in numpy's matmul, which releases the GIL.

A kriging rebuild runs beside the node's answers (its executor thread): scipy's LAPACK wrappers
hold the GIL for the whole call (``dpotri`` 0.7 s at J = 4,000, ``cho_solve`` ~0.1 s at
J = 5,000), numpy's matmul does not. Here only the diagonal blocks of :data:`BLOCK` rows go
through LAPACK; everything else is matmul.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf, dtrtri, dtrtrs

#: Rows per block of :func:`cholesky_blocked` and :func:`solve_blocked` (LAPACK, which holds
#: the GIL, sees one block at a time).
BLOCK = 512
#: Rows per block of :func:`inverse_from_cholesky`: smaller, as its products skip only whole
#: blocks of the triangles' zeros (23 ms at n = 1,000 against 35 ms with 512-row blocks; the
#: fit inverts once per likelihood evaluation).
INVERSE_BLOCK = 128


def cholesky_blocked(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """The lower Cholesky factor of the symmetric positive definite ``a`` (C-contiguous, (J, J)),
    in place: right-looking by blocks of :data:`BLOCK`, the panel solves and the trailing
    updates in numpy's matmul (the GIL released; ~70 GFLOP/s on one core of the project VM
    against ~25 for ``numpy.linalg.cholesky``'s LAPACK, and no second J x J array), only the
    diagonal blocks in LAPACK ``dpotrf``/``dtrtri``. Entries above the diagonal are zeroed.

    :raises numpy.linalg.LinAlgError: when ``a`` is not positive definite.
    """
    n, step = len(a), BLOCK
    for k in range(0, n, step):
        e = min(n, k + step)
        d, info = dpotrf(a[k:e, k:e], lower=1, clean=1)
        if info != 0:
            raise np.linalg.LinAlgError("covariance is not positive definite")
        a[k:e, k:e] = d
        a[k:e, e:] = 0.0
        if e == n:
            break
        inv, info = dtrtri(d, lower=1)
        if info != 0:
            raise np.linalg.LinAlgError("covariance is singular")
        panel = a[e:, k:e] @ inv.T                               # L21 = A21 L11^-T
        a[e:, k:e] = panel
        for j in range(e, n, step):                              # A22 -= L21 L21^T, lower
            f = min(n, j + step)
            a[j:, j:f] -= panel[j - e:] @ panel[j - e:f - e].T
    return a


def solve_blocked(low: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """K^-1 b for K = L L^T, L lower (entries above its diagonal ignored), by blocks of
    :data:`BLOCK` rows: the off-diagonal products run in numpy's matmul (the GIL released),
    only the diagonal blocks in LAPACK ``dtrtrs`` (scipy's ``cho_solve`` held the GIL for the
    whole solve: ~0.1 s at J = 5,000)."""
    n, step = len(low), BLOCK
    x = np.array(b, dtype=np.float64, order="C")
    starts = range(0, n, step)
    for i in starts:                                         # L u = b
        j = min(n, i + step)
        if i:
            x[i:j] -= low[i:j, :i] @ x[:i]
        x[i:j] = _triangular(low[i:j, i:j], x[i:j], trans=0)
    for i in reversed(starts):                               # L^T x = u
        j = min(n, i + step)
        if j < n:
            x[i:j] -= low[j:, i:j].T @ x[j:]
        x[i:j] = _triangular(low[i:j, i:j], x[i:j], trans=1)
    return x


def _triangular(low: NDArray[np.float64], b: NDArray[np.float64], trans: int
                ) -> NDArray[np.float64]:
    x, info = dtrtrs(np.asfortranarray(low), b, lower=1, trans=trans)
    if info != 0:
        raise np.linalg.LinAlgError("covariance is singular")
    return x


def inverse_from_cholesky(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """K^-1 (full, symmetric) from the lower Cholesky factor L of K (entries above its diagonal
    are ignored): K^-1 = L^-T L^-1, by blocks of :data:`INVERSE_BLOCK` rows.

    The products run in numpy's matmul, which releases the GIL; only the diagonal blocks go
    through LAPACK ``dtrtri``, whose scipy wrapper holds it. (``dpotri`` on the whole matrix held
    the GIL for 0.7 s at J = 4,000 and stalled the node's executor during a kriging rebuild.)
    """
    n = len(c)
    b = INVERSE_BLOCK
    li = np.zeros((n, n))                                   # L^-1, lower
    for i in range(0, n, b):
        j = min(n, i + b)
        d, info = dtrtri(np.tril(c[i:j, i:j]), lower=1)
        if info != 0:
            raise np.linalg.LinAlgError("covariance is singular")
        li[i:j, i:j] = d
        if i:   # block row i of L^-1: -D_ii^-1 (L_i,<i L^-1_<i,<i)
            li[i:j, :i] = -(d @ (c[i:j, :i] @ li[:i, :i]))
    p = np.empty((n, n))
    for i in range(0, n, b):
        j = min(n, i + b)
        p[i:j, :j] = li[i:, i:j].T @ li[i:, :j]             # rows k >= i hold L^-1[k, i:j]
        p[:i, i:j] = p[i:j, :i].T
        d = p[i:j, i:j]
        upper = np.triu_indices(j - i, 1)
        d[upper] = d.T[upper]                                # exactly symmetric
    return p
