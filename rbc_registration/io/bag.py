"""rosbag2 files of registration data, read and written with ``rosbags`` (no rclpy).

A bag holds the inputs of ``registration_node`` (docs/BAGS.md): ``FiducialPair`` messages on
``/registration_node/fiducial_pairs``, or ``geometry_msgs/PointStamped`` on
``/registration_node/working_point`` and ``/registration_node/destination_point`` (paired by
stamp), and optionally targets with truth on ``/registration_node/targets`` (``FiducialPair``:
``fiducial_id`` = target id, ``working_point`` = measured, ``destination_point`` = truth or NaN).
Units: metres (REP 103). Both rosbag2 storages are read and written: sqlite3 (``.db3``) and mcap,
as a bag directory (with ``metadata.yaml``) or a single storage file.

Every problem with a bag (missing, malformed, truncated, an unknown topic, a type without a
definition) raises :class:`BagError` with a message naming the bag and what was wrong.
"""

from __future__ import annotations

import math
import os
import sqlite3
import struct
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator, NamedTuple, Optional, Sequence, TextIO, Union

from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

FIDUCIAL_PAIR = "rbc_registration_interfaces/msg/FiducialPair"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"
INTERFACE_PACKAGE = "rbc_registration_interfaces"
STORAGES = ("sqlite3", "mcap")
#: Errors of rosbags and of the storage libraries on a bad or truncated file.
_READ_ERRORS = (ReaderError, SerdeError, TypesysError, sqlite3.Error, struct.error, OSError,
                EOFError, KeyError, IndexError, ValueError, UnicodeDecodeError, AssertionError)


class BagError(ValueError):
    """A bag that cannot be used; the message names the bag and the problem."""


class Topics(NamedTuple):
    """Topic names of the node's inputs and of the targets (resolved, absolute)."""

    fiducial_pairs: str
    working_point: str
    destination_point: str
    targets: str

    @classmethod
    def for_node(cls, node_name: str = "registration_node") -> "Topics":
        """The resolved ``~/...`` names of a node called ``node_name`` (root namespace)."""
        base = "/" + node_name.strip("/")
        return cls(f"{base}/fiducial_pairs", f"{base}/working_point",
                   f"{base}/destination_point", f"{base}/targets")


DEFAULT_TOPICS = Topics.for_node()


class PairMessage(NamedTuple):
    """A ``FiducialPair`` (``fiducial_id`` may be empty: id assigned by proximity)."""

    log_ns: int
    stamp_s: float
    fiducial_id: str
    working: tuple[float, float, float]
    working_frame: str
    destination: tuple[float, float, float]
    destination_frame: str


class PointMessage(NamedTuple):
    """A ``PointStamped`` of stream ``"working"`` or ``"destination"``."""

    log_ns: int
    stream: str
    xyz: tuple[float, float, float]
    frame_id: str
    stamp_s: float


class BagContents(NamedTuple):
    """What :func:`read_bag` found: the node's inputs in bag (receive-time) order, the targets,
    message counts per topic and the other topics of the bag (name -> type)."""

    path: Path
    inputs: tuple[Union[PairMessage, PointMessage], ...]
    targets: tuple[PairMessage, ...]
    counts: dict[str, int]
    other_topics: dict[str, str]


class Progress:
    """Progress of a long operation on stderr: a bar on a terminal, else a line every few
    seconds. ``total`` 0 means unknown."""

    def __init__(self, label: str, total: int = 0, stream: Optional[TextIO] = None,
                 enabled: bool = True, every_s: float = 2.0) -> None:
        self.label, self.total, self.count = label, int(total), 0
        self._stream = stream or sys.stderr
        self._enabled = enabled
        self._tty = enabled and hasattr(self._stream, "isatty") and self._stream.isatty()
        self._every = 0.2 if self._tty else every_s
        self._last = time.monotonic()

    def update(self, n: int = 1) -> None:
        """Count ``n`` more items; redraw when due."""
        self.count += n
        now = time.monotonic()
        if self._enabled and now - self._last >= self._every:
            self._last = now
            self._show(end="\r" if self._tty else "\n")

    def _show(self, end: str) -> None:
        if self.total:
            frac = min(1.0, self.count / self.total)
            bar = f" [{'#' * int(30 * frac):<30}]" if self._tty else ""
            text = f"{self.label}{bar} {self.count}/{self.total} ({100 * frac:.0f}%)"
        else:
            text = f"{self.label} {self.count}"
        self._stream.write(text + end)
        self._stream.flush()

    def done(self) -> None:
        """Print the final count."""
        if self._enabled:
            self._show(end="\n")


# -- types -------------------------------------------------------------------------------------
def interface_msg_dirs() -> list[Path]:
    """Where the ``.msg`` files of rbc_registration_interfaces may be: ``$RBC_MSG_DIR``, the
    share directory of every prefix in ``AMENT_PREFIX_PATH`` and of this Python's prefix, then
    the source tree (``msg_docs/``)."""
    rel = Path("share") / INTERFACE_PACKAGE / "msg"
    out = [Path(os.environ["RBC_MSG_DIR"])] if os.environ.get("RBC_MSG_DIR") else []
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    out += [Path(p) / rel for p in prefixes + [sys.prefix]]
    out.append(Path(__file__).resolve().parents[2] / "msg_docs" / INTERFACE_PACKAGE / "msg")
    return out


def make_typestore() -> Any:
    """A rosbags typestore with ROS 2 Kilted's standard types and rbc_registration_interfaces.

    :raises BagError: when no directory holds ``FiducialPair.msg`` (see :func:`interface_msg_dirs`).
    """
    store = get_typestore(Stores.ROS2_KILTED)
    for folder in interface_msg_dirs():
        if (folder / "FiducialPair.msg").is_file():
            types: dict[str, Any] = {}
            for f in sorted(folder.glob("*.msg")):
                types.update(get_types_from_msg(f.read_text(), f"{INTERFACE_PACKAGE}/msg/{f.stem}"))
            store.register(types)
            return store
    raise BagError("missing type definitions: FiducialPair.msg of rbc_registration_interfaces "
                   "not found in " + ", ".join(str(p) for p in interface_msg_dirs())
                   + " (set RBC_MSG_DIR to its msg directory)")


def _known(store: Any, msgtype: str) -> bool:
    try:
        store.get_msgdef(msgtype)
    except (TypesysError, KeyError):
        return False
    return True


# -- reading -----------------------------------------------------------------------------------
@contextmanager
def open_bag(path: Union[str, Path]) -> Iterator[Reader]:
    """Open a rosbag2 directory, ``.mcap`` or ``.db3`` file for reading.

    :raises BagError: when it does not exist or cannot be opened.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag {p}: no such file or directory")
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        raise BagError(f"bag {p}: not a rosbag2 directory (no metadata.yaml)")
    try:
        reader = Reader(p)
        reader.open()
    except _READ_ERRORS as exc:
        raise BagError(f"bag {p}: cannot open (truncated or corrupt?): {_describe(exc)}") from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except _READ_ERRORS:
            pass


def _describe(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if isinstance(exc, (ReaderError, BagError)) else f"{type(exc).__name__}: {text}"


def topic_types(reader: Reader) -> dict[str, str]:
    """``{topic: type}`` of an open bag (a topic with several types is an error)."""
    out: dict[str, str] = {}
    for conn in reader.connections:
        if out.setdefault(conn.topic, conn.msgtype) != conn.msgtype:
            raise BagError(f"bag {reader.path}: topic {conn.topic} has several types "
                           f"({out[conn.topic]}, {conn.msgtype})")
    return out


def check_definitions(reader: Reader, store: Any, topics: Iterable[str],
                      strict: bool = True) -> None:
    """Make sure every type of ``topics`` can be decoded: known to ``store`` (with the bag's
    hash, when the bag records one) or defined inside the bag (then registered in ``store``).

    :param strict: False: a type this installation does not know is let through unchecked (a
        replay publishes the serialized bytes and only needs the Python type).
    :raises BagError: for a type without a definition or with another definition than ours.
    """
    wanted = set(topics)
    for conn in reader.connections:
        if conn.topic not in wanted:
            continue
        if not _known(store, conn.msgtype):
            if not strict:
                continue
            if not conn.msgdef.data or conn.msgdef.format.name != "MSG":
                raise BagError(f"bag {reader.path}: missing type definition for {conn.msgtype} "
                               f"(topic {conn.topic}): the bag carries none and the type is not "
                               "installed")
            try:
                store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
                store.get_msgdef(conn.msgtype)
            except (TypesysError, ValueError, KeyError) as exc:
                raise BagError(f"bag {reader.path}: bad type definition of {conn.msgtype} "
                               f"(topic {conn.topic}): {exc}") from None
        if conn.digest and conn.digest != store.hash_rihs01(conn.msgtype):
            raise BagError(f"bag {reader.path}: topic {conn.topic} was recorded with another "
                           f"definition of {conn.msgtype} ({conn.digest}) than this installation's "
                           f"({store.hash_rihs01(conn.msgtype)})")


def _stamp(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _xyz(p: Any) -> tuple[float, float, float]:
    return (float(p.x), float(p.y), float(p.z))


def read_bag(path: Union[str, Path], topics: Topics = DEFAULT_TOPICS,
             required: Sequence[str] = (), progress: bool = True) -> BagContents:
    """Read the node's inputs and the targets from a bag.

    :param path: bag directory, ``.mcap`` or ``.db3`` file.
    :param topics: the topic names to read.
    :param required: topics that must be in the bag (e.g. the ones named on the command line).
    :param progress: show progress on stderr.
    :return: :class:`BagContents`.
    :raises BagError: when the bag cannot be read, a required topic is missing, a topic has the
        wrong type, the bag holds none of the input topics, or only one of the point topics.
    """
    expected = {topics.fiducial_pairs: FIDUCIAL_PAIR, topics.working_point: POINT_STAMPED,
                topics.destination_point: POINT_STAMPED, topics.targets: FIDUCIAL_PAIR}
    store = make_typestore()
    with open_bag(path) as reader:
        types = topic_types(reader)
        listing = ", ".join(f"{t} [{ty}]" for t, ty in sorted(types.items())) or "none"
        for topic in required:
            if topic not in types:
                raise BagError(f"bag {path}: no topic {topic} (topics in the bag: {listing})")
        for topic, want in expected.items():
            if topic in types and types[topic] != want:
                raise BagError(f"bag {path}: topic {topic} has type {types[topic]}, "
                               f"expected {want}")
        inputs = [t for t in topics[:3] if t in types]
        if not inputs:
            raise BagError(f"bag {path}: none of the input topics {', '.join(topics[:3])} "
                           f"(topics in the bag: {listing}); name them with --fiducial-topic, "
                           "--working-topic, --destination-topic")
        points = [t for t in topics[1:3] if t in types]
        if len(points) == 1:
            missing = set(topics[1:3]) - set(points)
            raise BagError(f"bag {path}: has {points[0]} but not {missing.pop()}: points cannot "
                           "be paired")
        wanted = [t for t in expected if t in types]
        check_definitions(reader, store, wanted)
        conns = [c for c in reader.connections if c.topic in wanted]
        bar = Progress(f"reading {Path(path).name}", sum(c.msgcount for c in conns),
                       enabled=progress)
        counts = {t: 0 for t in wanted}
        ins: list[Union[PairMessage, PointMessage]] = []
        tgts: list[PairMessage] = []
        k = 0
        try:
            for conn, log_ns, raw in reader.messages(conns):
                k += 1
                try:
                    msg = store.deserialize_cdr(raw, conn.msgtype)
                except Exception as exc:  # noqa: BLE001 - any decoding failure of bag data
                    raise BagError(f"bag {path}: message {k} on {conn.topic} cannot be decoded "
                                   f"as {conn.msgtype}: {_describe(exc)}") from None
                counts[conn.topic] += 1
                if conn.topic in (topics.fiducial_pairs, topics.targets):
                    pair = PairMessage(log_ns, _stamp(msg.header), msg.fiducial_id,
                                       _xyz(msg.working_point), msg.header.frame_id,
                                       _xyz(msg.destination_point), msg.destination_frame_id)
                    (ins if conn.topic == topics.fiducial_pairs else tgts).append(pair)
                else:
                    stream = "working" if conn.topic == topics.working_point else "destination"
                    ins.append(PointMessage(log_ns, stream, _xyz(msg.point),
                                            msg.header.frame_id, _stamp(msg.header)))
                bar.update()
        except _READ_ERRORS as exc:
            raise BagError(f"bag {path}: truncated or corrupt after {k} message(s): "
                           f"{_describe(exc)}") from None
        bar.done()
    other = {t: ty for t, ty in types.items() if t not in expected}
    return BagContents(Path(path), tuple(ins), tuple(tgts), counts, other)


class RawMessage(NamedTuple):
    """A serialized (CDR) message as recorded."""

    topic: str
    msgtype: str
    log_ns: int
    data: bytes


def read_raw(path: Union[str, Path], topics: Optional[Sequence[str]] = None,
             progress: bool = True) -> list[RawMessage]:
    """All messages of ``topics`` (default: every topic) in receive-time order, serialized.

    :raises BagError: when the bag cannot be read, a named topic is missing or a type has no
        definition or another definition than this installation's.
    """
    store = make_typestore()
    with open_bag(path) as reader:
        types = topic_types(reader)
        if topics:
            missing = [t for t in topics if t not in types]
            if missing:
                raise BagError(f"bag {path}: no topic {', '.join(missing)} (topics in the bag: "
                               + (", ".join(sorted(types)) or "none") + ")")
        wanted = list(topics) if topics else list(types)
        check_definitions(reader, store, wanted, strict=False)
        conns = [c for c in reader.connections if c.topic in wanted]
        bar = Progress(f"reading {Path(path).name}", sum(c.msgcount for c in conns),
                       enabled=progress)
        out: list[RawMessage] = []
        try:
            for conn, log_ns, raw in reader.messages(conns):
                out.append(RawMessage(conn.topic, conn.msgtype, log_ns, bytes(raw)))
                bar.update()
        except _READ_ERRORS as exc:
            raise BagError(f"bag {path}: truncated or corrupt after {len(out)} message(s): "
                           f"{_describe(exc)}") from None
        bar.done()
    out.sort(key=lambda m: m.log_ns)
    return out


# -- writing -----------------------------------------------------------------------------------
class OutMessage(NamedTuple):
    """A message to write: ``kind`` ``"pair"`` (FiducialPair) or ``"point"`` (PointStamped)."""

    topic: str
    kind: str
    stamp_ns: int
    frame_id: str
    xyz: tuple[float, float, float]
    fiducial_id: str = ""
    destination_frame: str = ""
    destination: tuple[float, float, float] = (math.nan, math.nan, math.nan)


def write_bag(path: Union[str, Path], messages: Iterable[OutMessage], storage: str = "sqlite3",
              progress: bool = True, total: int = 0) -> int:
    """Write ``messages`` (receive time = header stamp) to a new bag directory ``path``.

    :return: the number of messages written.
    :raises BagError: on an unknown storage or when ``path`` exists.
    """
    if storage not in STORAGES:
        raise BagError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
    store = make_typestore()
    types = {"pair": FIDUCIAL_PAIR, "point": POINT_STAMPED}
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
        for m in messages:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, types[m.kind], typestore=store)
            header = Header(stamp=Time(sec=m.stamp_ns // 1_000_000_000,
                                       nanosec=m.stamp_ns % 1_000_000_000), frame_id=m.frame_id)
            if m.kind == "pair":
                msg = Pair(header=header, fiducial_id=m.fiducial_id, working_point=Point(*m.xyz),
                           destination_frame_id=m.destination_frame,
                           destination_point=Point(*m.destination))
            else:
                msg = Stamped(header=header, point=Point(*m.xyz))
            writer.write(conns[m.topic], m.stamp_ns,
                         store.serialize_cdr(msg, types[m.kind]))
            n += 1
            bar.update()
    bar.done()
    return n
