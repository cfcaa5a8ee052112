"""The debounce rule (pure, exact times) and the recompute thread driven by a fake clock: no
sleeps, no counts over real time. Pure: no rclpy."""

import threading

import pytest

from rbc_registration.pipeline.worker import MAX_DELAY_FACTOR, Debounce, RecomputeWorker


class FakeClock:
    """Monotonic seconds that move only when the test says so."""

    def __init__(self) -> None:
        self.now = 0.0
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return self.now

    def set(self, t: float) -> None:
        with self._lock:
            self.now = t


# -- the rule ---------------------------------------------------------------------------------
def test_nothing_pending_is_never_due():
    d = Debounce()
    assert d.due_in(0.0, 0.2) is None and not d.pending


def test_a_burst_is_due_one_period_after_its_last_change():
    d = Debounce()
    for _ in range(200):
        d.change(5.0)
    assert d.pending
    assert d.due_in(5.0, 0.3) == pytest.approx(0.3)
    assert d.due_in(5.29, 0.3) > 0
    assert d.due_in(5.3, 0.3) <= 0
    d.start()
    assert d.due_in(100.0, 0.3) is None


def test_each_change_restarts_the_quiet_period():
    d = Debounce()
    d.change(0.0)
    d.change(0.2)
    assert d.due_in(0.3, 0.3) == pytest.approx(0.2)   # due at 0.5, not 0.3


def test_a_continuous_stream_is_due_ten_periods_after_its_first_change():
    """A change every 10 ms with a 50 ms period: never quiet, yet rebuilt 0.5 s after the first
    change of each round (at 0.5, 1.01 and 1.52 s)."""
    d = Debounce()
    period, rebuilds, first = 0.05, [], None
    for k in range(161):
        t = k * 0.01
        d.change(t)
        first = t if first is None else first
        if d.due_in(t, period) <= 1e-12:
            rebuilds.append((first, t))
            d.start()
            first = None
    assert len(rebuilds) == 3
    for start, at in rebuilds:
        assert at == pytest.approx(start + MAX_DELAY_FACTOR * period)


def test_urgent_is_due_at_once_and_a_negative_period_counts_as_zero():
    d = Debounce()
    d.urgent(1.0)
    assert d.due_in(1.0, 30.0) == 0.0
    d.start()
    d.change(2.0)
    assert d.due_in(2.0, -1.0) == 0.0


# -- the thread -------------------------------------------------------------------------------
def counting_worker(period, clock):
    calls = []

    def rebuild():
        calls.append(clock())

    errors = []
    return RecomputeWorker(rebuild, lambda: period, errors.append, clock), calls, errors


def test_a_burst_is_rebuilt_once_when_the_clock_reaches_the_period():
    clock = FakeClock()
    worker, calls, errors = counting_worker(30.0, clock)
    try:
        for _ in range(200):
            ticket = worker.notify()
        assert not worker.wait(ticket, 0.2)      # the fake clock stands still: not due
        assert calls == []
        clock.set(30.0)
        worker.wake()
        assert worker.wait(ticket, 10.0)
        assert worker.wait(worker.request_now(), 10.0)
        assert calls == [30.0, 30.0] and errors == []   # the burst once, then the request
    finally:
        worker.stop()


def test_a_continuous_stream_is_still_rebuilt():
    """Changes every 10 ms of the fake clock with a 50 ms period: no quiet period ever, yet the
    first rebuild comes at the latest 10 periods after the first change."""
    clock = FakeClock()
    worker, calls, _ = counting_worker(0.05, clock)
    try:
        first = worker.notify()
        for k in range(1, 61):
            clock.set(k * 0.01)
            worker.notify()
        worker.wake()
        assert worker.wait(first, 10.0)
        assert calls and calls[0] >= MAX_DELAY_FACTOR * 0.05 - 1e-9
    finally:
        worker.stop()


def test_only_the_first_change_of_a_pending_batch_wakes_the_thread():
    """The thread looks at the clock (and the period) once per wake-up: a burst of changes
    while one is pending wakes it once, a request_now again at once."""
    clock, looks, woke = FakeClock(), [], threading.Event()
    calls = []

    def period():
        looks.append(clock())
        woke.set()
        return 30.0

    worker = RecomputeWorker(lambda: calls.append(clock()), period, [].append, clock)
    try:
        assert woke.wait(10.0)                   # the thread's first look (nothing pending)
        woke.clear()
        first = worker.notify()
        assert woke.wait(10.0)                   # woken by the first change
        n_looks = len(looks)
        woke.clear()
        for _ in range(500):
            worker.notify()
        assert not woke.wait(0.2)                # not woken by the others: still waiting
        assert len(looks) == n_looks
        assert worker.wait(worker.request_now(), 10.0)
        assert len(looks) > n_looks and calls == [0.0]   # urgent: woken and rebuilt at once
        assert worker.wait(first, 0.0)           # that rebuild covered the whole batch
    finally:
        worker.stop()


def test_request_now_and_wait():
    worker, calls, _ = counting_worker(30.0, FakeClock())
    try:
        ticket = worker.request_now()
        assert worker.wait(ticket, 10.0)
        assert calls == [0.0]
    finally:
        worker.stop()


def test_an_exception_in_rebuild_is_reported_and_the_thread_goes_on():
    errors = []
    calls = []

    def rebuild():
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("boom")

    worker = RecomputeWorker(rebuild, lambda: 0.0, errors.append, FakeClock())
    try:
        assert worker.wait(worker.request_now(), 10.0)
        assert worker.wait(worker.request_now(), 10.0)
        assert len(calls) == 2 and [str(e) for e in errors] == ["boom"]
    finally:
        worker.stop()
