"""CSV files of fiducials and targets.

FIDUCIALS.csv: header ``id,wx,wy,wz,dx,dy,dz`` (w*: working frame, d*: destination frame; 2D files
may omit ``wz,dz``). Rows sharing an id are repeated measurements of one fiducial: their mean is its
location, their scatter gives sigma. TARGETS.csv: ``id,wx,wy,wz`` and optionally ``dx,dy,dz``
(truth). Any consistent length unit. Extra columns are ignored; column order is free.

Optional columns of FIDUCIALS.csv: ``group`` (fiducials that share an error, e.g. the reflectors
of one robot pose: held out together, :mod:`~rbc_registration.core.decision.groups`; empty: its own
group) and ``session`` (the measuring session; an empty cell continues the row before's session,
the first rows' is ``1``). With more than one session, every session's working points are mapped
into the reference session's frame when it moved, or left out when it cannot be compared
(:mod:`~rbc_registration.core.measurements.sessions`) before any other rule. TARGETS.csv may carry
``session`` too (empty or absent: the reference session).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.errors import InputError
from ..core.constants import DIMENSIONS
from ..core.repeats import repeat_outlier, typical_spacing
from ..core.measurements.sessions import SessionPlan, estimate_sessions, session_cells
from ..core.validation import MAX_ABS_COORDINATE
from ..pipeline.files import NotARegularFile, check_input_file
from ..pipeline.targets import first_conflict, mean_by_id, rows_by_id

PathLike = Union[str, Path]
#: Largest CSV file read (1 GiB: some 10 million rows).
MAX_CSV_BYTES = 1 << 30
#: Most rows of a candidates file ``plan`` reads: a longer file is refused at the row past it,
#: the rest not read.
MAX_CANDIDATE_ROWS = 1_000_000
#: A repeat of one id farther than this fraction of the typical fiducial spacing from the mean of
#: the id's earlier rows: a conflict in the destination frame (two different points, one id), an
#: outlier in the working frame (the node's ``outlier_distance`` rule, relative to the spacing).
CONFLICT_FRACTION = 0.25


class CsvError(InputError):
    """A CSV file that cannot be used; the message names the file, row and column."""


@dataclass(frozen=True)
class FiducialTable:
    """Fiducials read from CSV, in order of first appearance.

    :ivar working_repeats / destination_repeats: per fiducial, (n_j, d) measurements.
    """

    ids: tuple[str, ...]
    working_repeats: tuple[NDArray[np.float64], ...]
    destination_repeats: tuple[NDArray[np.float64], ...]
    dimension: int
    #: One line per row that was ignored (a working-frame repeat far from its siblings), and one
    #: for the rows dropped as a copied run of earlier rows (:func:`_copied_runs`).
    notes: tuple[str, ...] = ()
    #: The ``group`` of each fiducial ('' its own), or ``None`` without the column.
    groups: Optional[tuple[str, ...]] = None
    #: The sessions and their motions (``None`` without a ``session`` column); the repeats are
    #: already in the reference session's frame.
    sessions: Optional[SessionPlan] = None

    @property
    def working(self) -> NDArray[np.float64]:
        """Mean working-frame location of each fiducial (J, d)."""
        return np.array([r.mean(axis=0) for r in self.working_repeats])

    @property
    def destination(self) -> NDArray[np.float64]:
        """Mean destination-frame location of each fiducial (J, d)."""
        return np.array([r.mean(axis=0) for r in self.destination_repeats])


@dataclass(frozen=True)
class TargetTable:
    """Targets read from CSV (repeats of an id are averaged; ``counts``: the rows of each id)."""

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: Optional[NDArray[np.float64]]
    counts: tuple[int, ...] = ()
    #: The sessions the rows were measured in (those of a ``session`` column), in file order.
    sessions: tuple[str, ...] = ()
    #: The ``group`` of each id ('' its own; e.g. the robot pose measuring it with others), or
    #: ``None`` without the column.
    groups: Optional[tuple[str, ...]] = None


def header_problem(p: Path, header: list[str], required: Sequence[str]) -> Optional[CsvError]:
    """The error of a CSV header that is empty, not a header of points (another separator or
    decimal comma: :func:`_header_hint`) or names a column twice; None when it is sound."""
    if not header:
        return CsvError(f"{p}: empty file (expected a header {','.join(required)})")
    hint = _header_hint(header)
    if hint:
        return CsvError(f"{p}: the header {','.join(header)!r} {hint}; expected comma-separated "
                        f"columns {','.join(required)} (decimal point '.') in its first line")
    twice = sorted({h for h in header if h and header.count(h) > 1})
    if twice:
        return CsvError(f"{p}: column(s) {', '.join(twice)} appear more than once in the header "
                        f"{','.join(header)}")
    return None


def _read_rows(path: PathLike, required: list[str], max_rows: Optional[int] = None,
               kind: str = "data"
               ) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """The header and the data rows, each with its line in the file (the header is line 1;
    blank lines, which ``csv.DictReader`` skips, still count), for the messages' ``row N``.
    Rows whose every field is empty or blank (``,,,,``, as spreadsheets export trailing rows)
    are skipped like blank lines. More than ``max_rows`` rows are refused at the row past the
    limit, reading no further."""
    p = Path(path)
    try:
        check_input_file(str(p), MAX_CSV_BYTES)
        with p.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            rows = []
            for row in reader:
                if max_rows is not None and len(rows) >= max_rows:
                    raise CsvError(f"{p}: more than {max_rows:,} {kind} rows (row "
                                   f"{reader.line_num}): refused, the rest not read; split "
                                   "the file or thin it out")
                rows.append((reader.line_num, {(k or "").strip(): (v or "").strip()
                                               if isinstance(v, str) else v
                                               for k, v in row.items()}))
        rows = [(line, row) for line, row in rows if any(
            v for v in row.values() if isinstance(v, str)) or any(
            x.strip() for v in row.values() if isinstance(v, list) for x in v)]
    except FileNotFoundError:
        raise CsvError(f"{p}: no such file") from None
    except NotARegularFile as exc:
        raise CsvError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise CsvError(f"{p}: not a readable CSV file ({exc}){_likely_format(p)}") from None
    except csv.Error as exc:
        why = (": an opening quote (\") without its closing one, or not a CSV file of points"
               if "field limit" in str(exc) else "")
        raise CsvError(f"{p}: not a readable CSV file ({exc}){why}") from None
    problem = header_problem(p, header, required)
    if problem is not None:
        raise problem
    _refuse_swallowed_rows(p, header, rows)
    for line, row in rows:
        rest = row.get("")                 # csv.DictReader's list of fields beyond the header
        extra = [v for v in rest if v and v.strip()] if isinstance(rest, list) else []
        if extra:
            raise CsvError(f"{p}: row {line}: {len(header) + len(rest)} fields, the header "
                           f"has {len(header)} (extra: {','.join(extra)})")
    missing = [c for c in required if c not in header]
    if missing:
        raise CsvError(f"{p}: missing column(s) {', '.join(missing)}; header is "
                       f"{','.join(header)}")
    if not rows:
        raise CsvError(f"{p}: no data rows")
    return header, rows


def _refuse_swallowed_rows(p: Path, header: list[str],
                           rows: list[tuple[int, dict[str, object]]]) -> None:
    """Refuse a quoted field that holds lines which look like rows of the file (at least as many
    commas as the header has): an opening quote without its closing one (``"5 inch hole`` in a
    remark) makes the CSV reader take every following line, up to the next quote or the end of
    the file, as that one field, and the rows in it would be lost without a word. A remark of a
    few lines (a spreadsheet cell with line breaks) is kept."""
    commas = len(header) - 1
    for line, row in rows:
        for column, value in row.items():
            if not isinstance(value, str) or ("\n" not in value and "\r" not in value):
                continue
            inner = value.splitlines()
            looks = sum(1 for text in inner[1:] if text.count(",") >= commas)
            if looks:
                start = line - len(inner) + 1
                raise CsvError(
                    f"{p}: row {start}: the quoted field of column {column or '(extra)'} runs to "
                    f"row {line} and holds {looks} line(s) that look like rows: an opening quote "
                    f"(\") without its closing one? Close or remove it")


def _likely_format(p: Path) -> str:
    """What a file that does not decode as UTF-8 probably is (spreadsheets' other exports)."""
    try:
        with p.open("rb") as fh:
            start = fh.read(2)
    except OSError:
        return ""
    if start in (b"\xff\xfe", b"\xfe\xff"):
        return ": it is UTF-16 text (Excel's 'Unicode text'): save it as 'CSV UTF-8'"
    return ": not UTF-8 (e.g. Windows-1252 text): save it as 'CSV UTF-8'"


def _header_hint(header: list[str]) -> str:
    """Why a header line is likely no header: a spreadsheet's ``sep=`` line, a comment line,
    or another separator (semicolons, tabs), or "" when it looks like one."""
    first = header[0] if header else ""
    if first.lower().startswith("sep="):
        return "is a spreadsheet's 'sep=' line: remove it"
    if first.startswith("#"):
        return "is a comment line: remove the lines before the header"
    if len(header) == 1 and (";" in first or "\t" in first):
        which = "semicolons" if ";" in first else "tabs"
        return f"is one column holding {which}: a file separated by {which}"
    return ""


def _number(p: PathLike, line: int, column: str, text: Optional[str]) -> float:
    if text is None or text == "":
        raise CsvError(f"{p}: row {line}: column {column} is empty")
    try:
        if "_" in text:   # Python's float() reads 1_000 as 1000; no spreadsheet writes it
            raise ValueError(text)
        value = float(text)
    except ValueError:
        raise CsvError(f"{p}: row {line}: column {column} is not a number: {text!r}") from None
    if not math.isfinite(value):
        raise CsvError(f"{p}: row {line}: column {column} is not finite: {text!r}")
    if abs(value) > MAX_ABS_COORDINATE:
        raise CsvError(f"{p}: row {line}: column {column} is out of range: {text!r}")
    return value


def _dimension(p: PathLike, header: list[str], prefixes: list[str], dim: Optional[int]) -> int:
    has_z = [f"{pre}z" in header for pre in prefixes]
    if dim is None:
        if any(has_z) and not all(has_z):
            cols = ", ".join(f"{pre}z" for pre, h in zip(prefixes, has_z) if not h)
            raise CsvError(f"{p}: mixed 2D/3D columns: missing {cols}")
        return 3 if all(has_z) else 2
    if dim not in DIMENSIONS:
        raise CsvError(f"dimension must be 2 or 3, got {dim}")
    if dim == 3 and not all(has_z):
        raise CsvError(f"{p}: --dim 3 needs columns " + ", ".join(f"{pre}z" for pre in prefixes))
    return dim


def read_fiducials(path: PathLike, dim: Optional[int] = None,
                   outlier_distance: Optional[float] = None,
                   reference_sessions: Optional[Sequence[str]] = None) -> FiducialTable:
    """Read FIDUCIALS.csv (module docstring).

    Repeats of an id are checked in file order with the node's rule
    (:func:`~rbc_registration.core.repeats.repeat_outlier`): a row whose destination point is
    farther than the limit from the mean of the id's earlier rows is a conflict (two points, one
    id: the file is refused); a row whose working point is that far is ignored, with a note (the
    node rejects such a measurement and keeps the others). With a ``session`` column the rows are
    re-stationed into the reference session first (:func:`_restation`).

    :param path: the file.
    :param dim: 2 or 3; ``None``: 3 when ``wz`` and ``dz`` exist, else 2. With 2, z is ignored.
    :param outlier_distance: the limit in the file's unit; 0 switches the checks off; ``None``:
        ``CONFLICT_FRACTION`` x the typical fiducial spacing of each frame
        (:func:`~rbc_registration.core.repeats.typical_spacing` of the ids' first rows, so the
        ids under test and coinciding ids do not set it).
    :param reference_sessions: the sessions the targets were measured in: the reference is the
        latest of them (:func:`target_sessions`); ``None``: the latest session.
    :raises CsvError: naming the file, row and column of the first problem, including ids whose
        repeated destination points conflict, and one id in two groups.
    """
    header, rows = _read_rows(path, ["id", "wx", "wy", "dx", "dy"])
    d = _dimension(path, header, ["w", "d"], dim)
    axes = "xyz"[:d]
    parsed = []
    labels: dict[str, str] = {}
    sessions: dict[int, str] = {}
    session = "1"
    for line, row in rows:
        fid = row.get("id") or ""
        if not fid:
            raise CsvError(f"{path}: row {line}: column id is empty")
        w = [_number(path, line, f"w{a}", row.get(f"w{a}")) for a in axes]
        t = [_number(path, line, f"d{a}", row.get(f"d{a}")) for a in axes]
        group = row.get("group") or ""
        if group:
            if labels.setdefault(fid, group) != group:
                raise CsvError(f"{path}: row {line}: id {fid!r} is in group {group!r} here and "
                               f"in group {labels[fid]!r} in an earlier row: one fiducial, one "
                               "group")
        session = row.get("session") or session
        sessions[line] = session
        parsed.append((line, fid, tuple(row.get(h) for h in header), w, t))
    plan = None
    if "session" in header:
        plan, parsed = _restation(path, parsed, sessions, reference_sessions)
    copies = _copied_runs([(p[0], (p[1],) + p[2]) for p in parsed])
    copied = {line for line, _ in copies}
    groups: dict[str, list[tuple[int, list[float], list[float]]]] = {}
    for line, fid, _, w, t in parsed:
        if line not in copied:
            groups.setdefault(fid, []).append((line, w, t))
    limits = _repeat_limits([[g[0][1] for g in groups.values()],
                             [g[0][2] for g in groups.values()]], outlier_distance)
    notes: list[str] = []
    if plan is not None and plan.warning():
        notes.append(f"{path}: {plan.warning()}")
    if copies:
        shown = ", ".join(f"row {line} = row {first}" for line, first in copies[:3])
        more = f", and {len(copies) - 3} more" if len(copies) > 3 else ""
        notes.append(f"{path}: {len(copies)} row(s) repeat a run of earlier rows, field by "
                     f"field and in the same order ({shown}{more}): dropped as copies, not "
                     "counted as repeated measurements (a file pasted twice, two exports "
                     "joined? copies would make sigma too small)")
    work, dest, ignored = [], [], []
    for fid, group in groups.items():
        w, t = _checked_repeats(path, fid, group, limits, ignored)
        work.append(np.array(w))
        dest.append(np.array(t))
    notes += _ignored_rows_notes(path, ignored, len(parsed) - len(copied), limits[0])
    if d == 2 and ("wz" in header or "dz" in header):
        tilted = _dropped_z_note(rows, groups)
        if tilted:
            notes.append(f"{path}: {tilted}")
    group_column = tuple(labels.get(fid, "") for fid in groups) if "group" in header else None
    return FiducialTable(tuple(groups), tuple(work), tuple(dest), d, tuple(notes),
                         group_column, plan)


def reference_session(path: PathLike, order: Sequence[str],
                      reference_sessions: Optional[Sequence[str]]) -> Optional[str]:
    """The session the fiducials are re-stationed into: the latest (in ``order``, the
    fiducials' sessions) of the targets' ``reference_sessions``; None without targets' sessions
    (then the latest session). A target session no fiducial was measured in is refused."""
    if not reference_sessions:
        return None
    unknown = [s for s in dict.fromkeys(reference_sessions) if s not in order]
    if unknown:
        raise CsvError(f"{path}: the targets' session(s) {', '.join(map(repr, unknown))} "
                       f"are not among the fiducials' sessions {', '.join(order)}: targets "
                       "can only be placed in a session the fiducials were measured in")
    return [s for s in order if s in set(reference_sessions)][-1]


def _restation(path: PathLike, parsed: list, sessions: dict[int, str],
               reference_sessions: Optional[Sequence[str]]) -> tuple[SessionPlan, list]:
    """The session plan of the rows and the rows with their working points in the reference
    session's frame; rows of a session kept apart are left out."""
    labels = [sessions[p[0]] for p in parsed]
    order = list(dict.fromkeys(labels))
    reference = reference_session(path, order, reference_sessions)
    points = np.array([p[3] for p in parsed], dtype=np.float64)
    plan = estimate_sessions(session_cells([p[1] for p in parsed], labels, points), reference)
    moved, keep = plan.apply(points, labels)
    rows = [(line, fid, raw, [float(v) for v in moved[k]], t)
            for k, (line, fid, raw, _, t) in enumerate(parsed) if keep[k]]
    return plan, rows


def target_sessions(path: Optional[PathLike]) -> Optional[tuple[str, ...]]:
    """The sessions of TARGETS.csv's ``session`` column (empty cells continue the row
    before's), or ``None`` without a file or without the column."""
    if path is None:
        return None
    header, rows = _read_rows(path, ["id"])
    if "session" not in header:
        return None
    out, session = [], ""
    for _, row in rows:
        session = row.get("session") or session
        if session:
            out.append(session)
    return tuple(out) or None


def _dropped_z_note(rows: list, groups: dict) -> Optional[str]:
    """:func:`~rbc_registration.core.rigid.scale.dropped_z_warning` of a file read in 2D that has z
    columns, on each id's first row (z 0 where a frame has no z column, NaN where not a
    number: that row is not looked at)."""
    from ..core.rigid.scale import dropped_z_warning

    def value(row: dict, column: str) -> float:
        text = (row.get(column) or "").strip() if column in row else "0"
        try:
            return float(text)
        except ValueError:
            return math.nan

    first = {line: row for line, row in rows}
    heads = [first[group[0][0]] for group in groups.values()]
    return dropped_z_warning([[value(r, "w" + a) for a in "xyz"] for r in heads],
                             [[value(r, "d" + a) for a in "xyz"] for r in heads], "")


#: Ignored working-frame repeats named one line each; beyond that, one summary line.
IGNORED_ROWS_SHOWN = 3


def _ignored_rows_notes(path: PathLike, ignored: list[str], rows: int,
                        limit: tuple[float, str]) -> list[str]:
    """The lines for the ignored working-frame repeats: each one's own line, but past
    :data:`IGNORED_ROWS_SHOWN` one line for the rest, naming the limit (many ignored rows mean
    a limit below the measurements' scatter, not many outliers)."""
    if len(ignored) <= IGNORED_ROWS_SHOWN:
        return ignored
    value, name = limit
    return ignored[:IGNORED_ROWS_SHOWN] + [
        f"{path}: {len(ignored)} of {rows} rows ignored in all as working-frame outliers "
        f"({len(ignored) - IGNORED_ROWS_SHOWN} more not named here), each farther than "
        f"{name} {value:g} from its id's accepted repeats: if that is below the scatter of "
        "the repeats, raise --outlier-distance (0 = off)"]


#: Rows copied as a run at least this long (or as long as the file has ids, when fewer) are a
#: copy of part of the file (a file pasted twice, two exports joined), not repeats: a real repeat
#: of a rounded export equals an earlier row often (a third of the rows at 0.01 mm with a
#: 0.004 mm noise), a run of 8 in the same order about once in 6,500.
COPY_RUN = 8


#: The most recent earlier rows of equal text a row is compared with (a copy's original is one
#: of them unless the file holds that text over 64 times).
COPY_MATCHES = 64


def _copied_runs(rows: list[tuple[int, tuple[Optional[str], ...]]]) -> list[tuple[int, int]]:
    """The rows (line, its text) that belong to a run of at least :data:`COPY_RUN` consecutive
    rows (fewer when the file has fewer ids) of more than one id whose text, field by field,
    repeats an earlier run in the same order (ending before it starts); returned as (row, the
    row it copies), in row order. ``text`` starts with the id."""
    if not rows:
        return []
    n_ids = len({text[0] for _, text in rows})
    need = max(min(COPY_RUN, n_ids), 2)
    seen: dict[tuple[Optional[str], ...], list[int]] = {}
    run: dict[int, int] = {}         # earlier index q -> length of the run ending at (i, q)
    best: list[tuple[int, int]] = []  # per row: (run length, the q of it)
    for i, (_, text) in enumerate(rows):
        now = {q: run.get(q - 1, 0) + 1 for q in seen.get(text, ())}
        run = now
        # the earlier run must end before this one starts (rows A A A A of one id do not copy
        # themselves)
        best.append(max(((n, q) for q, n in now.items() if q < i - n + 1), default=(0, -1)))
        earlier = seen.setdefault(text, [])
        earlier.append(i)
        if len(earlier) > 2 * COPY_MATCHES:     # linear time for many equal rows
            del earlier[:COPY_MATCHES]
    copies: dict[int, int] = {}
    for i in range(len(rows) - 1, -1, -1):
        n, q = best[i]
        # a run of one id's rows is its repeats at a coarse rounding, not a copied block
        if n >= need and (n_ids == 1 or len({rows[i - k][1][0] for k in range(n)}) > 1):
            for k in range(n):
                copies.setdefault(i - k, q - k)
    return [(rows[i][0], rows[q][0]) for i, q in sorted(copies.items())]


def _repeat_limits(first_rows: list[list[list[float]]], outlier_distance: Optional[float],
                   kind: str = "fiducial", fallback_spacing: float = 0.0
                   ) -> tuple[tuple[float, str], ...]:
    """(limit, how it is named) for each frame of ``first_rows`` (the ids' first rows in it,
    e.g. working and destination): ``outlier_distance``, else :data:`CONFLICT_FRACTION` x the
    typical spacing of those rows (``kind``: what the ids are, for the name), or of the
    fiducials (``fallback_spacing``) when the rows are fewer than two distinct points."""
    if outlier_distance is not None:
        return ((float(outlier_distance), "outlier_distance"),) * len(first_rows)
    out = []
    for points in first_rows:
        spacing, whose = typical_spacing(points), kind
        if spacing <= 0 and fallback_spacing > 0:
            spacing, whose = fallback_spacing, "fiducial"
        out.append((CONFLICT_FRACTION * spacing,
                    f"{CONFLICT_FRACTION:g} x the {whose} spacing {spacing:.6g} ="))
    return tuple(out)


def _checked_repeats(path: PathLike, fid: str, group: list[tuple[int, list[float], list[float]]],
                     limits: tuple[tuple[float, str], ...], notes: list[str]
                     ) -> tuple[list[list[float]], list[list[float]]]:
    """The rows of one id that pass the repeat rule, in file order; raises on a destination
    conflict. The node's rule (each repeat against the mean of those accepted before it), with
    the id's most central row (:func:`_central_first`) taken first: a file holds every repeat,
    so a wrong first row is the one ignored, not the rows that agree with each other."""
    (w_limit, w_name), (d_limit, d_name) = limits
    kept: list[int] = []
    w_sum = [0.0] * len(group[0][1]) if group else []   # running sums: linear in the repeats
    d_sum = [0.0] * len(group[0][2]) if group else []
    for k in _central_first(group):
        line, w, t = group[k]
        n = len(kept)
        if n:
            far = repeat_outlier(fid, "destination", t, [v / n for v in d_sum], n, d_limit,
                                 d_name, others="accepted")
            if far:
                raise CsvError(f"{path}: id {fid!r} (first at row {group[0][0]}) has conflicting "
                               f"destination points: row {line}: {far}")
            far = repeat_outlier(fid, "working", w, [v / n for v in w_sum], n, w_limit, w_name,
                                 others="accepted")
            if far:
                notes.append(f"{path}: row {line}: {far}: row ignored (as the node rejects an "
                             "outlier)")
                continue
        kept.append(k)
        w_sum = [a + b for a, b in zip(w_sum, w)]
        d_sum = [a + b for a, b in zip(d_sum, t)]
    kept.sort()
    return [group[k][1] for k in kept], [group[k][2] for k in kept]


def _central_first(group: list[tuple[int, list[float], list[float]]]) -> list[int]:
    """The order the repeat rule takes an id's rows in: the row nearest the rows' median (per
    coordinate, both frames together) first, then the others in file order. With one or two
    rows, or a tie, the file's order (no majority to go by)."""
    order = list(range(len(group)))
    if len(group) < 3:
        return order
    points = np.array([list(w) + list(t) for _, w, t in group], dtype=float)
    dist = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    central = int(np.argmin(dist))              # the first of equally central rows
    return [central] + [k for k in order if k != central]


def read_targets(path: PathLike, dim: int, outlier_distance: Optional[float] = None,
                 kind: str = "target", fiducials: Optional[ArrayLike] = None,
                 sessions: Optional[SessionPlan] = None,
                 max_rows: Optional[int] = None) -> TargetTable:
    """Read TARGETS.csv: ``id,wx,wy[,wz]`` and optionally ``dx,dy[,dz]`` (truth) and ``group``
    (CANDIDATES.csv: the candidates measured together, one robot pose; every row of an id in
    one group).

    Rows sharing an id are repeated measurements of one point and are averaged. A row farther
    than the limit from the mean of the id's earlier rows, in the working frame or in the truth,
    is a conflict (two points under one id, e.g. a pasted row not renamed): the file is refused,
    as :func:`read_fiducials` refuses conflicting destination points.

    :param outlier_distance: the limit in the file's unit; 0 switches the check off; ``None``:
        :data:`CONFLICT_FRACTION` x the typical spacing of the file's ids (their first rows) in
        each frame, or of ``fiducials`` when the file's ids are at fewer than two places (one
        target id: its repeats still must agree).
    :param kind: what the ids are, named in messages (``target``, ``candidate``).
    :param fiducials: the fiducials' working-frame points (their spacing is that fallback).
    :param sessions: the fiducials' session plan (``FiducialTable.sessions``): rows of a
        ``session`` column are mapped into its reference session's frame before they are
        checked and averaged; rows without a session are in the reference session.
    :param max_rows: the most rows read (:data:`MAX_CANDIDATE_ROWS` for candidates); more are
        refused at the row past it.
    :raises CsvError: naming the file, row and column of the first problem, a session the
        fiducials do not have or left out, and rows past ``max_rows``.
    """
    header, rows = _read_rows(path, ["id", "wx", "wy"] + (["wz"] if dim == 3 else []),
                              max_rows, kind)
    axes = "xyz"[:dim]
    has_truth = all(f"d{a}" in header for a in axes)
    partial = [f"d{a}" for a in axes if f"d{a}" in header]
    if partial and not has_truth:
        raise CsvError(f"{path}: truth columns incomplete: has {', '.join(partial)}, needs "
                       + ", ".join(f"d{a}" for a in axes))
    tids, work, truth = [], [], []
    labels: dict[str, str] = {}
    for line, row in rows:
        tid = row.get("id") or ""
        if not tid:
            raise CsvError(f"{path}: row {line}: column id is empty")
        tids.append(tid)
        group = row.get("group") or ""
        if labels.setdefault(tid, group) != group:
            raise CsvError(f"{path}: row {line}: id {tid!r} is in group {group!r} here and in "
                           f"group {labels[tid]!r} in an earlier row: one {kind}, one group")
        work.append([_number(path, line, f"w{a}", row.get(f"w{a}")) for a in axes])
        if has_truth:
            truth.append(_truth(path, line, row, axes))
    lines = [line for line, _ in rows]
    row_sessions = _target_row_sessions(path, header, rows, sessions)
    if row_sessions:
        moved, _ = sessions.apply(work, row_sessions)
        work = moved.tolist()
    known = [k for k, t in enumerate(truth) if not math.isnan(t[0])]   # rows with truth
    named = [("working", list(range(len(tids))), work)] + (
        [("truth", known, truth)] if known else [])
    fallback = typical_spacing(fiducials) if fiducials is not None else 0.0
    for frame, index, points in named:
        sub = [tids[k] for k in index]
        first = [rows_k[0] for rows_k in rows_by_id(sub).values()]
        limit = _repeat_limits([[points[index[k]] for k in first]], outlier_distance, kind,
                               fallback)[0]
        conflict = first_conflict(sub, [(frame, [points[k] for k in index], *limit)], kind)
        if conflict is not None:
            row, first_row = index[conflict.row], index[conflict.first]
            raise CsvError(f"{path}: id {tids[row]!r} (first at row {lines[first_row]}) has "
                           f"conflicting {frame} points: row {lines[row]}: {conflict.message}")
    ids, (means,) = mean_by_id(tids, work)
    counts = tuple(len(index) for index in rows_by_id(tids).values())
    seen = tuple(dict.fromkeys(row_sessions))
    group_column = tuple(labels[t] for t in ids) if "group" in header else None
    if not known:
        return TargetTable(ids, means, None, counts, seen, group_column)
    # an id's truth: the mean of its rows with truth (NaN: none has; a target without truth)
    with_ids, (truth_means,) = mean_by_id([tids[k] for k in known], [truth[k] for k in known])
    destination = np.full_like(means, np.nan)
    position = {t: k for k, t in enumerate(ids)}
    destination[[position[t] for t in with_ids]] = truth_means
    return TargetTable(ids, means, destination, counts, seen, group_column)


def _target_row_sessions(path: PathLike, header: list[str], rows: list,
                         plan: Optional[SessionPlan]) -> list[str]:
    """Each target row's session (empty cells continue the row before's; the reference session
    where none is given), [] without a ``session`` column."""
    if "session" not in header:
        return []
    if plan is None:
        raise CsvError(f"{path}: has a session column but the fiducials have none: give the "
                       "fiducials' sessions too, or drop the column")
    out, session = [], plan.reference
    for line, row in rows:
        session = row.get("session") or session
        try:
            motion = plan.motion(session)
        except KeyError:
            raise CsvError(f"{path}: row {line}: session {session!r} is not among the "
                           f"fiducials' sessions") from None
        if motion.kept_apart:
            raise CsvError(f"{path}: row {line}: session {session!r} was kept apart (too few "
                           "fiducials in common with the others): its targets cannot be placed")
        out.append(session)
    return out


def _truth(path: PathLike, line: int, row: dict[str, str], axes: str) -> list[float]:
    """A row's truth: every ``d`` column a number, or all empty (NaN: no truth for this row)."""
    empty = [f"d{a}" for a in axes if not row.get(f"d{a}")]
    if len(empty) == len(axes):
        return [math.nan] * len(axes)
    if empty:
        raise CsvError(f"{path}: row {line}: truth column(s) {', '.join(empty)} empty: give "
                       f"all of {', '.join(f'd{a}' for a in axes)} or none (no truth)")
    return [_number(path, line, f"d{a}", row.get(f"d{a}")) for a in axes]


def write_fiducials(path: PathLike, ids, working_repeats, destination_repeats) -> None:
    """Write FIDUCIALS.csv: one row per measurement (repeats share an id)."""
    d = np.asarray(working_repeats[0]).shape[1]
    axes = "xyz"[:d]
    with Path(path).open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["id"] + [f"w{a}" for a in axes] + [f"d{a}" for a in axes])
        for fid, w, t in zip(ids, working_repeats, destination_repeats):
            w, t = np.atleast_2d(w), np.atleast_2d(t)
            if len(t) == 1 and len(w) > 1:
                t = np.repeat(t, len(w), axis=0)
            for wr, tr in zip(w, t):
                out.writerow([fid] + [repr(float(v)) for v in wr] + [repr(float(v)) for v in tr])


def write_targets(path: PathLike, ids, working, destination=None) -> None:
    """Write TARGETS.csv (truth columns when ``destination`` is given)."""
    work = np.asarray(working)
    axes = "xyz"[:work.shape[1]]
    with Path(path).open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["id"] + [f"w{a}" for a in axes]
                     + ([f"d{a}" for a in axes] if destination is not None else []))
        for k, tid in enumerate(ids):
            row = [tid] + [repr(float(v)) for v in work[k]]
            if destination is not None:
                row += [repr(float(v)) for v in np.asarray(destination)[k]]
            out.writerow(row)
