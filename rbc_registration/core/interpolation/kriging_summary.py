"""Kriging above :data:`~.kriging.EXACT_MAX_FIDUCIALS` fiducials: the posterior variance and the
held-out predictions conditioned on a summary of the data, never below the exact variance.

Exact kriging reads the whole J x J Cholesky factor for every target's variance (O(J^2): 7.5-10 ms
per target at J = 5,000, bound by the memory bus) and its held-out predictions need the precision
matrix (O(J^3)). Above the threshold the variance at a target T is the exact variance of the same
Gaussian process given *part of the information* in the measurements y:

- y_N, the measurements of the :data:`LOCAL_NEIGHBOURS` fiducials nearest to T (the near field);
- z_U = K_UX K^-1 y, the exact posterior means of the field at :data:`INDUCING_POINTS` fiducials U
  spread over the cell (farthest-point order): the far field, which long length scales need (the
  neighbourhood alone was 1.3-2x the exact standard deviation in 2D at long length scales).

Both are linear in y, and conditioning on less cannot reduce the variance, so
Var(f(T) | y_N, z_U) >= Var(f(T) | y): the reported standard deviation is an upper bound of the
exact one, equal to it when the neighbours and the inducing means hold all the information. With
w = T^T z_U whitened (Cov(w) = I, :func:`_whiten`), a = Cov(w, f(T)) = T^T Phi^T k(T) with
Phi = K^-1 K_XU, A_N = Cov(y_N, w) = (K_XU T)_N, C = Cov(y_N | w) = K_NN - A_N A_N^T and
r = Cov(y_N, f(T) | w) = k_N - A_N a:

    Var(f(T) | w, y_N) = s^2 - |a|^2 - r^T C^-1 r,
    E[f(T) | w, y_N] = a^T w + theta^T (y_N - A_N w)

with theta = C^-1 r. theta is solved with a tiny diagonal jitter and the variance evaluated as the
mean squared error of that predictor, s^2 - |a|^2 - 2 r^T theta + theta^T C theta, which is at
least the minimum whatever the rounding of the solve. Per target O(J k) for ``a`` plus O(m^2 k),
k <= :data:`INDUCING_POINTS`; the posterior *mean* of a target stays exact (k(T)^T K^-1 y).

Held-out predictions (:meth:`DataSummary.held_out`, cross-validation) condition the same way on the
kept fiducials R of each fold only: the m nearest kept fiducials and z^R = Phi_R^T y_R (Phi's rows
of the held-out fiducials dropped, a linear function of y_R). The prediction is the best linear
predictor from them and the standard deviation its exact predictive one (field plus the held-out
measurement's noise), so the conformal bound of :mod:`.decision` is calibrated on the same kind of
standard deviation the targets get.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from .blocked_linalg import solve_blocked

#: Measurements of the nearest fiducials each target's variance is conditioned on (y_N).
LOCAL_NEIGHBOURS = 32
#: Inducing fiducials whose exact posterior means (z_U) carry the far field.
INDUCING_POINTS = 128
#: Eigenvalues of Cov(z_U) below this fraction of the largest are dropped by :func:`_whiten`
#: (conditioning on fewer summaries: the variance can only grow).
WHITEN_RTOL = 1e-12
#: Relative diagonal jitter of the solve for theta (its error only raises the variance).
SOLVE_JITTER = 1e-10
#: Targets conditioned at once (each holds an (m, k) block of A_N).
TARGET_BLOCK = 128

Covariance = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def spread_indices(points: NDArray[np.float64], count: int) -> NDArray[np.intp]:
    """``count`` fiducials in farthest-point order from the one nearest the centroid (sorted
    indices): spread over the cell, independent of a rigid motion (and, but for ties, of the
    order of the points)."""
    j = len(points)
    count = min(count, j)
    chosen = np.empty(count, dtype=np.intp)
    chosen[0] = np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1))
    far = np.linalg.norm(points - points[chosen[0]], axis=1)
    for c in range(1, count):
        chosen[c] = np.argmax(far)
        np.minimum(far, np.linalg.norm(points - points[chosen[c]], axis=1), out=far)
    return np.sort(chosen)


def _whiten(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """T (p, k) with T^T Q T = I_k over the eigenvectors of the symmetric Q whose eigenvalues are
    above :data:`WHITEN_RTOL` of the largest (the rest dropped)."""
    lam, vec = np.linalg.eigh(0.5 * (q + q.T))
    keep = lam > WHITEN_RTOL * max(float(lam[-1]), 0.0)
    if not keep.any():
        return np.zeros((len(q), 0))
    return vec[:, keep] / np.sqrt(lam[keep])


class Conditioned(NamedTuple):
    """The best linear predictor of f from (w, y_N) per target: ``variance`` (B,) its mean
    squared error, ``theta`` (B, m) its weights on y_N and ``on_w`` (B, k) its weights on w."""

    variance: NDArray[np.float64]
    theta: NDArray[np.float64]
    on_w: NDArray[np.float64]


def condition(signal_var: float, a: NDArray[np.float64], a_n: NDArray[np.float64],
              c_nn: NDArray[np.float64], k_n: NDArray[np.float64]) -> Conditioned:
    """Condition f on w (Cov(w) = I, Cov(w, f) = ``a`` (B, k)) and then on y_N (Cov ``c_nn``
    (B, m, m), Cov(y_N, w) = ``a_n`` (B, m, k), Cov(y_N, f) = ``k_n`` (B, m)): module docstring."""
    c = c_nn - a_n @ np.transpose(a_n, (0, 2, 1))
    r = k_n - (a_n @ a[:, :, None])[:, :, 0]
    m = c.shape[1]
    solve = c.copy()
    diagonal = solve.reshape(len(c), m * m)[:, ::m + 1]
    solve.reshape(len(c), m * m)[:, ::m + 1] += SOLVE_JITTER * diagonal.mean(axis=1)[:, None]
    theta = np.linalg.solve(solve, r[:, :, None])[:, :, 0]
    ctheta = (c @ theta[:, :, None])[:, :, 0]
    var = (signal_var - np.einsum("bk,bk->b", a, a) - 2.0 * np.einsum("bm,bm->b", r, theta)
           + np.einsum("bm,bm->b", theta, ctheta))
    return Conditioned(var, theta, a - (theta[:, None, :] @ a_n)[:, 0, :])


class HeldOutWeights:
    """The held-out predictor of one fold as a linear map of the kept fiducials' values:
    ``weights @ e`` (e (|R|, d) in the kept fiducials' order) as :meth:`KrigingInterpolator.
    held_out` gives it, W = the neighbours' theta (sparse) + on_w @ basis^T (rank k)."""

    def __init__(self, neighbours: NDArray[np.intp], conditioned: Conditioned,
                 basis: NDArray[np.float64]) -> None:
        self.neighbours, self.theta = neighbours, conditioned.theta
        self.on_w, self.basis = conditioned.on_w, basis
        self.shape = (len(neighbours), len(basis))

    def __matmul__(self, e: NDArray[np.float64]) -> NDArray[np.float64]:
        e = np.asarray(e, dtype=np.float64)
        local = np.einsum("sm,smd->sd", self.theta, e[self.neighbours])
        return local + self.on_w @ (self.basis.T @ e)

    def dense(self) -> NDArray[np.float64]:
        """W as an (|S|, |R|) array."""
        w = self.on_w @ self.basis.T
        np.add.at(w, (np.arange(len(w))[:, None], self.neighbours), self.theta)
        return w


class DataSummary:
    """The summary kriging conditions on above the exact threshold (module docstring), built once
    per interpolator from its Cholesky factor."""

    def __init__(self, points: NDArray[np.float64], cov: Covariance, low: NDArray[np.float64],
                 noise_var: NDArray[np.float64], signal_var: float,
                 corrections: NDArray[np.float64]) -> None:
        """
        :param points: fiducials (J, d). :param cov: the signal covariance of distances.
        :param low: the lower Cholesky factor of K (signal + noise), entries above ignored.
        :param noise_var: (J,) the noise variance on K's diagonal. :param signal_var: s^2.
        :param corrections: y (J, d); :attr:`alpha` = K^-1 y is solved with Phi.
        """
        self.points, self.cov, self.noise_var, self.signal_var = points, cov, noise_var, signal_var
        self.inducing = spread_indices(points, INDUCING_POINTS)
        self.k_xu = cov(cdist(points, points[self.inducing]))          # (J, p), signal
        d = corrections.shape[1]
        both = solve_blocked(low, np.hstack([corrections, self.k_xu]))
        self.alpha, self.phi = both[:, :d].copy(), both[:, d:].copy()   # K^-1 y, K^-1 K_XU
        t = _whiten(self.k_xu.T @ self.phi)                              # Cov(z_U) = K_UX Phi
        self.psi = self.phi @ t                                          # Cov(w, f(x)) = psi^T k
        self.a = self.k_xu @ t                                           # Cov(y_j, w)
        self.tree = cKDTree(points)
        self.neighbours = min(LOCAL_NEIGHBOURS, len(points))

    def _c_nn(self, points: NDArray[np.float64], noise_var: NDArray[np.float64],
              nn: NDArray[np.intp]) -> NDArray[np.float64]:
        """Cov(y_N) (B, m, m) of the fiducials ``nn`` (B, m) of ``points`` (noise ``noise_var``)."""
        p = points[nn]
        p -= p[:, :1]                                    # centred: |p_i - p_j|^2 by products
        sq = np.einsum("bmd,bmd->bm", p, p)
        r = p @ np.transpose(p, (0, 2, 1))
        r *= -2.0
        r += sq[:, :, None]
        r += sq[:, None, :]
        np.maximum(r, 0.0, out=r)
        c = self.cov(np.sqrt(r, out=r))
        m = nn.shape[1]
        c.reshape(len(nn), m * m)[:, ::m + 1] += noise_var[nn]
        return c

    def variance(self, targets: NDArray[np.float64], ks: NDArray[np.float64]
                 ) -> NDArray[np.float64]:
        """Var(f(T) | w, y_N) (K,) per axis at ``targets`` (K, d), given their signal covariance
        with the fiducials ``ks`` (K, J)."""
        out = np.empty(len(targets))
        for s in range(0, len(targets), TARGET_BLOCK):
            t, k = targets[s:s + TARGET_BLOCK], ks[s:s + TARGET_BLOCK]
            nn = self.tree.query(t, self.neighbours)[1].reshape(len(t), -1)
            out[s:s + len(t)] = condition(self.signal_var, k @ self.psi, self.a[nn],
                                          self._c_nn(self.points, self.noise_var, nn),
                                          np.take_along_axis(k, nn, axis=1)).variance
        return out

    def held_out(self, groups: Sequence[NDArray[np.intp]]
                 ) -> list[tuple[HeldOutWeights, NDArray[np.float64]]]:
        """Per index set S: the predictor of the fiducials S from the other fiducials R (in index
        order) conditioned on the m nearest of R and z^R = Phi_R^T y_R, and its predictive
        standard deviation per axis of a measurement at S (module docstring)."""
        j = len(self.points)
        out = []
        for group in groups:
            s = np.asarray(group, dtype=np.intp)
            r = np.setdiff1d(np.arange(j), s)
            k_rs = self.cov(cdist(self.points[r], self.points[s]))          # (|R|, |S|)
            phi_r = self.phi[r]
            k_rr_phi = self.k_xu[r] - k_rs @ self.phi[s]                   # K_RR Phi_R
            t = _whiten(phi_r.T @ k_rr_phi)
            basis = phi_r @ t                                               # w = basis^T y_R
            kept = self.points[r]
            nn = cKDTree(kept).query(self.points[s], min(self.neighbours, len(r)))[1]
            nn = nn.reshape(len(s), -1)
            k_n = np.take_along_axis(k_rs.T, nn, axis=1)
            # Cov(f_S, w) = K_SR Phi_R T, and K_SR Phi_R = K_XU[S] - K_SS Phi_S (K Phi = K_XU):
            # an |S| x |S| product instead of |S| x |R|
            k_ss = self.cov(cdist(self.points[s], self.points[s]))
            k_ss.flat[::len(s) + 1] += self.noise_var[s]
            a_s = (self.k_xu[s] - k_ss @ self.phi[s]) @ t
            got = condition(self.signal_var, a_s, (k_rr_phi @ t)[nn],
                            self._c_nn(kept, self.noise_var[r], nn), k_n)
            std = np.sqrt(np.maximum(got.variance, 0.0) + self.noise_var[s])
            out.append((HeldOutWeights(nn, got, basis), std))
        return out
