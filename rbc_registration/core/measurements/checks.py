"""The value rules of one fiducial measurement: its id, stamp, stamp age and coordinates.

:meth:`.accumulator.FiducialAccumulator.prepare` applies them live and
:meth:`~.accumulator.FiducialAccumulator.check_record` again on a record read back from a
journal (the same functions both times). Each raises :class:`.records.RejectedMeasurement`
with its reason and a message naming what was wrong. Pure Python.
"""

from __future__ import annotations

import math

from numpy.typing import ArrayLike

from .records import EnabledChange, Measurement, Record, RejectedMeasurement, quote
from ..validation import MAX_ABS_COORDINATE

#: Longest fiducial id accepted [characters].
MAX_ID_LENGTH = 256
#: The character a UTF-8 decoder puts for bytes that are not UTF-8.
REPLACEMENT_CHARACTER = "\ufffd"


def check_id(fiducial_id: object) -> None:
    """The rule for a given fiducial id (live and on replay)."""
    if not isinstance(fiducial_id, str):
        raise RejectedMeasurement("malformed", f"fiducial_id must be a string, "
                                               f"got {quote(fiducial_id)}")
    if len(fiducial_id) > MAX_ID_LENGTH or any(c in fiducial_id for c in "\n\r\0"):
        raise RejectedMeasurement("malformed", f"fiducial_id must be at most {MAX_ID_LENGTH} "
                                               f"characters without line breaks, "
                                               f"got {quote(fiducial_id)}")


def check_label(name: str, label: object) -> None:
    """The rule for a measurement's ``group`` or ``session`` label (live and on replay): a
    string of at most :data:`MAX_ID_LENGTH` characters without line breaks or U+FFFD."""
    if not isinstance(label, str):
        raise RejectedMeasurement("malformed", f"{name} must be a string, got {quote(label)}")
    if (len(label) > MAX_ID_LENGTH or any(c in label for c in "\n\r\0")
            or REPLACEMENT_CHARACTER in label):
        raise RejectedMeasurement("malformed", f"{name} must be at most {MAX_ID_LENGTH} "
                                               f"characters of valid UTF-8 without line "
                                               f"breaks, got {quote(label)}")


def check_new_id(fiducial_id: object) -> None:
    """The rule for the given id of a new measurement: :func:`check_id`, and no U+FFFD.

    U+FFFD is what a UTF-8 decoder puts for bytes that are not UTF-8 (rclpy decodes a message's
    string with ``errors="replace"``), so two different ids sent as such bytes would become one
    fiducial. Not applied on replay: a journal written before this rule keeps its records.
    """
    check_id(fiducial_id)
    if REPLACEMENT_CHARACTER in fiducial_id:  # type: ignore[operator]
        raise RejectedMeasurement("malformed", f"fiducial_id is not valid UTF-8 (it holds "
                                               f"U+FFFD, which a decoder puts for bytes that "
                                               f"are not UTF-8), got {quote(fiducial_id)}")


#: Nanoseconds per second: the ``nanosec`` of a ``builtin_interfaces/Time`` is below it.
NS_PER_S = 1_000_000_000


def stamp_seconds(sec: int, nanosec: int) -> float:
    """A message stamp (``builtin_interfaces/Time``: ``sec``, ``nanosec``) in seconds.

    :raises RejectedMeasurement: ``malformed`` when ``nanosec`` is not in [0, 10^9): such a
        stamp is not a time (read as ``sec + nanosec·1e-9`` it would be another time, and
        pair or conflict with measurements it has nothing to do with).
    """
    if not 0 <= nanosec < NS_PER_S:
        raise RejectedMeasurement("malformed", f"header.stamp.nanosec must be below 10^9 "
                                               f"(a builtin_interfaces/Time), got {nanosec} "
                                               f"(sec {sec})")
    return sec + nanosec * 1e-9


def check_stamp(stamp_s: object) -> float:
    """The stamp as a finite float (live and on replay)."""
    if isinstance(stamp_s, bool):
        raise RejectedMeasurement("malformed", f"stamp must be a number, got {stamp_s!r}")
    try:
        stamp = float(stamp_s)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise RejectedMeasurement("malformed", f"stamp must be a number, "
                                               f"got {quote(stamp_s)}") from None
    if not math.isfinite(stamp):
        raise RejectedMeasurement("malformed", f"stamp must be finite, got {stamp_s!r}")
    return stamp


def check_coords(name: str, xyz: ArrayLike, dimension: int) -> tuple[float, ...]:
    """``xyz`` as plain floats, ``dimension`` of them (a 3-vector in 2D drops z): 3 or
    ``dimension`` numbers, finite and within ±``MAX_ABS_COORDINATE`` (live and on replay)."""
    # Plain floats, not numpy: a 3-vector per message is faster without array overhead.
    try:
        values = tuple(float(v) for v in xyz)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise RejectedMeasurement("malformed", f"{name} must be a sequence of numbers, "
                                           f"got {quote(xyz)}") from None
    if len(values) not in (3, dimension):
        raise RejectedMeasurement("malformed", f"{name} must have 3 or {dimension} "
                                           f"coordinates, got {len(values)}")
    if not all(map(math.isfinite, values)):
        raise RejectedMeasurement("nonfinite", f"{name} has NaN or inf: {list(values)}")
    if max(map(abs, values)) > MAX_ABS_COORDINATE:
        # Finite, but squaring it overflows: the model could not be built any more.
        raise RejectedMeasurement("nonfinite", f"{name} has a coordinate beyond "
                                           f"±{MAX_ABS_COORDINATE:g}: {list(values)}")
    return values[:dimension]


def check_age(stamp: float, now: float, max_stamp_age: float) -> None:
    """A stamp at most ``max_stamp_age`` [s] older or newer than ``now`` (live only)."""
    age = now - stamp
    if age > max_stamp_age:
        raise RejectedMeasurement("stale", f"stamp {stamp:.3f} s is {age:.3g} s older than "
                                           f"the clock ({now:.3f} s); max_stamp_age is "
                                           f"{max_stamp_age:g} s")
    if -age > max_stamp_age:
        raise RejectedMeasurement("stale", f"stamp {stamp:.3f} s is {-age:.3g} s ahead of "
                                           f"the clock ({now:.3f} s); max_stamp_age is "
                                           f"{max_stamp_age:g} s")


def check_record_values(record: Record, dimension: int) -> None:
    """The live value checks on a journal record (see
    :meth:`.accumulator.FiducialAccumulator.check_record`)."""
    if isinstance(record, EnabledChange):
        check_id(record.fiducial_id)
        return
    if not isinstance(record, Measurement):
        raise RejectedMeasurement("malformed", f"not a journal record: {quote(record)}")
    if not record.fiducial_id:
        raise RejectedMeasurement("malformed", "fiducial_id is empty")
    check_id(record.fiducial_id)
    check_label("group", record.group)
    check_label("session", record.session)
    check_stamp(record.stamp_s)
    for name, xyz in (("working point", record.working),
                      ("destination point", record.destination)):
        if len(xyz) != dimension:
            raise RejectedMeasurement("malformed", f"{name} has {len(xyz)} coordinates, "
                                                   f"expected {dimension}")
        check_coords(name, xyz, dimension)
