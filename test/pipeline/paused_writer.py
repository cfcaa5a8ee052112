"""A snapshot writer that stops half way, for fault tests: :func:`pause_half_way` is passed to
``write_atomic(write=...)`` (or to the node as its snapshot writer, see
test/ros/paused_snapshot_node.py), so that a test can SIGKILL the process inside the write.

As a script: ``python paused_writer.py MARKER PATH TEXT`` writes TEXT to PATH atomically with
the pausing writer.
"""

import functools
import os
import sys
import time

PAUSE_S = 600.0   # long enough for any test to kill the process meanwhile


def pause_half_way(marker):
    """A ``write(f, data)`` for ``write_atomic``: writes half of ``data``, fsyncs it, creates the
    file ``marker`` holding the temporary file's name, sleeps, then writes the rest."""
    def write(f, data):
        half = len(data) // 2
        f.write(data[:half])
        f.flush()
        os.fsync(f.fileno())
        with open(marker, "w") as m:
            m.write(f"{f.name}\n")
        time.sleep(PAUSE_S)
        f.write(data[half:])
    return write


def paused_write_atomic(marker):
    """``write_atomic`` with :func:`pause_half_way` (a node's ``write_snapshot``)."""
    from rbc_registration.pipeline.snapshot import write_atomic

    return functools.partial(write_atomic, write=pause_half_way(marker))


if __name__ == "__main__":
    marker, path, text = sys.argv[1:4]
    paused_write_atomic(marker)(path, text)
