"""Plan the measurements: which fiducial to measure next, and when there are enough.

Given the current fiducials (working frame), candidate locations (e.g. holes not yet measured,
working frame, approximate is enough) and optionally the targets that matter, :func:`plan` ranks
the candidates by the expected reduction of the median target registration error (TRE) and
returns a greedy sequence of ``count`` suggestions, each conditioned on the previous ones. The
expected error (:mod:`.expected_error`) depends only on the locations and the error model's
hyper-parameters, never on values not yet measured, so no candidate has to be measured to be
scored. Without targets the error is taken over the work volume: a regular grid in the bounding
box of the fiducials and candidates, kept inside their convex hull (:func:`work_volume`).

Candidates may come in groups (``groups``: a label per candidate, e.g. the robot pose that
measures them together): a group is ranked and measured as a whole, its gain the expected
reduction with all its candidates measured (a rank-m update), and the sequence is of groups.

Stopping rules (:mod:`.stopping`): ``enough`` when the expected median TRE now is within
``within`` (default 10 %) of what measuring every candidate is expected to give, or when the best
next unit is expected to gain less than ``min_gain_fraction`` of it or less than
``min_gain_length`` (both default 0: off). ``expected_after`` is the expected error as a function
of the number of fiducials along the suggestions. :mod:`.model_planner` plans from a built model,
its expected errors calibrated against the decision's cross-validated ones and the stopping rules
held back until that check trusts the error model (:mod:`.model_check`).

Cost: one Cholesky factorisation of the J fiducials per noise axis (O(J^3); one axis when the
noise is isotropic), O((K + C) J^2) to condition the K points and C candidates on them, then
O(K C) per greedy step; ``expected_with_all`` adds one factorisation of J + C points.

For arrays and a known error model::

    em = ExpectedErrorModel.from_axis_std(signal_std, length_scale, axis_std)
    p = plan(fiducials_working, candidates_working, em, targets_working, count=5)
    p.sequence, p.expected_now, p.expected_after, p.enough, p.reason
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .expected_error import (BiasPosterior, ExpectedErrorModel, RigidFitError,
                             expected_squared_errors, fiducial_covariance, inverse_repeats,
                             pooled_median, target_noise)
from ..interpolation.paper import HullTest
from .stopping import verdict
from ..repeats import TWIN_FRACTION, same_place_limit, typical_spacing
from ..validation import as_points, check_spread, rounding

#: ``expected_with_all`` conditions on J + C points at once (one Cholesky factorisation,
#: O((J + C)^3)); beyond this many it is not computed.
ALL_CANDIDATES_MAX = 2000


#: The largest ``within``: 10 x the best error is not "close to the best".
MAX_WITHIN = 10.0


@dataclass(frozen=True)
class PlanConfig:
    """How a plan is made (lengths in the unit of the points).

    :ivar within: ``enough`` when the expected median TRE is within this fraction of the one
        expected with every candidate measured (default 0.10; 0: off).
    :ivar min_gain_fraction: ... or when the best next unit gains less than this fraction of
        the expected median TRE (default 0: off).
    :ivar min_gain_length: ... or less than this length (default 0: off).
    :ivar work_volume_points: size of the grid sampling the work volume when no targets are
        given (before clipping to the convex hull).
    :ivar candidate_repeats: measurements that will be averaged into a new fiducial; None (the
        default): as many as the current fiducials had (the median of their repeat counts,
        :func:`measurement_repeats`).
    :ivar target_repeats: measurements that will be averaged into each target; None: the same.
    """

    min_gain_fraction: float = 0.0
    min_gain_length: float = 0.0
    within: float = 0.10
    work_volume_points: int = 400
    candidate_repeats: Optional[int] = None
    target_repeats: Optional[int] = None

    def __post_init__(self) -> None:
        f = self.min_gain_fraction
        if not isinstance(f, (int, float)) or not math.isfinite(f) or not 0 <= f < 1:
            raise ValueError(f"min_gain_fraction must be in [0, 1), got {f!r}")
        g = self.min_gain_length
        if not isinstance(g, (int, float)) or not math.isfinite(g) or g < 0:
            raise ValueError(f"min_gain_length must be a finite length >= 0, got {g!r}")
        w = self.within
        if not isinstance(w, (int, float)) or not math.isfinite(w) or not 0 <= w <= MAX_WITHIN:
            raise ValueError(f"within must be in [0, {MAX_WITHIN:g}], got {w!r}")
        _check_count(self.work_volume_points, "work_volume_points")
        for name in ("candidate_repeats", "target_repeats"):
            if getattr(self, name) is not None:
                _check_count(getattr(self, name), name)


def typical_repeats(counts: Optional[ArrayLike]) -> int:
    """The median of repeat counts, rounded, at least 1 (1 without counts)."""
    if counts is None or np.size(counts) == 0:
        return 1
    return max(1, int(round(float(np.median(np.asarray(counts, dtype=float))))))


def measurement_repeats(config: "PlanConfig", repeats: Optional[ArrayLike]) -> tuple[int, int]:
    """The measurements averaged into a new fiducial and into each target: the config's, or
    where it says None, the median of the current fiducials' repeat counts ``repeats``
    (:func:`typical_repeats`): a cell measured 200 times a point is planned for 200 more."""
    typical = typical_repeats(repeats)
    return (typical if config.candidate_repeats is None else config.candidate_repeats,
            typical if config.target_repeats is None else config.target_repeats)


#: Most candidates x points (targets or work-volume points) in one plan: the greedy steps hold
#: about a dozen (C, K) arrays of floats (5,000 x 5,000 peaked at 2.5 GB), so this bounds a plan
#: to ~0.5 GB.
MAX_CANDIDATE_POINTS = 5_000_000
#: A candidate or target farther than this many times the typical distance of the points from
#: their centre is refused: a typo or another unit (it would also stretch the work volume of a
#: plan without targets over empty space). Centre and distance are medians of the fiducials
#: with the candidates (and targets, for the candidates), so a cell started from a few
#: neighbouring fiducials can still be planned over its whole plate; a whole file in another
#: unit is what :func:`.scale.unit_mismatch` catches.
FAR_FACTOR = 10.0


def check_near(points: NDArray[np.float64], fiducials: NDArray[np.float64], name: str,
               others: Optional[NDArray[np.float64]] = None, itself: bool = True) -> None:
    """:raises ValueError: naming the first of ``points`` farther from the median of the
        reference points (``fiducials``, ``others`` and, with ``itself``, ``points``) than
        :data:`FAR_FACTOR` x their median distance from it (at least the fiducials' size, the
        largest side of their box). Targets are judged without themselves (80 targets in mm
        against 16 points in m set the median), candidates with themselves (a cell started
        from a few holes is planned over the plate the candidates span)."""
    every = np.vstack([fiducials] + ([points] if itself else [])
                      + ([others] if others is not None else []))
    centre = np.median(every, axis=0)
    size = float((fiducials.max(axis=0) - fiducials.min(axis=0)).max())
    reach = max(float(np.median(np.linalg.norm(every - centre, axis=1))), size)
    gap = np.linalg.norm(points - centre, axis=1)
    far = np.flatnonzero(gap > FAR_FACTOR * reach)
    if far.size:
        k = int(far[0])
        raise ValueError(f"{name} {k} ({', '.join(f'{v:.6g}' for v in points[k])}) is "
                         f"{gap[k]:.4g} from the centre of the points, more than {FAR_FACTOR:g} x "
                         f"their typical distance from it ({reach:.4g}): a typo, or another "
                         f"unit? ({far.size} such {name}(s))")


#: Candidates whose box lies farther than this many fiducial sizes from the fiducials' box are
#: refused (:func:`check_candidates_reach`).
REACH_FACTOR = 2.0


def check_candidates_reach(candidates: NDArray[np.float64],
                           fiducials: NDArray[np.float64]) -> None:
    """:raises ValueError: when the candidates' bounding box lies farther from the fiducials'
        box than :data:`REACH_FACTOR` x the fiducials' size (the largest side of their box): a
        whole file in another frame, origin or unit (a file shifted by 14 cell sizes was
        planned, its gains meaningless). Candidates around the fiducials, on the far side of a
        plate whose corner was measured, or on a parallel rail 1.2 sizes away pass; a shift of
        less than about two sizes cannot be told from them. :func:`check_near` cannot see it,
        since the candidates themselves set its centre."""
    lo, hi = fiducials.min(axis=0), fiducials.max(axis=0)
    size = float((hi - lo).max())
    apart = np.maximum(0.0, np.maximum(candidates.min(axis=0) - hi, lo - candidates.max(axis=0)))
    gap = float(np.linalg.norm(apart))
    if gap > REACH_FACTOR * size:
        raise ValueError(f"the candidates lie {gap:.4g} beyond the fiducials' box, more than "
                         f"{REACH_FACTOR:g} x the fiducials' size ({size:.4g}): are the candidates "
                         f"in another frame, origin or unit? They must be in the working frame, "
                         f"like the fiducials ({len(candidates)} candidates)")


def overlap_notes(fiducials: NDArray[np.float64], fiducial_ids: Sequence[str],
                  candidates: NDArray[np.float64], candidate_ids: Sequence[str]) -> list[str]:
    """Warnings (one line each, possibly none) for candidates that look like a mix-up of the
    files: ids that are fiducial ids at another place, and candidates at measured fiducials
    (one place by the twin rule, :func:`.repeats.same_place_limit`: measuring one again only
    averages its noise, so the plan ranks it last)."""
    out = []
    near = same_place_limit(fiducials)
    where = {name: k for k, name in enumerate(fiducial_ids)}
    moved = [name for k, name in enumerate(candidate_ids) if name in where
             and np.linalg.norm(candidates[k] - fiducials[where[name]]) > near]
    if moved:
        out.append(f"{len(moved)} candidate id(s) are fiducial ids at another place "
                   f"({', '.join(repr(v) for v in moved[:3])}{', ...' if len(moved) > 3 else ''})"
                   f": a mix-up between the files? They are planned as new locations")
    if near > 0:
        gap, _ = cKDTree(fiducials).query(candidates, k=1)
        at = np.flatnonzero(gap <= near)
        if at.size:
            out.append(f"{at.size} of {len(candidates)} candidates are at measured fiducials "
                       f"(within {TWIN_FRACTION * 100:g} % of their spacing, e.g. "
                       f"{candidate_ids[int(at[0])]!r}): measuring one again only averages its "
                       f"noise")
    return out


class MeasurementPlan(NamedTuple):
    """The ranked candidates and the stopping rule (lengths in the unit of the points).

    :ivar sequence: units to measure, in order (greedy, each conditioned on the previous ones);
        ``len == count``. A unit is a candidate index without groups, else the index of a group
        in ``unit_labels`` (its candidates: ``members``).
    :ivar expected_now: expected median TRE over the targets with the current fiducials.
    :ivar expected_after: expected median TRE after measuring ``sequence[:i + 1]``, per i.
    :ivar gains: (U,) per unit, in input order: expected reduction of the median TRE if that unit
        alone (all its candidates) were measured next.
    :ivar ranking: (U,) all units by ``gains``, best first (``ranking[0] == sequence[0]`` unless
        :func:`plan` was given ``first``; ties go to the lower index).
    :ivar enough: a stopping rule holds (:mod:`.stopping`) and nothing holds the plan back.
    :ivar reason: the verdict and its reason in one sentence.
    :ivar enough_after: how many of ``sequence`` to measure before a stopping rule is expected
        to hold (0 when ``enough``); None if not within ``sequence``, or while the rules are held
        back (:func:`plan`'s ``held_back``, :func:`unresolved_bias`; then ``enough`` is False).
    :ivar fiducial_count: J, the fiducials the plan starts from.
    :ivar points: (K, d) where the error was taken: the targets, or the work-volume sample.
    :ivar on_targets: True when ``points`` are the given targets.
    :ivar expected_point_errors: (K,) expected RMS TRE at each point now.
    :ivar expected_with_all: expected median TRE if every candidate were measured (what
        measuring can still buy); None when J + C > :data:`ALL_CANDIDATES_MAX`.
    :ivar candidate_repeats: measurements the plan assumed averaged into each new fiducial.
    :ivar target_repeats: ... and into each target (:func:`measurement_repeats`).
    :ivar enough_rule: which rule says enough: ``within``, ``gain``, ``within+gain``; None
        when not enough.
    :ivar members: per unit, its candidate indices (one each without groups).
    :ivar unit_labels: the group label of each unit; () without groups.
    :ivar model_check: how the error model compares with the cross-validated errors
        (:class:`.model_check.ModelCheck`), when the plan was made from a model.
    """

    sequence: tuple[int, ...]
    expected_now: float
    expected_after: tuple[float, ...]
    gains: NDArray[np.float64]
    ranking: NDArray[np.intp]
    enough: bool
    reason: str
    enough_after: Optional[int]
    fiducial_count: int
    points: NDArray[np.float64]
    on_targets: bool
    expected_point_errors: NDArray[np.float64]
    expected_with_all: Optional[float]
    candidate_repeats: int = 1
    target_repeats: int = 1
    enough_rule: Optional[str] = None
    members: tuple[tuple[int, ...], ...] = ()
    unit_labels: tuple[str, ...] = ()
    model_check: Any = None

    @property
    def error_curve(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Fiducial counts J, J + (the first unit's candidates), ... and the expected median TRE
        at each (the sequence)."""
        sizes = [len(self.members[u]) if self.members else 1 for u in self.sequence]
        n = self.fiducial_count + np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        return n, np.array((self.expected_now,) + self.expected_after)

    @property
    def ranked_candidates(self) -> tuple[int, ...]:
        """The candidate indices of ``sequence``, unit after unit."""
        if not self.members:
            return tuple(int(u) for u in self.sequence)
        return tuple(c for u in self.sequence for c in self.members[u])


def _check_count(v: object, name: str) -> int:
    if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
        raise ValueError(f"{name} must be a positive integer, got {v!r}")
    return int(v)


#: The defaults (2 %, no length threshold, 400 work-volume points, points measured as often as
#: the fiducials were).
DEFAULT_PLAN_CONFIG = PlanConfig()


def _frozen(a: ArrayLike) -> NDArray:
    out = np.array(a)
    out.setflags(write=False)
    return out


def work_volume(points: ArrayLike, count: int = 400) -> NDArray[np.float64]:
    """A regular grid of about ``count`` cell centres in the axis-aligned bounding box of
    ``points`` (working frame), kept inside their convex hull; the points themselves when the
    hull is flat or holds fewer than d + 1 grid points.

    :raises ValueError: on bad points or count.
    """
    p = as_points(points, "work-volume points", None, 1)
    count = _check_count(count, "work_volume_points")
    lo, hi = p.min(axis=0), p.max(axis=0)
    ext = hi - lo
    used = ext > 1e-12 * max(float(np.abs(p).max()), 1.0)
    if used.sum() < p.shape[1]:
        return p
    # The cell side h from the axes at least one cell thick: an axis thinner than h (a plate
    # whose z spread is rounding) gets one cell and leaves the others ~count cells, instead of
    # making h tiny and the grid unbounded (a 0.5 m plate 1e-8 thick asked for 11.8 GiB).
    thick = np.ones(len(ext), dtype=bool)
    while True:
        h = (float(np.prod(ext[thick])) / count) ** (1.0 / int(thick.sum()))
        thin = thick & (ext < h)
        if not thin.any() or thin.sum() == thick.sum():     # all thin: rounding of the root
            break
        thick &= ~thin
    axes = []
    for a in range(p.shape[1]):
        n = max(1, int(round(ext[a] / h))) if thick[a] else 1
        axes.append(lo[a] + (np.arange(n) + 0.5) * ext[a] / n)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, p.shape[1])
    try:
        hull = HullTest(p)
    except ValueError:                     # too few points for qhull
        return p
    inside = grid[hull.simplices(grid) >= 0] if not hull.flat else grid[:0]
    return inside if len(inside) > p.shape[1] else p


def unresolved_bias(fiducials: ArrayLike, error_model: ExpectedErrorModel) -> Optional[str]:
    """Why the error model cannot judge "enough", or None: its bias length scale is shorter than
    the median nearest-neighbour spacing of the fiducials (:func:`.repeats.typical_spacing`)
    while the bias it sees is larger than the noise. Fiducials that sparse cannot show how the
    bias varies between them (a correlation shorter than the sampling is not identifiable), so the
    model calls the bias unlearnable and every candidate gains little, though more fiducials would
    resolve it. Measured: A-like seed 34, 10 fiducials at a median spacing of 910 mm, length scale
    98 mm: "enough" at 10 with 52x the TRE of all fiducials (benchmarks/RESULTS.md, "Planner").
    With sigma fitted the kriging fit keeps the length scale at least that spacing
    (:data:`.gp_fit.FITTED_NOISE_MIN_LENGTH`): the variation between neighbours is noise there,
    and this rule applies to a given sigma."""
    x = np.asarray(fiducials, dtype=np.float64)
    if len(x) < 2:
        return None
    spacing = typical_spacing(x)
    bias = error_model.signal_std * math.sqrt(error_model.dimension)
    noise = math.sqrt(float(np.trace(error_model.noise_covariance)))
    # a length at the spacing (to rounding) is the floor of a fit with sigma unknown: resolved;
    # a bias within the noise, or of rounding (exact data), has nothing to resolve
    if error_model.length_scale >= spacing * (1 - 1e-9) or bias <= max(noise, rounding(x)):
        return None
    return (f"the fitted bias length scale ({error_model.length_scale:.4g}) is shorter than the "
            f"fiducials' spacing ({spacing:.4g}) while the bias ({bias:.4g}) exceeds the noise "
            f"({noise:.4g}): too few fiducials to tell how the bias varies")


def candidate_units(groups: Optional[Sequence[str]], count: int
                    ) -> tuple[tuple[tuple[int, ...], ...], tuple[str, ...]]:
    """The units of ``count`` candidates: with ``groups`` (a label per candidate; '' its own
    unit) one unit per label in order of first appearance, else one per candidate.

    :return: (members per unit, the label of each unit; () without groups).
    :raises ValueError: when ``groups`` is not ``count`` strings.
    """
    if groups is None:
        return tuple((k,) for k in range(count)), ()
    labels = [str(g) for g in groups]
    if len(labels) != count:
        raise ValueError(f"got {len(labels)} candidate group labels for {count} candidates")
    members: dict[str, list[int]] = {}
    for k, g in enumerate(labels):
        members.setdefault(g if g else f"\0{k}", []).append(k)
    names = tuple(g if not g.startswith("\0") else "" for g in members)
    return tuple(tuple(m) for m in members.values()), names


def _padded(members: Sequence[Sequence[int]]) -> NDArray[np.intp]:
    width = max(len(m) for m in members)
    out = np.full((len(members), width), -1, dtype=np.intp)
    for u, m in enumerate(members):
        out[u, :len(m)] = m
    return out



def _error_points(x: NDArray[np.float64], c: NDArray[np.float64], targets: Optional[ArrayLike],
                  config: PlanConfig) -> NDArray[np.float64]:
    """Where :func:`plan` takes the error: the targets (checked), or the work volume of the
    fiducials and candidates; refused when candidates x points is more than a plan holds."""
    d = x.shape[1]
    t = as_points(targets, "targets", d, 1) if targets is not None else None
    check_near(c, x, "candidate", t)
    check_candidates_reach(c, x)
    pts = t if t is not None else work_volume(np.vstack([x, c]), config.work_volume_points)
    if t is not None:
        check_near(pts, x, "target", c, itself=False)
    if len(c) * len(pts) > MAX_CANDIDATE_POINTS:
        kind = "targets" if t is not None else "work-volume points"
        raise ValueError(f"{len(c)} candidates x {len(pts)} {kind} = {len(c) * len(pts):,} is "
                         f"more than one plan holds ({MAX_CANDIDATE_POINTS:,}): give fewer "
                         f"candidates or targets")
    return pts


def _with_all(x: NDArray[np.float64], c: NDArray[np.float64], pts: NDArray[np.float64],
              error_model: ExpectedErrorModel, inv_n: NDArray[np.float64], n_cand: int,
              n_target: int) -> Optional[float]:
    """The expected median error with every candidate measured (None above
    :data:`ALL_CANDIDATES_MAX` fiducials and candidates)."""
    if len(x) + len(c) > ALL_CANDIDATES_MAX:
        return None
    n_all = np.concatenate([1.0 / inv_n, np.full(len(c), float(n_cand))])
    return float(pooled_median(expected_squared_errors(
        np.vstack([x, c]), pts, error_model, n_all, n_target), x.shape[1]))


def _after(members: Sequence[tuple[int, ...]], rigid: RigidFitError,
           bias: Optional[BiasPosterior], const: float,
           cal2: float) -> Callable[[NDArray[np.intp]], NDArray[np.float64]]:
    """The expected squared errors at the points after measuring each of the ``active`` units
    (one candidate each: rank-one updates; groups: rank-m), calibrated by ``cal2``."""
    singles = all(len(m) == 1 for m in members)
    padded = _padded(members)

    def after(active: NDArray[np.intp]) -> NDArray[np.float64]:
        if singles:
            idx = padded[active, 0]
            e = rigid.after_each(idx) + const
            return cal2 * (e + bias.after_each(idx) if bias is not None else e)
        e = rigid.after_units(padded[active]) + const
        return cal2 * (e + bias.after_units(padded[active]) if bias is not None else e)

    return after


def _greedy(count: int, medians: NDArray[np.float64],
            after: Callable[[NDArray[np.intp]], NDArray[np.float64]],
            members: Sequence[tuple[int, ...]], rigid: RigidFitError,
            bias: Optional[BiasPosterior], first_unit: Optional[int], now: float,
            d: int) -> tuple[list[int], list[float], list[float]]:
    """The greedy sequence of :func:`plan`: at each step the unit whose measurement is expected
    to leave the smallest median (``first_unit`` first when given), conditioned on the units
    chosen before (rank-one or rank-m updates of ``rigid`` and ``bias``). Returns the units,
    the expected median after each, and the best unit's gain at each step."""
    n_units = len(members)
    chosen = np.zeros(n_units, dtype=bool)
    guess = medians.copy()                       # warm start of the next step's medians
    sequence: list[int] = []
    expected: list[float] = []
    step_gains: list[float] = []
    before = now
    for i in range(count):
        active = np.flatnonzero(~chosen)
        med = medians if i == 0 else pooled_median(after(active), d, guess[active])
        guess[active] = med
        k = int(np.argmin(med))                  # first of equals: the lowest index
        best, value = int(active[k]), float(med[k])
        step_gains.append(before - value)
        if i == 0 and first_unit is not None:
            best, value = first_unit, float(med[first_unit])
        sequence.append(best)
        expected.append(value)
        chosen[best] = True
        before = value
        if i + 1 < count:
            for m in members[best]:
                rigid.add(m)
                if bias is not None:
                    bias.add(m)
    return sequence, expected, step_gains


def plan(fiducials: ArrayLike, candidates: ArrayLike, error_model: ExpectedErrorModel,
         targets: Optional[ArrayLike] = None, *, count: int = 1,
         repeats: Optional[ArrayLike] = None, config: PlanConfig = DEFAULT_PLAN_CONFIG,
         first: Optional[int] = None, held_back: Optional[str] = None,
         groups: Optional[Sequence[str]] = None, to_measure: str = "") -> MeasurementPlan:
    """Rank candidate fiducials by the expected reduction of the median TRE (module docstring).

    :param fiducials: (J, d) current fiducials, working frame (J >= d + 1, not degenerate).
    :param candidates: (C, d) locations that could be measured next, working frame.
    :param error_model: :class:`.expected_error.ExpectedErrorModel` (e.g.
        :func:`error_model_from`).
    :param targets: (K, d) working-frame targets that matter; None: the work volume.
    :param count: length of the greedy sequence, in units (1 <= count <= U).
    :param repeats: measurements averaged into each current fiducial, n_j (default 1 each).
    :param first: index of a candidate whose unit is suggested first whatever its gain (e.g.
        :func:`.model_planner.decisive_candidate`); the rest of the sequence is greedy after it.
        ``gains``, ``ranking`` and the verdict stay those of the gains.
    :param held_back: why the caller's state does not allow "enough" yet (e.g.
        :func:`.model_planner.held_back_by_decision`); with it, or with a reason from
        :func:`unresolved_bias`, ``enough`` is False, ``enough_after`` None, and ``reason`` is
        "measure more:" with the reasons and ``to_measure``.
    :param groups: a label per candidate ('' its own): candidates measured together (one robot
        pose); a group is one unit, ranked and measured as a whole.
    :param to_measure: what to measure to lift ``held_back``, said in the reason.
    :param config: :class:`PlanConfig`.
    :return: :class:`MeasurementPlan`.
    :raises ValueError: on bad shapes, NaN/inf, a dimension mismatch, degenerate fiducials or
        a count beyond the units.
    """
    d = error_model.dimension
    x = as_points(fiducials, "fiducials", d, d + 1)
    check_spread(x, "fiducials")
    c = as_points(candidates, "candidates", d, 1)
    count = _check_count(count, "count")
    members, labels = candidate_units(groups, len(c))
    what = "candidate groups" if labels else "candidates"
    if count > len(members):
        raise ValueError(f"count ({count}) exceeds the number of {what} ({len(members)})")
    if first is not None and not (isinstance(first, (int, np.integer))
                                  and 0 <= int(first) < len(c)):
        raise ValueError(f"first must be a candidate index in [0, {len(c)}), got {first!r}")
    on_targets = targets is not None
    pts = _error_points(x, c, targets, config)
    inv_n = inverse_repeats(repeats, len(x))
    n_cand, n_target = measurement_repeats(config, repeats)

    inv_nc = 1.0 / n_cand
    rigid = RigidFitError(x, fiducial_covariance(error_model, inv_n), c,
                          fiducial_covariance(error_model, np.array([inv_nc]))[0], pts)
    bias = BiasPosterior(x, inv_n, c, inv_nc, pts, error_model) if error_model.corrected \
        else None
    const = target_noise(error_model, n_target) + \
        (0.0 if error_model.corrected else d * error_model.signal_std ** 2)
    cal2 = error_model.calibration ** 2
    after = _after(members, rigid, bias, const, cal2)
    now_sq = cal2 * (rigid.now() + const + (bias.now() if bias is not None else 0.0))
    now = float(pooled_median(now_sq, d))
    with_all = _with_all(x, c, pts, error_model, inv_n, n_cand, n_target)
    n_units = len(members)
    medians = pooled_median(after(np.arange(n_units)), d, np.full(n_units, now))
    gains = now - medians
    first_unit = None if first is None else next(u for u, m in enumerate(members)
                                                 if int(first) in m)
    sequence, expected, step_gains = _greedy(count, medians, after, members, rigid, bias,
                                             first_unit, now, d)
    holds = [r for r in (held_back, unresolved_bias(x, error_model) if error_model.corrected
                         else None) if r]
    top = int(np.argmin(medians))
    name = (f"group {labels[top]!r}" if labels and labels[top] else f"candidate #{top}"
            if not labels else f"candidate #{members[top][0]}")
    v = verdict(now, with_all, len(c), name, step_gains[0], expected, step_gains, config.within,
                config.min_gain_fraction, config.min_gain_length, holds, to_measure)
    return MeasurementPlan(tuple(sequence), now, tuple(expected), _frozen(gains),
                           _frozen(np.argsort(-gains, kind="stable")), v.enough, v.reason,
                           v.enough_after, len(x), _frozen(pts), on_targets,
                           _frozen(np.sqrt(now_sq)), with_all, n_cand, n_target, v.rule,
                           members, labels)
