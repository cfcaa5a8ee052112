"""`register` and `plan` with the group and session columns (CSV), as users run them."""

import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import make_robot_cell, moved_sessions


def run(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "rbc_registration.cli", *map(str, args)],
                          capture_output=True, text=True,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def _write(path, header, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _session_files(d, move, seed=0):
    sc = moved_sessions(make_cell("RA", seed, repeats=1), seed, move)
    _write(d / f"fid{move}.csv", ["id", "session", "wx", "wy", "dx", "dy"],
           [[i, s, *p, *q] for i, s, p, q in zip(sc.ids, sc.sessions, sc.working,
                                                  sc.destination)])
    k = len(sc.target_truth)
    _write(d / f"tgt{move}.csv", ["id", "session", "wx", "wy", "dx", "dy"],
           [[i, s, *p, *sc.target_truth[n % k]]
            for n, (i, s, p) in enumerate(zip(sc.target_ids, sc.target_sessions,
                                              sc.target_working))])
    return d / f"fid{move}.csv", d / f"tgt{move}.csv"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("sessions")
    out = {}
    for move in (3.0, 0.0):
        fid, tgt = _session_files(d, move)
        js = d / f"r{move}.json"
        proc = run("register", fid, "--targets", tgt, "--unit", "mm", "--json", js)
        out[move] = (proc, json.loads(js.read_text()))
    return d, out


def test_a_moved_session_is_reported_and_restationed(sessions):
    _, out = sessions
    proc, rep = out[3.0]
    first = rep["sessions"][0]
    assert first["session"] == "s1" and first["moved"] and first["p_value"] < 1e-6
    assert first["n_common"] == 83 and len(first["translation"]) == 2
    assert proc.stderr.count("re-stationed") == 1 and "'s1' moved against 's2'" in proc.stderr


def test_restationed_targets_are_as_good_as_without_the_move(sessions):
    _, out = sessions
    moved = out[3.0][1]["summary"]["tre_median"]
    still = out[0.0][1]["summary"]["tre_median"]
    assert moved <= 1.1 * still
    assert not out[0.0][1]["sessions"][0]["moved"]
    assert "re-stationed" not in out[0.0][0].stderr


def test_without_sessions_the_move_is_mixed_in(sessions):
    d, out = sessions
    text = (d / "fid3.0.csv").read_text().replace(",session,", ",phase,")
    (d / "mixed.csv").write_text(text)
    tgt = (d / "tgt3.0.csv").read_text().replace(",session,", ",phase,")
    (d / "mixed_t.csv").write_text(tgt)
    js = d / "mixed.json"
    run("register", d / "mixed.csv", "--targets", d / "mixed_t.csv", "--json", js)
    rep = json.loads(js.read_text())
    assert "sessions" not in rep
    assert rep["summary"]["tre_median"] > 1.5 * out[3.0][1]["summary"]["tre_median"]


def test_a_target_session_the_fiducials_lack_is_one_line(tmp_path):
    fid, tgt = _session_files(tmp_path, 3.0)
    text = tgt.read_text().replace(",s2,", ",s9,")
    tgt.write_text(text)
    proc = run("register", fid, "--targets", tgt, check=False)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert "'s9'" in proc.stderr


def test_a_session_kept_apart_is_said_and_left_out(tmp_path):
    cell = make_cell("RA", 1, repeats=1)
    rows = [[i, "a", *m[0], *t] for i, m, t in zip(cell.fiducial_ids, cell.fiducial_measurements,
                                                   cell.fiducial_truth)]
    rows += [["F000", "b", *(cell.fiducial_measurements[0][0] + 3), *cell.fiducial_truth[0]],
             ["NEW1", "b", 900.0, 900.0, 900.0, 900.0]]
    _write(tmp_path / "f.csv", ["id", "session", "wx", "wy", "dx", "dy"], rows)
    js = tmp_path / "r.json"
    proc = run("register", tmp_path / "f.csv", "--json", js)
    rep = json.loads(js.read_text())
    assert [s["kept_apart"] for s in rep["sessions"]] == [False, True]
    assert "kept apart" in proc.stderr and rep["n_fiducials"] == 277


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    d = tmp_path_factory.mktemp("robot")
    cell = make_robot_cell(0)
    _write(d / "grouped.csv", ["id", "group", "wx", "wy", "wz", "dx", "dy", "dz"],
           [[i, g, *p, *q] for i, g, p, q in zip(cell.fiducial_ids, cell.fiducial_groups,
                                                  cell.working, cell.destination)])
    _write(d / "plain.csv", ["id", "wx", "wy", "wz", "dx", "dy", "dz"],
           [[i, *p, *q] for i, p, q in zip(cell.fiducial_ids, cell.working, cell.destination)])
    _write(d / "targets.csv", ["id", "wx", "wy", "wz", "dx", "dy", "dz"],
           [[f"T{k}", *p, *q] for k, (p, q) in enumerate(zip(cell.target_working,
                                                              cell.target_truth))])
    return d, cell


def test_groups_are_held_out_whole(robot):
    d, cell = robot
    js = d / "g.json"
    proc = run("register", d / "grouped.csv", "--targets", d / "targets.csv", "--json", js)
    rep = json.loads(js.read_text())
    assert rep["decision"]["folds"] == {"kind": "leave-one-out", "n_folds": 36,
                                        "grouped": True}
    assert "leave-one-group-out, 36 folds" in proc.stdout
    assert "`group`" not in proc.stderr


def test_ids_of_one_pose_without_groups_get_one_warning(robot):
    d, _ = robot
    proc = run("register", d / "plain.csv")
    lines = [line for line in proc.stderr.splitlines() if "`group`" in line]
    assert len(lines) == 1 and "pose00_N1" in lines[0]


def test_one_id_in_two_groups_is_refused(robot, tmp_path):
    d, _ = robot
    text = (d / "grouped.csv").read_text().splitlines()
    text.append(text[1].replace("pose00,", "pose99,", 1))
    (tmp_path / "bad.csv").write_text("\n".join(text) + "\n")
    proc = run("register", tmp_path / "bad.csv", check=False)
    assert proc.returncode == 2 and "one fiducial, one group" in proc.stderr


def test_plan_takes_the_columns(robot, tmp_path):
    d, cell = robot
    rng = np.random.default_rng(0)
    cand = rng.uniform(100, 900, size=(20, 3))
    _write(tmp_path / "cand.csv", ["id", "wx", "wy", "wz"],
           [[f"C{k}", *p] for k, p in enumerate(cand)])
    proc = run("plan", d / "grouped.csv", "--candidates", tmp_path / "cand.csv", "--count", "2")
    assert "`group`" not in proc.stderr
