"""The records of :mod:`rbc_registration.core.measurements.accumulator` (which re-exports them):
accepted
measurements, enable changes, the enabled fiducials ready for ``build_model``, a rejected
measurement with its reason, and the per-fiducial store of repeats. Pure Python + numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Optional, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from ..constants import REJECT_REASONS
from ..decision.noise import RepeatStats

if TYPE_CHECKING:   # scipy.stats is loaded where sessions are estimated, not with the records
    from .sessions import SessionPlan


#: Longest text of a rejected value quoted in an error message (a 1 MB id is not logged whole).
QUOTE_LIMIT = 60


def quote(value: Any, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)``, cut to ``limit`` characters with the full length noted when longer."""
    text = repr(value)
    if len(text) <= limit:
        return text
    length = f" ({len(value)} characters)" if isinstance(value, (str, bytes)) else ""
    return f"{text[:limit]}...{length}"


class RejectedMeasurement(InputError):
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
    ``auto_id`` is true when the id was assigned by proximity (``merge_radius``). ``group``:
    the fiducials that share its error (``""``: its own group); ``session``: as given, ``""``
    meaning the accumulator's current session (:mod:`.session_sums`).
    """

    fiducial_id: str
    working: tuple[float, ...]
    destination: tuple[float, ...]
    stamp_s: float
    auto_id: bool = False
    group: str = ""
    session: str = ""


@dataclass(frozen=True)
class EnabledChange:
    """Fiducial ``fiducial_id`` excluded from (``enabled=False``) or included in the model."""

    fiducial_id: str
    enabled: bool


Record = Union[Measurement, EnabledChange]


@dataclass(frozen=True)
class FiducialSet:
    """The enabled fiducials, ready for ``build_model`` (first-seen order, arrays (J, d)).

    ``working`` / ``destination`` are the means of the repeats; ``repeat_stats`` holds the count
    and working-frame scatter of each fiducial (``build_model(repeat_statistics=...)``).
    """

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: NDArray[np.float64]
    repeat_stats: RepeatStats
    disabled_ids: tuple[str, ...]
    n_measurements: int
    #: Enabled fiducials a build left out (:func:`~rbc_registration.pipeline.state.build_state`:
    #: the model could not be built with them), not in ``ids``; () from the accumulator.
    left_out_ids: tuple[str, ...] = ()
    #: Per fiducial its group label (``""``: its own group); ``None`` when no group was given.
    groups: Optional[tuple[str, ...]] = None
    #: The sessions' motions (:class:`~.sessions.SessionPlan`) when more than one session
    #: exists, else ``None``; ``working`` is then in the reference session's frame.
    sessions: Optional["SessionPlan"] = None
    #: Per fiducial the stamp of its first measurement [s] (0: unstamped); () when not known.
    first_stamps: tuple[float, ...] = ()
    #: Per session (``sessions``' names) the stamp of its first measurement [s].
    session_starts: tuple[tuple[str, float], ...] = ()
    #: The session current when the set was taken, whose working frame ``working`` is in
    #: (the reference of ``sessions``); "" when not known.
    session: str = ""

    def without(self, index: ArrayLike) -> "FiducialSet":
        """This set without the fiducials at positions ``index`` (they move to
        ``left_out_ids``; ``n_measurements`` still counts their measurements)."""
        keep = np.ones(len(self.ids), dtype=bool)
        keep[np.asarray(index, dtype=np.intp)] = False

        def kept(values: Optional[tuple]) -> Optional[tuple]:
            return None if values is None else tuple(v for v, k in zip(values, keep) if k)

        return FiducialSet(tuple(f for f, k in zip(self.ids, keep) if k), self.working[keep],
                           self.destination[keep], self.repeat_stats.subset(keep),
                           self.disabled_ids, self.n_measurements,
                           self.left_out_ids + tuple(f for f, k in zip(self.ids, keep) if not k),
                           kept(self.groups), self.sessions, kept(self.first_stamps) or (),
                           self.session_starts, self.session)


class FiducialRepeats:
    """The repeats of one fiducial as running statistics (Welford): count, means and sums of
    squared deviations per axis in both frames. O(d) memory per fiducial however many repeats
    arrive, so a node fed for hours does not grow; replaying the same records in the same order
    gives bit-identical values."""

    __slots__ = ("n", "_mean_w", "_m2_w", "_mean_d", "_m2_d", "enabled")

    def __init__(self, dimension: int) -> None:
        self.n = 0
        self._mean_w = [0.0] * dimension
        self._m2_w = [0.0] * dimension
        self._mean_d = [0.0] * dimension
        self._m2_d = [0.0] * dimension
        self.enabled = True

    def add(self, working: tuple[float, ...], destination: tuple[float, ...]) -> None:
        self.n += 1
        for mean, m2, point in ((self._mean_w, self._m2_w, working),
                                (self._mean_d, self._m2_d, destination)):
            for k, value in enumerate(point):
                delta = value - mean[k]
                mean[k] += delta / self.n
                m2[k] += delta * (value - mean[k])

    def remove(self, working: tuple[float, ...], destination: tuple[float, ...]) -> None:
        """Take back one measurement added earlier (Welford in reverse); at n = 0 every sum is
        0 again."""
        if self.n <= 1:
            self.n = 0
            for values in (self._mean_w, self._m2_w, self._mean_d, self._m2_d):
                values[:] = [0.0] * len(values)
            return
        self.n -= 1
        for mean, m2, point in ((self._mean_w, self._m2_w, working),
                                (self._mean_d, self._m2_d, destination)):
            for k, value in enumerate(point):
                before = mean[k]
                mean[k] = before + (before - value) / self.n
                m2[k] = max(0.0, m2[k] - (value - mean[k]) * (value - before))

    def m2_w(self) -> float:
        """The working-frame sum of squared deviations, summed over axes (rotation-invariant)."""
        return sum(self._m2_w)

    def mean_w(self) -> tuple[float, ...]:
        """Mean working-frame point."""
        return tuple(self._mean_w)

    def mean_d(self) -> tuple[float, ...]:
        """Mean destination-frame point."""
        return tuple(self._mean_d)

    def variance_w(self) -> float:
        """sigma_j^2: sum over axes of the working-frame sample variance; NaN below 2 repeats."""
        return sum(self._m2_w) / (self.n - 1) if self.n >= 2 else float("nan")

    def digest(self) -> tuple:
        """Every stored value (for state comparisons)."""
        return (self.n, self.enabled, tuple(self._mean_w), tuple(self._m2_w),
                tuple(self._mean_d), tuple(self._m2_d))
