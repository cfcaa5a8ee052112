"""JSON-ready values of models and registrations, shared by the calibration snapshot
(:mod:`.snapshot`) and the reports of ``register`` / ``evaluate``
(:mod:`rbc_registration.io.report`): NaN and infinity become ``null`` (JSON has neither), arrays
become lists.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np
from numpy.typing import ArrayLike

from ..core.rigid.registration import Registration


def json_number(value: Any) -> Optional[float]:
    """A JSON-safe number: ``None``, NaN and infinity become ``None`` (null)."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def json_vector(values: ArrayLike) -> list[Optional[float]]:
    """An array as a flat list of JSON-safe numbers."""
    return [json_number(v) for v in np.asarray(values, dtype=float).ravel()]


def json_clean(value: Any) -> Any:
    """``value`` with every non-finite float, also inside lists and dicts, replaced by ``None``."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (list, tuple)):
        return [json_clean(v) for v in value]
    if isinstance(value, dict):
        return {k: json_clean(v) for k, v in value.items()}
    return value


def registration_json(registration: Registration) -> dict[str, Any]:
    """``{"rotation": d x d, "translation": d, "fre_rms"}`` of a registration, which maps
    ``destination ≈ rotation @ working + translation``."""
    return {"rotation": [json_vector(row) for row in np.atleast_2d(registration.rotation)],
            "translation": json_vector(registration.translation),
            "fre_rms": json_number(registration.fre_rms)}
