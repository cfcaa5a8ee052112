"""The calibration snapshot of ``registration_node`` in ``state_dir`` (no rclpy).

``calibration.json``: the latest model, written atomically (temporary file, fsync, rename,
fsync of the directory): a reader sees the old or the new file, never a mix. The node never
loads it (the journal, :mod:`rbc_registration.ros.persistence`, is the source of truth);
:func:`tidy_state_dir` removes temporary files of an interrupted write and moves an unreadable
snapshot aside before the node starts.

Test hook: with ``RBC_TEST_SNAPSHOT_PAUSE=<path>`` in the environment, :func:`write_atomic` writes
half of the temporary file, creates ``<path>`` and sleeps (up to 10 minutes) before finishing,
so that a fault test can SIGKILL the node inside a snapshot write.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from typing import Any

SNAPSHOT_NAME = "calibration.json"
SNAPSHOT_FORMAT = "rbc_registration calibration 1"
PAUSE_ENV = "RBC_TEST_SNAPSHOT_PAUSE"


def fsync_dir(path: str) -> None:
    """fsync a directory (makes a rename in it durable)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: str, text: str) -> None:
    """Write ``text`` to ``path`` atomically: temporary file, fsync, rename, fsync directory.

    :raises OSError: when it cannot be written; ``path`` keeps its old content and the
        temporary file is removed.
    """
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    tmp = f"{path}.tmp.{os.getpid()}"
    data = text.encode("utf-8")
    try:
        with open(tmp, "wb") as f:
            if os.environ.get(PAUSE_ENV):
                data = _pause_inside_write(f, data, os.environ[PAUSE_ENV])
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(directory)


def _pause_inside_write(f: Any, data: bytes, marker: str) -> bytes:
    """The test hook (module docstring): write half, flush, signal ``marker``, sleep."""
    half = len(data) // 2
    f.write(data[:half])
    f.flush()
    os.fsync(f.fileno())
    with open(marker, "w") as m:
        m.write(f"{f.name}\n")
    time.sleep(600.0)
    return data[half:]


def read_snapshot(path: str) -> dict[str, Any]:
    """Read a calibration snapshot.

    :raises ValueError: when it is not a complete snapshot of this format (e.g. cut short).
    :raises OSError: when it cannot be read.
    """
    with open(path, "rb") as f:
        raw = f.read()
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not valid JSON ({len(raw)} bytes): {exc}") from None
    if not isinstance(data, dict) or data.get("format") != SNAPSHOT_FORMAT:
        raise ValueError(f"not a snapshot of format {SNAPSHOT_FORMAT!r}")
    return data


def tidy_state_dir(state_dir: str) -> list[str]:
    """Before a start: remove temporary files of an interrupted snapshot write and move an
    unreadable snapshot aside (``calibration.json.corrupt.<UTC time>.bak``). Neither is ever
    loaded: the model is rebuilt from the journal.

    :return: one warning per file removed or moved.
    """
    directory = os.path.abspath(os.path.expanduser(state_dir))
    if not os.path.isdir(directory):
        return []
    warnings = []
    for name in sorted(os.listdir(directory)):
        if name.startswith(f"{SNAPSHOT_NAME}.tmp."):
            os.unlink(os.path.join(directory, name))
            warnings.append(f"removed {name}: a snapshot write was interrupted (ignored; the "
                            f"model is rebuilt from the journal)")
    path = os.path.join(directory, SNAPSHOT_NAME)
    if os.path.exists(path):
        try:
            read_snapshot(path)
        except (ValueError, OSError) as exc:
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            aside = f"{path}.corrupt.{stamp}.{time.time_ns() % 10**9:09d}.bak"
            os.replace(path, aside)
            warnings.append(f"{path} is not a valid snapshot ({exc}): ignored and moved aside "
                            f"as {aside}; the model is rebuilt from the journal")
    return warnings


def snapshot_path(state_dir: str) -> str:
    """Path of the calibration snapshot in ``state_dir``."""
    return os.path.join(os.path.abspath(os.path.expanduser(state_dir)), SNAPSHOT_NAME)
