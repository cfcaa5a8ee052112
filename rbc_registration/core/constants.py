"""The closed sets and shared rules of the method, defined once and imported wherever needed
(core, pipeline, io, ros, cli). Plain Python: importing this module loads neither numpy nor
scipy, so the command-line parser can take its choices from here and stay fast.
"""

from __future__ import annotations

from enum import Enum
from typing import Optional

#: Dimensions a registration can have: 2 (x, y as in the paper) or 3.
DIMENSIONS = (2, 3)
#: How the rigid-body condition is restored (eq. 4): the paper's Gauss-Newton steps or the exact
#: minimum-norm solution.
RESTORATIONS = ("iterative", "closed-form")
#: Most iterative restoration steps accepted (node parameter and CLI ``--steps``).
MAX_RESTORATION_STEPS = 20
#: How fiducial corrections are interpolated at a target (eq. 5).
INTERPOLATIONS = ("paper", "kriging")
#: The registration fitted to the measured fiducials, without corrections.
UNCORRECTED = "uncorrected"
#: What the decision chooses between: the uncorrected registration or a corrected one.
CANDIDATES = (UNCORRECTED,) + INTERPOLATIONS


class FoldKind(str, Enum):
    """How the fiducials are split for cross-validation (:mod:`.crossval`): one fiducial (or
    group) held out at a time, or k folds."""

    LEAVE_ONE_OUT = "leave-one-out"
    K_FOLD = "k-fold"


#: The values of :class:`FoldKind`.
FOLD_KINDS = tuple(kind.value for kind in FoldKind)
#: Outcomes of the rho rule (paper section 6), see
#: :func:`rbc_registration.core.decision.noise.assess`.
RECOMMENDATIONS = ("apply", "uncertain", "do_not_apply", "unknown")


class SigmaSource(str, Enum):
    """Where sigma came from: given by the user, estimated from repeats, or unknown."""

    GIVEN = "given"
    REPEATS = "repeats"
    UNKNOWN = "unknown"


#: The values of :class:`SigmaSource`.
SIGMA_SOURCES = tuple(source.value for source in SigmaSource)
#: Reasons a measurement is rejected (the counters of ``FiducialAccumulator.rejected``).
REJECT_REASONS = ("frame", "nonfinite", "outlier", "malformed", "stale", "ambiguous",
                  "duplicate", "conflict")
#: The two point streams of the node (``~/working_point``, ``~/destination_point``), paired by
#: stamp (:mod:`.pairing`).
WORKING, DESTINATION = "working", "destination"
#: The synthetic cells modelled on the paper's experiments (:mod:`.synthetic`).
CELLS = ("A", "B", "RA")
#: Repeated measurements N of a synthetic cell: at most this many (memory grows with N); the
#: paper's Table 1 (``reproduce``) needs at least ``MIN_REPRODUCE_REPEATS`` for sigma.
MAX_REPEATS = 10_000
MIN_REPRODUCE_REPEATS = 2

#: Metres per millimetre (the synthetic cells are in mm; ROS and bags are in metres).
M_PER_MM = 1e-3
#: Millimetres per metre (figures and Markdown reports of metre data show mm).
MM_PER_M = 1e3
#: The length units ``register --unit`` accepts and ``export`` converts to metres (its
#: ``--unit`` and a report's ``unit``): metres per unit.
METRES_PER_UNIT = {"m": 1.0, "cm": 1e-2, "mm": M_PER_MM, "um": 1e-6, "in": 0.0254}
#: Other spellings of those units, read as the unit they name: the micro sign (U+00B5) and the
#: Greek mu (U+03BC) of micrometres, and ``inch``.
UNIT_ALIASES = {"\u00b5m": "um", "\u03bcm": "um", "inch": "in"}


def length_unit(text: str) -> str:
    """The unit of :data:`METRES_PER_UNIT` that ``text`` names (an alias of
    :data:`UNIT_ALIASES` as its unit: ``µm`` is ``um``).

    :raises ValueError: for any other text, naming it and the units accepted.
    """
    unit = UNIT_ALIASES.get(text, text) if isinstance(text, str) else text
    if not isinstance(unit, str) or unit not in METRES_PER_UNIT:
        raise ValueError(f"unknown length unit {text!r}: one of {', '.join(METRES_PER_UNIT)} "
                         f"(also {', '.join(UNIT_ALIASES)})")
    return unit



class DecisionMode(str, Enum):
    """How a model decides whether targets get corrections (``ModelConfig.decision``).

    - ``cv`` (default): cross-validated on the fiducials; a correction is applied only when it
      predicts held-out fiducials better than the uncorrected registration with confidence
      (:mod:`.decision`). Needs no sigma.
    - ``rho``: the paper's rule (section 6) on rho = sigma_L0 / sigma: apply when
      rho >= rho_apply, with the configured interpolation. Needs sigma.
    - ``on``: always apply the configured interpolation.
    - ``off``: never apply corrections.
    """

    CV = "cv"
    RHO = "rho"
    ON = "on"
    OFF = "off"


#: The decision modes as strings (``cv``, ``rho``, ``on``, ``off``).
DECISION_MODES = tuple(mode.value for mode in DecisionMode)


def rho_thresholds_error(rho_reject: float, rho_apply: float) -> Optional[str]:
    """Why the rho thresholds are not in order (``rho_reject <= rho_apply``), or ``None``."""
    if rho_reject > rho_apply:
        return f"rho_reject ({rho_reject:g}) must be <= rho_apply ({rho_apply:g})"
    return None


def check_rho_thresholds(rho_reject: float, rho_apply: float) -> None:
    """:raises ValueError: when ``rho_reject > rho_apply`` (:func:`rho_thresholds_error`)."""
    error = rho_thresholds_error(rho_reject, rho_apply)
    if error:
        raise ValueError(error)
