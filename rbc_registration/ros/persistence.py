"""Durable state of ``registration_node`` in ``state_dir`` (no rclpy).

``journal.jsonl``: one JSON object per line. The first line is a header (version, frames,
dimension); then one line per accepted measurement or enable change, in order. A record is
written and flushed to the OS before the node counts it, so a SIGKILL of the node loses no
accepted measurement. With ``fsync=True`` each record is also fsynced (survives power loss;
costs a disk sync per record). On open a torn last line (a write cut short) is skipped with a
warning and cut off so that appends stay line-aligned; an unreadable line elsewhere is skipped
with a warning. Floats are written with ``repr`` precision, so replay is bit-exact.

``calibration.json``: the latest model, written atomically (temporary file, fsync, rename,
fsync of the directory): a reader sees the old or the new file, never a mix.
"""

from __future__ import annotations

import json
import os
import time
from typing import Any, Iterable, Optional

from rbc_registration.core.accumulator import EnabledChange, Measurement, Record

JOURNAL_NAME = "journal.jsonl"
SNAPSHOT_NAME = "calibration.json"
JOURNAL_VERSION = 1


class JournalMismatch(ValueError):
    """The journal in ``state_dir`` was written with other frames or another dimension."""


def record_to_json(record: Record) -> str:
    """One journal line (without the newline) for ``record``."""
    if isinstance(record, Measurement):
        obj: dict[str, Any] = {"t": "m", "id": record.fiducial_id, "w": list(record.working),
                               "d": list(record.destination), "s": record.stamp_s}
        if record.auto_id:
            obj["auto"] = True
    elif isinstance(record, EnabledChange):
        obj = {"t": "e", "id": record.fiducial_id, "on": record.enabled}
    else:
        raise TypeError(f"record must be a Measurement or EnabledChange, got {record!r}")
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


def record_from_json(line: str) -> Record:
    """Parse one journal line.

    :raises ValueError: naming what is wrong with the line.
    """
    return record_from_object(json.loads(line), line)


def record_from_object(obj: Any, line: str = "") -> Record:
    """A journal record from its parsed JSON object (see :func:`record_from_json`)."""
    if not isinstance(obj, dict):
        raise ValueError(f"a journal record must be a JSON object, got {line[:80]!r}")
    kind = obj.get("t")
    if kind == "m":
        w, d = obj["w"], obj["d"]
        if not all(isinstance(v, (int, float)) for v in [*w, *d]):
            raise ValueError(f"measurement coordinates must be numbers: {line[:80]!r}")
        return Measurement(str(obj["id"]), tuple(float(v) for v in w),
                           tuple(float(v) for v in d), float(obj["s"]), bool(obj.get("auto")))
    if kind == "e":
        return EnabledChange(str(obj["id"]), bool(obj["on"]))
    raise ValueError(f"unknown journal record type {kind!r}")


class Journal:
    """Append-only journal of accepted records in ``state_dir`` (see the module docstring).

    :param state_dir: directory (created if missing).
    :param header: identifies the setup (frames, dimension); an existing journal with another
        header is refused (:class:`JournalMismatch`).
    :param fsync: fsync after every record.
    """

    def __init__(self, state_dir: str, header: dict[str, Any], fsync: bool = False) -> None:
        self.state_dir = os.path.abspath(os.path.expanduser(state_dir))
        self.path = os.path.join(self.state_dir, JOURNAL_NAME)
        self.header = {"t": "h", "version": JOURNAL_VERSION, **header}
        self.fsync = fsync
        self._file = None
        os.makedirs(self.state_dir, exist_ok=True)

    def load(self) -> tuple[list[Record], list[str]]:
        """Read the existing journal (if any) and open it for appending.

        :return: the records in order, and warnings about skipped lines.
        :raises JournalMismatch: when the header names other frames or another dimension.
        """
        records: list[Record] = []
        warnings: list[str] = []
        good_end = 0
        if os.path.exists(self.path):
            with open(self.path, "rb") as f:
                data = f.read()
            offset = 0
            lineno = 0
            while offset < len(data):
                end = data.find(b"\n", offset)
                lineno += 1
                if end < 0:
                    warnings.append(f"{self.path}:{lineno}: torn last record "
                                    f"({len(data) - offset} bytes without a newline) skipped")
                    break
                line = data[offset:end].decode("utf-8", errors="replace").strip()
                offset = end + 1
                good_end = offset
                if not line:
                    continue
                try:
                    obj = json.loads(line)
                    if isinstance(obj, dict) and obj.get("t") == "h":
                        self._check_header(obj)
                        continue
                    records.append(record_from_object(obj, line))
                except JournalMismatch:
                    raise
                except (ValueError, KeyError, TypeError) as exc:
                    warnings.append(f"{self.path}:{lineno}: unreadable record skipped ({exc})")
        self._open(truncate_to=good_end)
        return records, warnings

    def _check_header(self, found: dict[str, Any]) -> None:
        for key, want in self.header.items():
            if key != "version" and found.get(key) != want:
                raise JournalMismatch(
                    f"{self.path} was written with {key}={found.get(key)!r}, but the node runs "
                    f"with {key}={want!r}: move the journal away or start with the same "
                    f"parameters")

    def _open(self, truncate_to: int) -> None:
        exists = os.path.exists(self.path)
        self._file = open(self.path, "ab")
        if exists and self._file.tell() != truncate_to:
            self._file.truncate(truncate_to)
            self._file.seek(truncate_to)
        if truncate_to == 0:
            self._write(json.dumps(self.header, separators=(",", ":")))

    def _write(self, line: str) -> None:
        assert self._file is not None, "journal is not open: call load() first"
        self._file.write(line.encode("utf-8") + b"\n")
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def append(self, record: Record) -> None:
        """Write one record and flush it to the OS (and fsync it when configured).

        :raises OSError: when it cannot be written (the caller must not count the record).
        """
        self._write(record_to_json(record))

    def append_many(self, records: Iterable[Record]) -> None:
        """Append several records (one flush)."""
        lines = "".join(record_to_json(r) + "\n" for r in records)
        assert self._file is not None, "journal is not open: call load() first"
        self._file.write(lines.encode("utf-8"))
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def archive(self) -> Optional[str]:
        """Move the journal (and snapshot) aside as ``*.<UTC time>.bak`` and start a new one.

        :return: the archived journal's path, or ``None`` when there was none.
        """
        self.close()
        suffix = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + f".{time.time_ns() % 10**9:09d}"
        archived = None
        for name in (JOURNAL_NAME, SNAPSHOT_NAME):
            path = os.path.join(self.state_dir, name)
            if os.path.exists(path):
                os.replace(path, f"{path}.{suffix}.bak")
                if name == JOURNAL_NAME:
                    archived = f"{path}.{suffix}.bak"
        _fsync_dir(self.state_dir)
        self._open(truncate_to=0)
        return archived

    def close(self) -> None:
        """Flush and close the file (appends need :meth:`load` again)."""
        if self._file is not None:
            self._file.close()
            self._file = None


def _fsync_dir(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: str, text: str) -> None:
    """Write ``text`` to ``path`` atomically: temporary file, fsync, rename, fsync directory."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    tmp = f"{path}.tmp.{os.getpid()}"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(directory)


def snapshot_path(state_dir: str) -> str:
    """Path of the calibration snapshot in ``state_dir``."""
    return os.path.join(os.path.abspath(os.path.expanduser(state_dir)), SNAPSHOT_NAME)
