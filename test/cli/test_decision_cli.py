"""The decision in what `register` and `evaluate` report: the JSON `decision` object, each
target's `destination` and expected error, `--decision`, `--sigma` / `--sigma-axis` (pure)."""

import json
import math

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.core.constants import CANDIDATES, DECISION_MODES
from rbc_registration.core.model import ModelConfig, build_model
from rbc_registration.io.csv_io import write_fiducials, write_targets


def cell(seed, bias, noise=0.1, j=80, k=40):
    """A 2D cell in mm: destination = truth, working = rotated truth + smooth bias + noise per
    axis; fiducials and targets (with truth) measured once."""
    rng = np.random.default_rng(seed)
    y = rng.uniform(0, 1000, (j + k, 2))
    a = rng.uniform(-np.pi, np.pi)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    field = bias * np.sin(y / 400.0 + rng.uniform(0, 6, 2))[:, ::-1]
    x = (y - 500) @ rot + field + rng.normal(scale=noise, size=y.shape)
    return x[:j], y[:j], x[j:], y[j:]


def files(tmp_path, seed, bias, noise=0.1):
    xf, yf, xt, yt = cell(seed, bias, noise)
    fid, tgt = tmp_path / f"fid{seed}.csv", tmp_path / f"tgt{seed}.csv"
    write_fiducials(fid, [f"F{i}" for i in range(len(xf))], [p[None] for p in xf],
                    [p[None] for p in yf])
    write_targets(tgt, [f"T{i}" for i in range(len(xt))], xt, yt)
    return fid, tgt, (xf, yf, xt, yt)


def register(tmp_path, fid, tgt, *options, name="r.json"):
    out = tmp_path / name
    assert cli.main(["register", str(fid), "--targets", str(tgt), "--json", str(out),
                     *options]) == 0
    return json.loads(out.read_text())


@pytest.mark.parametrize("bias, applies", [(2.0, True), (0.0, False)])
def test_decision_object_and_destination_match_the_library(tmp_path, capsys, bias, applies):
    fid, tgt, (xf, yf, xt, yt) = files(tmp_path, 5, bias)
    rep = register(tmp_path, fid, tgt)
    model = build_model(xf, yf, ModelConfig(dimension=2))
    dec = rep["decision"]
    assert dec["mode"] == "cv" and dec["apply"] is applies
    assert dec["method"] == model.decision.method
    assert (dec["method"] != "uncorrected") is applies
    assert dec["reason"] == model.decision.reason and dec["rho"] is None   # no sigma: rho unknown
    assert set(dec["cv"]) == set(CANDIDATES)
    for name, c in dec["cv"].items():
        score = model.decision.candidate(name)
        assert c["available"] and c["median"] == pytest.approx(score.cv_median, rel=1e-12)
        assert c["rms"] == pytest.approx(score.cv_rms, rel=1e-12)
        assert c["bound"] == pytest.approx(score.cv_bound, rel=1e-12)
        if name == "uncorrected":
            assert c["statistic"] is None and c["p_value"] is None
        else:
            assert c["statistic"] == score.statistic and c["p_value"] == pytest.approx(
                score.p_value, rel=1e-12)
    tc = model.correct(xt)
    np.testing.assert_allclose([t["destination"] for t in rep["targets"]], tc.destination,
                               rtol=1e-12)
    np.testing.assert_allclose([t["expected_tre"] for t in rep["targets"]], tc.expected_tre,
                               rtol=1e-12)
    np.testing.assert_allclose([t["tre_bound"] for t in rep["targets"]], tc.tre_bound,
                               rtol=1e-12)
    tre = np.linalg.norm(tc.destination - yt, axis=1)
    np.testing.assert_allclose([t["tre"] for t in rep["targets"]], tre, rtol=1e-12)
    assert rep["summary"]["tre_median"] == pytest.approx(float(np.median(tre)))
    assert rep["summary"]["fraction_within_bound"] == pytest.approx(
        float(np.mean(tre <= tc.tre_bound)))
    # The point to use is the corrected one exactly when the decision applies corrections.
    chosen = np.array([t["destination"] for t in rep["targets"]])
    uncorrected = np.array([t["uncorrected"] for t in rep["targets"]])
    assert (not np.allclose(chosen, uncorrected, atol=1e-9)) is applies
    if applies:   # a strong smooth bias: correcting helps clearly
        assert rep["summary"]["tre_median"] < 0.5 * rep["summary"]["tre_u_median"]
    out = capsys.readouterr().out
    assert f"decision     cv -> {dec['method']}" in out and dec["reason"] in out
    assert "cross-validated error per candidate" in out


def test_sigma_and_sigma_axis_give_the_same_model(tmp_path):
    fid, tgt, _ = files(tmp_path, 6, 0.5)
    sigma_axis = 0.1
    a = register(tmp_path, fid, tgt, "--decision", "rho", "--sigma-axis", str(sigma_axis),
                 name="a.json")
    b = register(tmp_path, fid, tgt, "--decision", "rho", "--sigma",
                 repr(sigma_axis * math.sqrt(2)), name="b.json")
    assert a["sigma"] == pytest.approx(b["sigma"], rel=1e-15)
    assert a["sigma_axis"] == pytest.approx(sigma_axis, rel=1e-15)
    assert a["rho"] == pytest.approx(b["rho"], rel=1e-12) and a["rho"] is not None
    assert a["decision"] == b["decision"] and a["decision"]["mode"] == "rho"
    assert a["targets"] == b["targets"] and a["sigma_source"] == b["sigma_source"] == "given"


@pytest.mark.parametrize("mode", DECISION_MODES)
def test_every_decision_mode_is_reported(tmp_path, mode):
    fid, tgt, _ = files(tmp_path, 7, 2.0, noise=0.02)
    rep = register(tmp_path, fid, tgt, "--decision", mode, "--sigma", "0.03")
    assert rep["decision"]["mode"] == mode and rep["recommendation"] in ("apply", "uncertain",
                                                                         "do_not_apply")
    expect = {"on": True, "off": False}.get(mode)
    if expect is not None:
        assert rep["decision"]["apply"] is expect


def test_sigma_options_are_exclusive(tmp_path, capsys):
    fid, tgt, _ = files(tmp_path, 8, 0.0)
    with pytest.raises(SystemExit) as exc:
        cli.main(["register", str(fid), "--sigma", "0.1", "--sigma-axis", "0.1"])
    assert exc.value.code == 2
    assert "argument --sigma-axis: not allowed with argument --sigma" in capsys.readouterr().err


def test_removed_node_parameter_is_named(tmp_path, capsys):
    assert cli.main(["evaluate", str(tmp_path / "none"), "-p", "apply_corrections:=on"]) == 2
    err = capsys.readouterr().err
    assert "apply_corrections: it was replaced by 'decision'" in err and len(err.splitlines()) == 1
