"""Message type definitions for reading and writing bags with ``rosbags``: ROS 2 Kilted's
standard types plus rbc_registration_interfaces from its ``.msg`` files, and the check that a
bag's types can be decoded with them.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Iterable

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from .records import INTERFACE_PACKAGE, BagError


def interface_msg_dirs() -> list[Path]:
    """Where the ``.msg`` files of rbc_registration_interfaces may be: ``$RBC_MSG_DIR``, the
    share directory of every prefix in ``AMENT_PREFIX_PATH`` and of this Python's prefix, the
    copy this package installs (``share/rbc_registration/msg``, for an installation without
    ROS), then the source tree (``msg_docs/``)."""
    rel = Path("share") / INTERFACE_PACKAGE / "msg"
    out = [Path(os.environ["RBC_MSG_DIR"])] if os.environ.get("RBC_MSG_DIR") else []
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    out += [Path(p) / rel for p in prefixes + [sys.prefix]]
    out.append(Path(sys.prefix) / "share" / "rbc_registration" / "msg")
    out.append(Path(__file__).resolve().parents[3] / "msg_docs" / INTERFACE_PACKAGE / "msg")
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
