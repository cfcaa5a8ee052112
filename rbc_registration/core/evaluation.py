"""Evaluation of a model on targets with known truth (paper eq. 3) and leave-one-out."""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .model import RbcModel, build_model
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
    """Accuracy estimate without targets: each fiducial in turn is left out, the model rebuilt
    from the others (same config; kriging reuses the full model's hyper-parameters) and the
    left-out fiducial is evaluated as a target.

    Subsets in the config are dropped (indices would shift); all remaining fiducials are used.

    :raises ValueError: with fewer than d + 2 fiducials (each rebuild needs d + 1).
    """
    x, y = model.working, model.destination
    j = len(x)
    d = model.config.dimension
    if j < d + 2:
        raise ValueError(f"leave-one-out in {d}D needs at least {d + 2} fiducials (each rebuild "
                         f"needs {d + 1}), got {j}")
    cfg = replace(model.config, uncorrected_subset=None, corrected_subset=None)
    if cfg.sigma is None and model.sigma:
        cfg = replace(cfg, sigma=model.sigma)
    tre_u = np.empty(j)
    tre_c = np.empty(j)
    for k in range(j):
        keep = np.arange(j) != k
        sub = build_model(x[keep], y[keep], cfg,
                          repeat_statistics=model.repeat_stats.subset(keep),
                          kriging_hyperparameters=model.kriging_hyperparameters)
        err = target_errors(sub, x[k:k + 1], y[k:k + 1])
        tre_u[k], tre_c[k] = err.tre_u[0], err.tre_c[0]
    return TargetErrors(tre_u, tre_c, tre_c - tre_u)
