"""The model's warnings built in one place (core/warnings.py) for the CLI, the node and bags."""

import numpy as np

from rbc_registration.core import ModelConfig, build_model
from rbc_registration.core.warnings import model_warnings


def _cell(seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = rng.uniform(0, 2000, size=(12, 3))
    offsets = np.array([[0, 0, 0], [40, 0, 0], [0, 40, 0]], dtype=float)
    working = np.vstack([p + offsets for p in poses])
    ids = [f"pose{k:02d}_N{n}" for k in range(12) for n in range(1, 4)]
    return ids, working


def test_a_clean_model_has_no_warnings():
    rng = np.random.default_rng(1)
    working = rng.uniform(0, 1000, size=(20, 3))
    model = build_model(working, working + 5.0, ModelConfig(), ids=[f"F{k}" for k in range(20)])
    assert model_warnings(model, "mm") == []


def test_ids_of_poses_without_groups_get_one_line_naming_the_group_column():
    ids, working = _cell()
    rng = np.random.default_rng(2)
    model = build_model(working, working + rng.normal(0, 0.01, working.shape), ModelConfig(),
                        ids=ids)
    lines = model_warnings(model, "mm")
    grouped = [line for line in lines if "group" in line]
    assert len(grouped) == 1
    assert grouped[0].startswith("36 fiducials come in 12 sets named as points of one pose")
    assert "'pose00_N1', 'pose00_N2', 'pose00_N3'" in grouped[0] and "`group`" in grouped[0]
    with_groups = build_model(working, working + rng.normal(0, 0.01, working.shape),
                              ModelConfig(), ids=ids, groups=[i.split("_")[0] for i in ids])
    assert not [line for line in model_warnings(with_groups, "mm") if "group" in line]


def test_one_point_under_two_ids_is_named_in_the_unit_given():
    rng = np.random.default_rng(3)
    working = rng.uniform(0, 1000, size=(12, 3))
    working[11] = working[3]
    model = build_model(working, working + 5.0, ModelConfig(), ids=[f"F{k}" for k in range(12)])
    lines = model_warnings(model, "mm")
    assert any("F3" in line and "F11" in line for line in lines), lines
