"""Named things among the node's parameters: ``target_frames``, named targets (working-frame
points) the node publishes on ``/tf_static`` as corrected destination frames, and the rule for
the name of a saved calibration (``calibration_name``, a bare ``calibration_file``). Pure Python
(no numpy).

An entry is ``NAME:X,Y,Z``: a tf frame id, a colon and three numbers [m] in the working frame
(in 2D too: z passes through as for any target), e.g. ``peg_hole:0.42,0.1,0.05``.
"""

from __future__ import annotations

import math
import re
from typing import Any, NamedTuple, Optional, Sequence

from ..core.frames import frame_id_problem
from ..core.measurements.records import quote
from ..core.validation import MAX_ABS_COORDINATE

#: Most entries of ``target_frames`` (each is one answer per model, under the publishing lock).
MAX_TARGET_FRAMES = 1000
#: A calibration name: letters, digits, ``_``, ``-``, ``.``; not starting with ``.`` or ``-``.
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}\Z")
_SUFFIXES = (".yaml", ".yml")


class TargetFrame(NamedTuple):
    """One named target: the tf child frame ``name`` and its working-frame point [m]."""

    name: str
    point: tuple[float, float, float]


def parse_target_frames(value: Any) -> tuple[tuple[TargetFrame, ...], Optional[str]]:
    """The entries of a ``target_frames`` value (a list of ``NAME:X,Y,Z`` strings; ``None`` or an
    empty list: none), and why it is not valid (one line) or None."""
    if value is None:
        return (), None
    if isinstance(value, str) or not isinstance(value, Sequence):
        return (), (f"target_frames must be a list of strings NAME:X,Y,Z (metres, working "
                    f"frame), got {quote(str(value))}")
    if len(value) > MAX_TARGET_FRAMES:
        return (), f"target_frames: {len(value)} entries, at most {MAX_TARGET_FRAMES}"
    out: list[TargetFrame] = []
    for k, entry in enumerate(value):
        where = f"target_frames[{k}]"
        if not isinstance(entry, str):
            return (), f"{where} must be a string NAME:X,Y,Z, got {quote(str(entry))}"
        name, sep, numbers = entry.rpartition(":")
        parts = numbers.split(",")
        if not sep or len(parts) != 3:
            return (), (f"{where} {quote(entry)} must be NAME:X,Y,Z (a frame name, a colon, "
                        f"three numbers in metres in the working frame)")
        problem = frame_id_problem(name)
        if problem:
            return (), f"{where}: the name is a tf frame id: it {problem}, got {quote(name)}"
        try:
            xyz = tuple(float(p) for p in parts)
        except ValueError:
            return (), f"{where} {quote(entry)}: X,Y,Z must be numbers (metres)"
        if not all(math.isfinite(v) and abs(v) <= MAX_ABS_COORDINATE for v in xyz):
            return (), (f"{where} {quote(entry)}: coordinates must be finite and within "
                        f"±{MAX_ABS_COORDINATE:g} m")
        if any(f.name == name for f in out):
            return (), f"{where}: the name {quote(name)} is given twice"
        out.append(TargetFrame(name, (xyz[0], xyz[1], xyz[2])))
    return tuple(out), None


def target_frames_problem(value: Any, working_frame: str, destination_frame: str
                          ) -> Optional[str]:
    """Why ``value`` is not a valid ``target_frames`` for the node's frames, or None: each name
    is a child of ``destination_frame`` on /tf_static, so neither frame may be one."""
    frames, error = parse_target_frames(value)
    if error:
        return error
    for k, f in enumerate(frames):
        if f.name in (working_frame, destination_frame):
            which = "working_frame" if f.name == working_frame else "destination_frame"
            return (f"target_frames[{k}]: the name {quote(f.name)} is {which}: a target frame "
                    f"is a child of destination_frame on /tf_static, give it its own name")
    return None


def calibration_name_problem(name: str) -> Optional[str]:
    """Why ``name`` is not a calibration name (``calibration_name``, a bare
    ``calibration_file``), or None."""
    if not _NAME.match(name):
        return (f"a calibration name is 1-100 letters, digits, '_', '-' or '.', not starting "
                f"with '.' or '-', got {quote(name)}")
    if name.lower().endswith(_SUFFIXES):
        return f"a calibration name has no .yaml (it is added), got {quote(name)}"
    return None


def is_calibration_name(value: str) -> bool:
    """Whether a ``calibration_file`` value is a bare name (no ``/``, not starting with ``~``,
    not ending in ``.yaml``/``.yml``) rather than a path."""
    return bool(value) and "/" not in value and not value.startswith("~") and \
        not value.lower().endswith(_SUFFIXES)
