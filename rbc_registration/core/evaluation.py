"""Evaluation of a model on targets with known truth (paper eq. 3) and leave-one-out."""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .constants import FOLD_KINDS, UNCORRECTED
from .crossval import FoldScheme, cross_validate
from .model import RbcModel
from .validation import as_point_pairs


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
    reusable = (cv.scheme.kind == FOLD_KINDS[0] and cfg.uncorrected_subset is None
                and cfg.corrected_subset is None)
    if not (reusable and UNCORRECTED in cv.errors and method in cv.errors):
        cv = cross_validate(model.working, model.destination, (UNCORRECTED, method),
                            restoration=cfg.restoration, steps=cfg.steps,
                            kriging=model.interpolators.get("kriging"),
                            scheme=FoldScheme(FOLD_KINDS[0], len(model.working)))
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
