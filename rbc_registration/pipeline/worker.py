"""The debounced recompute thread of the node. No rclpy: the node passes in callables.

Debounce: after a change the model is rebuilt once no further change arrived for
``debounce_period`` seconds, or at the latest ``MAX_DELAY_FACTOR * debounce_period`` after the
first pending change (so a continuous stream still refreshes the model). The rule is
:class:`Debounce`, a pure function of the times it is given; :class:`RecomputeWorker` runs it in
its own thread with an injectable clock, so service calls keep being answered from the previous
model meanwhile and tests drive the timing with a fake clock instead of sleeping.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Optional

MAX_DELAY_FACTOR = 10.0


def _stop_and_join(worker: Any) -> None:
    """Set ``worker._stop`` under its condition, wake it, join its thread (unless from it)."""
    with worker._cond:
        worker._stop = True
        worker._cond.notify_all()
    if worker._thread is not threading.current_thread():
        worker._thread.join()


class Debounce:
    """When a rebuild is due, from the times of the changes (seconds of one monotonic clock).

    Not thread-safe: :class:`RecomputeWorker` calls it under its lock.
    """

    def __init__(self, max_delay_factor: float = MAX_DELAY_FACTOR) -> None:
        self.max_delay_factor = max_delay_factor
        self._first: Optional[float] = None   # first change not yet covered by a rebuild
        self._last = 0.0                       # latest change
        self._now = False                      # a rebuild was requested without debounce

    @property
    def pending(self) -> bool:
        """Whether a change is waiting for a rebuild."""
        return self._first is not None

    def change(self, now: float) -> None:
        """A change at time ``now``."""
        if self._first is None:
            self._first = now
        self._last = now

    def urgent(self, now: float) -> None:
        """A rebuild requested at ``now`` without waiting for the debounce period."""
        if self._first is None:
            self._first = now
        self._now = True

    def due_in(self, now: float, period: float) -> Optional[float]:
        """Seconds from ``now`` until a rebuild is due (<= 0: due), or ``None`` when nothing is
        pending. ``period`` is the debounce period [s] (negative counts as 0)."""
        if self._first is None:
            return None
        if self._now:
            return 0.0
        period = max(0.0, float(period))
        return min(self._last + period, self._first + self.max_delay_factor * period) - now

    def start(self) -> None:
        """A rebuild starts: it covers every change so far."""
        self._first = None
        self._now = False


class RecomputeWorker:
    """A thread calling ``rebuild()`` debounced after :meth:`notify` (or at once after
    :meth:`request_now`).

    :param rebuild: builds and swaps in a new model; exceptions are passed to ``on_error``.
    :param debounce_period: callable returning the current debounce period [s].
    :param on_error: called with an unexpected exception from ``rebuild`` (the thread goes on).
    :param clock: monotonic seconds (default :func:`time.monotonic`); a test passes a fake one
        and calls :meth:`wake` after advancing it.
    """

    def __init__(self, rebuild: Callable[[], Any], debounce_period: Callable[[], float],
                 on_error: Callable[[BaseException], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._rebuild = rebuild
        self._debounce_period = debounce_period
        self._on_error = on_error
        self._clock = clock
        self._cond = threading.Condition()
        self._debounce = Debounce()
        self._stop = False
        self._requested = 0   # bumped by every notify/request_now
        self._done = 0        # the value of _requested the last finished rebuild covered
        self._thread = threading.Thread(target=self._run, name="rbc_recompute", daemon=True)
        self._thread.start()

    def notify(self) -> int:
        """A measurement or enable change arrived: rebuild after the debounce period.

        Only the first change of a pending batch wakes the thread: a later one only moves the
        due time later, which the thread sees when its wait for the earlier due time ends. So a
        stream of measurements costs no thread hand-off per message.

        :return: a ticket for :meth:`wait`.
        """
        return self._request(self._debounce.change, urgent=False)

    def request_now(self) -> int:
        """Rebuild as soon as possible; returns a ticket for :meth:`wait`."""
        return self._request(self._debounce.urgent, urgent=True)

    def _request(self, mark: Callable[[float], None], urgent: bool) -> int:
        with self._cond:
            wake = urgent or not self._debounce.pending
            mark(self._clock())
            self._requested += 1
            if wake:
                self._cond.notify()
            return self._requested

    def wake(self) -> None:
        """Make the thread look at the clock again (after a fake clock was advanced)."""
        with self._cond:
            self._cond.notify()

    def wait(self, ticket: int, timeout: float) -> bool:
        """Wait until a rebuild covering ``ticket`` finished; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._done >= ticket or self._stop, timeout)

    def stop(self) -> None:
        """Stop and join the thread (a running rebuild finishes first)."""
        _stop_and_join(self)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop:
                    due = self._debounce.due_in(self._clock(), self._debounce_period())
                    if due is not None and due <= 0:
                        break
                    self._cond.wait(timeout=due)
                if self._stop:
                    return
                self._debounce.start()
                ticket = self._requested
            try:
                self._rebuild()
            except Exception as exc:  # noqa: BLE001 - boundary: keep the thread serving
                self._on_error(exc)
            with self._cond:
                self._done = max(self._done, ticket)
                self._cond.notify_all()


class LatestWriter:
    """A thread writing the latest submitted item with ``write(item)``: submissions while a
    write runs are coalesced into one write of the newest. Used for the calibration snapshot,
    so its serialisation and fsyncs never run on the node's executor or recompute thread (and for
    the planner's error model of the latest model).

    :param write: writes one item (e.g. serialises a model state and writes it atomically);
        returns what was written (e.g. the path).
    :param on_error: called with an exception ``write`` raised (the thread goes on).
    :param name: the thread's name.
    """

    def __init__(self, write: Callable[[Any], str],
                 on_error: Callable[[BaseException], None], name: str = "rbc_snapshot") -> None:
        self._write = write
        self._on_error = on_error
        self._cond = threading.Condition()
        self._item: Any = None
        self._pending = False
        self._busy = False
        self._stop = False
        self.n_written = 0
        self.last_written = ""   # what the last successful write returned
        self.last_error = ""     # the last failed write's error; "" after a success
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, item: Any) -> None:
        """Write ``item`` soon (replacing an item not yet being written)."""
        with self._cond:
            self._item, self._pending = item, True
            self._cond.notify_all()

    def wait_idle(self, timeout: float) -> bool:
        """Wait until nothing is pending or being written; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not (self._pending or self._busy), timeout)

    def stop(self) -> None:
        """Write what is pending, then stop and join the thread."""
        _stop_and_join(self)

    def cancel(self) -> None:
        """Drop what is pending, then stop and join the thread (after a write in progress)."""
        with self._cond:
            self._item, self._pending = None, False
        _stop_and_join(self)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending or self._stop)
                if not self._pending:
                    return
                item, self._item, self._pending, self._busy = self._item, None, False, True
            try:
                written = self._write(item)
                self.n_written, self.last_written, self.last_error = (
                    self.n_written + 1, written, "")
            except Exception as exc:  # noqa: BLE001 - boundary: keep the thread serving
                self.last_error = f"{type(exc).__name__}: {exc}" if not isinstance(
                    exc, OSError) else str(exc)
                self._on_error(exc)
            with self._cond:
                self._busy = False
                self._cond.notify_all()
