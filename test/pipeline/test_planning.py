"""The node's planner without ROS: the planning state of a model state, the request rules of
``~/suggest_next``, the parameters, and the planning thread's coalescing and cancel."""

import dataclasses
import math
import re
import threading

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.planning.model_planner import (error_model_from, expected_target_error,
                                                 plan_from_model)
from rbc_registration.core.planning.planner import PlanConfig
from rbc_registration.pipeline.planning import (NO_PLANNING, expected_error_now, plan_config,
                                                planning_state, request_error, suggest)
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.state import EMPTY_STATE, build_state
from rbc_registration.pipeline.worker import LatestWriter


def grid_state(settings, xs=(0, .3, .6), seed=0):
    """A 3D grid of holes (metres), tracker = world + 1 m + a smooth bias + noise."""
    rng = np.random.default_rng(seed)
    acc = FiducialAccumulator(3, "tracker", "world", 0.001, 0.0)
    grid = np.array([[x, y, z] for x in xs for y in (0, .3, .6) for z in (0, .2)], float)
    for k, p in enumerate(grid):
        acc.add(f"f{k}", p + 1e-3 * np.sin(3 * p) + rng.normal(0, 5e-5, 3), p + 1.0)
    return build_state(acc.fiducial_set(), settings, 1)


SETTINGS = Settings.from_mapping({"sigma": 8.7e-5, "max_candidates": 20})


def test_planning_state_of_a_model_is_the_core_planner():
    state = grid_state(SETTINGS)
    p = planning_state(state)
    assert p.state is state and p.error == "" and p.error_model is not None
    # the served error, calibrated by the cross-validated held-out errors
    assert state.model.decision.apply and p.error_model.calibration == p.check.ratio != 1.0
    assert p.expected_target_error == pytest.approx(
        p.check.ratio * expected_target_error(state.model), rel=1e-12)
    em = error_model_from(state.model)
    assert (p.error_model.signal_std, p.error_model.length_scale) == (em.signal_std,
                                                                      em.length_scale)
    assert expected_error_now(p, state) == p.expected_target_error
    other = grid_state(SETTINGS, seed=1)
    assert math.isnan(expected_error_now(p, other))     # belongs to another model state


def test_above_plan_max_fiducials_the_planner_is_off():
    state = grid_state(SETTINGS)                       # 18 fiducials
    p = planning_state(state, max_fiducials=17)
    assert math.isnan(p.expected_target_error) and p.error_model is None
    assert p.error == "the planner is off: 18 fiducials, more than plan_max_fiducials (17)"
    with pytest.raises(ValueError, match=re.escape(p.error)):
        suggest(p, state, SETTINGS, [[0, 0, 0]], None, 1)
    assert planning_state(state, max_fiducials=18).error_model is not None


def test_without_a_model_nan_and_the_reason():
    p = planning_state(EMPTY_STATE)
    assert math.isnan(p.expected_target_error) and p.error_model is None
    assert p.error == "no model yet: no measurements yet"
    assert math.isnan(expected_error_now(NO_PLANNING, EMPTY_STATE))
    with pytest.raises(ValueError, match="no model yet: no measurements yet"):
        suggest(p, EMPTY_STATE, SETTINGS, [[0, 0, 0]], None, 1)


def test_suggest_is_the_core_plan_once_the_error_model_is_ready():
    state = grid_state(SETTINGS, xs=(0, .3))
    cand = np.array([[x, y, z] for x in (0.6, 0.9) for y in (0, .3, .6) for z in (0, .2)])
    with pytest.raises(ValueError, match=r"error model of the current model \(12 fiducials\) "
                                         r"is still being computed: retry"):
        suggest(NO_PLANNING, state, SETTINGS, cand, None, 2)
    p = planning_state(state)
    plan = suggest(p, state, SETTINGS, cand, np.empty((0, 3)), 0)   # no targets, count 0: 1
    ref = plan_from_model(state.model, cand, count=1, config=plan_config(SETTINGS))
    assert plan.sequence == ref.sequence and not plan.on_targets
    assert plan.expected_after == pytest.approx(ref.expected_after, rel=1e-12)
    strict = SETTINGS.replace(plan_min_gain_fraction=0.5, plan_min_gain_length=1e-4)
    assert plan_config(strict) == PlanConfig(min_gain_fraction=0.5, min_gain_length=1e-4,
                                             target_repeats=1)   # ~/correct_target: one point
    # 12 fiducials: too few for the error model check, so never enough, and it says what to do
    held = suggest(p, state, strict, cand, None, 1)
    assert not held.enough and not p.check.trustworthy and p.check.units == 12
    assert "measure at least 3 more fiducials" in held.reason
    assert p.error_model.calibration == p.check.ratio
    trusted = dataclasses.replace(p, check=p.check._replace(trustworthy=True, note=""))
    assert suggest(trusted, state, strict, cand, None, 1).enough


def test_a_request_in_another_unit_is_refused():
    """Holes sent in mm to a node in metres were ranked (a 99 % "gain")."""
    state = grid_state(SETTINGS, xs=(0, .3))
    cand = np.array([[x, y, z] for x in (0.6, 0.9) for y in (0, .3, .6) for z in (0, .2)])
    p = planning_state(state)
    with pytest.raises(ValueError, match=r"all 12 candidates are outside the fiducials' hull .*"
                                         r"likely a unit mismatch between candidates and "
                                         r"fiducials .*; the node works in metres"):
        suggest(p, state, SETTINGS, cand * 1000, None, 1)
    with pytest.raises(ValueError, match=r"all 12 targets are outside .*the node works in metres"):
        suggest(p, state, SETTINGS, cand, cand * 1000, 1)
    with pytest.raises(ValueError, match=r"candidates contains NaN or inf"):
        suggest(p, state, SETTINGS, np.vstack([cand, [[np.nan, 0, 0]]]), None, 1)
    assert suggest(p, state, SETTINGS, cand, cand, 1).on_targets


@pytest.mark.parametrize("n_candidates, n_targets, message", [
    (21, 0, "21 candidates in one request, more than max_candidates (20): split or thin"),
    (5, 21, "21 targets in one request, more than max_candidates (20)"),
    (0, 3, "no candidates: send the locations that could be measured next"),
])
def test_request_rules(n_candidates, n_targets, message):
    assert request_error(SETTINGS, n_candidates, n_targets).startswith(message)
    state = grid_state(SETTINGS)
    with pytest.raises(ValueError, match=re.escape(message)):
        suggest(planning_state(state), state, SETTINGS, np.zeros((n_candidates, 3)),
                np.ones((n_targets, 3)) if n_targets else None, 1)


def test_request_within_the_limits_is_fine():
    assert request_error(SETTINGS, 20, 20) == ""


@pytest.mark.parametrize("name, value, message", [
    ("plan_min_gain_fraction", 1.0, "plan_min_gain_fraction must be in [0, 0.99]"),
    ("plan_min_gain_fraction", -0.1, "plan_min_gain_fraction must be in [0, 0.99]"),
    ("plan_min_gain_length", -1e-3, "plan_min_gain_length must be in [0, 1]"),
    ("max_candidates", 0, "max_candidates must be in [1, 100000]"),
    ("max_candidates", 2.5, "max_candidates must be an integer"),
])
def test_planner_parameters_are_validated(name, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        Settings.from_mapping({name: value})


def test_latest_writer_cancel_drops_what_is_pending():
    started, release, done = threading.Event(), threading.Event(), []

    def work(item):
        started.set()
        release.wait(10)
        done.append(item)
        return str(item)

    writer = LatestWriter(work, lambda exc: None, name="rbc_test_planner")
    writer.submit(1)
    assert started.wait(10)
    writer.submit(2)                     # pending while 1 runs
    writer.submit(3)                     # replaces 2
    threading.Timer(0.05, release.set).start()
    writer.cancel()                      # waits for 1, drops 3
    assert done == [1] and writer.n_written == 1
