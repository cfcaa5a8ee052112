"""A bag with two sessions (``FiducialPair.session``, the working frame moved between them)
evaluates to the fiducials, targets and ``sessions`` list of ``register`` on the same data as CSV
with a ``session`` column; recorded targets and a TARGETS.csv with sessions are re-stationed by
the same rule; a target in a session the fiducials lack is refused in one line. No rclpy."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.core.constants import M_PER_MM
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import moved_sessions
from rbc_registration.io.bag.records import DEFAULT_TOPICS, OutMessage
from rbc_registration.io.bag.writer import write_bag

M = M_PER_MM   # the synthetic cells are in mm; bags and these CSVs are in metres
AXES = ("x", "y", "z")


def _xyz(p) -> tuple[float, float, float]:
    return tuple(float(v) for v in p * M)


def _write_csv(path: Path, ids, sessions, working, truth) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "session", *(f"w{a}" for a in AXES), *(f"d{a}" for a in AXES)])
        for i, s, p, q in zip(ids, sessions, working, truth):
            w.writerow([i, s, *(repr(v) for v in _xyz(p)), *(repr(v) for v in _xyz(q))])
    return path


def _target_truth(sc):
    k = len(sc.target_truth)
    return [sc.target_truth[n % k] for n in range(len(sc.target_ids))]


def _messages(sc, target_sessions=None):
    """The session cell as FiducialPair messages, fiducials then targets, 0.1 s apart."""
    step = 100_000_000
    out = [OutMessage(DEFAULT_TOPICS.fiducial_pairs, "pair", (k + 1) * step, "tracker", _xyz(w),
                      fid, "world", _xyz(d), session=s)
           for k, (fid, s, w, d) in enumerate(zip(sc.ids, sc.sessions, sc.working,
                                                   sc.destination))]
    n = len(out)
    sessions = sc.target_sessions if target_sessions is None else target_sessions
    out += [OutMessage(DEFAULT_TOPICS.targets, "pair", (n + k + 1) * step, "tracker", _xyz(w),
                       tid, "world", _xyz(t), session=s)
            for k, (tid, s, w, t) in enumerate(zip(sc.target_ids, sessions, sc.target_working,
                                                    _target_truth(sc)))]
    return out


def _json(argv, path: Path) -> dict:
    assert cli.main(argv + ["--json", str(path)]) == 0
    return json.loads(path.read_text())


def _same(a, b, path="report", rtol=1e-9, atol=1e-15):
    """Equal structure; numbers equal to rounding."""
    if isinstance(a, dict):
        for key in a:
            assert key in b, f"{path}.{key} missing"
            _same(a[key], b[key], f"{path}.{key}", rtol, atol)
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{k}]", rtol, atol)
    elif isinstance(a, float) and isinstance(b, float):
        assert b == pytest.approx(a, rel=rtol, abs=atol), path
    else:
        assert a == b, path


#: Not through the kriging fit: equal to rounding.
EXACT = ("dim", "n_fiducials", "n_measurements", "sigma", "sigma_axis", "sigma_source",
         "sigma_L", "rho", "uncorrected", "corrected", "fiducials", "sessions")
#: Per target, the values that go through the kriging fit (hyper-parameters equal to ~1e-7).
FITTED = ("destination", "tre", "expected_tre", "tre_bound")


@pytest.fixture(scope="module")
def cell():
    return moved_sessions(make_cell("A", 4, repeats=1), 4, 3.0)


@pytest.fixture(scope="module")
def reports(cell, tmp_path_factory):
    d = tmp_path_factory.mktemp("bag_sessions")
    fid = _write_csv(d / "FIDUCIALS.csv", cell.ids, cell.sessions, cell.working,
                     cell.destination)
    tgt = _write_csv(d / "TARGETS.csv", cell.target_ids, cell.target_sessions,
                     cell.target_working, _target_truth(cell))
    write_bag(d / "bag", _messages(cell), "mcap", progress=False)
    reg = _json(["register", str(fid), "--targets", str(tgt), "--unit", "m"], d / "r.json")
    ev = _json(["evaluate", str(d / "bag"), "--quiet"], d / "e.json")
    return d, reg, ev


def test_the_bag_evaluates_to_the_fiducials_and_targets_of_register(reports):
    _, reg, ev = reports
    assert reg["sessions"][0]["session"] == "s1" and reg["sessions"][0]["moved"]
    _same({k: reg[k] for k in EXACT}, ev)
    assert [t["id"] for t in ev["targets"]] == [t["id"] for t in reg["targets"]]
    for a, b in zip(reg["targets"], ev["targets"]):
        _same({k: v for k, v in a.items() if k not in FITTED}, b)
        _same({k: a[k] for k in FITTED}, b, rtol=1e-5)
    assert ev["decision"]["method"] == reg["decision"]["method"]


def test_the_warning_line_names_the_move(reports, capsys):
    d, _, ev = reports
    line = [w for w in ev["warnings"] if "re-stationed" in w]
    assert len(line) == 1 and "session 's1' moved against 's2'" in line[0]
    assert "sessions start at stamp 's1' at 0.100 s" in line[0]
    assert cli.main(["evaluate", str(d / "bag"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.count("re-stationed") == 1 and "'s1' moved against 's2'" in err


def test_targets_csv_with_sessions_match_the_recorded_targets(reports, cell):
    d, _, ev = reports
    write_bag(d / "fiducials_only", [m for m in _messages(cell)
                                     if m.topic == DEFAULT_TOPICS.fiducial_pairs],
              "sqlite3", progress=False)
    by_csv = _json(["evaluate", str(d / "fiducials_only"), "--targets",
                    str(d / "TARGETS.csv"), "--quiet"], d / "c.json")
    for a, b in zip(ev["targets"], by_csv["targets"]):
        _same({k: v for k, v in a.items() if k not in FITTED}, b)


def test_a_target_without_a_session_is_in_the_reference_session(reports, cell, tmp_path):
    """Empty sessions continue the previous target message's, the first the reference's: the
    targets measured in s2 given once with their session, then with none, are the same."""
    d, _, _ = reports
    second = [k for k, s in enumerate(cell.target_sessions) if s == "s2"]
    msgs = [m for m in _messages(cell) if m.topic == DEFAULT_TOPICS.fiducial_pairs]
    targets = [m for m in _messages(cell) if m.topic == DEFAULT_TOPICS.targets]
    named = [targets[k] for k in second]
    write_bag(tmp_path / "named", msgs + named, "mcap", progress=False)
    write_bag(tmp_path / "empty", msgs + [m._replace(session="") for m in named], "mcap",
              progress=False)
    a = _json(["evaluate", str(tmp_path / "named"), "--quiet"], tmp_path / "a.json")
    b = _json(["evaluate", str(tmp_path / "empty"), "--quiet"], tmp_path / "b.json")
    assert a["targets"] == b["targets"]
    # the s1 measurements of the same targets are re-stationed: nearer to the s2 ones than when
    # they are said to be in s2 (the move left in)
    first = [targets[k] for k in range(len(targets)) if cell.target_sessions[k] == "s1"]
    write_bag(tmp_path / "first", msgs + first, "mcap", progress=False)
    write_bag(tmp_path / "mixed", msgs + [m._replace(session="s2") for m in first], "mcap",
              progress=False)
    c = _json(["evaluate", str(tmp_path / "first"), "--quiet"], tmp_path / "c.json")
    e = _json(["evaluate", str(tmp_path / "mixed"), "--quiet"], tmp_path / "e.json")

    def rms(report):
        diff = [np.subtract(t["uncorrected"], u["uncorrected"])
                for t, u in zip(report["targets"], a["targets"])]
        return float(np.sqrt(np.mean(np.sum(np.square(diff), axis=1))))

    assert rms(c) < 0.6 * rms(e)


def test_a_target_in_an_unknown_session_is_refused_in_one_line(cell, tmp_path, capsys):
    labels = ["lunch"] * len(cell.target_ids)
    write_bag(tmp_path / "bag", _messages(cell, labels), "mcap", progress=False)
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "session 'lunch' is not among the fiducials' sessions ('s1', 's2')" in err[0]


def _write_legacy(path: Path, messages) -> None:
    """A bag of FiducialPair recorded with the definition without group and session."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from rbc_registration.io.bag.reader import legacy_typestore
    from rbc_registration.io.bag.records import FIDUCIAL_PAIR

    store = legacy_typestore()
    t = store.types
    conns = {}
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        for m in messages:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, FIDUCIAL_PAIR, typestore=store)
            header = t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=m.stamp_ns // 10**9,
                                                       nanosec=m.stamp_ns % 10**9),
                frame_id=m.frame_id)
            point = t["geometry_msgs/msg/Point"]
            msg = t[FIDUCIAL_PAIR](header=header, fiducial_id=m.fiducial_id,
                                   working_point=point(*m.xyz),
                                   destination_frame_id=m.destination_frame,
                                   destination_point=point(*m.destination))
            writer.write(conns[m.topic], m.stamp_ns, store.serialize_cdr(msg, FIDUCIAL_PAIR))


def test_a_bag_recorded_without_group_and_session_is_read_with_a_note(cell, tmp_path):
    """The earlier FiducialPair (no group, no session): read as empty fields, the same model
    as the bag of today's definition with empty fields (the bump rule still applies)."""
    from rbc_registration.io.bag.reader import read_bag

    plain = [m._replace(session="") for m in _messages(cell)]
    _write_legacy(tmp_path / "old", plain)
    write_bag(tmp_path / "new", plain, "sqlite3", progress=False)
    old, new = read_bag(tmp_path / "old", progress=False), read_bag(tmp_path / "new",
                                                                    progress=False)
    assert old.inputs == new.inputs and old.targets == new.targets
    assert [n for n in old.notes if "without group and session: read as empty" in n]
    assert not new.notes
    a = _json(["evaluate", str(tmp_path / "old"), "--quiet"], tmp_path / "a.json")
    b = _json(["evaluate", str(tmp_path / "new"), "--quiet"], tmp_path / "b.json")
    assert a["targets"] == b["targets"] and a["fiducials"] == b["fiducials"]
