"""The calibration snapshot of ``registration_node`` in ``state_dir``: its JSON and the atomic
file operations (no rclpy).

``calibration.json``: the latest model, written atomically (a temporary file with a unique
name, fsync, rename, fsync of the directory) by one writer at a time (a lock per path): a reader
sees the old or the new file, never a mix, and concurrent writers (``~/save`` and the recompute
thread) never share or remove each other's temporary file. The node never
loads a model from it (the journal, :mod:`rbc_registration.pipeline.journal`, is the source of
truth; at start it only compares the snapshot's settings with its own, :func:`changed_settings`);
:func:`tidy_state_dir` removes temporary files of an interrupted write and moves an unreadable
snapshot aside before the node starts.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import threading
import time
from typing import TYPE_CHECKING, Any, BinaryIO, Callable

from .files import check_regular, open_private, read_regular
from .jsonable import json_clean, registration_json
from .settings import SPECS
from .state_dir import CHECKPOINT_NAME, SNAPSHOT_NAME, StateDir

if TYPE_CHECKING:
    from .state import ModelState

SNAPSHOT_FORMAT = "rbc_registration calibration 1"
#: A snapshot larger than this is not read (a device or a runaway file is not parsed).
MAX_SNAPSHOT_BYTES = 1 << 30

_WRITE_LOCKS: dict[str, threading.Lock] = {}
_WRITE_LOCKS_GUARD = threading.Lock()
_TMP_COUNTER = itertools.count()


def _write_lock(path: str) -> threading.Lock:
    """The lock serialising writes of ``path`` in this process (one writer at a time)."""
    with _WRITE_LOCKS_GUARD:
        return _WRITE_LOCKS.setdefault(path, threading.Lock())


def _exclusive(path: str, flags: int) -> int:
    """``open(opener=...)``: a new private regular file (never an existing one or a link)."""
    return open_private(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL)


def fsync_dir(path: str) -> None:
    """fsync a directory (makes a rename in it durable)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_all(f: BinaryIO, data: bytes) -> None:
    """Write ``data`` to the open file ``f`` (the default of :func:`write_atomic`)."""
    f.write(data)


def write_atomic(path: str, text: str,
                 write: Callable[[BinaryIO, bytes], None] = write_all) -> None:
    """Write ``text`` to ``path`` atomically: temporary file, fsync, rename, fsync directory.

    :param write: writes the bytes into the open temporary file (a fault test passes one that
        stops half way).
    :raises OSError: when it cannot be written; ``path`` keeps its old content and the
        temporary file is removed.
    """
    path = os.path.abspath(path)
    directory = os.path.dirname(path)
    os.makedirs(directory, exist_ok=True)
    data = text.encode("utf-8")
    with _write_lock(path):
        # Unique per process, thread and call: a concurrent writer never touches this file.
        tmp = (f"{path}.tmp.{os.getpid()}.{threading.get_ident()}.{next(_TMP_COUNTER)}."
               f"{os.urandom(4).hex()}")
        try:
            with open(tmp, "wb", opener=_exclusive) as f:
                write(f, data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        fsync_dir(directory)


def read_snapshot(path: str) -> dict[str, Any]:
    """Read a calibration snapshot.

    :raises ValueError: when it is not a complete snapshot of this format (e.g. cut short).
    :raises OSError: when it cannot be read.
    """
    raw = read_regular(path, MAX_SNAPSHOT_BYTES)
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
    return _tidy(state_dir)[0]


def start_warnings(state_dir: str, settings: Any) -> list[str]:
    """The warnings of a start, the snapshot read once: :func:`tidy_state_dir`'s, then
    :func:`changed_settings`' line if any settings differ."""
    warnings, snapshot = _tidy(state_dir)
    line = _settings_diff(snapshot, settings, snapshot_path(state_dir))
    return warnings + ([line] if line else [])


def _tidy(state_dir: str) -> tuple[list[str], dict[str, Any] | None]:
    """:func:`tidy_state_dir`'s warnings and the snapshot it read (None: none, or moved aside)."""
    files = StateDir.resolve(state_dir)
    directory = files.root
    if not os.path.isdir(directory):
        return [], None
    warnings = []
    for name in sorted(os.listdir(directory)):
        if name.startswith(f"{SNAPSHOT_NAME}.tmp."):
            os.unlink(os.path.join(directory, name))
            warnings.append(f"removed {name}: a snapshot write was interrupted (ignored; the "
                            f"model is rebuilt from the journal)")
        elif name.startswith(f"{CHECKPOINT_NAME}.tmp."):
            os.unlink(os.path.join(directory, name))
            warnings.append(f"removed {name}: a checkpoint write was interrupted (ignored)")
    path = files.snapshot
    snapshot = None
    if os.path.lexists(path):
        try:
            check_regular(path)
            snapshot = read_snapshot(path)
        except (ValueError, OSError) as exc:
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            aside = f"{path}.corrupt.{stamp}.{time.time_ns() % 10**9:09d}.bak"
            os.replace(path, aside)
            warnings.append(f"{path} is not a valid snapshot ({exc}): ignored and moved aside "
                            f"as {aside}; the model is rebuilt from the journal")
    return warnings, snapshot


#: The settings :func:`changed_settings` compares: those that change the model built from the
#: same fiducials (``Spec.changes_model``); others (paths, ``calibration_file``, ``point_mode``,
#: QoS, periods) change what the node does with its inputs or answers, not this model.
COMPARED = tuple(name for name, spec in SPECS.items() if spec.changes_model)


def changed_settings(state_dir: str, settings: Any) -> str:
    """One line naming the settings of ``state_dir``'s snapshot (the last model of the previous
    run) that differ from ``settings`` (this start's) among those that change the model
    (:data:`COMPARED`), or "" (no snapshot, none differ).

    Parameters changed at runtime are not kept across a restart (ROS parameters come from the
    start-up ones: ``params_file``, launch arguments): the journal gives back every measurement,
    but the model is rebuilt with this start's parameters, so its answers can differ.
    """
    path = snapshot_path(state_dir)
    if not os.path.lexists(path):
        return ""
    try:
        snapshot = read_snapshot(path)
    except (ValueError, OSError):
        return ""            # tidy_state_dir says so and moves it aside
    return _settings_diff(snapshot, settings, path)


def _settings_diff(snapshot: dict[str, Any] | None, settings: Any, path: str) -> str:
    """:func:`changed_settings`' line for a snapshot already read (None: no snapshot)."""
    before = None if snapshot is None else snapshot.get("settings")
    if not isinstance(before, dict):
        return ""
    now = json_clean({k: getattr(settings, k) for k in settings.__dataclass_fields__})
    diff = [f"{k} {before[k]!r} (now {now[k]!r})" for k in COMPARED
            if k in before and k in now and before[k] != now[k]]
    if not diff:
        return ""
    return (f"the last model ({path}) was built with other parameters than this start's: "
            f"{', '.join(diff)}; the model is rebuilt from the journal with this start's "
            f"(parameters set at runtime are not kept across a restart: put them in the "
            f"params_file to keep them)")


def snapshot_path(state_dir: str) -> str:
    """Path of the calibration snapshot in ``state_dir``."""
    return StateDir.resolve(state_dir).snapshot


def snapshot_json(state: ModelState, working_frame: str, destination_frame: str,
                  dimension: int) -> str:
    """The calibration snapshot (``calibration.json``) of ``state``: frames, both registrations
    (destination = R @ working + t, metres), the fiducials and their corrections, sigma, rho, the
    decision (``Decision.to_dict``) and the settings the model was built with."""
    model, fiducials, settings = state.model, state.fiducials, state.settings
    data: dict[str, Any] = {
        "format": SNAPSHOT_FORMAT, "working_frame": working_frame,
        "destination_frame": destination_frame, "dimension": int(dimension), "units": "m",
        "stamp_ns": state.stamp_ns, "model_valid": model is not None, "error": state.error,
        "n_measurements": state.n_measurements, "warning": state.warning,
    }
    if settings is not None:
        data["settings"] = {k: getattr(settings, k) for k in settings.__dataclass_fields__}
    if fiducials is not None:
        data["fiducial_ids"] = list(fiducials.ids)
        data["disabled_ids"] = list(fiducials.disabled_ids)
        data["left_out_ids"] = list(fiducials.left_out_ids)   # enabled, but the build left out
        data["working"] = fiducials.working.tolist()
        data["destination"] = fiducials.destination.tolist()
    if model is not None:
        data.update(corrections=model.corrections.tolist(),
                    corrected=registration_json(model.corrected),
                    uncorrected=registration_json(model.uncorrected),
                    sigma=model.sigma, sigma_source=model.sigma_source,
                    sigma_l=[float(v) for v in model.sigma_l], rho=model.rho,
                    recommendation=model.recommendation, decision=model.decision.to_dict())
    return json.dumps(json_clean(data), indent=1)
