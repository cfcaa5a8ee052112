"""FIDUCIALS.csv read as a stream: memory flat in the number of rows.

:func:`read_fiducial_sums` applies the rules of :func:`~.csv_io.read_fiducials` (the same ids,
means, notes, groups, sessions and errors, in the same order) but returns each fiducial's mean
points and :class:`~rbc_registration.core.decision.noise.RepeatStats` instead of its rows:

1. the file is parsed once (the ``csv`` module), :data:`CHUNK_ROWS` rows at a time, into a spool
   of fixed-width float64 records in an unlinked temporary file (line, id, session, the working
   and destination points) and a spool of the rows' text hashes; the sessions' per
   (session, fiducial) sums are kept on the way
   (:func:`~rbc_registration.core.measurements.sessions.
   session_cells`' sums, in row order);
2. a look at the spool, re-stationed, finds the copied runs (:func:`~.csv_io._copied_runs`'
   rule; only rows whose text hash occurs more than once are looked at one by one) and each
   id's first row (the repeat limits);
3. the ids are taken in batches of at most :data:`BATCH_ROWS` rows: one look at the spool per
   batch gathers their rows, and each id's repeat rule (:func:`~.csv_io._checked_repeats`: the
   most central row first, each row against the mean of those accepted before it) runs on its
   rows, vectorised, with the in-memory reader's arithmetic (the same floats).

Memory grows with the fiducials, sessions and copied rows, and with :data:`BATCH_ROWS` (or one
fiducial's rows, when it has more); the spools take 8 x (4 + 2 d) bytes of temporary disk per row
(plus 16 for a 2D read of a file with z columns).
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from operator import methodcaller
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterator, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from ..core.decision.noise import RepeatStats
from ..core.repeats import repeat_outlier
from ..core.measurements.sessions import SessionPlan, estimate_sessions
from ..core.validation import MAX_ABS_COORDINATE
from ..pipeline.files import NotARegularFile, check_input_file
from .progress import Progress
from .csv_io import (COPY_MATCHES, COPY_RUN, MAX_CSV_BYTES, CsvError, PathLike, _dimension,
                     _header_hint, _ignored_rows_notes, _likely_format, _number,
                     _refuse_swallowed_rows, _repeat_limits, header_problem, reference_session)

#: Rows parsed per chunk (and records per read of the spool).
CHUNK_ROWS = 16384
#: Rows of one batch of ids held at once for the repeat rule.
BATCH_ROWS = 1 << 18
#: Text hashes sorted at once to find those occurring more than once.
HASH_BUCKET_ROWS = 1 << 20
#: Rows of one id the repeat rule checks at once (from the last row it ignored).
RULE_BLOCK = 8192


@dataclass(frozen=True)
class FiducialSums:
    """Fiducials of a FIDUCIALS.csv, in order of first appearance, as their means and repeat
    statistics (:class:`~.csv_io.FiducialTable` without the rows)."""

    ids: tuple[str, ...]
    #: Mean working-frame (re-stationed) and destination-frame point of each fiducial (J, d).
    working: NDArray[np.float64]
    destination: NDArray[np.float64]
    repeat_stats: RepeatStats
    dimension: int
    notes: tuple[str, ...] = ()
    groups: Optional[tuple[str, ...]] = None
    sessions: Optional[SessionPlan] = None


class Spool:
    """Fixed-width records of one dtype in an unlinked temporary file, written and read in
    chunks."""

    def __init__(self, width: int, dtype: Any = np.float64) -> None:
        self.width, self.dtype = width, np.dtype(dtype)
        self.rows = 0
        self._file: IO[bytes] = tempfile.TemporaryFile(prefix="rbc-csv-")

    def write(self, block: NDArray) -> None:
        """Append records (m, width)."""
        if len(block):
            self._file.seek(0, 2)
            self._file.write(np.ascontiguousarray(block, dtype=self.dtype).tobytes())
            self.rows += len(block)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[NDArray]:
        """The records in order, ``rows`` at a time."""
        self._file.seek(0)
        size = rows * self.width * self.dtype.itemsize
        while True:
            data = self._file.read(size)
            if not data:
                return
            yield np.frombuffer(data, dtype=self.dtype).reshape(-1, self.width)

    def close(self) -> None:
        self._file.close()


@dataclass
class _Parsed:
    """What the parse keeps: the header, the ids and sessions (codes in order of first
    appearance), group labels and the per (session, id) sums."""

    header: list[str]
    d: int
    spool: Spool
    hashes: Spool
    z_extra: bool
    ids: dict[str, int]
    sessions: dict[str, int]
    labels: dict[str, str]
    cells: dict[tuple[int, int], int]
    cell_sums: NDArray[np.float64]
    cell_counts: list[int]


class _Parser:
    """Pass 1 (module docstring) over chunks of rows. A chunk of well-formed rows is converted
    column by column (numpy reads the numbers as ``float()`` does); any chunk with something to
    say (a short or long row, a blank id, a bad number or group) is taken row by row with the
    in-memory reader's checks, so the errors and their order are the same."""

    def __init__(self, path: PathLike, p: Path, raw: list[str], dim: Optional[int]) -> None:
        self.path, self.p, self.raw = path, p, raw
        self.header = header = [h.strip() for h in raw]
        self.nh = len(header)
        self.errors: dict[str, CsvError] = {}
        self.ok = bool(header) and not _header_hint(header) and not any(
            h and header.count(h) > 1 for h in header)
        self.missing = [c for c in REQUIRED if c not in header]
        self.d = 0
        if self.ok and not self.missing:
            try:
                self.d = _dimension(path, header, ["w", "d"], dim)
            except CsvError as exc:
                self.errors["dim"] = exc
        d = self.d
        axes = "xyz"[:d]
        self.z_extra = d == 2 and ("wz" in header or "dz" in header)
        self.numbers = [f"w{a}" for a in axes] + [f"d{a}" for a in axes]
        self.names = ["id"] + self.numbers + ["group", "session"] + (
            ["wz", "dz"] if self.z_extra else [])
        self.where = {h: k for k, h in enumerate(header)}   # DictReader keeps the last
        self.index = [self.where.get(n, -1) for n in self.names]
        self.simple = self.ok and "" not in header
        self.parsing = self.ok and not self.missing and d > 0
        self.has_group, self.has_session = "group" in header, "session" in header
        self.spool = Spool(3 + 2 * d + (2 if self.z_extra else 0)) if self.parsing else None
        self.hashes = Spool(1, np.int64) if self.parsing else None
        self.ids: dict[str, int] = {}
        self.sessions: dict[str, int] = {}
        self.labels: dict[str, str] = {}
        self.cells: dict[tuple[int, int], int] = {}
        self.cell_sums = [np.zeros((0, max(d, 1)))]
        self.cell_counts: list[int] = []
        self.session = "1"
        self.prev_line = 1
        self.n_rows = 0

    def chunk(self, rows: Optional[list[list[str]]], lines: list[int],
              cols: Optional[list[Sequence[str]]] = None,
              keys: Optional[list[int]] = None) -> None:
        """The next non-empty rows of the file and their lines; or their columns (every row
        of the header's length), and the hashes of their text (:func:`_text_key`)."""
        start = self.prev_line
        self.prev_line = lines[-1]
        if not self.ok:         # refused for its header, once the whole file is read
            return
        jumps = [k for k in range(len(lines)) if lines[k] - (lines[k - 1] if k else start) > 1]
        if self.parsing and self.simple:
            if cols is None and rows is not None and set(map(len, rows)) == {self.nh}:
                cols = list(zip(*rows))
            if cols is not None and self._fast(list(cols), lines, jumps, keys):
                return
        if rows is None:
            rows = [list(r) for r in zip(*cols)]
        self._slow(rows, lines, start)

    def _fast(self, cols: list[Sequence[str]], lines: list[int], jumps: list[int],
              keys: Optional[list[int]]) -> bool:
        """Convert well-formed rows column by column; False (nothing changed) when a row needs
        a closer look."""
        n = len(lines)
        idx = self.index
        nw = len(self.numbers)
        for k, col in enumerate(cols):
            joined = "\x00".join(col)
            if k in idx[1:1 + nw] and "_" in joined:
                return False
            if _padded(joined):
                cols[k] = tuple(map(str.strip, col))
                keys = None
        fids = cols[idx[0]]
        if "" in fids:
            return False
        points = np.empty((n, nw))
        for k in range(nw):
            try:
                points[:, k] = _floats(cols[idx[1 + k]])
            except ValueError:
                return False
        if not (np.isfinite(points) & (np.abs(points) <= MAX_ABS_COORDINATE)).all():
            return False
        if self.has_group:
            new: dict[str, str] = {}
            for fid, group in dict.fromkeys(zip(fids, cols[idx[1 + nw]])):
                if group and self.labels.get(fid, new.setdefault(fid, group)) != group:
                    return False
            self.labels.update((f, g) for f, g in new.items() if f not in self.labels)
        for k in jumps:
            self._swallowed(lines[k], dict(zip(self.header, (c[k] for c in cols))))
        for fid in dict.fromkeys(fids):
            self.ids.setdefault(fid, len(self.ids))
        codes = np.fromiter(map(self.ids.__getitem__, fids), np.float64, len(fids))
        if self.has_session:
            labels = []
            session = self.session
            for value in cols[idx[2 + nw]]:
                session = value or session
                labels.append(session)
            self.session = session
        else:
            labels = [self.session] * n
        for name in dict.fromkeys(labels):
            self.sessions.setdefault(name, len(self.sessions))
        scodes = np.fromiter(map(self.sessions.__getitem__, labels), np.float64, len(labels))
        parts = [np.array(lines, dtype=np.float64), codes, scodes, points.T]
        if self.z_extra:
            parts += [[_z_value(v, idx[3 + nw + k] >= 0) for v in (
                cols[idx[3 + nw + k]] if idx[3 + nw + k] >= 0 else [None] * n)]
                for k in range(2)]
        if keys is None:
            keys = [_text_key(r) for r in zip(*cols)]
        self._write(np.vstack(parts).T, keys)
        self.n_rows += n
        return True

    def _slow(self, rows: list[list[str]], lines: list[int], prev: int) -> None:
        """The rows one by one, with :func:`~.csv_io.read_fiducials`' checks in its order."""
        path, header, nh, names = self.path, self.header, self.nh, self.names
        nw = len(self.numbers)
        records: list[list[float]] = []
        row_hashes: list[int] = []
        for row, line in zip(rows, lines):
            jumped = line - prev > 1
            prev = line
            table = _row_dict(self.raw, row)
            if not _filled(table):
                continue
            self.n_rows += 1
            if jumped:
                self._swallowed(line, table)
            if len(row) > nh and "extra" not in self.errors:
                rest = row[nh:]
                extra = [v for v in rest if v and v.strip()]
                if extra:
                    self.errors["extra"] = CsvError(
                        f"{self.p}: row {line}: {nh + len(rest)} fields, the header has {nh} "
                        f"(extra: {','.join(extra)})")
            if not self.parsing:
                continue
            values = [table.get(n) if n in self.where else None for n in names]
            fid = values[0] or ""
            try:
                if not fid:
                    raise CsvError(f"{path}: row {line}: column id is empty")
                point = [_number(path, line, name, text)
                         for name, text in zip(self.numbers, values[1:1 + nw])]
                if self.has_group:
                    group = values[1 + nw] or ""
                    if group and self.labels.setdefault(fid, group) != group:
                        raise CsvError(
                            f"{path}: row {line}: id {fid!r} is in group {group!r} here and in "
                            f"group {self.labels[fid]!r} in an earlier row: one fiducial, one "
                            "group")
            except CsvError as exc:
                self.errors["row"] = exc
                self.parsing = False
                continue
            self.session = values[2 + nw] or self.session
            code = self.ids.setdefault(fid, len(self.ids))
            scode = self.sessions.setdefault(self.session, len(self.sessions))
            record = [float(line), float(code), float(scode)] + point
            if self.z_extra:
                record += [_z_value(values[3 + nw], self.index[3 + nw] >= 0),
                           _z_value(values[4 + nw], self.index[4 + nw] >= 0)]
            records.append(record)
            row_hashes.append(_text_key([table.get(h) for h in header]))
        if records:
            self._write(np.array(records, dtype=np.float64), row_hashes)

    def _swallowed(self, line: int, table: dict[str, Any]) -> None:
        if "swallowed" not in self.errors:
            try:
                _refuse_swallowed_rows(self.p, self.header, [(line, table)])
            except CsvError as exc:
                self.errors["swallowed"] = exc

    def _write(self, block: NDArray[np.float64], row_hashes: list[int]) -> None:
        if self.has_session:
            _add_cells(block, self.cells, self.cell_sums, self.cell_counts)
        self.spool.write(block)
        self.hashes.write(np.array(row_hashes, dtype=np.int64).reshape(-1, 1))

    def close(self) -> None:
        _close(self.spool, self.hashes)

    def result(self) -> _Parsed:
        """The parse, or the first error (:func:`~.csv_io.read_fiducials`' order)."""
        failure = _first_error(self.p, self.header, self.missing, self.n_rows, self.errors)
        if failure is not None:
            self.close()
            raise failure
        return _Parsed(self.header, self.d, self.spool, self.hashes, self.z_extra, self.ids,
                       self.sessions, self.labels, self.cells, self.cell_sums[0],
                       self.cell_counts)


def _floats(column: Sequence[str]) -> NDArray[np.float64]:
    """``float()`` of each text of a column (numpy converts as ``float()`` does); a column of
    few distinct texts (a destination point repeated with each measurement) converts each text
    once."""
    distinct = dict.fromkeys(column)
    if 4 * len(distinct) > len(column):
        return np.array(column, dtype=np.float64)
    table = dict(zip(distinct, np.array(list(distinct), dtype=np.float64).tolist()))
    return np.fromiter(map(table.__getitem__, column), np.float64, len(column))


def _text_key(values: Sequence[Any]) -> int:
    """The hash of a row's text (its stripped fields in the header's order) by which copied
    rows are found: of the fields joined by NUL (as the quick read hashes a line's), or of the
    fields themselves when one is missing or holds a NUL."""
    if all(isinstance(v, str) and "\x00" not in v for v in values):
        return hash("\x00".join(values))
    return hash(tuple(tuple(v) if isinstance(v, list) else v for v in values))


#: The ASCII characters ``str.strip`` removes.
_ASCII_SPACE = tuple(chr(c) for c in range(128) if chr(c).isspace())


def _padded(text: str) -> bool:
    """Whether fields joined by NUL may hold white space to strip (any at all, or non-ASCII)."""
    return not text.isascii() or any(c in text for c in _ASCII_SPACE)


REQUIRED = ["id", "wx", "wy", "dx", "dy"]


#: Characters of a file read in blocks at a time.
BLOCK_CHARS = 1 << 20


def _read_blocks(parser: _Parser, fh: IO[str], line_no: int, bar: Progress) -> None:
    """Feed ``parser`` the rest of the file: blocks of whole lines split at commas while they
    hold no quote, NUL or lone carriage return (then read exactly as the ``csv`` module reads
    them); from the first block that does, the ``csv`` module."""
    nh = parser.nh
    limit = csv.field_size_limit()
    while True:
        raw = fh.read(BLOCK_CHARS)
        if not raw:
            return
        if not raw.endswith("\n"):
            raw += fh.readline()
        bar.update(len(raw))
        block = raw.replace("\r\n", "\n") if "\r" in raw else raw
        if '"' in block or "\x00" in block or "\r" in block or (
                len(block) > limit and max(map(len, block.split("\n"))) > limit):
            _read_csv(parser, csv.reader(itertools.chain(io.StringIO(raw, newline=""), fh)),
                      line_no)
            return
        lines = block.split("\n")
        if block.endswith("\n"):
            lines.pop()
        numbers = list(range(line_no + 1, line_no + 1 + len(lines)))
        line_no += len(lines)
        if "" in lines:                     # blank lines: skipped, still counted
            numbers = [k for k, text in zip(numbers, lines) if text]
            lines = [text for text in lines if text]
            if not lines:
                continue
        if set(map(methodcaller("count", ","), lines)) == {nh - 1}:
            joined = "\n".join(lines)
            flat = joined.replace("\n", ",").split(",")
            keys = list(map(hash, joined.replace(",", "\x00").split("\n")))
            parser.chunk(None, numbers, [flat[k::nh] for k in range(nh)], keys)
        else:
            parser.chunk([text.split(",") for text in lines], numbers)


def _read_csv(parser: _Parser, reader: Any, offset: int) -> None:
    """Feed ``parser`` the rows of a ``csv`` reader (its lines after ``offset`` lines)."""
    rows: list[list[str]] = []
    lines: list[int] = []
    for row in reader:
        if row:
            rows.append(row)
            lines.append(offset + reader.line_num)
            if len(rows) >= CHUNK_ROWS:
                parser.chunk(rows, lines)
                rows, lines = [], []
    if rows:
        parser.chunk(rows, lines)


def _parse(path: PathLike, dim: Optional[int], progress: bool = False) -> _Parsed:
    """Pass 1 (module docstring). Errors are raised in :func:`~.csv_io.read_fiducials`' order:
    decoding and CSV errors, the header's, quoted fields swallowing rows, extra fields, missing
    columns, no rows, the dimension, then the first row of a bad value or group."""
    p = Path(path)
    try:
        check_input_file(str(p), MAX_CSV_BYTES)
        fh = p.open(newline="", encoding="utf-8-sig")
    except FileNotFoundError:
        raise CsvError(f"{p}: no such file") from None
    except NotARegularFile as exc:
        raise CsvError(str(exc)) from None
    parser: Optional[_Parser] = None
    bar = Progress(f"reading {p.name} (characters)", p.stat().st_size, enabled=progress,
                   delay_s=1.0)
    try:
        with fh:
            head = fh.readline()
            if '"' in head:
                reader = csv.reader(itertools.chain([head], fh))
                parser = _Parser(path, p, next(reader, []), dim)
                _read_csv(parser, reader, 0)
            else:
                parser = _Parser(path, p, next(csv.reader([head]), []), dim)
                _read_blocks(parser, fh, 1 if head else 0, bar)
        bar.done()
    except UnicodeDecodeError as exc:
        if parser is not None:
            parser.close()
        raise CsvError(f"{p}: not a readable CSV file ({exc}){_likely_format(p)}") from None
    except csv.Error as exc:
        if parser is not None:
            parser.close()
        why = (": an opening quote (\") without its closing one, or not a CSV file of points"
               if "field limit" in str(exc) else "")
        raise CsvError(f"{p}: not a readable CSV file ({exc}){why}") from None
    except BaseException:
        if parser is not None:
            parser.close()
        raise
    return parser.result()


def _first_error(p: Path, header: list[str], missing: list[str], n_rows: int,
                 errors: dict[str, CsvError]) -> Optional[CsvError]:
    problem = header_problem(p, header, REQUIRED)
    if problem is not None:
        return problem
    for kind in ("swallowed", "extra"):
        if kind in errors:
            return errors[kind]
    if missing:
        return CsvError(f"{p}: missing column(s) {', '.join(missing)}; header is "
                        f"{','.join(header)}")
    if not n_rows:
        return CsvError(f"{p}: no data rows")
    for kind in ("dim", "row"):
        if kind in errors:
            return errors[kind]
    return None


def _close(*spools: Optional[Spool]) -> None:
    for s in spools:
        if s is not None:
            s.close()


def _row_dict(fieldnames: list[str], row: list[str]) -> dict[str, Any]:
    """A row as :func:`~.csv_io._read_rows` sees it (``csv.DictReader``'s dict, keys and values
    stripped; fields beyond the header a list under ``""``)."""
    table: dict[Any, Any] = dict(zip(fieldnames, row))
    if len(row) > len(fieldnames):
        table[None] = row[len(fieldnames):]
    else:
        for key in fieldnames[len(row):]:
            table[key] = None
    return {(k or "").strip(): v.strip() if isinstance(v, str) else v for k, v in table.items()}


def _filled(table: dict[str, Any]) -> bool:
    """Whether a row has a field that is not empty or blank."""
    return any(v for v in table.values() if isinstance(v, str)) or any(
        x.strip() for v in table.values() if isinstance(v, list) for x in v)


def _z_value(text: Optional[str], present: bool) -> float:
    """:func:`~.csv_io._dropped_z_note`'s value of a z column."""
    if not present:
        return 0.0
    try:
        return float((text or "").strip())
    except ValueError:
        return math.nan


def _add_cells(block: NDArray[np.float64], cells: dict[tuple[int, int], int],
               sums: list[NDArray[np.float64]], counts: list[int]) -> None:
    """Add a chunk's working points to the per (session, id) sums (``sums[0]``, grown), in
    row order (as :func:`~rbc_registration.core.measurements.sessions.session_cells` adds them)."""
    d = sums[0].shape[1]
    cell = np.array([cells.setdefault(key, len(cells)) for key in zip(
        block[:, 2].astype(np.int64).tolist(), block[:, 1].astype(np.int64).tolist())],
        dtype=np.int64)
    grow = len(cells) - len(counts)
    if grow:
        sums[0] = np.vstack([sums[0], np.zeros((grow, d))])
        counts.extend([0] * grow)
    np.add.at(sums[0], cell, block[:, 3:3 + d])
    for k, c in zip(*np.unique(cell, return_counts=True)):
        counts[int(k)] += int(c)


def _plan(path: PathLike, parsed: _Parsed, reference_sessions: Optional[Sequence[str]]
          ) -> SessionPlan:
    """:func:`~.csv_io._restation`'s session plan from the per (session, id) sums."""
    order = list(parsed.sessions)
    reference = reference_session(path, order, reference_sessions)
    id_names = list(parsed.ids)
    cells: dict[str, dict[str, tuple[NDArray[np.float64], int]]] = {}
    for (s, f), k in parsed.cells.items():
        cells.setdefault(order[s], {})[id_names[f]] = (
            parsed.cell_sums[k] / parsed.cell_counts[k], parsed.cell_counts[k])
    return estimate_sessions(cells, reference)


def _kept_chunks(parsed: _Parsed, plan: Optional[SessionPlan]
                 ) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64],
                                     NDArray[np.int64]]]:
    """The spool's records, their working points re-stationed, and text hashes of the rows
    kept (a session kept apart leaves its rows out), chunk by chunk."""
    d = parsed.d
    names = list(parsed.sessions)
    for block, h in zip(parsed.spool.chunks(), parsed.hashes.chunks()):
        h = h[:, 0]
        if plan is None:
            yield block, block[:, 3:3 + d], h
            continue
        labels = [names[c] for c in block[:, 2].astype(np.int64).tolist()]
        moved, keep = plan.apply(block[:, 3:3 + d], labels)
        yield block[keep], moved[keep], h[keep]


def _repeated_hashes(parsed: _Parsed) -> NDArray[np.int64]:
    """The text hashes occurring more than once, sorted (buckets of about
    :data:`HASH_BUCKET_ROWS` by the hash modulo their number)."""
    buckets = max(1, -(-parsed.hashes.rows // HASH_BUCKET_ROWS))
    found = []
    for b in range(buckets):
        parts = [h[:, 0] if buckets == 1 else h[h[:, 0] % buckets == b, 0]
                 for h in parsed.hashes.chunks(1 << 18)]
        if parts:
            values, counts = np.unique(np.concatenate(parts), return_counts=True)
            found.append(values[counts > 1])
    return np.sort(np.concatenate(found)) if found else np.empty(0, dtype=np.int64)


class CopyFinder:
    """:func:`~.csv_io._copied_runs`' rule over the kept rows (text hash, id), fed in order;
    only rows whose hash is in ``repeated`` are looked at one by one (a row whose text occurs
    once is in no copied run). The run length needed and whether the file has one id are
    known at the end (:meth:`copies`)."""

    def __init__(self, repeated: NDArray[np.int64]) -> None:
        self.repeated = repeated
        self.seen: dict[int, list[int]] = {}
        self.run: dict[int, int] = {}
        self.events: list[tuple[int, int, int, bool]] = []  # (row, run, row copied, ids > 1)
        self.last = -2          # the last row looked at
        self.start = 0          # rows so far
        self.streak = 0         # first row of the current run of one id
        self.prev_id = -1

    def feed(self, hashes: NDArray[np.int64], ids: NDArray[np.int64]) -> None:
        """The next rows, in order."""
        n = len(hashes)
        if not n:
            return
        base = self.start
        change = np.ones(n, dtype=bool)             # the first row of each run of one id
        change[1:] = ids[1:] != ids[:-1]
        change[0] = int(ids[0]) != self.prev_id
        starts = np.where(change, np.arange(n) + base, -1)
        if not change[0]:
            starts[0] = self.streak
        streaks = np.maximum.accumulate(starts)
        self.streak, self.prev_id = int(streaks[-1]), int(ids[-1])
        self.start += n
        if not len(self.repeated):
            return
        for k in np.flatnonzero(np.isin(hashes, self.repeated)).tolist():
            i = base + k
            text = int(hashes[k])
            if i != self.last + 1:
                self.run = {}
            now = {q: self.run.get(q - 1, 0) + 1 for q in self.seen.get(text, ())}
            self.run = now
            m, q = max(((m, q) for q, m in now.items() if q < i - m + 1), default=(0, -1))
            if m >= 2:
                self.events.append((i, m, q, int(streaks[k]) > i - m + 1))
            earlier = self.seen.setdefault(text, [])
            earlier.append(i)
            if len(earlier) > 2 * COPY_MATCHES:     # linear time for many equal rows
                del earlier[:COPY_MATCHES]
            self.last = i

    def copies(self, n_ids: int) -> dict[int, int]:
        """Row -> the row it copies, for every row of a copied run, with ``n_ids`` ids."""
        need = max(min(COPY_RUN, n_ids), 2)
        out: dict[int, int] = {}
        for i, m, q, several in reversed(self.events):
            if m >= need and (n_ids == 1 or several):
                for k in range(m):
                    out.setdefault(i - k, q - k)
        return out


def read_fiducial_sums(path: PathLike, dim: Optional[int] = None,
                       outlier_distance: Optional[float] = None,
                       reference_sessions: Optional[Sequence[str]] = None,
                       progress: bool = False) -> FiducialSums:
    """Read FIDUCIALS.csv as :func:`~.csv_io.read_fiducials` does (its parameters, rules,
    notes and errors), in memory flat in the rows (module docstring).

    :param progress: show the reading's progress on a terminal (:class:`~.progress.Progress`).

    :raises CsvError: as :func:`~.csv_io.read_fiducials`.
    """
    parsed = _parse(path, dim, progress)
    try:
        return _summarise(path, parsed, outlier_distance, reference_sessions)
    finally:
        _close(parsed.spool, parsed.hashes)


def _summarise(path: PathLike, parsed: _Parsed, outlier_distance: Optional[float],
               reference_sessions: Optional[Sequence[str]]) -> FiducialSums:
    d, header = parsed.d, parsed.header
    plan = _plan(path, parsed, reference_sessions) if "session" in header else None
    id_names = list(parsed.ids)
    # pass 2: copied runs, each id's first kept row, rows per id
    finder = CopyFinder(_repeated_hashes(parsed))
    first: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    counts = np.zeros(len(id_names), dtype=np.int64)
    kept = 0
    for block, moved, h in _kept_chunks(parsed, plan):
        codes = block[:, 1].astype(np.int64)
        finder.feed(h, codes)
        _, at = np.unique(codes, return_index=True)
        for k in np.sort(at).tolist():
            first.setdefault(int(codes[k]), (block[k].copy(), moved[k].copy()))
        counts += np.bincount(codes, minlength=len(id_names))
        kept += len(block)
    order = list(first)                       # ids in order of their first kept row
    copies = finder.copies(len(order))
    copied = np.array(sorted(copies), dtype=np.int64)
    heads = [first[c][0] for c in order]
    limits = _repeat_limits([[first[c][1].tolist() for c in order],
                             [r[3 + d:3 + 2 * d].tolist() for r in heads]], outlier_distance)
    notes: list[str] = []
    if plan is not None and plan.warning():
        notes.append(f"{path}: {plan.warning()}")
    shown = sorted(copies.items())[:3]
    lines = _lines_of(parsed, plan, {k for pair in shown for k in pair}) if shown else {}
    if copies:
        text = ", ".join(f"row {lines[i]} = row {lines[q]}" for i, q in shown)
        more = f", and {len(copies) - 3} more" if len(copies) > 3 else ""
        notes.append(f"{path}: {len(copies)} row(s) repeat a run of earlier rows, field by "
                     f"field and in the same order ({text}{more}): dropped as copies, not "
                     "counted as repeated measurements (a file pasted twice, two exports "
                     "joined? copies would make sigma too small)")
    # pass 3: the repeat rule, a batch of ids at a time
    work = np.zeros((len(order), d))
    dest = np.zeros((len(order), d))
    n = np.zeros(len(order), dtype=np.int64)
    variances = np.full(len(order), np.nan)
    ignored: list[str] = []
    position = {c: k for k, c in enumerate(order)}
    for batch in _batches(order, counts):
        rows = _gather(parsed, plan, batch, copied)
        for code in batch:
            j = position[code]
            lines_j, w, t = rows[code]
            keep = _checked_repeats(path, id_names[code], lines_j, w, t, limits, ignored)
            wk, tk = w[keep], t[keep]
            work[j], dest[j], n[j] = wk.mean(axis=0), tk.mean(axis=0), len(wk)
            if len(wk) >= 2:
                variances[j] = float(np.sum(np.var(wk - wk[0], axis=0, ddof=1)))
    notes += _ignored_rows_notes(path, ignored, kept - len(copies), limits[0])
    if parsed.z_extra:
        from ..core.rigid.scale import dropped_z_warning

        tilted = dropped_z_warning([[float(r[3]), float(r[4]), float(r[7])] for r in heads],
                                   [[float(r[5]), float(r[6]), float(r[8])] for r in heads], "")
        if tilted:
            notes.append(f"{path}: {tilted}")
    ids = tuple(id_names[c] for c in order)
    groups = tuple(parsed.labels.get(f, "") for f in ids) if "group" in header else None
    return FiducialSums(ids, work, dest, RepeatStats(n, variances), d, tuple(notes), groups,
                        plan)


def _batches(order: list[int], counts: NDArray[np.int64]) -> Iterator[list[int]]:
    """The ids in order, in runs of at most :data:`BATCH_ROWS` rows (one id at least)."""
    batch: list[int] = []
    rows = 0
    for code in order:
        if batch and rows + int(counts[code]) > BATCH_ROWS:
            yield batch
            batch, rows = [], 0
        batch.append(code)
        rows += int(counts[code])
    if batch:
        yield batch


def _gather(parsed: _Parsed, plan: Optional[SessionPlan], batch: list[int],
            copied: NDArray[np.int64]
            ) -> dict[int, tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]]:
    """Per id of ``batch``: the lines, working and destination points of its kept rows that are
    no copies, in file order."""
    d = parsed.d
    wanted = np.zeros(len(parsed.ids), dtype=bool)
    wanted[batch] = True
    parts: dict[int, list[NDArray[np.float64]]] = {c: [] for c in batch}
    base = 0
    for block, moved, _ in _kept_chunks(parsed, plan):
        codes = block[:, 1].astype(np.int64)
        mask = wanted[codes]
        if len(copied):
            mask &= ~np.isin(np.arange(base, base + len(block)), copied)
        base += len(block)
        if not mask.any():
            continue
        sel = np.hstack([block[mask][:, :3], moved[mask], block[mask][:, 3 + d:3 + 2 * d]])
        sel_codes = codes[mask]
        by = np.argsort(sel_codes, kind="stable")
        sel, sel_codes = sel[by], sel_codes[by]
        cut = np.flatnonzero(np.diff(sel_codes)) + 1
        for part in np.split(sel, cut):
            parts[int(part[0, 1])].append(part)
    out = {}
    for code, chunks in parts.items():
        rows = np.concatenate(chunks)
        out[code] = (rows[:, 0].astype(np.int64), np.ascontiguousarray(rows[:, 3:3 + d]),
                     np.ascontiguousarray(rows[:, 3 + d:3 + 2 * d]))
    return out


def _lines_of(parsed: _Parsed, plan: Optional[SessionPlan], rows: set[int]) -> dict[int, int]:
    """The file lines of some kept rows (by their index among the kept rows)."""
    out: dict[int, int] = {}
    base = 0
    wanted = np.array(sorted(rows), dtype=np.int64)
    for block, _, _ in _kept_chunks(parsed, plan):
        index = np.arange(base, base + len(block))
        for k in np.flatnonzero(np.isin(index, wanted)).tolist():
            out[base + k] = int(block[k, 0])
        base += len(block)
        if len(out) == len(wanted):
            break
    return out


def _checked_repeats(path: PathLike, fid: str, lines: NDArray[np.int64],
                     w: NDArray[np.float64], t: NDArray[np.float64],
                     limits: tuple[tuple[float, str], ...], notes: list[str]
                     ) -> NDArray[np.int64]:
    """:func:`~.csv_io._checked_repeats` on one id's rows (arrays in file order): the indices
    of the rows kept, sorted; raises on a destination conflict. Blocks of rows are checked
    against the running means at once; a row near or past a limit is checked as the in-memory
    reader checks it (``math.dist`` against the mean of the rows accepted before it)."""
    (w_limit, w_name), (d_limit, d_name) = limits
    m = len(lines)
    order = _central_first(w, t)
    if m < 2 or (w_limit <= 0 and d_limit <= 0):
        return np.arange(m)
    wo, to = w[order], t[order]
    w_sum, d_sum = wo[0].copy(), to[0].copy()      # 0.0 + the first row: the same floats
    count = 1
    kept = [np.array([order[0]])]
    pos = 1
    slack = 1.0 - 1e-9
    while pos < m:
        end = min(m, pos + RULE_BLOCK)
        wb, tb = wo[pos:end], to[pos:end]
        # the sums of the accepted rows before each row, were every row of the block accepted
        ws = np.cumsum(np.vstack([w_sum, wb]), axis=0)[:-1]
        ds = np.cumsum(np.vstack([d_sum, tb]), axis=0)[:-1]
        nb = (count + np.arange(len(wb)))[:, None].astype(np.float64)
        near = np.zeros(len(wb), dtype=bool)
        if d_limit > 0:
            near |= np.linalg.norm(tb - ds / nb, axis=1) > d_limit * slack
        if w_limit > 0:
            near |= np.linalg.norm(wb - ws / nb, axis=1) > w_limit * slack
        flagged = np.flatnonzero(near)
        stop = int(flagged[0]) if len(flagged) else len(wb)
        if stop:
            kept.append(order[pos:pos + stop])
            w_sum, d_sum = ws[stop - 1] + wb[stop - 1], ds[stop - 1] + tb[stop - 1]
            count += stop
        if stop == len(wb):
            pos = end
            continue
        k = pos + stop
        line, wk, tk = int(lines[order[k]]), wo[k].tolist(), to[k].tolist()
        far = repeat_outlier(fid, "destination", tk, (d_sum / count).tolist(), count, d_limit,
                             d_name, others="accepted")
        if far:
            raise CsvError(f"{path}: id {fid!r} (first at row {int(lines[0])}) has conflicting "
                           f"destination points: row {line}: {far}")
        far = repeat_outlier(fid, "working", wk, (w_sum / count).tolist(), count, w_limit,
                             w_name, others="accepted")
        if far:
            notes.append(f"{path}: row {line}: {far}: row ignored (as the node rejects an "
                         "outlier)")
        else:
            kept.append(order[k:k + 1])
            w_sum, d_sum = w_sum + wo[k], d_sum + to[k]
            count += 1
        pos = k + 1
    return np.sort(np.concatenate(kept))


def _central_first(w: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.int64]:
    """:func:`~.csv_io._central_first` of one id's rows."""
    order = np.arange(len(w))
    if len(w) < 3:
        return order
    points = np.hstack([w, t])
    dist = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    central = int(np.argmin(dist))
    return np.concatenate([[central], order[order != central]])
