"""The RBC registration model: restoration, noise, rho, both registrations, the interpolators and
the decision whether targets get corrections.

This is what the CLI, the node and the bag evaluator build from a set of fiducials, and what answers
target corrections::

    model = build_model(working, destination, ModelConfig(dimension=3), ids=ids)
    model.decision.method, model.decision.reason   # what targets get, and why (decision.py)
    tc = model.correct(targets_working)
    tc.destination    # the point to use, per the decision, destination frame
    tc.expected_tre   # its expected error; tc.tre_bound: the 95 % bound
    tc.corrected      # R_c (T - eps(T)) + tau_c with the configured interpolation (eq. 5-6)
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field
from functools import cached_property, partial
from typing import Mapping, Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .answers import TargetAnswer, TargetCorrections, TargetEvaluation
from .config import ModelConfig
from .constants import CANDIDATES, INTERPOLATIONS, UNCORRECTED, DecisionMode, SigmaSource
from .decision.crossval import cross_validate, in_thread
from .decision.choice import Decision, decide
from .decision.groups import group_labels
from .interpolation.paper import PaperInterpolator
from .interpolation.kriging import KrigingHyperparameters, KrigingInterpolator, summarised
from .decision.noise import RepeatStats, assess, axis_sigma, resolve_repeat_stats
from .rigid.registration import Registration, rigid_fit
from .rigid.restoration import RestorationResult, restore_rigid_body
from .planning.rigid_tre import FitGeometry
from .rigid.scale import frame_mismatch
from .validation import as_point_pairs, as_points, check_subset

__all__ = ["INTERPOLATIONS", "Interpolator", "ModelConfig", "RbcModel", "TargetAnswer",
           "TargetCorrections", "build_model"]

Interpolator = Union[PaperInterpolator, KrigingInterpolator]
#: The defaults (decision ``cv``, 3D, iterative restoration, paper interpolation).
DEFAULT_CONFIG = ModelConfig()


@dataclass(frozen=True)
class RbcModel:
    """An immutable RBC registration model; build it with :func:`build_model`.

    ``sigma`` is in the point convention (:mod:`.noise`), ``sigma_axis`` per axis.
    ``interpolators`` holds every interpolation built (the configured one always; in modes ``cv``
    and ``rho`` the other too when the fiducials allow it).
    """

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
    interpolators: Mapping[str, Interpolator] = field(repr=False)
    decision: Decision = field(repr=False)
    #: the group label of each fiducial ('' its own group; :mod:`.groups`), or ``None``
    groups: Optional[tuple[str, ...]] = None

    @cached_property
    def fit_geometry(self) -> FitGeometry:
        """How the registration's error grows beyond the fiducials (:class:`~.rigid_tre.
        FitGeometry`): a target's error scale is multiplied by its ``beyond``."""
        return FitGeometry(self.working)

    @property
    def sigma_axis(self) -> Optional[float]:
        """Noise per axis, sigma / sqrt(d); None when unknown."""
        return axis_sigma(self.sigma, self.config.dimension)

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
        """The fitted GP hyper-parameters when a kriging interpolator was built (pass them as
        ``kriging_warm_start`` to the next :func:`build_model`)."""
        kriging = self.interpolators.get("kriging")
        return kriging.hyper if kriging is not None else None

    def answer(self, targets: ArrayLike) -> TargetAnswer:
        """The point to use for each target, per the decision, and its expected error: only the
        chosen method is evaluated (the fast path for a robot asking right before insertion).

        :param targets: (K, d) working-frame points (d = ``config.dimension``), each measured
            once.
        :return: :class:`TargetAnswer`.
        :raises ValueError: on a wrong shape or NaN/inf.
        """
        return TargetEvaluation(self, as_points(targets, "targets", self.config.dimension)).answer()

    def correct(self, targets: ArrayLike) -> TargetCorrections:
        """Correct targets measured in the working frame (eq. 5-6) and give the point to use.

        :param targets: (K, d) working-frame points (d = ``config.dimension``), each measured
            once.
        :return: :class:`TargetCorrections`: the configured interpolation's correction and the
            decision's :meth:`answer` together.
        :raises ValueError: on a wrong shape or NaN/inf.
        """
        t = as_points(targets, "targets", self.config.dimension)
        return TargetEvaluation(self, t).corrections()


def _fit_subset(working: NDArray[np.float64], destination: NDArray[np.float64],
                subset: Optional[Sequence[int]], name: str) -> Registration:
    idx = check_subset(subset, len(working), name)
    fit = rigid_fit(working[idx], destination[idx])
    res = fit.apply(working) - destination
    # fre_rms is reported over all fiducials, whichever subset the fit used.
    return fit._replace(fre_rms=float(np.sqrt(np.mean(np.sum(res * res, axis=1)))))


def _candidates(mode: DecisionMode, configured: str) -> tuple[str, ...]:
    """What the decision cross-validates: all in ``cv`` and ``rho``, the configured
    interpolation in ``on``, the uncorrected registration always (for its expected error)."""
    if mode in (DecisionMode.CV, DecisionMode.RHO):
        return CANDIDATES
    return (UNCORRECTED, configured) if mode is DecisionMode.ON else (UNCORRECTED,)


def build_model(working: ArrayLike, destination: ArrayLike, config: ModelConfig = DEFAULT_CONFIG,
                *, ids: Optional[Sequence[str]] = None,
                working_repeats: Optional[Sequence[ArrayLike]] = None,
                repeat_statistics: Optional[RepeatStats] = None,
                kriging_hyperparameters: Optional[KrigingHyperparameters] = None,
                kriging_warm_start: Optional[KrigingHyperparameters] = None,
                groups: Optional[Sequence[str]] = None) -> RbcModel:
    """Build the RBC registration model from J fiducials, with its decision (``config.decision``).

    :param working: mean fiducial locations in the working frame X, (J, d).
    :param destination: the same fiducials in the destination frame Y, (J, d).
    :param config: :class:`ModelConfig`.
    :param ids: fiducial ids (default ``"0"``, ``"1"``, ...).
    :param working_repeats: the individual working-frame measurements of each fiducial, one
        (n_j, d) array each; they give sigma (when none is given) and n_j for kriging.
    :param repeat_statistics: the same information as :class:`~.noise.RepeatStats` (counts and
        per-fiducial variances), e.g. kept as running sums; give one of the two at most.
    :param kriging_hyperparameters: use these GP hyper-parameters as they are (no fit).
    :param kriging_warm_start: fit the GP hyper-parameters starting from these, e.g. the previous
        model's ``kriging_hyperparameters`` (much faster when the fiducials changed little).
    :param groups: a group label per fiducial ('' its own group): fiducials that share an error
        (one robot pose, one probe) are held out together by the decision (:mod:`.groups`).
    :return: :class:`RbcModel`.
    :raises ValueError: on bad input or a degenerate fiducial configuration.
    """
    x, y = as_point_pairs(working, destination, config.dimension)
    mismatch = frame_mismatch(x, y)
    if mismatch is not None:
        raise ValueError(mismatch)
    j = len(x)
    names = _checked_ids(ids, j)
    labels = group_labels(groups, j)
    stats, sigma_est = resolve_repeat_stats(j, config.dimension, working_repeats,
                                            repeat_statistics)
    sigma, source = _sigma(config, sigma_est)

    restoration = restore_rigid_body(x, y, config.restoration, config.steps)
    assessment = assess(restoration.sigma_l0, sigma, config.rho_reject, config.rho_apply)
    uncorrected = _fit_subset(x, y, config.uncorrected_subset, "uncorrected_subset")
    corrected = _fit_subset(restoration.corrected(x), y, config.corrected_subset,
                            "corrected_subset")
    candidates = _candidates(config.decision, config.interpolation)
    interpolators, failed, pending = _interpolators(
        x, restoration.corrections, sigma, stats.counts, config.interpolation, candidates,
        kriging_hyperparameters, kriging_warm_start)
    cv = cross_validate(x, y, [c for c in candidates if c == UNCORRECTED or c in interpolators
                               or (c == "kriging" and pending is not None)],
                        restoration=config.restoration, steps=config.steps,
                        uncorrected_subset=config.uncorrected_subset,
                        corrected_subset=config.corrected_subset,
                        kriging=pending or (interpolators.get("kriging")
                                            if "kriging" in candidates else None),
                        groups=labels)
    if pending is not None:
        try:
            interpolators["kriging"] = pending.result()
        except ValueError as exc:
            if config.interpolation == "kriging":
                raise
            failed["kriging"] = str(exc)
    cv = cv._replace(unavailable={**cv.unavailable, **failed})
    decision = decide(config.decision, cv, config.interpolation, assessment, config.rho_reject,
                      config.rho_apply)
    return RbcModel(names, x, y, stats.counts, config, stats, restoration, uncorrected, corrected,
                    sigma, source, assessment.rho, assessment.recommendation,
                    interpolators[config.interpolation], interpolators, decision,
                    None if labels is None else tuple(str(g) for g in groups))


def _checked_ids(ids: Optional[Sequence[str]], j: int) -> tuple[str, ...]:
    """The fiducials' ids as strings (default ``"0"``, ``"1"``, ...), one per fiducial, unique."""
    names = tuple(str(i) for i in range(j)) if ids is None else tuple(str(i) for i in ids)
    if len(names) != j:
        raise ValueError(f"got {len(names)} ids for {j} fiducials")
    if len(set(names)) != j:
        raise ValueError("fiducial ids must be unique")
    return names


def _sigma(config: ModelConfig, estimated: Optional[float]) -> tuple[Optional[float], str]:
    """sigma and its :class:`~.constants.SigmaSource`: given, else from repeats, else unknown."""
    if config.known_sigma is not None:
        return config.known_sigma, SigmaSource.GIVEN.value
    if estimated:     # identical repeats give 0: no noise estimate (noise.identical_repeats)
        return estimated, SigmaSource.REPEATS.value
    return None, SigmaSource.UNKNOWN.value


def _interpolators(x: NDArray[np.float64], corrections: NDArray[np.float64],
                   sigma: Optional[float], counts: NDArray[np.int64], configured: str,
                   candidates: Sequence[str],
                   kriging_hyperparameters: Optional[KrigingHyperparameters],
                   kriging_warm_start: Optional[KrigingHyperparameters]
                   ) -> tuple[dict[str, Interpolator], dict[str, str], Optional[Future]]:
    """The configured interpolator and the decision's candidates (eq. 5), sharing one hull test
    (answers.py): (built, failed candidates with the reason, a large kriging model still
    being built beside the folds or None). The configured one failing raises."""
    interpolators: dict[str, Interpolator] = {}
    failed: dict[str, str] = {}
    hull = None
    pending: Optional[Future] = None
    for method in INTERPOLATIONS:
        if method != configured and method not in candidates:
            continue
        try:
            if method == "paper":
                interpolators[method] = PaperInterpolator(x, corrections, hull=hull)
            else:
                build = partial(KrigingInterpolator, x, corrections, sigma, counts,
                                kriging_hyperparameters, kriging_warm_start, hull=hull)
                if summarised(len(x)) and "kriging" in candidates:
                    # the fit and factor (~3 s of mostly GIL-free numpy at J = 5,000) beside the
                    # folds, which need the model only for kriging's held-out predictions
                    pending = in_thread(build, "rbc_kriging")
                    continue
                interpolators[method] = build()
            hull = interpolators[method].hull
        except ValueError as exc:
            if method == configured:
                raise
            failed[method] = str(exc)
    return interpolators, failed, pending
