"""Pairing of separately published working-frame and destination-frame points by time stamp.

Tracker and robot drivers publish one point each per measurement (``geometry_msgs/PointStamped``);
a working point and a destination point whose stamps differ by at most ``slop`` seconds are one
fiducial measurement. Pure Python: used by the ROS node and the offline bag evaluator alike.

Each stream is assumed to arrive in stamp order (as a driver publishes it). A buffered point is
*stale* once the other stream has delivered a stamp later than ``stamp + slop``: no later point
of that stream can match it any more, so it is dropped and reported. Buffers are bounded
(``max_buffer`` per stream, oldest dropped first).

A stream that goes back in time by more than :data:`RESTART_AFTER` (and ``slop``): one point
stamped far in the future, or a driver restarted with a new clock, starts again from the new
stamp: its buffered points later than it by more than ``slop`` are dropped as out of order, and
its latest stamp is the new one. Otherwise a single future stamp would make every later point of
the other stream look stale until a reset. A point merely late (back by less) is paired or
dropped as before, and the points after it stay buffered. A point whose other stream is ahead
of it by more than that (both drivers restarted, the other not yet heard from on its new clock)
is buffered, not dropped at once: the other stream's next point pairs it (it restarted too) or
drops it as stale (it did not); before, both clocks stepping back lost the first pair.

*Ambiguous* points: a working point and a destination point are one measurement only when each
is the other's only point within ``slop`` among the points of the other stream seen so far
(buffered, paired or refused). A point with two or more points of the other stream within
``slop`` (streams whose period is at most ``slop``, or a clock step between the two devices) is
refused as ambiguous, and so is a point whose only candidate has another candidate: which pair
is right is not known from the stamps, and "nearest in time" silently pairs the wrong ones when
the clocks are offset. A slop below half the measurement period never gives an ambiguous point.
Pairs are made as soon as the second point arrives, so a pair whose second candidate arrives
later is already made; that candidate is refused (and says so). Stamps that repeat (the
stream's previous stamp again) are not checked: pairing then goes by arrival order
(:attr:`PairingResult.repeated`).

*Duplicates*: a stamped point equal to one of its stream seen before (the same coordinates,
frame and stamp: a topic recorded twice, a point republished; among the stream's last
:data:`COPY_MEMORY` distinct points) is dropped as a duplicate before any of this, so its copy
makes no point ambiguous (a bag with both point topics recorded twice lost
every measurement to ``ambiguous``). Where stamps do not tell measurements apart, a copy
cannot be told from a repeat of the same hole (a robot's destination point is the same, bit for
bit, every time): unstamped points (stamp 0) are never duplicates, as for measurements
(:mod:`.accumulator`), and neither are the points of a stream once two different points of it
came in a row with one stamp (a driver that stamps every point with one time, or each hole's
repeats with one; both streams from then on, as the drivers of a cell are set up alike). Before
that is seen, a copy of the first such point is dropped: a robot that publishes a hole's
destination point before the tracker's working point loses that second measurement, and with
one constant stamp pairing by arrival order then pairs every later point wrongly (the stamps'
own warning, :attr:`PairingResult.repeated`, says so: stamp each measurement, or publish
``FiducialPair``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..constants import DESTINATION, WORKING

_OTHER = {WORKING: DESTINATION, DESTINATION: WORKING}
#: A stream going back by more than this [s] (and the slop) restarts (module docstring): longer
#: than a late delivery, shorter than a clock jump or a driver restart.
RESTART_AFTER = 1.0
#: Distinct points per stream a copy is looked for among (module docstring): two recordings of a
#: topic merged lie far closer together than this.
COPY_MEMORY = 256


@dataclass(frozen=True)
class StampedPoint:
    """A point (3 coordinates, caller's unit) in ``frame_id`` at ``stamp_s`` seconds."""

    xyz: tuple[float, float, float]
    frame_id: str
    stamp_s: float


class PointPair(NamedTuple):
    """A working point and a destination point matched by stamp."""

    working: StampedPoint
    destination: StampedPoint

    @property
    def stamp_s(self) -> float:
        """The stamp of the measurement: the working point's stamp."""
        return self.working.stamp_s


class DroppedPoint(NamedTuple):
    """A point that will never be paired (counted as a malformed measurement)."""

    stream: str  # "working" or "destination"
    point: StampedPoint
    reason: str
    #: Refused as ambiguous (module docstring), not merely unpairable.
    ambiguous: bool = False
    #: An exact copy of a point of its stream seen before (module docstring).
    duplicate: bool = False

#: The advice in the reason of an ambiguous point.
AMBIGUOUS_HINT = "lower pair_slop below half the measurement period"


class PairingResult(NamedTuple):
    """What one :meth:`StampPairer.add` produced: new pairs and newly dropped points;
    ``repeated``: the point has the same stamp as the stream's previous one (stamps that do not
    tell measurements apart: pairing then goes by arrival order)."""

    pairs: tuple[PointPair, ...]
    dropped: tuple[DroppedPoint, ...]
    repeated: bool = False


class StampPairer:
    """Pairs working and destination points whose stamps differ by at most ``slop`` seconds.

    :param slop: the largest stamp difference of a pair [s], > 0.
    :param max_buffer: the most unmatched points kept per stream (>= 1).
    :raises ValueError: on a bad slop or buffer size.
    """

    def __init__(self, slop: float, max_buffer: int = 100) -> None:
        self.slop = slop
        if isinstance(max_buffer, bool) or not isinstance(max_buffer, int) or max_buffer < 1:
            raise ValueError(f"max_buffer must be an integer >= 1, got {max_buffer!r}")
        self.max_buffer = max_buffer
        self._buffers: dict[str, deque[StampedPoint]] = {WORKING: deque(), DESTINATION: deque()}
        self._latest = {WORKING: -math.inf, DESTINATION: -math.inf}
        self._previous: dict[str, float] = {}       # each stream's last stamp
        # The points seen recently (buffered, paired or refused), for the ambiguity rule.
        self._seen: dict[str, deque[StampedPoint]] = {WORKING: deque(), DESTINATION: deque()}
        # The last COPY_MEMORY distinct points of each stream, for the duplicate rule (a set to
        # look them up in O(1), the deque to forget the oldest).
        self._recent: dict[str, deque[StampedPoint]] = {WORKING: deque(), DESTINATION: deque()}
        self._recent_set: dict[str, set[StampedPoint]] = {WORKING: set(), DESTINATION: set()}
        # Whether a stream brought two different points in a row with one stamp (then stamps
        # do not tell measurements apart: no duplicates).
        self._shared_stamps = False
        self.n_pairs = 0
        self.n_dropped = 0
        self.n_ambiguous = 0    # points refused as ambiguous (also counted in n_dropped)

    @property
    def slop(self) -> float:
        """The largest stamp difference of a pair [s]."""
        return self._slop

    @slop.setter
    def slop(self, value: float) -> None:
        v = float(value)
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"slop must be > 0 and finite (seconds), got {value!r}")
        self._slop = v

    def pending(self, stream: str) -> int:
        """Number of buffered, unmatched points of ``stream``."""
        return len(self._buffers[stream])

    def clear(self) -> None:
        """Drop every buffered point without reporting it (e.g. on reset)."""
        for buf in (*self._buffers.values(), *self._seen.values(), *self._recent.values(),
                    *self._recent_set.values()):
            buf.clear()
        self._shared_stamps = False
        self._latest = {WORKING: -math.inf, DESTINATION: -math.inf}
        self._previous = {}

    def add_working(self, xyz: ArrayLike, frame_id: str, stamp_s: float) -> PairingResult:
        """Add a working-frame point; see :meth:`add`."""
        return self.add(WORKING, xyz, frame_id, stamp_s)

    def add_destination(self, xyz: ArrayLike, frame_id: str, stamp_s: float) -> PairingResult:
        """Add a destination-frame point; see :meth:`add`."""
        return self.add(DESTINATION, xyz, frame_id, stamp_s)

    def add(self, stream: str, xyz: ArrayLike, frame_id: str, stamp_s: float) -> PairingResult:
        """Add a point of ``stream`` and pair it with the other stream's buffered point within
        the slop, if that is the only candidate of either (module docstring).

        Coordinates are not validated here (NaN is passed on to the accumulator, which rejects it
        with its own reason); only the shape and stamp must be usable for pairing.

        :param stream: ``"working"`` or ``"destination"``.
        :param xyz: the point, shape (3,).
        :param frame_id: its frame.
        :param stamp_s: its stamp [s].
        :return: the pairs made (0 or 1) and the points dropped as stale, overflowing or
            ambiguous.
        :raises ValueError: on an unknown stream, a point that is not 3 numbers or a
            non-finite stamp (the point is not buffered).
        """
        if stream not in self._buffers:
            raise ValueError(f"stream must be {WORKING!r} or {DESTINATION!r}, got {stream!r}")
        arr: NDArray[np.float64] = np.asarray(xyz, dtype=np.float64)
        if arr.shape != (3,):
            raise ValueError(f"{stream} point must have 3 coordinates, got shape {arr.shape}")
        stamp = float(stamp_s)
        if not math.isfinite(stamp):
            raise ValueError(f"{stream} point stamp must be finite, got {stamp_s!r}")
        point = StampedPoint((float(arr[0]), float(arr[1]), float(arr[2])), str(frame_id), stamp)
        if self._is_copy(stream, point):
            self.n_dropped += 1
            return PairingResult((), (DroppedPoint(
                stream, point, f"duplicate: the same {stream} point and stamp {stamp:.9f} as "
                "one before (a topic recorded twice or republished?)", duplicate=True),))
        other = _OTHER[stream]
        dropped: list[DroppedPoint] = []
        repeated = self._previous.get(stream) == stamp
        self._previous[stream] = stamp
        if stamp < self._latest[stream] - max(self._slop, RESTART_AFTER):   # back in time
            self._restart(stream, stamp, dropped)
        self._latest[stream] = max(self._latest[stream], stamp)
        # Points of the other stream older than stamp - slop cannot match this or later points.
        self._drop_stale(other, dropped)
        pairs: tuple[PointPair, ...] = ()
        ambiguous = not repeated and self._ambiguous(stream, point, dropped)
        match = None if ambiguous else self._take_nearest(other, stamp)
        if match is not None:
            pair = PointPair(point, match) if stream == WORKING else PointPair(match, point)
            pairs = (pair,)
            self.n_pairs += 1
        elif ambiguous:
            pass        # refused, with its reason in `dropped`
        elif (self._latest[other] > stamp + self._slop
              and not self._latest[other] > stamp + max(self._slop, RESTART_AFTER)):
            # The other stream is already past this point's window: it can never be paired.
            # (Far past, by more than RESTART_AFTER, it is on the clock this stream left: both
            # drivers restarted, its next point restarts it too and pairs with this one, or
            # drops this one as stale; module docstring.)
            dropped.append(DroppedPoint(stream, point, f"no {other} point within "
                                        f"{self._slop:g} s of stamp {stamp:.9f}"))
        else:
            buf = self._buffers[stream]
            buf.append(point)
            while len(buf) > self.max_buffer:
                dropped.append(DroppedPoint(stream, buf.popleft(), f"{stream} buffer full "
                                            f"({self.max_buffer} unmatched points)"))
        self.n_dropped += len(dropped)
        self.n_ambiguous += sum(d.ambiguous for d in dropped)
        return PairingResult(pairs, tuple(dropped), repeated)

    def _is_copy(self, stream: str, point: StampedPoint) -> bool:
        """Whether ``point`` equals (coordinates, frame and stamp) one of the last
        :data:`COPY_MEMORY` distinct points of ``stream`` whose stamps tell measurements apart;
        if not, it is remembered. An unstamped point (stamp 0) is never a copy, nor is any point
        once a stream brought two different points in a row with one stamp (module docstring).
        A point with a NaN or inf coordinate (rejected later) is no copy and tells nothing."""
        if point.stamp_s == 0.0 or self._shared_stamps or not all(map(math.isfinite,
                                                                          point.xyz)):
            return False
        known = self._recent_set[stream]
        if point in known:
            return True
        if self._previous.get(stream) == point.stamp_s:
            self._shared_stamps = True
            return False
        recent = self._recent[stream]
        recent.append(point)
        known.add(point)
        if len(recent) > COPY_MEMORY:
            known.discard(recent.popleft())
        return False

    def _ambiguous(self, stream: str, point: StampedPoint, dropped: list[DroppedPoint]) -> bool:
        """Whether ``point`` is ambiguous (module docstring), then refused with its reason in
        ``dropped``, with its only candidate when that is buffered (which has two now). Records
        ``point`` as seen."""
        other, slop, stamp = _OTHER[stream], self._slop, point.stamp_s
        near = self._near(other, stamp)
        self._remember(stream, point)
        if not near:
            return False
        where = f"within {slop:g} s of {stream} stamp {stamp:.9f}"
        if len(near) >= 2:
            stamps = ", ".join(f"{p.stamp_s:.9f}" for p in near[:3])
            dropped.append(DroppedPoint(stream, point, f"ambiguous: {len(near)} {other} points "
                                        f"{where} ({stamps}); {AMBIGUOUS_HINT}", True))
            self._refuse_buffered(other, near, f"ambiguous: within {slop:g} s of {stream} "
                                  f"stamp {stamp:.9f}, which has {len(near)} {other} points "
                                  f"within it; {AMBIGUOUS_HINT}", dropped)
            return True
        candidate = near[0]
        rivals = [p for p in self._near(stream, candidate.stamp_s) if p is not point]
        buffered = any(p is candidate for p in self._buffers[other])
        if buffered and not rivals:
            return False
        rival = f" and of {stream} stamp {rivals[0].stamp_s:.9f}" if rivals else ""
        dropped.append(DroppedPoint(stream, point, f"ambiguous: the {other} point at "
                                    f"{candidate.stamp_s:.9f} is {where}{rival}"
                                    + ("" if buffered else " (paired or refused before)")
                                    + f"; {AMBIGUOUS_HINT}", True))
        if buffered:
            self._refuse_buffered(other, near, f"ambiguous: {stream} points at "
                                  f"{rivals[0].stamp_s:.9f} and {stamp:.9f} are within "
                                  f"{slop:g} s of it; {AMBIGUOUS_HINT}", dropped)
        return True

    def _refuse_buffered(self, stream: str, points: list[StampedPoint], reason: str,
                         dropped: list[DroppedPoint]) -> None:
        """Take those of ``points`` still buffered out of the buffer of ``stream``, refused as
        ambiguous with ``reason``."""
        buf = self._buffers[stream]
        chosen = {id(q) for q in points}               # by identity: points may be equal
        refused = [p for p in buf if id(p) in chosen]
        if refused:
            self._buffers[stream] = deque(p for p in buf if id(p) not in chosen)
            dropped += [DroppedPoint(stream, p, reason, True) for p in refused]

    def _near(self, stream: str, stamp: float) -> list[StampedPoint]:
        """The points of ``stream`` seen or buffered within the slop of ``stamp``."""
        seen = self._seen[stream]
        in_seen = {id(q) for q in seen}
        extra = [p for p in self._buffers[stream] if id(p) not in in_seen]
        return [p for p in (*seen, *extra) if abs(p.stamp_s - stamp) <= self._slop]

    def _remember(self, stream: str, point: StampedPoint) -> None:
        """Add ``point`` to the seen points of ``stream``; forget those no later point can be
        near (older than the stream's latest stamp by more than twice the slop), at most
        ``max_buffer`` besides the buffered ones."""
        seen = self._seen[stream]
        seen.append(point)
        horizon = self._latest[stream] - 2 * self._slop
        while seen and (seen[0].stamp_s < horizon or len(seen) > self.max_buffer):
            seen.popleft()

    def discard(self, stream: str, xyz: ArrayLike, stamp_s: float) -> bool:
        """Drop the buffered point of ``stream`` at ``xyz`` and ``stamp_s`` (recorded otherwise,
        e.g. by ``~/take_sample``) without reporting it; whether there was one. It is not
        a candidate of the ambiguity rule either: its stamp partner is buffered as usual."""
        key = (tuple(float(v) for v in np.asarray(xyz, dtype=np.float64)), float(stamp_s))
        buf = self._buffers[stream]
        for k, point in enumerate(buf):
            if (point.xyz, point.stamp_s) == key:
                del buf[k]
                self._seen[stream] = deque(p for p in self._seen[stream] if p is not point)
                return True
        return False

    def _restart(self, stream: str, stamp: float, dropped: list[DroppedPoint]) -> None:
        """``stream`` from ``stamp`` on (module docstring): its points after it dropped."""
        keep = deque()
        for old in self._buffers[stream]:
            if old.stamp_s > stamp + self._slop:
                dropped.append(DroppedPoint(stream, old, f"stamp {old.stamp_s:.9f} is out of "
                                            f"order: a later {stream} point has stamp "
                                            f"{stamp:.9f}"))
            else:
                keep.append(old)
        self._buffers[stream] = keep
        self._seen[stream] = deque(p for p in self._seen[stream]
                                   if p.stamp_s <= stamp + self._slop)
        self._latest[stream] = max((p.stamp_s for p in keep), default=stamp)

    def _drop_stale(self, stream: str, dropped: list[DroppedPoint]) -> None:
        buf = self._buffers[stream]
        horizon = self._latest[_OTHER[stream]] - self._slop
        if not buf or min(p.stamp_s for p in buf) >= horizon:
            return
        keep = deque()
        for old in buf:
            if old.stamp_s < horizon:
                dropped.append(DroppedPoint(stream, old, f"no {_OTHER[stream]} point within "
                                            f"{self._slop:g} s of stamp {old.stamp_s:.9f}"))
            else:
                keep.append(old)
        self._buffers[stream] = keep

    def _take_nearest(self, stream: str, stamp: float) -> StampedPoint | None:
        buf = self._buffers[stream]
        best_k, best_dt = -1, math.inf
        for k, candidate in enumerate(buf):
            dt = abs(candidate.stamp_s - stamp)
            if dt <= self._slop and dt < best_dt:
                best_k, best_dt = k, dt
        if best_k < 0:
            return None
        point = buf[best_k]
        del buf[best_k]
        return point
