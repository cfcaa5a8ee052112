"""The pipeline settings (:mod:`rbc_registration.pipeline.settings`) as ROS parameters of
``registration_node``: declared with descriptors and ranges, and the reason given for a value of
the wrong ROS type. Units: metres and seconds (REP 103).
"""

from __future__ import annotations

import difflib
from typing import Any, Iterable

from ..pipeline.state_dir import default_state_dir, state_root
from ..pipeline.settings import REMOVED, SPECS, STATE_DIR_AUTO, Settings

#: Parameters rclpy itself declares or reads (never reported as unknown).
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")


def unknown_overrides(names: Iterable[str]) -> str:
    """The warning for start-up overrides (``-p name:=value``, a params file) that name no
    parameter of the node, each with the closest parameter name if one is close ("" when all
    are known). rclpy ignores them silently: ``decison:="'off'"`` left the decision ``cv``."""
    unknown = sorted(n for n in names if n not in SPECS and n not in ROS_PARAMETERS
                     and n not in REMOVED and not n.startswith("qos_overrides."))
    if not unknown:
        return ""
    parts = []
    for name in unknown:
        close = difflib.get_close_matches(name, SPECS, n=1, cutoff=0.75)
        parts.append(f"{name} (did you mean {close[0]}?)" if close else name)
    return (f"ignored {len(unknown)} parameter(s) this node does not have: {', '.join(parts)} "
            f"(its parameters: msg_docs/README.md)")

#: ROS parameter type names of the Python types of :data:`SPECS` defaults.
ROS_TYPE_NAMES = {bool: "bool", int: "integer", float: "double", str: "string",
                  tuple: "string array"}


def type_error(name: str, got_type: str, value: Any, declared_type: str = "") -> str:
    """The reason for a value of the wrong ROS type, e.g. ``sigma:=1`` (an integer) for a double.

    ``got_type`` and ``declared_type`` are ``rclpy.Parameter.Type`` names (``"INTEGER"``); the
    type wanted is the node's :data:`SPECS` for its own parameters, else ``declared_type`` (the
    declared type of a parameter rclpy declares, e.g. ``use_sim_time``: bool).
    Starts with "Wrong parameter type" as rclpy's own reason does (rclpy tests that prefix).
    """
    spec = SPECS.get(name)
    if spec is not None:
        want = ROS_TYPE_NAMES.get(type(spec.default), "")
    else:
        want = declared_type.lower().replace("_", " ")
    got = f"got {got_type.lower().replace('_', ' ')} {value!r}"
    if not want or want == "not set":
        return f"Wrong parameter type: {name} does not take this type, {got}"
    hint = f" (write {float(value)!r})" if want == "double" and isinstance(value, int) \
        and not isinstance(value, bool) else ""
    if want == "string" and isinstance(value, bool):
        hint = (" (YAML reads an unquoted on, off, yes, no, true or false as a boolean: quote "
                f"it, e.g. {name}:=\"'off'\" on the command line or {name}: 'off' in a file)")
    if want == "bool" and isinstance(value, str):
        hint = f" (write {name}:=true or {name}:=false, unquoted)"
    return f"Wrong parameter type: {name} must be of type {want}, {got}{hint}"


def declare(node: Any) -> Settings:
    """Declare every parameter on ``node`` (an ``rclpy.node.Node``) with its descriptor and
    return the validated :class:`Settings` (overrides from the command line or a YAML file
    included). ``state_dir`` ``auto`` becomes the node's own directory,
    ``<state_root()>/<namespace tokens>.<node name>`` (:mod:`rbc_registration.pipeline.state_dir`).

    :raises ValueError: when a starting value is invalid, or a removed parameter
        (:data:`~rbc_registration.pipeline.settings.REMOVED`) is given (the node refuses to
        start, naming what replaces it).
    """
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException

    for name in REMOVED:
        if name in getattr(node, "_parameter_overrides", {}):
            raise ValueError(f"parameter {name} no longer exists: {REMOVED[name]}")

    values = {}
    for name, spec in SPECS.items():
        desc = ParameterDescriptor(name=name, description=spec.description,
                                   read_only=spec.read_only)
        if spec.choices:
            desc.additional_constraints = "one of: " + ", ".join(spec.choices)
        if isinstance(spec.default, int) and not isinstance(spec.default, bool):
            desc.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                               step=1)]
        elif isinstance(spec.default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(spec.low),
                                                            to_value=float(spec.high), step=0.0)]
            if spec.low_exclusive:
                desc.additional_constraints = f"> {spec.low:g}"
        default = spec.default
        if isinstance(default, tuple):
            # A string array: rclpy types an empty default as a byte array, and a params file's
            # `[]` (or `ros2 param set ... "[]"`) comes as another type or none: typed by the
            # on-set callback (Settings), which reads an empty list of any kind as none.
            desc.dynamic_typing, default = True, list(default)
            desc.additional_constraints = "a list of strings"
        try:
            values[name] = node.declare_parameter(name, default, desc).value
        except InvalidParameterTypeException:
            given = node._parameter_overrides[name]
            raise ValueError(type_error(name, given.type_.name, given.value)) from None
    if values["state_dir"] == STATE_DIR_AUTO:
        values["state_dir"] = default_state_dir(node.get_namespace(), node.get_name(),
                                                root=state_root())
    return Settings.from_mapping(values)
