"""Whether the planner's error model can be trusted, and its calibration: the error model's
expected held-out errors against the decision's cross-validated ones.

The decision cross-validates kriging on the fiducials (:mod:`.crossval`): each fold (a fiducial,
or a group held out whole) is predicted from the others, and its error in the destination frame
is measured. The error model (:mod:`.expected_error`) predicts the same quantity before anything
is measured: for the fiducials S of a fold, from the others,

- the bias and the held-out points' own noise: per noise axis a, the covariance of a measurement
  at S given the others, (P_SS)^-1 with P = (s^2 K + diag(lambda_a / n_j))^-1 (the GP's
  precision; the fold removed exactly, as :meth:`.kriging.KrigingInterpolator.held_out` does);
- the rigid fit without S: tr(D_k G_S^-1 S_S G_S^-1 D_k^T), G_S and S_S the sums of
  :mod:`.rigid_tre` over the other fiducials.

``ratio`` = (median cross-validated error) / (pooled expected median of the same held-out
fiducials). It is the calibration of the plan's expected errors (``ExpectedErrorModel.
calibration``): the plan's ``expected_now`` and ``expected_with_all`` are the model's, times it.

The error model is **trustworthy** when at least :data:`TRUST_MIN_UNITS` units were held out and
the ratio is within :data:`TRUST_FACTOR` of 1 either way: then the model's split of the error
into bias and noise predicts the errors it had not seen, and a single factor carries it over to
more fiducials. Measured (benchmarks/RESULTS.md, "Planner"): on the A-like cell with sigma
unknown, 10 fiducials put the bias into the noise (fitted noise 10-20x the true one), the
expected error with every hole stays near today's, and the ratio still looks fine at 10: hence
the count as well as the factor.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from scipy.spatial.distance import cdist

from ..interpolation.blocked_linalg import inverse_from_cholesky
from ..decision.crossval import fold_groups
from .expected_error import JITTER, ExpectedErrorModel, fiducial_covariance, pooled_median
from ..interpolation.gp_fit import matern52
from ..decision.groups import group_labels
from ..model import RbcModel
from .rigid_tre import RigidFrame, _inverse_normal

#: The expected and the cross-validated held-out medians agree within this factor (either way)
#: for the error model to be trusted.
TRUST_FACTOR = 1.25
#: Fewest held-out units (fiducials, or groups held out whole) for the check to count: the
#: median of fewer held-out errors is too uncertain to show the model right.
TRUST_MIN_UNITS = 15
#: Most fiducials the check is computed for (one factorisation of J x J per noise axis).
CHECK_MAX_FIDUCIALS = 2000
#: The candidate whose held-out errors the plan is checked against: the plans assume the
#: corrected registration with the kriging correction (:func:`.model_planner.error_model_from`).
CHECKED_METHOD = "kriging"


class ModelCheck(NamedTuple):
    """The error model against the cross-validated held-out errors (unit of the points).

    :ivar available: whether the check could be made (else ``note`` says why; numbers NaN).
    :ivar units: held-out units (folds' members counted as one per group).
    :ivar expected_median: pooled median of the model's expected held-out errors (uncalibrated).
    :ivar cross_validated_median: median of the decision's held-out errors of kriging.
    :ivar ratio: cross_validated_median / expected_median, the calibration factor (1 when not
        available).
    :ivar trustworthy: at least :data:`TRUST_MIN_UNITS` units and the ratio within
        :data:`TRUST_FACTOR` of 1.
    :ivar note: why not available, or why not trustworthy ("" when trustworthy).
    """

    available: bool
    units: int
    expected_median: float
    cross_validated_median: float
    ratio: float
    trustworthy: bool
    note: str

    def to_dict(self) -> dict:
        """JSON-ready (NaN as None); ``factor`` and ``min_units`` are the rule's."""
        def num(v: float) -> Optional[float]:
            return float(v) if math.isfinite(v) else None

        return {"available": self.available, "units": self.units,
                "expected_held_out_median": num(self.expected_median),
                "cross_validated_median": num(self.cross_validated_median),
                "ratio": num(self.ratio), "factor": TRUST_FACTOR, "min_units": TRUST_MIN_UNITS,
                "trustworthy": self.trustworthy, "note": self.note}


def _unavailable(note: str, units: int = 0) -> ModelCheck:
    return ModelCheck(False, units, math.nan, math.nan, 1.0, False, note)


def expected_held_out(working: NDArray[np.float64], counts: NDArray[np.float64],
                      folds: list[NDArray[np.intp]], model: ExpectedErrorModel
                      ) -> NDArray[np.float64]:
    """(J,) expected squared error of each fiducial predicted from the fiducials outside its
    fold (module docstring), calibration not applied.

    :param working: (J, d) working-frame fiducials.
    :param counts: (J,) measurements averaged into each.
    :param folds: index sets held out together, covering every fiducial once.
    """
    x = np.asarray(working, dtype=np.float64)
    inv_n = 1.0 / np.asarray(counts, dtype=np.float64)
    s2 = model.signal_std ** 2
    lam = np.clip(np.linalg.eigvalsh(model.noise_covariance), 0.0, None)
    out = np.zeros(len(x))
    if model.corrected:
        k = s2 * matern52(cdist(x, x), model.length_scale)
        for lam_a in lam:
            chol = scipy.linalg.cholesky(k + np.diag(lam_a * inv_n + JITTER * s2), lower=True)
            p = inverse_from_cholesky(chol)
            for s in folds:
                out[s] += np.diag(np.linalg.inv(p[np.ix_(s, s)]))
    else:                      # the bias is error: its prior, plus the held-out point's noise
        out += model.dimension * s2 + float(lam.sum()) * inv_n
    frame = RigidFrame(x)
    dx = frame.design(x)
    gj = np.einsum("nai,naj->nij", dx, dx)
    sj = np.einsum("nai,nab,nbj->nij", dx, fiducial_covariance(model, inv_n), dx)
    g, s_all = gj.sum(axis=0), sj.sum(axis=0)
    for s in folds:
        g_inv = _inverse_normal(g - gj[s].sum(axis=0), "the fiducials outside a fold")
        theta = g_inv @ (s_all - sj[s].sum(axis=0)) @ g_inv
        out[s] += np.einsum("kai,ij,kaj->k", dx[s], theta, dx[s])
    return model.calibration ** 2 * out


def check_model(model: RbcModel, error_model: ExpectedErrorModel) -> ModelCheck:
    """:class:`ModelCheck` of ``error_model`` (the planning one of ``model``) against the
    decision's cross-validated held-out errors of kriging."""
    cv = model.decision.cross_validation
    errors = cv.errors.get(CHECKED_METHOD)
    if errors is None:
        why = cv.unavailable.get(CHECKED_METHOD, "the decision did not cross-validate it")
        return _unavailable(f"no cross-validated errors of {CHECKED_METHOD}: {why}")
    j = len(model.working)
    if j > CHECK_MAX_FIDUCIALS:
        return _unavailable(f"{j} fiducials, more than the check computes "
                            f"({CHECK_MAX_FIDUCIALS})", cv.n_units)
    folds = fold_groups(model.working, cv.scheme, model.destination,
                        group_labels(model.groups, j))
    try:
        expected = expected_held_out(model.working, model.counts, folds,
                                     _uncalibrated(error_model))
    except (ValueError, np.linalg.LinAlgError) as exc:
        return _unavailable(f"the expected held-out errors: {exc}", cv.n_units)
    exp_med = float(pooled_median(expected, error_model.dimension))
    act_med = float(np.median(errors))
    if not (exp_med > 0 and math.isfinite(act_med) and act_med > 0):
        return _unavailable("a held-out median of zero", cv.n_units)
    ratio = act_med / exp_med
    units = cv.n_units
    notes = []
    if units < TRUST_MIN_UNITS:
        notes.append(f"{units} held-out {'groups' if cv.units is not None else 'fiducials'}, "
                     f"fewer than the {TRUST_MIN_UNITS} that show the error model right")
    if not 1 / TRUST_FACTOR <= ratio <= TRUST_FACTOR:
        notes.append(f"the cross-validated held-out errors are {ratio:.3g} x what the error "
                     f"model expects, not within {TRUST_FACTOR:g} x")
    return ModelCheck(True, units, exp_med, act_med, ratio, not notes, "; ".join(notes))


def _uncalibrated(error_model: ExpectedErrorModel) -> ExpectedErrorModel:
    import dataclasses
    return dataclasses.replace(error_model, calibration=1.0)


def units_to_trust(check: ModelCheck) -> int:
    """How many more units (fiducials or groups) to measure before the count rule of the
    check can hold (0 when it holds)."""
    return max(0, TRUST_MIN_UNITS - check.units)
