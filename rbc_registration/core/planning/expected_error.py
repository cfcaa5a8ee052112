"""Expected target registration error of a fiducial configuration, computable before measuring.

The expected squared error at a working-frame point T is the sum of three independent parts
(variances add; lengths in the unit of the points):

1. **Bias field** (corrected registration): the kriging posterior variance of the correction
   eps(T) given the fiducials, summed over the d axes. The bias is modelled as in
   :mod:`.kriging`: each component a zero-mean Gaussian process with covariance s^2 k(r / l)
   (Matérn 5/2), observed at fiducial j with the measurement noise averaged over its n_j repeats.
   With a noise covariance Sigma of one measurement, the prior is isotropic, so in the
   eigenbasis of Sigma (eigenvalues lambda_a) the d components stay independent GPs with noise
   lambda_a / n_j:  var_bias(T) = sum_a [s^2 - k(T)^T (s^2 K + diag(lambda_a / n_j))^-1 k(T)].
   It depends on the locations and hyper-parameters only, never on measured values: adding a
   candidate c is a rank-one update of the posterior (:class:`BiasPosterior`),
   var'(T) = var(T) - cov(T, c)^2 / (var(c) + lambda_a / n_c).
   Uncorrected registration: the bias is not corrected; its prior variance d s^2 stays.
2. **Rigid fit**: first-order propagation of the fiducial localisation error through the
   least-squares rigid fit, TRE_rigid^2(T) = trace(D(T) G^-1 S G^-1 D(T)^T)
   (:mod:`.rigid_tre`: Fitzpatrick & West 2001, anisotropic as Wiles et al. 2008 and
   Danilchenko & Fitzpatrick 2011), with fiducial error covariance C_j = Sigma / n_j (the noise;
   per axis sigma_x^2, sigma_y^2, ... when Sigma is diagonal); the uncorrected registration adds
   the bias as fiducial error, C_j = Sigma / n_j + s^2 I. The destination frame is exact.
3. **Target measurement**: trace(Sigma) / n_T, the noise of the target itself (uncorrected: plus
   nothing, its bias is part 1).

The expected *median* TRE over a set of points is the median of the pooled predicted
distribution: each point's error is taken as an isotropic Gaussian with its expected squared
error E_k, so ||error_k||^2 ~ (E_k / d) chi^2_d, and the median m solves
mean_k P(chi^2_d <= d m^2 / E_k) = 1/2 (:func:`pooled_median`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
import scipy.linalg
import scipy.special
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.distance import cdist

from ..constants import DIMENSIONS
# matern52 overwrites its distances: pass fresh ones
from ..interpolation.gp_fit import matern52 as _matern52
from .rigid_tre import RigidFitError
from ..validation import as_points

#: Relative jitter on the GP diagonal, as :mod:`.kriging` uses.
JITTER = 1e-10


@dataclass(frozen=True, eq=False)
class ExpectedErrorModel:
    """What the expected error depends on besides the locations (unit of the points).

    :ivar signal_std: s, prior standard deviation of each component of the bias correction.
    :ivar length_scale: l of the Matérn 5/2 covariance of the bias.
    :ivar noise_covariance: (d, d) covariance of one working-frame measurement, working frame
        (diagonal: the variance per axis).
    :ivar corrected: True: the registration applies the correction eps(T) (kriging); False: the
        uncorrected registration (the bias stays in the error).
    :ivar calibration: factor on every expected error (1: as modelled; e.g. the ratio of
        cross-validated to expected errors, :func:`.model_planner.check_expected_error`).
    """

    signal_std: float
    length_scale: float
    noise_covariance: NDArray[np.float64]
    corrected: bool = True
    calibration: float = 1.0

    def __post_init__(self) -> None:
        for name in ("signal_std", "length_scale", "calibration"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")
        cov = np.array(self.noise_covariance, dtype=np.float64)
        if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or cov.shape[0] not in DIMENSIONS:
            raise ValueError(f"noise_covariance must have shape (2, 2) or (3, 3), got {cov.shape}")
        if not np.all(np.isfinite(cov)):
            raise ValueError("noise_covariance contains NaN or inf")
        if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-300):
            raise ValueError("noise_covariance must be symmetric")
        if np.linalg.eigvalsh(cov).min() < -1e-12 * max(float(np.trace(cov)), 1e-300):
            raise ValueError("noise_covariance must be positive semi-definite")
        cov.setflags(write=False)
        object.__setattr__(self, "noise_covariance", cov)

    @classmethod
    def from_axis_std(cls, signal_std: float, length_scale: float, axis_std: ArrayLike,
                      corrected: bool = True, calibration: float = 1.0) -> "ExpectedErrorModel":
        """Noise independent per working-frame axis with standard deviations ``axis_std`` (d,)."""
        std = np.asarray(axis_std, dtype=np.float64)
        if std.ndim != 1 or len(std) not in DIMENSIONS or not np.all(np.isfinite(std)) \
                or (std < 0).any():
            raise ValueError(f"axis_std must be 2 or 3 finite values >= 0, got {axis_std!r}")
        return cls(signal_std, length_scale, np.diag(std * std), corrected, calibration)

    @property
    def dimension(self) -> int:
        """d, 2 or 3."""
        return self.noise_covariance.shape[0]


class BiasPosterior:
    """Kriging posterior variance of the bias at K points (module docstring, part 1), with
    rank-one updates for candidates, vectorised over candidates."""

    def __init__(self, fiducials: NDArray[np.float64], inv_n: NDArray[np.float64],
                 candidates: NDArray[np.float64], candidate_inv_n: float,
                 points: NDArray[np.float64], model: ExpectedErrorModel) -> None:
        s2, length = model.signal_std ** 2, model.length_scale
        lam = np.clip(np.linalg.eigvalsh(model.noise_covariance), 0.0, None)
        # Equal noise on every axis: one GP serves all d components.
        iso = lam.max() - lam.min() <= 1e-12 * max(lam.max(), 1e-300)
        self.noise = lam[:1] if iso else lam
        self.weight = np.array([float(len(lam))]) if iso else np.ones(len(lam))
        self.s2, self.length = s2, length
        self.candidates = candidates
        self.candidate_noise = self.noise * candidate_inv_n + JITTER * s2
        k_ff = s2 * _matern52(cdist(fiducials, fiducials), length)
        k_fc = s2 * _matern52(cdist(fiducials, candidates), length)
        k_fp = s2 * _matern52(cdist(fiducials, points), length)
        k_pc = s2 * _matern52(cdist(points, candidates), length)
        self.var_p, self.cov_pc, self.var_c, self.w_c = [], [], [], []
        for lam_a in self.noise:
            chol = scipy.linalg.cholesky(k_ff + np.diag(lam_a * inv_n + JITTER * s2), lower=True)
            wp = scipy.linalg.solve_triangular(chol, k_fp, lower=True)
            wc = scipy.linalg.solve_triangular(chol, k_fc, lower=True)
            self.var_p.append(s2 - np.sum(wp * wp, axis=0))
            self.cov_pc.append(k_pc - wp.T @ wc)
            self.var_c.append(s2 - np.sum(wc * wc, axis=0))
            self.w_c.append(wc)
        self.updates: list[list[NDArray[np.float64]]] = [[] for _ in self.noise]

    def now(self) -> NDArray[np.float64]:
        """(K,) summed posterior variance of the bias components."""
        return sum(w * np.maximum(v, 0.0) for w, v in zip(self.weight, self.var_p))

    def after_each(self, active: NDArray[np.intp]) -> NDArray[np.float64]:
        """(len(active), K) summed posterior variance after adding each candidate alone."""
        out = 0.0
        for a, w in enumerate(self.weight):
            cov = self.cov_pc[a][:, active]                         # (K, C)
            den = np.maximum(self.var_c[a][active], 0.0) + self.candidate_noise[a]
            out = out + w * np.maximum(self.var_p[a][None, :] - (cov * cov).T / den[:, None], 0.0)
        return out

    def after_units(self, members: NDArray[np.intp]) -> NDArray[np.float64]:
        """(U, K) summed posterior variance after adding each unit's candidates together:
        ``members`` (U, m) candidate indices per unit, padded with -1. Per component, the
        posterior given a unit G is var(T) - diag(cov(T, G) (cov(G, G) + noise)^-1 cov(G, T))
        (a rank-m update; m = 1 is :meth:`after_each`)."""
        used = members >= 0
        at = np.maximum(members, 0)
        pts = self.candidates[at]                                     # (U, m, d)
        gap = np.linalg.norm(pts[:, :, None, :] - pts[:, None, :, :], axis=-1)
        prior = self.s2 * _matern52(gap, self.length)                 # (U, m, m)
        pair = used[:, :, None] & used[:, None, :]
        eye = np.eye(members.shape[1], dtype=bool)[None]
        out = 0.0
        for a, w in enumerate(self.weight):
            wc = self.w_c[a][:, at]                                   # (J, U, m)
            cov_gg = prior - np.einsum("jui,juk->uik", wc, wc)
            for u in self.updates[a]:
                cov_gg = cov_gg - u[at][:, :, None] * u[at][:, None, :]
            cov_gg = np.where(pair, cov_gg, 0.0) + np.where(
                eye, np.where(used, self.candidate_noise[a], 1.0)[:, :, None], 0.0)
            cov_pg = np.where(used[:, None, :], self.cov_pc[a][:, at].transpose(1, 0, 2), 0.0)
            solved = np.linalg.solve(cov_gg, cov_pg.transpose(0, 2, 1))  # (U, m, K)
            drop = np.einsum("ukm,umk->uk", cov_pg, solved)
            out = out + w * np.maximum(self.var_p[a][None, :] - drop, 0.0)
        return out

    def add(self, c: int) -> None:
        """Condition on candidate ``c`` having been measured (rank-one update, per component)."""
        prior_row = self.s2 * _matern52(cdist(self.candidates[c:c + 1], self.candidates),
                                        self.length)[0]
        for a in range(len(self.noise)):
            row = prior_row - self.w_c[a][:, c] @ self.w_c[a]        # cov(c, candidates)
            for u in self.updates[a]:
                row = row - u[c] * u
            den = max(float(row[c]), 0.0) + float(self.candidate_noise[a])
            u = row / math.sqrt(den)
            col = self.cov_pc[a][:, c] / math.sqrt(den)                # cov(points, c) / sqrt
            self.var_p[a] = self.var_p[a] - col * col
            self.cov_pc[a] = self.cov_pc[a] - np.outer(col, u)
            self.var_c[a] = self.var_c[a] - u * u
            self.updates[a].append(u)


def _chi2_cdf_pdf(x: NDArray[np.float64], d: int) -> tuple[NDArray[np.float64],
                                                             NDArray[np.float64]]:
    """P(chi^2_d / 2 <= x) and its derivative in x (x = chi^2 / 2), d = 2 or 3, in closed form:
    d = 2: 1 - e^-x and e^-x; d = 3: erf(sqrt x) - p and p = 2 sqrt(x / pi) e^-x."""
    if d == 2:
        pdf = np.exp(-x)
        return 1.0 - pdf, pdf
    root = np.sqrt(x)
    pdf = (2.0 / math.sqrt(math.pi)) * root * np.exp(-x)
    return scipy.special.erf(root) - pdf, pdf


def pooled_median(expected_sq: ArrayLike, dimension: int, start: Optional[ArrayLike] = None,
                  iterations: int = 60) -> NDArray[np.float64]:
    """Median of the pooled predicted TRE distribution over the last axis (module docstring).

    :param expected_sq: (..., K) expected squared errors E_k (> 0).
    :param dimension: d = 2 or 3, the degrees of freedom of each error.
    :param start: (...) a guess of the medians (e.g. from a previous, similar call).
    :return: (...) the median m with mean_k P(||e_k|| <= m) = 1/2, solved by Newton steps on
        log m^2 kept inside a bisection bracket.
    """
    e = np.maximum(np.asarray(expected_sq, dtype=np.float64), 1e-300)
    d = int(dimension)
    if d not in DIMENSIONS:
        raise ValueError(f"dimension must be 2 or 3, got {dimension!r}")
    med_d = float(scipy.special.gammaincinv(d / 2.0, 0.5))       # median of chi^2_d / 2
    # m^2 = u; each point's own median u_k = 2 med_d E_k / d brackets the pooled median.
    own = np.log(2.0 * med_d * e / d)
    lo, hi = own.min(axis=-1), own.max(axis=-1)
    s = np.median(own, axis=-1) if start is None else \
        np.clip(2.0 * np.log(np.maximum(np.asarray(start, dtype=np.float64), 1e-150)), lo, hi)
    for _ in range(iterations):
        x = np.exp(s)[..., None] * d / (2.0 * e)
        cdf, pdf = _chi2_cdf_pdf(x, d)
        f = cdf.mean(axis=-1) - 0.5
        lo = np.where(f < 0, s, lo)
        hi = np.where(f > 0, s, hi)
        slope = (pdf * x).mean(axis=-1)                           # dF / d log u
        step = s - f / np.maximum(slope, 1e-300)                  # Newton, kept in the bracket
        newton = (step >= lo) & (step <= hi)
        new = np.where(newton, step, 0.5 * (lo + hi))
        # quadratic convergence: after a Newton step this small the error is below 1e-14
        done = np.all(newton & (np.abs(new - s) < 1e-7))
        s = new
        if done:
            break
    return np.sqrt(np.exp(s))


def inverse_repeats(repeats: Optional[ArrayLike], j: int) -> NDArray[np.float64]:
    """1 / n_j of ``repeats`` (J,) counts >= 1 (all 1 when None)."""
    if repeats is None:
        return np.ones(j)
    n = np.asarray(repeats, dtype=np.float64)
    if n.shape != (j,) or not np.all(np.isfinite(n)) or (n < 1).any():
        raise ValueError(f"repeats must be {j} counts >= 1, got shape {n.shape}")
    return 1.0 / n


def target_noise(model: ExpectedErrorModel, repeats: float) -> float:
    """trace(Sigma) / n_T: the target's own measurement noise (part 3), squared length."""
    return float(np.trace(model.noise_covariance)) / repeats


def fiducial_covariance(model: ExpectedErrorModel, inv_n: NDArray[np.float64]
                        ) -> NDArray[np.float64]:
    """(J, d, d) localisation error covariance of fiducials measured 1 / inv_n times: the noise
    Sigma / n_j, plus the bias s^2 I for the uncorrected registration."""
    d = model.dimension
    cov = inv_n[:, None, None] * model.noise_covariance[None]
    if not model.corrected:
        cov = cov + model.signal_std ** 2 * np.eye(d)[None]
    return cov


def expected_squared_errors(fiducials: ArrayLike, points: ArrayLike, model: ExpectedErrorModel,
                            repeats: Optional[ArrayLike] = None, target_repeats: float = 1.0
                            ) -> NDArray[np.float64]:
    """(K,) expected squared TRE at each point with these fiducials, calibration applied.

    :param fiducials: (J, d) working-frame fiducials.
    :param points: (K, d) working-frame targets.
    :param model: :class:`ExpectedErrorModel`.
    :param repeats: measurements averaged into each fiducial, n_j (default 1 each).
    :param target_repeats: measurements averaged into each target.
    :raises ValueError: on bad shapes, NaN/inf, too few or degenerate fiducials.
    """
    d = model.dimension
    x = as_points(fiducials, "fiducials", d, d + 1)
    p = as_points(points, "targets", d, 1)
    inv_n = inverse_repeats(repeats, len(x))
    none = np.zeros((0, d))
    rigid = RigidFitError(x, fiducial_covariance(model, inv_n), none, model.noise_covariance, p)
    total = rigid.now() + target_noise(model, target_repeats)
    if model.corrected:
        total = total + BiasPosterior(x, inv_n, none, 1.0, p, model).now()
    else:
        total = total + d * model.signal_std ** 2
    return model.calibration ** 2 * total
