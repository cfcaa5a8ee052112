"""Noise-aware interpolation of fiducial corrections: Gaussian-process regression ("kriging").

Each component of eps is modelled as a zero-mean Gaussian process over the working frame with a
Matérn 5/2 covariance s^2 k(r / l), observed at the fiducials with noise variance
sigma^2 / (d n_j) per axis (sigma as in :func:`noise.estimate_sigma`, n_j repeats averaged into
fiducial j). The signal variance s^2 and
length scale l (and sigma when it is unknown) are fitted to the corrections by maximising the
marginal likelihood, shared by the d components. The posterior mean shrinks corrections toward zero
where noise dominates the field (rho < 1), so correcting does not make registration worse; where the
bias dominates it follows the fiducials closely. The posterior standard deviation is reported as the
expected error of the correction.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Sequence

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.distance import cdist, pdist, squareform

from .interpolation import HullTest, Interpolated
from .validation import as_point_pairs, as_points


class KrigingHyperparameters(NamedTuple):
    """Fitted GP hyper-parameters (units of the points): ``signal_std`` s (per axis),
    ``length_scale`` l, ``noise_std`` sigma of a single measurement (all axes, as
    :func:`noise.estimate_sigma`), and whether sigma was fitted."""

    signal_std: float
    length_scale: float
    noise_std: float
    noise_fitted: bool


def _matern52(r: NDArray[np.float64], length: float) -> NDArray[np.float64]:
    a = math.sqrt(5.0) * r / length
    return (1.0 + a + a * a / 3.0) * np.exp(-a)


class KrigingInterpolator:
    """Gaussian-process interpolation of corrections (module docstring)."""

    method = "kriging"

    def __init__(self, points: ArrayLike, corrections: ArrayLike, sigma: Optional[float] = None,
                 repeats: Optional[Sequence[int]] = None,
                 hyperparameters: Optional[KrigingHyperparameters] = None) -> None:
        """
        :param points: fiducials in the working frame (J, d).
        :param corrections: eps at the fiducials (J, d).
        :param sigma: noise sigma of one measurement (all axes); ``None``: fitted as well.
        :param repeats: measurements averaged into each fiducial, n_j (default 1 each).
        :param hyperparameters: reuse these instead of fitting (e.g. in leave-one-out).
        :raises ValueError: on bad input or fewer than d + 1 fiducials.
        """
        self.points, self.corrections = as_point_pairs(points, corrections, min_count=1)
        j, self.dim = self.points.shape
        if j < self.dim + 1:
            raise ValueError(f"kriging in {self.dim}D needs at least {self.dim + 1} fiducials, "
                             f"got {j}")
        n = np.ones(j) if repeats is None else np.asarray(repeats, dtype=np.float64)
        if n.shape != (j,) or not np.all(np.isfinite(n)) or (n < 1).any():
            raise ValueError(f"repeats must be {j} counts >= 1, got {repeats!r}")
        if sigma is not None and (not math.isfinite(sigma) or sigma < 0):
            raise ValueError(f"sigma must be finite and >= 0, got {sigma}")
        self.inv_n = 1.0 / n
        self.hull = HullTest(self.points)
        self.dist = squareform(pdist(self.points))
        self.hyper = hyperparameters or self._fit(sigma)
        k = self._cov(self.dist) + np.diag(self._noise_var())
        self.chol = scipy.linalg.cho_factor(k, lower=True)
        self.alpha = scipy.linalg.cho_solve(self.chol, self.corrections)

    def _cov(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.hyper.signal_std ** 2 * _matern52(r, self.hyper.length_scale)

    def _noise_var(self) -> NDArray[np.float64]:
        h = self.hyper
        return h.noise_std ** 2 / self.dim * self.inv_n + 1e-10 * h.signal_std ** 2

    def _fit(self, sigma: Optional[float]) -> KrigingHyperparameters:
        eps = self.corrections
        j, d = eps.shape
        var = max(float(np.mean(eps * eps)), 1e-300)
        off = self.dist[np.triu_indices(j, 1)]
        spacing = float(np.min(np.where(off > 0, off, np.inf)))
        extent = float(off.max())
        fit_noise = sigma is None

        def unpack(theta: NDArray[np.float64]) -> tuple[float, float, float]:
            s2 = var * math.exp(theta[0])
            length = math.exp(theta[1])
            noise2 = var * math.exp(theta[2]) if fit_noise else float(sigma) ** 2 / d
            return s2, length, noise2

        def nll(theta: NDArray[np.float64]) -> float:
            s2, length, noise2 = unpack(theta)
            k = s2 * _matern52(self.dist, length)
            k[np.diag_indices(j)] += noise2 * self.inv_n + 1e-10 * s2
            try:
                c, low = scipy.linalg.cho_factor(k, lower=True, check_finite=False)
            except np.linalg.LinAlgError:
                return 1e300
            a = scipy.linalg.cho_solve((c, low), eps, check_finite=False)
            return 0.5 * float(np.sum(eps * a)) + d * float(np.sum(np.log(np.diag(c))))

        lo_l, hi_l = math.log(spacing / 4), math.log(extent * 10)
        bounds = [(math.log(1e-8), math.log(1e3)), (lo_l, hi_l)]
        if fit_noise:
            bounds.append((math.log(1e-12), math.log(1e2)))
        best = None
        for length0 in np.geomspace(spacing, extent, 5):
            theta0 = [0.0, math.log(length0)] + ([math.log(0.1)] if fit_noise else [])
            res = scipy.optimize.minimize(nll, theta0, method="L-BFGS-B", bounds=bounds)
            if best is None or res.fun < best.fun:
                best = res
        s2, length, noise2 = unpack(best.x)       # noise2: per axis
        return KrigingHyperparameters(math.sqrt(s2), length, math.sqrt(noise2 * d), fit_noise)

    def __call__(self, targets: ArrayLike) -> Interpolated:
        """Posterior mean (eps(T), shape (K, d)) and standard deviation per axis at the targets."""
        t = as_points(targets, "targets", self.dim)
        ks = self._cov(cdist(t, self.points))
        mean = ks @ self.alpha
        v = scipy.linalg.solve_triangular(self.chol[0], ks.T, lower=True)
        var = self.hyper.signal_std ** 2 - np.sum(v * v, axis=0)
        inside = self.hull.simplices(t) >= 0
        return Interpolated(mean, inside, np.sqrt(np.maximum(var, 0.0)))
