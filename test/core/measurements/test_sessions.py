"""Sessions between which the working frame moved: the F test, re-stationing, sessions kept
apart, and the live bump detector (core/measurements/sessions.py)."""

import numpy as np
import pytest

from rbc_registration.core.measurements.sessions import (BumpDetector, estimate_sessions,
                                                         motion_test,
                                            session_cells, spread_enough)
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import moved_sessions


def _plan(cell):
    return estimate_sessions(session_cells(cell.ids, cell.sessions, cell.working))


@pytest.mark.parametrize("name", ["RA", "A"])
def test_a_move_of_three_sigma_is_found_and_undone(name):
    base = make_cell(name, 0, repeats=2)
    cell = moved_sessions(base, 0, 3.0)
    plan = _plan(cell)
    assert plan.reference == "s2"
    first = plan.motion("s1")
    assert first.moved and first.p_value < 1e-6 and not first.kept_apart
    # re-stationed: s1's points land where s2 measures the same fiducials, to the noise
    points, keep = plan.apply(cell.working, cell.sessions)
    assert keep.all()
    sigma = base.spec.sigma / np.sqrt(base.spec.dimension)
    common = [k for k, s in enumerate(cell.sessions) if s == "s2"]
    fid = {f: k for k, f in enumerate(cell.ids) if cell.sessions[k] == "s1"}
    diff = np.array([points[fid[cell.ids[k]]] - points[k] for k in common])
    assert np.sqrt(np.mean(diff ** 2)) < 2.0 * sigma


@pytest.mark.parametrize("name", ["RA", "A"])
def test_no_move_is_no_move(name):
    cell = moved_sessions(make_cell(name, 1, repeats=1), 1, 0.0)
    plan = _plan(cell)
    assert not plan.motion("s1").moved
    points, _ = plan.apply(cell.working, cell.sessions)
    np.testing.assert_array_equal(points, cell.working)
    assert plan.warning() == ""


def test_the_move_is_reported_in_json_form():
    plan = _plan(moved_sessions(make_cell("RA", 2, repeats=1), 2, 10.0))
    rows = plan.to_list()
    assert [r["session"] for r in rows] == ["s1", "s2"]
    assert rows[0]["moved"] and rows[0]["n_common"] > 20 and rows[0]["p_value"] < 1e-10
    assert set(rows[0]) == {"session", "n_measurements", "n_common", "moved", "kept_apart",
                            "translation", "rotation_deg", "p_value"}
    assert "re-stationed" in plan.warning("mm") and "'s1' moved" in plan.warning("mm")


def test_too_few_common_fiducials_keep_a_session_apart():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 100, size=(10, 2))
    ids = [f"F{k}" for k in range(10)] + ["F0", "F1", "X"]
    sessions = ["a"] * 10 + ["b"] * 3
    working = np.vstack([pts, pts[:2] + 5.0, [[50.0, 50.0]]])
    plan = estimate_sessions(session_cells(ids, sessions, working), reference="a")
    assert plan.motion("b").kept_apart and plan.motion("b").transform is None
    _, keep = plan.apply(working, sessions)
    assert keep.tolist() == [True] * 10 + [False] * 3
    assert "kept apart" in plan.warning()


def test_collinear_common_fiducials_are_not_enough():
    line = np.c_[np.arange(5.0), np.zeros(5)]
    assert not spread_enough(line)
    assert spread_enough(np.r_[line, [[0.0, 1.0]]])


def test_the_reference_is_the_latest_unless_given():
    cell = moved_sessions(make_cell("RA", 3, repeats=1), 3, 3.0)
    cells = session_cells(cell.ids, cell.sessions, cell.working)
    assert estimate_sessions(cells).reference == "s2"
    given = estimate_sessions(cells, reference="s1")
    assert given.reference == "s1" and given.motion("s2").moved
    with pytest.raises(ValueError, match="reference session 'x'"):
        estimate_sessions(cells, reference="x")


def test_exact_data_moved_or_not():
    rng = np.random.default_rng(1)
    a = rng.uniform(size=(6, 3))
    assert motion_test(a, a.copy())[1] == 1.0
    assert motion_test(a, a + 1e-3)[1] == 0.0


def test_false_moves_stay_rare():
    moved = 0
    for seed in range(40):
        cell = moved_sessions(make_cell("RA", seed, repeats=1), seed, 0.0)
        moved += _plan(cell).motion("s1").moved
    assert moved <= 3          # 1 % level: 0.4 expected of 40


def test_the_live_detector_finds_a_bump_where_it_began():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 400, size=(100, 2))
    ids = [f"F{k}" for k in range(100)]
    det = BumpDetector(2)
    means = {}
    seq = 0
    for k in range(100):                         # first pass
        det.observe(seq, ids[k], pts[k], None)
        means[ids[k]] = pts[k]
        seq += 1
    for k in range(0, 100, 3):                   # repeats, no move: nothing
        assert det.observe(seq, ids[k], pts[k] + rng.normal(0, 0.08, 2), means[ids[k]]) is None
        seq += 1
    began = seq
    found = None
    for k in range(1, 100, 3):                   # the stand is bumped: 0.5 mm
        found = det.observe(seq, ids[k], pts[k] + [0.5, -0.5] + rng.normal(0, 0.08, 2),
                            means[ids[k]])
        seq += 1
        if found:
            break
    assert found is not None and found.start == began and found.n_fiducials >= 3
    np.testing.assert_allclose(found.motion.translation, [0.5, -0.5], atol=0.2)


def test_the_live_detector_ignores_noise_and_an_outlier():
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 1000, size=(60, 3))
    det = BumpDetector(3)
    seq = 0
    for rep in range(5):
        for k in range(60):
            p = pts[k] + rng.normal(0, 0.03, 3)
            if rep == 2 and k == 7:
                p = p + 2.0                        # one blunder: no common motion
            assert det.observe(seq, f"F{k}", p, pts[k] if rep else None) is None
            seq += 1


def test_a_latest_session_that_joins_nothing_is_the_one_kept_apart():
    rng = np.random.default_rng(2)
    pts = rng.uniform(0, 100, size=(10, 2))
    ids = [f"F{k}" for k in range(10)] + ["F0", "X"]
    working = np.vstack([pts, pts[:1] + 5.0, [[50.0, 50.0]]])
    plan = estimate_sessions(session_cells(ids, ["a"] * 10 + ["b"] * 2, working))
    assert plan.reference == "a" and plan.motion("b").kept_apart
