"""The records of registration bags: topic names, message type names, storages, what a read
found and what to write; :class:`BagError`. Plain Python (no rosbags, no numpy), so the
command-line parser can use it.

A bag holds the inputs of ``registration_node`` (docs/BAGS.md): ``FiducialPair`` messages on
``/registration_node/fiducial_pairs``, or ``geometry_msgs/PointStamped`` on
``/registration_node/working_point`` and ``/registration_node/destination_point`` (paired by
stamp), and optionally targets with truth on ``/registration_node/targets`` (``FiducialPair``:
``fiducial_id`` = target id, ``working_point`` = measured, ``destination_point`` = truth or NaN).
Units: metres (REP 103). Both rosbag2 storages are read and written: sqlite3 (``.db3``) and mcap,
as a bag directory (with ``metadata.yaml``) or a single storage file.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import NamedTuple, Union

from ...core.errors import InputError
from ...pipeline.inputs import PairMessage, PointMessage

FIDUCIAL_PAIR = "rbc_registration_interfaces/msg/FiducialPair"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"
INTERFACE_PACKAGE = "rbc_registration_interfaces"
STORAGES = ("sqlite3", "mcap")
#: ``replay``: the time scales accepted (0.001 plays a 1 s bag in 17 min; 1e6: as fast as the
#: graph takes it) and the longest wait for subscribers [s].
REPLAY_RATES = (1e-3, 1e6)
MAX_REPLAY_WAIT = 3600.0
#: ``replay --max-gap``: the longest pause between two messages [s of wall time] (a longer gap
#: in the receive times, e.g. one message logged days late, is shortened to it).
DEFAULT_MAX_GAP = 60.0
#: ``synth-bag --period``: seconds between measurements (stamps are in whole nanoseconds and
#: the bag must end before the int64 nanosecond stamps overflow).
PERIODS = (1e-9, 3600.0)
#: Its default: more than twice the default ``pair_slop`` (0.02 s), so that the point streams of
#: ``--points`` are never ambiguous (:mod:`rbc_registration.core.measurements.pairing`; the earlier
#: default
#: 0.02 s, equal to the slop, put every point within the slop of two points of the other stream).
SYNTH_PERIOD_S = 0.05
#: ``OutMessage.kind`` -> the message type written.
MESSAGE_TYPES = {"pair": FIDUCIAL_PAIR, "point": POINT_STAMPED}

__all__ = ["DEFAULT_TOPICS", "FIDUCIAL_PAIR", "INTERFACE_PACKAGE", "MESSAGE_TYPES",
           "POINT_STAMPED", "STORAGES", "SYNTH_PERIOD_S", "BagContents", "BagError",
           "OutMessage", "PairMessage",
           "PointMessage", "RawMessage", "Topics", "node_name_error", "topic_name_error"]


#: A token of a ROS name (rcl's rules): a letter or underscore, then letters, digits, underscores.
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


#: rcl's longest topic name (RMW_TOPIC_MAX_NAME_LENGTH: 255 less the DDS prefix's 8).
MAX_TOPIC_LENGTH = 247
#: The longest ``~/`` topic of the node (its name's topics must fit in MAX_TOPIC_LENGTH).
_LONGEST_SUFFIX = "/destination_point"
#: The longest node name (with its namespace) whose topics are valid ROS topic names.
MAX_NODE_NAME_LENGTH = MAX_TOPIC_LENGTH - 1 - len(_LONGEST_SUFFIX)


def node_name_error(name: str) -> str:
    """Why ``name`` is not a valid ROS node name, optionally with its namespace (``cell_a/reg``:
    tokens separated by ``/``, at most :data:`MAX_NODE_NAME_LENGTH` characters, so that its
    topics fit rcl's limit), or ""."""
    tokens = name.strip("/").split("/")
    if len(name.strip("/")) > MAX_NODE_NAME_LENGTH or not all(_TOKEN.fullmatch(t)
                                                               for t in tokens):
        return (f"{name!r} is not a valid ROS node name (letters, digits and underscores, not "
                f"starting with a digit, at most {MAX_NODE_NAME_LENGTH} characters, so that "
                f"its topics are at most {MAX_TOPIC_LENGTH}; a namespace before it with '/')")
    return ""


def topic_name_error(name: str) -> str:
    """Why ``name`` is not a valid resolved ROS topic name (``/`` then tokens separated by
    ``/``, at most :data:`MAX_TOPIC_LENGTH` characters), or ""."""
    tokens = name[1:].split("/") if name.startswith("/") else None
    if tokens is None or len(name) > MAX_TOPIC_LENGTH or not all(_TOKEN.fullmatch(t)
                                                                  for t in tokens):
        return (f"{name!r} is not a valid ROS topic name ('/' then names of letters, digits and "
                f"underscores, not starting with a digit, separated by '/'; at most "
                f"{MAX_TOPIC_LENGTH} characters)")
    return ""


class BagError(InputError):
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


class BagContents(NamedTuple):
    """What :func:`read_bag` found: the node's inputs in bag (receive-time) order, every message
    as recorded (duplicates are the accumulator's to reject, as in the node), the targets,
    message counts per topic (as read), the other topics of the bag (name -> type), a line per
    topic whose metadata count differs from the messages read and notes (an input topic
    without messages)."""

    path: Path
    #: In bag order; :func:`read_bag` gives an on-disk ``InputSpool`` that reads as this tuple.
    inputs: tuple[Union[PairMessage, PointMessage], ...]
    targets: tuple[PairMessage, ...]
    counts: dict[str, int]
    other_topics: dict[str, str]
    count_mismatches: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


class RawMessage(NamedTuple):
    """A serialized (CDR) message as recorded."""

    topic: str
    msgtype: str
    log_ns: int
    data: bytes


class OutMessage(NamedTuple):
    """A message to write: ``kind`` ``"pair"`` (FiducialPair) or ``"point"`` (PointStamped);
    ``group`` and ``session`` as in ``FiducialPair`` (pairs only; empty: its own group, the
    current session)."""

    topic: str
    kind: str
    stamp_ns: int
    frame_id: str
    xyz: tuple[float, float, float]
    fiducial_id: str = ""
    destination_frame: str = ""
    destination: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    group: str = ""
    session: str = ""
