"""The RBC registration model: restoration, noise, rho, both registrations and the interpolator.

This is what the CLI, the node and the bag evaluator build from a set of fiducials, and what answers
target corrections::

    model = build_model(working, destination, ModelConfig(dimension=3), ids=ids,
                        working_repeats=repeats)
    tc = model.correct(targets_working)
    tc.corrected  # R_c (T - eps(T)) + tau_c in the destination frame (eq. 5-6)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .constants import INTERPOLATIONS, MAX_RESTORATION_STEPS, check_rho_thresholds
from .interpolation import PaperInterpolator
from .kriging import KrigingHyperparameters, KrigingInterpolator
from .noise import RepeatStats, assess, repeat_stats, sigma_from_stats
from .registration import Registration, rigid_fit
from .restoration import METHODS, RestorationResult, restore_rigid_body
from .validation import as_point_pairs, as_points, check_subset

Interpolator = Union[PaperInterpolator, KrigingInterpolator]


@dataclass(frozen=True)
class ModelConfig:
    """How a model is built. Lengths are in the unit of the points (metres in ROS).

    :ivar dimension: 2 (x, y as in the paper) or 3.
    :ivar restoration: ``"iterative"`` (the paper's Gauss-Newton steps) or ``"closed-form"``.
    :ivar steps: iterative steps (paper: 2).
    :ivar interpolation: ``"paper"`` (tetrahedron / 8 surrounding fiducials) or ``"kriging"``.
    :ivar sigma: known noise sigma: RMS distance of one measurement from the true point (all axes;
        per axis sigma / sqrt(d)), see :func:`noise.estimate_sigma`; ``None``: from repeats.
    :ivar rho_reject: rho below which correcting is not recommended (paper: 1).
    :ivar rho_apply: rho from which correcting is recommended (paper: 2.5).
    :ivar uncorrected_subset: indices of the fiducials the uncorrected registration is fitted to
        (the paper uses 5); ``None``: all.
    :ivar corrected_subset: indices for the corrected registration (the paper uses 3); ``None``: all.
    """

    dimension: int = 3
    restoration: str = "iterative"
    steps: int = 2
    interpolation: str = "paper"
    sigma: Optional[float] = None
    rho_reject: float = 1.0
    rho_apply: float = 2.5
    uncorrected_subset: Optional[tuple[int, ...]] = None
    corrected_subset: Optional[tuple[int, ...]] = None

    def __post_init__(self) -> None:
        if self.dimension not in (2, 3):
            raise ValueError(f"dimension must be 2 or 3, got {self.dimension!r}")
        if self.restoration not in METHODS:
            raise ValueError(f"restoration must be one of {METHODS}, got {self.restoration!r}")
        if not isinstance(self.steps, int) or isinstance(self.steps, bool) or self.steps < 1:
            raise ValueError(f"steps must be a positive integer, got {self.steps!r}")
        if self.steps > MAX_RESTORATION_STEPS:   # the node's restoration_steps range too
            raise ValueError(f"steps must be in 1..{MAX_RESTORATION_STEPS}, got {self.steps!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, "
                             f"got {self.interpolation!r}")
        if self.sigma is not None and (not math.isfinite(self.sigma) or self.sigma <= 0):
            raise ValueError(f"sigma must be a positive finite length or None, got {self.sigma!r}")
        for name in ("rho_reject", "rho_apply"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        check_rho_thresholds(self.rho_reject, self.rho_apply)


class TargetCorrections(NamedTuple):
    """Answers for K targets (unit of the points).

    :ivar uncorrected: R_u T + tau_u, destination frame (K, d).
    :ivar corrected: R_c (T - eps(T)) + tau_c, destination frame (K, d) (eq. 6).
    :ivar correction: eps(T), working frame (K, d) (eq. 5).
    :ivar inside_hull: (K,) target inside the fiducials' convex hull.
    :ivar expected_error: (K,) 1-sigma uncertainty of eps(T) per axis (kriging); NaN otherwise.
    """

    uncorrected: NDArray[np.float64]
    corrected: NDArray[np.float64]
    correction: NDArray[np.float64]
    inside_hull: NDArray[np.bool_]
    expected_error: NDArray[np.float64]


@dataclass(frozen=True)
class RbcModel:
    """An immutable RBC registration model; build it with :func:`build_model`."""

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: NDArray[np.float64]
    counts: NDArray[np.int64]
    config: ModelConfig
    repeat_stats: RepeatStats
    restoration: RestorationResult
    uncorrected: Registration
    corrected: Registration
    sigma: Optional[float]
    sigma_source: str
    rho: Optional[float]
    recommendation: str
    interpolator: Interpolator = field(repr=False)

    @property
    def corrections(self) -> NDArray[np.float64]:
        """eps at the fiducials (J, d), working frame."""
        return self.restoration.corrections

    @property
    def sigma_l(self) -> tuple[float, ...]:
        """sigma_L0, sigma_L1, ... (eq. 7): before and after each restoration step."""
        return self.restoration.sigma_l

    @property
    def kriging_hyperparameters(self) -> Optional[KrigingHyperparameters]:
        """The fitted GP hyper-parameters when interpolation is kriging."""
        return getattr(self.interpolator, "hyper", None)

    def correct(self, targets: ArrayLike) -> TargetCorrections:
        """Correct targets measured in the working frame (eq. 5-6).

        :param targets: (K, d) working-frame points (d = ``config.dimension``).
        :return: :class:`TargetCorrections`.
        :raises ValueError: on a wrong shape or NaN/inf.
        """
        t = as_points(targets, "targets", self.config.dimension)
        interp = self.interpolator(t)
        return TargetCorrections(self.uncorrected.apply(t),
                                 self.corrected.apply(t - interp.correction),
                                 interp.correction, interp.inside_hull, interp.expected_error)


def _fit_subset(working: NDArray[np.float64], destination: NDArray[np.float64],
                subset: Optional[Sequence[int]], name: str) -> Registration:
    idx = check_subset(subset, len(working), name)
    fit = rigid_fit(working[idx], destination[idx])
    res = fit.apply(working) - destination
    # fre_rms is reported over all fiducials, whichever subset the fit used.
    return fit._replace(fre_rms=float(np.sqrt(np.mean(np.sum(res * res, axis=1)))))


def build_model(working: ArrayLike, destination: ArrayLike, config: ModelConfig = ModelConfig(),
                *, ids: Optional[Sequence[str]] = None,
                working_repeats: Optional[Sequence[ArrayLike]] = None,
                repeat_statistics: Optional[RepeatStats] = None,
                kriging_hyperparameters: Optional[KrigingHyperparameters] = None) -> RbcModel:
    """Build the RBC registration model from J fiducials.

    :param working: mean fiducial locations in the working frame X, (J, d).
    :param destination: the same fiducials in the destination frame Y, (J, d).
    :param config: :class:`ModelConfig`.
    :param ids: fiducial ids (default ``"0"``, ``"1"``, ...).
    :param working_repeats: the individual working-frame measurements of each fiducial, one
        (n_j, d) array each; they give sigma (when ``config.sigma`` is None) and n_j for kriging.
    :param repeat_statistics: the same information as :class:`~.noise.RepeatStats` (counts and
        per-fiducial variances), e.g. kept as running sums; give one of the two at most.
    :param kriging_hyperparameters: reuse fitted GP hyper-parameters instead of fitting them.
    :return: :class:`RbcModel`.
    :raises ValueError: on bad input or a degenerate fiducial configuration.
    """
    x, y = as_point_pairs(working, destination, config.dimension)
    j = len(x)
    names = tuple(str(i) for i in range(j)) if ids is None else tuple(str(i) for i in ids)
    if len(names) != j:
        raise ValueError(f"got {len(names)} ids for {j} fiducials")
    if len(set(names)) != j:
        raise ValueError("fiducial ids must be unique")
    if working_repeats is not None and repeat_statistics is not None:
        raise ValueError("give working_repeats or repeat_statistics, not both")
    if working_repeats is not None:
        if len(working_repeats) != j:
            raise ValueError(f"got repeats for {len(working_repeats)} fiducials, expected {j}")
        stats = repeat_stats(working_repeats, config.dimension)
    elif repeat_statistics is not None:
        stats = RepeatStats(np.asarray(repeat_statistics.counts, dtype=np.int64),
                            np.asarray(repeat_statistics.variances, dtype=np.float64))
        if stats.counts.shape != (j,) or stats.variances.shape != (j,) or (stats.counts < 1).any():
            raise ValueError(f"repeat statistics must hold {j} counts >= 1 and {j} variances")
    else:
        stats = RepeatStats(np.ones(j, dtype=np.int64), np.full(j, np.nan))
    counts = stats.counts
    sigma_est = sigma_from_stats(stats)
    if config.sigma is not None:
        sigma, source = config.sigma, "given"
    elif sigma_est is not None:
        sigma, source = sigma_est, "repeats"
    else:
        sigma, source = None, "unknown"

    restoration = restore_rigid_body(x, y, config.restoration, config.steps)
    rho, recommendation = assess(restoration.sigma_l0, sigma, config.rho_reject,
                                 config.rho_apply)
    uncorrected = _fit_subset(x, y, config.uncorrected_subset, "uncorrected_subset")
    corrected = _fit_subset(restoration.corrected(x), y, config.corrected_subset,
                            "corrected_subset")
    if config.interpolation == "paper":
        interpolator: Interpolator = PaperInterpolator(x, restoration.corrections)
    else:
        interpolator = KrigingInterpolator(x, restoration.corrections, sigma, counts,
                                           kriging_hyperparameters)
    return RbcModel(names, x, y, counts, config, stats, restoration, uncorrected, corrected, sigma,
                    source, rho, recommendation, interpolator)
