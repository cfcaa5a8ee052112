"""Evaluation of a model on targets with known truth (paper eq. 3) and leave-one-out."""

from __future__ import annotations

from typing import NamedTuple

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
