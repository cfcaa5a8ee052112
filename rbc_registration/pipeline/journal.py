"""The measurement journal of ``registration_node`` in ``state_dir`` (no rclpy).

``journal.jsonl``: one JSON object per line. The first line is a header (version, frames,
dimension); then one line per accepted measurement or enable change, in order. A record is
written and flushed to the OS before the node counts it, so a SIGKILL of the node loses no
accepted measurement. With ``fsync=True`` each record is also fsynced (survives power loss;
costs a disk sync per record). On open a torn last line (a write cut short) is skipped with a
warning and cut off so that appends stay line-aligned; an unreadable line elsewhere is skipped
with a warning. Floats are written with ``repr`` precision, so replay is bit-exact.

The journal's content is input, read as carefully as a message (version 2):

- every record ends with ``"c":"<crc32>"``, the CRC-32 of the setup's digest (a hash of the
  header: version, frames, dimension) followed by the record's bytes: a flipped digit is
  detected and the record skipped, and a record written for another setup never verifies, so a
  journal whose header line was lost is refused by a node configured differently
  (:class:`JournalMismatch`);
- lines longer than :data:`MAX_LINE_BYTES`, integers of more than :data:`MAX_INT_DIGITS`
  digits, ``NaN``/``Infinity`` and more than :data:`MAX_BRACKETS` brackets (nesting) are
  refused before or while parsing; a record must have exactly the fields and types this module
  writes (:func:`record_from_object`); the accumulator's live value checks then run on it on
  replay (``FiducialAccumulator.restore``);
- the file is opened without following symlinks and must be a regular file
  (:mod:`rbc_registration.pipeline.files`), at most :data:`MAX_JOURNAL_BYTES`; created 0600.

A version 1 journal (no checksums) is still read, its records validated the same way, and
rewritten as version 2 at once (atomically; the old file is kept as
``journal.jsonl.v1.<time>.bak``).

A record that cannot be written (disk full, file-size limit, I/O error) raises ``OSError`` and
leaves nothing behind: a partly written line is cut off again at once, so the record can never
reappear later (the caller does not count it).

``calibration.json``: the latest model, see :mod:`rbc_registration.pipeline.snapshot`.

``checkpoint.json``: the accumulator's running sums at a journal position (bytes, lines,
records, CRC-32 of those bytes), see :mod:`rbc_registration.pipeline.checkpoint`. The journal
keeps the running CRC-32 of its bytes as it appends (:meth:`Journal.position`);
:meth:`Journal.load_after` checks a checkpoint's position against the file in 1 MiB chunks and
reads only the records after it, so a start costs a pass of ``zlib.crc32`` over the journal
instead of parsing and holding every record.
"""

from __future__ import annotations

import errno
import json
import os
import time
import zlib
from typing import Any, Iterable, Optional

from ..core.measurements.accumulator import Record
from .checkpoint import JournalPosition
from .files import open_private, pread_range, private_dir, read_fd
from .journal_records import (JOURNAL_VERSION, MAX_JOURNAL_BYTES, MAX_LINE_BYTES,
                              READABLE_VERSIONS, JournalMismatch, parse_line, record_from_json,
                              record_to_json, seal, setup_digest, unseal)
from .snapshot import fsync_dir, write_atomic
from .state_dir import CHECKPOINT_NAME, JOURNAL_NAME, SNAPSHOT_NAME

#: How the journal is opened for appending (created when missing).
_APPEND_OR_CREATE = os.O_RDWR | os.O_APPEND | os.O_CREAT

#: Re-exported: the record format lives in :mod:`.journal_records`.
__all__ = ["JOURNAL_NAME", "JOURNAL_VERSION", "Journal", "JournalMismatch", "record_from_json",
           "record_to_json"]


class Journal:
    """Append-only journal of accepted records in ``state_dir`` (see the module docstring).

    :param state_dir: directory (created 0700 if missing).
    :param header: identifies the setup (frames, dimension); an existing journal with another
        header, or without a header and with records of another setup, is refused
        (:class:`JournalMismatch`).
    :param fsync: fsync after every record.
    """

    def __init__(self, state_dir: str, header: dict[str, Any], fsync: bool = False) -> None:
        self.state_dir = private_dir(state_dir)
        self.path = os.path.join(self.state_dir, JOURNAL_NAME)
        self.header = {"t": "h", "version": JOURNAL_VERSION, **header}
        self.digest = setup_digest(self.header)
        self.fsync = fsync
        self._fd: Optional[int] = None
        self._size = 0                # bytes of whole records in the file
        self._needs_header = False    # the header is written with the first record that fits
        self._dirty = False           # a failed write could not be cut off yet
        self.n_skipped = 0            # lines skipped by the last load (torn, corrupt, invalid)
        self._unterminated: Optional[int] = None   # offset of a kept last record without newline
        # The journal position (checkpoint.JournalPosition) of the end of the file: its CRC-32,
        # lines and records, and the lines in it the last load skipped that stay in the file.
        self._crc = self._lines = self._records = self._kept_skips = 0
        #: Why the last :meth:`load_after` did not match ("" when it did).
        self.mismatch = ""

    def load(self) -> tuple[list[Record], list[str]]:
        """Read the existing journal (if any) and open it for appending.

        :return: the records in order, and warnings about skipped lines (one per line).
        :raises JournalMismatch: when the header names other frames, another dimension or an
            unknown version, or there is no header and no record was written for this setup.
        :raises NotARegularFile: when the journal is a symlink, FIFO, device or directory.
        """
        self.close()
        fd = open_private(self.path, _APPEND_OR_CREATE)
        try:
            data = read_fd(fd, self.path, MAX_JOURNAL_BYTES)
            records, warnings, good_end, version = self._parse(data)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        if version == 1:
            os.close(fd)
            self._fd = None
            warnings.append(self._migrate(records))
            fd = open_private(self.path, os.O_RDWR | os.O_APPEND)
            self._fd = fd
            data = read_fd(fd, self.path, MAX_JOURNAL_BYTES)
            good_end = len(data)
        self._crc, self._lines = zlib.crc32(data[:good_end]), data.count(b"\n", 0, good_end)
        self._records = len(records)
        return self._opened(records, warnings, good_end, data)

    def load_after(self, position: JournalPosition) -> Optional[tuple[list[Record], list[str]]]:
        """Open the journal for appending when its first ``position.offset`` bytes still are
        those of a checkpoint's :class:`~.checkpoint.JournalPosition` (same header, lines and
        CRC-32; read in chunks, never held), and read only the records after them.

        :return: the records after the position and warnings about skipped lines (as
            :meth:`load`), or ``None`` when the journal does not match (:attr:`mismatch` says
            why; nothing is opened: call :meth:`load`).
        :raises JournalMismatch: as :meth:`load`, for a header of another setup.
        :raises NotARegularFile: as :meth:`load`.
        """
        self.close()
        fd = open_private(self.path, _APPEND_OR_CREATE)
        try:
            self.mismatch = self._check_prefix(fd, position)
            if self.mismatch:
                os.close(fd)
                return None
            size = os.fstat(fd).st_size
            if size > MAX_JOURNAL_BYTES:
                raise ValueError(f"{self.path} is {size} bytes, more than the limit of "
                                 f"{MAX_JOURNAL_BYTES}: refused")
            tail = pread_range(fd, position.offset, size)
            records, warnings, good_end, _ = self._parse(tail, position.lines, JOURNAL_VERSION)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        if self._unterminated is not None:
            self._unterminated += position.offset
        self._crc = zlib.crc32(tail[:good_end], position.crc)
        self._lines = position.lines + tail.count(b"\n", 0, good_end)
        self._records = position.records + len(records)
        self._kept_skips += position.skipped
        return self._opened(records, warnings, position.offset + good_end, tail, position.offset,
                            position.crc)

    def _check_prefix(self, fd: int, position: JournalPosition) -> str:
        """Why the journal open as ``fd`` does not start with ``position``'s bytes ("": it
        does). The header is checked as :meth:`load` checks it."""
        size = os.fstat(fd).st_size
        if size < position.offset:
            return f"the journal has {size} bytes, fewer than the checkpoint's {position.offset}"
        first = os.pread(fd, MAX_LINE_BYTES + 1, 0).split(b"\n", 1)[0]
        try:
            header = parse_line(first.decode("utf-8"))
        except (ValueError, UnicodeDecodeError):
            header = None
        if not isinstance(header, dict) or header.get("t") != "h":
            return "the journal does not start with a header line"
        if self._check_header(header) != JOURNAL_VERSION:
            return f"the journal is of version {header.get('version')}"
        crc = lines = 0
        for start in range(0, position.offset, 1 << 20):
            chunk = os.pread(fd, min(1 << 20, position.offset - start), start)
            crc, lines = zlib.crc32(chunk, crc), lines + chunk.count(b"\n")
        if position.offset and os.pread(fd, 1, position.offset - 1) != b"\n":
            return f"byte {position.offset} of the journal does not end a line"
        if (crc, lines) != (position.crc, position.lines):
            return (f"its first {position.offset} bytes are not the checkpoint's (CRC-32 "
                    f"{crc:08x}, {lines} lines; the checkpoint's {position.crc:08x}, "
                    f"{position.lines} lines)")
        return ""

    def _opened(self, records: list[Record], warnings: list[str], good_end: int, data: bytes,
                base: int = 0, base_crc: int = 0) -> tuple[list[Record], list[str]]:
        """Open for appending after ``good_end`` bytes and end a kept last line without its
        newline (``data``: the bytes read from offset ``base``, whose CRC-32 is ``base_crc``)."""
        error = self._open(truncate_to=good_end)
        if self._unterminated is not None:
            try:
                self._write(b"\n")
            except OSError as exc:        # cannot end the line: cut it off as a torn record
                os.ftruncate(self._fd, self._unterminated)
                self._size = self._unterminated
                self._crc = zlib.crc32(data[:self._unterminated - base], base_crc)
                self._records -= 1
                records.pop()
                warnings[-1] = (f"{self.path}: last record without a newline skipped: the "
                                f"newline could not be added ({exc})")   # the parse's last
        if error:
            warnings.append(error)
        return records, warnings

    def _parse(self, data: bytes, lineno: int = 0, version: Optional[int] = None
               ) -> tuple[list[Record], list[str], int, Optional[int]]:
        """(records, warnings, bytes of whole lines, header version or None) of ``data``,
        whose first line is line ``lineno + 1`` of the journal (``version``: of a header read
        before it)."""
        records: list[Record] = []
        warnings: list[str] = []
        offset = good_end = 0
        self._unterminated = None
        self._kept_skips = 0   # unreadable lines: they stay in the file
        unsealed = 0   # records that failed their checksum
        while offset < len(data):
            end = data.find(b"\n", offset)
            lineno += 1
            if end < 0:
                kept = self._whole_last_record(data[offset:], version)
                if kept is not None:      # only its newline is missing (a hand edit, a restore)
                    records.append(kept)
                    self._unterminated, good_end = offset, len(data)   # load() adds the newline
                    warnings.append(f"{self.path}:{lineno}: last record without a newline kept "
                                    f"(its checksum holds); the newline added")
                else:
                    warnings.append(f"{self.path}:{lineno}: torn last record "
                                    f"({len(data) - offset} bytes without a newline) skipped")
                break
            raw = data[offset:end].strip()
            offset = good_end = end + 1
            if not raw:
                continue
            try:
                if len(raw) > MAX_LINE_BYTES:
                    raise ValueError(f"line of {len(raw)} bytes, more than {MAX_LINE_BYTES}")
                if version is None and not records and b'"h"' in raw[:16]:
                    first = parse_line(raw.decode("utf-8"))
                    if isinstance(first, dict) and first.get("t") == "h":
                        version = self._check_header(first)
                        continue
                if version != 1:
                    try:
                        raw = unseal(raw, self.digest)
                    except ValueError:
                        unsealed += 1
                        raise
                records.append(record_from_json(raw.decode("utf-8")))
            except JournalMismatch:
                raise
            except (ValueError, KeyError, TypeError, RecursionError) as exc:
                warnings.append(f"{self.path}:{lineno}: unreadable record skipped ({exc})")
                self._kept_skips += 1
        if version is None and unsealed and not records:
            raise JournalMismatch(
                f"{self.path} has no header line and none of its {unsealed} record(s) was "
                f"written for this setup ({self._setup()}): move the journal away or start "
                f"with the parameters it was written with")
        self.n_skipped = len(warnings) - (self._unterminated is not None)   # kept: not skipped
        return records, warnings, good_end, version

    def _whole_last_record(self, raw: bytes, version: Optional[int]) -> Optional[Record]:
        """The record of a last line without its newline when its checksum holds (sealed
        versions only: a write cut short never verifies), else None."""
        raw = raw.strip()
        if version is None or version == 1 or not raw or len(raw) > MAX_LINE_BYTES:
            return None
        try:
            return record_from_json(unseal(raw, self.digest).decode("utf-8"))
        except (ValueError, KeyError, TypeError, RecursionError):
            return None

    def _setup(self) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in self.header.items() if k not in ("t", "version"))

    def _check_header(self, found: Any) -> int:
        if not isinstance(found, dict) or found.get("version") not in READABLE_VERSIONS:
            got = found.get("version") if isinstance(found, dict) else found
            raise JournalMismatch(
                f"{self.path} has journal version {got!r}; this node reads versions "
                f"{', '.join(map(str, READABLE_VERSIONS))}: move the journal away")
        for key, want in self.header.items():
            if key != "version" and found.get(key) != want:
                raise JournalMismatch(
                    f"{self.path} was written with {key}={found.get(key)!r}, but the node runs "
                    f"with {key}={want!r}: move the journal away or start with the same "
                    f"parameters")
        return int(found["version"])

    def _migrate(self, records: list[Record]) -> str:
        """Rewrite a version 1 journal as this version (atomically; the old one kept)."""
        backup = f"{self.path}.v1.{_stamp()}.bak"
        os.link(self.path, backup)
        header = json.dumps(self.header, separators=(",", ":")).encode("utf-8") + b"\n"
        write_atomic(self.path, (header + self._sealed(records)).decode("utf-8"))
        return (f"{self.path}: journal version 1 rewritten as version {JOURNAL_VERSION} "
                f"({len(records)} records; the old file is kept as {backup})")

    def _sealed(self, records: Iterable[Record]) -> bytes:
        return b"".join(seal(record_to_json(r).encode("utf-8"), self.digest) + b"\n"
                        for r in records)

    def _open(self, truncate_to: int) -> str:
        """Open for appending after ``truncate_to`` bytes; returns a warning when a new
        journal's header cannot be written yet (it is retried with the first record)."""
        if self._fd is None:
            self._fd = open_private(self.path, _APPEND_OR_CREATE)
        fd = self._fd
        if os.fstat(fd).st_size != truncate_to:
            os.ftruncate(fd, truncate_to)
        self._size, self._dirty = truncate_to, False
        if truncate_to == 0:
            self._crc = self._lines = self._records = self._kept_skips = 0
        self._needs_header = truncate_to == 0
        if self._needs_header:
            try:
                self._write(b"")
            except OSError as exc:
                return f"{self.path}: header not written yet ({exc}); retried with the first record"
        return ""

    def _write(self, data: bytes) -> None:
        """Append ``data`` (whole lines) in full, or raise ``OSError`` leaving the file as is."""
        if self._fd is None:
            raise OSError(f"{self.path}: the journal is not open")
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
        self._crc, self._lines = zlib.crc32(data, self._crc), self._lines + data.count(b"\n")
        self._needs_header = False

    def append(self, record: Record) -> None:
        """Write one record with one ``write`` to the OS (and fsync it when configured).

        :raises OSError: when it cannot be written in full; nothing of it stays in the journal
            and the caller must not count the record.
        """
        self._write(self._sealed((record,)))
        self._records += 1

    def append_many(self, records: Iterable[Record]) -> None:
        """Append several records (one write): all of them or, on ``OSError``, none."""
        records = list(records)
        self._write(self._sealed(records))
        self._records += len(records)

    def archive(self) -> Optional[str]:
        """Move the journal (and snapshot and checkpoint) aside as ``*.<UTC time>.bak`` and start
        a new one.

        :return: the archived journal's path, or ``None`` when there was none.
        :raises OSError: when a file cannot be moved or the new journal cannot be created; the
            journal then stays as it was, open for appending (the snapshot may be archived
            already: the next model rewrites it).
        """
        suffix = _stamp()
        for name in (SNAPSHOT_NAME, CHECKPOINT_NAME):
            aside = os.path.join(self.state_dir, name)
            if os.path.exists(aside):
                os.replace(aside, f"{aside}.{suffix}.bak")
        archived = f"{self.path}.{suffix}.bak" if os.path.exists(self.path) else None
        if archived:
            os.replace(self.path, archived)     # the open descriptor moves with the file
        try:
            fd = open_private(self.path, _APPEND_OR_CREATE)
        except OSError:
            if archived:                        # put it back: the journal stays as it was
                os.replace(archived, self.path)
            raise
        self.close()
        self._fd = fd                           # from here on the reset has happened
        try:
            fsync_dir(self.state_dir)
        except OSError:
            pass    # durability of the renames only: the new journal is open either way
        self._open(truncate_to=0)
        return archived

    def position(self, skipped: int = 0) -> JournalPosition:
        """The position of the end of the journal (after the last record written), for a
        checkpoint; ``skipped``: lines the caller's replay skipped besides the unreadable ones
        (records that failed the live checks)."""
        return JournalPosition(self._size, self._lines, self._records, self._crc,
                               self._kept_skips + skipped)

    def close(self) -> None:
        """Close the file (appends need :meth:`load` again)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:  # a journal dropped without close() must not leak its descriptor
        self.close()


def _stamp() -> str:
    """A UTC time stamp unique enough for backup names."""
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + f".{time.time_ns() % 10**9:09d}"
