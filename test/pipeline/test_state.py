"""Model-state building from the enabled fiducials and the settings (pure: no rclpy)."""

import numpy as np

from rbc_registration.core.accumulator import FiducialAccumulator
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.state import build_state, model_config


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
    # every sigma_L is computed in the building (recompute) thread, not at the first status
    cached = state.model.restoration.sigma_l_cached
    assert len(cached) == 3 and np.isfinite(cached).all()
