"""Restoration of the rigid-body condition (RBC) among fiducials: paper eq. 4, NISTIR 8180.

Corrections eps_j to the working-frame fiducials X_j are sought so that every pairwise distance of
the corrected points X_j - eps_j equals the destination-frame distance ||Y_i - Y_j|| (eq. 4).

``iterative`` (the paper's procedure): each step is a minimum-norm Gauss-Newton step on the
squared-distance equations linearised at the current points,

    2 D_ij . (eps_i - eps_j) = ||D_ij||^2 - ||E_ij||^2,   D_ij = X_i - X_j, E_ij = Y_i - Y_j.

The step and its solvers are :mod:`.gauss_newton`: the normal equations assembled from the
pair blocks, or applied matrix-free by conjugate gradients, with the rigid motions removed.

``closed-form``: the exact minimum-norm solution, eps = X - R^T (Y - t) with (R, t) the
least-squares rigid fit: the residuals of the fit mapped back into the working frame. The two agree
to second order in the bias.
"""

from __future__ import annotations

import math
from dataclasses import InitVar, dataclass, field
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import RegistrationError
from ..constants import RESTORATIONS as METHODS
from .gauss_newton import DIRECT_MAX_FIDUCIALS, gauss_newton_step
from .mismatch import sigma_l_stages
from .registration import rigid_fit
from ..validation import as_point_pairs, check_spread, rounding

#: An iterative step that moves a fiducial farther than this many times the rigid fit's largest
#: residual has diverged (:func:`restore_rigid_body`).
DIVERGED_FACTOR = 100.0


@dataclass(frozen=True, eq=False)
class RestorationResult:
    """Outcome of an RBC restoration (same unit as the input points). Immutable.

    sigma_L (eq. 7) of a stage is an O(J^2) pass, so it is computed only when asked for and then
    kept: :attr:`sigma_l0` alone (what rho needs) or :attr:`sigma_l` for every stage (the stages
    still missing are computed together, in one pass). Concurrent first reads from several threads
    are safe; at worst a value is computed twice.

    :ivar corrections: eps, shape (J, d): corrected fiducials are ``working - corrections``.
    :ivar step_corrections: the corrections of each step (eps', eps'', ...); one for closed-form.
    :ivar method: ``"iterative"`` or ``"closed-form"``.
    :ivar working: the working-frame fiducials X the restoration started from, (J, d).
    :ivar destination: the destination-frame fiducials Y, (J, d).
    """

    corrections: NDArray[np.float64]
    step_corrections: tuple[NDArray[np.float64], ...]
    method: str
    working: NDArray[np.float64] = field(repr=False)
    destination: NDArray[np.float64] = field(repr=False)
    compute_sigma_l: InitVar[bool] = True
    #: sigma_L per stage once computed (None: not yet); NaN throughout when switched off.
    _sigma: list = field(init=False, repr=False)

    def __post_init__(self, compute_sigma_l: bool) -> None:
        n = len(self.step_corrections) + 1
        object.__setattr__(self, "_sigma", [None if compute_sigma_l else math.nan] * n)

    def corrected(self, working: Optional[ArrayLike] = None) -> NDArray[np.float64]:
        """The corrected fiducials ``working - corrections`` (default: :attr:`working`)."""
        x = self.working if working is None else np.asarray(working, dtype=np.float64)
        return x - self.corrections

    def stages(self, working: Optional[ArrayLike] = None) -> list[NDArray[np.float64]]:
        """The fiducials before any step and after each step (for sigma_L and histograms of L):
        ``working`` (default :attr:`working`) minus the sum of the steps so far."""
        x = self.working if working is None else np.asarray(working, dtype=np.float64)
        out = [x]
        total = np.zeros_like(x)
        for eps in self.step_corrections:
            total = total + eps
            out.append(x - total)
        return out

    def _sigma_of(self, wanted: Sequence[int]) -> None:
        missing = [k for k in wanted if self._sigma[k] is None]
        if missing:
            stages = self.stages()
            values = sigma_l_stages([stages[k] for k in missing], self.destination)
            for k, v in zip(missing, values):
                self._sigma[k] = v              # one list item: atomic, so safe across threads

    @property
    def sigma_l0(self) -> float:
        """sigma_L before any step (eq. 7): the mismatch rho compares with sigma."""
        self._sigma_of([0])
        return self._sigma[0]

    @property
    def sigma_l(self) -> tuple[float, ...]:
        """sigma_L (eq. 7) before any step and after each step: (sigma_L0, sigma_L1, ...);
        NaN when switched off (``compute_sigma_l=False``)."""
        self._sigma_of(range(len(self._sigma)))
        return tuple(self._sigma)

    @property
    def sigma_l_cached(self) -> tuple[float, ...]:
        """The sigma_L values computed so far, NaN for the others; never computes (cheap)."""
        return tuple(math.nan if v is None else v for v in self._sigma)


def closed_form_corrections(working: ArrayLike, destination: ArrayLike) -> NDArray[np.float64]:
    """The exact minimum-norm corrections: residuals of the least-squares rigid fit, mapped back
    into the working frame, eps = X - R^T (Y - t)."""
    x, y = as_point_pairs(working, destination)
    return x - rigid_fit(x, y).inverse_apply(y)


def restore_rigid_body(working: ArrayLike, destination: ArrayLike, method: str = "iterative",
                       steps: int = 2, solver: str = "auto",
                       compute_sigma_l: bool = True) -> RestorationResult:
    """Compute corrections eps restoring the rigid-body condition among the fiducials (eq. 4).

    :param working: fiducials in the working frame X, shape (J, d), d = 2 or 3.
    :param destination: the same fiducials in the destination frame Y, shape (J, d).
    :param method: ``"iterative"`` (the paper's Gauss-Newton steps) or ``"closed-form"``.
    :param steps: number of iterative steps (the paper uses 2); ignored by closed-form.
    :param solver: linear solver of each iterative step, see :func:`gauss_newton_step`.
    :param compute_sigma_l: when False, sigma_L is never computed and reads as NaN; by default
        each value is computed on first access (:class:`RestorationResult`).
    :return: :class:`RestorationResult`.
    :raises ValueError: on bad input, a degenerate configuration or an unknown method.
    """
    x, y = as_point_pairs(working, destination)
    d = x.shape[1]
    if method not in METHODS:
        raise ValueError(f"restoration method must be one of {METHODS}, got {method!r}")
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    if len(x) < d + 1:
        raise ValueError(f"restoring the rigid-body condition in {d}D needs at least {d + 1} "
                         f"fiducials, got {len(x)}")
    check_spread(x, "working points")
    check_spread(y, "destination points")
    if method == "closed-form":
        eps = closed_form_corrections(x, y)
        step_eps = [eps]
    else:
        # A step moves a fiducial about as far as the rigid fit's residuals (at most 1.4 x the
        # largest over 430 cells: A/B/RA, random, thin). On collinear 2D fiducials CG's first
        # step reported success with components off the minimum-norm one, and the second then
        # moved a fiducial 172 mm against 0.05 mm residuals (sigma_L 0.04 -> 45 mm): then the
        # steps are taken again with the direct solver (the exact minimum-norm steps), and
        # refused only if those diverge too.
        limit = DIVERGED_FACTOR * max(float(np.abs(x - rigid_fit(x, y).inverse_apply(y)).max()),
                                      rounding(x, y))
        try:
            eps, step_eps = _iterate(x, y, int(steps), solver, limit)
        except _Diverged:
            if solver != "auto" or len(x) > DIRECT_MAX_FIDUCIALS:
                raise ValueError(_diverged_text(limit)) from None
            try:
                eps, step_eps = _iterate(x, y, int(steps), "direct", limit)
            except _Diverged:
                raise ValueError(_diverged_text(limit)) from None
    return RestorationResult(eps, tuple(step_eps), method, x, y, compute_sigma_l)


class _Diverged(RegistrationError):
    """An iterative step moved a fiducial farther than the limit."""


def _iterate(x: NDArray[np.float64], y: NDArray[np.float64], steps: int, solver: str,
             limit: float) -> tuple[NDArray[np.float64], list[NDArray[np.float64]]]:
    """The corrections and the steps of ``steps`` Gauss-Newton steps. :raises _Diverged:"""
    current = x
    eps = np.zeros_like(x)
    step_eps = []
    for _ in range(steps):
        step = gauss_newton_step(current, y, solver)
        if not float(np.abs(step).max()) <= limit:
            raise _Diverged()
        step_eps.append(step)
        eps = eps + step
        current = x - eps
    return eps, step_eps


def _diverged_text(limit: float) -> str:
    return (f"the iterative restoration diverged: a step moved a fiducial more than "
            f"{DIVERGED_FACTOR:g} x the rigid fit's largest residual "
            f"({limit / DIVERGED_FACTOR:.3g}) with every solver: the fiducial geometry is "
            f"degenerate; use the closed-form restoration or spread the fiducials")
