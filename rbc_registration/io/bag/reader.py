"""Reading registration bags with ``rosbags`` (no rclpy): the node's inputs and the targets
(:func:`read_bag`, decoded) or every message as recorded (:func:`read_raw`, serialized).

Every problem with a bag (missing, malformed, truncated, an unknown topic, a type without a
definition) raises :class:`~.records.BagError` with a message naming the bag and what was wrong.

A ``FiducialPair`` topic recorded with the definition without ``group`` and ``session``
(:data:`LEGACY_FIDUCIAL_PAIR`) is read too: every fiducial its own group, every measurement in
the current session, and a note says so.
"""

from __future__ import annotations

import math
import sqlite3
import struct
import sys
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, Sequence, Union

from rosbags.rosbag2 import Reader, ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from ...core.constants import DESTINATION, WORKING
from ...core.measurements.checks import stamp_seconds
from ...core.measurements.records import RejectedMeasurement
from ...pipeline.files import NotARegularFile, check_input_file
from ..progress import Progress
from .mcap_crc import check_mcap, storage_files
from .spool import InputSpool
from .records import (DEFAULT_TOPICS, FIDUCIAL_PAIR, POINT_STAMPED, BagContents, BagError,
                      PairMessage, PointMessage, RawMessage, Topics)
from .typestore import check_definitions, make_typestore

#: ``FiducialPair`` without ``group`` and ``session``, as bags recorded before those fields hold
#: it (the fields alone decide the type's hash and its CDR).
LEGACY_FIDUCIAL_PAIR = """std_msgs/Header header
string fiducial_id
geometry_msgs/Point working_point
string destination_frame_id
geometry_msgs/Point destination_point
"""


def legacy_typestore() -> Any:
    """A typestore whose ``FiducialPair`` is :data:`LEGACY_FIDUCIAL_PAIR`."""
    store = get_typestore(Stores.ROS2_KILTED)
    store.register(get_types_from_msg(LEGACY_FIDUCIAL_PAIR, FIDUCIAL_PAIR))
    return store


def _legacy_topics(reader: Reader, topics: Sequence[str], legacy: Any) -> list[str]:
    """The ``FiducialPair`` topics of ``topics`` whose every connection was recorded with
    :data:`LEGACY_FIDUCIAL_PAIR`: by its hash, or without a hash by the definition the bag
    carries (its own fields, before the dependencies' ``===`` blocks)."""
    digest = legacy.hash_rihs01(FIDUCIAL_PAIR)
    verdict: dict[str, bool] = {}
    for conn in reader.connections:
        if conn.topic not in topics or conn.msgtype != FIDUCIAL_PAIR:
            continue
        if conn.digest:
            old = conn.digest == digest
        else:
            own = (conn.msgdef.data or "").split("\n===")[0]
            fields = {line.split()[1] for line in own.splitlines()
                      if len(line.split()) >= 2 and not line.lstrip().startswith("#")}
            old = bool(own.strip()) and not {"group", "session"} & fields
        verdict[conn.topic] = verdict.get(conn.topic, True) and old
    return [t for t, old in verdict.items() if old]

try:        # rosbags reads .db3 files through apsw where it is installed (its errors while
    import apsw     # iterating are not wrapped); the standard library's sqlite3 otherwise
    _SQLITE_ERRORS: tuple[type[BaseException], ...] = (sqlite3.Error, apsw.Error)
except ImportError:             # pragma: no cover - depends on the rosbags installation
    _SQLITE_ERRORS = (sqlite3.Error,)

#: Errors of rosbags and of the storage libraries on a bad or truncated file (a corrupt mcap
#: length field raises OverflowError, or MemoryError in an mcap without chunks).
_READ_ERRORS = (ReaderError, SerdeError, TypesysError, struct.error, OSError, EOFError, KeyError,
                IndexError, ValueError, UnicodeDecodeError, AssertionError,
                OverflowError, MemoryError) + _SQLITE_ERRORS


@contextmanager
def open_bag(path: Union[str, Path]) -> Iterator[Reader]:
    """Open a rosbag2 directory, ``.mcap`` or ``.db3`` file for reading; the CRCs of its mcap
    files are checked first (:mod:`.mcap_crc`).

    :raises BagError: when it does not exist, cannot be opened or fails a CRC check.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag {p}: no such file or directory")
    if p.is_dir() and not (p / "metadata.yaml").exists():
        raise BagError(f"bag {p}: not a rosbag2 directory (no metadata.yaml)")
    files = storage_files(p)             # metadata.yaml read once for the checks below
    # a FIFO (or a device) as the metadata or a storage file would block open() for ever
    for f in ([p / "metadata.yaml"] if p.is_dir() else []) + files:
        try:
            check_input_file(str(f), sys.maxsize)
        except NotARegularFile as exc:
            raise BagError(f"bag {p}: {exc}") from None
        except OSError:
            pass                        # missing or unreadable: opening it below says so
    for f in files:
        if f.suffix != ".mcap" or not f.is_file():
            continue
        try:
            check_mcap(f)
        except OSError:
            pass                        # unreadable: opening it below says so
    try:
        reader = Reader(p)
        reader.open()
    except _READ_ERRORS as exc:
        raise BagError(f"bag {p}: cannot open (truncated or corrupt?): {_describe(exc)}") from None
    if p.is_dir():
        try:
            _check_db3_topics(p, reader, files)
        except BagError:
            reader.close()
            raise
    try:
        yield reader
    finally:
        try:
            reader.close()
        except _READ_ERRORS:
            pass


def _check_db3_topics(bag: Path, reader: Reader, files: Sequence[Path]) -> None:
    """Every topic (name, type) with messages in a ``.db3`` file of a bag directory must be one
    its ``metadata.yaml`` lists, which rosbags reads the storage by: a hand-edited metadata (a
    topic "renamed" there) made a topic's messages vanish with only a count note.

    :param files: the bag's storage files (:func:`~.mcap_crc.storage_files`).
    :raises BagError: naming what each side has that the other has not.
    """
    listed = {(c.topic, c.msgtype) for c in reader.connections}
    stored: set[tuple[str, str]] = set()
    unread: set[tuple[str, str]] = set()     # in the storage with messages, not in the metadata
    for f in files:
        if f.suffix != ".db3" or not f.is_file():
            continue
        try:
            with closing(sqlite3.connect(f"file:{f}?mode=ro", uri=True)) as db:
                for topic_id, name, msgtype in db.execute("SELECT id, name, type FROM topics"):
                    key = (str(name), str(msgtype))
                    stored.add(key)
                    if key not in listed and db.execute(
                            "SELECT EXISTS(SELECT 1 FROM messages WHERE topic_id = ?)",
                            (topic_id,)).fetchone()[0]:
                        unread.add(key)
        except sqlite3.Error:
            return                      # not readable this way: rosbags has opened it
    if not unread:
        return                          # a listed topic the storage lacks: count_mismatches
    only_stored = ", ".join(f"{n} [{t}]" for n, t in sorted(unread))
    only_listed = ", ".join(f"{n} [{t}]" for n, t in sorted(listed - stored)) or "none"
    raise BagError(f"bag {bag}: metadata.yaml and the storage disagree on the topics: with "
                   f"messages only in the storage: {only_stored}; only in metadata.yaml: "
                   f"{only_listed} (a "
                   f"hand-edited metadata.yaml? rosbag2 writes both alike; rosbags reads the "
                   f"storage by the metadata's names)")


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


def _stamp(header: Any) -> tuple[float, str]:
    """The header stamp [s] and ``""``, or NaN and why it is not a time (the message is
    rejected as the node rejects it)."""
    try:
        return stamp_seconds(int(header.stamp.sec), int(header.stamp.nanosec)), ""
    except RejectedMeasurement as exc:
        return math.nan, exc.message


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _xyz(p: Any) -> tuple[float, float, float]:
    return (float(p.x), float(p.y), float(p.z))


def _checked_types(path: Union[str, Path], reader: Any, topics: Topics,
                   expected: dict[str, str], required: Sequence[str]) -> dict[str, str]:
    """The bag's ``{topic: type}``, refused (naming the topics in the bag) when a required
    topic is missing, a topic has the wrong type or none of the input topics is there."""
    types = topic_types(reader)
    listing = ", ".join(f"{t} [{ty}]" for t, ty in sorted(types.items())) or "none"
    for topic in required:
        if topic not in types:
            raise BagError(f"bag {path}: no topic {topic} (topics in the bag: {listing})")
    for topic, want in expected.items():
        if topic in types and types[topic] != want:
            raise BagError(f"bag {path}: topic {topic} has type {types[topic]}, "
                           f"expected {want}")
    if not any(t in types for t in topics[:3]):
        raise BagError(f"bag {path}: none of the input topics {', '.join(topics[:3])} "
                       f"(topics in the bag: {listing}); name them with --fiducial-topic, "
                       "--working-topic, --destination-topic")
    return types


def read_bag(path: Union[str, Path], topics: Topics = DEFAULT_TOPICS,
             required: Sequence[str] = (), progress: bool = True) -> BagContents:
    """Read the node's inputs and the targets from a bag.

    :param path: bag directory, ``.mcap`` or ``.db3`` file.
    :param topics: the topic names to read.
    :param required: topics that must be in the bag (e.g. the ones named on the command line).
    :param progress: show progress on stderr.
    :return: :class:`BagContents`; its ``inputs`` are an :class:`~.spool.InputSpool` (read
        message by message into a temporary file: memory flat in the messages), the targets
        a tuple.
    :raises BagError: when the bag cannot be read, a required topic is missing, a topic has the
        wrong type, the bag holds none of the input topics, or only one of the point topics.
    """
    if len(set(topics[:4])) < 4:
        raise BagError(f"bag {path}: each topic can be one input only, got fiducial pairs "
                       f"{topics.fiducial_pairs}, working points {topics.working_point}, "
                       f"destination points {topics.destination_point}, targets "
                       f"{topics.targets}")
    expected = {topics.fiducial_pairs: FIDUCIAL_PAIR, topics.working_point: POINT_STAMPED,
                topics.destination_point: POINT_STAMPED, topics.targets: FIDUCIAL_PAIR}
    store = make_typestore()
    with open_bag(path) as reader:
        types = _checked_types(path, reader, topics, expected, required)
        wanted = [t for t in expected if t in types]
        legacy_store = legacy_typestore()
        legacy = _legacy_topics(reader, wanted, legacy_store)
        check_definitions(reader, store, [t for t in wanted if t not in legacy])
        conns = [c for c in reader.connections if c.topic in wanted]
        bar = Progress(f"reading {Path(path).name}", sum(c.msgcount for c in conns),
                       enabled=progress)
        counts = {t: 0 for t in wanted}
        ins = InputSpool()      # the inputs on disk, not as Python objects: flat in messages
        tgts: list[PairMessage] = []
        k = 0
        try:
            for conn, log_ns, raw in reader.messages(conns):
                k += 1
                try:
                    msg = (legacy_store if conn.topic in legacy else store).deserialize_cdr(
                        raw, conn.msgtype)
                except Exception as exc:  # noqa: BLE001 - any decoding failure of bag data
                    raise BagError(f"bag {path}: message {k} on {conn.topic} cannot be decoded "
                                   f"as {conn.msgtype}: {_describe(exc)}") from None
                counts[conn.topic] += 1
                if conn.topic in (topics.fiducial_pairs, topics.targets):
                    stamp, stamp_error = _stamp(msg.header)
                    pair = PairMessage(log_ns, stamp, msg.fiducial_id,
                                       _xyz(msg.working_point), msg.header.frame_id,
                                       _xyz(msg.destination_point), msg.destination_frame_id,
                                       _stamp_ns(msg.header), stamp_error,
                                       getattr(msg, "group", ""), getattr(msg, "session", ""))
                    (ins if conn.topic == topics.fiducial_pairs else tgts).append(pair)
                else:
                    stream = WORKING if conn.topic == topics.working_point else DESTINATION
                    ins.append(PointMessage(log_ns, stream, _xyz(msg.point),
                                            msg.header.frame_id, *_stamp(msg.header)))
                bar.update()
        except BagError:
            raise                       # already names the bag and the message
        except _READ_ERRORS as exc:
            raise BagError(f"bag {path}: truncated or corrupt after {k} message(s): "
                           f"{_describe(exc)}") from None
        bar.done()
    # A topic without messages (``ros2 bag record -a`` lists every topic it saw) decides
    # nothing: the point streams count by the messages read (not the metadata's counts).
    empty = [t for t in topics[:3] if t in types and not counts[t]]
    points = [t for t in topics[1:3] if counts.get(t)]
    if len(points) == 1:
        missing = (set(topics[1:3]) - set(points)).pop()
        raise BagError(f"bag {path}: has {points[0]} but not {missing}"
                       f"{' (no messages)' if missing in types else ''}: points cannot be "
                       "paired")
    notes = tuple(f"bag {path}: {t}: no messages (ignored)" for t in empty)
    notes += tuple(f"bag {path}: {t} was recorded with a FiducialPair without group and "
                   "session: read as empty (every fiducial its own group, every measurement in "
                   "the current session)" for t in legacy if counts.get(t))
    other = {t: ty for t, ty in types.items() if t not in expected}
    return BagContents(Path(path), ins, tuple(tgts), counts, other,
                       count_mismatches(path, conns, counts), notes)


def listed_counts(conns: Sequence[Any]) -> dict[str, int]:
    """``{topic: messages}`` as the bag's metadata lists them (its connections' counts)."""
    listed: dict[str, int] = {}
    for c in conns:
        listed[c.topic] = listed.get(c.topic, 0) + int(c.msgcount)
    return listed


def count_mismatches(path: Union[str, Path], conns: Sequence[Any], read: dict[str, int]
                     ) -> tuple[str, ...]:
    """One line per topic whose count in the bag's metadata (``message_count`` of its
    connections) differs from the messages read: the storage lost messages, or another storage
    file was put in its place."""
    listed = listed_counts(conns)
    return tuple(f"bag {path}: {topic}: the metadata lists {n} message(s), {read.get(topic, 0)} "
                 "were read (the storage and its metadata disagree: messages lost?)"
                 for topic, n in sorted(listed.items()) if n != read.get(topic, 0))


def read_raw(path: Union[str, Path], topics: Optional[Sequence[str]] = None,
             progress: bool = True, warn: Optional[Callable[[str], None]] = None
             ) -> list[RawMessage]:
    """All messages of ``topics`` (default: every topic) in receive-time order, serialized.

    :param warn: called with each line of :func:`count_mismatches` (messages the metadata lists
        that were not read, or the other way round), and, when ``topics`` is not given, with the
        line of each topic whose type cannot be decoded here (left out; without ``warn`` that
        refuses the bag).

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
        if topics:
            wanted = list(topics)
            check_definitions(reader, store, wanted, strict=False)
        else:
            # every topic: one recorded with another definition than this installation's (e.g.
            # a /rosout of another ROS release) is left out with a line, not the whole bag
            wanted = []
            for topic in types:
                try:
                    check_definitions(reader, store, [topic], strict=False)
                    wanted.append(topic)
                except BagError as exc:
                    if warn is None:
                        raise
                    warn(f"{exc}: skipped")
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
    if warn is not None:
        read: dict[str, int] = {}
        for m in out:
            read[m.topic] = read.get(m.topic, 0) + 1
        for line in count_mismatches(path, conns, read):
            warn(line)
    out.sort(key=lambda m: m.log_ns)
    return out
