"""``registration_node`` as a separate process, started and stopped cleanly: used by the demo,
the tests and the benchmarks. DDS stays on this machine: the child always gets
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and no static peers; it inherits ``ROS_DOMAIN_ID``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from typing import IO, Any, Mapping, Optional, Sequence, Union

#: ``python -m rbc_registration.ros.node``, with this interpreter.
NODE_COMMAND = (sys.executable, "-m", "rbc_registration.ros.node")
STOP_TIMEOUT_S = 15.0


def node_arguments(name: str, params: Optional[Mapping[str, Any]] = None,
                   ros_args: Sequence[str] = ()) -> list[str]:
    """``--ros-args -r __node:=NAME -p key:=value ...`` (then ``ros_args``)."""
    args = ["--ros-args", "-r", f"__node:={name}"]
    for key, value in (params or {}).items():
        args += ["-p", f"{key}:={value}"]
    return args + list(ros_args)


def loopback_environment(extra: Optional[Mapping[str, str]] = None) -> dict[str, str]:
    """This process's environment with DDS discovery on loopback only, plus ``extra``."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", **(extra or {}))
    env.pop("ROS_STATIC_PEERS", None)
    return env


def start_node(name: str, params: Optional[Mapping[str, Any]] = None, *,
               log: Union[None, int, IO[Any]] = None, env: Optional[Mapping[str, str]] = None,
               ros_args: Sequence[str] = (), command: Sequence[str] = NODE_COMMAND,
               popen: Optional[Mapping[str, Any]] = None) -> subprocess.Popen:
    """Start ``registration_node`` named ``name`` with parameters ``params``.

    :param log: where stdout and stderr go (a file, ``subprocess.PIPE``, ...; default: nowhere).
    :param env: extra environment variables.
    :param ros_args: extra ``--ros-args`` arguments.
    :param command: the program (default :data:`NODE_COMMAND`).
    :param popen: extra ``subprocess.Popen`` arguments (e.g. ``preexec_fn``, ``stdout``).
    """
    kwargs = {"stdout": subprocess.DEVNULL if log is None else log,
              "stderr": subprocess.STDOUT, **(popen or {})}
    return subprocess.Popen([*command, *node_arguments(name, params, ros_args)],
                            env=loopback_environment(env), **kwargs)


def stop_process(proc: Optional[subprocess.Popen], sig: int = signal.SIGINT,
                 timeout: float = STOP_TIMEOUT_S) -> Optional[int]:
    """Stop ``proc`` with ``sig`` (Ctrl-C by default); kill it after ``timeout`` seconds.

    :return: its exit status, or ``None`` for no process.
    """
    if proc is None:
        return None
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode
