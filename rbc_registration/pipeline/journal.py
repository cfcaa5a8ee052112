"""The measurement journal of ``registration_node`` in ``state_dir`` (no rclpy).

``journal.jsonl``: one JSON object per line. The first line is a header (version, frames,
dimension); then one line per accepted measurement or enable change, in order. A record is
written and flushed to the OS before the node counts it, so a SIGKILL of the node loses no
accepted measurement. With ``fsync=True`` each record is also fsynced (survives power loss;
costs a disk sync per record). On open a torn last line (a write cut short) is skipped with a
warning and cut off so that appends stay line-aligned; an unreadable line elsewhere is skipped
with a warning. Floats are written with ``repr`` precision, so replay is bit-exact.

A record that cannot be written (disk full, file-size limit, I/O error) raises ``OSError`` and
leaves nothing behind: a partly written line is cut off again at once, so the record can never
reappear later (the caller does not count it).

``calibration.json``: the latest model, see :mod:`rbc_registration.pipeline.snapshot`.
"""

from __future__ import annotations

import errno
import json
import os
import time
from typing import Any, Iterable, Optional

from ..core.accumulator import EnabledChange, Measurement, Record
from .snapshot import SNAPSHOT_NAME, fsync_dir

JOURNAL_NAME = "journal.jsonl"
JOURNAL_VERSION = 1


class JournalMismatch(ValueError):
    """The journal in ``state_dir`` was written with other frames or another dimension."""


_json_string = json.encoder.encode_basestring_ascii  # what json.dumps uses for a str
_float_repr = float.__repr__                          # what json.dumps uses for a float


def _measurement_line(m: Measurement) -> Optional[str]:
    """The journal line of ``m`` written directly: the same characters ``json.dumps`` gives
    (keys in order, ``(",", ":")`` separators, ASCII, floats by ``float.__repr__``), at about
    half the cost per ingested message. ``None`` (then :func:`record_to_json` takes the
    ``json`` path, which refuses NaN and inf) unless the id is a str and every coordinate and
    the stamp a float (``float.__repr__`` raises ``TypeError`` otherwise) and finite (the
    ``repr`` of a finite float has no "n", that of ``nan`` / ``inf`` has)."""
    if type(m.fiducial_id) is not str:
        return None
    try:
        w = ",".join(map(_float_repr, m.working))
        d = ",".join(map(_float_repr, m.destination))
        s = _float_repr(m.stamp_s)
    except TypeError:
        return None
    if "n" in w or "n" in d or "n" in s:
        return None
    auto = ',"auto":true' if m.auto_id else ""
    return f'{{"t":"m","id":{_json_string(m.fiducial_id)},"w":[{w}],"d":[{d}],"s":{s}{auto}}}'


def record_to_json(record: Record) -> str:
    """One journal line (without the newline) for ``record``."""
    if type(record) is Measurement:
        line = _measurement_line(record)
        if line is not None:
            return line
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
        self._fd: Optional[int] = None
        self._size = 0                # bytes of whole records in the file
        self._needs_header = False    # the header is written with the first record that fits
        self._dirty = False           # a failed write could not be cut off yet
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
        error = self._open(truncate_to=good_end)
        if error:
            warnings.append(error)
        return records, warnings

    def _check_header(self, found: dict[str, Any]) -> None:
        for key, want in self.header.items():
            if key != "version" and found.get(key) != want:
                raise JournalMismatch(
                    f"{self.path} was written with {key}={found.get(key)!r}, but the node runs "
                    f"with {key}={want!r}: move the journal away or start with the same "
                    f"parameters")

    def _open(self, truncate_to: int) -> str:
        """Open for appending after ``truncate_to`` bytes; returns a warning when a new
        journal's header cannot be written yet (it is retried with the first record)."""
        self.close()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        if os.fstat(fd).st_size != truncate_to:
            os.ftruncate(fd, truncate_to)
        self._fd, self._size, self._dirty = fd, truncate_to, False
        self._needs_header = truncate_to == 0
        if self._needs_header:
            try:
                self._write(b"")
            except OSError as exc:
                return f"{self.path}: header not written yet ({exc}); retried with the first record"
        return ""

    def _write(self, data: bytes) -> None:
        """Append ``data`` (whole lines) in full, or raise ``OSError`` leaving the file as is."""
        assert self._fd is not None, "journal is not open: call load() first"
        if self._dirty:                      # cut off what a failed write left, before appending
            os.ftruncate(self._fd, self._size)
            self._dirty = False
        if self._needs_header:
            data = json.dumps(self.header, separators=(",", ":")).encode("utf-8") + b"\n" + data
        try:
            view = memoryview(data)
            while view:
                written = os.write(self._fd, view)
                if written <= 0:
                    raise OSError(errno.ENOSPC, "no space left for the journal")
                view = view[written:]
            if self.fsync:
                os.fsync(self._fd)
        except OSError:
            # A short write (disk full, file-size limit) leaves part of a line: cut it off now,
            # so that the record can never reappear once space is free again.
            try:
                os.ftruncate(self._fd, self._size)
            except OSError:
                self._dirty = True
            raise
        self._size += len(data)
        self._needs_header = False

    def append(self, record: Record) -> None:
        """Write one record with one ``write`` to the OS (and fsync it when configured).

        :raises OSError: when it cannot be written in full; nothing of it stays in the journal
            and the caller must not count the record.
        """
        self._write(record_to_json(record).encode("utf-8") + b"\n")

    def append_many(self, records: Iterable[Record]) -> None:
        """Append several records (one write): all of them or, on ``OSError``, none."""
        self._write("".join(record_to_json(r) + "\n" for r in records).encode("utf-8"))

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
        fsync_dir(self.state_dir)
        self._open(truncate_to=0)
        return archived

    def close(self) -> None:
        """Close the file (appends need :meth:`load` again)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:  # a journal dropped without close() must not leak its descriptor
        self.close()
