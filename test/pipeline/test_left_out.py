"""A fiducial whose distances to the others differ grossly between the frames (a mistyped
coordinate of a new fiducial, 1e7 m) made the model impossible to build: the node answered
``no model yet: model not built: fiducials are coplanar`` (or "likely the frames are in different
units") until someone found and disabled it. build_state (node and evaluate) now leaves such
fiducials out, names them, and serves the model of the others (core/decision/evaluation.py
``gross_misfits``). No rclpy."""

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.decision.evaluation import (BLUNDER_FACTOR, distance_misfits,
                                                       gross_misfits)
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.state import build_state


def single(name, seed=0):
    cell = make_cell(name, seed=seed, repeats=1)
    return np.array([m[0] for m in cell.fiducial_measurements]), cell.fiducial_truth.copy(), cell


def accumulated(x, y, ids, dimension=3):
    acc = FiducialAccumulator(dimension, "tracker", "world", 1e-9, 0.0)
    for fid, w, d in zip(ids, x, y):
        acc.add(fid, w, d)
    return acc.fiducial_set()


@pytest.mark.parametrize("name", ["A", "B", "RA"])
def test_sound_cells_have_no_gross_misfit_in_any_unit(name):
    for seed in range(3):
        x, y, _ = single(name, seed)
        for scale in (1.0, 1e-3, 1e3):                   # mm, m and km alike: nothing stands out
            flagged, misfit = gross_misfits(x * scale, y * scale, floor=0.0)
            assert len(flagged) == 0 and misfit.max() < BLUNDER_FACTOR / 2 * np.median(misfit)


def test_the_lower_median_keeps_sound_fiducials_small_next_to_blunders():
    x, y, _ = single("A")
    y = y.copy()
    y[[3, 40, 77]] += [1e4, 0, 0]                         # three typos of 10 m (mm cell)
    misfit = distance_misfits(x, y)
    flagged, _ = gross_misfits(x, y, floor=0.0)
    assert sorted(flagged) == [3, 40, 77]
    sound = np.delete(misfit, [3, 40, 77])                # mm: the others unaffected
    assert sound.max() < 10.0 and sound.max() < BLUNDER_FACTOR / 2 * np.median(sound)


def test_above_the_partner_count_the_check_is_deterministic_and_finds_the_typo():
    rng = np.random.default_rng(0)
    y = rng.uniform(0, 3, (500, 3))
    x = y + 1e-4 * np.sin(3 * y)
    x[123, 2] += 5.0
    a, b = distance_misfits(x, y), distance_misfits(x, y)
    np.testing.assert_array_equal(a, b)
    assert list(gross_misfits(x, y, floor=0.01)[0]) == [123]


def test_a_wild_new_fiducial_is_left_out_named_and_the_others_served():
    x, y, cell = single("RA")                              # 2D cell, mm: scale to metres
    x, y = x * 1e-3, y * 1e-3
    ids = list(cell.fiducial_ids)
    settings = Settings.from_mapping({"dimension": 2})
    clean = build_state(accumulated(x, y, ids, 2), settings, 1)
    wild = build_state(accumulated(np.vstack([x, [1e7, 0.5]]), np.vstack([y, [0.5, 0.5]]),
                                   ids + ["typo"], 2), settings, 1)
    assert clean.model is not None and wild.model is not None and wild.error == ""
    assert wild.fiducials.ids == clean.fiducials.ids and wild.fiducials.left_out_ids == ("typo",)
    assert wild.n_measurements == clean.n_measurements + 1
    np.testing.assert_array_equal(wild.model.corrections, clean.model.corrections)
    assert wild.warning.startswith("fiducial 'typo' (1e+07 m): distances to the other fiducials "
                                   "differ between the frames by that much (median; the "
                                   "fiducials' median ")
    assert "left out of the model, which could not be built with it: a typo or a wrong hole?" \
        in wild.warning


def test_a_model_that_builds_keeps_a_moderate_blunder_and_warns_as_before():
    x, y, cell = single("A")
    x, y = x * 1e-3, y * 1e-3
    y[50, 0] -= 0.027                                      # 27 mm: the model still builds
    state = build_state(accumulated(x, y, cell.fiducial_ids), Settings.from_mapping({}), 1)
    assert state.fiducials.left_out_ids == () and len(state.model.ids) == len(x)
    assert state.warning.startswith(f"fiducial {cell.fiducial_ids[50]}: held-out error")


def test_outlier_distance_0_turns_the_screen_off_and_the_error_names_the_suspect():
    x, y, cell = single("A")
    x, y = x * 1e-3, y * 1e-3
    wx, wy = np.vstack([x, [1e7, 0, 0]]), np.vstack([y, [0.5, 0.5, 0.5]])
    ids = list(cell.fiducial_ids) + ["typo"]
    off = build_state(accumulated(wx, wy, ids), Settings.from_mapping({"outlier_distance": 0.0}),
                      1)
    assert off.model is None and off.error.startswith("model not built: ")
    assert "typo" not in off.error
    # too few left without it: not built, the suspect named
    few = build_state(accumulated(wx[-9:], wy[-9:], ids[-9:]),
                      Settings.from_mapping({"min_fiducials": 9}), 1)
    assert few.model is None and few.error.startswith("model not built: ")
    assert few.error.endswith(" m)") and "; likely through fiducial 'typo' (" in few.error
