"""Set-up errors between the fiducials' two frames: a unit mismatch or a mirrored frame is refused
with one line; a flat cell, noise and bias are not."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbc_registration.core.model import ModelConfig, build_model
from rbc_registration.core.rigid.scale import frame_mismatch, rigidity_warnings, unit_mismatch
from rbc_registration.core.synthetic.cells import make_cell, random_rotation


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


def test_one_mistyped_target_is_no_unit_mismatch_of_all():
    """one truth point mistyped (3.4e8 mm) made 'all 8 targets ... unit mismatch'
    (an RMS over the targets); the median distance leaves it to the per-target blunder line.
    Without a hull (the truth, in the destination frame) the text claims none."""
    rng = np.random.default_rng(2)
    fiducials = rng.uniform(-500, 500, (30, 3))
    targets = rng.uniform(-400, 400, (8, 3))
    wild = targets.copy()
    wild[0, 0] = 3.4e8
    assert unit_mismatch(fiducials, wild, None, "target truth") is None
    text = unit_mismatch(fiducials, targets * 1000, None, "target truth")
    assert text.startswith("all 8 targets are ~") and "hull" not in text
    assert "likely a unit mismatch between target truth and fiducials" in text


def test_a_tight_cluster_beside_the_cell_is_no_unit_mismatch():
    """two candidates 1 cm apart, 0.2 m beyond a 0.9 m cell in metres, were
    'likely a unit mismatch (~107x smaller in spread)' and ~/suggest_next refused them. Points
    in a larger unit shrink towards the origin with their spread; these did not."""
    grid = np.stack(np.meshgrid(*[np.linspace(0.0, 0.9, 4)] * 3), axis=-1).reshape(-1, 3)
    fiducials = grid + [0.5, 0.5, 0.2]
    pair = np.array([[1.6, 0.9, 0.5], [1.61, 0.9, 0.5]])          # outside the hull
    assert unit_mismatch(fiducials, pair, [False, False], "candidates", "candidates") is None
    assert unit_mismatch(fiducials, pair[[0, 0, 0]], [False] * 3) is None   # one hole, thrice
    mm_cell = fiducials * 1000.0                                   # the same holes in metres
    text = unit_mismatch(mm_cell, fiducials[:5] + 0.01, [False] * 5, "candidates", "candidates")
    assert text.startswith("all 5 candidates are outside the fiducials' hull and ~")
    assert "smaller in spread (and nearer the frame's origin) than the fiducials" in text


@pytest.mark.parametrize("size, metres_per_unit, unit, expected", [
    (500.0, 1.0, "m", "is 500 m, larger than any cell (100 m)"),      # mm read as m
    (0.5, 1e-3, "mm", "is 0.5 mm (0.0005 m), smaller than any cell"),  # m read as mm
    (500.0, 1e-3, "mm", None),
    (0.5, 1.0, "m", None),
])
def test_a_file_whose_cell_size_fits_another_unit_is_named(size, metres_per_unit, unit,
                                                         expected):
    """register --unit m on a millimetre file exported a transform 1000x off."""
    from rbc_registration.core.rigid.scale import implausible_size
    rng = np.random.default_rng(4)
    points = rng.normal(size=(40, 3))
    points *= size / np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1)))
    text = implausible_size(points, metres_per_unit, unit)
    if expected is None:
        assert text is None
    else:
        assert expected in text and "check --unit" in text


@pytest.mark.parametrize("j", [0, 1])
def test_no_fiducials_is_one_error_without_numpy_warnings(j):
    """zero fiducials printed four numpy RuntimeWarnings (the mean of an empty slice in
    frame_mismatch) before the ValueError."""
    import warnings

    from rbc_registration.core.model import build_model

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert frame_mismatch(np.zeros((j, 3)), np.zeros((j, 3))) is None
        with pytest.raises(ValueError, match=f"needs at least 4 fiducials, got {j}"):
            build_model(np.zeros((j, 3)), np.zeros((j, 3)))


def _cell(seed=0, j=30):
    rng = np.random.default_rng(seed)
    y = rng.uniform(0.0, 1000.0, (j, 3))                            # mm
    rot = random_rotation(rng, 3)
    x = (y - 500.0) @ rot + rng.normal(scale=0.02, size=y.shape) + 0.3 * np.sin(y / 300.0)
    return x, y


def test_a_sound_cell_has_no_rigidity_warning():
    x, y = _cell()
    assert rigidity_warnings(build_model(x, y, ModelConfig(decision="off")), "mm") == []


def test_one_axis_in_another_unit_is_named_and_the_unconverged_restoration_too():
    """dz in metres, the rest in mm: FRE 213 mm on a 1 m cell, the corrected
    FRE 54 mm (two steps did not restore rigidity), corrections applied, no word."""
    x, y = _cell()
    y[:, 2] /= 1000.0
    lines = rigidity_warnings(build_model(x, y, ModelConfig(decision="off")), "mm")
    assert len(lines) == 2
    assert lines[0].startswith("the frames do not match rigidly: the uncorrected FRE ")
    assert "one axis in another unit, or a scaled frame? check each axis" in lines[0]
    assert lines[1].startswith("the restoration did not converge in 2 step(s): the corrected "
                               "fiducials' FRE is ")


def test_a_plate_measured_in_3d_says_its_restoration_did_not_converge():
    """Coplanar fiducials in 3D: sigma_L2 looked converged (3e-7 mm), the corrected FRE was 28 %
    of the uncorrected one; closed-form restores them exactly."""
    rng = np.random.default_rng(4)
    y = np.c_[rng.uniform(0.0, 500.0, (12, 2)), np.zeros(12)]
    x = y @ random_rotation(rng, 3) + rng.normal(scale=0.01, size=y.shape)
    config = ModelConfig(interpolation="kriging", decision="off")
    model = build_model(x, y, config)
    assert model.restoration.sigma_l[-1] < 1e-5
    (line,) = rigidity_warnings(model, "mm")
    assert "did not converge in 2 step(s)" in line and "closed-form restoration" in line
    closed = build_model(x, y, ModelConfig(interpolation="kriging", decision="off",
                                           restoration="closed-form"))
    assert rigidity_warnings(closed, "mm") == []
