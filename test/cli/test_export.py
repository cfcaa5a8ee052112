"""``rbc-registration export``: the calibration YAML from a node snapshot and from a register
report (millimetres converted to metres), the static_transform_publisher line and the launch
snippet printed; bad input is one line, exit 2."""

import json
import math

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.calibration import (read_calibration,
                                             static_transform_publisher_command)
from rbc_registration.io.calibration_model import calibration_from_state
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag
from rbc_registration.io.csv_io import write_fiducials, write_targets
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.snapshot import snapshot_json
from rbc_registration.pipeline.state import build_state


def _matrix(registration):
    d = len(registration.rotation)
    m = np.eye(4)
    m[:d, :d], m[:d, 3] = registration.rotation, registration.translation
    return m


@pytest.fixture(scope="module")
def node_state():
    """A served model state as the node builds it (metres) and its settings."""
    rng = np.random.default_rng(0)
    settings = Settings.from_mapping({"working_frame": "laser", "destination_frame": "base",
                                      "decision": "on", "state_dir": ""})
    acc = FiducialAccumulator(3, "laser", "base", 0.005, 0.0)
    truth = np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(2)]) * 0.4
    for _repeat in range(2):
        for k, p in enumerate(truth):
            working = p[[1, 0, 2]] * [1, -1, 1] + 0.5 + 1e-3 * np.sin(3 * p) \
                + rng.normal(0, 3e-5, 3)
            acc.add(f"F{k}", working, p)
    return build_state(acc.fiducial_set(), settings, 1_700_000_000_500_000_000), settings


@pytest.mark.parametrize("registration", ["corrected", "uncorrected"])
def test_export_of_a_node_snapshot(tmp_path, capsys, node_state, registration):
    state, settings = node_state
    snap = tmp_path / "calibration.json"
    snap.write_text(snapshot_json(state, "laser", "base", 3))
    out = tmp_path / "cell.yaml"
    assert cli.main(["export", str(snap), "--out", str(out), "--registration",
                     registration]) == 0
    cal = read_calibration(str(out))
    model = state.model
    np.testing.assert_allclose(cal.transform_matrix(), _matrix(getattr(model, registration)),
                               atol=1e-12)
    assert (cal.parent_frame, cal.child_frame, cal.registration) == ("base", "laser",
                                                                     registration)
    assert cal.decision.mode == "on" and cal.decision.apply and cal.decision.method == "paper"
    assert cal.decision.reason == model.decision.reason
    assert cal.expected_tre_with_corrections == pytest.approx(
        model.decision.candidate("paper").cv_median, rel=1e-12)
    assert cal.expected_tre_rigid == pytest.approx(
        model.decision.candidate("uncorrected").cv_median, rel=1e-12)
    assert cal.n_fiducials == 18 and cal.created.startswith("2023-11-14T22:13:20.5")
    assert cal.sigma == pytest.approx(model.sigma, rel=1e-12)
    # The node's own ~/save builds the same calibration from the state, with the answers a
    # snapshot does not hold (an exported file publishes tf only).
    direct = calibration_from_state(state, settings, registration)
    assert cal.answers is None and direct.answers is not None
    assert direct.to_mapping() == {**cal.to_mapping(), "package_version":
                                   direct.package_version,
                                   "answers": direct.answers.to_mapping()}
    printed = capsys.readouterr().out
    assert static_transform_publisher_command(cal) in printed.splitlines()
    assert "executable='static_transform_publisher'" in printed and "'--frame-id', 'base'" \
        in printed


def test_export_of_a_register_report_in_mm(tmp_path, capsys):
    cell = make_cell("RA", seed=3)  # 2D, millimetres
    csv = tmp_path / "fiducials.csv"
    write_fiducials(csv, cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    report = tmp_path / "report.json"
    assert cli.main(["register", str(csv), "--json", str(report)]) == 0  # unit label mm
    data = json.loads(report.read_text())
    out = tmp_path / "cal.yaml"
    assert cli.main(["export", str(report), "--out", str(out), "--parent-frame", "world",
                     "--child-frame", "tracker"]) == 0
    cal = read_calibration(str(out))
    assert cal.dimension == 2 and cal.translation[2] == 0.0
    np.testing.assert_allclose(cal.translation[:2],
                               np.array(data["corrected"]["translation"]) * 1e-3, rtol=1e-12)
    np.testing.assert_allclose(cal.rotation_matrix()[:2, :2], data["corrected"]["rotation"],
                               atol=1e-9)
    assert cal.fre_rms == pytest.approx(data["corrected"]["fre_rms"] * 1e-3, rel=1e-12)
    assert cal.sigma_l == pytest.approx([v * 1e-3 for v in data["sigma_L"]], rel=1e-12)
    dec = data["decision"]
    assert (cal.decision.mode, cal.decision.method, cal.decision.apply, cal.decision.reason) == (
        "cv", dec["method"], dec["apply"], dec["reason"])
    assert cal.expected_tre_with_corrections == pytest.approx(
        dec["cv"][dec["method"]]["median"] * 1e-3, rel=1e-12)
    assert cal.expected_tre_rigid == pytest.approx(dec["cv"]["uncorrected"]["median"] * 1e-3,
                                                   rel=1e-12)
    assert "--frame-id world --child-frame-id tracker" in capsys.readouterr().out


@pytest.mark.parametrize("content, message", [
    ("{not json", "not valid JSON"),
    ('{"format": "rbc_registration calibration 1", "model_valid": false, "error": "3 enabled"}',
     "holds no model (3 enabled)"),
    ('{"unit": "ft", "interpolation": "paper"}', "unit 'ft'"),
    ('{"unit": "mm", "interpolation": "paper", "n_fiducials": 5, "sigma_L": [1.0], '
     '"recommendation": "apply"}', "corrected: missing"),
    ('{"unit": "mm", "n_fiducials": 5, "sigma_L": [1.0], "corrected": {"rotation": [[1, 0], '
     '[0, 1]], "translation": [0, 0], "fre_rms": 0}}', "decision: missing"),
    ('{"unit": "mm", "n_fiducials": 5, "sigma_L": [1.0], "decision": {"mode": "cv"}, '
     '"corrected": {"rotation": [[1, 0], [0, 1]], "translation": [0, 0], "fre_rms": 0}}',
     "decision: needs mode, method, apply, reason and cv"),
    ("[]", "not a JSON object"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, content, message):
    src = tmp_path / "in.json"
    src.write_text(content)
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rbc-registration export: error: ") and message in err, err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.yaml").exists()


REPORT = {"unit": "mm", "n_fiducials": 5, "sigma_L": [1.0], "sigma": 0.1,
          "decision": {"mode": "cv", "method": "kriging", "apply": True, "reason": "r",
                       "cv": {"kriging": {"median": 0.01}}},
          "corrected": {"rotation": [[1, 0], [0, 1]], "translation": [0, 0], "fre_rms": 0}}


@pytest.mark.parametrize("path, value, message", [
    (("unit",), ["mm"], "unit ['mm']: a calibration is in metres"),
    (("decision", "cv", "kriging", "median"), "x",
     "decision: cv: kriging: median: must be a number, got 'x'"),
    (("corrected", "translation"), [0, 10 ** 400],
     "corrected: translation[1]: out of range, got an integer of 401 digits"),
    (("corrected", "fre_rms"), 10 ** 400, "corrected: fre_rms: out of range"),
    (("corrected",), [1, 2], "corrected: not a JSON object where rotation is expected"),
    (("sigma",), "x", "sigma: must be a number, got 'x'"),
    (("sigma_L",), 3, "sigma_L: must be a list of numbers, got int"),
    (("n_fiducials",), "5", "n_fiducials: must be an integer, got '5'"),
])
def test_an_edited_report_is_one_line_exit_2(tmp_path, capsys, path, value, message):
    """Fields of the wrong type or size gave tracebacks (TypeError, OverflowError)."""
    data = json.loads(json.dumps(REPORT))
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    src = tmp_path / "in.json"
    src.write_text(json.dumps(data))
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rbc-registration export: error: ") and message in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize("field, value, message", [
    ("stamp_ns", "x", "stamp_ns: must be a number, got 'x'"),
    ("stamp_ns", 1e300, "stamp_ns: out of range (0 to the year 9999)"),
    ("fiducial_ids", 5, "fiducial_ids: must be a list, got int"),
])
def test_an_edited_snapshot_is_one_line_exit_2(tmp_path, capsys, node_state, field, value,
                                               message):
    state, settings = node_state
    data = json.loads(snapshot_json(state, "laser", "base", 3))
    data[field] = value
    src = tmp_path / "calibration.json"
    src.write_text(json.dumps(data))
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_a_source_that_is_not_a_regular_file_is_refused(capsys):
    assert cli.main(["export", "/dev/zero"]) == 2
    err = capsys.readouterr().err
    assert "/dev/zero is a character device, not a regular file: refused" in err
    assert len(err.strip().splitlines()) == 1


def test_missing_file(tmp_path, capsys):
    assert cli.main(["export", str(tmp_path / "nope.json")]) == 2
    assert "cannot be read" in capsys.readouterr().err


# --- what each expected error is, units, frames -------------------------------------

@pytest.fixture(scope="module")
def ra_report(tmp_path_factory):
    """A register report of cell RA (mm) with targets and truth: the decision corrects."""
    d = tmp_path_factory.mktemp("ra")
    cell = make_cell("RA", seed=3)
    write_fiducials(d / "fiducials.csv", cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    write_targets(d / "targets.csv", cell.target_ids, cell.target_means, cell.target_truth)
    assert cli.main(["register", str(d / "fiducials.csv"), "--targets", str(d / "targets.csv"),
                     "--json", str(d / "report.json")]) == 0
    return cell, d / "report.json", json.loads((d / "report.json").read_text())


@pytest.mark.parametrize("registration", ["corrected", "uncorrected"])
def test_the_file_says_what_the_transform_alone_gives(tmp_path, capsys, ra_report,
                                                      registration):
    """``expected_tre`` was kriging's held-out median (0.078 mm) while the file's
    transform alone gives the rigid registration's error at the targets (0.26 mm)."""
    cell, report, data = ra_report
    assert data["decision"]["apply"]
    out = tmp_path / "cal.yaml"
    assert cli.main(["export", str(report), "--out", str(out), "--registration", registration,
                     "--parent-frame", "world", "--child-frame", "tracker"]) == 0
    cal = read_calibration(str(out))
    cv = data["decision"]["cv"]
    assert cal.expected_tre_rigid == pytest.approx(cv["uncorrected"]["median"] * 1e-3, rel=1e-12)
    assert cal.expected_tre_with_corrections == pytest.approx(
        cv[data["decision"]["method"]]["median"] * 1e-3, rel=1e-12)
    # What a user of the transform alone gets at the targets: the rigid figure, not the other.
    m = cal.transform_matrix()
    work = np.c_[cell.target_means * 1e-3, np.zeros(len(cell.target_means))]
    alone = np.median(np.linalg.norm((work @ m[:3, :3].T + m[:3, 3])[:, :2]
                                     - cell.target_truth * 1e-3, axis=1))
    assert abs(math.log(cal.expected_tre_rigid / alone)) < abs(
        math.log(cal.expected_tre_with_corrections / alone))
    printed = capsys.readouterr().out
    assert (f"expected target error: {cal.expected_tre_rigid * 1e3:.4g} mm with this transform "
            f"alone (expected_tre_rigid); {cal.expected_tre_with_corrections * 1e3:.4g} mm only "
            f"with the model's kriging corrections") in printed
    assert "expected_tre_with_corrections: only" in out.read_text()   # the file's comment


def test_a_corrected_registration_fitted_to_other_fiducials_has_no_rigid_figure(tmp_path):
    cell = make_cell("RA", seed=3)
    csv = tmp_path / "fiducials.csv"
    write_fiducials(csv, cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    report = tmp_path / "report.json"
    assert cli.main(["register", str(csv), "--corrected-fit", ",".join(cell.fiducial_ids[:40]),
                     "--json", str(report)]) == 0
    data = json.loads(report.read_text())
    assert data["corrected_fit"] == list(cell.fiducial_ids[:40]) and data["uncorrected_fit"] \
        is None
    for registration, known in (("corrected", False), ("uncorrected", True)):
        out = tmp_path / f"{registration}.yaml"
        assert cli.main(["export", str(report), "--out", str(out), "--registration",
                         registration]) == 0
        assert (read_calibration(str(out)).expected_tre_rigid is not None) == known


@pytest.mark.parametrize("recorded, given", [("m", "mm"), ("mm", "m")])
def test_a_unit_that_contradicts_the_report_is_refused(tmp_path, capsys, recorded, given):
    """``--unit mm`` on a report in metres rescaled it by 1000 without a word."""
    src = tmp_path / "in.json"
    src.write_text(json.dumps({**REPORT, "unit": recorded}))
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml"), "--unit",
                     given]) == 2
    err = capsys.readouterr().err
    assert (f"{src}: --unit {given} contradicts the file's unit {recorded!r}: refused" in err
            and len(err.strip().splitlines()) == 1), err
    assert not (tmp_path / "x.yaml").exists()
    # The same unit, or none given: the report's own.
    for extra in ([], ["--unit", recorded]):
        assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml"), *extra]) == 0
        assert read_calibration(str(tmp_path / "x.yaml")).sigma == pytest.approx(
            0.1 * (1e-3 if recorded == "mm" else 1.0))


def test_a_report_without_a_unit_needs_one(tmp_path, capsys):
    data = {k: v for k, v in REPORT.items() if k != "unit"}
    src = tmp_path / "in.json"
    src.write_text(json.dumps(data))
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml")]) == 2
    assert (f"{src}: unit: missing: the file records no length unit; give --unit "
            f"(m, cm, mm, um, in)") in capsys.readouterr().err
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml"), "--unit", "mm"]) == 0


def test_the_snapshot_unit_and_dimension_are_checked(tmp_path, capsys, node_state):
    state, _settings = node_state
    data = json.loads(snapshot_json(state, "laser", "base", 3))
    for change, args, message in (
            ({}, ["--unit", "mm"], "--unit mm contradicts the file's units 'm': refused"),
            ({"units": "mm"}, [], None),
            ({"units": "ft"}, [], "units 'ft': a calibration is in metres; export converts "
                                  "m, cm, mm, um, in"),
            ({"dimension": 2}, [], "dimension is 2, but the rotation is 3 x 3")):
        src = tmp_path / "calibration.json"
        src.write_text(json.dumps({**data, **change}))
        out = tmp_path / "x.yaml"
        code = cli.main(["export", str(src), "--out", str(out), *args])
        err = capsys.readouterr().err
        if message is None:   # a snapshot in mm (hand-made) is converted like a report
            assert code == 0
            assert read_calibration(str(out)).translation == pytest.approx(
                [v * 1e-3 for v in data["corrected"]["translation"]], rel=1e-12)
            continue
        assert code == 2 and f"{src}: {message}" in err and len(err.strip().splitlines()) == 1, \
            err


def test_every_export_error_names_the_file(tmp_path, capsys):
    """a bad field of the decision record (``apply: "yes"``) came without the file."""
    data = json.loads(json.dumps(REPORT))
    data["decision"]["apply"] = "yes"
    src = tmp_path / "in.json"
    src.write_text(json.dumps(data))
    assert cli.main(["export", str(src), "--out", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err
    assert f"error: {src}: decision.apply: must be true or false, got 'yes'" in err, err


def test_frames_of_an_evaluate_report_and_the_defaults_of_a_register_report(tmp_path, capsys,
                                                                            ra_report):
    """an evaluate report recorded no frames, so export used world/tracker without a
    word. The evaluate report records the node's frames its measurements were accepted in; a
    register report (a CSV has no frames) gets the defaults and one warning line saying so."""
    cell, report, _ = ra_report
    bag = tmp_path / "bag"
    write_bag(bag, cell_messages(cell, working_frame="laser", destination_frame="base_link"),
              "sqlite3", progress=False)
    ev = tmp_path / "ev.json"
    assert cli.main(["evaluate", str(bag), "--quiet", "-p", "working_frame:=laser", "-p",
                     "destination_frame:=base_link", "--json", str(ev)]) == 0
    data = json.loads(ev.read_text())
    assert (data["working_frame"], data["destination_frame"]) == ("laser", "base_link")
    capsys.readouterr()
    assert cli.main(["export", str(ev), "--out", str(tmp_path / "ev.yaml")]) == 0
    cal = read_calibration(str(tmp_path / "ev.yaml"))
    assert (cal.parent_frame, cal.child_frame) == ("base_link", "laser")
    assert "warning" not in capsys.readouterr().err
    assert cli.main(["export", str(report), "--out", str(tmp_path / "reg.yaml")]) == 0
    err = capsys.readouterr().err
    assert err == (f"rbc-registration export: warning: {report} records no frames (a register "
                   f"report, or an evaluate report of an earlier version): --parent-frame world "
                   f"--child-frame tracker assumed (the node's defaults); give the option to say "
                   f"which\n")
    # an evaluate report of an earlier version (no frames, no fits recorded): the node's model,
    # both registrations fitted to all fiducials, so the rigid figure is known
    old = {k: v for k, v in data.items() if k not in ("working_frame", "destination_frame",
                                                      "uncorrected_fit", "corrected_fit")}
    (tmp_path / "old_ev.json").write_text(json.dumps(old))
    assert cli.main(["export", str(tmp_path / "old_ev.json"), "--out",
                     str(tmp_path / "old.yaml")]) == 0
    assert read_calibration(str(tmp_path / "old.yaml")).expected_tre_rigid is not None
    assert "an evaluate report of an earlier version" in capsys.readouterr().err
    assert cli.main(["export", str(report), "--out", str(tmp_path / "reg.yaml"),
                     "--parent-frame", "world"]) == 0
    assert "--child-frame tracker assumed" in capsys.readouterr().err
