"""The restart checkpoint of ``registration_node`` in ``state_dir`` (no rclpy): the running sums of
:class:`~rbc_registration.core.measurements.accumulator.FiducialAccumulator` with the journal
position they
stand for, so that a start loads them and replays only the journal's tail.

``checkpoint.json`` is written atomically (:func:`~.snapshot.write_atomic`) after each
calibration snapshot; its size grows with the fiducials and sessions, not with the measurements.
Two lines: the CRC-32 of the second, then one JSON object holding

- ``setup``: what the sums depend on besides the records (journal header: frames, dimension,
  version; the accumulator's duplicate window; the session tail and the bump detector's window
  and significance);
- ``journal``: the position, :class:`JournalPosition` (bytes, lines and records of the journal
  up to there, the CRC-32 of those bytes, and the lines skipped in them);
- ``state``: every field of the accumulator, its session sums and bump detector, floats by
  ``repr`` (the values are bit-exact after a load).

The journal stays the record. At start a checkpoint is used only when it reads whole (its CRC),
is of this format, was written for the same setup, and the journal's first ``offset`` bytes
still have its CRC (:meth:`~.journal.Journal.load_after`); otherwise a warning names why and the
journal is replayed whole. Loading the checkpoint then committing the tail gives the same
accumulator as replaying every record (``state_digest`` and ``session_digest`` equal).
"""

from __future__ import annotations

import json
import os
import zlib
from collections import deque
from typing import Any, Iterable, NamedTuple, Optional

import numpy as np

from ..core.measurements.accumulator import FiducialAccumulator, Record
from ..core.measurements.records import REJECT_REASONS, FiducialRepeats
from ..core.rigid.registration import Registration
from ..core.measurements.sessions import Bump
from .files import read_regular
from .state_dir import CHECKPOINT_NAME, StateDir  # noqa: F401  (the name, also importable here)

CHECKPOINT_FORMAT = "rbc_registration checkpoint 1"
#: A checkpoint holds O(fiducials x (sessions + duplicate window)) values.
MAX_CHECKPOINT_BYTES = 1 << 29


class JournalPosition(NamedTuple):
    """A place in the journal: ``offset`` bytes of whole lines, ``lines`` lines and ``records``
    records in them, ``crc`` the CRC-32 of those bytes, ``skipped`` the lines among them that a
    replay skips (unreadable, or failing the live checks)."""

    offset: int
    lines: int
    records: int
    crc: int
    skipped: int


class Checkpoint(NamedTuple):
    """A checkpoint read back: the journal position and the accumulator's state there."""

    position: JournalPosition
    state: dict[str, Any]


def checkpoint_path(state_dir: str) -> str:
    """Path of the checkpoint in ``state_dir``."""
    return StateDir.resolve(state_dir).checkpoint


def setup_of(acc: FiducialAccumulator, header: dict[str, Any]) -> dict[str, Any]:
    """What the sums depend on besides the records (module docstring)."""
    detector = acc.sessions._detector
    return {"journal": dict(header), "duplicate_window": acc.duplicate_window,
            "session_tail": acc.sessions.tail, "bump_window": detector.window,
            "bump_significance": detector.significance}


# -- the accumulator's state as JSON values ---------------------------------------------------
def _repeats(r: FiducialRepeats) -> list:
    return [r.n, r.enabled, r._mean_w, r._m2_w, r._mean_d, r._m2_d]


def _floats(values: Any, d: int) -> list[float]:
    out = [float(v) for v in values]
    if len(out) != d:
        raise ValueError(f"expected {d} values, got {len(out)}")
    return out


def _repeats_from(value: Any, d: int) -> FiducialRepeats:
    n, enabled, mean_w, m2_w, mean_d, m2_d = value
    if not isinstance(n, int) or n < 1 or not isinstance(enabled, bool):
        raise ValueError(f"bad repeats {value!r:.80}")
    r = FiducialRepeats(d)
    r.n, r.enabled = n, enabled
    r._mean_w, r._m2_w = _floats(mean_w, d), _floats(m2_w, d)
    r._mean_d, r._m2_d = _floats(mean_d, d), _floats(m2_d, d)
    return r


def export_state(acc: FiducialAccumulator) -> dict[str, Any]:
    """Every field of ``acc`` (and its session sums) as JSON values."""
    sums, detector = acc.sessions, acc.sessions._detector
    return {
        "fiducials": [[f, _repeats(acc._fiducials[f])] for f in acc._order],
        "next_auto": acc._next_auto,
        "recent": [[f, [[s, [list(p) for p in points]] for s, points in by_stamp.items()]]
                   for f, by_stamp in acc._recent.items()],
        "n_measurements": acc.n_measurements,
        "groups": list(acc._groups.items()),
        "first_stamps": list(acc._first_stamps.items()),
        "sessions": {
            "cells": [[s, [[f, _repeats(c)] for f, c in cells.items()]]
                      for s, cells in sums._cells.items()],
            "starts": list(sums._starts.items()),
            "current": sums.current,
            "tail": [[q, f, list(w), list(d), t, s] for q, f, w, d, t, s in sums._tail],
            "sequence": sums._sequence,
            "bumps": [[s, b.start, b.motion.rotation.tolist(), b.motion.translation.tolist(),
                       b.motion.fre_rms, b.p_value, b.n_fiducials] for s, b in sums.bumps],
            "detector": [[q, f, m.tolist(), p.tolist()] for q, f, m, p in detector._recent],
            "detector_tested": detector._tested,
        },
    }


def import_state(acc: FiducialAccumulator, state: dict[str, Any]) -> None:
    """Set ``acc`` to an :func:`export_state` result (of an accumulator of the same setup).

    :raises ValueError: when ``state`` is not such a result; ``acc`` is then cleared.
    """
    try:
        _import(acc, state)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        acc.clear()
        raise ValueError(f"not a checkpoint state ({type(exc).__name__}: {exc})") from None


def _import(acc: FiducialAccumulator, state: dict[str, Any]) -> None:
    d = acc.dimension
    acc.clear()
    for f, value in state["fiducials"]:
        if not isinstance(f, str) or f in acc._fiducials:
            raise ValueError(f"bad fiducial id {f!r:.80}")
        acc._fiducials[f] = _repeats_from(value, d)
        acc._index[f] = len(acc._order)
        acc._order.append(f)
    acc._dest_means = np.array([acc._fiducials[f].mean_d() for f in acc._order],
                               dtype=np.float64).reshape(-1, d)
    acc._next_auto = int(state["next_auto"])
    for f, by_stamp in state["recent"]:
        if f not in acc._fiducials:
            raise ValueError(f"stamps of an unknown fiducial {f!r:.80}")
        acc._recent[f] = {float(s): tuple(tuple(_floats(p, 2 * d)) for p in points)
                          for s, points in by_stamp}
    acc.n_measurements = int(state["n_measurements"])
    acc.rejected = {reason: 0 for reason in REJECT_REASONS}
    acc._groups = {str(f): str(g) for f, g in state["groups"]}
    acc._first_stamps = {str(f): float(t) for f, t in state["first_stamps"]}
    s, sums = state["sessions"], acc.sessions
    sums._cells = {str(name): {str(f): _repeats_from(c, d) for f, c in cells}
                   for name, cells in s["cells"]}
    sums._starts = {str(name): float(t) for name, t in s["starts"]}
    sums.current = str(s["current"])
    sums._tail = deque(([int(q), str(f), tuple(_floats(w, d)), tuple(_floats(x, d)), float(t),
                         str(name)] for q, f, w, x, t, name in s["tail"]), maxlen=sums.tail)
    sums._sequence = int(s["sequence"])
    sums.bumps.clear()
    for name, start, rotation, translation, fre, p_value, n_fid in s["bumps"]:
        motion = Registration(np.array(rotation, dtype=np.float64).reshape(d, d),
                              np.array(translation, dtype=np.float64).reshape(d), float(fre))
        sums.bumps.append((str(name), Bump(int(start), motion, float(p_value), int(n_fid))))
    sums._detector._recent = [(int(q), str(f), np.array(_floats(m, d)), np.array(_floats(p, d)))
                              for q, f, m, p in s["detector"]]
    sums._detector._tested = int(s["detector_tested"])
    if acc.n_measurements < sum(r.n for r in acc._fiducials.values()):
        raise ValueError("fewer measurements than the fiducials hold")


def replay(acc: FiducialAccumulator, records: Iterable[Record], first: int = 0) -> list[str]:
    """Commit ``records`` (numbered from ``first``) on top of the state of ``acc``, skipping
    what :meth:`~FiducialAccumulator.restore` skips, with its messages."""
    return acc.replay(records, first)


def resume(acc: FiducialAccumulator, journal: Any,
           log: Any) -> tuple[Optional[tuple[list[Record], list[str]]], int]:
    """Load the checkpoint of ``journal``'s ``state_dir`` into ``acc`` when it matches the
    journal (:meth:`~.journal.Journal.load_after` opens the journal after its position).

    :param journal: a :class:`~.journal.Journal`.
    :param log: an rclpy-style logger; why a checkpoint is not used is logged as a warning.
    :return: ``((the records after the position, warnings), lines the replay of the records
        before it skipped)``; ``(None, 0)`` when there is no checkpoint or it is not used:
        ``acc`` is cleared and the journal not open, to be replayed whole.
    :raises JournalMismatch: when the journal's header names another setup.
    """
    path = checkpoint_path(journal.state_dir)
    checkpoint, why = read_checkpoint(path, acc, journal.header)
    if checkpoint is None:
        if why:
            log.warning(f"{why}: not used, the journal is replayed whole")
        return None, 0
    loaded = journal.load_after(checkpoint.position)
    if loaded is None:
        log.warning(f"{path} does not match the journal ({journal.mismatch}): not used, the "
                    f"journal is replayed whole")
        return None, 0
    try:
        import_state(acc, checkpoint.state)
    except ValueError as exc:
        journal.close()
        log.warning(f"{path}: {exc}: not used, the journal is replayed whole")
        return None, 0
    return loaded, checkpoint.position.skipped


# -- the file ---------------------------------------------------------------------------------
def checkpoint_text(acc: FiducialAccumulator, header: dict[str, Any],
                    position: JournalPosition) -> str:
    """The checkpoint of ``acc`` at ``position`` of the journal with ``header``.

    :raises ValueError: when a value is not finite (nothing accepted is: never expected).
    """
    body = json.dumps({"format": CHECKPOINT_FORMAT, "setup": setup_of(acc, header),
                       "journal": position._asdict(), "state": export_state(acc)},
                      separators=(",", ":"), allow_nan=False)
    return f"{zlib.crc32(body.encode('utf-8')):08x}\n{body}\n"


def read_checkpoint(path: str, acc: FiducialAccumulator,
                    header: dict[str, Any]) -> tuple[Optional[Checkpoint], str]:
    """The checkpoint at ``path`` when it can be used for ``acc`` with the journal ``header``.

    :return: ``(checkpoint, "")``; ``(None, "")`` when there is none; ``(None, why)`` when it
        is unreadable, corrupt, of another format or another setup (one line naming what).
    """
    if not os.path.lexists(path):
        return None, ""
    try:
        raw = read_regular(path, MAX_CHECKPOINT_BYTES)
        crc, _, body = raw.partition(b"\n")
        body = body.rstrip(b"\n")
        if crc != f"{zlib.crc32(body):08x}".encode("ascii"):
            return None, f"{path} is corrupt (its checksum does not hold)"
        data = json.loads(body.decode("utf-8"))
        if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
            return None, f"{path} is not a checkpoint of format {CHECKPOINT_FORMAT!r}"
        want = json.loads(json.dumps(setup_of(acc, header)))
        found = data.get("setup")
        if found != want:
            diff = ", ".join(f"{k} {found.get(k)!r} (now {v!r})" for k, v in want.items()
                             if not isinstance(found, dict) or found.get(k) != v)
            return None, f"{path} was written for another setup: {diff}"
        j = data["journal"]
        position = JournalPosition(*(int(j[k]) for k in JournalPosition._fields))
        if min(position) < 0:
            raise ValueError(f"negative journal position {position}")
        if not isinstance(data["state"], dict):
            raise ValueError("no state")
        return Checkpoint(position, data["state"]), ""
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        return None, f"{path} is not a usable checkpoint ({type(exc).__name__}: {exc})"
