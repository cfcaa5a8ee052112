"""Noise-aware interpolation of fiducial corrections: Gaussian-process regression ("kriging").

Each component of eps is modelled as a zero-mean Gaussian process over the working frame with a
Matérn 5/2 covariance s^2 k(r / l), observed at the fiducials with noise variance
sigma^2 / (d n_j) per axis (sigma as in :func:`noise.estimate_sigma`, n_j repeats averaged into
fiducial j). The signal variance s^2 and length scale l (and sigma when it is unknown) are fitted to
the corrections by maximising the marginal likelihood, shared by the d components
(:mod:`.gp_fit`: analytic gradients, warm start, a subsample for large J). The posterior mean
shrinks corrections toward zero where noise dominates the field (rho < 1), so correcting does not
make registration worse; where the bias dominates it follows the fiducials closely. The posterior
standard deviation is reported as the expected error of the correction.

Up to :data:`EXACT_MAX_FIDUCIALS` fiducials everything is exact. Above it (every answer's exact
variance reads the J x J factor: 7.5-10 ms per target at J = 5,000) the posterior variance and the
cross-validation's held-out predictions condition on a summary of the data instead
(:mod:`.kriging_summary`: the nearest fiducials' measurements and the exact posterior means at
inducing fiducials spread over the cell), which never gives a smaller variance than the exact one
(measured 1.00-1.12x the exact standard deviation, 2D and 3D, short and long length scales,
J = 1,000-5,000: benchmarks/RESULTS.md); the posterior mean of a target stays exact. There the
fit factorises with GIL-free calls, and :func:`~.model.build_model` builds the model in a thread
beside the cross-validation's folds.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Union

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dtrtrs
from scipy.spatial.distance import cdist

from .blocked_linalg import cholesky_blocked, inverse_from_cholesky
from .gp_fit import (JITTER, KrigingHyperparameters, MarginalLikelihood, fit_hyperparameters,
                     matern52, repeat_counts)
from .paper import HullTest, Interpolated
from .kriging_summary import DataSummary, HeldOutWeights
from ..validation import as_point_pairs, as_points

__all__ = ["EXACT_MAX_FIDUCIALS", "KrigingHyperparameters", "KrigingInterpolator",
           "MarginalLikelihood", "fit_hyperparameters", "summarised"]

#: Exact kriging up to this many fiducials; above it the posterior variance and the held-out
#: predictions of cross-validation condition on a summary of the data (module docstring,
#: :mod:`.kriging_summary`). Measured against the exact values in benchmarks/RESULTS.md.
EXACT_MAX_FIDUCIALS = 2000
#: Most fiducials kriged at all: the model factors a J x J covariance (1.8 GB at 15,000;
#: 100,000 fiducials ended in a MemoryError traceback asking for 74.5 GiB). Above it kriging is
#: an unavailable candidate of the decision, and refused when configured.
MAX_FIDUCIALS = 15000


def summarised(count: int) -> bool:
    """Whether a kriging model of ``count`` fiducials conditions its variance on the summary
    (above :data:`EXACT_MAX_FIDUCIALS`)."""
    return count > EXACT_MAX_FIDUCIALS

#: Target-fiducial covariance entries :meth:`KrigingInterpolator.__call__` holds at once
#: (16 MB of float64 per array).
CHUNK_ELEMENTS = 2_000_000


class KrigingInterpolator:
    """Gaussian-process interpolation of corrections (module docstring)."""

    method = "kriging"

    def __init__(self, points: ArrayLike, corrections: ArrayLike, sigma: Optional[float] = None,
                 repeats: Optional[Sequence[int]] = None,
                 hyperparameters: Optional[KrigingHyperparameters] = None,
                 warm_start: Optional[KrigingHyperparameters] = None, *,
                 hull: Optional[HullTest] = None) -> None:
        """
        :param points: fiducials in the working frame (J, d).
        :param corrections: eps at the fiducials (J, d).
        :param sigma: noise sigma of one measurement (all axes); ``None``: fitted as well.
        :param repeats: measurements averaged into each fiducial, n_j (default 1 each).
        :param hyperparameters: use these as they are instead of fitting (e.g. in leave-one-out).
        :param warm_start: fit, starting from these (e.g. the previous model's).
        :param hull: a :class:`~.interpolation.HullTest` of these same points to share (e.g. the
            paper interpolator's ``hull``); default: built here.
        :raises ValueError: on bad input or fewer than d + 1 fiducials.
        """
        self.points, self.corrections = as_point_pairs(points, corrections, min_count=1)
        j, self.dim = self.points.shape
        if j < self.dim + 1:
            raise ValueError(f"kriging in {self.dim}D needs at least {self.dim + 1} fiducials, "
                             f"got {j}")
        if j > MAX_FIDUCIALS:
            raise ValueError(f"kriging holds a J x J covariance: {j} fiducials would need "
                             f"{8 * j * j / 1e9:.3g} GB for it, at most {MAX_FIDUCIALS} are "
                             f"kriged (use the paper's interpolation, or fewer fiducials)")
        n = repeat_counts(repeats, j)
        if sigma is not None and (not math.isfinite(sigma) or sigma < 0):
            raise ValueError(f"sigma must be finite and >= 0, got {sigma}")
        self.inv_n = 1.0 / n
        self.hull = hull if hull is not None else HullTest(self.points)
        self.hyper = hyperparameters or fit_hyperparameters(
            self.points, self.corrections, sigma, n, warm_start, gil_free=summarised(j))
        k = self._cov(cdist(self.points, self.points))
        noise = self._noise_var()
        k.flat[::j + 1] += noise
        #: The summary the variance conditions on above :data:`EXACT_MAX_FIDUCIALS`, else None.
        self.summary: Optional[DataSummary] = None
        #: K's Cholesky factor as (factor, lower) up to the threshold; None above it.
        self.chol: Optional[tuple[NDArray[np.float64], bool]] = None
        if summarised(j):
            low = cholesky_blocked(k)                   # in place, GIL-free matmul blocks
            self.summary = DataSummary(self.points, self._cov, low, noise,
                                       self.hyper.signal_std ** 2, self.corrections)
            self.alpha = self.summary.alpha
            # the answers and held-out predictions read the summary only: the J x J factor
            # (200 MB at J = 5,000, 800 MB at 10,000) is not kept
            del low, k
        else:
            # numpy's Cholesky releases the GIL (scipy's cho_factor held it for 0.4 s at
            # J = 4,000, stalling the node's executor); chol = (L^T, False): upper,
            # Fortran-ordered, no copy.
            self.chol = (np.linalg.cholesky(k).T, False)
            self.alpha = scipy.linalg.cho_solve(self.chol, self.corrections, check_finite=False)

    @property
    def noise_axis_std(self) -> float:
        """Noise of one measurement per axis, noise_std / sqrt(d)."""
        return self.hyper.noise_std / math.sqrt(self.dim)

    def _cov(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        """Signal covariance at the distances ``r`` (overwritten)."""
        k = matern52(r, self.hyper.length_scale)
        k *= self.hyper.signal_std ** 2
        return k

    def _noise_var(self) -> NDArray[np.float64]:
        h = self.hyper
        return h.noise_std ** 2 / self.dim * self.inv_n + JITTER * h.signal_std ** 2

    def held_out(self, groups: Sequence[NDArray[np.intp]]
                 ) -> list[tuple[Union[NDArray[np.float64], HeldOutWeights],
                                 NDArray[np.float64]]]:
        """The GP's exact prediction of held-out fiducials from the others, per group.

        For each index set S: ``(W, std)`` with W (|S|, J - |S|) such that ``W @ e`` is the
        posterior mean at the fiducials S of a field observed as ``e`` at the other fiducials
        (in index order), and ``std`` (|S|,) the predictive standard deviation per axis of a
        measurement at S (field plus its noise). From the precision matrix P = K^-1:
        W = -P_SS^-1 P_S,rest, covariance P_SS^-1 (the GP refitted without S, same
        hyper-parameters). Above :data:`EXACT_MAX_FIDUCIALS` fiducials: the summary's predictor
        (:meth:`.kriging_summary.DataSummary.held_out`; W a linear map, not an array).
        """
        if self.summary is not None:
            return self.summary.held_out(groups)
        p = inverse_from_cholesky(self.chol[0] if self.chol[1] else self.chol[0].T)
        out = []
        for group in groups:
            s = np.asarray(group, dtype=np.intp)
            rest = np.setdiff1d(np.arange(len(p)), s)
            p_ss = p[np.ix_(s, s)]
            cov = np.linalg.inv(p_ss)
            out.append((-cov @ p[np.ix_(s, rest)], np.sqrt(np.maximum(np.diag(cov), 0.0))))
        return out

    def __call__(self, targets: ArrayLike) -> Interpolated:
        """Posterior mean (eps(T), shape (K, d)) and standard deviation per axis at the targets.

        Targets are taken in chunks of at most :data:`CHUNK_ELEMENTS` target-fiducial pairs, so
        a large batch needs O(J) memory per chunk, not O(K J) (10,000 targets at J = 5,000 were
        two 400 MB arrays).
        """
        t = as_points(targets, "targets", self.dim)
        return self._at(t, self.hull.simplices(t))

    def _at(self, t: NDArray[np.float64], simplex: NDArray[np.intp]) -> Interpolated:
        """:meth:`__call__` of targets already validated (:func:`.validation.as_points`), given
        their ``hull.simplices`` (one location per call shared by interpolators of one hull)."""
        step = max(1, CHUNK_ELEMENTS // len(self.points))
        if len(t) <= step:                  # one chunk (every small batch): no copies
            mean, var = self._posterior(t)
        else:
            mean = np.empty((len(t), self.dim))
            var = np.empty(len(t))
            for s in range(0, len(t), step):
                mean[s:s + step], var[s:s + step] = self._posterior(t[s:s + step])
        return Interpolated(mean, simplex >= 0, np.sqrt(np.maximum(var, 0.0)))

    def _posterior(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                            NDArray[np.float64]]:
        """Posterior mean (K, d) and variance per axis (K,) at targets ``t`` (the variance from
        the summary above :data:`EXACT_MAX_FIDUCIALS`)."""
        ks = self._cov(cdist(t, self.points))
        mean = ks @ self.alpha
        if self.summary is not None:
            return mean, self.summary.variance(t, ks)
        v = self._lower_solve(ks.T)         # overwrites ks
        return mean, self.hyper.signal_std ** 2 - np.einsum("jk,jk->k", v, v)

    def _lower_solve(self, b: NDArray[np.float64]) -> NDArray[np.float64]:
        """L^-1 b for the Cholesky factor L (``b`` may be overwritten), ``chol`` holding L
        (lower) or L^T (upper): the LAPACK call ``solve_triangular`` makes for a Fortran-ordered
        factor, without that wrapper's checks and conversions (~9 us of a single target's ~12)."""
        factor, lower = self.chol
        if factor.flags.f_contiguous:   # lower: L itself; upper: L^T, solved transposed
            v, info = dtrtrs(factor, b, lower=int(lower), trans=0 if lower else 1,
                             overwrite_b=1)
            if info == 0:
                return v
        return scipy.linalg.solve_triangular(factor, b, lower=lower, trans=0 if lower else 1,
                                             check_finite=False)
