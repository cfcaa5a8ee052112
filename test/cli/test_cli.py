"""The `rbc-registration` command, run as users run it (a subprocess), against the core library."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from rbc_registration.core import ModelConfig, build_model, leave_one_out, target_errors
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.csv_io import write_fiducials, write_targets
from rbc_registration.io.report import format_report, model_report


def run(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "rbc_registration.cli", *map(str, args)],
                          capture_output=True, text=True,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture(scope="module")
def ra_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("ra")
    cell = make_cell("RA", seed=3)
    write_fiducials(d / "fiducials.csv", cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    write_targets(d / "targets.csv", cell.target_ids, cell.target_means, cell.target_truth)
    return d, cell


@pytest.mark.parametrize("interpolation", ["paper", "kriging"])
def test_register_matches_the_library(ra_files, interpolation):
    d, cell = ra_files
    out = d / f"report_{interpolation}.json"
    proc = run("register", d / "fiducials.csv", "--targets", d / "targets.csv",
               "--interpolation", interpolation, "--json", out)
    assert "rho" in proc.stdout and "TRE uncorrected" in proc.stdout
    assert "decision     cv -> " in proc.stdout
    rep = json.loads(out.read_text())
    model = build_model(cell.fiducial_means, cell.fiducial_truth,
                        ModelConfig(dimension=2, interpolation=interpolation),
                        working_repeats=cell.fiducial_measurements)
    err = target_errors(model, cell.target_means, cell.target_truth)
    assert rep["dim"] == 2 and rep["n_fiducials"] == 277 and rep["sigma_source"] == "repeats"
    np.testing.assert_allclose(rep["sigma_L"], model.sigma_l, rtol=1e-6, atol=1e-15)
    assert rep["rho"] == pytest.approx(model.rho) and rep["recommendation"] == model.recommendation
    assert rep["uncorrected"]["fre_rms"] == pytest.approx(model.uncorrected.fre_rms)
    assert rep["corrected"]["fre_rms"] < 1e-8
    np.testing.assert_allclose(rep["corrected"]["rotation"], model.corrected.rotation, atol=1e-12)
    np.testing.assert_allclose([t["tre_c"] for t in rep["targets"]], err.tre_c, rtol=1e-9)
    np.testing.assert_allclose([t["tre_u"] for t in rep["targets"]], err.tre_u, rtol=1e-9)
    assert {k: rep["summary"][k] for k in err.summary()} == pytest.approx(err.summary())
    assert set(rep["summary"]) == set(err.summary()) | {"tre_median", "fraction_within_bound"}
    assert {"id", "destination", "expected_tre", "tre_bound", "tre", "tre_u", "tre_c",
            "uncorrected", "corrected",
            "correction", "inside_hull", "expected_error"} == set(rep["targets"][0])
    assert rep["decision"]["method"] == model.decision.method
    assert rep["sigma_axis"] == pytest.approx(model.sigma_axis)
    assert (rep["targets"][0]["expected_error"] is None) == (interpolation == "paper")


def test_register_loo_closed_form_and_subsets(ra_files):
    d, cell = ra_files
    out = d / "loo.json"
    ids = cell.fiducial_ids
    run("register", d / "fiducials.csv", "--loo", "--restoration", "closed-form",
        "--uncorrected-fit", ",".join(ids[i] for i in (0, 40, 120, 200, 270)),
        "--corrected-fit", ",".join(ids[i] for i in (10, 150, 260)), "--json", out)
    rep = json.loads(out.read_text())
    model = build_model(cell.fiducial_means, cell.fiducial_truth,
                        ModelConfig(dimension=2, restoration="closed-form",
                                    uncorrected_subset=(0, 40, 120, 200, 270),
                                    corrected_subset=(10, 150, 260)),
                        working_repeats=cell.fiducial_measurements)
    loo = leave_one_out(model)
    assert rep["loo"]["tre_c_median"] == pytest.approx(float(np.median(loo.tre_c)))
    assert len(rep["loo"]["fiducials"]) == 277 and rep["steps"] == 1
    assert rep["targets"] == [] and rep["summary"]["tre_u_median"] is None


@pytest.mark.parametrize("args, message", [
    (["register", "missing.csv"], "no such file"),
    (["register", "{bad}"], "column wz is not a number"),
    (["register", "{good}", "--sigma", "-1"], "sigma must be"),
    (["register", "{good}", "--corrected-fit", "nope"], "unknown fiducial id"),
    (["register", "{few}"], "at least 4"),
    (["register", "{good}", "--steps", "1000000"], "must be in 1..20"),   # issue 11: bounds
    (["register", "{good}", "--steps", "0"], "steps must be a positive integer"),
    (["register", "{huge}"], "row 3: column wx is out of range: '1e140'"),   # qhull crashed
])
def test_bad_input_is_one_clear_line(tmp_path, ra_files, args, message):
    (tmp_path / "bad.csv").write_text("id,wx,wy,wz,dx,dy,dz\na,1,2,x,1,2,3\n")
    (tmp_path / "few.csv").write_text("id,wx,wy,wz,dx,dy,dz\na,0,0,0,0,0,0\nb,1,0,0,1,0,0\n"
                                      "c,0,1,0,0,1,0\n")
    huge = ("1e140,0,0", "0,1e140,0", "0,0,1e140", "1e140,1e140,1e140")
    (tmp_path / "huge.csv").write_text("id,wx,wy,wz,dx,dy,dz\na,0,0,0,0,0,0\n" + "".join(
        f"{k},{p},{p}\n" for k, p in zip("bcde", huge)))
    files = {"bad": tmp_path / "bad.csv", "few": tmp_path / "few.csv",
             "huge": tmp_path / "huge.csv",
             "good": ra_files[0] / "fiducials.csv"}
    proc = run(*[a.format(**files) for a in args], check=False)
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_console_script_is_installed():
    # pip puts it beside the interpreter; colcon in <prefix>/lib/rbc_registration (for ros2 run)
    candidates = [os.path.join(os.path.dirname(sys.executable), "rbc-registration"),
                  shutil.which("rbc-registration") or ""]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        candidates.append(os.path.join(prefix, "lib", "rbc_registration", "rbc-registration"))
    exe = next((c for c in candidates if c and os.access(c, os.X_OK)), None)
    assert exe, f"rbc-registration not found in {candidates}"
    proc = subprocess.run([exe, "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "reproduce" in proc.stdout


@pytest.mark.parametrize("interpolation", ["paper", "kriging"])
@pytest.mark.parametrize("dim", [2, 3])
def test_the_smallest_valid_configuration_registers_end_to_end(tmp_path, dim, interpolation):
    """Issue 11: d + 1 well-spread fiducials (4 in 3D, 3 in 2D) are what restoration accepts;
    the hull test and the interpolation accept them too, so ``register`` succeeds."""
    rng = np.random.default_rng(dim)
    simplex = np.vstack([np.zeros(dim), np.eye(dim)]) * 100.0          # mm
    rot, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    rot[:, 0] *= np.sign(np.linalg.det(rot))                          # proper: det = +1
    working = [np.array([p, p + rng.normal(0, 0.05, dim)]) for p in simplex]
    means = np.array([w.mean(axis=0) for w in working])
    truth = simplex @ rot.T + 1000.0 + 0.3 * np.sin(simplex / 30.0)    # not rigid: eps != 0
    ids = [f"F{k}" for k in range(dim + 1)]
    write_fiducials(tmp_path / "f.csv", ids, working, [t[None] for t in truth])
    inside, outside = means.mean(axis=0), means.mean(axis=0) + 300.0
    write_targets(tmp_path / "t.csv", ["in", "out"], np.array([inside, outside]))
    out = tmp_path / "r.json"
    run("register", tmp_path / "f.csv", "--targets", tmp_path / "t.csv", "--interpolation",
        interpolation, "--json", out)
    rep = json.loads(out.read_text())
    assert rep["n_fiducials"] == dim + 1 and rep["corrected"]["fre_rms"] < 1e-6
    assert [t["inside_hull"] for t in rep["targets"]] == [True, False]
    model = build_model(means, truth,
                        ModelConfig(dimension=dim, interpolation=interpolation),
                        working_repeats=working)
    np.testing.assert_allclose([t["correction"] for t in rep["targets"]],
                               model.correct(np.array([inside, outside])).correction,
                               rtol=1e-9, atol=1e-12)
    loo = run("register", tmp_path / "f.csv", "--loo", check=False)   # d + 1: no rebuild left
    assert loo.returncode == 2 and f"leave-one-out in {dim}D needs at least {dim + 2}" in loo.stderr
    if interpolation == "paper" and dim == 3:   # barycentric at the centroid: the mean eps
        np.testing.assert_allclose(rep["targets"][0]["correction"],
                                   model.corrections.mean(axis=0), atol=1e-9)


def test_identical_repeats_show_sigma_and_rho_unknown():
    """Identical repeats (through the core): no noise estimate, sigma and rho unknown in the
    text as in JSON (once sigma = 0 and rho = inf, whose JSON null the text showed as
    'rho n/a -> apply' while the reason said 'rho = inf')."""
    working = np.array([[0, 0, 0], [1000, 0, 0], [0, 1000, 0], [0, 0, 1000], [500, 500, 500]],
                       dtype=float)
    destination = working + [0, 0, 0]
    destination[4, 2] += 0.1
    repeats = [np.array([w, w]) if k == 0 else w[None] for k, w in enumerate(working)]
    model = build_model(working, destination, ModelConfig(dimension=3),
                        working_repeats=repeats)
    text = format_report(model_report(model, unit="mm"))
    assert "rho          n/a -> unknown" in text, text
    assert "sigma        n/a per point, n/a per axis (unknown)" in text, text


@pytest.mark.parametrize("interpolation", ["paper", "kriging"])
def test_the_target_table_names_whose_correction_it_shows(interpolation):
    """The per-target '|eps|' is the configured interpolation's, which the decision may not
    apply (cv chose kriging, or uncorrected); the header names it."""
    cell = make_cell("A", seed=0)
    model = build_model(cell.fiducial_means, cell.fiducial_truth,
                        ModelConfig(dimension=3, interpolation=interpolation))
    text = format_report(model_report(model, cell.target_ids[:2], cell.target_means[:2],
                                      unit="mm"))
    head = next(line for line in text.splitlines() if line.strip().startswith("target "))
    assert f"|eps| {interpolation}" in head, head
    eps = np.linalg.norm(model.correct(cell.target_means[:1]).correction[0])
    assert f"{eps:.4g}" in text


def test_register_reports_targets_without_truth_beside_targets_with_it(tmp_path):
    """A targets file with some rows' truth left empty: TRE for the others, null for those,
    one warning line naming the count."""
    cell = make_cell("A", seed=0)
    write_fiducials(tmp_path / "f.csv", cell.fiducial_ids, cell.fiducial_measurements,
                    cell.fiducial_truth)
    rows = ["id,wx,wy,wz,dx,dy,dz"] + [
        f"{tid},{','.join(map(repr, map(float, w)))},"
        + (",," if k % 4 == 1 else ",".join(map(repr, map(float, d))))
        for k, (tid, w, d) in enumerate(zip(cell.target_ids, cell.target_means,
                                            cell.target_truth))]
    (tmp_path / "t.csv").write_text("\n".join(rows) + "\n")
    proc = run("register", tmp_path / "f.csv", "--targets", tmp_path / "t.csv", "--json",
               tmp_path / "r.json")
    blind = sum(1 for k in range(len(cell.target_ids)) if k % 4 == 1)
    assert (f"{blind} of {len(cell.target_ids)} targets have no truth, e.g. "
            f"'{cell.target_ids[1]}'") in proc.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    missing = [t["id"] for t in report["targets"] if t["tre_u"] is None]
    assert missing == [cell.target_ids[k] for k in range(len(cell.target_ids)) if k % 4 == 1]
    kept = [t["tre_u"] for t in report["targets"] if t["tre_u"] is not None]
    assert report["summary"]["tre_u_median"] == pytest.approx(float(np.median(kept)))
