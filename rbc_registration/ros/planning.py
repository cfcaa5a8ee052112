"""The measurement planner of ``registration_node`` (a mixin of
:class:`~rbc_registration.ros.node.RegistrationNode`): the planning thread, which computes the
error model and the expected target error of every new model (``~/status``
``expected_target_error``), and ``~/suggest_next``, answered from the served model and its
error model. Bad requests are answered ``success=False`` with the reason; see msg_docs/README.md.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from geometry_msgs.msg import Point
from numpy.typing import NDArray

from rbc_registration_interfaces.srv import SuggestNext

from ..pipeline.planning import (NO_PLANNING, PlanningState, expected_error_now, planning_state,
                                 request_error, suggest)
from ..pipeline.state import ModelState
from ..pipeline.worker import LatestWriter
from .parts import NodeParts


def points_to_array(points: Sequence[Point], dimension: int) -> NDArray[np.float64]:
    """(N, dimension) working-frame coordinates of ``points`` (2D: z ignored)."""
    return np.array([(p.x, p.y, p.z) for p in points], dtype=np.float64).reshape(-1, 3)[
        :, :dimension]


class PlanningMixin(NodeParts):
    """The planner; the node provides ``_state``, ``_settings`` and ``get_logger``, and calls
    :meth:`_start_planner` in its start, :meth:`_plan_model` with every new model state,
    :meth:`_expected_target_error` for its status, and stops ``_planner`` when destroyed."""

    get_logger: Any

    def _start_planner(self) -> None:
        self._planning: PlanningState = NO_PLANNING
        self._planner = LatestWriter(self._update_planning, self._on_planner_error,
                                     name="rbc_planner")

    def _plan_model(self, state: ModelState) -> None:
        """Compute the error model of ``state`` in the planning thread (the newest wins)."""
        self._planner.submit(state)

    def _expected_target_error(self) -> float:
        """The expected target error [m] of the served model; NaN while it is computed."""
        return expected_error_now(self._planning, self._state)

    def _update_planning(self, state: ModelState) -> str:
        planning = planning_state(state, self._settings.plan_max_fiducials)
        if state is not self._state:   # a newer model (or a reset) came meanwhile
            return "stale"
        new_reason = planning.error.split(":")[0] != self._planning.error.split(":")[0]
        if planning.error and state.model is not None and new_reason:
            self.get_logger().warning(f"planner: {planning.error}")   # once per kind of reason
        self._planning = planning   # ~/status carries it from its next publication (timer)
        return planning.error or f"expected target error {planning.expected_target_error:.3g} m"

    def _on_planner_error(self, exc: BaseException) -> None:
        self.get_logger().error(f"planner failed: {type(exc).__name__}: {exc}")

    def _on_suggest_next(self, request: SuggestNext.Request,
                         response: SuggestNext.Response) -> SuggestNext.Response:
        state, planning, s = self._state, self._planning, self._settings
        error = request_error(s, len(request.candidates), len(request.targets))
        if error:
            response.success, response.message = False, error
            return response
        groups = list(request.candidate_groups) or None
        if groups is not None and len(groups) != len(request.candidates):
            response.success = False
            response.message = (f"candidate_groups: {len(groups)} labels for "
                                f"{len(request.candidates)} candidates (one per candidate, or "
                                f"none)")
            return response
        try:
            plan = suggest(planning, state, s, points_to_array(request.candidates, s.dimension),
                           points_to_array(request.targets, s.dimension)
                           if request.targets else None, int(request.count), groups)
        except ValueError as exc:
            response.success, response.message = False, str(exc)
            return response
        response.success = True
        response.ranked = [int(k) for k in plan.ranked_candidates]
        response.ranked_groups = [plan.unit_labels[u] for u in plan.sequence] \
            if plan.unit_labels else []
        response.expected_error_after = [float(v) for v in plan.expected_after]
        response.expected_error_now = float(plan.expected_now)
        response.expected_error_with_all = float("nan") if plan.expected_with_all is None \
            else float(plan.expected_with_all)
        response.enough, response.reason = bool(plan.enough), plan.reason
        response.enough_rule = plan.enough_rule or ""
        response.model_trusted = bool(plan.model_check is not None
                                      and plan.model_check.trustworthy)
        where = f"{len(plan.points)} targets" if plan.on_targets else \
            f"the work volume ({len(plan.points)} points)"
        what = "candidate groups" if plan.unit_labels else "candidates"
        response.message = (f"{len(plan.sequence)} suggestion(s) of {len(plan.gains)} "
                            f"{what} from {plan.fiducial_count} fiducials; median target "
                            f"error over {where}")
        return response
