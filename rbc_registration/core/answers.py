"""What an :class:`~.model.RbcModel` answers for targets (its ``correct`` and ``answer``): the
records, and one call's evaluation.

A call validates its targets once, locates them once in the fiducials' hull (the interpolators of a
model share one :class:`~.interpolation.HullTest`, so the paper interpolation and kriging use the
same simplices), evaluates each interpolation it needs once and maps each point into the
destination frame once. A single target (``~/correct_target``) thus costs one hull location, not
one per interpolator, with the same numbers as the interpolators' own ``__call__``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Optional

import numpy as np
from numpy.typing import NDArray

from .constants import UNCORRECTED
from .interpolation.paper import HullTest, Interpolated

if TYPE_CHECKING:                       # model imports this module
    from .model import RbcModel

__all__ = ["TargetAnswer", "TargetCorrections", "TargetEvaluation"]


class TargetCorrections(NamedTuple):
    """Answers for K targets (unit of the points).

    :ivar uncorrected: R_u T + tau_u, destination frame (K, d).
    :ivar corrected: R_c (T - eps(T)) + tau_c with the configured interpolation, destination
        frame (K, d) (eq. 6).
    :ivar correction: eps(T) of the configured interpolation, working frame (K, d) (eq. 5).
    :ivar inside_hull: (K,) target inside the fiducials' convex hull.
    :ivar expected_error: (K,) 1-sigma uncertainty of eps(T) per axis (kriging); NaN otherwise.
    :ivar destination: the point to use per the decision (``RbcModel.decision.method``),
        destination frame (K, d).
    :ivar expected_tre: (K,) expected distance of ``destination`` from the true point (the
        chosen method's cross-validated median error, scaled per target; ``ErrorModel``).
    :ivar tre_bound: (K,) the distance ``destination`` stays within with 95 % probability
        (NaN, like ``expected_tre``, with fewer than d + 2 fiducials: nothing to cross-validate).

    The last three are None only in records built by hand with the first five fields.
    """

    uncorrected: NDArray[np.float64]
    corrected: NDArray[np.float64]
    correction: NDArray[np.float64]
    inside_hull: NDArray[np.bool_]
    expected_error: NDArray[np.float64]
    # Defaults keep records built by hand with the first five fields valid; correct() fills all.
    destination: Optional[NDArray[np.float64]] = None
    expected_tre: Optional[NDArray[np.float64]] = None
    tre_bound: Optional[NDArray[np.float64]] = None


class TargetAnswer(NamedTuple):
    """What a robot needs for K targets (unit of the points): :meth:`RbcModel.answer`.

    :ivar destination: the point to use per the decision, destination frame (K, d).
    :ivar expected_tre: (K,) its expected distance from the true point.
    :ivar tre_bound: (K,) the distance it stays within with 95 % probability (NaN with fewer
        than d + 2 fiducials: nothing to cross-validate).
    :ivar inside_hull: (K,) target inside the fiducials' convex hull.
    :ivar method: the decision's method (one of ``CANDIDATES``).
    """

    destination: NDArray[np.float64]
    expected_tre: NDArray[np.float64]
    tre_bound: NDArray[np.float64]
    inside_hull: NDArray[np.bool_]
    method: str


class TargetEvaluation:
    """One call's targets and what has been computed for them (module docstring).

    :param model: the model answering.
    :param targets: (K, d) working-frame targets, already validated
        (:func:`.validation.as_points` with the model's dimension): nothing here checks them.
    """

    __slots__ = ("model", "targets", "_located", "_interpolated", "_registered")

    def __init__(self, model: RbcModel, targets: NDArray[np.float64]) -> None:
        self.model, self.targets = model, targets
        self._located: list[tuple[HullTest, NDArray[np.intp]]] = []
        self._interpolated: dict[str, Interpolated] = {}
        self._registered: dict[str, NDArray[np.float64]] = {}

    def simplices(self, hull: HullTest) -> NDArray[np.intp]:
        """``hull.simplices`` of the targets, located once per hull."""
        for known, simplex in self._located:
            if known is hull:
                return simplex
        simplex = hull.simplices(self.targets)
        self._located.append((hull, simplex))
        return simplex

    def interpolated(self, method: str) -> Interpolated:
        """The interpolation ``method`` (``paper`` or ``kriging``) at the targets, once."""
        found = self._interpolated.get(method)
        if found is None:
            interpolator = self.model.interpolators[method]
            found = interpolator._at(self.targets, self.simplices(interpolator.hull))
            self._interpolated[method] = found
        return found

    def registered(self, method: str) -> NDArray[np.float64]:
        """The targets in the destination frame by ``method``: R_u T + tau_u (``uncorrected``)
        or R_c (T - eps(T)) + tau_c with that interpolation's eps (eq. 6), once."""
        point = self._registered.get(method)
        if point is None:
            m = self.model
            point = (m.uncorrected.apply(self.targets) if method == UNCORRECTED else
                     m.corrected.apply(self.targets - self.interpolated(method).correction))
            self._registered[method] = point
        return point

    def answer(self) -> TargetAnswer:
        """:meth:`RbcModel.answer`: only the decision's method is evaluated (and kriging when the
        expected error is scaled by its posterior)."""
        m = self.model
        method = m.decision.method
        destination = self.registered(method)
        # the interpolators share one hull, located once per call
        inside = self.simplices(m.interpolator.hull) >= 0
        errors = m.decision.error_model
        # beyond every fiducial the registration's rotation error grows with the distance: the
        # held-out fiducials calibrate the bound only as far out as they are
        scale = m.fit_geometry.beyond(self.targets)
        if errors.scaled:
            kriging = m.interpolators["kriging"]
            scale *= np.hypot(self.interpolated("kriging").expected_error, kriging.noise_axis_std)
        expected, bound = errors.at(scale)
        return TargetAnswer(destination, expected, bound, inside, method)

    def corrections(self) -> TargetCorrections:
        """:meth:`RbcModel.correct`: the configured interpolation's correction and the decision's
        :meth:`answer` together."""
        configured = self.model.config.interpolation
        interp = self.interpolated(configured)
        ans = self.answer()
        uncorrected, corrected = self.registered(UNCORRECTED), self.registered(configured)
        destination = ans.destination
        if destination is uncorrected or destination is corrected:    # no aliased fields
            destination = destination.copy()
        return TargetCorrections(uncorrected, corrected, interp.correction, interp.inside_hull,
                                 interp.expected_error, destination, ans.expected_tre,
                                 ans.tre_bound)
