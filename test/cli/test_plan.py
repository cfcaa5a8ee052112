"""`rbc-registration plan`, run as users run it (a subprocess), against the core planner."""

import json

import numpy as np
import pytest
from test_cli import run as run_cli

from rbc_registration.core import ModelConfig, build_model
from rbc_registration.core.planning.model_planner import plan_from_model
from rbc_registration.core.planning.planner import PlanConfig
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.csv_io import write_fiducials, write_targets

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run(*args, check=True):
    return run_cli("plan", *args, check=check)


@pytest.fixture(scope="module")
def ra(tmp_path_factory):
    """RA-like cell, single measurements: 15 fiducials measured, the other holes candidates."""
    d = tmp_path_factory.mktemp("plan")
    cell = make_cell("RA", seed=3)
    ids = np.array(cell.fiducial_ids)
    measured = np.random.default_rng(0).choice(len(ids), 15, replace=False)
    rest = np.setdiff1d(np.arange(len(ids)), measured)
    first = np.array([m[0] for m in cell.fiducial_measurements])
    write_fiducials(d / "fiducials.csv", ids[measured], [first[i][None] for i in measured],
                    [cell.fiducial_truth[i][None] for i in measured])
    write_targets(d / "candidates.csv", ids[rest], cell.fiducial_means[rest])
    write_targets(d / "targets.csv", cell.target_ids, cell.target_means)
    model = build_model(first[measured], cell.fiducial_truth[measured],
                        ModelConfig(dimension=2, sigma=0.11), ids=list(ids[measured]))
    return d, cell, model, ids[rest], cell.fiducial_means[rest]


def test_plan_prints_and_writes_the_ranking_of_the_library(ra):
    d, cell, model, cand_ids, cand = ra
    out = d / "plan.json"
    proc = run(d / "fiducials.csv", "--candidates", d / "candidates.csv", "--targets",
               d / "targets.csv", "--sigma", "0.11", "--count", "4", "--json", out)
    p = plan_from_model(model, cand, cell.target_means, count=4)
    rep = json.loads(out.read_text())
    assert [s["id"] for s in rep["suggestions"]] == [cand_ids[k] for k in p.sequence]
    assert [s["index"] for s in rep["suggestions"]] == list(p.sequence)
    np.testing.assert_allclose([s["expected_after"] for s in rep["suggestions"]],
                               p.expected_after, rtol=1e-9)
    np.testing.assert_allclose([s["gain"] for s in rep["suggestions"]],
                               -np.diff((p.expected_now,) + p.expected_after), rtol=1e-9)
    assert rep["expected_now"] == pytest.approx(p.expected_now, rel=1e-9)
    assert rep["expected_with_all"] == pytest.approx(p.expected_with_all, rel=1e-9)
    assert (rep["enough"], rep["reason"], rep["enough_after"]) == (p.enough, p.reason,
                                                                  p.enough_after)
    assert rep["error_at"] == "targets" and rep["n_points"] == 80 and rep["n_fiducials"] == 15
    assert rep["dim"] == 2 and rep["corrected"] is True and rep["n_candidates"] == len(cand)
    assert rep["min_gain_fraction"] == 0.0 and rep["min_gain_length"] == 0.0
    assert rep["within"] == 0.1 and rep["enough_rule"] == p.enough_rule
    assert rep["model_check"] == p.model_check.to_dict() and rep["model_check"]["units"] == 15
    assert rep["error_model"]["calibration"] == pytest.approx(p.model_check.ratio, rel=1e-12)
    np.testing.assert_allclose([c["gain"] for c in rep["candidates"]], p.gains, rtol=1e-9)
    assert [c["id"] for c in rep["candidates"]] == list(cand_ids)
    assert sorted(rep["candidates"], key=lambda c: c["rank"])[0]["index"] == p.sequence[0]
    assert rep["error_curve"] == {"n_fiducials": [15, 16, 17, 18, 19],
                                  "expected": pytest.approx((p.expected_now,)
                                                            + p.expected_after, rel=1e-9)}
    # printed: the suggestions in order with their expected error, the error now, the verdict
    lines = proc.stdout.splitlines()
    rows = [next(i for i, line in enumerate(lines) if f"  {cand_ids[k]} " in line)
            for k in p.sequence]
    assert rows == sorted(rows)
    assert f"{p.expected_after[0]:.4g} mm" in lines[rows[0]]
    assert f"expected median target error now  {p.expected_now:.4g} mm" in proc.stdout
    assert f"verdict: {p.reason}" in proc.stdout


def test_stopping_rule_options_reach_the_verdict(ra):
    d, cell, model, cand_ids, cand = ra
    out = d / "loose.json"
    run(d / "fiducials.csv", "--candidates", d / "candidates.csv", "--sigma", "0.11",
        "--count", "1", "--min-gain-fraction", "0.5", "--min-gain", "0.001", "--json", out)
    rep = json.loads(out.read_text())
    p = plan_from_model(model, cand, count=1,
                        config=PlanConfig(min_gain_fraction=0.5, min_gain_length=0.001))
    assert rep["enough"] is True and p.enough and rep["reason"] == p.reason
    assert rep["reason"].startswith("enough:") and "50 %" in rep["reason"]
    assert rep["error_at"] == "work_volume" and rep["min_gain_length"] == 0.001


def test_default_count_is_at_most_the_candidates(tmp_path, ra):
    d = ra[0]
    (tmp_path / "two.csv").write_text("id,wx,wy\nc1,-500,-500\nc2,-300,-600\n")
    rep_path = tmp_path / "two.json"
    run(d / "fiducials.csv", "--candidates", tmp_path / "two.csv", "--json", rep_path)
    rep = json.loads(rep_path.read_text())
    assert len(rep["suggestions"]) == 2 and {s["id"] for s in rep["suggestions"]} == {"c1", "c2"}


def test_figure_is_written_3d_work_volume(tmp_path):
    cell = make_cell("A", seed=1, repeats=2)
    ids = np.array(cell.fiducial_ids)
    measured = np.arange(0, len(ids), 4)         # every 4th grid point measured
    rest = np.setdiff1d(np.arange(len(ids)), measured)
    write_fiducials(tmp_path / "f.csv", ids[measured],
                    [cell.fiducial_measurements[i] for i in measured],
                    [cell.fiducial_truth[i][None] for i in measured])
    write_targets(tmp_path / "c.csv", ids[rest], cell.fiducial_means[rest])
    fig = tmp_path / "out" / "plan.png"
    proc = run(tmp_path / "f.csv", "--candidates", tmp_path / "c.csv", "--count", "3",
               "--figure", fig, "--json", tmp_path / "p.json")
    assert fig.read_bytes()[:8] == PNG_MAGIC and fig.stat().st_size > 20_000
    assert f"wrote {fig}" in proc.stdout
    rep = json.loads((tmp_path / "p.json").read_text())
    assert rep["dim"] == 3 and rep["error_at"] == "work_volume" and len(rep["suggestions"]) == 3


def test_the_top_suggestion_fills_the_empty_region(tmp_path):
    # fiducials on the left half of a plate only: the best candidate is on the right half
    g = np.stack(np.meshgrid(np.arange(0.0, 500, 50), np.arange(0.0, 500, 50)), -1)
    g = g.reshape(-1, 2)
    left = g[g[:, 0] < 250]
    rng = np.random.default_rng(4)
    bias = 0.3 * np.sin(left / 300.0)
    work = left + bias + rng.normal(0, 0.05, left.shape)
    write_fiducials(tmp_path / "f.csv", [f"L{i}" for i in range(len(left))],
                    [w[None] for w in work], [t[None] for t in left])
    write_targets(tmp_path / "c.csv", [f"C{i}" for i in range(len(g))], g)
    out = tmp_path / "p.json"
    run(tmp_path / "f.csv", "--candidates", tmp_path / "c.csv", "--sigma", "0.07",
        "--count", "1", "--json", out)
    best = json.loads(out.read_text())["suggestions"][0]["index"]
    assert g[best, 0] >= 250


def test_targets_are_planned_as_often_measured_as_their_file_says(tmp_path, ra):
    d, cell, _, ids, holes = ra
    write_targets(tmp_path / "t3.csv", [t for t in cell.target_ids for _ in range(3)],
                  np.repeat(cell.target_means, 3, axis=0))
    out = tmp_path / "p.json"
    run(d / "fiducials.csv", "--candidates", d / "candidates.csv", "--targets", tmp_path / "t3.csv",
        "--count", "1", "--json", out)
    rep = json.loads(out.read_text())
    assert (rep["candidate_repeats"], rep["target_repeats"]) == (1, 3)
    run(d / "fiducials.csv", "--candidates", d / "candidates.csv", "--targets", tmp_path / "t3.csv",
        "--count", "1", "--target-repeats", "2", "--candidate-repeats", "4", "--json", out)
    rep = json.loads(out.read_text())
    assert (rep["candidate_repeats"], rep["target_repeats"]) == (4, 2)


def test_candidates_in_another_unit_get_a_warning(tmp_path, ra):
    """Holes in metres against fiducials in mm planned without a word."""
    d, cell, _, ids, holes = ra
    write_targets(tmp_path / "m.csv", ids, holes * 1e-3)
    proc = run(d / "fiducials.csv", "--candidates", tmp_path / "m.csv", "--count", "1")
    warning = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert len(warning) == 1 and warning[0].startswith("rbc-registration plan: warning: all "
                                                       f"{len(ids)} candidates are outside")
    assert "likely a unit mismatch between candidates and fiducials" in warning[0]
    proc = run(d / "fiducials.csv", "--candidates", d / "candidates.csv", "--count", "1")
    assert "warning" not in proc.stderr


def test_plan_warns_of_its_model_as_register_does(tmp_path, ra):
    """``plan`` built the model ``register`` warns about without a word: a cell 1000x too large
    for its unit, a typo'd fiducial. It prints register's model warnings now (one function,
    cli/options.warn_model)."""
    d, cell, _, ids, holes = ra
    fid = (d / "fiducials.csv").read_text().splitlines()
    big = [fid[0]] + [",".join([r.split(",")[0]] + [repr(float(v) * 1e3) for v in
                                                     r.split(",")[1:]]) for r in fid[1:]]
    (tmp_path / "km.csv").write_text("\n".join(big) + "\n")
    write_targets(tmp_path / "holes.csv", ids, holes * 1e3)
    for command in ("plan", "register"):
        args = [tmp_path / "km.csv"] + (["--candidates", tmp_path / "holes.csv", "--count", "1"]
                                        if command == "plan" else [])
        proc = run_cli(command, *args)
        lines = [line for line in proc.stderr.splitlines() if "larger than any cell" in line]
        assert len(lines) == 1 and lines[0].startswith(f"rbc-registration {command}: warning: "
                                                       "the fiducials' RMS distance"), proc.stderr


@pytest.mark.parametrize("args, message", [
    (["{fid}", "--candidates", "missing.csv"], "missing.csv: no such file"),
    (["{fid}", "--candidates", "{bad}"], "row 3: column wy is not a number"),
    (["{fid}", "--candidates", "{nowz}", "--dim", "3"], "--dim 3 needs columns"),
    (["{fid3}", "--candidates", "{nowz}"], "missing column(s) wz"),
    (["{fid}", "--candidates", "{cand}", "--targets", "{bad}"], "column wy is not a number"),
    (["{fid}", "--candidates", "{cand}", "--count", "0"], "count must be a positive integer"),
    (["{fid}", "--candidates", "{nowz}", "--count", "3"],
     "count (3) exceeds the number of candidates (2)"),
    (["{fid}", "--candidates", "{cand}", "--min-gain-fraction", "1.5"],
     "--min-gain-fraction: min_gain_fraction must be in [0, 1), got 1.5"),
    (["{fid}", "--candidates", "{cand}", "--candidate-repeats", "0"],
     "--candidate-repeats: candidate_repeats must be a positive integer, got 0"),
    (["{fid}", "--candidates", "{far}"], "candidate 1 (1e+06, 0) is "),
    (["{fid}", "--candidates", "{cand}", "--figure", "plan"], "--figure plan: must name a .png"),
    (["{fid}", "--candidates", "{cand}", "--figure", "out/"], "names a directory, not a file"),
    (["{fid}", "--candidates", "{cand}", "--min-gain", "-1"],
     "min_gain_length must be a finite length >= 0, got -1.0"),
    (["{fid}", "--candidates", "{cand}", "--min-gain", "nan"], "min_gain_length must be"),
    (["{few}", "--candidates", "{cand}"], "needs at least 3 fiducials, got 2"),
    (["{fid}", "--candidates", "{empty}"], "no data rows"),
    (["{fid}", "--candidates", "{dupid}"],
     "id 'a' (first at row 2) has conflicting working points: row 4: candidate 'a'"),
    (["{fid}", "--candidates", "{cand}", "--targets", "{dupid}"], "row 4: target 'a'"),
])
def test_bad_input_is_one_clear_line(tmp_path, ra, args, message):
    (tmp_path / "bad.csv").write_text("id,wx,wy\na,1,2\nb,1,x\n")
    (tmp_path / "nowz.csv").write_text("id,wx,wy\na,1,2\nb,3,4\n")
    (tmp_path / "empty.csv").write_text("id,wx,wy\n")
    (tmp_path / "far.csv").write_text("id,wx,wy\na,100,100\nb,1000000,0\n")     # a typo'd hole
    (tmp_path / "dupid.csv").write_text("id,wx,wy\na,0,0\nb,100,0\na,60,0\n")
    (tmp_path / "few.csv").write_text("id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,1,0\n")
    (tmp_path / "fid3.csv").write_text("id,wx,wy,wz,dx,dy,dz\n" + "".join(
        f"p{i},{x},{y},{z},{x},{y},{z}\n" for i, (x, y, z) in enumerate(
            [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)])))
    files = {"bad": tmp_path / "bad.csv", "nowz": tmp_path / "nowz.csv",
             "empty": tmp_path / "empty.csv", "dupid": tmp_path / "dupid.csv",
             "far": tmp_path / "far.csv",
             "few": tmp_path / "few.csv",
             "fid3": tmp_path / "fid3.csv", "fid": ra[0] / "fiducials.csv",
             "cand": ra[0] / "candidates.csv"}
    proc = run(*[a.format(**files) for a in args], check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert proc.stderr.startswith("rbc-registration plan: error: ")


def test_a_group_column_plans_poses(ra, tmp_path):
    """CANDIDATES.csv with a group column: a group (a robot pose) is ranked and suggested as a
    whole; the JSON lists the groups, every candidate carries its group's gain and rank."""
    d, cell, model, cand_ids, cand = ra
    cand, cand_ids = cand[:60], cand_ids[:60]
    labels = [f"p{k // 3}" for k in range(len(cand))]
    path = tmp_path / "posed.csv"
    rows = ["id,wx,wy,group"] + [f"{i},{float(x)!r},{float(y)!r},{g}" for i, (x, y), g in
                                 zip(cand_ids, cand, labels)]
    path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "posed.json"
    proc = run(d / "fiducials.csv", "--candidates", path, "--sigma", "0.11", "--count", "2",
               "--json", out)
    p = plan_from_model(model, cand, count=2, groups=labels)
    rep = json.loads(out.read_text())
    assert [s["group"] for s in rep["suggestions"]] == [p.unit_labels[u] for u in p.sequence]
    assert [s["ids"] for s in rep["suggestions"]] == [[cand_ids[c] for c in p.members[u]]
                                                     for u in p.sequence]
    np.testing.assert_allclose([s["expected_after"] for s in rep["suggestions"]],
                               p.expected_after, rtol=1e-9)
    assert len(rep["groups"]) == 20 and rep["n_candidates"] == 60
    np.testing.assert_allclose([g["gain"] for g in rep["groups"]], p.gains, rtol=1e-9)
    for c in rep["candidates"]:
        g = rep["groups"][int(c["group"][1:])]
        assert (c["gain"], c["rank"]) == (g["gain"], g["rank"]) and c["id"] in g["ids"]
    assert rep["error_curve"]["n_fiducials"] == [15, 18, 21]
    first = p.unit_labels[p.sequence[0]]
    assert f"group {first}: " in proc.stdout and rep["reason"] == p.reason
    # one id in two groups is refused, naming the row
    path.write_text("id,wx,wy,group\nh1,1,2,a\nh1,1,2,b\nh2,5,6,a\n")
    bad = run(d / "fiducials.csv", "--candidates", path, "--sigma", "0.11", check=False)
    assert bad.returncode != 0
    assert "row 3: id 'h1' is in group 'b' here and in group 'a' in an earlier row" in bad.stderr
