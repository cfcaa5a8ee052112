"""``~/take_sample``: record one fiducial now from the latest ``~/working_point`` and
``~/destination_point`` (or a tf lookup of the destination point), each checked against
``sample_max_age`` [s] on the node clock. The pair goes through the node's ingestion (validation,
journal, counters) like every measurement. Units: metres.
"""

from __future__ import annotations

import threading
from typing import Any, NamedTuple, Optional, Sequence

from geometry_msgs.msg import PointStamped

from rbc_registration_interfaces.msg import FiducialPair

from ..core.measurements.pairing import DESTINATION, WORKING
from ..core.measurements.records import RejectedMeasurement
from ..pipeline.ingest import PairArgs
from ..pipeline.settings import Settings
from . import conversions as conv

try:  # tf2_ros (tf2_ros_py) is not on PyPI: without it the 'tf' source is refused.
    from tf2_ros import Buffer, TransformException, TransformListener
    TF2_ROS_MISSING = ""
except ImportError as _exc:  # pragma: no cover - depends on the installation
    Buffer = TransformListener = None
    TransformException = LookupError
    TF2_ROS_MISSING = f"tf2_ros is not importable ({_exc})"


def source_error(source: str) -> Optional[str]:
    """Why ``sample_destination_source`` = ``source`` cannot be used here, or ``None``."""
    if source == "tf" and TF2_ROS_MISSING:
        return f"sample_destination_source 'tf' needs tf2_ros: {TF2_ROS_MISSING}"
    return None


class Latest(NamedTuple):
    """A point as received: the message and when (node clock [ns])."""

    msg: PointStamped
    received_ns: int
    paired: bool = False        # recorded already as a stamp pair (point_mode pair)
    sampled: bool = False       # recorded already by a ~/take_sample


class Taken(NamedTuple):
    """What a sample is taken from: the latest working point and the destination point's
    stamp [s] (the pair's stamp is the working point's)."""

    working: Optional[Latest]
    destination_stamp_s: float


def _same_point(a: PointStamped, b: PointStamped) -> bool:
    """Whether two points have the same coordinates, frame and stamp."""
    return ((a.point.x, a.point.y, a.point.z, a.header.frame_id, a.header.stamp.sec,
             a.header.stamp.nanosec) == (b.point.x, b.point.y, b.point.z, b.header.frame_id,
                                         b.header.stamp.sec, b.header.stamp.nanosec))


class SampleTaker:
    """The latest working and destination points of a node, and the tf buffer of the 'tf'
    source (created when first needed).

    :param node: the ``rclpy.node.Node`` (its clock and, for tf, a listener).
    """

    def __init__(self, node: Any) -> None:
        self._node = node
        self._lock = threading.Lock()
        self._latest: dict[str, Latest] = {}
        self._buffer: Any = None

    def update(self, stream: str, msg: PointStamped) -> None:
        """Remember ``msg`` as the latest point of ``stream`` (``working`` / ``destination``).
        A copy of the latest point (the same coordinates, frame and stamp: a topic bridged or
        recorded twice, which the pairer drops as a duplicate; a driver re-sending its last
        measurement) is the same measurement: it keeps the latest point's marks (paired,
        sampled); its time of arrival is the copy's, as before."""
        with self._lock:
            now = self._node.get_clock().now().nanoseconds
            old = self._latest.get(stream)
            if old is not None and _same_point(old.msg, msg):
                self._latest[stream] = old._replace(msg=msg, received_ns=now)
                return
            self._latest[stream] = Latest(msg, now)

    def mark_paired(self, pairs: Sequence[Any]) -> None:
        """Stamp pairs (``core.measurements.pairing.PointPair``) were recorded: a latest point that
        is one of
        their points (same coordinates and stamp) must not be recorded again by
        ``~/take_sample``."""
        with self._lock:
            for stream, latest in self._latest.items():
                try:
                    xyz, _, stamp = conv.point_stamped_to_tuple(latest.msg)
                except RejectedMeasurement:     # a stamp that is not a time: never paired
                    continue
                key = (tuple(float(v) for v in xyz), float(stamp))
                if any((p.working.xyz, p.working.stamp_s) == key if stream == WORKING else
                       (p.destination.xyz, p.destination.stamp_s) == key for p in pairs):
                    self._latest[stream] = latest._replace(paired=True)

    def mark_sampled(self, taken: Any) -> None:
        """A ``~/take_sample`` recorded the working point of ``taken`` (the :class:`Taken`
        :meth:`pair` returned): while no newer ``~/working_point`` arrived, another sample
        would record the same measurement again."""
        with self._lock:
            latest = self._latest.get(WORKING)
            if latest is not None and latest is taken.working:
                self._latest[WORKING] = latest._replace(sampled=True)

    def _point(self, stream: str, topic: str, settings: Settings, now_ns: int) -> Any:
        latest = self._latest.get(stream)
        if latest is None:
            return f"no {topic} received yet"
        age = (now_ns - latest.received_ns) * 1e-9
        if age > settings.sample_max_age:
            return (f"the latest {topic} is stale: received {age:.3g} s ago, more than "
                    f"sample_max_age {settings.sample_max_age:g} s")
        return latest.msg

    def _tf_point(self, settings: Settings) -> Any:
        error = source_error("tf")
        if error:
            return error
        if not settings.sample_tf_child:
            return "sample_tf_child is empty: set the frame whose origin is the destination point"
        if self._buffer is None:
            self._buffer = Buffer()
            self._listener = TransformListener(self._buffer, self._node)
        parent = settings.sample_tf_parent or settings.destination_frame
        try:
            t = self._buffer.lookup_transform(parent, settings.sample_tf_child,
                                              conv.nanoseconds_to_stamp(0))
        except TransformException as exc:  # lookup, connectivity or extrapolation error
            return f"tf lookup {parent} <- {settings.sample_tf_child} failed: {exc}"
        age = (self._node.get_clock().now().nanoseconds
               - (t.header.stamp.sec * 1_000_000_000 + t.header.stamp.nanosec)) * 1e-9
        static = t.header.stamp.sec == 0 and t.header.stamp.nanosec == 0
        if not static and age > settings.sample_max_age:
            return (f"tf {parent} <- {settings.sample_tf_child} is stale: {age:.3g} s old, more "
                    f"than sample_max_age {settings.sample_max_age:g} s")
        msg = PointStamped()
        msg.header = t.header
        v = t.transform.translation
        msg.point.x, msg.point.y, msg.point.z = v.x, v.y, v.z
        return msg

    def pair(self, fiducial_id: str, settings: Settings
             ) -> tuple[Optional[PairArgs], str, Any]:
        """The measurement to record now: ``(PairArgs, "", token)``, or ``(None, why not,
        None)`` naming the missing, stale or already recorded point; ``token`` is a
        :class:`Taken`. Once the pair is recorded, pass it to :meth:`mark_sampled`.

        :raises RejectedMeasurement: ``malformed`` when a point's stamp is not a time (the caller
            counts it as every rejected measurement is counted).
        """
        now_ns = self._node.get_clock().now().nanoseconds
        with self._lock:
            latest = self._latest.get(WORKING)
            if settings.point_mode == "pair" and latest is not None and latest.paired:
                return None, ("the latest ~/working_point is recorded already, paired by stamp "
                              "(point_mode pair): a sample would count it twice (a false "
                              "repeat, sigma too small); send a new point, or use point_mode "
                              "sample"), None
            if latest is not None and latest.sampled:
                return None, ("the latest ~/working_point is recorded already, by the previous "
                              "~/take_sample: a second sample of the same point would be a "
                              "false repeat (zero scatter, sigma too small); measure the hole "
                              "again (a new ~/working_point), then take the sample"), None
            working = self._point(WORKING, "~/working_point", settings, now_ns)
            destination = (self._point(DESTINATION, "~/destination_point", settings, now_ns)
                           if settings.sample_destination_source == "topic" else None)
        if destination is None:
            destination = self._tf_point(settings)
        errors = [p for p in (working, destination) if isinstance(p, str)]
        if errors:
            return None, "; ".join(errors), None
        (w, w_frame, stamp), (d, d_frame, d_stamp) = (conv.point_stamped_to_tuple(working),
                                                      conv.point_stamped_to_tuple(destination))
        return (PairArgs(fiducial_id or None, w, d, w_frame, d_frame, stamp), "",
                Taken(latest, d_stamp))


def pair_message(record: Any, args: PairArgs, settings: Settings) -> FiducialPair:
    """The recorded measurement as a ``FiducialPair`` (its assigned id; 2D: z as received)."""
    msg = FiducialPair()
    msg.header.frame_id = settings.working_frame
    msg.header.stamp = conv.nanoseconds_to_stamp(int(round(args.stamp_s * 1e9)))
    msg.fiducial_id = record.fiducial_id
    msg.working_point = conv.array_to_point(args.working_xyz)
    msg.destination_frame_id = settings.destination_frame
    msg.destination_point = conv.array_to_point(args.destination_xyz)
    msg.group, msg.session = record.group, record.session
    return msg
