"""The running sums of :class:`~.accumulator.FiducialAccumulator` per (fiducial, session), the
live bump rule, and the fiducials' means in the reference session's frame.

**Sessions.** Every measurement carries a session (:attr:`~.records.Measurement.session`): a
non-empty name switches the current session, an empty one means the current session (the first
is :data:`FIRST_SESSION`). The current session is the one of the latest measurement; it is the
reference the others are re-stationed into (:func:`~.sessions.estimate_sessions`).

**The bump rule.** Every committed measurement of a fiducial measured before in the current
session is shown to a :class:`~.sessions.BumpDetector` with that earlier mean. When it finds a
move, a new session ``auto-N`` opens at the bump's first measurement: the committed measurements
from there on, still held in a tail of the latest :data:`TAIL` measurements, are taken out of
the old session's sums and put into the new one's (a bump starting before the tail's oldest
measurement moves only those in the tail). It runs where a record is committed, so replaying a
journal finds the same bumps at the same measurements and gives the same state.

Memory: O(fiducials x sessions) running sums, plus the tail. Pure Python + numpy.
"""

from __future__ import annotations

from collections import deque
from typing import Optional

import numpy as np
from numpy.typing import NDArray

from .records import FiducialRepeats, Measurement
from .sessions import Bump, BumpDetector, SessionPlan, estimate_sessions

#: The name of the first session when none is given.
FIRST_SESSION = "1"
#: Sessions opened by the bump rule are ``auto-1``, ``auto-2``, ...
AUTO_SESSION_PREFIX = "auto-"
#: Committed measurements kept for the bump rule's relabelling.
TAIL = 256


class Combined:
    """One fiducial over several sessions (Chan et al.'s parallel update): count, means and the
    working-frame sum of squared deviations, summed over axes (the trace, rotation-invariant)."""

    __slots__ = ("n", "mean_w", "mean_d", "m2_w")

    def __init__(self, dimension: int) -> None:
        self.n = 0
        self.mean_w = np.zeros(dimension)
        self.mean_d = np.zeros(dimension)
        self.m2_w = 0.0

    def join(self, n: int, mean_w: NDArray[np.float64], mean_d: NDArray[np.float64],
             m2_w: float) -> None:
        """Add a session's statistics: M2 = M2a + M2b + |ma - mb|^2 na nb / (na + nb)."""
        total = self.n + n
        delta = mean_w - self.mean_w
        self.m2_w += m2_w + float(delta @ delta) * self.n * n / total
        self.mean_w = self.mean_w + delta * (n / total)
        self.mean_d = self.mean_d + (mean_d - self.mean_d) * (n / total)
        self.n = total

    def variance_w(self) -> float:
        """sigma_j^2 as :meth:`~.records.FiducialRepeats.variance_w`; NaN below 2."""
        return self.m2_w / (self.n - 1) if self.n >= 2 else float("nan")


class SessionSums:
    """Per session (in order of first appearance), per fiducial: its repeats (module docstring).

    :param dimension: 2 or 3.
    :param tail: committed measurements kept for relabelling after a bump.
    """

    def __init__(self, dimension: int, tail: int = TAIL) -> None:
        self.dimension = dimension
        self.tail = tail
        self.clear()

    def clear(self) -> None:
        """Forget every session."""
        self._cells: dict[str, dict[str, FiducialRepeats]] = {}
        self._starts: dict[str, float] = {}
        self.current = ""
        self._tail: deque[list] = deque(maxlen=self.tail)
        self._detector = BumpDetector(self.dimension)
        self._sequence = 0
        #: The bumps found, with the session each opened (latest last, at most 16 kept).
        self.bumps: deque[tuple[str, Bump]] = deque(maxlen=16)

    @property
    def names(self) -> tuple[str, ...]:
        """The sessions, in order of first appearance."""
        return tuple(self._cells)

    def resolve(self, session: str) -> str:
        """The session a measurement with ``session`` goes to."""
        return session or self.current or FIRST_SESSION

    def cell(self, session: str, fiducial_id: str) -> Optional[FiducialRepeats]:
        """The repeats of ``fiducial_id`` in ``session``, or ``None``."""
        return self._cells.get(session, {}).get(fiducial_id)

    def add(self, record: Measurement) -> Optional[Bump]:
        """Count ``record`` in its session; the :class:`~.sessions.Bump` when it completes a
        move (a session ``auto-N`` was opened), else ``None``."""
        name = self.resolve(record.session)
        if name != self.current:
            self._detector.reset()
            self.current = name
        cells = self._cells.setdefault(name, {})
        self._starts.setdefault(name, record.stamp_s)
        fid = record.fiducial_id
        cell = cells.get(fid)
        earlier = None if cell is None else cell.mean_w()
        if cell is None:
            cell = cells[fid] = FiducialRepeats(self.dimension)
        cell.add(record.working, record.destination)
        sequence = self._sequence
        self._sequence += 1
        self._tail.append([sequence, fid, record.working, record.destination, record.stamp_s,
                           name])
        if earlier is None:
            return None
        bump = self._detector.observe(sequence, fid, record.working, earlier)
        if bump is not None:
            self._open(bump)
        return bump

    def _open(self, bump: Bump) -> None:
        """Open ``auto-N`` at ``bump.start`` and move the tail's measurements from there."""
        n = 1
        while f"{AUTO_SESSION_PREFIX}{n}" in self._cells:
            n += 1
        new, old = f"{AUTO_SESSION_PREFIX}{n}", self.current
        cells, moved = self._cells[old], self._cells.setdefault(new, {})
        for entry in self._tail:
            sequence, fid, working, destination, stamp, session = entry
            if sequence < bump.start or session != old:
                continue
            cells[fid].remove(working, destination)
            if cells[fid].n == 0:
                del cells[fid]
            moved.setdefault(fid, FiducialRepeats(self.dimension)).add(working, destination)
            self._starts.setdefault(new, stamp)
            entry[5] = new
        if not cells:
            del self._cells[old], self._starts[old]
        self.current = new
        self.bumps.append((new, bump))

    def plan(self, enabled: set[str]) -> Optional[SessionPlan]:
        """The sessions' motions against the current one, from the ``enabled`` fiducials'
        means; ``None`` with one session (or none)."""
        cells = {s: {f: (np.array(c.mean_w()), c.n) for f, c in fids.items() if f in enabled}
                 for s, fids in self._cells.items()}
        cells = {s: c for s, c in cells.items() if c}
        if len(cells) < 2 or self.current not in cells:
            return None
        return estimate_sessions(cells, reference=self.current)

    def combined(self, plan: SessionPlan, ids: list[str]) -> dict[str, Combined]:
        """Each of ``ids`` over the sessions ``plan`` keeps, working means mapped into the
        reference's frame; a fiducial measured only in kept-apart sessions is missing."""
        out: dict[str, Combined] = {}
        for motion in plan.motions:
            if motion.transform is None:
                continue
            for fid in ids:
                cell = self._cells.get(motion.session, {}).get(fid)
                if cell is None:
                    continue
                mean_w = np.array(cell.mean_w())
                if motion.moved:
                    mean_w = motion.transform.apply(mean_w[None])[0]
                out.setdefault(fid, Combined(self.dimension)).join(
                    cell.n, mean_w, np.array(cell.mean_d()), cell.m2_w())
        return {f: out[f] for f in ids if f in out}

    def starts(self) -> tuple[tuple[str, float], ...]:
        """Per session the stamp of its first measurement [s]."""
        return tuple((s, self._starts[s]) for s in self._cells)

    def digest(self) -> tuple:
        """Every stored value (for state comparisons)."""
        return (self.current, tuple((s, tuple((f, c.digest()) for f, c in fids.items()))
                                    for s, fids in self._cells.items()),
                tuple(tuple(e) for e in self._tail), self._sequence,
                tuple((s, b.start) for s, b in self.bumps))
