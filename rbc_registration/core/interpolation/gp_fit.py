"""Fitting the kriging hyper-parameters by maximum marginal likelihood, fast.

The model (:mod:`.kriging`): each component of the corrections eps is a zero-mean Gaussian process
with covariance s^2 M(r / l) (Matérn 5/2), observed with noise sigma^2 / (d n_j) per axis; the d
components share s, l and sigma. :func:`fit_hyperparameters`:

- the distance matrix is computed once per fit, and the Matérn terms once per length scale;
- a coarse grid over (l, noise / signal) with s^2 profiled out in closed form picks the basin
  (one Cholesky factorisation per grid point), then L-BFGS-B refines it with the analytic gradient
  of the log marginal likelihood (Rasmussen & Williams 2006, eq. 5.9);
- a warm start (the previous model's hyper-parameters, e.g. from the node) is refined, not reused
  blindly: the grid's best point is refined as well when it scores better; above
  :data:`FIT_MAX_FIDUCIALS` a warm start in the best basin is refined on the fit's subsample from
  itself (one or a few evaluations when the fiducials changed little), not from the search's;
- above :data:`FIT_MAX_FIDUCIALS` fiducials the hyper-parameters are fitted on a subsample of that
  size (grid on :data:`SEARCH_MAX_FIDUCIALS`); the interpolator always conditions on all fiducials.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Sequence

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist, squareform

from .blocked_linalg import inverse_from_cholesky
from ..repeats import typical_spacing
from ..validation import as_point_pairs

#: Above this many fiducials the hyper-parameters are fitted on a subsample of this many (the
#: fiducials ranked by distance from their centroid, every k-th: spread over the whole cell,
#: independent of their order and of rigid motions). The fit costs O(n^3) per evaluation.
FIT_MAX_FIDUCIALS = 1000
#: The coarse grid search runs on a subsample of at most this many fiducials (same rule).
SEARCH_MAX_FIDUCIALS = 300
#: Grid of the coarse search: length scales from spacing / 2 to 3 x extent (twice the largest
#: distance from the centroid), and noise / signal variance ratios (a noise-free bias field ...
#: pure noise).
GRID_LENGTHS = 8
GRID_NOISE_RATIOS = tuple(10.0 ** k for k in range(-6, 3))
#: With the noise fitted (no sigma given), the length scale is at least this many times the
#: fiducials' median nearest-neighbour distance (:func:`.repeats.typical_spacing`: coinciding
#: fiducials count once). Single measurements cannot tell a field that
#: varies between neighbouring fiducials from noise, and the likelihood then often prefers "no
#: noise, l ~ half the spacing": kriging passes through every fiducial's noise, and leave-one-out
#: cannot see it (a held-out fiducial is a spacing from the others, where such a field has faded
#: to its mean), so the decision applied it confidently while targets near a fiducial got that
#: fiducial's noise (1.21-1.40x the uncorrected TRE on 2D grids of 36, bias 0.3 x the noise,
#: without this floor). With sigma given the noise is known and
#: the bound is spacing / 4.
FITTED_NOISE_MIN_LENGTH = 1.0
#: Relative diagonal jitter (of s^2) that keeps the covariance numerically positive definite.
JITTER = 1e-10
#: L-BFGS-B stops when the nll changes by less than FTOL (relative) or the projected gradient is
#: below GTOL: tight, so the optimum does not depend on rounding (a rigid motion of the frame or a
#: reordering of the fiducials changes the hyper-parameters by < 1e-6 relative).
FTOL = 1e-11
GTOL = 1e-5
_SQRT5 = math.sqrt(5.0)
#: Entries :func:`matern52` processes at once (1 MB of float64 per scratch buffer).
_BLOCK_ELEMENTS = 1 << 17
_FAILED = 1e300


class KrigingHyperparameters(NamedTuple):
    """Fitted GP hyper-parameters (units of the points): ``signal_std`` s (per axis),
    ``length_scale`` l, ``noise_std`` sigma of a single measurement (all axes, as
    :func:`noise.estimate_sigma`), and whether sigma was fitted."""

    signal_std: float
    length_scale: float
    noise_std: float
    noise_fitted: bool


def matern52(r: NDArray[np.float64], length: float) -> NDArray[np.float64]:
    """Matérn 5/2 correlation of the distances ``r``, which are overwritten and returned.

    Computed in place, at most :data:`_BLOCK_ELEMENTS` entries at a time with two small scratch
    buffers: no array of the size of ``r`` is allocated (on the project VM every fresh 200 MB
    array, J = 5,000, cost about 0.3 s of page faults; the covariance took 1.5 s, now 0.1 s).
    """
    flat = r.reshape(-1)   # a view for the C-contiguous arrays of cdist (else a copy, returned)
    step = max(1, min(flat.size, _BLOCK_ELEMENTS))
    e, f = np.empty(step), np.empty(step)
    for s in range(0, flat.size, step):
        a = flat[s:s + step]
        eb, fb = e[:len(a)], f[:len(a)]
        a *= _SQRT5 / length
        np.negative(a, out=eb)
        np.exp(eb, out=eb)                         # exp(-a)
        np.add(a, 3.0, out=fb)
        fb *= a
        fb *= 1.0 / 3.0
        fb += 1.0                                  # a (a + 3) / 3 + 1 = 1 + a + a^2 / 3
        np.multiply(fb, eb, out=a)
    return flat.reshape(r.shape)


def _matern_terms(scaled: NDArray[np.float64], length: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """a = sqrt(5) r / l, exp(-a) and the Matérn 5/2 correlation (1 + a + a^2/3) exp(-a)."""
    a = scaled / length
    e = np.exp(-a)
    m = a * (1.0 / 3.0)
    m += 1.0
    m *= a
    m += 1.0
    m *= e
    return a, e, m


def _cholesky(k: NDArray[np.float64], gil_free: bool = False) -> Optional[NDArray[np.float64]]:
    """Lower Cholesky factor of the symmetric matrix ``k`` (overwritten), None if not PD;
    ``gil_free``: numpy's, which releases the GIL (scipy's ``dpotrf`` holds it)."""
    if gil_free:
        try:
            return np.linalg.cholesky(k)
        except np.linalg.LinAlgError:
            return None
    c, info = lapack.dpotrf(k.T, lower=1, clean=1, overwrite_a=1)   # k.T: Fortran view, no copy
    return c if info == 0 else None


def _lower_inverse(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """The lower triangle of K^-1 (zeros above) from the clean lower Cholesky factor of K."""
    inv, info = lapack.dpotri(c, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError("covariance is singular")
    return inv


def _subsample(points: NDArray[np.float64], size: int) -> NDArray[np.intp]:
    """Indices of at most ``size`` fiducials spread over the cell: ranked by distance from the
    centroid (stable), every k-th. Invariant to rigid motion and to the order of the points."""
    j = len(points)
    if j <= size:
        return np.arange(j)
    radius = np.linalg.norm(points - points.mean(axis=0), axis=1)
    order = np.argsort(radius, kind="stable")
    return np.sort(order[np.unique(np.linspace(0, j - 1, size).round().astype(np.intp))])


class MarginalLikelihood:
    """Negative log marginal likelihood of the corrections and its gradient (R&W eq. 2.30, 5.9).

    nll = 1/2 tr(E^T K^-1 E) + d/2 log|K| (constant dropped), the d components sharing
    K = s^2 (M + jitter I) + noise^2 diag(1 / n_j), M the Matérn 5/2 correlation.
    theta = (log(s^2 / v), log l, log(noise^2 / v)) with v the mean squared correction;
    noise^2 (per axis) is fixed when given. The gradient is 1/2 tr((d K^-1 - a a^T) dK/dtheta),
    a = K^-1 E. The scaled distances sqrt(5) r are computed once.
    """

    def __init__(self, points: NDArray[np.float64], corrections: NDArray[np.float64],
                 inv_n: NDArray[np.float64], scale: float,
                 noise2: Optional[float] = None, gil_free: bool = False) -> None:
        self.eps = corrections
        self.inv_n = inv_n
        self.scale = scale
        self.noise2 = noise2
        self.gil_free = gil_free
        self.scaled = _SQRT5 * squareform(pdist(points))
        self.evaluations = 0

    def unpack(self, theta: Sequence[float]) -> tuple[float, float, float]:
        """(s^2, l, noise^2 per axis) of theta."""
        s2 = self.scale * math.exp(theta[0])
        noise2 = self.scale * math.exp(theta[2]) if self.noise2 is None else self.noise2
        return s2, math.exp(theta[1]), noise2

    def _factor(self, m: NDArray[np.float64], s2: float, noise2: float
                ) -> Optional[NDArray[np.float64]]:
        k = s2 * m
        k.flat[::len(k) + 1] += noise2 * self.inv_n + JITTER * s2
        return _cholesky(k, self.gil_free)

    def _data_fit(self, c: NDArray[np.float64]) -> tuple[NDArray[np.float64], float, float]:
        alpha, _ = lapack.dpotrs(c, self.eps, lower=1)
        return alpha, float(np.sum(self.eps * alpha)), 2.0 * float(np.sum(np.log(np.diag(c))))

    def __call__(self, theta: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """nll and its gradient with respect to theta."""
        self.evaluations += 1
        s2, length, noise2 = self.unpack(theta)
        a, e, m = _matern_terms(self.scaled, length)
        c = self._factor(m, s2, noise2)
        if c is None:
            return _FAILED, np.zeros(len(theta))
        alpha, quad, logdet = self._data_fit(c)
        d = self.eps.shape[1]
        # K^-1, lower triangle (upper zeros); GIL-free: from blocked products (dpotri held the
        # GIL for ~14 ms per evaluation at n = 1,000, delaying the node's answers)
        low = np.tril(inverse_from_cholesky(c)) if self.gil_free else _lower_inverse(c)
        if not np.isfinite(low).all():           # a factor too close to singular to invert
            return _FAILED, np.zeros(len(theta))
        diag_inv = np.diag(low).copy()

        def trace_b(dk: NDArray[np.float64]) -> float:
            """tr((d K^-1 - a a^T) dK) for a symmetric dK, from K^-1's lower triangle."""
            tr_inv = 2.0 * float(np.vdot(low, dk)) - float(diag_inv @ np.diag(dk))
            return d * tr_inv - float(np.sum(alpha * (dk @ alpha)))

        diag_b = d * diag_inv - np.sum(alpha * alpha, axis=1)
        grad = [0.5 * s2 * (trace_b(m) + JITTER * float(diag_b.sum()))]
        a2 = a * a                                   # dM/dlog l = a^2 (1 + a) exp(-a) / 3
        a2 *= 1.0 + a
        a2 *= e
        grad.append(0.5 * s2 / 3.0 * trace_b(a2))
        if self.noise2 is None:
            grad.append(0.5 * noise2 * float(diag_b @ self.inv_n))
        return 0.5 * quad + 0.5 * d * logdet, np.array(grad)

    def grid_search(self, lengths: Sequence[float]) -> NDArray[np.float64]:
        """The best theta over ``lengths`` x :data:`GRID_NOISE_RATIOS` (noise fitted: s^2 in
        closed form, s^2 = tr(E^T C^-1 E) / (J d) with C = K / s^2) or over ``lengths`` x signal
        variances (noise given). One Matérn evaluation per length, one Cholesky per point."""
        j, d = self.eps.shape
        best, best_theta = math.inf, None
        for length in lengths:
            m = _matern_terms(self.scaled, length)[2]
            for ratio in GRID_NOISE_RATIOS:
                if self.noise2 is None:      # C = M + ratio diag(1/n_j); profile s^2
                    c = self._factor(m, 1.0, ratio)
                    if c is None:
                        continue
                    _, quad, logdet = self._data_fit(c)
                    s2 = max(quad / (j * d), 1e-300)
                    value = 0.5 * j * d * (1.0 + math.log(s2)) + 0.5 * d * logdet
                    noise2 = ratio * s2
                else:                         # noise fixed: grid over s^2 = noise^2 / ratio
                    s2 = self.noise2 / ratio if self.noise2 > 0 else self.scale * ratio
                    c = self._factor(m, s2, self.noise2)
                    if c is None:
                        continue
                    _, quad, logdet = self._data_fit(c)
                    value = 0.5 * quad + 0.5 * d * logdet
                    noise2 = self.noise2
                if value < best:
                    best = value
                    best_theta = [math.log(s2 / self.scale), math.log(length)]
                    if self.noise2 is None:
                        best_theta.append(math.log(max(noise2, 1e-300) / self.scale))
        if best_theta is None:
            raise ValueError("kriging: no covariance of the search grid is positive definite")
        return np.array(best_theta)


def _minimise(nll: MarginalLikelihood, theta0: NDArray[np.float64],
              bounds: list[tuple[float, float]]) -> scipy.optimize.OptimizeResult:
    lo, hi = np.array(bounds).T
    return scipy.optimize.minimize(nll, np.clip(theta0, lo, hi), jac=True, method="L-BFGS-B",
                                   bounds=bounds, options={"ftol": FTOL, "gtol": GTOL})


def fit_hyperparameters(points: ArrayLike, corrections: ArrayLike,
                        sigma: Optional[float] = None, repeats: Optional[Sequence[int]] = None,
                        initial: Optional[KrigingHyperparameters] = None,
                        gil_free: bool = False) -> KrigingHyperparameters:
    """Maximum marginal likelihood hyper-parameters of the correction field (module docstring).

    :param points: fiducials in the working frame (J, d).
    :param corrections: eps at the fiducials (J, d).
    :param sigma: noise sigma of one measurement (all axes); ``None``: fitted as well.
    :param repeats: measurements averaged into each fiducial, n_j (default 1 each).
    :param initial: a warm start, e.g. the previous model's hyper-parameters: refined from there
        (and compared with the coarse grid's best point), never reused as they are.
    :param gil_free: factorise and invert with calls that release the GIL (numpy's Cholesky,
        :func:`.blocked_linalg.inverse_from_cholesky`): the same optimum to rounding, not bit for
        bit; kriging uses it above :data:`~.kriging.EXACT_MAX_FIDUCIALS`, where the fit runs
        beside the node's answers.
    :return: :class:`KrigingHyperparameters`.
    :raises ValueError: on bad input.
    """
    x, eps = as_point_pairs(points, corrections, min_count=2)
    j, d = x.shape
    inv_n = 1.0 / repeat_counts(repeats, j)
    if sigma is not None and (not math.isfinite(sigma) or sigma < 0):
        raise ValueError(f"sigma must be finite and >= 0, got {sigma}")
    scale = max(float(np.mean(eps * eps)), 1e-300)
    near = cKDTree(x).query(x, k=2)[0][:, 1]
    spacing = float(np.min(near[near > 0])) if (near > 0).any() else 1.0
    # extent: twice the largest distance from the centroid (invariant to rotations of the frame)
    extent = max(2.0 * float(np.linalg.norm(x - x.mean(axis=0), axis=1).max()), spacing)
    noise2 = None if sigma is None else float(sigma) ** 2 / d
    shortest = spacing / 4
    if noise2 is None:          # variation between neighbours is not told from noise
        shortest = max(shortest, FITTED_NOISE_MIN_LENGTH * typical_spacing(x))
    bounds = [(math.log(1e-8), math.log(1e3)), (math.log(shortest), math.log(extent * 10))]
    if noise2 is None:
        bounds.append((math.log(1e-12), math.log(1e2)))

    def likelihood(idx: NDArray[np.intp]) -> MarginalLikelihood:
        # GIL-free pays only beyond the search's size (scipy's LAPACK holds it < 1 ms there)
        return MarginalLikelihood(x[idx], eps[idx], inv_n[idx], scale, noise2,
                                  gil_free and len(idx) > SEARCH_MAX_FIDUCIALS)

    fit_idx = _subsample(x, FIT_MAX_FIDUCIALS)
    search_idx = _subsample(x, SEARCH_MAX_FIDUCIALS)
    fit = likelihood(fit_idx)
    search = fit if len(search_idx) == len(fit_idx) else likelihood(search_idx)
    grid = search.grid_search(np.geomspace(max(spacing / 2, shortest), max(extent, shortest) * 3,
                                           GRID_LENGTHS))
    start = None if initial is None else _theta(initial, scale, noise2, d)
    if start is not None:
        best = _minimise(search, start, bounds)
        if search(grid)[0] < best.fun:        # the warm start sits in a worse basin
            other = _minimise(search, grid, bounds)
            best = other if other.fun < best.fun else best
            start = None
    else:
        best = _minimise(search, grid, bounds)
    if search is not fit:
        # A warm start in the best basin is refined on the fit's subsample from where it was:
        # the previous model's optimum of (nearly) the same subsample, a few evaluations away;
        # the search subsample's optimum is ~15 evaluations of O(FIT_MAX_FIDUCIALS^3) away.
        best = _minimise(fit, best.x if start is None else start, bounds)
    s2, length, n2 = fit.unpack(best.x)
    return KrigingHyperparameters(math.sqrt(s2), length, math.sqrt(n2 * d), noise2 is None)


def _theta(h: KrigingHyperparameters, scale: float, noise2: Optional[float],
           dim: int) -> NDArray[np.float64]:
    """theta of :class:`MarginalLikelihood` for given hyper-parameters (a warm start)."""
    theta = [2 * math.log(max(h.signal_std, 1e-150)) - math.log(scale),
             math.log(max(h.length_scale, 1e-300))]
    if noise2 is None:                      # noise_std is all axes; theta holds it per axis
        theta.append(2 * math.log(max(h.noise_std, 1e-150)) - math.log(dim * scale))
    return np.array(theta)


def repeat_counts(repeats: Optional[Sequence[int]], j: int) -> NDArray[np.float64]:
    """n_j as floats (default 1 each). :raises ValueError: unless ``j`` finite counts >= 1."""
    n = np.ones(j) if repeats is None else np.asarray(repeats, dtype=np.float64)
    if n.shape != (j,) or not np.all(np.isfinite(n)) or (n < 1).any():
        raise ValueError(f"repeats must be {j} counts >= 1, got {repeats!r}")
    return n
