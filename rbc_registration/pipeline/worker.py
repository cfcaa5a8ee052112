"""The model state the node serves (immutable, swapped atomically) and the debounced recompute
thread. No rclpy: the node passes in callables.

Debounce: after a change the model is rebuilt once no further change arrived for
``debounce_period`` seconds, or at the latest ``MAX_DELAY_FACTOR * debounce_period`` after the
first pending change (so a continuous stream still refreshes the model). Rebuilding runs in its
own thread: service calls keep being answered from the previous model meanwhile.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional

from rbc_registration.core.accumulator import FiducialSet
from rbc_registration.core.model import ModelConfig, RbcModel, build_model

from .params import Settings

MAX_DELAY_FACTOR = 10.0


@dataclass(frozen=True)
class ModelState:
    """What the node serves: the model (or ``None`` with the reason in ``error``), the fiducials
    and settings it was built from, and when (``stamp_ns``, node clock; 0 = never)."""

    model: Optional[RbcModel]
    fiducials: Optional[FiducialSet]
    settings: Optional[Settings]
    error: str
    stamp_ns: int = 0

    @property
    def n_measurements(self) -> int:
        """Accepted measurements included in this model state."""
        return self.fiducials.n_measurements if self.fiducials is not None else 0


EMPTY_STATE = ModelState(None, None, None, "no measurements yet")


def model_config(settings: Settings) -> ModelConfig:
    """The core model configuration for the node's parameters (``sigma`` 0 means unknown)."""
    return ModelConfig(dimension=settings.dimension, restoration=settings.restoration,
                       steps=settings.restoration_steps, interpolation=settings.interpolation,
                       sigma=settings.sigma if settings.sigma > 0 else None,
                       rho_reject=settings.rho_reject, rho_apply=settings.rho_apply)


def build_state(fiducials: FiducialSet, settings: Settings, stamp_ns: int) -> ModelState:
    """Build the model for ``fiducials``; a bad or degenerate set gives ``model=None`` and the
    core's error message (never raises ValueError)."""
    n = len(fiducials.ids)
    if n < settings.min_fiducials:
        return ModelState(None, fiducials, settings,
                          f"{n} enabled fiducials, need min_fiducials={settings.min_fiducials}",
                          stamp_ns)
    try:
        model = build_model(fiducials.working, fiducials.destination, model_config(settings),
                            ids=list(fiducials.ids),
                            repeat_statistics=fiducials.repeat_stats)
    except ValueError as exc:
        return ModelState(None, fiducials, settings, f"model not built: {exc}", stamp_ns)
    return ModelState(model, fiducials, settings, "", stamp_ns)


class RecomputeWorker:
    """A thread calling ``rebuild()`` debounced after :meth:`notify` (or at once after
    :meth:`request_now`).

    :param rebuild: builds and swaps in a new model; exceptions are passed to ``on_error``.
    :param debounce_period: callable returning the current debounce period [s].
    :param on_error: called with an unexpected exception from ``rebuild`` (the thread goes on).
    """

    def __init__(self, rebuild: Callable[[], Any], debounce_period: Callable[[], float],
                 on_error: Callable[[BaseException], None]) -> None:
        self._rebuild = rebuild
        self._debounce_period = debounce_period
        self._on_error = on_error
        self._cond = threading.Condition()
        self._first_change: Optional[float] = None
        self._last_change = 0.0
        self._now = False
        self._stop = False
        self._requested = 0   # bumped by every notify/request_now
        self._done = 0        # the value of _requested the last finished rebuild covered
        self._thread = threading.Thread(target=self._run, name="rbc_recompute", daemon=True)
        self._thread.start()

    def notify(self) -> None:
        """A measurement or enable change arrived: rebuild after the debounce period."""
        with self._cond:
            now = time.monotonic()
            if self._first_change is None:
                self._first_change = now
            self._last_change = now
            self._requested += 1
            self._cond.notify()

    def request_now(self) -> int:
        """Rebuild as soon as possible; returns a ticket for :meth:`wait`."""
        with self._cond:
            if self._first_change is None:
                self._first_change = time.monotonic()
            self._now = True
            self._requested += 1
            self._cond.notify()
            return self._requested

    def wait(self, ticket: int, timeout: float) -> bool:
        """Wait until a rebuild covering ``ticket`` finished; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._done >= ticket or self._stop, timeout)

    def stop(self) -> None:
        """Stop and join the thread (a running rebuild finishes first)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join()

    def _due_in(self) -> Optional[float]:
        """Seconds until a rebuild is due (<= 0: now), or None when nothing is pending."""
        if self._first_change is None:
            return None
        if self._now:
            return 0.0
        period = max(0.0, float(self._debounce_period()))
        now = time.monotonic()
        return min(self._last_change + period, self._first_change + MAX_DELAY_FACTOR * period) - now

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop:
                    due = self._due_in()
                    if due is not None and due <= 0:
                        break
                    self._cond.wait(timeout=due)
                if self._stop:
                    return
                self._first_change = None
                self._now = False
                ticket = self._requested
            try:
                self._rebuild()
            except Exception as exc:  # noqa: BLE001 - boundary: keep the thread serving
                self._on_error(exc)
            with self._cond:
                self._done = max(self._done, ticket)
                self._cond.notify_all()
