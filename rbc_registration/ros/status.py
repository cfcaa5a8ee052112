"""What ``registration_node`` reports about its model: ``~/status`` and ``/diagnostics``, built
from an immutable :class:`~rbc_registration.pipeline.state.ModelState` plus the ingestion
counters. Units: metres (REP 103); NaN where a value is unknown.
"""

from __future__ import annotations

import math
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rbc_registration_interfaces.msg import RegistrationStatus

from ..io.calibration_model import expected_tre
from ..pipeline.health import Health, HealthInputs, HealthMonitor, Level
from ..pipeline.ingest import Counters
from ..pipeline.settings import Settings
from ..pipeline.state import ModelState
from .conversions import nanoseconds_to_stamp, stamp_to_seconds

#: RegistrationStatus.sigma_source for each of the core's
#: :data:`~rbc_registration.core.constants.SIGMA_SOURCES`.
STATUS_SIGMA_SOURCE = {"given": "parameter", "repeats": "repeats", "unknown": "unknown"}
#: DiagnosticStatus level of each health :class:`~rbc_registration.pipeline.health.Level`.
DIAGNOSTIC_LEVEL = {Level.OK: DiagnosticStatus.OK, Level.WARN: DiagnosticStatus.WARN,
                    Level.ERROR: DiagnosticStatus.ERROR}


def _nan(value: Any) -> float:
    return float("nan") if value is None else float(value)


def status_msg(state: ModelState, settings: Settings, counters: Counters,
               now: Time, expected_target_error: float = float("nan")) -> RegistrationStatus:
    """The ``RegistrationStatus`` for ``state`` (built with possibly older settings) and the
    planner's expected target error of its model [m] (NaN: unknown)."""
    msg = RegistrationStatus()
    msg.header.stamp = now
    msg.header.frame_id = settings.destination_frame
    msg.working_frame_id = settings.working_frame
    msg.destination_frame_id = settings.destination_frame
    msg.dimension = settings.dimension
    fiducials = state.fiducials
    msg.n_fiducials = len(fiducials.ids) if fiducials is not None else 0
    msg.n_disabled = counters.n_disabled
    msg.n_measurements = counters.n_measurements
    msg.n_pending = max(0, counters.n_measurements - state.n_measurements)
    msg.n_rejected = sum(counters.rejected.values())
    for reason, count in counters.rejected.items():
        setattr(msg, f"n_rejected_{reason}", count)
    model = state.model
    msg.decision_mode = (state.settings or settings).decision
    msg.restoration = (state.settings or settings).restoration
    msg.interpolation = (state.settings or settings).interpolation
    msg.last_recompute = nanoseconds_to_stamp(state.stamp_ns)
    msg.n_journal_failures = counters.n_journal_failures
    msg.message = state.error or state.warning
    if counters.n_replay_skipped:
        msg.message = "; ".join(filter(None, (
            f"journal replay skipped {counters.n_replay_skipped} corrupt or invalid record(s) "
            f"(see the log)", state.error)))
    if counters.journal_error:
        msg.message = "; ".join(filter(None, (
            f"journal write failed, {counters.n_journal_failures} record(s) not accepted: "
            f"{counters.journal_error}", msg.message)))
    msg.model_valid = model is not None
    msg.expected_target_error = float(expected_target_error) if model is not None else math.nan
    if model is None:
        msg.sigma = msg.sigma_axis = msg.rho = float("nan")
        msg.fre_rms_uncorrected = msg.fre_rms_corrected = float("nan")
        msg.expected_tre_median = msg.expected_tre_bound = float("nan")
        msg.sigma_source = "unknown"
        msg.recommendation = "unknown"
        return msg
    msg.sigma = _nan(model.sigma)
    msg.sigma_axis = _nan(model.sigma_axis)
    msg.sigma_source = STATUS_SIGMA_SOURCE.get(model.sigma_source, model.sigma_source)
    msg.sigma_l = [float(v) for v in model.sigma_l]
    msg.rho = _nan(model.rho)
    msg.recommendation = model.recommendation
    msg.fre_rms_uncorrected = float(model.uncorrected.fre_rms)
    msg.fre_rms_corrected = float(model.corrected.fre_rms)
    decision = model.decision
    msg.decision_mode = decision.mode.value
    msg.decision_method = decision.method
    msg.decision_reason = decision.reason
    msg.decision_confident = decision.confident
    msg.corrections_applied = decision.apply
    chosen = decision.candidate(decision.method)
    msg.expected_tre_median = _nan(expected_tre(decision))
    msg.expected_tre_bound = float(chosen.cv_bound) if chosen is not None else float("nan")
    msg.cv_methods = [c.method for c in decision.candidates]
    msg.cv_median = [float(c.cv_median) for c in decision.candidates]
    msg.cv_rms = [float(c.cv_rms) for c in decision.candidates]
    msg.cv_p_value = [_nan(c.p_value) for c in decision.candidates]
    return msg


def health_of(status: RegistrationStatus, monitor: HealthMonitor, journal_error: str = "",
              calibration: str = "", model_warning: str = "", sim_time: bool = False) -> Health:
    """The health (:mod:`rbc_registration.pipeline.health`) of ``status`` at its stamp;
    ``model_warning``: the served state's :attr:`~.ModelState.warning`; ``sim_time``: the node's
    clock is ``/clock`` (``use_sim_time``), so a stamp of 0 means no ``/clock`` has arrived."""
    clock = ""
    if sim_time and status.header.stamp.sec == 0 and status.header.stamp.nanosec == 0:
        clock = NO_CLOCK
    return monitor.assess(HealthInputs(
        status.model_valid, status.message, status.decision_confident, status.decision_reason,
        status.n_fiducials, status.decision_method, status.n_rejected, status.n_pending,
        journal_error, calibration, model_warning, clock), stamp_to_seconds(status.header.stamp))


#: The health's line when ``use_sim_time`` is true and no ``/clock`` message has arrived.
NO_CLOCK = ("use_sim_time is true and no /clock message has arrived: stamps are 0 and "
            "max_stamp_age / sample_max_age compare against time 0 (start the /clock source, "
            "e.g. a bag played with --clock, or set use_sim_time false)")


def diagnostics_msg(status: RegistrationStatus, node_name: str, now: Time,
                    health: Health) -> DiagnosticArray:
    """``/diagnostics``: one status at the ``health`` level (:func:`health_of`), its reason in
    the message, the status' numbers and the decision as key/values. The status is named
    ``<node_name>: registration`` (diagnostic_updater's ``<node name>: <task>``), with
    ``node_name`` the fully qualified name (``/cell_a/registration_node``), so that two cells'
    nodes of one name in different namespaces are told apart."""
    d = DiagnosticStatus(name=f"{node_name}: registration",
                         hardware_id=f"{status.working_frame_id}->{status.destination_frame_id}")
    d.level, d.message = DIAGNOSTIC_LEVEL[health.level], health.message
    values = {
        "n_fiducials": status.n_fiducials, "n_disabled": status.n_disabled,
        "n_measurements": status.n_measurements, "n_pending": status.n_pending,
        "n_rejected": status.n_rejected, "n_rejected_frame": status.n_rejected_frame,
        "n_rejected_nonfinite": status.n_rejected_nonfinite,
        "n_rejected_outlier": status.n_rejected_outlier,
        "n_rejected_malformed": status.n_rejected_malformed,
        "n_rejected_stale": status.n_rejected_stale,
        "n_rejected_ambiguous": status.n_rejected_ambiguous,
        "n_rejected_duplicate": status.n_rejected_duplicate,
        "n_rejected_conflict": status.n_rejected_conflict,
        "n_journal_failures": status.n_journal_failures,
        "sigma [m]": status.sigma, "sigma_axis [m]": status.sigma_axis,
        "sigma_source": status.sigma_source, "rho": status.rho,
        "recommendation": status.recommendation, "decision": status.decision_mode,
        "method": status.decision_method, "decision_confident": status.decision_confident,
        "corrections_applied": status.corrections_applied,
        "expected_tre_median [m]": status.expected_tre_median,
        "expected_tre_bound [m]": status.expected_tre_bound,
        **{f"cv_median {m} [m]": v for m, v in zip(status.cv_methods, status.cv_median)},
        "fre_rms_uncorrected [m]": status.fre_rms_uncorrected,
        "fre_rms_corrected [m]": status.fre_rms_corrected,
    }
    d.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    msg = DiagnosticArray(status=[d])
    msg.header.stamp = now
    return msg
