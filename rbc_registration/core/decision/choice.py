"""Whether and how to correct: the cross-validated decision, the paper's rho rule beside it, and
the expected error of a target.

Mode ``cv`` (:class:`~.constants.DecisionMode`): the candidates' held-out errors per fiducial
(:mod:`.crossval`) are compared with the uncorrected registration's in a paired, one-sided Wilcoxon
signed-rank test (H1: the corrected method's errors are smaller). A corrected method is chosen only
when its p-value is below :data:`SIGNIFICANCE` divided by the number of corrected candidates
(Bonferroni: the chance of correcting when no method helps is at most :data:`SIGNIFICANCE`).
Among such methods the first in :data:`PREFERENCE` is chosen unless another one's held-out errors
are significantly smaller than its own (the same paired one-sided test at :data:`SIGNIFICANCE`):
a lower median alone does not switch methods. Otherwise the uncorrected registration is used.
Modes ``rho``, ``on`` and ``off`` follow the paper's rule or the user; the rho rule's result is
reported in every mode.

Expected error of a target (:class:`ErrorModel`): from the chosen method's held-out errors, which
are errors of points measured like targets. A conformal bound: the held-out errors e_j, divided by
a per-point scale s_j, have the empirical quantile q at rank ceil(level (J + 1)); a target gets
the bound q s(T), which it stays within with probability >= level when targets are like the
fiducials. For a corrected method the scale is kriging's predictive standard deviation (the field's
posterior plus one measurement's noise), so targets near fiducials get tighter bounds than
extrapolated ones; for the uncorrected registration it is 1 (the quantile of the errors).

A target's scale is never taken below the smallest scale of the held-out fiducials
(``ErrorModel.scale_floor``): the quantile is calibrated on those scales only, and below them the
scale rests on kriging's noise estimate, which single measurements of a biased cell cannot check
(maximum likelihood often puts the noise into a short-scale field, fitted noise ~0: a target on
a fiducial then got a bound of ~0 against an error of its own noise and the fiducial's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

import numpy as np
import scipy.stats
from numpy.typing import ArrayLike, NDArray

from ..constants import CANDIDATES, UNCORRECTED, DecisionMode
from .crossval import CrossValidation, FoldScheme
from .groups import unit_means, weighted_quantile
from .noise import Assessment, format_rho

#: Family-wise level of the test: a correction is applied only when it beats the uncorrected
#: registration with 95 % confidence (one-sided p < 0.05, Bonferroni over the corrected
#: candidates).
SIGNIFICANCE = 0.05
#: Coverage of the reported error bound of a target (``TargetCorrections.tre_bound``).
BOUND_LEVEL = 0.95
#: Paired differences smaller than this fraction of the uncorrected median error are ties (dropped
#: by the Wilcoxon test): e.g. kriging's near-zero corrections on pure noise differ from the
#: uncorrected errors only by rounding, whose signs must not decide anything. It is above the
#: reproducibility of the held-out errors themselves (~1e-5 relative: kriging's hyper-parameters
#: are optimised to a tolerance, and a rigid motion of either frame moves the optimum within it),
#: so a difference that rounding can flip never counts; 1e-4 of a 0.1 mm error is 10 nm.
TIE_TOLERANCE = 1e-4
#: A correction that looks better by less than this fraction of the uncorrected median error is
#: not worth applying: a ``cv`` decision for the uncorrected registration is confident when no
#: candidate improves the median by this much, or when one is shown better.
RELEVANT_GAIN = 0.05
#: Order of preference among the corrected candidates that beat the uncorrected registration: the
#: first is chosen unless another is shown better than it. Kriging comes first: it models the
#: noise of each correction (its nugget) where the paper's interpolation passes through every
#: fiducial's noisy correction, and between two methods that both help, the held-out medians of a
#: few dozen fiducials differ by chance. Measured on the RA-like cell (random subsets of 11-60
#: fiducials, 10 seeds, single measurements; benchmarks/decision_subsets.py): the smallest median
#: picks ``paper`` for 25 of 100 sets; this rule keeps kriging in 20 of them (the other 5 stay
#: ``paper``), and kriging's target TRE is lower in 17 of the 20, by up to 0.030 mm
#: (benchmarks/RESULTS.md, "Which correction on few fiducials").
PREFERENCE = ("kriging", "paper")


@dataclass(frozen=True)
class CandidateScore:
    """Cross-validated accuracy of one candidate (unit of the points).

    :ivar method: one of :data:`~.constants.CANDIDATES`.
    :ivar available: whether it could be cross-validated (else ``note`` says why; numbers NaN).
    :ivar cv_median: median held-out error.
    :ivar cv_rms: root mean square held-out error.
    :ivar cv_bound: conformal :data:`BOUND_LEVEL` quantile of the held-out errors.
    :ivar statistic: Wilcoxon signed-rank statistic W+ (sum of the ranks of the fiducials where
        this method's error is smaller than uncorrected's); None for uncorrected.
    :ivar p_value: one-sided p-value of "smaller errors than uncorrected"; None for uncorrected.
    :ivar note: why it is unavailable, else empty.
    """

    method: str
    available: bool
    cv_median: float
    cv_rms: float
    cv_bound: float
    statistic: Optional[float]
    p_value: Optional[float]
    note: str = ""


@dataclass(frozen=True)
class ErrorModel:
    """How a target's ``expected_tre`` and bound follow from the held-out errors of ``method``:
    ``median_factor * scale`` and ``bound_factor * scale``, ``scale`` the kriging predictive
    standard deviation per axis at the target when ``scaled`` (at least ``scale_floor``, the
    smallest of the held-out fiducials'), else 1. ``level`` is the bound's coverage. NaN
    factors: no cross-validation was possible."""

    method: str
    scaled: bool
    median_factor: float
    bound_factor: float
    level: float = BOUND_LEVEL
    scale_floor: float = 0.0

    def at(self, scale: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(expected_tre, bound) for targets of the given scale (ones when not ``scaled``),
        the scale raised to ``scale_floor`` where it is below."""
        s = np.maximum(np.asarray(scale, dtype=np.float64), self.scale_floor)
        return self.median_factor * s, self.bound_factor * s


@dataclass(frozen=True)
class Decision:
    """The decision of a model (build it with :func:`decide`; ``RbcModel.decision``).

    :ivar mode: the :class:`~.constants.DecisionMode` it was made in.
    :ivar method: the registration targets get: one of :data:`~.constants.CANDIDATES`.
    :ivar apply: whether corrections are applied (``method != "uncorrected"``).
    :ivar reason: one sentence saying why.
    :ivar confident: ``cv``: a correction was shown better, or none looks relevantly better
        (:data:`RELEVANT_GAIN`); ``rho``: rho is known and outside the uncertain band;
        ``on``/``off``: always.
    :ivar candidates: :class:`CandidateScore` of every candidate evaluated.
    :ivar folds: the :class:`~.crossval.FoldScheme`.
    :ivar significance: :data:`SIGNIFICANCE`.
    :ivar rho: the paper's rho = sigma_L0 / sigma (None without sigma), always reported.
    :ivar rho_recommendation: the paper's rule on it (``apply``, ``uncertain``, ...).
    :ivar error_model: :class:`ErrorModel` of the chosen method.
    :ivar cross_validation: the held-out errors per fiducial.
    """

    mode: DecisionMode
    method: str
    apply: bool
    reason: str
    confident: bool
    candidates: tuple[CandidateScore, ...]
    folds: FoldScheme
    significance: float
    rho: Optional[float]
    rho_recommendation: str
    error_model: ErrorModel
    cross_validation: CrossValidation = field(repr=False)
    #: ``reason`` with ``{0}``, ``{1}``, ... where it quotes lengths (held-out errors, unit of
    #: the points), and those lengths: :meth:`reason_in` shows them in another unit.
    reason_template: str = field(default="", repr=False, compare=False)
    reason_lengths: tuple[float, ...] = field(default=(), repr=False, compare=False)

    def reason_in(self, scale: float) -> str:
        """``reason`` with its lengths times ``scale`` (e.g. 1000: metres to mm), formatted as
        in ``reason``; ``reason`` itself without lengths to convert."""
        if not self.reason_template:
            return self.reason
        return self.reason_template.format(*(_g(v * scale) for v in self.reason_lengths))

    def candidate(self, method: str) -> Optional[CandidateScore]:
        """The score of ``method``, None when it was not evaluated."""
        return next((c for c in self.candidates if c.method == method), None)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``mode``, ``apply``, ``method``, ``reason``, ``confident``,
        ``significance``, ``folds`` {kind, n_folds, grouped}, ``rho``, ``rho_recommendation``,
        ``bound_level``, and ``cv``: per candidate {available, median, rms, bound, statistic,
        p_value, note} (NaN as None)."""
        def num(v: Optional[float]) -> Optional[float]:
            return None if v is None or not math.isfinite(v) else float(v)

        return {"mode": self.mode.value, "apply": self.apply, "method": self.method,
                "reason": self.reason, "confident": self.confident,
                "significance": self.significance,
                "folds": {"kind": self.folds.kind, "n_folds": self.folds.n_folds,
                          "grouped": self.folds.grouped},
                "rho": num(self.rho), "rho_recommendation": self.rho_recommendation,
                "bound_level": self.error_model.level,
                "cv": {c.method: {"available": c.available, "median": num(c.cv_median),
                                  "rms": num(c.cv_rms), "bound": num(c.cv_bound),
                                  "statistic": num(c.statistic), "p_value": num(c.p_value),
                                  "note": c.note} for c in self.candidates}}


def conformal_quantile(values: ArrayLike, level: float = BOUND_LEVEL,
                       units: Optional[NDArray[np.intp]] = None) -> float:
    """The value at rank ceil(level (n + 1)) of n values (their maximum when n is too small for
    the rank, below 1 / (1 - level) - 1 values); NaN for none. With ``units`` (groups held out
    together) every group weighs alike (:func:`~.groups.weighted_quantile`)."""
    return weighted_quantile(values, level, units)


def paired_test(uncorrected: NDArray[np.float64], method: NDArray[np.float64],
                resolution: float = 0.0,
                units: Optional[NDArray[np.intp]] = None) -> tuple[float, float]:
    """One-sided Wilcoxon signed-rank test that ``method``'s errors are smaller (paired per
    fiducial, or per group with ``units``: the mean error of each group, one independent unit
    each): (W+, p). Differences within :data:`TIE_TOLERANCE` of the median error, or within
    ``resolution`` (``CrossValidation.resolution``: rounding), are ties and dropped; identical
    errors give (0, 1)."""
    uncorrected, method = unit_means(uncorrected, units), unit_means(method, units)
    diff = uncorrected - method
    tie = max(TIE_TOLERANCE * float(np.median(uncorrected)), resolution)
    diff[np.abs(diff) <= tie] = 0.0
    if not np.any(diff != 0):
        return 0.0, 1.0
    res = scipy.stats.wilcoxon(diff, alternative="greater")
    return float(res.statistic), float(res.pvalue)


def _score(cv: CrossValidation, method: str) -> CandidateScore:
    if method not in cv.errors:
        note = cv.unavailable.get(method, "not evaluated")
        return CandidateScore(method, False, math.nan, math.nan, math.nan, None, None, note)
    e = cv.errors[method]
    stat = p = None
    if method != UNCORRECTED and UNCORRECTED in cv.errors:
        stat, p = paired_test(cv.errors[UNCORRECTED], e, cv.resolution, cv.units)
    return CandidateScore(method, True, float(np.median(e)), float(np.sqrt(np.mean(e * e))),
                          conformal_quantile(e, units=cv.units), stat, p)


def error_model(cv: CrossValidation, method: str) -> ErrorModel:
    """The :class:`ErrorModel` of ``method`` from its held-out errors (module docstring)."""
    if method not in cv.errors:
        return ErrorModel(method, False, math.nan, math.nan)
    e = cv.errors[method]
    scaled = method != UNCORRECTED and cv.scale is not None and bool(np.all(cv.scale > 0))
    ratio = e / cv.scale if scaled else e
    return ErrorModel(method, scaled, float(np.median(ratio)),
                      conformal_quantile(ratio, units=cv.units),
                      scale_floor=float(np.min(cv.scale)) if scaled else 0.0)


def _g(v: float) -> str:
    return f"{v:.3g}"


def _preferred(winners: list[CandidateScore], errors: Mapping[str, NDArray[np.float64]],
               resolution: float, units: Optional[NDArray[np.intp]]) -> CandidateScore:
    """The winner first in :data:`PREFERENCE`, unless another winner's held-out errors are
    significantly smaller than its own (then the one of those with the smallest median)."""
    ranked = sorted(winners, key=lambda s: PREFERENCE.index(s.method))
    first = ranked[0]
    better = [s for s in ranked[1:]
              if paired_test(errors[first.method], errors[s.method], resolution, units)[1]
              < SIGNIFICANCE]
    return min(better, key=lambda s: s.cv_median) if better else first


def _cv_choice(scores: list[CandidateScore], cv: CrossValidation
               ) -> tuple[str, str, bool, tuple[float, ...]]:
    """The method, the reason as a template (``{k}``: the k-th length), whether confident, and
    the lengths the reason quotes."""
    lengths: list[float] = []
    errors, resolution = cv.errors, cv.resolution
    n = f"{_held_out_count(cv)} held-out fiducials"
    if cv.units is not None:
        n += f" ({cv.n_units} groups, each held out whole)"

    def length(v: float) -> str:
        lengths.append(v)
        return f"{{{len(lengths) - 1}}}"

    base = scores[0]
    if not base.available:
        note = base.note.replace("{", "{{").replace("}", "}}")
        return UNCORRECTED, (f"Cross-validation was not possible ({note}), so the "
                             f"uncorrected registration is used."), False, ()
    tested = [s for s in scores[1:] if s.available and s.p_value is not None]
    if not tested:
        return UNCORRECTED, ("No correction method could be cross-validated, so the uncorrected "
                             "registration is used."), True, ()
    level = SIGNIFICANCE / len(tested)
    winners = [s for s in tested if s.p_value < level]
    if winners:
        best = _preferred(winners, errors, resolution, cv.units)
        lower = [s for s in winners if s.cv_median < best.cv_median]
        head = (f"{best.method.capitalize()} corrections predicted the {n} "
                f"better than the uncorrected registration (median error "
                f"{length(best.cv_median)} vs {length(base.cv_median)}, one-sided Wilcoxon p = "
                f"{best.p_value:.2g} < {_g(level)}")
        kept = "".join(f"; {s.method}'s lower median {length(s.cv_median)} was not "
                       f"significantly smaller than {best.method}'s errors" for s in lower)
        return best.method, f"{head}{kept}), so they are applied.", True, tuple(lengths)
    best = min(tested, key=lambda s: s.cv_median)
    # a gain below the rounding of the errors (exact data) is no gain either
    confident = best.cv_median > (1.0 - RELEVANT_GAIN) * base.cv_median - resolution
    return UNCORRECTED, (
        f"No correction beat the uncorrected registration with {_g(100 * (1 - SIGNIFICANCE))} % "
        f"confidence on the {n} (best: {best.method}, median error "
        f"{length(best.cv_median)} vs {length(base.cv_median)}, p = {best.p_value:.2g}), so the "
        f"uncorrected registration is used."), confident, tuple(lengths)


def _rho_choice(assessment: Assessment, configured: str, rho_reject: float,
                rho_apply: float) -> tuple[str, str, bool]:
    rho, rec = assessment.rho, assessment.recommendation
    if rho is None:
        return UNCORRECTED, ("The paper's rho rule needs sigma (repeated measurements, sigma or "
                             "sigma_axis), which is unknown, so the uncorrected registration is "
                             "used."), False
    shown = format_rho(rho, rho_reject, rho_apply)
    if rec == "apply":
        return configured, (f"The paper's rule: rho = {shown} >= {_g(rho_apply)}, so "
                            f"{configured} corrections are applied."), True
    if rec == "do_not_apply":
        return UNCORRECTED, (f"The paper's rule: rho = {shown} < {_g(rho_reject)}, so the "
                             f"uncorrected registration is used."), True
    return UNCORRECTED, (f"The paper's rule: rho = {shown} is between {_g(rho_reject)} and "
                         f"{_g(rho_apply)} (uncertain), so the uncorrected registration is "
                         f"used."), False


def decide(mode: DecisionMode, cv: CrossValidation, configured: str, assessment: Assessment,
           rho_reject: float = 1.0, rho_apply: float = 2.5) -> Decision:
    """Make the decision (module docstring).

    :param mode: :class:`~.constants.DecisionMode` (or its string).
    :param cv: the held-out errors (:func:`~.crossval.cross_validate`).
    :param configured: the configured interpolation (``rho`` and ``on`` apply it).
    :param assessment: the paper's rho rule (:func:`~.noise.assess`), reported in every mode.
    :param rho_reject: rho below which the rule says do not apply (for the reason).
    :param rho_apply: rho from which the rule says apply (for the reason).
    :return: :class:`Decision`.
    :raises ValueError: on an unknown mode or interpolation.
    """
    mode = DecisionMode(mode)
    if configured not in CANDIDATES[1:]:
        raise ValueError(f"configured interpolation must be one of {CANDIDATES[1:]}, "
                         f"got {configured!r}")
    evaluated = [c for c in CANDIDATES if c in cv.errors or c in cv.unavailable]
    scores = [_score(cv, c) for c in evaluated]
    template, lengths = "", ()
    if mode is DecisionMode.CV:
        if not scores or scores[0].method != UNCORRECTED:
            scores.insert(0, _score(cv, UNCORRECTED))
        method, template, confident, lengths = _cv_choice(scores, cv)
        reason = template.format(*(_g(v) for v in lengths))
    elif mode is DecisionMode.RHO:
        method, reason, confident = _rho_choice(assessment, configured, rho_reject, rho_apply)
    elif mode is DecisionMode.ON:
        method, confident = configured, True
        reason = f"Corrections are on (decision mode 'on'): {configured} corrections are applied."
    else:
        method, confident = UNCORRECTED, True
        reason = "Corrections are off (decision mode 'off'): the uncorrected registration is used."
    return Decision(mode, method, method != UNCORRECTED, reason, confident, tuple(scores),
                    cv.scheme, SIGNIFICANCE, assessment.rho, assessment.recommendation,
                    error_model(cv, method), cv, template, lengths)


def _held_out_count(cv: CrossValidation) -> int:
    return max((len(e) for e in cv.errors.values()), default=0)
