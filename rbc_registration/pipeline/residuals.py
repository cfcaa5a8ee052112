"""Per-fiducial residuals of the served model (``~/get_fiducials``): what an integrator looks at
to spot an outlier fiducial to disable. No rclpy.

Per fiducial: the length of its correction |eps_j| (eq. 4), its held-out error from the
decision's cross-validation for the chosen method and for the uncorrected registration, and its
residual in the uncorrected fit (eq. 2). A fiducial measured wrongly (a misread hole, a bumped
target) stands out with the largest values: the rigid-body condition is restored mostly by
moving it, and a model built without it predicts it worst. Units: those of the points (metres in
ROS).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Sequence

import numpy as np

from ..core.constants import UNCORRECTED
from ..core.model import RbcModel


class FiducialSummary(NamedTuple):
    """What the accumulator holds of one fiducial: id, measurements, enabled, the means of its
    working- and destination-frame measurements (d coordinates each)."""

    fiducial_id: str
    n_measurements: int
    enabled: bool
    working_mean: tuple[float, ...]
    destination_mean: tuple[float, ...]


class FiducialResidual(NamedTuple):
    """One fiducial's residuals (NaN where the model does not hold it, or where no
    cross-validation was possible).

    :ivar summary: the :class:`FiducialSummary`.
    :ivar correction_norm: |eps_j| (eq. 4), working frame.
    :ivar cv_error: held-out error with the decision's method.
    :ivar cv_error_uncorrected: held-out error with the uncorrected registration.
    :ivar residual_uncorrected: |R_u X_j + tau_u - Y_j| (eq. 2).
    """

    summary: FiducialSummary
    correction_norm: float
    cv_error: float
    cv_error_uncorrected: float
    residual_uncorrected: float


def fiducial_residuals(model: Optional[RbcModel], fiducials: Sequence[FiducialSummary]
                       ) -> tuple[str, list[FiducialResidual]]:
    """The residuals of ``fiducials`` in ``model`` (None: every model value NaN).

    :return: (the decision's method, or empty without a model; one record per fiducial in the
        given order). A fiducial the model was not built from (disabled, or measured after the
        last rebuild) gets NaN model values.
    """
    nan = math.nan
    if model is None:
        return "", [FiducialResidual(f, nan, nan, nan, nan) for f in fiducials]
    index = {fid: k for k, fid in enumerate(model.ids)}
    norms = np.linalg.norm(model.corrections, axis=1)
    residual = np.linalg.norm(model.uncorrected.apply(model.working) - model.destination, axis=1)
    decision = model.decision
    errors = decision.cross_validation.errors
    nans = np.full(len(model.ids), nan)
    chosen = errors.get(decision.method, nans)
    uncorrected = errors.get(UNCORRECTED, nans)
    out = []
    for f in fiducials:
        k = index.get(f.fiducial_id) if f.enabled else None
        if k is None:
            out.append(FiducialResidual(f, nan, nan, nan, nan))
        else:
            out.append(FiducialResidual(f, float(norms[k]), float(chosen[k]),
                                        float(uncorrected[k]), float(residual[k])))
    return decision.method, out
