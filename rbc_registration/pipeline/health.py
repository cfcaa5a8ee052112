"""The health of the served model, as ``/diagnostics`` reports it: a level and its reason, from
what the status says and from what happened since the last report. Pure Python (no rclpy):
:mod:`rbc_registration.ros.status` maps the levels onto ``diagnostic_msgs/DiagnosticStatus``.

Levels (issue 10 item 6, issue 9):

- ``ERROR``: no model to answer targets (or the journal cannot be written);
- ``WARN``: an uncertain decision, a fiducial whose held-out error stands out (a likely typo or
  wrong hole), a session whose working frame moved (re-stationed, or kept apart; the model
  state's warning, :func:`~rbc_registration.pipeline.state.session_warning`), measurements
  rejected since the last report, a stale model (accepted
  measurements waiting longer than ``stale_after`` seconds to enter it), a loaded
  calibration without a live model, or ``use_sim_time`` with no ``/clock`` received (every stamp
  0);
- ``OK``: a valid model with a confident decision, whether or not it applies corrections.
"""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple, Optional


class Level(str, Enum):
    """How healthy the registration is (``diagnostic_msgs/DiagnosticStatus`` OK, WARN, ERROR)."""

    OK = "ok"
    WARN = "warn"
    ERROR = "error"


class Health(NamedTuple):
    """A level and the reasons for it, joined into one message."""

    level: Level
    message: str


class HealthInputs(NamedTuple):
    """What the level depends on.

    :ivar model_valid: a model exists.
    :ivar model_error: why not (when ``model_valid`` is false).
    :ivar confident: the decision was made with confidence (``Decision.confident``).
    :ivar decision_reason: the decision's reason in words.
    :ivar n_fiducials: fiducials in the model.
    :ivar method: the decision's method.
    :ivar n_rejected: rejected measurements so far (all reasons).
    :ivar n_pending: accepted measurements not yet in the model.
    :ivar journal_error: why the journal cannot be written, empty when it can.
    :ivar calibration: what a loaded calibration file published without a live model is
        (publish-only), empty when none.
    :ivar model_warning: what to check in the served model (a suspect fiducial, a session
        that moved), empty when nothing.
    :ivar clock_warning: what is wrong with the node's clock (``use_sim_time`` with no ``/clock``
        yet), empty when nothing.
    """

    model_valid: bool
    model_error: str
    confident: bool
    decision_reason: str
    n_fiducials: int
    method: str
    n_rejected: int
    n_pending: int
    journal_error: str = ""
    calibration: str = ""
    model_warning: str = ""
    clock_warning: str = ""


class HealthMonitor:
    """Turns successive :class:`HealthInputs` into :class:`Health`, remembering what the
    previous report saw (rejections) and since when measurements have been pending.

    :param stale_after: seconds pending measurements may wait before the model is stale.
    """

    def __init__(self, stale_after: float) -> None:
        if not stale_after > 0:
            raise ValueError(f"stale_after must be > 0 s, got {stale_after!r}")
        self.stale_after = float(stale_after)
        self._last_rejected: Optional[int] = None
        self._pending_since: Optional[float] = None

    def assess(self, inputs: HealthInputs, now: float) -> Health:
        """The health now (``now``: seconds on the caller's clock); call once per report.

        Rejections count when ``n_rejected`` grew since the previous call (the first call counts
        every rejection so far).
        """
        new_rejections = inputs.n_rejected - (self._last_rejected or 0)
        self._last_rejected = inputs.n_rejected
        if inputs.n_pending <= 0:
            self._pending_since = None
        elif self._pending_since is None:
            self._pending_since = now
        waited = 0.0 if self._pending_since is None else now - self._pending_since
        if inputs.journal_error:
            return Health(Level.ERROR, f"journal: {inputs.journal_error}")
        warnings = []
        if new_rejections > 0:
            warnings.append(f"{new_rejections} measurement(s) rejected since the last report")
        if waited > self.stale_after:
            warnings.append(f"stale model: {inputs.n_pending} measurement(s) waiting for "
                            f"{waited:.0f} s (stale_after {self.stale_after:g} s)")
        if inputs.clock_warning:
            warnings.append(inputs.clock_warning)
        if not inputs.model_valid:
            if inputs.calibration:
                return Health(Level.WARN, "; ".join([f"publish-only: {inputs.calibration}"]
                                                    + warnings))
            return Health(Level.ERROR, "; ".join([f"no model: {inputs.model_error}"]
                                                 + warnings))
        if inputs.model_warning:
            warnings.insert(0, inputs.model_warning)
        if not inputs.confident:
            warnings.insert(0, f"uncertain decision: {inputs.decision_reason}")
        if warnings:
            return Health(Level.WARN, "; ".join(warnings))
        return Health(Level.OK, f"{inputs.n_fiducials} fiducials, decision {inputs.method}: "
                                f"{inputs.decision_reason}")
