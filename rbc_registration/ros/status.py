"""What ``registration_node`` reports: ``~/status``, ``/diagnostics``, ``~/markers`` and the
calibration snapshot, each built from an immutable :class:`~rbc_registration.ros.worker.ModelState`
plus counters. Units: metres (REP 103); NaN where a value is unknown.
"""

from __future__ import annotations

import json
import math
from typing import Any, Mapping, NamedTuple

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from rbc_registration_interfaces.msg import RegistrationStatus

from .conversions import array_to_point, embed_3d, nanoseconds_to_stamp
from .params import Settings, corrections_applied
from .snapshot import SNAPSHOT_FORMAT
from .worker import ModelState

#: RegistrationStatus.sigma_source for the core's sigma_source values.
SIGMA_SOURCES = {"given": "parameter", "repeats": "repeats", "unknown": "unknown"}


class Counters(NamedTuple):
    """Accumulator counters at one moment (read under the node's lock)."""

    n_measurements: int
    rejected: Mapping[str, int]
    n_disabled: int
    n_journal_failures: int = 0
    journal_error: str = ""


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
    if counters.journal_error:
        msg.message = "; ".join(filter(None, (
            f"journal write failed, {counters.n_journal_failures} record(s) not accepted: "
            f"{counters.journal_error}", state.error)))
    msg.model_valid = model is not None
    if model is None:
        msg.sigma = msg.rho = msg.fre_rms_uncorrected = msg.fre_rms_corrected = float("nan")
        msg.sigma_source = "unknown"
        msg.recommendation = "unknown"
        return msg
    msg.sigma = _nan(model.sigma)
    msg.sigma_source = SIGMA_SOURCES.get(model.sigma_source, model.sigma_source)
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


def _color(r: float, g: float, b: float, a: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=a)


def markers_msg(state: ModelState, settings: Settings, now: Time) -> MarkerArray:
    """``~/markers`` in the destination frame: enabled fiducials (green spheres), disabled ones
    (grey), and per enabled fiducial an arrow along its correction mapped by R_c, drawn
    ``marker_arrow_gain`` times longer than the correction. Starts with DELETEALL."""
    out = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
    fiducials, model = state.fiducials, state.model
    if fiducials is None:
        return out
    frame, ns, scale = settings.destination_frame, "rbc_registration", settings.marker_scale

    def marker(kind: int, mid: int, name: str) -> Marker:
        m = Marker(type=kind, id=mid, ns=f"{ns}/{name}", action=Marker.ADD)
        m.header.frame_id = frame
        m.header.stamp = now
        m.pose.orientation.w = 1.0
        m.lifetime = Duration()
        return m

    def xyz(points: np.ndarray) -> np.ndarray:
        return points if points.shape[1] == 3 else np.column_stack([points, np.zeros(len(points))])

    spheres = marker(Marker.SPHERE_LIST, 0, "fiducials")
    spheres.scale.x = spheres.scale.y = spheres.scale.z = scale
    spheres.color = _color(0.1, 0.8, 0.2)
    spheres.points = [array_to_point(p) for p in xyz(fiducials.destination)]
    out.markers.append(spheres)
    if fiducials.disabled_ids:
        disabled = marker(Marker.TEXT_VIEW_FACING, 1, "disabled")
        disabled.scale.z = scale
        disabled.color = _color(0.6, 0.6, 0.6)
        disabled.text = "disabled: " + ", ".join(fiducials.disabled_ids)
        out.markers.append(disabled)
    if model is None:
        return out
    r, t = embed_3d(model.corrected.rotation, model.corrected.translation)
    start = xyz(fiducials.destination)
    step = xyz(np.asarray(model.corrections)) @ r.T * (-settings.marker_arrow_gain)
    for k in range(len(start)):
        arrow = marker(Marker.ARROW, k, "corrections")
        arrow.scale.x, arrow.scale.y, arrow.scale.z = scale * 0.2, scale * 0.4, scale * 0.4
        arrow.color = _color(0.9, 0.3, 0.1)
        arrow.points = [array_to_point(start[k]), array_to_point(start[k] + step[k])]
        out.markers.append(arrow)
    return out


def snapshot_json(state: ModelState, status: RegistrationStatus) -> str:
    """The calibration snapshot (``calibration.json``): frames, both registrations (destination
    = R @ working + t, metres), the fiducials and their corrections, sigma, rho and settings."""
    model, fiducials, settings = state.model, state.fiducials, state.settings
    data: dict[str, Any] = {
        "format": SNAPSHOT_FORMAT,
        "working_frame": status.working_frame_id,
        "destination_frame": status.destination_frame_id,
        "dimension": int(status.dimension), "units": "m",
        "stamp_ns": state.stamp_ns, "model_valid": model is not None, "error": state.error,
        "n_measurements": state.n_measurements,
    }
    if settings is not None:
        data["settings"] = {k: getattr(settings, k) for k in settings.__dataclass_fields__}
    if fiducials is not None:
        data["fiducial_ids"] = list(fiducials.ids)
        data["disabled_ids"] = list(fiducials.disabled_ids)
        data["working"] = fiducials.working.tolist()
        data["destination"] = fiducials.destination.tolist()
    if model is not None:
        def reg(registration: Any) -> dict[str, Any]:
            return {"rotation": np.asarray(registration.rotation).tolist(),
                    "translation": np.asarray(registration.translation).tolist(),
                    "fre_rms": float(registration.fre_rms)}
        data.update(corrections=np.asarray(model.corrections).tolist(),
                    corrected=reg(model.corrected), uncorrected=reg(model.uncorrected),
                    sigma=model.sigma, sigma_source=model.sigma_source,
                    sigma_l=[float(v) for v in model.sigma_l], rho=model.rho,
                    recommendation=model.recommendation)

    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, list):
            return [clean(x) for x in v]
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        return v
    return json.dumps(clean(data), indent=1)

