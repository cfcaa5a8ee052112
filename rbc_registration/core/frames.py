"""The rule for a tf frame id: one definition for the node's frame parameters and the frames of
a calibration file. Pure Python.
"""

from __future__ import annotations

from typing import Optional

#: Longest frame id accepted [characters].
MAX_FRAME_ID = 1000


def frame_id_problem(value: str) -> Optional[str]:
    """Why ``value`` is not a tf2 frame id (the phrase after the parameter's name), or ``None``.

    A frame id is non-empty, at most :data:`MAX_FRAME_ID` characters, does not start with '/'
    (tf2 refuses it) and holds no whitespace or control characters (one word on a command
    line, in a log line and in ``static_transform_publisher --frame-id``).
    """
    if not value:
        return "must not be empty"
    if len(value) > MAX_FRAME_ID:
        return f"must be at most {MAX_FRAME_ID} characters"
    if value.startswith("/"):
        return "must not start with '/' (tf2 refuses it)"
    if any(c.isspace() or not c.isprintable() for c in value):
        return "must not contain whitespace or control characters"
    return None


#: Why the registration's two frames must differ.
REGISTRATION_FRAMES = ("a registration maps one frame into another; tf2 drops a frame's "
                       "transform into itself")


def same_frame_problem(parent_name: str, parent: str, child: str,
                       why: str = REGISTRATION_FRAMES) -> Optional[str]:
    """Why a transform of ``child`` into ``parent`` means nothing (the same frame; ``why``
    says what it is for; the phrase after the child frame's name), or ``None``."""
    if parent == child:
        return f"must differ from {parent_name}, both are {parent!r} ({why})"
    return None
