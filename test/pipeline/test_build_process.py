"""The build process (pipeline.build_process): the same model state as the thread, bit for bit; a
child that dies is replaced; close() ends a build in progress. Real child processes, no rclpy."""

import dataclasses
import os
import signal
import sys
import threading

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.pipeline import build_process
from rbc_registration.pipeline.build_process import (BuildCancelled, BuildProcessDied,
                                                     ProcessBuilder, uses_process)
from rbc_registration.pipeline.settings import PROCESS_MIN_FIDUCIALS, Settings
from rbc_registration.pipeline.state import build_state

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(__file__)), "ros"))
from ros_helpers import make_cell  # noqa: E402  (numpy only: the node tests' cell)


def fiducials(cell, indices=None):
    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.01)
    for k in range(len(cell["fid"])) if indices is None else indices:
        acc.add(str(cell["ids"][cell["fid"][k]]), cell["working"][k], cell["destination"][k])
    return acc.fiducial_set()


def settings(**values):
    return Settings.from_mapping({"rebuild_worker": "process", **values})


@pytest.fixture
def builder():
    b = ProcessBuilder()
    yield b
    b.close()


def same_state(a, b, targets):
    assert (a.error, a.warning, a.stamp_ns) == (b.error, b.warning, b.stamp_ns)
    np.testing.assert_array_equal(a.model.corrections, b.model.corrections)
    assert a.model.sigma_l == b.model.sigma_l
    np.testing.assert_equal(dataclasses.asdict(a.model.decision),
                            dataclasses.asdict(b.model.decision))
    ca, cb = a.model.correct(targets), b.model.correct(targets)
    for name in ("corrected", "uncorrected", "correction", "expected_tre", "tre_bound"):
        np.testing.assert_array_equal(getattr(ca, name), getattr(cb, name), err_msg=name)
    assert a.fiducials.ids == b.fiducials.ids


def test_auto_builds_in_the_process_from_the_threshold_on():
    assert not uses_process("auto", PROCESS_MIN_FIDUCIALS - 1)
    assert uses_process("auto", PROCESS_MIN_FIDUCIALS)
    assert uses_process("process", 4) and not uses_process("thread", 10 * PROCESS_MIN_FIDUCIALS)


@pytest.mark.parametrize("interpolation", ["paper", "kriging"])
def test_the_process_builds_what_the_thread_builds_bit_for_bit(builder, interpolation):
    cell = make_cell()
    fs, s = fiducials(cell), settings(interpolation=interpolation)
    remote = builder(fs, s, 123)
    assert builder.n_started == 1 and builder.child_pid is not None
    same_state(remote, build_state(fs, s, 123), cell["targets"])
    again = builder(fs, s, 124)       # the same child serves the next build
    assert builder.n_started == 1 and again.stamp_ns == 124


def test_below_the_threshold_auto_builds_in_the_thread(builder):
    cell = make_cell()
    state = builder(fiducials(cell), settings(rebuild_worker="auto"), 5)
    assert state.model is not None and builder.n_started == 0 and builder.child_pid is None


def test_a_set_the_core_refuses_gives_the_same_error_state_as_the_thread(builder):
    cell = make_cell()
    fs = fiducials(cell, indices=range(3))     # 3 fiducials: below min_fiducials
    s = settings(min_fiducials=3)
    collinear = fiducials({**cell, "working": np.outer(np.arange(len(cell["fid"])), [1.0, 0, 0]),
                           "destination": np.outer(np.arange(len(cell["fid"])), [1.0, 0, 0])},
                          indices=range(3))
    for fset in (fs, collinear):
        remote, local = builder(fset, s, 1), build_state(fset, s, 1)
        assert remote.model is None and remote.error == local.error and remote.error


def test_an_unexpected_error_of_the_build_is_raised_with_its_type_and_the_child_serves_on(
        builder):
    cell = make_cell()
    fs, s = fiducials(cell), settings(interpolation="kriging")
    with pytest.raises(RuntimeError, match=r"^build process: [A-Za-z]+Error: "):
        builder(fs, s, 1, previous="not hyper-parameters")
    assert builder(fs, s, 2).model is not None and builder.n_started == 1


def test_a_child_killed_during_a_build_is_replaced_and_the_build_retried(builder):
    cell = make_cell()
    fs, s = fiducials(cell), settings(interpolation="kriging")
    builder(fs, s, 1)                              # the child runs
    pid = builder.child_pid
    done = threading.Event()
    results = []

    def build():
        results.append(builder(fs, s, 2))
        done.set()

    thread = threading.Thread(target=build)
    thread.start()
    os.kill(pid, signal.SIGKILL)                   # during (or right before) the build
    thread.join(timeout=120)
    assert done.is_set() and builder.n_started == 2 and builder.child_pid != pid
    same_state(results[0], build_state(fs, s, 2), cell["targets"])


def test_a_child_that_dies_twice_raises_naming_how_it_ended(builder, monkeypatch):
    monkeypatch.setattr(build_process, "CHILD_MODULE", "rbc_registration.no_such_module")
    with pytest.raises(BuildProcessDied, match=r"twice in a row \(last exited with status 1\); "
                                               r"the previous model is kept"):
        builder(fiducials(make_cell()), settings(), 1)
    assert builder.n_started == 2


def test_a_result_the_child_cannot_send_back_is_built_in_the_thread(monkeypatch):
    """A model state pickle cannot write: the child dies no more ('died twice in a
    row' on every rebuild, two children and two builds each time, the model never updated)."""
    lines = []
    builder = ProcessBuilder(warn=lines.append)
    monkeypatch.setattr(build_process, "CHILD_MODULE", "unsendable_build_child")
    monkeypatch.setenv("PYTHONPATH", os.path.dirname(os.path.abspath(__file__)))
    try:
        cell = make_cell()
        fs, s = fiducials(cell), settings()
        for stamp in (1, 2):
            same_state(builder(fs, s, stamp), build_state(fs, s, stamp), cell["targets"])
        assert builder.n_started == 1, "the child serves on"
        assert len(lines) == 2 and all("could not send its result back (" in line
                                       and "this build runs in the thread" in line
                                       for line in lines)
    finally:
        builder.close()


def test_the_child_does_not_import_from_the_working_directory(builder, tmp_path, monkeypatch):
    """A checkout in the node's working directory would shadow the package (no -P before)."""
    fake = tmp_path / "rbc_registration" / "pipeline"
    fake.mkdir(parents=True)
    (tmp_path / "rbc_registration" / "__init__.py").write_text("")
    (fake / "__init__.py").write_text("")
    (fake / "build_child.py").write_text("raise SystemExit(3)\n")
    monkeypatch.chdir(tmp_path)
    cell = make_cell()
    fs, s = fiducials(cell), settings()
    same_state(builder(fs, s, 1), build_state(fs, s, 1), cell["targets"])
    assert builder.n_started == 1


def test_close_ends_a_build_in_the_child_at_once_and_later_ones_are_refused(builder,
                                                                          monkeypatch):
    monkeypatch.setattr(build_process, "CHILD_MODULE", "hanging_build_child")
    monkeypatch.setenv("PYTHONPATH", os.path.dirname(os.path.abspath(__file__)))
    cell = make_cell()
    fs, s = fiducials(cell), settings()
    errors = []

    def build():
        try:
            builder(fs, s, 1)
        except BuildCancelled as exc:
            errors.append(exc)

    thread = threading.Thread(target=build)
    thread.start()
    while builder.child_pid is None:
        thread.join(timeout=0.01)
    child = builder._child.process
    builder.close()
    thread.join(timeout=60)
    assert not thread.is_alive() and len(errors) == 1
    assert "closed during the build" in str(errors[0]) and child.poll() is not None
    with pytest.raises(BuildCancelled, match="the builder is closed"):
        builder(fs, s, 2)
    assert builder(fs, settings(rebuild_worker="thread"), 3).model is not None  # thread: works


def test_a_child_that_cannot_start_is_reported_once_and_the_build_runs_in_the_thread(monkeypatch):
    lines = []
    builder = ProcessBuilder(warn=lines.append)
    monkeypatch.setattr(sys, "executable", "/nonexistent/python3")
    cell = make_cell()
    fs, s = fiducials(cell), settings()
    for stamp in (1, 2):
        same_state(builder(fs, s, stamp), build_state(fs, s, stamp), cell["targets"])
    assert len(lines) == 1 and builder.n_started == 0
    assert lines[0].startswith("cannot start the build process (") and "/nonexistent/python3" in \
        lines[0] and lines[0].endswith("): building in the thread")
    monkeypatch.undo()
    assert builder(fs, s, 3).model is not None and builder.n_started == 1
    assert builder.start_error == ""
    builder.close()
