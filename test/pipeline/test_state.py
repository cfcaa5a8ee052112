"""Model-state building from the enabled fiducials and the settings (pure: no rclpy)."""

import math

import numpy as np

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.constants import DecisionMode
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.state import build_state, model_config, warm_start


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
    assert state.warning == ""     # no fiducial stands out (core/decision/evaluation.py blunders)
    assert state.model.sigma_source == "given"
    assert model_config(Settings.from_mapping({})).sigma is None
    # every sigma_L is computed in the building (recompute) thread, not at the first status
    cached = state.model.restoration.sigma_l_cached
    assert len(cached) == 3 and np.isfinite(cached).all()


def test_model_config_carries_the_decision_and_sigma_axis():
    cfg = model_config(Settings.from_mapping({"sigma_axis": 1e-4, "decision": "rho",
                                              "dimension": 2}))
    assert cfg.decision is DecisionMode.RHO and cfg.sigma is None and cfg.sigma_axis == 1e-4
    assert math.isclose(cfg.known_sigma, 1e-4 * math.sqrt(2))
    assert model_config(Settings.from_mapping({})).decision is DecisionMode.CV


def test_warm_start_passes_the_served_kriging_hyperparameters():
    rng = np.random.default_rng(1)
    acc = FiducialAccumulator(2, "tracker", "world", 1e-4, 0.0)
    grid = np.array([[x, y] for x in np.linspace(0, 1, 6) for y in np.linspace(0, 1, 5)])
    for k, p in enumerate(grid):
        acc.add(f"f{k}", p + 2e-3 * np.sin(3 * p) + rng.normal(0, 1e-4, 2), p)
    settings = Settings.from_mapping({"interpolation": "kriging", "dimension": 2})
    first = build_state(acc.fiducial_set(), settings, 1)
    hyper = warm_start(first)
    assert hyper is not None and hyper == first.model.kriging_hyperparameters
    again = build_state(acc.fiducial_set(), settings, 2, hyper)
    assert again.model is not None
    # Started at the optimum of the same data, the refined fit stays there.
    np.testing.assert_allclose(again.model.kriging_hyperparameters, hyper, rtol=1e-3)
    assert warm_start(build_state(acc.fiducial_set(), settings.replace(min_fiducials=100), 3)) \
        is None


def test_one_point_under_two_ids_is_the_served_models_warning():
    """The node says it too (~/status message, the log), not only the CLI: the state's
    warning names one point measured under two ids ('H01' and 'H01 ' from two drivers)."""
    rng = np.random.default_rng(1)
    acc = FiducialAccumulator(3, "tracker", "world", 1e-6, 0.0)
    grid = np.array([[x, y, z] for x in (0, .3, .6) for y in (0, .3) for z in (0, .2)], float)
    for k, p in enumerate(grid):
        acc.add(f"H{k:02d}", p + rng.normal(0, 1e-4, 3), p + 1.0)
    acc.add("H01 ", grid[1] + rng.normal(0, 1e-6, 3), grid[1] + 1.0)
    state = build_state(acc.fiducial_set(), Settings.from_mapping({}), 1)
    assert state.error == ""
    assert ("1 point(s) measured under two or more ids, the same place in both frames: 'H01' "
            "and 'H01 ' (") in state.warning


def test_identical_repeats_are_the_served_models_warning_and_sigma_unknown():
    """The node's accumulator sees the same point again under new stamps (a driver that
    re-sends its last measurement): the repeats' spread is 0, which is no noise estimate; the
    state's warning says so and the model's sigma is unknown (was 0, rho inf)."""
    rng = np.random.default_rng(2)
    acc = FiducialAccumulator(3, "tracker", "world", 0.001, 0.0)
    grid = np.array([[x, y, z] for x in (0, .3, .6) for y in (0, .3) for z in (0, .2)], float)
    for k, p in enumerate(grid):
        w = p + rng.normal(0, 1e-4, 3)
        for n in range(3):
            acc.add(f"H{k:02d}", w, p + 1.0, stamp_s=1.0 + k + 0.1 * n)
    state = build_state(acc.fiducial_set(), Settings.from_mapping({}), 1)
    assert state.error == "" and state.model.sigma is None, state.model.sigma
    assert "are identical to their first measurement" in state.warning, state.warning
