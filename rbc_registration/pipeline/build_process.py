"""Model builds in a separate Python process, so a long rebuild does not share the node's GIL
with the executor answering ``~/correct_target``. No rclpy.

In one process, a rebuild thread and the executor thread take turns holding the GIL: with a
client calling back to back, a kriging rebuild at J = 5,000 fiducials takes about twice its
in-process time. A build in a child process has its own interpreter and GIL.

:class:`ProcessBuilder` is called like :func:`~.state.build_state`. Where a build runs is the
``rebuild_worker`` setting:

- ``thread`` -- in the calling thread (the node's recompute thread);
- ``process`` -- in the child process, whatever the number of fiducials;
- ``auto`` (default) -- in the child from :data:`~.settings.PROCESS_MIN_FIDUCIALS` enabled
  fiducials on (where a kriging build takes a second or more), in the thread below (a child's
  start and the transfer of the model would cost more than the build).

The child (:mod:`.build_child`, started with this interpreter as ``python -m``) is started at the
first build that needs it and kept for the next ones; it imports numpy, scipy and this package's
``core`` and ``pipeline`` only. A request is the build's arguments, the reply the
:class:`~.state.ModelState` (or the build's error), both pickled over the child's stdin and
stdout. The child inherits the environment, so ``OPENBLAS_NUM_THREADS`` too: it builds exactly
what the thread would (bit for bit, checked by the tests).

A child that dies during a build (killed, out of memory) is replaced and the build retried once
in a new child; a second death raises :class:`BuildProcessDied` (the node logs it and keeps
serving the previous model). A child that cannot be started at all (no interpreter at
``sys.executable``, out of memory) is reported once and the build runs in the thread.
:meth:`ProcessBuilder.close` kills the child at once, so a node shuts down without waiting for
a long rebuild; the build in progress raises :class:`BuildCancelled`.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
from typing import IO, Any, Callable, Optional

from ..core.errors import OperationError
from ..core.measurements.accumulator import FiducialSet
from ..core.interpolation.kriging import KrigingHyperparameters
from .settings import PROCESS_MIN_FIDUCIALS, Settings
from .state import ModelState, build_state

__all__ = ["PROCESS_MIN_FIDUCIALS", "BuildCancelled", "BuildProcessDied", "ProcessBuilder",
           "uses_process"]

#: The child's module, run as ``python -m``.
CHILD_MODULE = "rbc_registration.pipeline.build_child"


class BuildProcessDied(OperationError):
    """The build process exited during a build, twice in a row (the message says how)."""


class BuildCancelled(OperationError):
    """The builder was closed (the node shuts down) while the build ran in the child."""


def uses_process(rebuild_worker: str, n_fiducials: int) -> bool:
    """Whether a build of ``n_fiducials`` runs in the child for the ``rebuild_worker`` setting
    (``auto``, ``thread`` or ``process``; module docstring)."""
    if rebuild_worker == "process":
        return True
    return rebuild_worker == "auto" and n_fiducials >= PROCESS_MIN_FIDUCIALS


def _child_environment() -> dict[str, str]:
    """This process's environment, with the directory holding this package first on
    ``PYTHONPATH`` (the child imports the same code even when this process found it through
    ``sys.path`` rather than the environment)."""
    env = dict(os.environ)
    package_parent = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (package_parent, env.get("PYTHONPATH", "")) if p)
    return env


class _Child:
    """One running build process and its two pipes."""

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            # -P: the working directory is not on sys.path (a checkout there would shadow
            # the package the node runs)
            [sys.executable, "-P", "-m", CHILD_MODULE], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, env=_child_environment(), close_fds=True)
        self._stdin: IO[bytes] = self.process.stdin  # type: ignore[assignment]
        self._stdout: IO[bytes] = self.process.stdout  # type: ignore[assignment]

    def call(self, request: tuple[Any, ...]) -> tuple[Any, ...]:
        """Send one request, wait for its reply.

        :raises EOFError, OSError, pickle.UnpicklingError: the child exited or its pipe broke.
        """
        pickle.dump(request, self._stdin, protocol=pickle.HIGHEST_PROTOCOL)
        self._stdin.flush()
        return pickle.load(self._stdout)

    def exit_reason(self) -> str:
        """How the child ended (after a broken pipe), e.g. ``killed by signal 9``."""
        try:
            code = self.process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            return "its pipe broke while it still runs"
        return f"killed by signal {-code}" if code < 0 else f"exited with status {code}"

    def kill(self) -> None:
        """Kill the child and reap it."""
        self.process.kill()
        self.process.wait()
        for pipe in (self._stdin, self._stdout):
            try:
                pipe.close()
            except OSError:
                pass


class ProcessBuilder:
    """Builds model states like :func:`~.state.build_state`, in a child process where the
    ``rebuild_worker`` setting says so (module docstring). Thread-safe; builds in the child run
    one at a time.

    :param build: the in-thread build (default :func:`~.state.build_state`).
    :param warn: called with one line when a child cannot be started (e.g. no ``sys.executable``,
        out of memory): that build then runs in the calling thread, and so do later ones until a
        start succeeds (tried again at each build).
    """

    def __init__(self, build: Callable[..., ModelState] = build_state,
                 warn: Callable[[str], None] = lambda line: None) -> None:
        self._build = build
        self._warn = warn
        #: Why the last child could not be started, "" after a start or none tried.
        self.start_error = ""
        self._lock = threading.Lock()     # one build in the child at a time
        self._state_lock = threading.Lock()  # guards _child and _closed
        self._child: Optional[_Child] = None
        self._closed = False
        #: Children started so far (a test checks a dead one is replaced).
        self.n_started = 0

    def __call__(self, fiducials: FiducialSet, settings: Settings, stamp_ns: int,
                 previous: Optional[KrigingHyperparameters] = None) -> ModelState:
        """The model state of :func:`~.state.build_state` for these arguments.

        :raises BuildProcessDied: the child died during this build and again in a new child.
        :raises BuildCancelled: :meth:`close` was called during the build.
        """
        if not uses_process(settings.rebuild_worker, len(fiducials.ids)):
            return self._build(fiducials, settings, stamp_ns, previous)
        request = (fiducials, settings, stamp_ns, previous)
        with self._lock:
            reason = ""
            for _ in range(2):
                try:
                    child = self._running_child()
                except OSError as exc:
                    error = f"cannot start the build process ({exc}): building in the thread"
                    if error != self.start_error:
                        self._warn(error)
                    self.start_error = error
                    return self._build(fiducials, settings, stamp_ns, previous)
                try:
                    reply = child.call(request)
                except (EOFError, OSError, ValueError, pickle.UnpicklingError):
                    reason = child.exit_reason()
                    child.kill()
                    with self._state_lock:
                        if self._closed:
                            raise BuildCancelled("the builder was closed during the build") \
                                from None
                        self._child = None
                    continue
                if reply[0] == "ok":
                    return reply[1]
                if reply[0] == "unsendable":    # built, but its result cannot be pickled
                    self._warn(f"the build process could not send its result back "
                               f"({reply[1]}): this build runs in the thread")
                    return self._build(fiducials, settings, stamp_ns, previous)
                raise RuntimeError(f"build process: {reply[1]}")
            raise BuildProcessDied(f"the build process died during the build twice in a row "
                                   f"(last {reason}); the previous model is kept")

    def _running_child(self) -> _Child:
        with self._state_lock:
            if self._closed:
                raise BuildCancelled("the builder is closed")
            if self._child is None or self._child.process.poll() is not None:
                self._child = _Child()
                self.n_started += 1
                self.start_error = ""
            return self._child

    @property
    def child_pid(self) -> Optional[int]:
        """The running child's process id, None when none runs."""
        with self._state_lock:
            return self._child.process.pid if self._child is not None else None

    def close(self) -> None:
        """Kill the child (a build in progress raises :class:`BuildCancelled`); later builds in
        the child raise it too. Builds in the thread are unaffected."""
        with self._state_lock:
            self._closed = True
            child, self._child = self._child, None
        if child is not None:   # the pipes are closed by the thread reading them, if any
            child.process.kill()
            child.process.wait()
            if not self._lock.acquire(blocking=False):
                return
            child.kill()
            self._lock.release()
