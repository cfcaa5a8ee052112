"""Offline evaluation of a recorded cell: recorded inputs go through the node's own ingestion
(:class:`~.ingest.Ingest`: stamp pairing, validation, id assignment, outlier rejection, the
shared ``FiducialAccumulator``) and model builder (:func:`~.state.build_state`), exactly as
``registration_node`` would process them. The report around it is
:mod:`rbc_registration.io.evaluation`.

No rclpy, no message packages. Lengths in metres as recorded (REP 103).
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, NamedTuple, Optional, Sequence, Union

import numpy as np
from numpy.typing import NDArray

from ..core.errors import InputError
from ..core.measurements.accumulator import FiducialAccumulator, FiducialSet
from ..core.constants import WORKING
from ..core.model import RbcModel
from ..core.measurements.pairing import StampPairer
from ..core.measurements.records import RejectedMeasurement, quote
from ..core.measurements.sessions import SessionPlan
from .ingest import Ingest, PairArgs
from .inputs import PairMessage, PointMessage
from .settings import SPECS, Settings
from .state import build_state, with_warning
from .targets import Targets, first_conflict, mean_by_id, with_truth

Input = Union[PairMessage, PointMessage]


class EvaluationError(InputError):
    """Recorded data that give no model or unusable targets; the message says why."""


class Accumulated(NamedTuple):
    """The fiducials after ingestion, rejections by reason, the log lines of the rejections,
    the warnings about point stamps that repeat, the first rejection's message by reason, and in
    2D the warning for z that differ between the frames (:meth:`.ingest.Ingest.
    dropped_z_warning`, "" when none), and the sessions the measurements were in."""

    fiducials: FiducialSet
    rejected: dict[str, int]
    log_lines: tuple[str, ...]
    stamp_warnings: tuple[str, ...]
    first_rejections: dict[str, str]
    dropped_z: str = ""
    session_names: tuple[str, ...] = ()


class OfflineModel(NamedTuple):
    """The outcome of :func:`evaluate_inputs`; ``warning``: the model state's (a fiducial whose
    held-out error stands out, :attr:`~.state.ModelState.warning`; "" when none)."""

    model: RbcModel
    fiducials: FiducialSet
    settings: Settings
    targets: Optional[Targets]
    rejected: dict[str, int]
    notes: tuple[str, ...]
    warning: str = ""
    #: The first rejection's message by reason (as :attr:`Accumulated.first_rejections`).
    first_rejections: tuple[tuple[str, str], ...] = ()


class _Log:
    """Collects what the node would log (rejections) instead of printing every line."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def warning(self, text: str) -> None:
        self.lines.append(text)

    error = info = warning


def infer_dimension(inputs: Sequence[Input], targets: Sequence[PairMessage] = (),
                    working_frame: str = "", destination_frame: str = "") -> tuple[int, str]:
    """2 when every z coordinate of the measurements is exactly 0, else 3.

    Only the measurements the node would take count: in ``working_frame`` and
    ``destination_frame`` (default: the parameters' defaults; an empty frame id is the
    parameter's, as the node takes it) with finite z; the targets never decide (dimension 2
    passes a target's z through), and a message in another frame, which is rejected, does not
    either.

    :return: the dimension and a sentence saying why.
    """
    working_frame = working_frame or SPECS["working_frame"].default
    destination_frame = destination_frame or SPECS["destination_frame"].default
    zs = []
    for m in inputs:
        if isinstance(m, PointMessage):
            frame = working_frame if m.stream == WORKING else destination_frame
            if (m.frame_id or frame) == frame:
                zs.append(m.xyz[2])
        elif (m.working_frame or working_frame) == working_frame and \
                (m.destination_frame or destination_frame) == destination_frame:
            zs += [m.working[2], m.destination[2]]
    zs = [z for z in zs if math.isfinite(z)]
    target_z = any(z != 0.0 for m in targets for z in (m.working[2], m.destination[2])
                   if math.isfinite(z))
    if zs and all(z == 0.0 for z in zs):
        return 2, ("dimension 2: every z of the measurements is 0"
                   + (" (the targets' z is passed through)" if target_z else "")
                   + " (--dim 3 to override)")
    return 3, "dimension 3: the measurements have non-zero z (--dim 2 to register x, y only)"


def settings_for(dimension: int, overrides: Mapping[str, Any]) -> Settings:
    """The node's parameters (defaults) with ``dimension`` and ``overrides`` applied.

    :raises ValueError: naming an unknown or invalid parameter.
    """
    return Settings.from_mapping({**overrides, "dimension": dimension})


def accumulate(inputs: Sequence[Input], settings: Settings) -> Accumulated:
    """Feed the inputs, in recorded order, through the node's ingestion."""
    s = settings
    # every stamp kept for the duplicate rule: the recording is in memory anyway, and a bag
    # recorded twice brings each copy after all of a fiducial's repeats
    acc = FiducialAccumulator(s.dimension, s.working_frame, s.destination_frame, s.merge_radius,
                              s.outlier_distance, duplicate_window=None)
    log = _Log()
    ingest = Ingest(acc, StampPairer(s.pair_slop, s.point_buffer), None, log)
    for m in inputs:
        if m.stamp_error:        # rejected as the node rejects the message
            what = (f"FiducialPair {quote(m.fiducial_id)}" if isinstance(m, PairMessage)
                    else f"{m.stream} point")
            ingest.reject(RejectedMeasurement("malformed", f"{what}: {m.stamp_error}"))
        elif isinstance(m, PairMessage):
            ingest.measurement(PairArgs(m.fiducial_id or None, m.working, m.destination,
                                        m.working_frame, m.destination_frame, m.stamp_s,
                                        m.group, m.session))
        else:
            ingest.point(m.stream, m.xyz, m.frame_id, m.stamp_s)
    return Accumulated(ingest.fiducial_set(), dict(acc.rejected), tuple(log.lines),
                       tuple(ingest.stamp_warnings.values()), dict(ingest.first_rejections),
                       ingest.dropped_z_warning(), acc.sessions.names)


def recorded_targets(targets: Sequence[PairMessage], settings: Settings,
                     source: str = "input", sessions: Optional[SessionPlan] = None,
                     session_names: Sequence[str] = ()) -> Optional[Targets]:
    """Targets from recorded ``FiducialPair`` targets, repeats of an id averaged (first-seen
    order); the truth of an id is the mean of its messages with a finite destination point, a
    row of NaN when it has none, and ``None`` when no target has truth.

    Sessions follow the rule of TARGETS.csv's ``session`` column: a message's ``session``
    names the session its working point was measured in, an empty one continues the previous
    target message's (the first ones: the reference session); points of a moved session are
    mapped into the reference's frame (``sessions``, the fiducials' plan) before they are
    checked and averaged.

    :param source: names the data in error messages (e.g. the bag's path); every message also
        names the target's id and the target message's number (from 1, in bag order).
    :param sessions: the fiducials' session plan (:attr:`FiducialSet.sessions`); ``None``: one
        session, every target in it.
    :param session_names: the sessions the fiducials were measured in (with one session, a
        target may name it).

    :raises EvaluationError: for a target in another frame than the node's, a non-finite
        working point, a repeat farther than ``outlier_distance`` from the mean of its id's
        earlier messages in either frame (:func:`.targets.first_conflict`), or a session the
        fiducials do not have or kept apart.
    """
    if not targets:
        return None
    d = settings.dimension
    ids = [m.fiducial_id or f"target-{k}" for k, m in enumerate(targets)]

    def which(k: int) -> str:
        return f"{source}: target {ids[k]!r} (target message {k + 1} of {len(targets)})"

    for k, m in enumerate(targets):
        for name, got, want in (("working", m.working_frame, settings.working_frame),
                                ("destination", m.destination_frame, settings.destination_frame)):
            if got and got != want:
                raise EvaluationError(f"{which(k)}: {name} frame {got!r}, expected {want!r}")
    work = [m.working[:d] for m in targets]
    dest = [m.destination[:d] for m in targets]
    bad = np.flatnonzero(~np.isfinite(np.asarray(work, dtype=float)).all(axis=1))
    if bad.size:
        raise EvaluationError(f"{which(int(bad[0]))}: working point has NaN or inf "
                              f"({bad.size} such target message(s))")
    labels = target_sessions(targets, sessions, session_names, which)
    if labels:
        moved, _ = sessions.apply(work, labels)
        work = [tuple(p) for p in moved.tolist()]
    limit = settings.outlier_distance
    known_rows = np.flatnonzero(with_truth(dest, len(dest)))
    for rows, name, points in ((range(len(ids)), "working", work),
                               (known_rows, "destination", dest)):
        conflict = first_conflict([ids[k] for k in rows], [(name, [points[k] for k in rows],
                                                             limit, "outlier_distance")])
        if conflict is not None:
            raise EvaluationError(f"{which(rows[conflict.row])}: conflicts with the earlier "
                                  f"repeats of its id: {conflict.message}")
    unique, (working,) = mean_by_id(ids, work)
    if not known_rows.size:
        return Targets(unique, working, None, "bag")
    known, (means,) = mean_by_id([ids[k] for k in known_rows], [dest[k] for k in known_rows])
    truth = np.full_like(working, np.nan)
    row = {t: k for k, t in enumerate(unique)}
    truth[[row[t] for t in known]] = means
    return Targets(unique, working, truth, "bag")


def target_sessions(targets: Sequence[PairMessage], plan: Optional[SessionPlan],
                    names: Sequence[str], which: Callable[[int], str]) -> list[str]:
    """Each target message's session (:func:`recorded_targets`); [] when the fiducials have one
    session (``plan`` ``None``), whose name (``names``) a target may give.

    :raises EvaluationError: a session the fiducials do not have, or one kept apart.
    """
    if plan is None:
        for k, m in enumerate(targets):
            if m.session and m.session not in names:
                raise EvaluationError(f"{which(k)}: session {m.session!r} is not the "
                                      f"fiducials' session "
                                      f"({', '.join(map(repr, names)) or 'none'})")
        return []
    out, session = [], plan.reference
    for k, m in enumerate(targets):
        session = m.session or session
        try:
            motion = plan.motion(session)
        except KeyError:
            raise EvaluationError(f"{which(k)}: session {session!r} is not among the "
                                  f"fiducials' sessions "
                                  f"({', '.join(repr(m.session) for m in plan.motions)})"
                                  ) from None
        if motion.kept_apart:
            raise EvaluationError(f"{which(k)}: session {session!r} was kept apart (too few "
                                  "fiducials in common with the others): its targets cannot "
                                  "be placed")
        out.append(session)
    return out


def truth_note(ids: Sequence[str], destination: Optional[NDArray[np.float64]]) -> str:
    """The note on targets without truth ("" when every target has truth).

    :param ids: the targets' ids; :param destination: their truth (K, d), a row of NaN for a
        target without; ``None``: none has.
    """
    if destination is None:
        return "targets have no truth: TRE not computed"
    blind = [t for t, has in zip(ids, with_truth(destination, len(ids))) if not has]
    if not blind:
        return ""
    return (f"{len(blind)} of {len(ids)} targets have no truth, e.g. {blind[0]!r}: their TRE "
            f"is not computed, the TRE summary is over the other {len(ids) - len(blind)}")


def evaluate_inputs(inputs: Sequence[Input], settings: Settings,
                    recorded: Sequence[PairMessage] = (),
                    targets: Union[Targets, Callable[[Optional[SessionPlan]], Targets],
                                   None] = None,
                    source: str = "input") -> OfflineModel:
    """Accumulate ``inputs`` and build the node's model; the targets to report are ``targets``
    or else the ``recorded`` ones (if any).

    :param targets: the targets, or a function of the fiducials' session plan giving them
        (a TARGETS.csv with a ``session`` column, mapped into the reference session's frame).
    :param source: names the data in error messages (e.g. the bag's path).
    :raises EvaluationError: when no model can be built (too few fiducials, degenerate
        geometry), naming ``source`` and the first rejection.
    """
    acc = accumulate(inputs, settings)
    if acc.rejected.get("conflict"):
        # the node rejects the later message live; a recording is refused (the accumulator's
        # duplicate rule): which of the two is right is not known
        raise EvaluationError(f"{source}: {acc.first_rejections['conflict']}; remove the "
                              "wrong message"
                              + (f" ({acc.rejected['conflict']} such message(s))"
                                 if acc.rejected["conflict"] > 1 else ""))
    state = build_state(acc.fiducials, settings, 0)
    if state.model is None:
        raise EvaluationError(f"{source}: no model: {state.error}"
                              + (f" ({sum(acc.rejected.values())} measurement(s) rejected, e.g. "
                                 f"{acc.log_lines[0]})" if acc.log_lines else ""))
    if callable(targets):
        targets = targets(acc.fiducials.sessions)
    if targets is None:
        targets = recorded_targets(recorded, settings, source, acc.fiducials.sessions,
                                   acc.session_names)
    note = truth_note(targets.ids, targets.destination) if targets is not None else ""
    notes = (note,) if note else ()
    notes += acc.stamp_warnings
    state = with_warning(state, acc.dropped_z)
    return OfflineModel(state.model, state.fiducials, settings, targets, acc.rejected, notes,
                        state.warning, tuple(acc.first_rejections.items()))
