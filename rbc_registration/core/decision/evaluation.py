"""Evaluation of a model on targets with known truth (paper eq. 3) and leave-one-out; the
fiducials that stand out as blunders, after a build (:func:`blunders`) and before one
(:func:`gross_misfits`)."""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..constants import UNCORRECTED, FoldKind
from .crossval import FoldScheme, cross_validate
from .groups import group_labels
from ..model import RbcModel
from ..validation import as_point_pairs


class TargetErrors(NamedTuple):
    """Target registration errors (eq. 3) per target, unit of the points.

    :ivar tre_u: ||R_u T + tau_u - T_Y||, uncorrected.
    :ivar tre_c: ||R_c (T - eps(T)) + tau_c - T_Y||, corrected.
    :ivar delta: tre_c - tre_u (< 0: correcting improved the target).
    """

    tre_u: NDArray[np.float64]
    tre_c: NDArray[np.float64]
    delta: NDArray[np.float64]

    def summary(self) -> dict[str, float]:
        """Median TREs and the fraction of targets improved."""
        return {"tre_u_median": float(np.median(self.tre_u)),
                "tre_c_median": float(np.median(self.tre_c)),
                "fraction_improved": float(np.mean(self.delta < 0))}


def target_errors(model: RbcModel, targets_working: ArrayLike,
                  targets_destination: ArrayLike) -> TargetErrors:
    """TRE_u, TRE_c and Delta TRE (eq. 3) of targets measured in both frames."""
    tw, td = as_point_pairs(targets_working, targets_destination, model.config.dimension)
    tc = model.correct(tw)
    tre_u = np.linalg.norm(tc.uncorrected - td, axis=1)
    tre_c = np.linalg.norm(tc.corrected - td, axis=1)
    return TargetErrors(tre_u, tre_c, tre_c - tre_u)


def leave_one_out(model: RbcModel) -> TargetErrors:
    """Accuracy estimate without targets: each fiducial in turn is held out and evaluated as a
    target of a model rebuilt from the others (restoration and both registrations refitted;
    kriging conditioned on the others with the full model's hyper-parameters), see
    :func:`~.crossval.cross_validate`. ``tre_c`` is the configured interpolation's.

    Subsets in the config are not used (indices would shift); all remaining fiducials are.
    Reuses the decision's cross-validation when that was leave-one-out without subsets.

    :raises ValueError: with fewer than d + 2 fiducials (each rebuild needs d + 1), or when a fold
        is degenerate.
    """
    cfg = model.config
    j, d = len(model.working), cfg.dimension
    if j < d + 2:
        raise ValueError(f"leave-one-out in {d}D needs at least {d + 2} fiducials (each rebuild "
                         f"needs {d + 1}), got {j}")
    method = cfg.interpolation
    cv = model.decision.cross_validation
    reusable = (cv.scheme.kind == FoldKind.LEAVE_ONE_OUT.value and cfg.uncorrected_subset is None
                and cfg.corrected_subset is None)
    if not (reusable and UNCORRECTED in cv.errors and method in cv.errors):
        labels = group_labels(model.groups, j)
        cv = cross_validate(model.working, model.destination, (UNCORRECTED, method),
                            restoration=cfg.restoration, steps=cfg.steps,
                            kriging=model.interpolators.get("kriging"),
                            scheme=FoldScheme(FoldKind.LEAVE_ONE_OUT.value, j), groups=labels)
    if cv.unavailable:
        name, why = next(iter(cv.unavailable.items()))
        raise ValueError(f"leave-one-out of {name}: {why}")
    tre_u, tre_c = cv.errors[UNCORRECTED], cv.errors[method]
    return TargetErrors(tre_u, tre_c, tre_c - tre_u)


#: A fiducial whose held-out error is this many times the median of the fiducials' is a likely
#: blunder (a typo in one coordinate): held-out errors of sound cells stay within a few times
#: their median (the largest of 125 single measurements: ~3x).
BLUNDER_FACTOR = 20.0
#: Fewest fiducials for the median of their held-out errors to say what is typical.
BLUNDER_MIN_FIDUCIALS = 8


class Blunder(NamedTuple):
    """A fiducial whose held-out error stands out: its id, that error, the median of all
    fiducials' and the candidate whose held-out errors tell (unit of the points)."""

    fiducial_id: str
    error: float
    median: float
    method: str


def blunders(model: RbcModel, factor: float = BLUNDER_FACTOR) -> list[Blunder]:
    """Fiducials whose held-out error (the decision's cross-validation) is more than ``factor``
    times the median of the fiducials', largest first, by the candidate with the smallest
    median held-out error (where one wrong point stands out most). None without a
    cross-validation or with fewer than :data:`BLUNDER_MIN_FIDUCIALS` fiducials.

    One mistyped coordinate of 125 fiducials (27 mm) left the model 4.6x worse at the targets
    and the decision confident: its held-out error was 25.9 mm against a median of 0.29 mm.
    """
    cv = model.decision.cross_validation
    errors = {m: np.asarray(e, dtype=float) for m, e in (cv.errors if cv else {}).items()
              if len(e) == len(model.ids) and np.isfinite(e).all()}
    if len(model.ids) < BLUNDER_MIN_FIDUCIALS or not errors:
        return []
    method = min(errors, key=lambda m: float(np.median(errors[m])))
    err = errors[method]
    median = float(np.median(err))
    if not median > 0:
        return []
    flagged = np.flatnonzero(err > factor * median)
    return [Blunder(model.ids[k], float(err[k]), median, method)
            for k in flagged[np.argsort(-err[flagged])]]


def describe_blunders(found: Sequence[Blunder], unit: str) -> str:
    """One line naming the fiducial of ``found`` (:func:`blunders`, largest first) whose held-out
    error stands out most, and the others over the threshold; "" when there are none.

    :param unit: the unit of the points, for the errors (e.g. "mm"; "m" on the ROS side).
    """
    if not found:
        return ""
    worst = found[0]
    more = (f"; {len(found) - 1} more over {BLUNDER_FACTOR:g} x ("
            + ", ".join(b.fiducial_id for b in found[1:6])
            + (", ..." if len(found) > 6 else "")
            + "), maybe through it: their held-out predictions use it") if found[1:] else ""
    return (f"fiducial {worst.fiducial_id}: held-out error {worst.error:.4g} {unit}, "
            f"{worst.error / worst.median:.0f} x the median of the fiducials "
            f"({worst.median:.4g} {unit}, {worst.method}): a typo or a wrong hole? check "
            f"its points first{more}")



def describe_truth_blunders(ids: Sequence[str], tre_u: ArrayLike, unit: str,
                            factor: float = BLUNDER_FACTOR) -> str:
    """One line naming the targets whose uncorrected TRE (eq. 3) is more than ``factor`` times
    the median of the targets' (at least :data:`BLUNDER_MIN_FIDUCIALS` targets with finite
    TRE), worst first; "" when none. A target's truth mistyped, or two targets' truth swapped,
    shows as a TRE the registration cannot explain: sound targets stay within a few times the
    median, also outside the fiducials' hull."""
    err = np.asarray(tre_u, dtype=float)
    finite = np.isfinite(err)
    if finite.sum() < BLUNDER_MIN_FIDUCIALS:
        return ""
    median = float(np.median(err[finite]))
    if not median > 0:
        return ""
    flagged = np.flatnonzero(finite & (err > factor * median))
    if not len(flagged):
        return ""
    flagged = flagged[np.argsort(-err[flagged], kind="stable")]
    named = ", ".join(f"{ids[k]!r} ({err[k]:.4g} {unit})" for k in flagged[:6])
    more = f" and {len(flagged) - 6} more" if len(flagged) > 6 else ""
    return (f"target{'s' if len(flagged) > 1 else ''} {named}{more}: uncorrected TRE over "
            f"{factor:g} x the median of the targets ({median:.4g} {unit}): its truth mistyped, "
            f"or swapped with another target's? check the truth of "
            f"{'these targets' if len(flagged) > 1 else 'this target'}")

#: Partners each fiducial's distances are compared with in :func:`distance_misfits` (all others
#: below this many + 1 fiducials; a fixed random choice above, so the check stays O(J)).
MISFIT_PARTNERS = 64


def distance_misfits(working: ArrayLike, destination: ArrayLike) -> NDArray[np.float64]:
    """Per fiducial, how far its distances to the other fiducials differ between the two frames:
    the lower median over its partners j of | ||x_k - x_j|| - ||y_k - y_j|| | (unit of the
    points). The rigid-body condition (paper eq. 1) says 0 up to noise and bias; a fiducial with a
    mistyped coordinate or measured at the wrong hole differs from nearly all its partners, and
    the lower median keeps a sound fiducial's value small even when up to half its partners are
    such blunders. Needs no registration, so a blunder cannot hide by pulling the fit.

    Partners: every other fiducial up to :data:`MISFIT_PARTNERS`; above, that many chosen at
    random (a fixed seed: the same points give the same values).
    """
    x, y = as_point_pairs(working, destination)
    j = len(x)
    if j < 2:
        return np.zeros(j)
    if j - 1 <= MISFIT_PARTNERS:
        partners = np.array([[i for i in range(j) if i != k] for k in range(j)], dtype=np.intp)
    else:
        rng = np.random.default_rng(j)
        partners = rng.integers(0, j - 1, size=(j, MISFIT_PARTNERS))
        partners += partners >= np.arange(j)[:, None]          # never the fiducial itself
    mismatch = np.abs(np.linalg.norm(x[:, None, :] - x[partners], axis=2)
                      - np.linalg.norm(y[:, None, :] - y[partners], axis=2))
    mismatch.sort(axis=1)
    return mismatch[:, (mismatch.shape[1] - 1) // 2]


def gross_misfits(working: ArrayLike, destination: ArrayLike, floor: float,
                  factor: float = BLUNDER_FACTOR) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """``(flagged, misfit)``: the indices of the fiducials whose :func:`distance_misfits`
    value is more than ``factor`` times the median of all fiducials' and more than ``floor``
    (unit of the points), largest first, and every fiducial's value; none flagged with fewer
    than :data:`BLUNDER_MIN_FIDUCIALS` fiducials or a median of 0. The relative test keeps a
    cell in another unit than ``floor`` from being flagged whole: where every fiducial differs
    alike, none stands out."""
    misfit = distance_misfits(working, destination)
    median = float(np.median(misfit)) if len(misfit) else 0.0
    if len(misfit) < BLUNDER_MIN_FIDUCIALS or not median > 0:
        return np.zeros(0, dtype=np.intp), misfit
    flagged = np.flatnonzero((misfit > factor * median) & (misfit > floor))
    return flagged[np.argsort(-misfit[flagged], kind="stable")], misfit


def describe_misfits(ids: Sequence[str], misfit: NDArray[np.float64], flagged: Sequence[int],
                     unit: str) -> str:
    """``fiducial 'h7' (its distances to the other fiducials differ between the frames by
    1e+07 m in median; the fiducials' median 0.0005 m)``: the flagged fiducials of
    :func:`gross_misfits` (at most 6 named) with their :func:`distance_misfits` values."""
    flagged = list(flagged)
    named = ", ".join(f"{ids[k]!r} ({misfit[k]:.4g} {unit})" for k in flagged[:6])
    more = f" and {len(flagged) - 6} more" if len(flagged) > 6 else ""
    return (f"fiducial{'s' if len(flagged) > 1 else ''} {named}{more}: distances to the other "
            f"fiducials differ between the frames by that much (median; the fiducials' median "
            f"{float(np.median(misfit)):.4g} {unit})")
