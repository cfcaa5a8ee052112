"""The records of :mod:`rbc_registration.core.accumulator` (which re-exports them): accepted
measurements, enable changes, the enabled fiducials ready for ``build_model``, a rejected
measurement with its reason, and the per-fiducial store of repeats. Pure Python + numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Union

import numpy as np
from numpy.typing import NDArray

#: Reasons a measurement is rejected (the counters of ``FiducialAccumulator.rejected``).
REJECT_REASONS = ("frame", "nonfinite", "outlier", "malformed", "stale")

#: Longest text of a rejected value quoted in an error message (a 1 MB id is not logged whole).
QUOTE_LIMIT = 60


def quote(value: Any, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)``, cut to ``limit`` characters with the full length noted when longer."""
    text = repr(value)
    if len(text) <= limit:
        return text
    length = f" ({len(value)} characters)" if isinstance(value, (str, bytes)) else ""
    return f"{text[:limit]}...{length}"


class RejectedMeasurement(ValueError):
    """A measurement that must not reach the model.

    :ivar reason: one of :data:`REJECT_REASONS`.
    :ivar message: what was wrong, for the log.
    """

    def __init__(self, reason: str, message: str) -> None:
        if reason not in REJECT_REASONS:
            raise ValueError(f"reason must be one of {REJECT_REASONS}, got {reason!r}")
        super().__init__(f"{reason}: {message}")
        self.reason = reason
        self.message = message


@dataclass(frozen=True)
class Measurement:
    """One accepted measurement of fiducial ``fiducial_id`` (coordinates in the caller's unit).

    ``working`` and ``destination`` hold the first ``dimension`` coordinates (x, y[, z]);
    ``auto_id`` is true when the id was assigned by proximity (``merge_radius``).
    """

    fiducial_id: str
    working: tuple[float, ...]
    destination: tuple[float, ...]
    stamp_s: float
    auto_id: bool = False


@dataclass(frozen=True)
class EnabledChange:
    """Fiducial ``fiducial_id`` excluded from (``enabled=False``) or included in the model."""

    fiducial_id: str
    enabled: bool


Record = Union[Measurement, EnabledChange]


@dataclass(frozen=True)
class FiducialSet:
    """The enabled fiducials, ready for ``build_model`` (first-seen order, arrays (J, d)).

    ``working`` / ``destination`` are the means of the repeats; ``working_repeats[j]`` is the
    (n_j, d) array of all measurements of fiducial ``ids[j]`` in the working frame.
    """

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: NDArray[np.float64]
    working_repeats: tuple[NDArray[np.float64], ...]
    destination_repeats: tuple[NDArray[np.float64], ...]
    disabled_ids: tuple[str, ...]
    n_measurements: int


class FiducialRepeats:
    """Repeats of one fiducial with running sums (for O(1) means); the accumulator's store."""

    __slots__ = ("working", "destination", "sum_w", "sum_d", "enabled")

    def __init__(self, dimension: int) -> None:
        self.working: list[tuple[float, ...]] = []
        self.destination: list[tuple[float, ...]] = []
        self.sum_w = [0.0] * dimension
        self.sum_d = [0.0] * dimension
        self.enabled = True

    def add(self, working: tuple[float, ...], destination: tuple[float, ...]) -> None:
        self.working.append(working)
        self.destination.append(destination)
        self.sum_w = [s + v for s, v in zip(self.sum_w, working, strict=True)]
        self.sum_d = [s + v for s, v in zip(self.sum_d, destination, strict=True)]

    def mean_w(self) -> tuple[float, ...]:
        n = len(self.working)
        return tuple(s / n for s in self.sum_w)

    def mean_d(self) -> tuple[float, ...]:
        n = len(self.destination)
        return tuple(s / n for s in self.sum_d)
