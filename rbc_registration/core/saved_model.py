"""A model that answers targets from the parts a saved calibration holds (docs/CALIBRATION.md,
``answers``): the fiducials in the working frame with their corrections ε (eq. 4) and repeat
counts, both registrations, the configured interpolation, the decision's method with its error
model, σ and kriging's hyper-parameters.

Its answers are those of the :class:`~.model.RbcModel` the parts were taken from: each
interpolation is rebuilt from the same numbers (kriging with the saved hyper-parameters, so
nothing is fitted), the registrations are the saved ones, and :class:`~.answers.TargetEvaluation`
evaluates them exactly as for the live model (eq. 5-6; the expected TRE and its bound from the
error model and the fit geometry of the same fiducials). Nothing is cross-validated again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Mapping, NamedTuple, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .answers import TargetAnswer, TargetCorrections, TargetEvaluation
from .config import ModelConfig
from .constants import CANDIDATES, INTERPOLATIONS, UNCORRECTED
from .decision.choice import ErrorModel
from .interpolation.paper import PaperInterpolator
from .interpolation.kriging import KrigingHyperparameters, KrigingInterpolator
from .model import Interpolator, RbcModel
from .rigid.registration import Registration
from .planning.rigid_tre import FitGeometry
from .validation import as_point_pairs, as_points

__all__ = ["ModelParts", "SavedDecision", "SavedModel", "needed_interpolations", "parts_of",
           "saved_model"]


class ModelParts(NamedTuple):
    """What a model needs to answer targets (unit of the points, working frame).

    :ivar ids: fiducial ids (J,).
    :ivar working: fiducial means X (J, d).
    :ivar corrections: ε at the fiducials (J, d).
    :ivar counts: measurements averaged into each fiducial (J,), kriging's n_j.
    :ivar uncorrected: {R_u, τ_u}.
    :ivar corrected: {R_c, τ_c}.
    :ivar interpolation: the configured interpolation (``corrected``, ``correction``).
    :ivar method: the decision's method (``destination``): one of ``CANDIDATES``.
    :ivar error_model: the decision's :class:`~.decision.ErrorModel` (of ``method``).
    :ivar sigma: σ of one measurement (all axes) or None.
    :ivar kriging: the kriging hyper-parameters, when kriging was built; None otherwise.
    """

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    corrections: NDArray[np.float64]
    counts: NDArray[np.int64]
    uncorrected: Registration
    corrected: Registration
    interpolation: str
    method: str
    error_model: ErrorModel
    sigma: Optional[float]
    kriging: Optional[KrigingHyperparameters]


def parts_of(model: RbcModel) -> ModelParts:
    """The :class:`ModelParts` of a built model."""
    return ModelParts(tuple(model.ids), model.working, model.corrections,
                      np.asarray(model.counts, dtype=np.int64), model.uncorrected,
                      model.corrected, model.config.interpolation, model.decision.method,
                      model.decision.error_model, model.sigma, model.kriging_hyperparameters)


def needed_interpolations(interpolation: str, method: str, scaled: bool) -> tuple[str, ...]:
    """The interpolations answers evaluate: the configured one (``corrected``), the decision's
    method when it corrects (``destination``), and kriging when the error model is scaled by
    its predictive standard deviation; in the order of ``INTERPOLATIONS``."""
    wanted = {interpolation, method, "kriging" if scaled else UNCORRECTED}
    return tuple(m for m in INTERPOLATIONS if m in wanted)


@dataclass(frozen=True)
class SavedDecision:
    """The part of a decision the answers read: ``method``, ``apply`` and the error model."""

    method: str
    apply: bool
    error_model: ErrorModel


@dataclass(frozen=True)
class SavedModel:
    """Answers targets as :class:`~.model.RbcModel` does (build it with :func:`saved_model`):
    :meth:`correct` and :meth:`answer` take (K, d) working-frame points."""

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    config: ModelConfig
    uncorrected: Registration
    corrected: Registration
    interpolators: Mapping[str, Interpolator] = field(repr=False)
    decision: SavedDecision

    @property
    def interpolator(self) -> Interpolator:
        """The configured interpolation's interpolator."""
        return self.interpolators[self.config.interpolation]

    @cached_property
    def fit_geometry(self) -> FitGeometry:
        """:attr:`RbcModel.fit_geometry` of the same fiducials."""
        return FitGeometry(self.working)

    def answer(self, targets: ArrayLike) -> TargetAnswer:
        """:meth:`RbcModel.answer`."""
        t = as_points(targets, "targets", self.config.dimension)
        return TargetEvaluation(self, t).answer()   # type: ignore[arg-type]

    def correct(self, targets: ArrayLike) -> TargetCorrections:
        """:meth:`RbcModel.correct`."""
        t = as_points(targets, "targets", self.config.dimension)
        return TargetEvaluation(self, t).corrections()   # type: ignore[arg-type]


def saved_model(parts: ModelParts) -> SavedModel:
    """The model answering from ``parts``.

    :raises ValueError: naming what is wrong: shapes that do not agree, a method or
        interpolation that is not one, kriging needed without its hyper-parameters, or what
        an interpolator refuses (e.g. coplanar fiducials for the paper's interpolation).
    """
    x, eps = as_point_pairs(parts.working, parts.corrections, min_count=1)
    j, d = x.shape
    counts = np.asarray(parts.counts, dtype=np.int64)
    if len(parts.ids) != j or counts.shape != (j,):
        raise ValueError(f"{j} fiducials, but {len(parts.ids)} ids and {counts.size} repeat "
                         f"counts")
    if parts.interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got "
                         f"{parts.interpolation!r}")
    if parts.method not in CANDIDATES:
        raise ValueError(f"method must be one of {', '.join(CANDIDATES)}, got {parts.method!r}")
    for name, reg in (("uncorrected", parts.uncorrected), ("corrected", parts.corrected)):
        if np.shape(reg.rotation) != (d, d) or np.shape(reg.translation) != (d,):
            raise ValueError(f"{name}: needs a {d} x {d} rotation and {d} translation for "
                             f"{d}D fiducials")
    needed = needed_interpolations(parts.interpolation, parts.method, parts.error_model.scaled)
    if "kriging" in needed and parts.kriging is None:
        raise ValueError("kriging is needed (interpolation, method or a scaled error model) but "
                         "its hyper-parameters are missing")
    interpolators: dict[str, Interpolator] = {}
    hull = None                 # one hull shared, as build_model does
    for method in needed:
        if method == "paper":
            interpolators[method] = PaperInterpolator(x, eps, hull=hull)
        else:
            interpolators[method] = KrigingInterpolator(x, eps, parts.sigma, counts,
                                                        parts.kriging, hull=hull)
        hull = interpolators[method].hull
    config = ModelConfig(dimension=d, interpolation=parts.interpolation)
    decision = SavedDecision(parts.method, parts.method != UNCORRECTED, parts.error_model)
    return SavedModel(tuple(parts.ids), x, config, parts.uncorrected, parts.corrected,
                      interpolators, decision)
