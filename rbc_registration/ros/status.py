"""What ``registration_node`` reports about its model: ``~/status`` and ``/diagnostics``, built
from an immutable :class:`~rbc_registration.pipeline.state.ModelState` plus the ingestion
counters. Units: metres (REP 103); NaN where a value is unknown.
"""

from __future__ import annotations

from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rbc_registration_interfaces.msg import RegistrationStatus

from ..pipeline.ingest import Counters
from ..pipeline.settings import Settings, corrections_applied
from ..pipeline.state import ModelState
from .conversions import nanoseconds_to_stamp

#: RegistrationStatus.sigma_source for each of the core's
#: :data:`~rbc_registration.core.constants.SIGMA_SOURCES`.
STATUS_SIGMA_SOURCE = {"given": "parameter", "repeats": "repeats", "unknown": "unknown"}


def _nan(value: Any) -> float:
    return float("nan") if value is None else float(value)


def status_msg(state: ModelState, settings: Settings, counters: Counters,
               now: Time) -> RegistrationStatus:
    """The ``RegistrationStatus`` for ``state`` (built with possibly older settings)."""
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
    msg.correction_mode = settings.apply_corrections
    msg.restoration = (state.settings or settings).restoration
    msg.interpolation = (state.settings or settings).interpolation
    msg.last_recompute = nanoseconds_to_stamp(state.stamp_ns)
    msg.n_journal_failures = counters.n_journal_failures
    msg.message = state.error
    if counters.n_replay_skipped:
        msg.message = "; ".join(filter(None, (
            f"journal replay skipped {counters.n_replay_skipped} corrupt or invalid record(s) "
            f"(see the log)", state.error)))
    if counters.journal_error:
        msg.message = "; ".join(filter(None, (
            f"journal write failed, {counters.n_journal_failures} record(s) not accepted: "
            f"{counters.journal_error}", msg.message)))
    msg.model_valid = model is not None
    if model is None:
        msg.sigma = msg.rho = msg.fre_rms_uncorrected = msg.fre_rms_corrected = float("nan")
        msg.sigma_source = "unknown"
        msg.recommendation = "unknown"
        return msg
    msg.sigma = _nan(model.sigma)
    msg.sigma_source = STATUS_SIGMA_SOURCE.get(model.sigma_source, model.sigma_source)
    msg.sigma_l = [float(v) for v in model.sigma_l]
    msg.rho = _nan(model.rho)
    msg.recommendation = model.recommendation
    msg.fre_rms_uncorrected = float(model.uncorrected.fre_rms)
    msg.fre_rms_corrected = float(model.corrected.fre_rms)
    msg.corrections_applied = corrections_applied(settings.apply_corrections,
                                                  model.recommendation)
    return msg


def diagnostics_msg(status: RegistrationStatus, node_name: str, now: Time,
                    journal_error: str = "") -> DiagnosticArray:
    """``/diagnostics``: OK with a valid model whose corrections are trusted or off; WARN
    without a model, with an uncertain or negative recommendation, or after rejections; ERROR
    when the journal cannot be written."""
    d = DiagnosticStatus(name=f"{node_name}: registration",
                         hardware_id=f"{status.working_frame_id}->{status.destination_frame_id}")
    if journal_error:
        d.level, d.message = DiagnosticStatus.ERROR, f"journal: {journal_error}"
    elif not status.model_valid:
        d.level, d.message = DiagnosticStatus.WARN, f"no model: {status.message}"
    elif status.recommendation != "apply" and status.correction_mode != "off":
        d.level = DiagnosticStatus.WARN
        d.message = f"recommendation {status.recommendation} (rho {status.rho:.3g})"
    else:
        d.level = DiagnosticStatus.OK
        d.message = (f"{status.n_fiducials} fiducials, corrections "
                     f"{'applied' if status.corrections_applied else 'not applied'}")
    values = {
        "n_fiducials": status.n_fiducials, "n_disabled": status.n_disabled,
        "n_measurements": status.n_measurements, "n_pending": status.n_pending,
        "n_rejected": status.n_rejected, "n_rejected_frame": status.n_rejected_frame,
        "n_rejected_nonfinite": status.n_rejected_nonfinite,
        "n_rejected_outlier": status.n_rejected_outlier,
        "n_rejected_malformed": status.n_rejected_malformed,
        "n_rejected_stale": status.n_rejected_stale,
        "n_journal_failures": status.n_journal_failures,
        "sigma [m]": status.sigma, "sigma_source": status.sigma_source, "rho": status.rho,
        "recommendation": status.recommendation, "correction_mode": status.correction_mode,
        "corrections_applied": status.corrections_applied,
        "fre_rms_uncorrected [m]": status.fre_rms_uncorrected,
        "fre_rms_corrected [m]": status.fre_rms_corrected,
    }
    d.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    msg = DiagnosticArray(status=[d])
    msg.header.stamp = now
    return msg
