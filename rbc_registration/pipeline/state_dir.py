"""A node's ``state_dir``: resolved once into a :class:`StateDir` that names every file in it,
and its default, derived from the node's namespace and name so that two cells (two nodes) never
share a journal. Pure Python; used by launch/registration.launch.py too.

The files (one name each, here only): ``journal.jsonl`` (every accepted measurement),
``calibration.json`` (the snapshot of the last model), ``checkpoint.json`` (the accumulator's
sums at a journal position), ``lock`` (one writer), ``calibration.yaml`` (``~/save``) and
``calibrations/NAME.yaml`` (``~/save`` with ``calibration_name``).

The default: ``~/.ros/rbc_registration/<namespace tokens>.<name>``, e.g.
``/cell_a/registration_node`` -> ``~/.ros/rbc_registration/cell_a.registration_node`` and
``/registration_node`` -> ``~/.ros/rbc_registration/registration_node``. The separator ``.``
cannot occur in a ROS name, so different nodes always get different directories (``/a_b/c``
and ``/a/b_c`` are ``a_b.c`` and ``a.b_c``).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Mapping, Optional

JOURNAL_NAME = "journal.jsonl"
SNAPSHOT_NAME = "calibration.json"
CHECKPOINT_NAME = "checkpoint.json"
LOCK_NAME = "lock"
#: The calibration file ``~/save`` writes; named calibrations go to :data:`CALIBRATIONS_DIR`.
CALIBRATION_NAME = "calibration.yaml"
CALIBRATIONS_DIR = "calibrations"

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


@dataclass(frozen=True)
class StateDir:
    """A ``state_dir`` resolved once (``~`` expanded, absolute) and the paths of its files.

    :ivar root: the directory, absolute.
    """

    root: str

    @classmethod
    def resolve(cls, path: str) -> "StateDir":
        """The state directory at ``path`` (``~`` expanded, made absolute; nothing created).

        :raises ValueError: for an empty path (no state_dir: nothing persists).
        """
        if not path:
            raise ValueError("state_dir is empty: no state directory")
        return cls(os.path.abspath(os.path.expanduser(path)))

    def _file(self, name: str) -> str:
        return os.path.join(self.root, name)

    @property
    def journal(self) -> str:
        """``journal.jsonl``: every accepted measurement, the record."""
        return self._file(JOURNAL_NAME)

    @property
    def snapshot(self) -> str:
        """``calibration.json``: the snapshot of the last model."""
        return self._file(SNAPSHOT_NAME)

    @property
    def checkpoint(self) -> str:
        """``checkpoint.json``: the accumulator's sums at a journal position."""
        return self._file(CHECKPOINT_NAME)

    @property
    def lock(self) -> str:
        """``lock``: held by the one node writing here."""
        return self._file(LOCK_NAME)

    @property
    def calibration(self) -> str:
        """``calibration.yaml``: what ``~/save`` writes without ``calibration_name``."""
        return self._file(CALIBRATION_NAME)

    @property
    def calibrations(self) -> str:
        """``calibrations/``: the named calibrations."""
        return self._file(CALIBRATIONS_DIR)

    def named_calibration(self, name: str) -> str:
        """``calibrations/NAME.yaml`` (``name`` is checked by the caller)."""
        return os.path.join(self.calibrations, f"{name}.yaml")
