"""Calibrations (:mod:`.calibration`) from what the node and the CLI hold: the served model
state, the node's snapshot (``state_dir/calibration.json``) or a ``register`` / ``evaluate`` JSON
report; and the check that a loaded calibration belongs to the node's frames. No rclpy.

Units: a calibration is in metres; a report in another unit of
:data:`~rbc_registration.core.constants.METRES_PER_UNIT` (its ``unit``) is converted.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any, Callable, Mapping, NamedTuple, Optional

from ..core.constants import METRES_PER_UNIT, UNCORRECTED, UNIT_ALIASES
from ..core.decision.choice import Decision as ModelDecision
from ..pipeline.named import calibration_name_problem, is_calibration_name
from ..pipeline.settings import Settings
from ..pipeline.snapshot import SNAPSHOT_FORMAT
from ..pipeline.state import ModelState
from ..pipeline.state_dir import CALIBRATIONS_DIR, StateDir
from .calibration import REGISTRATIONS, Calibration, Decision, calibration_from_registration
from .calibration_answers import answers_of_model
from .calibration_format import _quote, check_number



def calibration_path(state_dir: str) -> str:
    """Path of the calibration file in ``state_dir``."""
    return StateDir.resolve(state_dir).calibration


def named_calibration_path(state_dir: str, name: str) -> str:
    """Path of the calibration named ``name`` in ``state_dir``: ``calibrations/NAME.yaml``.

    :raises ValueError: when ``name`` is not a calibration name
        (:func:`~rbc_registration.pipeline.named.calibration_name_problem`).
    """
    problem = calibration_name_problem(name)
    if problem:
        raise ValueError(problem)
    return StateDir.resolve(state_dir).named_calibration(name)


def resolve_calibration_file(value: str, state_dir: str) -> str:
    """The absolute path of a ``calibration_file`` value: a bare name (no ``/``, no ``.yaml``;
    :func:`~rbc_registration.pipeline.named.is_calibration_name`) is
    ``state_dir/calibrations/NAME.yaml``, anything else a path (``~`` expanded).

    :raises ValueError: for a name without ``state_dir``, or not a valid name.
    """
    if not is_calibration_name(value):
        return os.path.abspath(os.path.expanduser(value))
    if not state_dir:
        raise ValueError(f"calibration_file {value!r} is a calibration name, read from "
                         f"state_dir/{CALIBRATIONS_DIR}/, but state_dir is empty: give the "
                         f"file's path")
    return named_calibration_path(state_dir, value)


def decision_record(decision: ModelDecision) -> Decision:
    """The calibration file's decision (mode, method, apply, reason) of a model's decision."""
    return Decision(mode=decision.mode.value, method=decision.method, apply=decision.apply,
                    reason=decision.reason)


def _cv_median(decision: ModelDecision, method: str) -> Optional[float]:
    score = decision.candidate(method)
    ok = score is not None and math.isfinite(score.cv_median)
    return float(score.cv_median) if ok else None


def expected_tre(decision: ModelDecision) -> Optional[float]:
    """The expected TRE of the decision: its chosen method's cross-validated median error (unit
    of the points); None when it could not be cross-validated. With a correcting method it needs
    the corrections (the calibration file's ``expected_tre_with_corrections``)."""
    return _cv_median(decision, decision.method)


def rigid_expected_tre(decision: ModelDecision) -> Optional[float]:
    """The expected TRE of the rigid registration alone, no corrections: the ``uncorrected``
    candidate's cross-validated median error (each held-out fiducial mapped by the rigid fit of
    the others; unit of the points); None when it could not be cross-validated."""
    return _cv_median(decision, UNCORRECTED)


class _Figures(NamedTuple):
    decision: Decision
    with_corrections: Optional[float]   # [m]
    uncorrected: Optional[float]        # [m]


def _document_decision(data: Mapping[str, Any], where: str, scale: float) -> _Figures:
    """The decision and the expected TREs [m] of a snapshot or report (its ``decision``
    object): the decision's method's and the uncorrected registration's cross-validated
    medians."""
    d = _get(data, "decision", where)
    try:
        record = Decision(mode=d["mode"], method=d["method"], apply=d["apply"],
                          reason=d["reason"])
        medians = {m: d["cv"].get(m, {}).get("median") for m in (d["method"], UNCORRECTED)}
    except (KeyError, TypeError, AttributeError):
        raise ValueError(f"{where}: decision: needs mode, method, apply, reason and cv") from None
    except ValueError as exc:   # a field of the record, e.g. decision.apply: must be true or ...
        raise ValueError(f"{where}: {exc}") from None
    figures = [None if v is None else
               scale * check_number(f"{where}: decision: cv: {m}: median", v)
               for m, v in medians.items()]
    return _Figures(record, figures[0], figures[-1])


def calibration_from_state(state: ModelState, settings: Settings, registration: str,
                           clock: Optional[Callable[[], float]] = None) -> Calibration:
    """The calibration of the served model: ``registration`` (``corrected`` / ``uncorrected``)
    from destination_frame (parent) to working_frame (child), with the model's ``answers`` (a
    node loading it answers targets as this model does); ``created`` from the model's stamp
    (node clock) unless ``clock`` is given.

    :raises ValueError: without a model, or for an unknown ``registration``.
    """
    model = state.model
    if model is None:
        raise ValueError(f"no model to save as a calibration yet: {state.error}")
    if registration not in REGISTRATIONS:
        raise ValueError(f"registration must be one of {', '.join(REGISTRATIONS)}, "
                         f"got {registration!r}")
    reg = model.corrected if registration == "corrected" else model.uncorrected
    stamp_s = state.stamp_ns * 1e-9
    return calibration_from_registration(
        reg.rotation, reg.translation, parent_frame=settings.destination_frame,
        child_frame=settings.working_frame, registration=registration, fre_rms=reg.fre_rms,
        decision=decision_record(model.decision), sigma=model.sigma, sigma_l=model.sigma_l,
        # The node fits both registrations to all fiducials: the corrected one's rigid part
        # then agrees with the uncorrected one to second order in the bias (core/rigid/restoration).
        expected_tre_rigid=rigid_expected_tre(model.decision),
        expected_tre_with_corrections=expected_tre(model.decision),
        n_fiducials=len(model.ids), clock=clock or (lambda: stamp_s),
        answers=answers_of_model(model))


def _get(data: Mapping[str, Any], key: str, where: str) -> Any:
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: not a JSON object where {key} is expected")
    if key not in data or data[key] is None:
        raise ValueError(f"{where}: {key}: missing")
    return data[key]


def _number(data: Mapping[str, Any], key: str, where: str) -> float:
    """``data[key]``, a finite number (:func:`.calibration_format.check_number`)."""
    return check_number(f"{where}: {key}", _get(data, key, where))


def _numbers(data: Mapping[str, Any], key: str, where: str) -> list[float]:
    """``data[key]``, a list of finite numbers."""
    values = _get(data, key, where)
    if not isinstance(values, list):
        raise ValueError(f"{where}: {key}: must be a list of numbers, got {type(values).__name__}")
    return [check_number(f"{where}: {key}[{k}]", v) for k, v in enumerate(values)]


#: The latest ``stamp_ns`` a snapshot can have (the year 9999).
_LAST_STAMP_NS = 253402300799 * 10**9


def _unit_scale(data: Mapping[str, Any], where: str, key: str, unit: Optional[str],
                default: Optional[str] = None) -> float:
    """Metres per unit of the source: the unit it records under ``key`` (``default`` when it
    records none), else ``unit`` (``--unit``); a ``unit`` other than the recorded one is
    refused, naming both."""
    recorded = data.get(key, default)
    recorded = UNIT_ALIASES.get(recorded, recorded) if isinstance(recorded, str) else recorded
    unit = UNIT_ALIASES.get(unit, unit) if unit is not None else None
    if recorded is None:
        if unit is None:
            raise ValueError(f"{where}: {key}: missing: the file records no length unit; give "
                             f"--unit ({', '.join(METRES_PER_UNIT)})")
        recorded = unit
    if not isinstance(recorded, str) or recorded not in METRES_PER_UNIT:
        raise ValueError(f"{where}: {key} {_quote(recorded)}: a calibration is in metres; "
                         f"export converts {', '.join(METRES_PER_UNIT)}")
    if unit is not None and unit != recorded:
        raise ValueError(f"{where}: --unit {unit} contradicts the file's {key} {recorded!r}: "
                         f"refused (export converts by the unit the file records; drop --unit)")
    return METRES_PER_UNIT[recorded]


def _check_dimension(data: Mapping[str, Any], where: str, key: str, rotation: list) -> None:
    """The recorded dimension (``key``), when there is one, must be the rotation's."""
    if data.get(key) is None:
        return
    dim = data[key]
    if isinstance(dim, bool) or dim not in (2, 3):
        raise ValueError(f"{where}: {key}: must be 2 or 3, got {_quote(dim)}")
    if len(rotation) != dim:
        raise ValueError(f"{where}: {key} is {dim}, but the rotation is {len(rotation)} x "
                         f"{len(rotation[0]) if rotation else 0}")


def calibration_from_document(data: Any, where: str, registration: str = "corrected", *,
                              parent_frame: Optional[str] = None,
                              child_frame: Optional[str] = None, unit: Optional[str] = None,
                              mtime: Optional[float] = None,
                              note: Callable[[str], None] = lambda _line: None) -> Calibration:
    """The calibration in a node snapshot (``format`` ``rbc_registration calibration 1``) or a
    ``register`` / ``evaluate --json`` report.

    :param where: the file name, for messages.
    :param parent_frame: the destination frame (default: the snapshot's or the report's
        ``destination_frame``; a report that records none: ``world``, said through ``note``).
    :param child_frame: the working frame (default: the recorded ``working_frame``, or
        ``tracker``, said through ``note``).
    :param unit: the length unit (of ``METRES_PER_UNIT``) of a source that records none; one that
        records its unit (a report's ``unit``, a snapshot's ``units``) is read in it, and a
        different ``unit`` is refused.
    :param mtime: seconds since the epoch for ``created`` of a report (it holds no time).
    :param note: called with one line for each default that stood in for a missing value.
    :raises ValueError: one line naming ``where`` and what is missing or wrong.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{where}: not a JSON object")
    if registration not in REGISTRATIONS:
        raise ValueError(f"{where}: registration must be one of {', '.join(REGISTRATIONS)}, "
                         f"got {registration!r}")
    snapshot = data.get("format") == SNAPSHOT_FORMAT
    notes: list[str] = []   # said once the calibration is built, not before an error
    source = (_snapshot_source(data, where, unit, parent_frame, child_frame) if snapshot else
              _report_source(data, where, unit, parent_frame, child_frame, mtime, notes))
    scale, parent, child, created_s, n_fiducials, sigma_l, same_fits = source
    reg = _get(data, registration, where)
    sigma = None if data.get("sigma") is None else _number(data, "sigma", where)
    figures = _document_decision(data, where, scale)
    at = f"{where}: {registration}"
    rows = _get(reg, "rotation", at)
    if not isinstance(rows, list) or not all(isinstance(r, list) for r in rows):
        raise ValueError(f"{at}: rotation: must be a list of rows of numbers")
    rotation = [[check_number(f"{at}: rotation[{i}][{k}]", v) for k, v in enumerate(row)]
                for i, row in enumerate(rows)]
    _check_dimension(data, where, "dimension" if snapshot else "dim", rotation)
    translation = [scale * v for v in _numbers(reg, "translation", at)]
    fre_rms = scale * _number(reg, "fre_rms", at)
    if isinstance(n_fiducials, bool) or not isinstance(n_fiducials, int):
        raise ValueError(f"{where}: n_fiducials: must be an integer, got {n_fiducials!r}")
    # The uncorrected registration's held-out error is the rigid figure of either registration
    # when both were fitted to the same fiducials (they then agree to second order in the bias,
    # core/rigid/restoration); of a corrected one fitted to other fiducials it is not known.
    rigid = figures.uncorrected if registration == UNCORRECTED or same_fits else None
    try:
        cal = calibration_from_registration(
            rotation, translation,
            parent_frame=parent, child_frame=child, registration=registration,
            fre_rms=fre_rms,
            decision=figures.decision, sigma=None if sigma is None else scale * sigma,
            sigma_l=[scale * v for v in sigma_l], expected_tre_rigid=rigid,
            expected_tre_with_corrections=figures.with_corrections, n_fiducials=n_fiducials,
            clock=lambda: created_s)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    for line in notes:
        note(line)
    return cal


class _Source(NamedTuple):
    """What a snapshot or a report gives beside its registrations (lengths x ``scale`` in m)."""

    scale: float
    parent: str
    child: str
    created_s: float
    n_fiducials: Any
    sigma_l: list
    same_fits: bool     # both registrations fitted to the same fiducials


def _snapshot_source(data: Mapping[str, Any], where: str, unit: Optional[str],
                     parent_frame: Optional[str], child_frame: Optional[str]) -> _Source:
    """A node snapshot's frames, stamp, fiducial count and sigma_L (its units: metres)."""
    if not data.get("model_valid"):
        raise ValueError(f"{where}: the snapshot holds no model ({data.get('error', '')})")
    scale = _unit_scale(data, where, "units", unit, default="m")   # the format's metres
    parent = parent_frame or _get(data, "destination_frame", where)
    child = child_frame or _get(data, "working_frame", where)
    stamp_ns = _number(data, "stamp_ns", where)
    if not 0 <= stamp_ns <= _LAST_STAMP_NS:
        raise ValueError(f"{where}: stamp_ns: out of range (0 to the year 9999), got "
                         f"{stamp_ns:g}")
    ids = _get(data, "fiducial_ids", where)
    if not isinstance(ids, list):
        raise ValueError(f"{where}: fiducial_ids: must be a list, got {type(ids).__name__}")
    # the node fits both registrations to all fiducials
    return _Source(scale, parent, child, stamp_ns * 1e-9, len(ids),
                   _numbers(data, "sigma_l", where), True)


def _report_source(data: Mapping[str, Any], where: str, unit: Optional[str],
                   parent_frame: Optional[str], child_frame: Optional[str],
                   mtime: Optional[float], notes: list[str]) -> _Source:
    """A ``register`` / ``evaluate`` report's unit, frames (the node's defaults when it records
    none, said in ``notes``), fiducial count and sigma_L; ``created`` from ``mtime`` or now."""
    scale = _unit_scale(data, where, "unit", unit)
    parent = parent_frame or data.get("destination_frame")
    child = child_frame or data.get("working_frame")
    assumed = [f"{option} {default}" for option, frame, default in
               (("--parent-frame", parent, "world"), ("--child-frame", child, "tracker"))
               if frame is None]
    if assumed:
        notes.append(f"{where} records no frames (a register report, or an evaluate report "
                     f"of an earlier version): {' '.join(assumed)} assumed (the node's "
                     f"defaults); give the option to say which")
    # an evaluate report (it has "bag") is the node's model: both fitted to all fiducials
    same_fits = "bag" in data or ("uncorrected_fit" in data and "corrected_fit" in data
                                  and data["uncorrected_fit"] == data["corrected_fit"])
    return _Source(scale, parent or "world", child or "tracker",
                   time.time() if mtime is None else mtime, _get(data, "n_fiducials", where),
                   _numbers(data, "sigma_L", where), same_fits)


def check_matches(cal: Calibration, where: str, working_frame: str, destination_frame: str,
                  dimension: int) -> None:
    """Refuse a calibration of other frames or another dimension than the node's.

    :raises ValueError: naming ``where``, the field and both values.
    """
    for name, got, want in (("parent_frame", cal.parent_frame, destination_frame),
                            ("child_frame", cal.child_frame, working_frame),
                            ("dimension", cal.dimension, dimension)):
        if got != want:
            raise ValueError(f"{where}: {name} is {got!r}, but the node has {want!r} "
                             f"(destination_frame / working_frame / dimension)")
