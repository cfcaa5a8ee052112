"""The model state the node serves and ``evaluate`` reports: an immutable record swapped
atomically, built from the enabled fiducials and the settings. No rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from ..core.measurements.accumulator import FiducialSet
from ..core.decision.evaluation import describe_misfits, gross_misfits
from ..core.interpolation.kriging import KrigingHyperparameters
from ..core.model import ModelConfig, RbcModel, build_model
from ..core.measurements.session_sums import AUTO_SESSION_PREFIX
from ..core.warnings import model_warnings
from .settings import Settings


@dataclass(frozen=True)
class ModelState:
    """What the node serves: the model (or ``None`` with the reason in ``error``), the fiducials
    and settings it was built from, and when (``stamp_ns``, node clock; 0 = never).

    ``warning``: what to check in a model that is served, one line, "" when nothing: a fiducial
    whose held-out error stands out (:func:`~rbc_registration.core.decision.evaluation.blunders`, a
    typo'd coordinate or a wrong hole; errors in metres), one point under two or more ids
    (:func:`~rbc_registration.core.repeats.twin_groups`), sessions moved or kept apart
    (:func:`session_warning`), fiducials that look grouped though no group was given
    (:func:`~rbc_registration.core.warnings.model_warnings`).
    """

    model: Optional[RbcModel]
    fiducials: Optional[FiducialSet]
    settings: Optional[Settings]
    error: str
    stamp_ns: int = 0
    warning: str = ""

    @property
    def n_measurements(self) -> int:
        """Accepted measurements included in this model state."""
        return self.fiducials.n_measurements if self.fiducials is not None else 0


EMPTY_STATE = ModelState(None, None, None, "no measurements yet")
#: Served from the first accepted (or restored) measurement until the first model is built.
BUILDING_STATE = ModelState(None, None, None, "the first model is being built from the accepted "
                                              "measurements: retry in a moment")


def first_build_failed(reason: str) -> ModelState:
    """Served when the first build failed (e.g. its process was killed): no model, the
    measurements kept, the reason said where a client looks (``~/status``, every answer)."""
    return ModelState(None, None, None, f"the first model could not be built ({reason}); the "
                                        "measurements are kept: call ~/recompute to retry")


def model_config(settings: Settings) -> ModelConfig:
    """The core model configuration for the node's parameters (``sigma`` / ``sigma_axis`` 0
    means unknown)."""
    return ModelConfig(dimension=settings.dimension, restoration=settings.restoration,
                       steps=settings.restoration_steps, interpolation=settings.interpolation,
                       sigma=settings.sigma if settings.sigma > 0 else None,
                       sigma_axis=settings.sigma_axis if settings.sigma_axis > 0 else None,
                       decision=settings.decision, rho_reject=settings.rho_reject,
                       rho_apply=settings.rho_apply)


def warm_start(state: ModelState) -> Optional[KrigingHyperparameters]:
    """The kriging hyper-parameters of ``state``'s model (the warm start of the next build),
    None without a model or kriging."""
    return state.model.kriging_hyperparameters if state.model is not None else None


def build_state(fiducials: FiducialSet, settings: Settings, stamp_ns: int,
                previous: Optional[KrigingHyperparameters] = None) -> ModelState:
    """Build the model for ``fiducials``; a bad or degenerate set gives ``model=None`` and the
    core's error message (never raises ValueError).

    :param previous: kriging hyper-parameters to start the fit from (:func:`warm_start` of the
        model served so far): a rebuild after a few new fiducials refines instead of searching.
    """
    n = len(fiducials.ids)
    if n < settings.min_fiducials:
        return ModelState(None, fiducials, settings,
                          f"{n} enabled fiducials, need min_fiducials={settings.min_fiducials}"
                          + _kept_apart_hint(fiducials), stamp_ns)
    left_out = ""
    try:
        model = _build(fiducials, settings, previous)
    except ValueError as exc:
        flagged, misfit = (gross_misfits(fiducials.working, fiducials.destination,
                                         settings.outlier_distance)
                           if settings.outlier_distance > 0 else (np.zeros(0, np.intp), None))
        if not len(flagged):
            return ModelState(None, fiducials, settings, f"model not built: {exc}", stamp_ns)
        named = describe_misfits(fiducials.ids, misfit, flagged, "m")
        kept = fiducials.without(flagged)
        if len(kept.ids) < settings.min_fiducials:
            return ModelState(None, fiducials, settings,
                              f"model not built: {exc}; likely through {named}", stamp_ns)
        try:
            model = _build(kept, settings, previous)
        except ValueError:
            return ModelState(None, fiducials, settings,
                              f"model not built: {exc}; likely through {named}", stamp_ns)
        fiducials = kept
        left_out = (f"{named}: left out of the model, which could not be built with "
                    f"{'them' if len(flagged) > 1 else 'it'}: a typo or a wrong hole? check "
                    f"the points, or disable the fiducial")
    # The status and the snapshot report every sigma_L (computed on first access, O(J^2)): here,
    # in the recompute thread, rather than on the executor at the first status.
    _ = model.restoration.sigma_l
    warning = "; ".join(filter(None, (left_out, session_warning(fiducials),
                                      *model_warnings(model, "m",
                                                      fiducials.first_stamps or None))))
    return ModelState(model, fiducials, settings, "", stamp_ns, warning)


def session_warning(fiducials: FiducialSet) -> str:
    """The sessions' line of :attr:`ModelState.warning`: the sessions moved (re-stationed) and
    kept apart (:meth:`~rbc_registration.core.measurements.sessions.SessionPlan.warning`, metres),
    the
    sessions the node opened on a move it detected (``auto-N``, :mod:`~rbc_registration.core.
    session_sums`), and when each session starts (the stamp of its first measurement); "" with
    one session or nothing to say."""
    plan = fiducials.sessions
    if plan is None or not plan.warning():
        return ""
    starts = fiducials.session_starts
    when = ", ".join(f"{s!r} at {t:.3f} s" for s, t in starts)
    live = [f"{s!r} at stamp {t:.3f} s" for s, t in starts if s.startswith(AUTO_SESSION_PREFIX)]
    detected = (f"; the node detected a move of the working frame and opened session(s) "
                f"{', '.join(live)}" if live else "")
    return (plan.warning("m") + detected
            + (f" (sessions start at stamp {when})" if when else ""))


def session_mismatch(state: ModelState, current: str) -> str:
    """Why targets of the session ``current`` cannot be answered from ``state``'s model: the
    model was built in another session's working frame (a new session opened, declared or by
    a detected move, and the rebuild is still to come); "" when they can."""
    fiducials = state.fiducials
    if fiducials is None or not fiducials.session or fiducials.session == current:
        return ""
    return (f"targets are in session {current!r}, the model is still in session "
            f"{fiducials.session!r}'s working frame: retry once ~/status shows the rebuild "
            "(n_pending 0)")


def _kept_apart_hint(fiducials: FiducialSet) -> str:
    """Why a model of the current session has few fiducials: the other sessions kept apart
    (the current session shares too few fiducials with them), and what to measure; "" else."""
    plan = fiducials.sessions
    if plan is None or not plan.kept_apart:
        return ""
    d = fiducials.working.shape[1]
    return (f" in session {plan.reference!r}; {plan.warning('m')}: measure at least {d + 1} "
            f"fiducials of the earlier sessions again (not on one line) in session "
            f"{plan.reference!r} to re-station them")


def with_warning(state: ModelState, line: str) -> ModelState:
    """``state`` with ``line`` added to its :attr:`~ModelState.warning` (joined by "; "); the
    same state when ``line`` is empty or no model is served. For what only the ingestion knows,
    e.g. :meth:`.ingest.Ingest.dropped_z_warning`."""
    if not line or state.model is None:
        return state
    return replace(state, warning="; ".join(filter(None, (state.warning, line))))


def _build(fiducials: FiducialSet, settings: Settings,
           previous: Optional[KrigingHyperparameters]) -> RbcModel:
    return build_model(fiducials.working, fiducials.destination, model_config(settings),
                       ids=list(fiducials.ids), repeat_statistics=fiducials.repeat_stats,
                       kriging_warm_start=previous, groups=fiducials.groups)
