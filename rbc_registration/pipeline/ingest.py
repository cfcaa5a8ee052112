"""Thread-safe ingestion, shared by ``registration_node`` and offline ``evaluate``: pairing,
validation (the shared
:class:`~rbc_registration.core.measurements.accumulator.FiducialAccumulator`),
journaling before a measurement counts, rejection logging, and the counters the node reports.
No rclpy, no message packages: the node converts messages to :class:`PairArgs` and passes its
logger in.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Mapping, NamedTuple, Optional, Sequence

from ..core.measurements.accumulator import (FiducialAccumulator, FiducialSet, Measurement, Record,
                                RejectedMeasurement)
from ..core.constants import DESTINATION, WORKING
from ..core.measurements.pairing import DroppedPoint, PointPair, StampPairer
from ..core.rigid.scale import dropped_z_warning
from .checkpoint import checkpoint_text, replay, resume
from .journal import Journal
from .residuals import FiducialSummary
from .settings import Settings

#: Every rejection of a reason is logged up to this count, then at most once per second.
LOG_EVERY_UP_TO = 20


class PairArgs(NamedTuple):
    """A fiducial pair as the arguments of ``FiducialAccumulator.prepare`` (points (3,)):
    ``fiducial_id`` ``None`` means "assign by proximity"; stamp in seconds; ``group`` and
    ``session`` as in ``FiducialPair`` (empty: its own group, the current session)."""

    fiducial_id: Optional[str]
    working_xyz: Sequence[float]
    destination_xyz: Sequence[float]
    working_frame: str
    destination_frame: str
    stamp_s: float
    group: str = ""
    session: str = ""


def repeated_stamps(stream: str, stamp_s: float) -> str:
    """The warning (once per stream) for point stamps that repeat."""
    return (f"{stream} point stamps repeat ({stamp_s:.9f} s twice in a row): pairing by stamp "
            "then goes by arrival order, and one lost message pairs every later point wrongly; "
            "stamp each measurement, or publish FiducialPair")


def _point_key(xyz: Any, stamp_s: float) -> Optional[tuple[tuple[float, ...], float]]:
    """A point as the pairer keeps it (coordinates, stamp), to compare; ``None`` if unusable."""
    try:
        return tuple(float(v) for v in xyz), float(stamp_s)
    except (TypeError, ValueError):
        return None


class _Held(NamedTuple):
    """A rejection from the pairing held back while ``~/take_sample`` may record its point."""

    key: tuple[tuple[float, ...], float]
    reason: str
    message: str
    received_s: float


#: The :attr:`_Outcome.reason` of a valid measurement the journal could not write.
JOURNAL_FAILED = "journal"


class _Outcome(NamedTuple):
    """One measurement's fate: the accepted ``record``, or ``None`` with the rejection's
    ``reason`` (a ``REJECT_REASONS`` code, or :data:`JOURNAL_FAILED`) and ``why`` (a line)."""

    record: Optional[Measurement]
    reason: str = ""
    why: str = ""


class Counters(NamedTuple):
    """Accumulator counters at one moment (read under the ingestion lock)."""

    n_measurements: int
    rejected: Mapping[str, int]
    n_disabled: int
    n_journal_failures: int = 0
    journal_error: str = ""
    n_replay_skipped: int = 0


class Ingest:
    """The node's measurement store: all methods may be called from any thread.

    :param accumulator: validates, assigns ids and accumulates measurements.
    :param pairer: pairs ``~/working_point`` and ``~/destination_point`` by stamp.
    :param journal: appends each accepted record before it counts; ``None``: no persistence.
    :param logger: an rclpy-style logger (``warning``, ``error``, ``info``).
    :param clock: the time now [s] (the node clock) for the accumulator's ``max_stamp_age``
        check; ``None``: stamps are not checked against a clock (offline evaluation).
    :param log_clock: monotonic seconds, for the rate limit of rejection log lines.
    :param hold_s: how long [s, on ``clock``] a point dropped from the pairing while it is the
        latest point of its stream is held back before it counts as rejected
        (``sample_max_age`` in point_mode pair, as ``~/take_sample`` may still record it); 0:
        counted at once.
    """

    def __init__(self, accumulator: FiducialAccumulator, pairer: StampPairer,
                 journal: Optional[Journal], logger: Any,
                 clock: Optional[Callable[[], float]] = None,
                 log_clock: Callable[[], float] = time.monotonic, hold_s: float = 0.0) -> None:
        self._acc = accumulator
        self._pairer = pairer
        self._journal = journal
        self._log = logger
        self._clock = clock
        self._log_clock = log_clock
        self._lock = threading.Lock()
        self._last_log: dict[str, float] = {}
        #: The warnings logged for point stamps that repeat (one per stream at most).
        self.stamp_warnings: dict[str, str] = {}
        #: The message of the first rejection of each reason (since the last reset).
        self.first_rejections: dict[str, str] = {}
        self.journal_error = ""      # the last journal write error; "" once a write succeeds
        self.n_journal_failures = 0  # records refused because the journal could not be written
        self.n_replay_skipped = 0    # journal lines skipped on replay (corrupt or invalid)
        self._replay_errors = 0      # records of the journal that failed the live checks
        #: How the last :meth:`restore` went: "" (the journal replayed whole), or which records
        #: came from the checkpoint and how many of the journal's tail were replayed.
        self.restore_summary = ""
        # In 2D: the 3D points of each fiducial's first measurement accepted by this process
        # (the accumulator and the journal keep x, y only), for dropped_z_warning.
        self._first_xyz: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {}
        self.hold_s = hold_s
        # Per stream: the latest point and when it arrived, its held-back rejection, and the
        # point ~/take_sample recorded last (never counted as rejected).
        self._latest_point: dict[str, tuple[Any, float]] = {}
        self._held: dict[str, _Held] = {}
        self._sampled: dict[str, Any] = {}

    def restore(self) -> int:
        """Replay the journal (if any) into the accumulator; return the measurements restored.
        With a checkpoint that matches the journal (:mod:`.checkpoint`) its sums are loaded and
        only the journal's tail is replayed; a checkpoint that is stale, corrupt or of another
        setup is named in a warning and the journal replayed whole. Lines that are corrupt
        (checksum), unparsable or fail the live validation are skipped, logged and counted
        (:attr:`n_replay_skipped`).

        :raises journal.JournalMismatch: when the journal belongs to another setup.
        """
        if self._journal is None:
            return 0
        resumed, skipped_before = resume(self._acc, self._journal, self._log)
        if resumed is None:
            records, warnings = self._journal.load()
        else:
            records, warnings = resumed
            total = self._journal.position().records
            self.restore_summary = (f"the sums of the first {total - len(records)} records from "
                                    f"the checkpoint, the journal's last {len(records)} replayed")
        for warning in warnings:
            self._log.warning(warning)
        with self._lock:
            if resumed is None:
                errors = self._acc.restore(records)
            else:
                errors = replay(self._acc, records, self._journal.position().records
                                - len(records))
            for error in errors:
                self._log.warning(f"journal: {error}")
            self._replay_errors = len(errors)
            self.n_replay_skipped = self._journal.n_skipped + len(errors) + skipped_before
            if self.n_replay_skipped:
                self._log.warning(f"journal replay skipped {self.n_replay_skipped} record(s); "
                                  f"restored {self._acc.n_measurements} measurements")
            return self._acc.n_measurements

    def checkpoint_text(self) -> str:
        """The checkpoint (:mod:`.checkpoint`) of the accumulator at the journal's end, taken
        under the lock ("" without a journal).

        :raises ValueError: when a value cannot be written (never expected).
        """
        with self._lock:
            if self._journal is None:
                return ""
            return checkpoint_text(self._acc, self._journal.header,
                                   self._journal.position(self._replay_errors))

    def _rejected(self, exc: RejectedMeasurement) -> None:
        self.first_rejections.setdefault(exc.reason, exc.message)
        count = self._acc.rejected[exc.reason]
        now = self._log_clock()
        if count <= LOG_EVERY_UP_TO or now - self._last_log.get(exc.reason, 0.0) >= 1.0:
            self._last_log[exc.reason] = now
            self._log.warning(f"rejected measurement ({exc.reason}, {count} so far): "
                              f"{exc.message}")

    def _accept(self, record: Record) -> bool:
        """Journal (flushed) then commit; False when the journal cannot be written."""
        if self._journal is not None:
            try:
                self._journal.append(record)
            except OSError as exc:
                self.journal_error = str(exc)
                self.n_journal_failures += 1
                what = "measurement" if isinstance(record, Measurement) else "enable change"
                self._log.error(f"journal write failed, {what} NOT accepted "
                                f"({self.n_journal_failures} so far): {exc}")
                return False
            self.journal_error = ""
        self._acc.commit(record)
        return True

    def _measurement_locked(self, args: PairArgs) -> _Outcome:
        """Validate, journal and count one measurement."""
        now = self._clock() if self._clock is not None and self._acc.max_stamp_age > 0 else None
        try:
            record = self._acc.prepare(*args[:6], now_s=now,
                                       group=args[6] if len(args) > 6 else "",
                                       session=args[7] if len(args) > 7 else "")
        except RejectedMeasurement as exc:
            self._rejected(exc)
            return _Outcome(None, exc.reason, f"rejected ({exc.reason}): {exc.message}")
        if not self._accept(record):
            return _Outcome(None, JOURNAL_FAILED,
                            f"journal write failed, not accepted: {self.journal_error}")
        working, destination = args[1], args[2]         # PairArgs or a plain tuple
        if (self._acc.dimension == 2 and record.fiducial_id not in self._first_xyz
                and len(working) == 3 and len(destination) == 3):
            self._first_xyz[record.fiducial_id] = (tuple(map(float, working)),
                                                   tuple(map(float, destination)))
        return _Outcome(record)

    def reject(self, exc: RejectedMeasurement) -> None:
        """Count and log an input rejected before it could be validated as a measurement
        (e.g. a message whose stamp is not a time)."""
        with self._lock:
            self._rejected(self._acc.reject(exc.reason, exc.message))

    def take(self, args: PairArgs) -> tuple[Optional[Measurement], str]:
        """One measurement (e.g. ``~/take_sample``): ``(the accepted record, "")`` or
        ``(None, the reason it was not accepted)``."""
        with self._lock:
            outcome = self._measurement_locked(args)
            return outcome.record, outcome.why

    def measurement(self, args: PairArgs) -> bool:
        """One FiducialPair measurement; True when accepted (journaled and counted)."""
        with self._lock:
            return self._measurement_locked(args).record is not None

    def point(self, stream: str, xyz: Any, frame_id: str, stamp_s: float,
              recorded: Optional[list[PointPair]] = None) -> list[PointPair]:
        """One ``~/working_point`` / ``~/destination_point``: the pairs it completed that were
        accepted (empty: none; truthy when the model must be rebuilt). Unpairable points are
        rejected as malformed, ambiguous ones (:mod:`~rbc_registration.core.measurements.pairing`)
        as
        ambiguous, a copy of a point seen before as a duplicate.

        :param recorded: when given, extended by the pairs that are recorded now: the accepted
            ones and those rejected as a ``duplicate`` of a recorded measurement (so that
            ``~/take_sample`` does not record their points again).
        """
        with self._lock:
            key = _point_key(xyz, stamp_s)
            held = self._held.get(stream)
            if held is not None and held.key != key:    # a newer point: it can't be sampled
                self._release_locked(stream)
            self._release_expired_locked()
            self._latest_point[stream] = (key, self._clock() if self._clock else 0.0)
            try:
                result = self._pairer.add(stream, xyz, frame_id, stamp_s)
            except ValueError as exc:
                self._rejected(self._acc.reject("malformed", str(exc)))
                return []
            for dropped in result.dropped:
                self._dropped_locked(dropped)
            if result.repeated and stream not in self.stamp_warnings:
                self.stamp_warnings[stream] = repeated_stamps(stream, stamp_s)
                self._log.warning(self.stamp_warnings[stream])
            accepted = []
            for pair in result.pairs:
                outcome = self._measurement_locked(PairArgs(
                    None, pair.working.xyz, pair.destination.xyz, pair.working.frame_id,
                    pair.destination.frame_id, pair.stamp_s))
                if outcome.record is not None:
                    accepted.append(pair)
                if recorded is not None and (outcome.record is not None
                                             or outcome.reason == "duplicate"):
                    recorded.append(pair)
            return accepted

    def _dropped_locked(self, dropped: DroppedPoint) -> None:
        """Count a point the pairing dropped; not the point ``~/take_sample`` recorded last,
        and, while ``~/take_sample`` may still record it (the latest point of its stream,
        within :attr:`hold_s`), held back (:meth:`_release_locked`)."""
        reason = ("ambiguous" if dropped.ambiguous else
                  "duplicate" if dropped.duplicate else "malformed")
        message = f"unpaired {dropped.stream} point dropped: {dropped.reason}"
        key = _point_key(dropped.point.xyz, dropped.point.stamp_s)
        if self._sampled.get(dropped.stream) == key:
            return
        latest = self._latest_point.get(dropped.stream)
        if (self.hold_s > 0 and self._clock is not None and not dropped.duplicate
                and latest is not None and latest[0] == key):
            self._held[dropped.stream] = _Held(key, reason, message, latest[1])
            return
        self._rejected(self._acc.reject(reason, message))

    def _release_locked(self, stream: str) -> None:
        """Count the held-back rejection of ``stream``."""
        held = self._held.pop(stream)
        self._rejected(self._acc.reject(held.reason, held.message))

    def _release_expired_locked(self) -> None:
        """Count the held-back rejections older than :attr:`hold_s` (``~/take_sample`` calls
        their points stale)."""
        if not self._held or self._clock is None:
            return
        now = self._clock()
        for stream in [s for s, h in self._held.items() if now - h.received_s > self.hold_s]:
            self._release_locked(stream)

    def sampled(self, working_xyz: Any, working_stamp_s: float, destination_xyz: Any,
                destination_stamp_s: float) -> None:
        """``~/take_sample`` recorded these points (point_mode pair): neither is counted as
        rejected by the pairing (a held-back rejection is forgotten, a later drop not
        counted), and the working point leaves the pairing, so that its stamp partner
        arriving later does not record it again."""
        with self._lock:
            for stream, key in ((WORKING, _point_key(working_xyz, working_stamp_s)),
                                (DESTINATION, _point_key(destination_xyz, destination_stamp_s))):
                self._sampled[stream] = key
                if stream in self._held and self._held[stream].key == key:
                    del self._held[stream]
            self._pairer.discard(WORKING, working_xyz, working_stamp_s)

    def discard_point(self, stream: str, xyz: Any, stamp_s: float) -> bool:
        """Drop a buffered, unpaired point recorded otherwise (``~/take_sample`` in point_mode
        pair), so that it is not recorded again when its partner arrives."""
        with self._lock:
            return self._pairer.discard(stream, xyz, stamp_s)

    def set_enabled(self, fiducial_id: str, enabled: bool) -> tuple[bool, str]:
        """Enable or disable a fiducial (journaled); returns (success, message)."""
        with self._lock:
            try:
                change = self._acc.prepare_enabled(fiducial_id, enabled)
            except KeyError as exc:
                return False, str(exc.args[0])
            word = "enabled" if enabled else "disabled"
            if self._acc.is_enabled(fiducial_id) == bool(enabled):
                return True, f"fiducial {fiducial_id!r} was already {word}"
            if not self._accept(change):
                return False, f"journal write failed: {self.journal_error}"
            return True, f"fiducial {fiducial_id!r} {word}; the model is rebuilt after debounce"

    def reset(self) -> tuple[bool, str]:
        """Forget all measurements; the journal is archived first. Returns (success,
        message): when archiving fails nothing is forgotten (the journal would bring the
        measurements back on the next start), and the journal stays open."""
        with self._lock:
            archived = None
            if self._journal is not None:
                try:
                    archived = self._journal.archive()
                except OSError as exc:
                    return False, (f"nothing forgotten: archiving the journal (and snapshot) "
                                   f"failed: {exc}")
            self._acc.clear()
            self._pairer.clear()
            self._latest_point.clear()
            self._held.clear()
            self._sampled.clear()
            self._first_xyz.clear()
            self.first_rejections.clear()
            self.n_journal_failures = 0
            self._replay_errors = 0
            self.journal_error = ""
            if self._journal is None:
                return True, "all measurements forgotten"
            return True, f"all measurements forgotten; journal archived as {archived}"

    def configure(self, settings: Settings) -> None:
        """Apply changed dynamic parameters (pairing slop, merge radius, outlier distance,
        stamp age)."""
        with self._lock:
            self._pairer.slop = settings.pair_slop
            self._acc.merge_radius = settings.merge_radius
            self._acc.outlier_distance = settings.outlier_distance
            self._acc.max_stamp_age = settings.max_stamp_age
            self.hold_s = settings.sample_max_age if settings.point_mode == "pair" else 0.0

    def fiducial_set(self) -> FiducialSet:
        """The enabled fiducials now (for a model rebuild)."""
        with self._lock:
            return self._acc.fiducial_set()

    def current_session(self) -> str:
        """The session a measurement without one goes to now (:mod:`~rbc_registration.core.
        session_sums`): the one targets are measured in. Without the lock (one attribute
        read), so that ``~/correct_target`` never waits for an ingestion batch."""
        return self._acc.sessions.resolve("")

    def dropped_z_warning(self) -> str:
        """In 2D, :func:`~rbc_registration.core.rigid.scale.dropped_z_warning` (lengths in metres)
        of
        the enabled fiducials' first measurements accepted since this process started (or the
        last reset): the journal keeps x, y only, so measurements restored from it are not
        looked at. "" when there is nothing to say."""
        with self._lock:
            first = [xyz for fid, xyz in self._first_xyz.items() if self._acc.is_enabled(fid)]
        if self._acc.dimension != 2 or not first:
            return ""
        return dropped_z_warning([w for w, _ in first], [d for _, d in first], "m") or ""

    def disabled_points(self) -> dict[str, tuple[float, ...]]:
        """The mean destination-frame point of each disabled fiducial (for ``~/markers``)."""
        with self._lock:
            return {fid: mean_d for fid, (_n, enabled, _mw, _m2w, mean_d, _m2d)
                    in self._acc.state_digest() if not enabled}

    def fiducial_summaries(self) -> list[FiducialSummary]:
        """Every fiducial (enabled and disabled) with its count and mean points, in the order
        first measured (for ``~/get_fiducials``)."""
        with self._lock:
            return [FiducialSummary(fid, n, enabled, tuple(mean_w), tuple(mean_d))
                    for fid, (n, enabled, mean_w, _m2w, mean_d, _m2d)
                    in self._acc.state_digest()]

    def counters(self) -> Counters:
        """Measurement and rejection counters now (held-back rejections older than
        :attr:`hold_s` count from here)."""
        with self._lock:
            self._release_expired_locked()
            return Counters(self._acc.n_measurements, dict(self._acc.rejected),
                            self._acc.n_disabled, self.n_journal_failures, self.journal_error,
                            self.n_replay_skipped)

    def close(self) -> None:
        """Close the journal."""
        with self._lock:
            if self._journal is not None:
                self._journal.close()
