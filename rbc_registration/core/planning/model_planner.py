"""The measurement planner for a built :class:`.model.RbcModel` (what the CLI and node call).

The model gives the fiducials (working frame), their repeats and the error model: the bias
hyper-parameters of its kriging, its noise sigma, and whether it applies the correction::

    model = build_model(working, destination, ModelConfig(dimension=2, interpolation="kriging"))
    p = plan_from_model(model, candidates_working, targets_working, count=5)
    p.sequence, p.expected_now, p.expected_after, p.enough, p.reason
    expected_target_error(model)                 # the expected median TRE now (work volume)
    check_expected_error(model).ratio            # leave-one-out: actual / expected

The plans assume the corrected registration (:func:`error_model_from`). So while a ``cv``
decision serves the uncorrected registration without being confident (a correction looked
relevantly better on the held-out fiducials but was not shown better), the error the plan expects
is not what targets get, and the stopping rule does not say enough (:func:`held_back_by_decision`).
Meanwhile the first suggestion is the one that tests the correction best
(:func:`decisive_candidate`), the rest of the sequence greedy after it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..constants import DecisionMode
from ..decision.evaluation import leave_one_out
from .expected_error import ExpectedErrorModel, expected_squared_errors, pooled_median
from ..interpolation.kriging import KrigingInterpolator
from ..model import RbcModel
from .model_check import ModelCheck, check_model, units_to_trust
from .planner import (DEFAULT_PLAN_CONFIG, MeasurementPlan, PlanConfig, measurement_repeats,
                      plan, work_volume)
from ..validation import as_points


class ExpectedErrorCheck(NamedTuple):
    """Leave-one-out check of the error model (unit of the points).

    :ivar expected: (J,) expected TRE (RMS) of each fiducial predicted from the others.
    :ivar actual: (J,) the leave-one-out TRE of the model (corrected or uncorrected as modelled).
    :ivar expected_median: pooled expected median of ``expected``.
    :ivar actual_median: median of ``actual``.
    :ivar ratio: actual_median / expected_median (a calibration for the error model).
    """

    expected: NDArray[np.float64]
    actual: NDArray[np.float64]
    expected_median: float
    actual_median: float
    ratio: float


def _applies_correction(model: RbcModel) -> bool:
    """Whether the model's registration applies the correction eps(T) to targets: the
    cross-validated decision of issue 9 when the model has one (``decision.apply``), else
    always (the model serves the corrected registration)."""
    decision = getattr(model, "decision", None)
    return True if decision is None else bool(decision.apply)


def error_model_from(model: RbcModel, axis_std: Optional[ArrayLike] = None, *,
                     served: bool = False) -> ExpectedErrorModel:
    """The error model of a built :class:`.model.RbcModel`.

    The bias hyper-parameters are the model's kriging ones (fitted now for the ``paper``
    interpolation); the noise is isotropic with sigma / sqrt(d) per axis (sigma: the model's,
    else the fitted one) unless ``axis_std`` (d,) gives the standard deviation per working axis.

    :param served: False (planning): the corrected registration, whatever the decision serves
        now. More fiducials are measured to learn the bias field; a decision that serves the
        uncorrected registration today (too few fiducials to cross-validate a correction) would
        otherwise see the bias as a floor no measurement lowers, and stop at once. True: the
        registration the model serves (its decision), for reporting the error of today's answer.
    """
    hyper = model.kriging_hyperparameters
    if hyper is None:
        hyper = KrigingInterpolator(model.working, model.corrections, model.sigma,
                                    model.counts).hyper
    d = model.config.dimension
    std = np.full(d, hyper.noise_std / math.sqrt(d)) if axis_std is None else axis_std
    em = ExpectedErrorModel.from_axis_std(hyper.signal_std, hyper.length_scale, std)
    return served_error_model(model, em) if served else em


def served_error_model(model: RbcModel, error_model: ExpectedErrorModel) -> ExpectedErrorModel:
    """``error_model`` for the registration ``model`` serves now: corrected as its decision
    says (the planning one, :func:`error_model_from`, always assumes the correction)."""
    return dataclasses.replace(error_model, corrected=_applies_correction(model))


def held_back_by_decision(model: RbcModel) -> Optional[str]:
    """Why the stopping rule cannot say enough yet, or None: a ``cv`` decision that serves the
    uncorrected registration without being confident (``decision.confident`` False: a correction
    looked better by at least :data:`.decision.RELEVANT_GAIN` but was not shown better, or
    cross-validation was not possible). More fiducials give the test the power to decide either
    way; until then the corrected error the plan expects is not what targets get. Other modes
    (``rho``, ``on``, ``off``) do not change with more fiducials the same way: never held back."""
    decision = getattr(model, "decision", None)
    if (decision is None or decision.apply or decision.confident
            or decision.mode is not DecisionMode.CV):
        return None
    return ("the decision serves the uncorrected registration but is not confident that "
            "correcting does not help, so more fiducials are needed before the expected error "
            "below is what targets get")


#: The decisive candidate (:func:`decisive_candidate`) is suggested first only when its
#: correction is at least this many of its standard deviations: below, it is noise and tests
#: nothing, and the plan is greedy from its first suggestion (without the floor a correction of
#: 0.00065 sigma would displace the best-gain candidate).
MIN_DECISIVE_Z = 1.0


def decisive_candidate(model: RbcModel, candidates: ArrayLike) -> Optional[tuple[int, float]]:
    """The candidate that tests the correction best, and its score: where the model's kriging
    expects the largest correction against its uncertainty, z = |eps(c)| / s(c) (posterior mean
    over its 1-sigma per axis). If the bias is real, that fiducial is where the rigid fit errs and
    the correction does not, which is the evidence the decision's test lacks. None without a
    kriging interpolator in the model (or when no candidate has a posterior spread).

    Measured (benchmarks/RESULTS.md, "Planner"): on the RA-like cell, in the 12 unsure states of
    20 seeds' planner runs, the decision applied corrections after this candidate in 10 (after
    the largest-gain candidate in 5), and the median target TRE was 0.155 against 0.195 mm."""
    kriging = model.interpolators.get("kriging")
    if kriging is None:
        return None
    c = as_points(candidates, "candidates", model.config.dimension, 1)
    out = kriging(c)
    spread = np.asarray(out.expected_error, dtype=np.float64)
    if not np.any(spread > 0):
        return None
    size = np.linalg.norm(out.correction, axis=1)
    z = np.where(spread > 0, size / np.where(spread > 0, spread, 1.0), -np.inf)
    k = int(np.argmax(z))                       # first of equals: the lowest index
    return k, float(z[k])


def calibrated(model: RbcModel, error_model: Optional[ExpectedErrorModel] = None
               ) -> tuple[ExpectedErrorModel, ModelCheck]:
    """The planning error model (default ``error_model_from(model)``) with its calibration set
    to the ratio of the decision's cross-validated held-out errors to its expected ones
    (:func:`.model_check.check_model`; 1 when the check is not available), and the check."""
    em = error_model_from(model) if error_model is None else error_model
    check = check_model(model, em)
    return dataclasses.replace(em, calibration=check.ratio), check


def _to_trust(check: ModelCheck, grouped: bool) -> str:
    """What to measure so that the error model can be trusted (:mod:`.model_check`)."""
    more = units_to_trust(check)
    if more:
        return (f"measure at least {more} more {'groups' if grouped else 'fiducials'} (the "
                f"suggestions first) and plan again")
    return "measure the suggestions and plan again (the error model is refitted with them)"


def plan_from_model(model: RbcModel, candidates: ArrayLike, targets: Optional[ArrayLike] = None,
                    *, count: int = 1, config: PlanConfig = DEFAULT_PLAN_CONFIG,
                    error_model: Optional[ExpectedErrorModel] = None,
                    check: Optional[ModelCheck] = None,
                    groups: Optional[Sequence[str]] = None) -> MeasurementPlan:
    """:func:`plan` from the model's fiducials, repeats and error model (or ``error_model``;
    default the planning one, ``error_model_from(model)``: corrected registration), calibrated
    against the decision's cross-validated held-out errors (:func:`calibrated`; ``check``: the
    check already made for this ``error_model``, which then is taken as calibrated). ``enough``
    is never said while the check does not trust the error model (the reason says what to
    measure), nor while :func:`held_back_by_decision` gives a reason: then ``enough_after`` is
    None (when the decision will apply corrections is not known), the first suggestion is
    :func:`decisive_candidate` and the reason says all of this. ``groups``: a label per
    candidate, candidates measured together (:func:`plan`)."""
    if check is None:
        em, check = calibrated(model, error_model)
    else:
        em = error_model_from(model) if error_model is None else error_model
    holds = []
    if not check.trustworthy:
        holds.append("the error model is not yet trustworthy (" + (
            check.note if check.note else "not checked") + ")")
    held = held_back_by_decision(model)
    decisive = decisive_candidate(model, candidates) if held is not None else None
    if decisive is not None and decisive[1] < MIN_DECISIVE_Z:
        decisive = None                 # no correction stands out of its noise: it tests nothing
    if decisive is not None:
        held += (f"; the first suggestion (#{decisive[0]}) is where the correction is expected "
                 f"largest against its uncertainty ({decisive[1]:.3g} sigma), to test it")
    if held is not None:
        holds.append(held)
    to_measure = _to_trust(check, groups is not None and model.groups is not None) \
        if not check.trustworthy else ""
    p = plan(model.working, candidates, em, targets, count=count, repeats=model.counts,
             config=config, first=None if decisive is None else decisive[0],
             held_back="; ".join(holds) or None, groups=groups, to_measure=to_measure)
    return p._replace(model_check=check)


def expected_target_error(model: RbcModel, targets: Optional[ArrayLike] = None, *,
                          config: PlanConfig = DEFAULT_PLAN_CONFIG,
                          error_model: Optional[ExpectedErrorModel] = None) -> float:
    """Expected median TRE of the model now, over ``targets`` (K, d) (working frame) or, without
    them, over the work volume of the fiducials (:func:`work_volume`), without candidates (e.g.
    for a status report). Default error model: the registration the model serves
    (``error_model_from(model, served=True)``)."""
    em = error_model_from(model, served=True) if error_model is None else error_model
    pts = work_volume(model.working, config.work_volume_points) if targets is None else targets
    n_target = measurement_repeats(config, model.counts)[1]
    return float(pooled_median(expected_squared_errors(model.working, pts, em, model.counts,
                                                       n_target), em.dimension))


def check_expected_error(model: RbcModel, error_model: Optional[ExpectedErrorModel] = None
                         ) -> ExpectedErrorCheck:
    """Compare the expected leave-one-out error of each fiducial (predicted from the others)
    with the model's actual leave-one-out TRE (:func:`.evaluation.leave_one_out`).

    :return: :class:`ExpectedErrorCheck`; ``ratio`` can serve as
        ``ExpectedErrorModel.calibration``.
    """
    em = error_model_from(model) if error_model is None else error_model
    x, n = model.working, model.counts
    keep = ~np.eye(len(x), dtype=bool)
    expected = np.array([expected_squared_errors(x[keep[k]], x[k:k + 1], em, n[keep[k]],
                                                 float(n[k]))[0] for k in range(len(x))])
    loo = leave_one_out(model)
    actual = loo.tre_c if em.corrected else loo.tre_u
    exp_med = float(pooled_median(expected, em.dimension))
    act_med = float(np.median(actual))
    return ExpectedErrorCheck(np.sqrt(expected), actual, exp_med, act_med, act_med / exp_med)
