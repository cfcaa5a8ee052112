"""The records of the measurement journal (no file access, no rclpy): their line encoding,
the per-record checksum bound to the setup, and bounded parsing. See
:mod:`rbc_registration.pipeline.journal` for the file and what the bounds are for.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import zlib
from typing import Any, Optional

from ..core.errors import InputError
from ..core.measurements.accumulator import EnabledChange, Measurement, Record
from .state_dir import JOURNAL_NAME  # noqa: F401  (the journal's file name, also importable here)

JOURNAL_VERSION = 2
#: Versions this module reads (1: without record checksums, rewritten as 2 on load).
READABLE_VERSIONS = (1, 2)
#: Bounds on the journal's content (a record is < 5 kB: ids, groups and sessions are at most 256
#: characters each, 6 bytes per character escaped).
MAX_LINE_BYTES = 8192
MAX_INT_DIGITS = 20
MAX_BRACKETS = 4
MAX_JOURNAL_BYTES = 8 << 30
_SEAL = re.compile(rb',"c":"([0-9a-f]{8})"\}$')
_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"')


class JournalMismatch(InputError):
    """The journal in ``state_dir`` was written with other frames or another dimension."""


_json_string = json.encoder.encode_basestring_ascii  # what json.dumps uses for a str
_float_repr = float.__repr__                          # what json.dumps uses for a float


def _measurement_line(m: Measurement) -> Optional[str]:
    """The journal line of ``m`` written directly: the same characters ``json.dumps`` gives
    (keys in order, ``(",", ":")`` separators, ASCII, floats by ``float.__repr__``), at about
    half the cost per ingested message. ``None`` (then :func:`record_to_json` takes the
    ``json`` path, which refuses NaN and inf) unless the id, group and session are str and every
    coordinate and the stamp a float (``float.__repr__`` raises ``TypeError`` otherwise) and
    finite (the ``repr`` of a finite float has no "n", that of ``nan`` / ``inf`` has)."""
    if type(m.fiducial_id) is not str or type(m.group) is not str \
            or type(m.session) is not str:
        return None
    try:
        w = ",".join(map(_float_repr, m.working))
        d = ",".join(map(_float_repr, m.destination))
        s = _float_repr(m.stamp_s)
    except TypeError:
        return None
    if "n" in w or "n" in d or "n" in s:
        return None
    auto = ',"auto":true' if m.auto_id else ""
    if m.group:
        auto += f',"g":{_json_string(m.group)}'
    if m.session:
        auto += f',"se":{_json_string(m.session)}'
    return f'{{"t":"m","id":{_json_string(m.fiducial_id)},"w":[{w}],"d":[{d}],"s":{s}{auto}}}'


def record_to_json(record: Record) -> str:
    """One journal line (without the newline) for ``record``."""
    if type(record) is Measurement:
        line = _measurement_line(record)
        if line is not None:
            return line
    if isinstance(record, Measurement):
        obj: dict[str, Any] = {"t": "m", "id": record.fiducial_id, "w": list(record.working),
                               "d": list(record.destination), "s": record.stamp_s}
        if record.auto_id:
            obj["auto"] = True
        if record.group:
            obj["g"] = record.group
        if record.session:
            obj["se"] = record.session
    elif isinstance(record, EnabledChange):
        obj = {"t": "e", "id": record.fiducial_id, "on": record.enabled}
    else:
        raise TypeError(f"record must be a Measurement or EnabledChange, got {record!r}")
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


def setup_digest(header: dict[str, Any]) -> bytes:
    """The digest every record's checksum includes: SHA-256 of the canonical header (version,
    frames, dimension), truncated to 16 hex digits."""
    canonical = json.dumps(header, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()[:16].encode("ascii")


def seal(body: bytes, digest: bytes) -> bytes:
    """``body`` (a JSON object) with its checksum field ``"c"`` appended."""
    return body[:-1] + b',"c":"%08x"}' % zlib.crc32(digest + body)


def unseal(line: bytes, digest: bytes) -> bytes:
    """The record of a sealed line, without its checksum field.

    :raises ValueError: when the line has no checksum or it does not match (a changed byte, or
        a record written for another setup).
    """
    match = _SEAL.search(line)
    if match is None:
        raise ValueError("no checksum")
    body = line[:match.start()] + b"}"
    if b"%08x" % zlib.crc32(digest + body) != match.group(1):
        raise ValueError("checksum mismatch (corrupt, or written for another setup)")
    return body


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"integer of {len(text)} digits")
    return int(text)


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number")


def parse_line(text: str) -> Any:
    """``json.loads`` with the journal's bounds (see the module docstring).

    :raises ValueError: naming the bound that was exceeded.
    """
    if len(text) > MAX_LINE_BYTES:
        raise ValueError(f"line of {len(text)} characters, more than {MAX_LINE_BYTES}")
    brackets = sum(map(_STRINGS.sub("", text).count, "[{"))
    if brackets > MAX_BRACKETS:
        raise ValueError(f"{brackets} brackets, more than {MAX_BRACKETS} (nesting)")
    return json.loads(text, parse_int=_bounded_int, parse_constant=_no_constant)


def record_from_json(line: str) -> Record:
    """Parse one journal record (without its checksum field).

    :raises ValueError: naming what is wrong with the line.
    """
    return record_from_object(parse_line(line), line)


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def record_from_object(obj: Any, line: str = "") -> Record:
    """A journal record from its parsed JSON object: exactly the fields and types
    :func:`record_to_json` writes (see :func:`record_from_json`)."""
    if not isinstance(obj, dict):
        raise ValueError(f"a journal record must be a JSON object, got {line[:80]!r}")
    kind = obj.get("t")
    keys = set(obj) - {"c"}
    if kind == "m":
        if not {"t", "id", "w", "d", "s"} <= keys <= {"t", "id", "w", "d", "s", "auto", "g", "se"}:
            raise ValueError(f"measurement fields must be t, id, w, d, s[, auto, g, se]: "
                             f"{line[:80]!r}")
        w, d, fid, stamp = obj["w"], obj["d"], obj["id"], obj["s"]
        if not (isinstance(w, list) and isinstance(d, list) and 2 <= len(w) == len(d) <= 3
                and all(_number(v) for v in [*w, *d])):
            raise ValueError(f"measurement coordinates must be numbers: {line[:80]!r}")
        if not isinstance(fid, str) or not _number(stamp) or not math.isfinite(stamp):
            raise ValueError(f"measurement id must be a string and s a finite number: "
                             f"{line[:80]!r}")
        if not isinstance(obj.get("auto", False), bool):
            raise ValueError(f"measurement auto must be a boolean: {line[:80]!r}")
        group, session = obj.get("g", ""), obj.get("se", "")
        if not isinstance(group, str) or not isinstance(session, str):
            raise ValueError(f"measurement g (group) and se (session) must be strings: "
                             f"{line[:80]!r}")
        return Measurement(fid, tuple(float(v) for v in w), tuple(float(v) for v in d),
                           float(stamp), obj.get("auto", False), group, session)
    if kind == "e":
        if keys != {"t", "id", "on"} or not isinstance(obj["id"], str) \
                or not isinstance(obj["on"], bool):
            raise ValueError(f"an enable change must be t, id (string), on (boolean): "
                             f"{line[:80]!r}")
        return EnabledChange(obj["id"], obj["on"])
    raise ValueError(f"unknown journal record type {kind!r}")
