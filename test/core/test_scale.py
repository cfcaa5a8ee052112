"""Set-up errors between the fiducials' two frames: a unit mismatch or a mirrored frame is refused
with one line; a flat cell, noise and bias are not."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbc_registration.core.model import ModelConfig, build_model
from rbc_registration.core.scale import frame_mismatch
from rbc_registration.core.synthetic import make_cell


def rigid(d, j=20, seed=0, noise=0.0, flat=False):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 1000, (j, d))
    if flat:
        x[:, 2] = 0.0
    rot = (Rotation.from_rotvec(rng.normal(size=3)).as_matrix() if d == 3 else
           np.array([[np.cos(0.5), -np.sin(0.5)], [np.sin(0.5), np.cos(0.5)]]))
    y = x @ rot.T + 100.0
    return x + rng.normal(scale=noise, size=x.shape), y


@pytest.mark.parametrize("d", [2, 3])
def test_a_mirrored_destination_is_refused(d):
    x, y = rigid(d, noise=0.05)
    y[:, -1] *= -1.0
    with pytest.raises(ValueError, match="destination frame looks mirrored.*handedness"):
        build_model(x, y, ModelConfig(dimension=d))


@pytest.mark.parametrize("factor", [1000.0, 0.001, 25.4, 2.5])
def test_frames_in_different_units_are_refused(factor):
    x, y = rigid(3)
    with pytest.raises(ValueError, match=re.escape(f"{factor:.4g}x the size") + ".*units"):
        build_model(x, y * factor, ModelConfig(dimension=3))


def test_noise_bias_and_flat_cells_are_not_set_up_errors():
    for seed in range(30):      # coplanar 3D fiducials: a reflection through the plane fits too
        assert frame_mismatch(*rigid(3, j=8, seed=seed, noise=0.5, flat=True)) is None
        assert frame_mismatch(*rigid(2, j=4, seed=seed, noise=20.0)) is None
    for name in ("A", "B", "RA"):
        c = make_cell(name, 0)
        assert frame_mismatch(c.fiducial_means, c.fiducial_truth) is None
    x, y = rigid(3)
    assert frame_mismatch(x, y * 1.9) is None          # within the factor: a bias to correct
    assert frame_mismatch(np.ones((4, 3)), np.ones((4, 3))) is None   # registration's to say
