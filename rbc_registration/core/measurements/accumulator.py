"""Accumulation of fiducial measurements (working frame, destination frame) into the per-fiducial
means and repeats that :func:`rbc_registration.core.model.build_model` takes.

Shared by the ROS node and the offline bag evaluator: one code path. Pure Python + numpy.

A measurement goes through two steps so that a caller can make it durable in between:
:meth:`FiducialAccumulator.prepare` validates it and assigns its fiducial id (or raises
:class:`RejectedMeasurement`), returning an immutable :class:`Measurement` record;
:meth:`FiducialAccumulator.commit` adds the record. :meth:`FiducialAccumulator.add` does both.
Replaying the committed records (:meth:`FiducialAccumulator.restore`) rebuilds the identical state,
because a record carries the id it was given: replay never re-runs the proximity assignment.
The value rules a measurement must pass (id, stamp, coordinates) are :mod:`.measurement_checks`.

**Duplicates.** A measurement with a stamp (not 0) whose fiducial already holds an accepted
measurement with that stamp is one of two things. With the same points (bit for bit) it is the
same message again (a topic bridged or republished twice, a bag recorded twice): rejected as
``duplicate``, so it does not count as a repeat (it would lower sigma, to 0 for a fiducial
measured once, and make rho infinite). With other points and the same given id it is a
``conflict``: one stamp is one measurement, and which one is right is not known (the later is
rejected; ``evaluate`` refuses the recording). Points without an id join a fiducial by
proximity first and are compared within it, never as a conflict (two points of a fiducial at one
stamp without ids are kept). The live node keeps the last :data:`DUPLICATE_WINDOW` stamps per
fiducial (bounded memory in a long run): an exact copy arriving after that many newer stamps of
the same fiducial is not detected there. ``evaluate`` holds the whole recording anyway and keeps
every stamp (``duplicate_window=None``): a bag recorded twice is caught whatever the repeats.
Unstamped measurements (stamp 0) cannot be told apart and are never duplicates. Journal replay
(:meth:`FiducialAccumulator.restore`) fills the window too, so a
copy arriving after a restart is still a duplicate.

**Groups and sessions.** A measurement may name its fiducial's group (fiducials sharing one
error, :mod:`.groups`): a fiducial keeps the first non-empty group it is given, and a later
measurement with another non-empty group is rejected as ``conflict``. Its session
(:mod:`.session_sums`: sums per fiducial and session, the live bump rule) decides which working
frame it is in; with more than one session :meth:`FiducialAccumulator.fiducial_set` maps the
sessions into the current one's frame (:func:`~.sessions.estimate_sessions`) and leaves out the
sessions kept apart. The outlier check of the working point compares with the fiducial's
repeats in the measurement's own session (a re-stationed tracker moves every working point).
"""

from __future__ import annotations

import math
import re
from typing import Iterable, Optional

import numpy as np
from numpy.typing import ArrayLike

from .checks import (MAX_ID_LENGTH, check_age, check_coords, check_label,
                                 check_new_id, check_record_values, check_stamp)
from ..decision.noise import RepeatStats
from .records import (REJECT_REASONS, EnabledChange, FiducialRepeats, FiducialSet, Measurement,
                      Record, RejectedMeasurement, quote)
from ..repeats import repeat_outlier
from .session_sums import SessionSums

__all__ = ["AUTO_ID_PREFIX", "DUPLICATE_WINDOW", "MAX_ID_LENGTH", "REJECT_REASONS", "EnabledChange",
           "FiducialAccumulator", "FiducialSet", "Measurement", "Record", "RejectedMeasurement"]

#: Stamps kept per fiducial for the duplicate rule (module docstring).
DUPLICATE_WINDOW = 16

#: Ids given to measurements without one are ``auto-0000``, ``auto-0001``, ...
AUTO_ID_PREFIX = "auto-"
_AUTO_ID = re.compile(r"^auto-(\d+)$")


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be {bound} and finite, got {value!r}")
    return v


#: An unknown id's message names at most this many known ids.
KNOWN_IDS_SHOWN = 20


class FiducialAccumulator:
    """Collects measurements per fiducial; validates, assigns ids, rejects outliers.

    :param dimension: 2 (x, y as in the paper; z is dropped) or 3.
    :param working_frame: the only accepted working frame; an empty frame means this one.
    :param destination_frame: the only accepted destination frame; empty means this one.
    :param merge_radius: a measurement without an id joins the nearest fiducial whose mean
        destination point is within this distance (else a new ``auto-NNNN`` fiducial).
    :param outlier_distance: a measurement farther than this from its fiducial's mean of earlier
        repeats (in either frame) is rejected as an outlier; 0 disables the check.
    :param max_stamp_age: a measurement whose stamp is more than this [s] older than ``now_s``
        given to :meth:`prepare`, or more than this ahead of it, is rejected as stale; 0 (or no
        ``now_s``) disables the check.
    :raises ValueError: on a bad dimension, frame or distance.
    """

    def __init__(self, dimension: int, working_frame: str, destination_frame: str,
                 merge_radius: float, outlier_distance: float = 0.0,
                 max_stamp_age: float = 0.0,
                 duplicate_window: Optional[int] = DUPLICATE_WINDOW) -> None:
        if dimension not in (2, 3) or isinstance(dimension, bool):
            raise ValueError(f"dimension must be 2 or 3, got {dimension!r}")
        for name, frame in (("working_frame", working_frame),
                            ("destination_frame", destination_frame)):
            if not isinstance(frame, str) or not frame:
                raise ValueError(f"{name} must be a non-empty string, got {frame!r}")
        self.dimension = int(dimension)
        self.working_frame = working_frame
        self.destination_frame = destination_frame
        self.merge_radius = _positive("merge_radius", merge_radius)
        self.outlier_distance = _positive("outlier_distance", outlier_distance, allow_zero=True)
        self.max_stamp_age = _positive("max_stamp_age", max_stamp_age, allow_zero=True)
        if duplicate_window is not None and (isinstance(duplicate_window, bool)
                                             or int(duplicate_window) != duplicate_window
                                             or duplicate_window < 1):
            raise ValueError(f"duplicate_window must be a positive integer or None, "
                             f"got {duplicate_window!r}")
        #: stamps kept per fiducial for the duplicate rule (``None``: all of them)
        self.duplicate_window = duplicate_window
        self.clear()

    # -- state --------------------------------------------------------------------------------
    def clear(self) -> None:
        """Forget every measurement and reset the counters."""
        self._fiducials: dict[str, FiducialRepeats] = {}
        self._dest_means = np.empty((0, self.dimension))  # row k: mean of fiducial _order[k]
        self._order: list[str] = []
        self._index: dict[str, int] = {}
        self._next_auto = 0
        # per fiducial: stamp -> the points (working + destination, one flat tuple) accepted at
        # that stamp, for the last duplicate_window stamps (insertion order: oldest first). The
        # points themselves, not a hash: Python's float hashes collide (hash(-1.0) == hash(-2.0))
        self._recent: dict[str, dict[float, tuple[tuple[float, ...], ...]]] = {}
        self.n_measurements = 0
        self.rejected = {reason: 0 for reason in REJECT_REASONS}
        self._groups: dict[str, str] = {}           # fiducial -> its first non-empty group
        self._first_stamps: dict[str, float] = {}   # fiducial -> stamp of its first measurement
        self.sessions = SessionSums(self.dimension)

    @property
    def n_rejected(self) -> int:
        """Total rejected measurements (all reasons)."""
        return sum(self.rejected.values())

    @property
    def ids(self) -> tuple[str, ...]:
        """All fiducial ids, enabled or not, in first-seen order."""
        return tuple(self._order)

    def is_enabled(self, fiducial_id: str) -> bool:
        """:raises KeyError: for an unknown id."""
        return self._fiducials[fiducial_id].enabled

    # -- measurements -------------------------------------------------------------------------
    def reject(self, reason: str, message: str) -> RejectedMeasurement:
        """Count a rejection and return the exception describing it (for callers that reject
        before a measurement reaches :meth:`prepare`, e.g. an unpairable point)."""
        self.rejected[reason] += 1
        return RejectedMeasurement(reason, message)

    def prepare(self, fiducial_id: Optional[str], working_xyz: ArrayLike,
                destination_xyz: ArrayLike, working_frame: str = "", destination_frame: str = "",
                stamp_s: float = 0.0, now_s: Optional[float] = None, group: str = "",
                session: str = "") -> Measurement:
        """Validate one measurement and assign its id, without adding it (see :meth:`commit`).

        :param fiducial_id: the fiducial's id; ``None`` or ``""``: assigned by proximity.
        :param working_xyz: the point in the working frame, shape (3,) or (dimension,).
        :param destination_xyz: the same point in the destination frame.
        :param working_frame: frame of ``working_xyz``; ``""`` means :attr:`working_frame`.
        :param destination_frame: frame of ``destination_xyz``; ``""`` means the default.
        :param stamp_s: measurement time [s].
        :param now_s: the clock now [s], for the :attr:`max_stamp_age` check (``None``: no check).
        :param group: the fiducials sharing its error (``""``: its own group).
        :param session: its session (``""``: the current one; module docstring).
        :return: the record to :meth:`commit`.
        :raises RejectedMeasurement: with reason frame, nonfinite, outlier, malformed, stale,
            duplicate or conflict (a stamp measured twice, or another group than the
            fiducial's) (the rejection is counted in :attr:`rejected`).
        """
        try:
            return self._prepare(fiducial_id, working_xyz, destination_xyz, working_frame,
                                 destination_frame, stamp_s, now_s, group, session)
        except RejectedMeasurement as exc:
            self.rejected[exc.reason] += 1
            raise

    def _prepare(self, fiducial_id: Optional[str], working_xyz: ArrayLike,
                 destination_xyz: ArrayLike, working_frame: str, destination_frame: str,
                 stamp_s: float, now_s: Optional[float], group: str = "",
                 session: str = "") -> Measurement:
        if fiducial_id is not None:
            check_new_id(fiducial_id)
        check_label("group", group)
        check_label("session", session)
        for name, got, want in (("working frame", working_frame, self.working_frame),
                                ("destination frame", destination_frame,
                                 self.destination_frame)):
            if not isinstance(got, str):
                raise RejectedMeasurement("malformed", f"{name} must be a string, got {quote(got)}")
            if got and got != want:
                raise RejectedMeasurement("frame", f"{name} must be {want!r}, got {quote(got)}")
        stamp = check_stamp(stamp_s)
        if self.max_stamp_age > 0 and now_s is not None:
            check_age(stamp, float(now_s), self.max_stamp_age)
        w = check_coords("working point", working_xyz, self.dimension)
        d = check_coords("destination point", destination_xyz, self.dimension)
        auto = not fiducial_id
        fid = self._nearest(d) if auto else fiducial_id
        if fid is None:
            fid = self._new_auto_id()
        fiducial = self._fiducials.get(fid)
        if fiducial is not None and stamp != 0:
            self._check_duplicate(fid, stamp, w, d, auto)
        known = self._groups.get(fid, "")
        if group and known and group != known:
            raise RejectedMeasurement(
                "conflict", f"fiducial {quote(fid)} is in group {quote(known)}, this measurement "
                            f"says group {quote(group)}: a fiducial is in one group (send its "
                            "group unchanged, or give the other point its own id)")
        if fiducial is not None and self.outlier_distance > 0:
            own = self.sessions.cell(self.sessions.resolve(session), fid)
            for name, repeats, point, mean in (
                    ("working", own, w, own.mean_w() if own is not None else None),
                    ("destination", fiducial, d, fiducial.mean_d())):
                if repeats is None:
                    continue
                far = repeat_outlier(fid, name, point, mean, repeats.n, self.outlier_distance)
                if far:
                    raise RejectedMeasurement("outlier", far)
        return Measurement(fid, w, d, stamp, auto, group, session)

    def _check_duplicate(self, fid: str, stamp: float, working: tuple[float, ...],
                         destination: tuple[float, ...], auto: bool) -> None:
        """The duplicate rule (module docstring)."""
        same = self._recent.get(fid, {}).get(stamp)
        if not same:
            return
        at = f"fiducial {quote(fid)} at stamp {stamp:.9f} s"
        if working + destination in same:
            raise RejectedMeasurement(
                "duplicate", f"{at}: the same points as an accepted measurement with that stamp "
                             "(a topic bridged or republished twice, a bag recorded twice?): one "
                             "measurement, not a repeat")
        if not auto:
            raise RejectedMeasurement(
                "conflict", f"{at}: other points than an accepted measurement with that stamp "
                            f"(working {working}, destination {destination}): one stamp is one "
                            "measurement, which one is right is not known (stamp each "
                            "measurement with its own acquisition time, or leave the stamp 0)")

    def check_record(self, record: Record) -> None:
        """The live value checks of :meth:`prepare` on a record read back from a journal: the
        id rules, finite stamp, finite coordinates within ±``MAX_ABS_COORDINATE``, the
        dimension (the parameter-dependent checks — frames, stamp age, outliers — were decided
        when the record was accepted and are not repeated). Nothing is counted.

        :raises RejectedMeasurement: naming what is wrong.
        """
        check_record_values(record, self.dimension)

    def _nearest(self, destination: tuple[float, ...]) -> Optional[str]:
        if not self._order:
            return None
        dist = np.linalg.norm(self._dest_means - destination, axis=1)
        k = int(np.argmin(dist))
        return self._order[k] if dist[k] <= self.merge_radius else None

    def _new_auto_id(self) -> str:
        n = self._next_auto
        while f"{AUTO_ID_PREFIX}{n:04d}" in self._fiducials:
            n += 1
        return f"{AUTO_ID_PREFIX}{n:04d}"

    def commit(self, record: Record) -> None:
        """Add a record made by :meth:`prepare` or :meth:`prepare_enabled` (or read back from a
        journal). Never rejects a measurement: it was validated when prepared.

        :raises ValueError: when a record does not fit this accumulator (dimension, unknown id).
        """
        if isinstance(record, EnabledChange):
            if record.fiducial_id not in self._fiducials:
                raise ValueError(f"unknown fiducial id {record.fiducial_id!r}")
            self._fiducials[record.fiducial_id].enabled = bool(record.enabled)
            return
        if not isinstance(record, Measurement):
            raise TypeError(f"record must be a Measurement or EnabledChange, got {record!r}")
        if len(record.working) != self.dimension or len(record.destination) != self.dimension:
            raise ValueError(f"record of fiducial {record.fiducial_id!r} has "
                             f"{len(record.working)} coordinates, expected {self.dimension}")
        fid = record.fiducial_id
        fiducial = self._fiducials.get(fid)
        if fiducial is None:
            fiducial = self._fiducials[fid] = FiducialRepeats(self.dimension)
            self._index[fid] = len(self._order)
            self._order.append(fid)
            self._dest_means = np.vstack([self._dest_means, np.zeros((1, self.dimension))])
            match = _AUTO_ID.match(fid)
            if match:
                self._next_auto = max(self._next_auto, int(match.group(1)) + 1)
        fiducial.add(tuple(record.working), tuple(record.destination))
        self._dest_means[self._index[fid]] = fiducial.mean_d()
        self.n_measurements += 1
        self._first_stamps.setdefault(fid, record.stamp_s)
        if record.group:
            self._groups.setdefault(fid, record.group)
        self.sessions.add(record)
        if record.stamp_s != 0:
            recent = self._recent.setdefault(fid, {})
            points = tuple(record.working) + tuple(record.destination)
            recent[record.stamp_s] = recent.get(record.stamp_s, ()) + (points,)
            if self.duplicate_window is not None and len(recent) > self.duplicate_window:
                del recent[next(iter(recent))]

    def add(self, fiducial_id: Optional[str], working_xyz: ArrayLike, destination_xyz: ArrayLike,
            working_frame: str = "", destination_frame: str = "",
            stamp_s: float = 0.0, now_s: Optional[float] = None, group: str = "",
            session: str = "") -> str:
        """:meth:`prepare` then :meth:`commit` one measurement.

        :return: the id of the fiducial it was added to.
        :raises RejectedMeasurement: see :meth:`prepare`.
        """
        record = self.prepare(fiducial_id, working_xyz, destination_xyz, working_frame,
                              destination_frame, stamp_s, now_s, group, session)
        self.commit(record)
        return record.fiducial_id

    # -- enable / disable ---------------------------------------------------------------------
    def prepare_enabled(self, fiducial_id: str, enabled: bool) -> EnabledChange:
        """Validate an enable/disable request (see :meth:`commit`).

        :raises KeyError: for an unknown fiducial id (the message lists the known ones).
        """
        if fiducial_id not in self._fiducials:
            # quoted: an id may hold a comma or a space (known: 'a, b', 'c' is two ids)
            more = len(self._order) - KNOWN_IDS_SHOWN
            known = (", ".join(quote(f) for f in self._order[:KNOWN_IDS_SHOWN])
                     + (f" and {more} more" if more > 0 else ""))
            raise KeyError(f"unknown fiducial id {quote(fiducial_id)} (known: {known or 'none'})")
        return EnabledChange(fiducial_id, bool(enabled))

    def set_enabled(self, fiducial_id: str, enabled: bool) -> None:
        """Exclude a fiducial from :meth:`fiducial_set` (its measurements are kept) or include it.

        :raises KeyError: for an unknown fiducial id.
        """
        self.commit(self.prepare_enabled(fiducial_id, enabled))

    # -- output -------------------------------------------------------------------------------
    def fiducial_set(self) -> FiducialSet:
        """The enabled fiducials' means and repeats (see :class:`FiducialSet`); with more than
        one session in the current session's frame, kept-apart sessions left out (module
        docstring)."""
        ids = [f for f in self._order if self._fiducials[f].enabled]
        d = self.dimension
        plan = self.sessions.plan(set(ids))
        if plan is None:
            fids: list = [self._fiducials[f] for f in ids]
            working = [f.mean_w() for f in fids]
            destination = [f.mean_d() for f in fids]
            variances = [f.variance_w() for f in fids]
        else:
            joined = self.sessions.combined(plan, ids)
            ids = list(joined)
            fids = list(joined.values())
            working = [f.mean_w for f in fids]
            destination = [f.mean_d for f in fids]
            variances = [f.variance_w() for f in fids]
        groups = tuple(self._groups.get(f, "") for f in ids)
        return FiducialSet(
            ids=tuple(ids),
            working=np.array(working, dtype=np.float64).reshape(-1, d),
            destination=np.array(destination, dtype=np.float64).reshape(-1, d),
            repeat_stats=RepeatStats(np.array([f.n for f in fids], dtype=np.int64),
                                     np.array(variances, dtype=np.float64)),
            disabled_ids=tuple(f for f in self._order if not self._fiducials[f].enabled),
            n_measurements=self.n_measurements,
            groups=groups if any(groups) else None, sessions=plan,
            first_stamps=tuple(self._first_stamps[f] for f in ids),
            session_starts=self.sessions.starts() if plan is not None else (),
            session=self.sessions.resolve(""))

    def restore(self, records: Iterable[Record]) -> list[str]:
        """Clear, then commit ``records`` in order: the state after the same accepted
        measurements and enable changes, whatever the parameters were then. Rejection counters
        start from zero (rejections are not records). A record that fails the live value checks
        (:meth:`check_record`: NaN, inf, beyond ±1e12, a bad id or stamp) or does not fit
        (another dimension, an enable change of an unknown id) is skipped.

        :return: one message per skipped record (empty when all fitted).
        """
        self.clear()
        return self.replay(records)

    def replay(self, records: Iterable[Record], first: int = 0) -> list[str]:
        """Commit ``records`` (numbered from ``first``) on top of this state, skipping those
        :meth:`check_record` or :meth:`commit` refuses; one message per skipped record."""
        errors = []
        for k, record in enumerate(records, first):
            try:
                self.check_record(record)
                self.commit(record)
            except (TypeError, ValueError) as exc:   # RejectedMeasurement is a ValueError
                errors.append(f"record {k} skipped: {exc}")
        return errors

    @property
    def n_disabled(self) -> int:
        """Number of disabled fiducials."""
        return sum(not f.enabled for f in self._fiducials.values())

    def state_digest(self) -> tuple:
        """A hashable summary of the state (ids, enabled flags, every running statistic): equal
        digests mean equal accumulators. For tests and restart checks."""
        return tuple((f, self._fiducials[f].digest()) for f in self._order)

    def session_digest(self) -> tuple:
        """Groups and every per-session statistic (:meth:`.session_sums.SessionSums.digest`)."""
        return tuple(self._groups.items()), self.sessions.digest()

