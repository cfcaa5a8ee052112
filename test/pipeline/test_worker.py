"""Debounced recompute thread and model-state building (pure: no rclpy)."""

import threading
import time

import numpy as np

from rbc_registration.core.accumulator import FiducialAccumulator
from rbc_registration.ros.params import Settings
from rbc_registration.ros.worker import RecomputeWorker, build_state, model_config


def counting_worker(period):
    calls = []
    done = threading.Event()

    def rebuild():
        calls.append(time.monotonic())
        done.set()

    errors = []
    return RecomputeWorker(rebuild, lambda: period, errors.append), calls, done, errors


def test_a_burst_is_rebuilt_once_after_the_debounce_period():
    worker, calls, done, errors = counting_worker(0.3)
    try:
        for _ in range(200):
            worker.notify()
        assert done.wait(5.0)
        time.sleep(0.5)
        assert len(calls) == 1 and errors == []
    finally:
        worker.stop()


def test_a_continuous_stream_still_rebuilds_at_the_latest_after_ten_periods():
    worker, calls, done, _ = counting_worker(0.05)
    try:
        end = time.monotonic() + 1.5
        while time.monotonic() < end:   # a change every 10 ms: never quiet for 50 ms
            worker.notify()
            time.sleep(0.01)
        assert 1 <= len(calls) <= 4
    finally:
        worker.stop()


def test_request_now_and_wait():
    worker, calls, _, _ = counting_worker(30.0)
    try:
        ticket = worker.request_now()
        assert worker.wait(ticket, 5.0)
        assert len(calls) == 1
    finally:
        worker.stop()


def test_an_exception_in_rebuild_is_reported_and_the_thread_goes_on():
    errors = []
    calls = []

    def rebuild():
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("boom")

    worker = RecomputeWorker(rebuild, lambda: 0.0, errors.append)
    try:
        assert worker.wait(worker.request_now(), 5.0)
        assert worker.wait(worker.request_now(), 5.0)
        assert len(calls) == 2 and [str(e) for e in errors] == ["boom"]
    finally:
        worker.stop()


def test_build_state_needs_min_fiducials_and_reports_core_errors():
    settings = Settings.from_mapping({"min_fiducials": 4})
    acc = FiducialAccumulator(3, "tracker", "world", 0.001, 0.0)
    for k in range(3):
        acc.add(f"f{k}", [k, 0, 0], [k, 0, 0])
    state = build_state(acc.fiducial_set(), settings, 5)
    assert state.model is None and "3 enabled fiducials, need min_fiducials=4" in state.error
    acc.add("f3", [3, 0, 0], [3, 0, 0])   # collinear: the core refuses
    state = build_state(acc.fiducial_set(), settings, 6)
    assert state.model is None and state.error.startswith("model not built:")
    assert state.n_measurements == 4 and state.stamp_ns == 6


def test_build_state_builds_a_model():
    rng = np.random.default_rng(0)
    acc = FiducialAccumulator(3, "tracker", "world", 0.001, 0.0)
    grid = np.array([[x, y, z] for x in (0, .3, .6) for y in (0, .3) for z in (0, .2)], float)
    for k, p in enumerate(grid):
        acc.add(f"f{k}", p + rng.normal(0, 1e-3, 3), p + 1.0)
    settings = Settings.from_mapping({"sigma": 1e-4})
    state = build_state(acc.fiducial_set(), settings, 1)
    assert state.error == "" and state.model.ids == acc.fiducial_set().ids
    assert state.model.sigma_source == "given"
    assert model_config(Settings.from_mapping({})).sigma is None


def test_guards_answer_and_log_unexpected_errors():
    from rbc_registration.ros.guards import guard_input, guard_service

    class Log:
        def __init__(self):
            self.lines = []

        def error(self, line):
            self.lines.append(line)

    class Response:
        success, message = True, ""

    log = Log()

    def broken(*_):
        raise RuntimeError("bug")

    response = guard_service(log, "~/correct_target", broken)(None, Response())
    assert not response.success and response.message == "internal error: bug"
    guard_input(log, "~/fiducial_pairs", broken)(object())
    assert log.lines == ["~/correct_target failed: RuntimeError: bug",
                         "~/fiducial_pairs: message dropped: RuntimeError: bug"]
