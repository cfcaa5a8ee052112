"""Settings of the pipeline (the node's parameters): table, validation, config file (pure)."""

import math
import os
import re

import pytest

from rbc_registration.core.constants import DECISION_MODES
from rbc_registration.pipeline.settings import REMOVED, SPECS, Settings, validate, validate_one


def test_defaults_are_valid_and_cover_every_setting():
    s = Settings.from_mapping({})
    assert set(SPECS) == set(Settings.__dataclass_fields__)
    assert s.dimension == 3 and s.decision == "cv" and s.sigma == 0.0 and s.sigma_axis == 0.0
    for name, spec in SPECS.items():
        assert validate_one(name, spec.default) is None, name
        assert spec.description


@pytest.mark.parametrize("name, value, match", [
    ("dimension", 4, r"dimension must be in \[2, 3\]"),
    ("dimension", 2.0, "dimension must be an integer"),
    ("restoration", "magic", "restoration must be one of iterative, closed-form"),
    ("restoration_steps", 0, "restoration_steps must be in"),
    ("interpolation", "linear", "interpolation must be one of paper, kriging"),
    ("sigma", -1e-3, "sigma must be in"),
    ("sigma", math.nan, "sigma must be finite"),
    ("rho_apply", -1.0, "rho_apply must be in"),
    ("decision", "auto", "decision must be one of cv, rho, on, off"),
    ("sigma_axis", -1e-3, "sigma_axis must be in"),
    ("stale_after", 0.0, r"stale_after must be in \(0"),
    ("apply_corrections", "on", "parameter apply_corrections no longer exists: it was replaced "
                                "by 'decision'"),
    ("min_fiducials", 2, "min_fiducials must be in"),
    ("pair_slop", 0.0, r"pair_slop must be in \(0, 10\]"),
    ("merge_radius", 0.0, r"merge_radius must be in \(0"),
    ("outlier_distance", -0.1, "outlier_distance must be in"),
    ("debounce_period", 61.0, "debounce_period must be in"),
    ("working_frame", "", "working_frame is a tf frame id: it must not be empty"),
    ("destination_frame", "/world", "must not start with '/'"),
    ("sample_tf_child", "tcp\nframe", "sample_tf_child is a tf frame id .or empty.: it must not "
                                       "contain whitespace or control characters"),
    ("working_frame", "x" * 1001, "must be at most 1000 characters"),
    ("journal_fsync", 1, "journal_fsync must be a bool"),
    ("state_dir", 3, "state_dir must be a string"),
    ("sigma", True, "sigma must be a number"),
    ("bogus", 1, "unknown parameter 'bogus'"),
])
def test_each_rule_rejects_with_a_reason(name, value, match):
    error = validate_one(name, value)
    assert error is not None

    assert re.search(match, error), error


def test_rho_thresholds_must_be_ordered():
    s = Settings.from_mapping({})
    with pytest.raises(ValueError, match=r"rho_reject \(3\) must be <= rho_apply \(2.5\)"):
        s.replace(rho_reject=3.0)
    assert s.replace(rho_reject=3.0, rho_apply=4.0).rho_reject == 3.0
    assert validate({"rho_reject": 1.0, "rho_apply": 1.0}) is None


def test_replace_returns_a_new_validated_snapshot():
    s = Settings.from_mapping({"sigma": 1e-4})
    t = s.replace(interpolation="kriging")
    assert s.interpolation == "paper" and t.interpolation == "kriging" and t.sigma == 1e-4
    with pytest.raises(ValueError, match="interpolation"):
        s.replace(interpolation="nearest")


def test_decision_choices_are_the_core_modes_and_the_removed_parameter_is_not_a_setting():
    assert SPECS["decision"].choices == DECISION_MODES
    assert not set(REMOVED) & set(SPECS)


def test_sigma_and_sigma_axis_are_exclusive():
    s = Settings.from_mapping({"sigma_axis": 1e-4})
    assert s.sigma_axis == 1e-4 and s.sigma == 0.0
    with pytest.raises(ValueError, match=r"give sigma or sigma_axis, not both \(sigma 0.0002, "
                                         r"sigma_axis 0.0001; 0 = unknown\)"):
        s.replace(sigma=2e-4)
    assert s.replace(sigma=2e-4, sigma_axis=0.0).sigma == 2e-4


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_config_file_lists_every_parameter_with_a_valid_value():
    yaml = pytest.importorskip("yaml")
    with open(os.path.join(ROOT, "config", "registration_node.yaml")) as f:
        values = yaml.safe_load(f)["/**"]["ros__parameters"]
    values.pop("use_sim_time")
    assert set(values) == set(SPECS)
    settings = Settings.from_mapping(values)
    for name, value in values.items():
        default = SPECS[name].default   # ROS types must match; a string array is a YAML list
        assert type(value) is (list if isinstance(default, tuple) else type(default)), name
        if isinstance(default, tuple):
            assert all(isinstance(item, str) for item in value), name
    assert settings.state_dir


@pytest.mark.parametrize("values, message", [
    ({"working_frame": "world", "destination_frame": "world"},
     "working_frame must differ from destination_frame, both are 'world'"),
    ({"sample_tf_child": "world"},
     r"sample_tf_child must differ from sample_tf_parent \(empty: destination_frame\)"),
    ({"sample_tf_parent": "world", "sample_tf_child": "world"},
     "sample_tf_child must differ from sample_tf_parent, both are 'world'"),
    # the accumulator rejects a sample in another frame than destination_frame: refused early
    ({"sample_tf_parent": "base_link"},
     "sample_tf_parent must be empty or destination_frame 'world', got 'base_link': a tf "
     "sample's destination point is recorded in the destination frame"),
    ({"sample_tf_child": "tracker"},
     "sample_tf_child must not be working_frame 'tracker': a tf sample's destination point "
     "would be the working frame's origin, which is the registration itself"),
])
def test_a_frame_registered_into_itself_is_refused(values, message):
    """working_frame == destination_frame started and latched a world -> world
    transform on /tf_static, which tf2 drops."""
    with pytest.raises(ValueError, match=message):
        Settings.from_mapping(values)
