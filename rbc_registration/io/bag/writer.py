"""Writing registration bags with ``rosbags`` (no rclpy): ``FiducialPair`` and
``PointStamped`` messages, sqlite3 or mcap storage (an mcap file with the chunk and summary
CRC-32s that rosbag2 writes, :func:`.mcap_crc.write_crcs`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Sequence, Union

from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

from ..progress import Progress
from .mcap_crc import mcap_files, write_crcs
from .records import FIDUCIAL_PAIR, MESSAGE_TYPES, POINT_STAMPED, STORAGES, BagError, OutMessage
from .typestore import make_typestore


def write_bag(path: Union[str, Path], messages: Iterable[OutMessage], storage: str = "sqlite3",
              progress: bool = True, total: int = 0,
              empty: Sequence[tuple[str, str]] = ()) -> int:
    """Write ``messages`` (receive time = header stamp) to a new bag directory ``path``.

    :param empty: ``(topic, kind)`` of topics to list without messages (as ``ros2 bag record
        -a`` lists a topic that published nothing); ``kind`` as in :class:`OutMessage`.

    :return: the number of messages written.
    :raises BagError: on an unknown storage or when ``path`` exists.
    """
    if storage not in STORAGES:
        raise BagError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
    store = make_typestore()
    types = MESSAGE_TYPES
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Point = store.types["geometry_msgs/msg/Point"]
    Pair, Stamped = store.types[FIDUCIAL_PAIR], store.types[POINT_STAMPED]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    try:
        writer = Writer(Path(path), version=9, storage_plugin=plugin)
    except WriterError as exc:
        raise BagError(f"bag {path}: {exc}") from None
    conns: dict[str, Any] = {}
    bar = Progress(f"writing {Path(path).name}", total, enabled=progress)
    n = 0
    with writer:
        for topic, kind in empty:
            conns[topic] = writer.add_connection(topic, types[kind], typestore=store)
        for m in messages:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, types[m.kind], typestore=store)
            header = Header(stamp=Time(sec=m.stamp_ns // 1_000_000_000,
                                       nanosec=m.stamp_ns % 1_000_000_000), frame_id=m.frame_id)
            if m.kind == "pair":
                msg = Pair(header=header, fiducial_id=m.fiducial_id, working_point=Point(*m.xyz),
                           destination_frame_id=m.destination_frame,
                           destination_point=Point(*m.destination), group=m.group,
                           session=m.session)
            else:
                msg = Stamped(header=header, point=Point(*m.xyz))
            writer.write(conns[m.topic], m.stamp_ns,
                         store.serialize_cdr(msg, types[m.kind]))
            n += 1
            bar.update()
    if storage == "mcap":           # the CRCs rosbag2 writes and rosbags' writer leaves 0
        for f in mcap_files(Path(path)):
            write_crcs(f)
    bar.done()
    return n
