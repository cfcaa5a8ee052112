"""Default ``state_dir`` of a registration node, derived from its namespace and name, so that two
cells (two nodes) never share a journal. Pure Python; used by launch/registration.launch.py.

``~/.ros/rbc_registration/<namespace tokens>.<name>``, e.g. ``/cell_a/registration_node`` ->
``~/.ros/rbc_registration/cell_a.registration_node`` and ``/registration_node`` ->
``~/.ros/rbc_registration/registration_node``. The separator ``.`` cannot occur in a ROS name, so
different nodes always get different directories (``/a_b/c`` and ``/a/b_c`` are ``a_b.c`` and
``a.b_c``).
"""

from __future__ import annotations

import os
import re
from typing import Mapping, Optional

STATE_ROOT = "~/.ros/rbc_registration"  # '~' is expanded by the node (state_dir parameter)
SEPARATOR = "."                          # not a character of ROS names: the mapping is one-to-one
# A ROS 2 node name, or one token of a namespace (rmw_validate_node_name / _namespace): letters,
# digits and underscores, not starting with a digit.
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
MAX_NAME = 255  # rmw's limit for node names and namespaces


def resolve_namespace(namespace: str = "", pushed: Optional[str] = None) -> str:
    """The absolute namespace a node gets, as launch_ros computes it: a relative ``namespace`` is
    put under ``pushed`` (the namespace of an enclosing ``PushRosNamespace``), an absolute one is
    kept; empty means ``pushed`` or the root.

    :return: ``/`` or ``/token[/token...]``, without a trailing ``/``.
    :raises ValueError: when a token is not a valid ROS name token.
    """
    parts: list[str] = []
    for label, value in (("pushed namespace", pushed or ""), ("namespace", namespace or "")):
        if value.startswith("/"):
            parts = []  # absolute: replaces what came before
        parts += _tokens(label, value)
    resolved = "/" + "/".join(parts)
    if len(resolved) > MAX_NAME:
        raise ValueError(f"namespace {resolved[:60]!r}... is longer than {MAX_NAME} characters")
    return resolved


def _tokens(label: str, value: str) -> list[str]:
    stripped = value.strip("/")
    if not stripped:
        return []
    tokens = stripped.split("/")
    for token in tokens:
        if not _TOKEN.match(token):
            raise ValueError(f"{label} {value!r}: {token!r} is not a valid ROS name token "
                             f"(letters, digits and '_', not starting with a digit)")
    return tokens


def check_node_name(name: str) -> str:
    """A valid ROS 2 node name (no namespace).

    :raises ValueError: naming the problem.
    """
    if not isinstance(name, str) or not _TOKEN.match(name) or len(name) > MAX_NAME:
        raise ValueError(f"node name {name!r} is not valid: letters, digits and '_', not "
                         f"starting with a digit, at most {MAX_NAME} characters")
    return name


def state_dir_name(namespace: str, name: str, pushed: Optional[str] = None) -> str:
    """The directory name of node ``name`` in ``namespace``: its namespace tokens and its name
    joined with ``.`` (one-to-one: different nodes, different names)."""
    resolved = resolve_namespace(namespace, pushed)
    return SEPARATOR.join([t for t in resolved.split("/") if t] + [check_node_name(name)])


def state_root(environ: Optional[Mapping[str, str]] = None) -> str:
    """Where a node started without a launch file keeps its default ``state_dir``:
    ``$ROS_HOME/rbc_registration`` (ROS_HOME as rcl uses it for logs), else :data:`STATE_ROOT`."""
    ros_home = (os.environ if environ is None else environ).get("ROS_HOME", "")
    return os.path.join(ros_home, "rbc_registration") if ros_home else STATE_ROOT


def default_state_dir(namespace: str, name: str, pushed: Optional[str] = None,
                      root: str = STATE_ROOT) -> str:
    """The default ``state_dir`` of node ``name`` in ``namespace``:
    ``<root>/<state_dir_name(namespace, name)>`` (``~`` left for the node to expand).

    :raises ValueError: when the namespace or name is not a valid ROS name.
    """
    return os.path.join(root, state_dir_name(namespace, name, pushed))
