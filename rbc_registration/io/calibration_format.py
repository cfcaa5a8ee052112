"""The calibration file's fields (docs/CALIBRATION.md): the :class:`Decision` record, the checks
that name the field they reject, and the mapping to and from the YAML document.

Used by :mod:`rbc_registration.io.calibration`; no rclpy.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
import reprlib
from datetime import datetime
from typing import Any, Optional, Sequence

import yaml

from ..core.frames import frame_id_problem
from ..core.validation import MAX_ABS_COORDINATE

FORMAT = "rbc_registration_calibration"
FORMAT_VERSION = 3
#: Versions this reader reads: 1 had one ``expected_tre`` (the decision's figure, read as
#: ``expected_tre_with_corrections``; ``expected_tre_rigid`` then unknown); 1 and 2 have no
#: ``answers`` (read as null: the file publishes tf, it answers no targets).
READABLE_VERSIONS = (1, 2, 3)
UNITS = "m"
MAX_TEXT = 1000  # characters of a frame id, mode, reason or version string

# Keys of the document in file order; nested mappings list their keys.
VECTOR_KEYS = {"translation": ("x", "y", "z"), "rotation": ("x", "y", "z", "w")}
DECISION_KEYS = ("mode", "method", "apply", "reason")
KEYS = ("format", "format_version", "parent_frame", "child_frame", "dimension", "units",
        "registration", "translation", "rotation", "fre_rms", "decision", "sigma",
        "sigma_axis", "sigma_L", "expected_tre_rigid", "expected_tre_with_corrections",
        "n_fiducials", "created", "package_version", "answers")
#: The keys of a version 2 file (no ``answers``).
KEYS_V2 = KEYS[:-1]
#: The keys of a version 1 file.
KEYS_V1 = ("format", "format_version", "parent_frame", "child_frame", "dimension", "units",
           "registration", "translation", "rotation", "fre_rms", "decision", "sigma",
           "sigma_axis", "sigma_L", "expected_tre", "n_fiducials", "created", "package_version")


@dataclasses.dataclass(frozen=True)
class Decision:
    """Whether and how targets are corrected with this calibration.

    :ivar mode: the decision mode that chose it (``cv``, ``rho``, ``on``, ``off``; files of older
        versions: ``auto``).
    :ivar method: what a target gets: ``uncorrected``, or a correction by ``paper`` or ``kriging``
        interpolation (eq. 5-6).
    :ivar apply: whether corrections are applied (true needs a correcting method).
    :ivar reason: the reason in words (e.g. ``rho 3.1 >= 2.5``).
    :raises ValueError: naming the field (``decision.mode`` ...) when a value is not valid.
    """

    mode: str
    method: str
    apply: bool
    reason: str

    def __post_init__(self) -> None:
        check_text("decision.mode", self.mode)
        check_text("decision.method", self.method)
        if not isinstance(self.apply, bool):
            raise ValueError(f"decision.apply: must be true or false, got {_quote(self.apply)}")
        check_text("decision.reason", self.reason, allow_empty=True)


_REPR = reprlib.Repr()  # bounded: a YAML alias bomb must not be expanded into a message
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxother = 2, 4, 4, 60, 60


def _quote(value: Any) -> str:
    text = _REPR.repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _name(key: Any) -> str:
    """A key as it appears in a message: plain when it is a short printable string."""
    return key if isinstance(key, str) and len(key) <= 60 and key.isprintable() else _quote(key)


def check_text(name: str, value: Any, allow_empty: bool = False) -> str:
    """A one-line string of at most :data:`MAX_TEXT` characters (non-empty unless allowed)."""
    if not isinstance(value, str):
        raise ValueError(f"{name}: must be a string, got {_quote(value)}")
    if not value and not allow_empty:
        raise ValueError(f"{name}: must not be empty")
    if len(value) > MAX_TEXT or any(c in value for c in "\n\r\0"):
        raise ValueError(f"{name}: must be one line of at most {MAX_TEXT} characters, got "
                         f"{_quote(value)}")
    return value


def check_frame(name: str, value: Any) -> str:
    """A tf frame id (:func:`rbc_registration.core.frames.frame_id_problem`)."""
    check_text(name, value)
    problem = frame_id_problem(value)
    if problem:
        raise ValueError(f"{name}: {problem}, got {_quote(value)}")
    return value


def check_choice(name: str, value: Any, choices: Sequence[str]) -> str:
    if value not in choices or not isinstance(value, str):
        raise ValueError(f"{name}: must be one of {', '.join(choices)}, got {_quote(value)}")
    return value


def check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name}: must be an integer, got {_quote(value)}")
    if value < minimum:
        raise ValueError(f"{name}: must be at least {minimum}, got {value}")
    return int(value)


def check_number(name: str, value: Any, bound: float = math.inf) -> float:
    """A finite real number (not a bool, not a string) within ±``bound``."""
    if isinstance(value, str) and re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+", value):
        # PyYAML (YAML 1.1) reads a float only with a point and a signed exponent: 5e-05 and
        # 1.5e5 are text (a quoted '0.5' is text too, and says so as any string does)
        raise ValueError(f"{name}: must be a number, got {_quote(value)} (YAML 1.1 reads it as "
                         f"text: its floats need a decimal point and a signed exponent, e.g. "
                         f"5.0e-05 or 1.5e+05)")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: must be a number, got {_quote(value)}")
    try:
        v = float(value)
    except OverflowError:                # an integer of hundreds of digits
        raise ValueError(f"{name}: out of range, got an integer of {len(str(value))} "
                         f"digits") from None
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    if abs(v) > bound:
        raise ValueError(f"{name}: must be within ±{bound:g} m (as any coordinate), got {v!r}")
    return v


def check_length(name: str, value: Any) -> float:
    """A finite, non-negative length [m], at most :data:`MAX_ABS_COORDINATE`."""
    v = check_number(name, value, MAX_ABS_COORDINATE)
    if v < 0:
        raise ValueError(f"{name}: must be >= 0 (a length in metres), got {v!r}")
    return v


def sequence(name: str, value: Any) -> tuple[Any, ...]:
    if isinstance(value, (str, bytes, dict)) or not isinstance(value, Sequence):
        raise ValueError(f"{name}: must be a list, got {_quote(value)}")
    return tuple(value)


def floats(name: str, value: Any, axes: str, bound: float = math.inf) -> tuple[float, ...]:
    """``len(axes)`` finite numbers within ±``bound``, named ``name.<axis>`` in errors."""
    values = sequence(name, value)
    if len(values) != len(axes):
        raise ValueError(f"{name}: must have {len(axes)} components ({', '.join(axes)}), got "
                         f"{len(values)}")
    return tuple(check_number(f"{name}.{axis}", v, bound) for axis, v in zip(axes, values))


def utc_time(name: str, value: Any) -> str:
    """An ISO 8601 time in UTC (``Z`` or ``+00:00``); a YAML timestamp is accepted too.

    :return: the text as written (a YAML timestamp: ``YYYY-MM-DDTHH:MM:SS.ffffffZ``).
    """
    if isinstance(value, datetime):
        parsed, text = value, value.isoformat(timespec="microseconds").replace("+00:00", "Z")
    else:
        text = check_text(name, value)
        try:
            parsed = datetime.fromisoformat(text)
        except ValueError:
            raise ValueError(f"{name}: not an ISO 8601 time, got {_quote(text)}") from None
    offset = parsed.utcoffset()
    if offset is None or offset.total_seconds() != 0:
        raise ValueError(f"{name}: must be in UTC (ending in Z or +00:00), got {_quote(text)}")
    return text


def to_mapping(cal: Any) -> dict[str, Any]:
    """The YAML document of a :class:`~rbc_registration.io.calibration.Calibration`."""
    data: dict[str, Any] = {"format": FORMAT, "format_version": FORMAT_VERSION, "units": UNITS}
    for key in KEYS:
        if key in VECTOR_KEYS:
            data[key] = dict(zip(VECTOR_KEYS[key], getattr(cal, key)))
        elif key == "decision":
            data[key] = dataclasses.asdict(cal.decision)
        elif key == "sigma_L":
            data[key] = list(cal.sigma_l)
        elif key == "answers":      # io.calibration_answers.Answers, or None
            data[key] = None if cal.answers is None else cal.answers.to_mapping()
        elif key not in data:
            data[key] = getattr(cal, key)
    return {key: data[key] for key in KEYS}


def _mapping(name: str, value: Any, keys: Sequence[str]) -> dict[str, Any]:
    if not isinstance(value, dict):
        what = f"{name}: must be a mapping with keys {', '.join(keys)}" if name else \
            "the document must be a mapping of the fields of docs/CALIBRATION.md"
        raise ValueError(f"{what}, got {_quote(value)}")
    prefix = f"{name}." if name else ""
    for key in value:
        if key not in keys:
            raise ValueError(f"{prefix}{_name(key)}: unknown field (known: {', '.join(keys)})")
    for key in keys:
        if key not in value:
            raise ValueError(f"{prefix}{key}: missing")
    return value


def from_mapping(data: Any) -> dict[str, Any]:
    """The :class:`~rbc_registration.io.calibration.Calibration` keyword arguments of a parsed
    document; checks its structure (format, version, units, keys), the record checks values.
    ``answers`` is the parsed mapping (or None), read by the caller
    (:func:`~rbc_registration.io.calibration_answers.read_answers`).

    :raises ValueError: naming the field.
    """
    if isinstance(data, dict) and data.get("format") != FORMAT:
        got = "missing" if "format" not in data else f"got {_quote(data['format'])}"
        raise ValueError(f"format: must be {FORMAT!r} (not a calibration file?), {got}")
    version = None
    if isinstance(data, dict) and "format_version" in data:
        version = check_int("format_version", data["format_version"], minimum=1)
    if version is not None and version not in READABLE_VERSIONS:
        raise ValueError(f"format_version: {version} is not supported (this reader knows "
                         f"versions {', '.join(map(str, READABLE_VERSIONS))})")
    data = _mapping("", data, {1: KEYS_V1, 2: KEYS_V2}.get(version, KEYS))
    if version == 1:   # its expected_tre was the decision's figure (docs/CALIBRATION.md)
        data = {**data, "expected_tre_rigid": None,
                "expected_tre_with_corrections": data["expected_tre"]}
    if version in (1, 2):
        data = {**data, "answers": None}
    if data["units"] != UNITS:
        raise ValueError(f"units: must be {UNITS!r} (all lengths are metres), got "
                         f"{_quote(data['units'])}")
    kwargs = {key: data[key] for key in KEYS if key not in ("format", "format_version", "units")}
    for key, axes in VECTOR_KEYS.items():
        kwargs[key] = tuple(_mapping(key, data[key], axes)[axis] for axis in axes)
    kwargs["decision"] = Decision(**_mapping("decision", data["decision"], DECISION_KEYS))
    kwargs["sigma_l"] = kwargs.pop("sigma_L")
    return kwargs


def optional_length(name: str, value: Optional[Any]) -> Optional[float]:
    """None, or a length as :func:`check_length`."""
    return None if value is None else check_length(name, value)



#: The longest number read [characters]: below Python's limit of 4300 digits (which raises a bare
#: error naming no field); a float64 needs 25, a longer one is refused by its field.
MAX_NUMBER_CHARS = 4000

#: A number as a calibration file writes it: decimal digits, a point, an exponent (and YAML's
#: .inf/.nan, which the field checks refuse with their own message).
_DECIMAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?|[-+]?\.(inf|Inf|INF)|\.(nan|NaN|NAN)")


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses a mapping with a key twice (the plain loader keeps the
    last: an edited file with two ``translation`` blocks would load the second silently), a key
    that is a list or a mapping (``? [a, b] : 1``: no field has such a name), a number YAML 1.1
    reads otherwise than it looks: ``1:20`` (sexagesimal, 80), ``012`` (octal, 10), ``0x1f``,
    ``0b11``, ``1_000``, and a boolean other than ``true`` / ``false`` (``yes``, ``no``, ``on``,
    ``off``: ``mode: off`` is read as false)."""

    def _number(self, node: Any, construct: Any) -> Any:
        text = str(node.value)
        if len(text) > MAX_NUMBER_CHARS:    # Python refuses int('9' * 4301) with a bare error
            raise yaml.constructor.ConstructorError(
                None, None, f"a number of {len(text)} characters (at most {MAX_NUMBER_CHARS})",
                node.start_mark)
        ambiguous = not _DECIMAL.fullmatch(text) or re.fullmatch(r"[-+]?0\d+", text)
        if ambiguous:
            raise yaml.constructor.ConstructorError(
                None, None, f"the number {text!r} is not plain decimal (YAML 1.1 reads it as "
                f"{construct(self, node)!r}): write it in decimal, or quote it", node.start_mark)
        return construct(self, node)

    def construct_yaml_int(self, node: Any) -> Any:
        return self._number(node, yaml.SafeLoader.construct_yaml_int)

    def construct_yaml_float(self, node: Any) -> Any:
        return self._number(node, yaml.SafeLoader.construct_yaml_float)

    def construct_yaml_bool(self, node: Any) -> Any:
        """``true`` / ``false`` only: YAML 1.1 also reads ``yes``, ``no``, ``on``, ``off`` as
        booleans (``mode: off`` would be false, ``apply: yes`` true)."""
        text = str(node.value)
        if text.lower() not in ("true", "false"):
            raise yaml.constructor.ConstructorError(
                None, None, _bool_problem(None, node), node.start_mark)
        return yaml.SafeLoader.construct_yaml_bool(self, node)

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        seen: set = set()
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                raise yaml.constructor.ConstructorError(
                    None, None, "a merge key (<<) is not read here: write the fields out",
                    key_node.start_mark)
            if not isinstance(key_node, yaml.ScalarNode):   # ? [a, b] : 1, {[1, 2]: x}
                kind = "list" if isinstance(key_node, yaml.SequenceNode) else "mapping"
                raise yaml.constructor.ConstructorError(
                    None, None, f"a key must be a name, got a {kind}", key_node.start_mark)
            key = self.construct_object(key_node, deep=deep)
            if (isinstance(value_node, yaml.ScalarNode) and value_node.style is None
                    and value_node.tag == "tag:yaml.org,2002:bool"
                    and str(value_node.value).lower() not in ("true", "false")):
                raise yaml.constructor.ConstructorError(
                    None, None, _bool_problem(key, value_node), value_node.start_mark)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"found the key {key!r} twice", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _bool_problem(key: Any, node: Any) -> str:
    """Why a YAML 1.1 boolean other than true/false is refused, and what to write instead."""
    name = f"{_name(key)}: " if key is not None else ""
    value = yaml.SafeLoader.bool_values[str(node.value).lower()]
    return (f"{name}{node.value} is read by YAML 1.1 as {str(value).lower()}: write true or "
            f"false for a boolean, or quote a string: {name}'{node.value}'")


_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:bool", _UniqueKeyLoader.construct_yaml_bool)
_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:int", _UniqueKeyLoader.construct_yaml_int)
_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:float", _UniqueKeyLoader.construct_yaml_float)


def load_yaml(text: str) -> Any:
    """The YAML document in ``text`` (safe types only; a key twice in a mapping is an error).

    :raises yaml.YAMLError: on invalid YAML, naming the problem and its mark.
    """
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
