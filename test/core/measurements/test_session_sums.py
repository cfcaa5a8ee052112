"""The accumulator's sessions (core/measurements/session_sums.py,
core/measurements/accumulator.py): declared sessions
re-stationed into the current one, the live bump rule opening ``auto-N``, sessions kept apart,
groups kept per fiducial (a conflicting group rejected), and a restore giving the same state."""

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.measurements.records import (FiducialRepeats, Measurement,
                                                        RejectedMeasurement)
from rbc_registration.core.measurements.session_sums import SessionSums
from rbc_registration.core.measurements.sessions import estimate_sessions, session_cells
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import moved_sessions


def _acc(d: int = 2) -> FiducialAccumulator:
    return FiducialAccumulator(d, "tracker", "world", merge_radius=1.0)


def _stream(acc: FiducialAccumulator, cell, labelled: bool) -> list[Measurement]:
    """Every measurement of a session cell, in order; sessions given when ``labelled``."""
    records = []
    for k, (fid, ses) in enumerate(zip(cell.ids, cell.sessions)):
        record = acc.prepare(fid, cell.working[k], cell.destination[k], stamp_s=100.0 + k,
                             session=ses if labelled else "")
        acc.commit(record)
        records.append(record)
    return records


def _restationed_means(cell) -> dict[str, np.ndarray]:
    """The CSV rule (re-station the rows, then average per id), for comparison."""
    plan = estimate_sessions(session_cells(cell.ids, cell.sessions, cell.working))
    points, keep = plan.apply(cell.working, cell.sessions)
    assert keep.all()
    out: dict[str, list] = {}
    for fid, p in zip(cell.ids, points):
        out.setdefault(fid, []).append(p)
    return {f: np.mean(v, axis=0) for f, v in out.items()}


@pytest.mark.parametrize("name", ["RA", "A"])
def test_declared_sessions_are_restationed_as_the_csv_rule_does(name):
    cell = moved_sessions(make_cell(name, 3, repeats=1), 3, 3.0)
    acc = _acc(make_cell(name, 3, repeats=1).spec.dimension)
    _stream(acc, cell, labelled=True)
    fs = acc.fiducial_set()
    assert fs.sessions is not None and fs.sessions.reference == "s2"
    assert fs.sessions.motion("s1").moved
    want = _restationed_means(cell)
    assert set(fs.ids) == set(want)
    for fid, w in zip(fs.ids, fs.working):
        np.testing.assert_allclose(w, want[fid], atol=1e-9)
    assert [s for s, _ in fs.session_starts] == ["s1", "s2"]
    assert dict(fs.session_starts)["s2"] == 100.0 + cell.sessions.index("s2")


def test_a_bump_nobody_declared_opens_a_session_where_it_began():
    cell = moved_sessions(make_cell("RA", 1, repeats=1), 1, 3.0)
    acc = _acc()
    _stream(acc, cell, labelled=False)
    began = cell.sessions.index("s2")
    assert acc.sessions.names == ("1", "auto-1") and acc.sessions.current == "auto-1"
    name, bump = acc.sessions.bumps[-1]
    assert name == "auto-1" and bump.start == began
    fs = acc.fiducial_set()
    assert fs.sessions.reference == "auto-1" and fs.sessions.motion("1").moved
    assert dict(fs.session_starts)["auto-1"] == 100.0 + began
    # the same fiducial set as with the sessions declared
    declared = _acc()
    _stream(declared, cell, labelled=True)
    ds = declared.fiducial_set()
    assert fs.ids == ds.ids
    np.testing.assert_allclose(fs.working, ds.working, atol=1e-9)
    np.testing.assert_allclose(fs.repeat_stats.variances, ds.repeat_stats.variances, rtol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_a_still_cell_opens_no_session(seed):
    cell = moved_sessions(make_cell("RA", seed, repeats=1), seed, 0.0)
    acc = _acc()
    _stream(acc, cell, labelled=False)
    assert acc.sessions.names == ("1",) and not acc.sessions.bumps
    fs = acc.fiducial_set()
    assert fs.sessions is None and fs.session_starts == ()


def test_a_session_with_too_few_common_fiducials_is_kept_apart():
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 1000, size=(12, 3))
    acc = _acc(3)
    for k, p in enumerate(pts):
        acc.add(f"F{k}", p, p, session="a")
    acc.add("F0", pts[0] + 0.3, pts[0], session="b")      # b shares 2 fiducials with a
    acc.add("F1", pts[1] + 0.3, pts[1])
    acc.add("X", [5.0, 5.0, 5.0], [5.0, 5.0, 5.0], session="c")
    for k in range(2, 6):                                 # c shares 4 with a: joined
        acc.add(f"F{k}", pts[k] + [0.5, 0.0, 0.0], pts[k])
    fs = acc.fiducial_set()
    plan = fs.sessions
    assert plan.reference == "c" and plan.motion("b").kept_apart
    assert not plan.motion("a").kept_apart
    # b's two measurements are left out: F0 and F1 carry a's single measurement only
    assert dict(zip(fs.ids, fs.repeat_stats.counts))["F0"] == 1
    assert "kept apart" in plan.warning()


def test_the_current_session_kept_apart_leaves_only_its_own_fiducials():
    rng = np.random.default_rng(6)
    pts = rng.uniform(0, 1000, size=(10, 2))
    acc = _acc()
    for k, p in enumerate(pts):
        acc.add(f"F{k}", p, p)
    acc.add("F0", pts[0] + 1.0, pts[0], session="after lunch")
    fs = acc.fiducial_set()
    assert fs.ids == ("F0",) and fs.sessions.reference == "after lunch"
    assert fs.sessions.motion("1").kept_apart


def test_a_fiducial_keeps_its_group_and_another_group_is_a_conflict():
    acc = _acc()
    acc.add("P1_a", [0.0, 0.0], [0.0, 0.0], group="pose1")
    acc.add("P1_a", [0.0, 0.0], [0.0, 0.0])                 # empty: the same group
    acc.add("P1_b", [50.0, 0.0], [50.0, 0.0], group="pose1")
    acc.add("Q", [0.0, 80.0], [0.0, 80.0])
    with pytest.raises(RejectedMeasurement) as info:
        acc.add("P1_a", [0.0, 0.0], [0.0, 0.0], group="pose2")
    assert info.value.reason == "conflict" and "'pose1'" in info.value.message
    assert acc.rejected["conflict"] == 1
    assert acc.fiducial_set().groups == ("pose1", "pose1", "")
    bad = "x" * 300
    with pytest.raises(RejectedMeasurement, match="group must be at most"):
        acc.add("Q", [0.0, 80.0], [0.0, 80.0], group=bad)
    with pytest.raises(RejectedMeasurement, match="session must be"):
        acc.add("Q", [0.0, 80.0], [0.0, 80.0], session="a\nb")


def test_no_group_given_is_none():
    acc = _acc()
    acc.add("A", [0.0, 0.0], [0.0, 0.0])
    assert acc.fiducial_set().groups is None


def test_restore_gives_the_same_sessions_bumps_and_groups():
    cell = moved_sessions(make_cell("RA", 2, repeats=1), 2, 3.0)
    acc = _acc()
    records = _stream(acc, cell, labelled=False)
    records[0] = Measurement(records[0].fiducial_id, records[0].working,
                             records[0].destination, records[0].stamp_s, group="g0")
    acc.restore(records)
    again = _acc()
    assert again.restore(records) == []
    assert again.session_digest() == acc.session_digest()
    assert again.state_digest() == acc.state_digest()
    assert again.sessions.names == ("1", "auto-1")
    np.testing.assert_array_equal(again.fiducial_set().working, acc.fiducial_set().working)


def test_remove_takes_back_an_add():
    rng = np.random.default_rng(1)
    r = FiducialRepeats(3)
    points = [tuple(rng.normal(size=3)) for _ in range(5)]
    for p in points:
        r.add(p, p)
    r.remove(points[-1], points[-1])
    ref = FiducialRepeats(3)
    for p in points[:-1]:
        ref.add(p, p)
    np.testing.assert_allclose(r.mean_w(), ref.mean_w(), atol=1e-12)
    assert r.n == 4 and r.variance_w() == pytest.approx(ref.variance_w(), rel=1e-9)
    for p in points[:-1]:
        r.remove(p, p)
    assert r.n == 0 and r.mean_w() == (0.0, 0.0, 0.0)


def test_a_bump_older_than_the_tail_moves_only_the_tail():
    sums = SessionSums(2, tail=4)
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 100, size=(8, 2))
    for k, p in enumerate(pts):
        sums.add(Measurement(f"F{k}", tuple(p), tuple(p), float(k)))
    moved = 0
    for k, p in enumerate(pts):
        bump = sums.add(Measurement(f"F{k}", tuple(p + [3.0, -2.0]), tuple(p), 10.0 + k))
        if bump is not None:
            moved = k
            break
    assert sums.current == "auto-1"
    assert sum(c.n for c in sums._cells["auto-1"].values()) == min(4, moved + 1)
