"""How a model is built: :class:`ModelConfig` (re-exported by :mod:`.model`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from .constants import (INTERPOLATIONS, MAX_RESTORATION_STEPS, DecisionMode,
                        check_rho_thresholds)
from .decision.noise import point_sigma
from .rigid.restoration import METHODS
from .validation import MAX_ABS_COORDINATE


def _check_length(name: str, value: Optional[float]) -> None:
    if value is not None and (not isinstance(value, (int, float)) or not math.isfinite(value)
                              or value <= 0):
        raise ValueError(f"{name} must be a positive finite length or None, got {value!r}")
    if value is not None and value > MAX_ABS_COORDINATE:     # its square must stay finite
        raise ValueError(f"{name} must be at most {MAX_ABS_COORDINATE:g} (the coordinate "
                         f"limit), got {value!r}")


@dataclass(frozen=True)
class ModelConfig:
    """How a model is built. Lengths are in the unit of the points (metres in ROS).

    :ivar dimension: 2 (x, y as in the paper) or 3.
    :ivar restoration: ``"iterative"`` (the paper's Gauss-Newton steps) or ``"closed-form"``.
    :ivar steps: iterative steps (paper: 2).
    :ivar interpolation: ``"paper"`` (tetrahedron / 8 surrounding fiducials) or ``"kriging"``:
        what ``TargetCorrections.corrected`` uses, and what modes ``rho`` and ``on`` apply.
    :ivar sigma: known noise: RMS distance of one measurement from the true point, all axes
        (:mod:`.noise`); ``None``: from repeats, or ``sigma_axis``.
    :ivar sigma_axis: known noise per axis (sigma / sqrt(d)); give ``sigma`` or this, not both.
    :ivar decision: :class:`~.constants.DecisionMode` (or its string): ``cv`` (default,
        cross-validated, needs no sigma), ``rho`` (the paper's rule), ``on``, ``off``.
    :ivar rho_reject: rho below which correcting is not recommended (paper: 1).
    :ivar rho_apply: rho from which correcting is recommended (paper: 2.5).
    :ivar uncorrected_subset: indices of the fiducials the uncorrected registration is fitted to
        (the paper uses 5); ``None``: all.
    :ivar corrected_subset: indices for the corrected registration (the paper uses 3);
        ``None``: all.
    """

    dimension: int = 3
    restoration: str = "iterative"
    steps: int = 2
    interpolation: str = "paper"
    sigma: Optional[float] = None
    sigma_axis: Optional[float] = None
    decision: DecisionMode = DecisionMode.CV
    rho_reject: float = 1.0
    rho_apply: float = 2.5
    uncorrected_subset: Optional[tuple[int, ...]] = None
    corrected_subset: Optional[tuple[int, ...]] = None

    def __post_init__(self) -> None:
        if self.dimension not in (2, 3):
            raise ValueError(f"dimension must be 2 or 3, got {self.dimension!r}")
        if self.restoration not in METHODS:
            raise ValueError(f"restoration must be one of {METHODS}, got {self.restoration!r}")
        if not isinstance(self.steps, int) or isinstance(self.steps, bool) or self.steps < 1:
            raise ValueError(f"steps must be a positive integer, got {self.steps!r}")
        if self.steps > MAX_RESTORATION_STEPS:   # the node's restoration_steps range too
            raise ValueError(f"steps must be in 1..{MAX_RESTORATION_STEPS}, got {self.steps!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, "
                             f"got {self.interpolation!r}")
        _check_length("sigma", self.sigma)
        _check_length("sigma_axis", self.sigma_axis)
        if self.sigma is not None and self.sigma_axis is not None:
            raise ValueError(f"give sigma or sigma_axis, not both (got {self.sigma!r} and "
                             f"{self.sigma_axis!r})")
        try:
            object.__setattr__(self, "decision", DecisionMode(self.decision))
        except ValueError:
            raise ValueError(f"decision must be one of {[m.value for m in DecisionMode]}, "
                             f"got {self.decision!r}") from None
        for name in ("rho_reject", "rho_apply"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        check_rho_thresholds(self.rho_reject, self.rho_apply)

    @property
    def known_sigma(self) -> Optional[float]:
        """The given noise in the ``sigma`` convention (from ``sigma`` or ``sigma_axis``)."""
        return self.sigma if self.sigma is not None else point_sigma(self.sigma_axis,
                                                                      self.dimension)
