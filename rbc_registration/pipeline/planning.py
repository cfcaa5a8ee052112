"""The measurement planner for the served model (no rclpy): the error model and the expected
target error of a :class:`~.state.ModelState`, computed once per model in the node's planning
thread, and the validated request of ``~/suggest_next`` answered from them.

Units: those of the model (metres in the node). The expected error is O(J^3), and a model without
a kriging interpolator (e.g. decision off) needs the kriging hyper-parameters fitted first
(seconds at a thousand fiducials), so it is computed beside the recompute thread, never on the
executor, and a plan is refused (with the reason) until the error model of the current model is
ready.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..core.planning.expected_error import ExpectedErrorModel
from ..core.planning.model_check import ModelCheck
from ..core.planning.model_planner import calibrated, expected_target_error, plan_from_model, \
    served_error_model
from ..core.planning.planner import MeasurementPlan, PlanConfig
from ..core.rigid.scale import point_sets_unit_mismatch
from ..core.validation import as_points
from .settings import Settings
from .state import EMPTY_STATE, ModelState


#: Measurements of a target the node's plans and expected errors assume: ``~/correct_target``
#: answers one measured point (a new fiducial is assumed streamed as the fiducials so far
#: were: the median of their pair counts, :func:`~rbc_registration.core.planning.planner.
#: measurement_repeats`).
TARGET_REPEATS = 1


@dataclass(frozen=True)
class PlanningState:
    """What the planner knows of one model state.

    :ivar state: the model state this belongs to (compared by identity with the served one).
    :ivar error_model: the model's planning :class:`~rbc_registration.core.planning.expected_error.
        ExpectedErrorModel` (the corrected registration, what more fiducials improve),
        calibrated against the decision's cross-validated held-out errors
        (:func:`~rbc_registration.core.planning.model_planner.calibrated`); None without a model or
        when it could not be made.
    :ivar expected_target_error: expected median TRE over the work volume of the fiducials of
        the registration the model serves (its decision; unit of the model); NaN when unknown.
    :ivar error: why there is no error model ("" when there is).
    :ivar check: the error model against the cross-validated errors
        (:class:`~rbc_registration.core.planning.model_check.ModelCheck`; the plans say ``enough``
        only
        while it trusts the error model); None without an error model.
    """

    state: ModelState
    error_model: Optional[ExpectedErrorModel]
    expected_target_error: float
    error: str
    check: Optional[ModelCheck] = None


#: Nothing planned yet (belongs to no served state but the empty one).
NO_PLANNING = PlanningState(EMPTY_STATE, None, math.nan, "no model yet")


def planning_state(state: ModelState, max_fiducials: Optional[int] = None) -> PlanningState:
    """The error model and the expected target error of ``state``'s model (never raises
    ValueError: a model the planner cannot use gives NaN and the reason).

    :param max_fiducials: above this many fiducials nothing is computed (the node's
        ``plan_max_fiducials``); None: no limit.
    """
    model = state.model
    if model is None:
        return PlanningState(state, None, math.nan, f"no model yet: {state.error}")
    if max_fiducials is not None and len(model.ids) > max_fiducials:
        return PlanningState(state, None, math.nan, f"the planner is off: {len(model.ids)} "
                             f"fiducials, more than plan_max_fiducials ({max_fiducials})")
    try:
        em, check = calibrated(model)   # planning: the corrected registration
        served = served_error_model(model, em)
        if not served.corrected:        # the calibration is that of the corrected errors
            served = dataclasses.replace(served, calibration=1.0)
        value = expected_target_error(model, config=PlanConfig(target_repeats=TARGET_REPEATS),
                                      error_model=served)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return PlanningState(state, None, math.nan, f"no error model: {exc}")
    return PlanningState(state, em, value, "", check)


def expected_error_now(planning: PlanningState, state: ModelState) -> float:
    """The expected target error to report for the served ``state``: NaN unless ``planning``
    belongs to it."""
    return planning.expected_target_error if planning.state is state else math.nan


def plan_config(settings: Settings) -> PlanConfig:
    """The stopping rule's thresholds from the node parameters; one measurement per target."""
    return PlanConfig(within=settings.plan_within,
                      min_gain_fraction=settings.plan_min_gain_fraction,
                      min_gain_length=settings.plan_min_gain_length,
                      target_repeats=TARGET_REPEATS)


#: Most suggestions of one ``~/suggest_next`` request: a plan runs on the executor and each
#: suggestion costs a greedy step (~33 ms at 500 candidates and 500 targets, J = 60; count 500
#: held the executor 3.7-4.4 s); measure, then ask again.
MAX_SUGGESTIONS = 10


def request_error(settings: Settings, n_candidates: int, n_targets: int) -> str:
    """Why a ``~/suggest_next`` request of this size is refused ("" when it is not): no
    candidates, or more candidates or targets than ``max_candidates``."""
    limit = settings.max_candidates
    for name, n in (("candidates", n_candidates), ("targets", n_targets)):
        if n > limit:
            return (f"{n} {name} in one request, more than max_candidates ({limit}): split or "
                    f"thin the request")
    if n_candidates == 0:
        return "no candidates: send the locations that could be measured next"
    return ""


def suggest(planning: PlanningState, state: ModelState, settings: Settings,
            candidates: ArrayLike, targets: Optional[ArrayLike], count: int,
            groups: Optional[Sequence[str]] = None) -> MeasurementPlan:
    """The plan of a ``~/suggest_next`` request, from the served ``state`` and its ``planning``.

    :param candidates: (C, d) working-frame candidates, 1 <= C <= ``max_candidates``.
    :param targets: (K, d) working-frame targets (K <= ``max_candidates``), or None: the work
        volume.
    :param count: suggestions (0: one), in units (a group counts once).
    :param groups: a label per candidate ('' its own; None or all '': no groups): candidates
        measured together (one robot pose), ranked and suggested as a whole.
    :raises ValueError: naming what is wrong: no model, its error model not ready (yet), too
        many or no candidates or targets, a bad point, a count beyond the candidates or above
        :data:`MAX_SUGGESTIONS`.
    """
    if state.model is None:
        raise ValueError(f"no model yet: {state.error}")
    if planning.state is not state:
        raise ValueError(f"the error model of the current model ({len(state.model.ids)} "
                         f"fiducials) is still being computed: retry in a moment")
    if planning.error_model is None:
        raise ValueError(planning.error)
    if targets is not None and len(targets) == 0:
        targets = None
    error = request_error(settings, len(candidates), 0 if targets is None else len(targets))
    if error:
        raise ValueError(error)
    d = state.model.working.shape[1]
    candidates = as_points(candidates, "candidates", d, 1)
    targets = None if targets is None else as_points(targets, "targets", d, 1)
    # a whole request in another unit (mm sent to a node in metres): refused, not planned
    mismatch = point_sets_unit_mismatch(state.model.working, state.model.interpolator.hull,
                                        (("candidates", candidates), ("targets", targets)))
    if mismatch:
        raise ValueError(f"{mismatch[0]}; the node works in metres")
    if groups is not None and not any(groups):
        groups = None
    if count > MAX_SUGGESTIONS:
        raise ValueError(f"count {count}: at most {MAX_SUGGESTIONS} suggestions per request "
                         f"(each is a step of the plan on the executor); measure them, then "
                         f"ask again")
    return plan_from_model(state.model, candidates, targets, count=max(1, count),
                           config=plan_config(settings), error_model=planning.error_model,
                           check=planning.check, groups=groups)
