"""Sessions between which the working frame moved: the motion, its test, the re-stationing.

A tracker stand bumped, a tracker re-stationed after lunch, a robot base re-clamped: measurements
before and after are in two working frames. Mixed as repeats they break the rigid-body condition
with an error no interpolation can learn. Each measurement carries a session (empty: the current
one). For every session but the reference (the session the targets are measured in, by default
the latest), the rigid motion of the working frame against the reference is estimated from the
fiducials measured in both (their mean per session), and tested against the noise:

    A_k = R B_k + t + e_k,   k = 1..n common fiducials, e_k ~ N(0, s^2 (1/n_A + 1/n_B)) per axis

The fit (weighted by 1 / (1/n_A + 1/n_B), :func:`~.registration.rigid_fit`) explains the part
SS0 - SS1 of the weighted squared differences SS0 = sum w ||A_k - B_k||^2 with q = d (d + 1) / 2
parameters; SS1 is left with d n - q degrees of freedom. Under "no move"
F = ((SS0 - SS1) / q) / (SS1 / (d n - q)) follows F(q, d n - q), which needs no sigma: the
residuals estimate the noise. The session moved when p < :data:`SESSION_SIGNIFICANCE`; then its
measurements (fiducials and targets) are mapped into the reference's frame before anything else;
otherwise they stay as they are. A session with fewer than d + 1 common fiducials, or with all of
them on one line, cannot be re-stationed: it is kept apart (left out of the model), never mixed.
Sessions are joined one by one, the one with the most common fiducials first, each joined session
adding its fiducials to those the next ones are compared with.

The live node finds a move nobody declared with :class:`BumpDetector`: re-measured fiducials whose
new points are explained by one rigid motion of their earlier means, by the same F test at
:data:`LIVE_SIGNIFICANCE`, open a new session at the first of them. Every size k of the newest
re-measurements is tested at once, from running sums (:func:`newest_motion_tests`): one batched
d x d SVD per test, not a rigid fit per k; and the test runs at most once per
``window - d - 1`` measurements, which the window of ``window`` re-measurements still spans: a
move is found a few measurements later at most, and starts where it began (the change point
over the window).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np
import scipy.stats
from numpy.typing import ArrayLike, NDArray

from ..rigid.registration import Registration, rigid_fit

#: A session moved when the F test's p-value is below this (1 % false moves per session).
SESSION_SIGNIFICANCE = 0.01
#: The live detector's level per test (it tests at every re-measured fiducial).
LIVE_SIGNIFICANCE = 1e-4
#: Common fiducials on one line (second singular value below this fraction of the first) fix
#: no rotation about that line.
COLLINEAR_FRACTION = 1e-3


@dataclass(frozen=True)
class SessionMotion:
    """How one session's working frame relates to the reference session's.

    :ivar session: its name.
    :ivar n_measurements: measurements (fiducials) in it.
    :ivar n_common: fiducials it shares with the sessions it was compared with.
    :ivar moved: whether the motion is significant (then its points are re-stationed).
    :ivar translation: (d,) the estimated motion's displacement at the common fiducials'
        centroid (unit of the points): where that centroid lands minus where it was (reported
        whether or not it is significant).
    :ivar rotation_deg: the estimated motion's rotation angle [deg].
    :ivar p_value: the F test's p-value; ``None`` for the reference and kept-apart sessions.
    :ivar kept_apart: too few common fiducials to re-station: left out of the model.
    :ivar transform: the map applied to its points (identity unless ``moved``; ``None`` when
        kept apart): ``reference point = transform.apply(session point)``.
    """

    session: str
    n_measurements: int
    n_common: int
    moved: bool
    translation: NDArray[np.float64]
    rotation_deg: float
    p_value: Optional[float]
    kept_apart: bool
    transform: Optional[Registration]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``session``, ``n_measurements``, ``n_common``, ``moved``, ``kept_apart``,
        ``translation`` (list), ``rotation_deg``, ``p_value``."""
        return {"session": self.session, "n_measurements": self.n_measurements,
                "n_common": self.n_common, "moved": self.moved, "kept_apart": self.kept_apart,
                "translation": [float(v) for v in self.translation],
                "rotation_deg": float(self.rotation_deg),
                "p_value": None if self.p_value is None else float(self.p_value)}


@dataclass(frozen=True)
class SessionPlan:
    """Every session's motion against ``reference`` (:func:`estimate_sessions`)."""

    reference: str
    motions: tuple[SessionMotion, ...]

    def motion(self, session: str) -> SessionMotion:
        """The motion of ``session``.

        :raises KeyError: for a session the plan does not know.
        """
        for m in self.motions:
            if m.session == session:
                return m
        raise KeyError(f"unknown session {session!r}")

    @property
    def moved(self) -> tuple[SessionMotion, ...]:
        """The sessions re-stationed."""
        return tuple(m for m in self.motions if m.moved)

    @property
    def kept_apart(self) -> tuple[SessionMotion, ...]:
        """The sessions left out."""
        return tuple(m for m in self.motions if m.kept_apart)

    def apply(self, points: ArrayLike, sessions: Sequence[str]
              ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """``points`` (n, d) of the given sessions in the reference's frame, and which are kept
        (False: their session is kept apart, or unknown to the plan)."""
        p = np.array(points, dtype=np.float64, copy=True)
        keep = np.ones(len(p), dtype=bool)
        labels = np.asarray(list(sessions), dtype=object)
        for name in dict.fromkeys(sessions):
            rows = labels == name
            try:
                m = self.motion(name)
            except KeyError:
                keep[rows] = False
                continue
            if m.transform is None:
                keep[rows] = False
            elif m.moved:
                p[rows] = m.transform.apply(p[rows])
        return p, keep

    def warning(self, unit: str = "") -> str:
        """One line naming the sessions moved and those kept apart, or ``""``."""
        u = f" {unit}" if unit else ""
        parts = [f"session {m.session!r} moved against {self.reference!r} by "
                 f"{float(np.linalg.norm(m.translation)):.3g}{u} and {m.rotation_deg:.3g} deg "
                 f"(p = {m.p_value:.2g}, {m.n_common} common fiducials): re-stationed"
                 for m in self.moved]
        parts += [f"session {m.session!r} shares {m.n_common} fiducial(s) with the others, too "
                  f"few to re-station (needs {_least(self)} not on one line): kept apart, "
                  f"{m.n_measurements} measurement(s) left out" for m in self.kept_apart]
        return "; ".join(parts)

    def to_list(self) -> list[dict[str, Any]]:
        """The ``sessions`` list of the JSON reports."""
        return [m.to_dict() for m in self.motions]


def _least(plan: SessionPlan) -> int:
    d = len(plan.motions[0].translation) if plan.motions else 3
    return d + 1


def _identity(d: int) -> Registration:
    return Registration(np.eye(d), np.zeros(d), 0.0)


def _angle_deg(rotation: NDArray[np.float64]) -> float:
    if rotation.shape == (2, 2):
        return abs(math.degrees(math.atan2(rotation[1, 0], rotation[0, 0])))
    c = (float(np.trace(rotation)) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def spread_enough(points: NDArray[np.float64]) -> bool:
    """Whether ``points`` (n, d) fix a rigid motion: at least d + 1, not all on one line."""
    n, d = points.shape
    if n < d + 1:
        return False
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return bool(sv[0] > 0 and sv[1] > COLLINEAR_FRACTION * sv[0])


def motion_test(before: NDArray[np.float64], after: NDArray[np.float64],
                weights: Optional[NDArray[np.float64]] = None
                ) -> tuple[Registration, float]:
    """The rigid motion ``before`` -> ``after`` (n, d) of the same fiducials and the F test's
    p-value that there is none (module docstring). ``weights``: 1 / (1/n_A + 1/n_B) each."""
    n, d = before.shape
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    reg = rigid_fit(before, after, w)
    ss0 = float(np.sum(w * np.sum((after - before) ** 2, axis=1)))
    ss1 = float(np.sum(w * np.sum((after - reg.apply(before)) ** 2, axis=1)))
    q = d * (d + 1) // 2
    dof = d * n - q
    scale = float(np.sum(w * np.sum(after ** 2, axis=1))) + 1e-300
    if ss1 <= 1e-24 * scale:                  # exact data: moved iff it differs at all
        return reg, 0.0 if ss0 > 1e-20 * scale else 1.0
    f = ((ss0 - ss1) / q) / (ss1 / dof)
    return reg, float(scipy.stats.f.sf(max(f, 0.0), q, dof))


def newest_motion_tests(before: NDArray[np.float64], after: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """:func:`motion_test`'s F statistic (unweighted) for each k = d + 1 .. n newest rows of
    ``before`` -> ``after`` (n, d), and whether those k fix a motion (:func:`spread_enough`),
    from running sums and one batched d x d SVD. With centred sums H = sum b' a'^T = U S V^T,
    the least-squares rotation leaves SS1 = |b'|^2 + |a'|^2 - 2 (s_1 + .. + sign(det U V) s_d).

    :return: (F, spread), each (n - d,), entry i for the newest d + 1 + i rows.
    """
    n, d = before.shape
    origin = before[-1]
    b, a = (before - origin)[::-1], (after - origin)[::-1]       # newest first
    k = np.arange(1, n + 1, dtype=np.float64)
    sb, sa = np.cumsum(b, axis=0), np.cumsum(a, axis=0)
    bb = (np.cumsum(np.einsum("ni,nj->nij", b, b), axis=0)
          - np.einsum("ni,nj->nij", sb, sb) / k[:, None, None])
    h = (np.cumsum(np.einsum("ni,nj->nij", b, a), axis=0)
         - np.einsum("ni,nj->nij", sb, sa) / k[:, None, None])
    aa = np.cumsum(np.sum(a * a, axis=1)) - np.sum(sa * sa, axis=1) / k
    ss0 = np.cumsum(np.sum((a - b) ** 2, axis=1))[d:]
    u, sv, vt = np.linalg.svd(h[d:])
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt))
    sv[:, -1] *= np.where(sign == 0, 1.0, sign)
    ss1 = np.maximum(np.trace(bb[d:], axis1=1, axis2=2) + aa[d:] - 2 * sv.sum(axis=1), 0.0)
    q = d * (d + 1) // 2
    dof = d * k[d:] - q
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(ss1 > 0, ((ss0 - ss1) / q) / (ss1 / dof), np.where(ss0 > 0, np.inf, 0.0))
    spread_sv = np.sqrt(np.maximum(np.linalg.eigvalsh(bb[d:])[:, ::-1], 0.0))
    spread = (spread_sv[:, 0] > 0) & (spread_sv[:, 1] > COLLINEAR_FRACTION * spread_sv[:, 0])
    return f, spread


def session_cells(ids: Sequence[str], sessions: Sequence[str], points: ArrayLike
                  ) -> dict[str, dict[str, tuple[NDArray[np.float64], int]]]:
    """Per session (in order of first appearance), per fiducial id: (mean point, count)."""
    p = np.asarray(points, dtype=np.float64)
    sums: dict[str, dict[str, list]] = {}
    for k, (fid, ses) in enumerate(zip(ids, sessions)):
        cell = sums.setdefault(ses, {}).setdefault(fid, [np.zeros(p.shape[1]), 0])
        cell[0] = cell[0] + p[k]
        cell[1] += 1
    return {s: {f: (c[0] / c[1], c[1]) for f, c in cells.items()} for s, cells in sums.items()}


def estimate_sessions(cells: dict[str, dict[str, tuple[NDArray[np.float64], int]]],
                      reference: Optional[str] = None,
                      significance: float = SESSION_SIGNIFICANCE) -> SessionPlan:
    """Every session's motion against ``reference`` (module docstring).

    :param cells: per session (in order of first appearance), per fiducial id: (mean working
        point (d,), number of measurements); :func:`session_cells` builds it from rows.
    :param reference: the session the others are mapped into; default the latest (last key),
        or when the latest shares too few fiducials with every other, the latest that does.
    :param significance: the F test's level.
    :return: :class:`SessionPlan`.
    :raises ValueError: for no sessions or an unknown reference.
    """
    names = list(cells)
    if not names:
        raise ValueError("no sessions")
    if reference is not None:
        if reference not in cells:
            raise ValueError(f"reference session {reference!r} is not among the sessions "
                             f"{names}")
        return _join(cells, reference, significance)
    # the latest session, unless another reference keeps more measurements (the latest shares
    # too few fiducials with the others): then the latest of those that keep the most
    best: Optional[SessionPlan] = None
    for ref in reversed(names):
        plan = _join(cells, ref, significance)
        if best is None or _kept(plan) > _kept(best):
            best = plan
        if not plan.kept_apart:
            break
    return best


def _kept(plan: SessionPlan) -> int:
    return sum(m.n_measurements for m in plan.motions if not m.kept_apart)


def _join(cells: dict[str, dict[str, tuple[NDArray[np.float64], int]]], ref: str,
          significance: float) -> SessionPlan:
    """The plan with reference ``ref`` (module docstring)."""
    names = list(cells)
    d = len(next(iter(cells[ref].values()))[0])
    anchor = {f: (m * n, n) for f, (m, n) in cells[ref].items()}
    motions = {ref: SessionMotion(ref, sum(n for _, n in cells[ref].values()),
                                  len(cells[ref]), False, np.zeros(d), 0.0, None, False,
                                  _identity(d))}
    remaining = [s for s in names if s != ref]
    while remaining:
        def common(s: str) -> list[str]:
            return [f for f in cells[s] if f in anchor]

        joinable = [s for s in remaining
                    if spread_enough(np.array([cells[s][f][0] for f in common(s)]).reshape(-1, d))]
        if not joinable:
            for s in remaining:
                motions[s] = SessionMotion(s, sum(n for _, n in cells[s].values()),
                                           len(common(s)), False, np.zeros(d), 0.0, None, True,
                                           None)
            break
        s = max(reversed(joinable), key=lambda name: len(common(name)))
        shared = common(s)
        before = np.array([cells[s][f][0] for f in shared])
        after = np.array([anchor[f][0] / anchor[f][1] for f in shared])
        n_b = np.array([cells[s][f][1] for f in shared], dtype=float)
        n_a = np.array([anchor[f][1] for f in shared], dtype=float)
        reg, p = motion_test(before, after, 1.0 / (1.0 / n_a + 1.0 / n_b))
        moved = p < significance
        transform = reg if moved else _identity(d)
        centre = before.mean(axis=0)
        shift = reg.apply(centre[None])[0] - centre          # the estimate, moved or not
        motions[s] = SessionMotion(s, sum(n for _, n in cells[s].values()), len(shared), moved,
                                   shift, _angle_deg(reg.rotation), p, False, transform)
        for f, (m, n) in cells[s].items():
            moved_mean = transform.apply(m[None])[0]
            total, count = anchor.get(f, (np.zeros(d), 0))
            anchor[f] = (total + moved_mean * n, count + n)
        remaining.remove(s)
    return SessionPlan(ref, tuple(motions[s] for s in names))


@dataclass(frozen=True)
class Bump:
    """A move found live: the new session starts at measurement ``start`` (the sequence number
    given to :meth:`BumpDetector.observe`), explained by ``motion`` (old frame -> new frame)
    with the F test's ``p_value``, from ``n_fiducials`` re-measured fiducials."""

    start: int
    motion: Registration
    p_value: float
    n_fiducials: int


class BumpDetector:
    """Finds a move of the working frame nobody declared, from the stream (module docstring).

    Call :meth:`observe` with every accepted measurement of the current session, in order, with
    the mean of that fiducial's earlier measurements in the current session (``None`` for its
    first). It keeps the latest re-measurement of each fiducial, at most ``2 window`` of them
    (memory bounded). When the newest k of them (k from d + 1 up to ``window``) are explained by
    one rigid motion of their earlier means at :data:`LIVE_SIGNIFICANCE` (divided by the number
    of k tried), a :class:`Bump` is returned; the new session starts at the change point among
    the kept re-measurements (at the latest the first of those k): the one before which no
    motion and from which on the motion leave the least squared misfit. Then the detector starts
    over: call :meth:`reset` when a session opens for any other reason.

    :param dimension: 2 or 3.
    :param window: most re-measurements kept (default 4 (d + 1)).
    """

    def __init__(self, dimension: int, window: Optional[int] = None,
                 significance: float = LIVE_SIGNIFICANCE) -> None:
        if dimension not in (2, 3):
            raise ValueError(f"dimension must be 2 or 3, got {dimension!r}")
        self.dimension = dimension
        self.window = window or 4 * (dimension + 1)
        #: The test runs once per this many measurements (module docstring).
        self.every = max(1, self.window - dimension - 1)
        self.significance = significance
        self._recent: list[tuple[int, str, NDArray[np.float64], NDArray[np.float64]]] = []
        self._critical: dict[int, NDArray[np.float64]] = {}
        self._tested = -1         # the sequence number of the last test (-1: none since reset)

    def reset(self) -> None:
        """Forget the re-measurements (a new session opened)."""
        self._recent.clear()
        self._tested = -1

    def _critical_f(self, n: int) -> NDArray[np.float64]:
        """The F test's critical values for k = d + 1 .. n newest, at the level per k."""
        if n not in self._critical:
            d = self.dimension
            q = d * (d + 1) // 2
            k = np.arange(d + 1, n + 1)
            level = self.significance / len(k)
            self._critical[n] = np.asarray(scipy.stats.f.isf(level, q, d * k - q), dtype=float)
        return self._critical[n]

    def observe(self, sequence: int, fiducial_id: str, point: ArrayLike,
                earlier_mean: Optional[ArrayLike]) -> Optional[Bump]:
        """Take one accepted measurement; a :class:`Bump` when it completes a detected move."""
        if earlier_mean is None:
            return None
        p = np.asarray(point, dtype=np.float64)[: self.dimension]
        m = np.asarray(earlier_mean, dtype=np.float64)[: self.dimension]
        self._recent = [r for r in self._recent if r[1] != fiducial_id]
        self._recent.append((sequence, fiducial_id, m, p))
        del self._recent[: max(0, len(self._recent) - 2 * self.window)]
        d = self.dimension
        recently = self._tested >= 0 and sequence - self._tested < self.every
        tested = self._recent[-self.window:]
        if len(tested) < d + 1 or recently:
            return None     # tested at most once per `every` measurements (the window spans it)
        self._tested = sequence
        n = len(tested)
        f, spread = newest_motion_tests(np.array([r[2] for r in tested]),
                                        np.array([r[3] for r in tested]))
        hits = np.flatnonzero(spread & (f > self._critical_f(n)))
        if len(hits):
            k = int(hits[0]) + d + 1
            before = np.array([r[2] for r in self._recent])
            after = np.array([r[3] for r in self._recent])
            reg, p_value = motion_test(before[-k:], after[-k:])
            # the change point among all kept re-measurements (at the latest the first of the
            # newest k; the test may run some measurements after the move began): no motion
            # before it, the motion from it on, least squares
            still = np.sum((after - before) ** 2, axis=1)
            moved = np.sum((after - reg.apply(before)) ** 2, axis=1)
            cost = (np.concatenate([[0.0], np.cumsum(still)])
                    + np.concatenate([np.cumsum(moved[::-1])[::-1], [0.0]]))
            first = min(int(np.argmin(cost[:-1])), len(self._recent) - k)
            bump = Bump(self._recent[first][0], reg, p_value, len(self._recent) - first)
            self.reset()
            return bump
        return None
