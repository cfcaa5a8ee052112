"""The build process of :mod:`.build_process`: ``python -m rbc_registration.pipeline.build_child``.

Reads pickled requests ``(fiducials, settings, stamp_ns, previous)`` from stdin, one after
another, and answers each on stdout with ``("ok", ModelState)`` or ``("error", "<type>: <msg>")``
(the build's unexpected exception; a bad fiducial set is a ModelState with its error, as in the
thread). Exits at the end of stdin (the node closed the pipe or exited). Ignores SIGINT: a Ctrl-C
in the node's terminal reaches the whole process group, and the node, not its child, decides
when the child ends. Anything else written to stdout (a library's print) goes to stderr, so the
reply stream stays clean. No rclpy.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys


#: prctl's PR_SET_PDEATHSIG (Linux): the signal the child gets when its parent dies.
PR_SET_PDEATHSIG = 1


def end_with_parent() -> None:
    """On Linux, ask the kernel to SIGKILL this child when the node dies (a SIGKILLed node left
    a child computing a multi-GB build for a minute, orphaned, beside the restarted node's new
    one); if the node died before, end now. Elsewhere the child ends at the end of stdin."""
    parent = os.getppid()
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent or parent == 1:   # the node died before prctl took effect
        os._exit(0)


def main() -> int:
    """Serve build requests until stdin ends; 0 then."""
    end_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    requests = sys.stdin.buffer
    # numpy reads OPENBLAS_NUM_THREADS here, from the environment the node passed on (the node
    # set its default, rbc_registration.runtime, before it loaded numpy itself).
    from .state import build_state

    while True:
        try:
            fiducials, settings, stamp_ns, previous = pickle.load(requests)
        except (EOFError, pickle.UnpicklingError):  # the node closed the pipe, or died
            return 0                                  # while it wrote a request
        try:
            reply = ("ok", build_state(fiducials, settings, stamp_ns, previous))
        except Exception as exc:  # noqa: BLE001 - boundary: the node logs it, the child goes on
            reply = ("error", f"{type(exc).__name__}: {exc}")
        try:        # serialised whole first: a reply pickle cannot write is never half sent
            data = pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - the node builds this one in its thread
            data = pickle.dumps(("unsendable", f"{type(exc).__name__}: {exc}"),
                                protocol=pickle.HIGHEST_PROTOCOL)
        try:
            replies.write(data)
            replies.flush()
        except BrokenPipeError:  # the node is gone
            return 0
        # nothing of this build is kept while the child waits (~30 MB at J = 5,000)
        del reply, data, fiducials, settings, previous


if __name__ == "__main__":
    sys.exit(main())
