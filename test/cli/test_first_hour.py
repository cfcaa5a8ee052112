"""What a cell integrator meets in the first hour with the command line: ``register`` prints the
chosen registration (translation, quaternion x y z w, roll pitch yaw in degrees) and names every
column by its method; ``--unit`` of ``register`` and ``export`` accept one set of units, and
``export`` converts each; ``export --urdf`` writes a URDF / xacro fixed joint; a closed pipe
(``| head``) ends every subcommand quietly."""

import json
import math
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.cli import BROKEN_PIPE_STATUS
from rbc_registration.core.constants import (CANDIDATES, METRES_PER_UNIT, UNCORRECTED,
                                             UNIT_ALIASES, length_unit)
from rbc_registration.io.calibration import read_calibration
from rbc_registration.io.csv_io import write_fiducials, write_targets
from rbc_registration.io.escape import xml_attribute, xml_comment

#: The cell's true pose of the working frame in the destination frame (mm, degrees).
ROLL_PITCH_YAW_DEG = (5.0, -10.0, 30.0)
TRANSLATION_MM = np.array([1500.0, -200.0, 800.0])


def _rot(roll, pitch, yaw):
    """Rz(yaw) Ry(pitch) Rx(roll): URDF's and REP 103's fixed-axis rpy, built by hand."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


TRUE_ROTATION = _rot(*np.radians(ROLL_PITCH_YAW_DEG))


def _working(destination):
    """Working-frame points of destination points: the rigid pose and a smooth 0.3 mm bias."""
    w = (destination - TRANSLATION_MM) @ TRUE_ROTATION
    return w + 0.3 * np.sin(w / 400.0)


def _cell(folder, n_targets):
    """A 3D cell in mm: 48 fiducials measured twice (0.02 mm noise), targets with truth, and
    candidates (working-frame points) for ``plan``."""
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.linspace(0, 1200, 4), np.linspace(0, 1000, 4),
                                np.linspace(0, 600, 3), indexing="ij"), -1).reshape(-1, 3)
    grid += rng.uniform(-30, 30, grid.shape)
    write_fiducials(folder / "fiducials.csv", [f"F{k:02d}" for k in range(len(grid))],
                    [_working(d) + rng.normal(0, 0.02, (2, 3)) for d in grid],
                    [d[None] for d in grid])
    truth = rng.uniform([100, 100, 100], [1100, 900, 500], (n_targets, 3))
    write_targets(folder / "targets.csv", [f"T{k:04d}" for k in range(n_targets)],
                  _working(truth) + rng.normal(0, 0.02, truth.shape), truth)
    cand = rng.uniform([0, 0, 0], [1200, 1000, 600], (6, 3))
    write_targets(folder / "candidates.csv", [f"C{k}" for k in range(len(cand))],
                  _working(cand))
    return folder


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    return _cell(tmp_path_factory.mktemp("first_hour"), 6)


def _register(capsys, folder, *extra):
    capsys.readouterr()
    assert cli.main(["register", str(folder / "fiducials.csv"), "--targets",
                     str(folder / "targets.csv"), *map(str, extra)]) == 0
    return capsys.readouterr()


def _numbers_after(text, label):
    """The comma-separated numbers of the report line that starts with ``label``."""
    line = next(x for x in text.splitlines() if x.strip().startswith(label))
    return [float(v) for v in line.split("=", 1)[1].split(" deg")[0].split(" mm")[0]
            .split(",")]


# --- register prints the chosen registration -------------------------------------------------

def test_register_prints_the_chosen_registration_as_json_has_it(cell, capsys, tmp_path):
    out = _register(capsys, cell, "--json", tmp_path / "r.json").out
    rep = json.loads((tmp_path / "r.json").read_text())
    reg = rep["registration"]
    assert rep["decision"]["method"] == "kriging" and reg["method"] == "kriging"
    assert reg["name"] == "corrected"          # kriging corrects on top of {R_c, tau_c}
    assert "registration corrected (destination = R working + t, then each target's kriging " \
           "correction)" in out
    translation = _numbers_after(out, "translation")
    quaternion = _numbers_after(out, "quaternion")
    rpy = _numbers_after(out, "rpy")
    # the text has 10 significant digits of the JSON's numbers
    np.testing.assert_allclose(translation, reg["translation"], rtol=1e-9)
    np.testing.assert_allclose(quaternion, reg["quaternion"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rpy, reg["rpy_deg"], rtol=1e-9, atol=1e-12)
    # ... which are the corrected registration's rotation and translation
    rotation = np.array(rep["corrected"]["rotation"])
    np.testing.assert_allclose(reg["translation"], rep["corrected"]["translation"], rtol=1e-12)
    np.testing.assert_allclose(_rot(*np.radians(reg["rpy_deg"])), rotation, atol=1e-12)
    x, y, z, w = reg["quaternion"]
    np.testing.assert_allclose(2 * math.acos(w), math.acos((np.trace(rotation) - 1) / 2),
                               atol=1e-9)
    np.testing.assert_allclose(np.array([x, y, z]) / math.sqrt(1 - w * w),
                               [rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                                rotation[1, 0] - rotation[0, 1]]
                               / np.linalg.norm([rotation[2, 1] - rotation[1, 2],
                                                 rotation[0, 2] - rotation[2, 0],
                                                 rotation[1, 0] - rotation[0, 1]]), atol=1e-9)
    # and the cell's true pose to within its 0.3 mm bias over a metre
    np.testing.assert_allclose(rpy, ROLL_PITCH_YAW_DEG, atol=0.05)
    np.testing.assert_allclose(translation, TRANSLATION_MM, atol=1.0)


def test_an_uncorrected_decision_prints_the_uncorrected_registration(cell, capsys, tmp_path):
    out = _register(capsys, cell, "--decision", "off", "--json", tmp_path / "r.json").out
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["registration"]["name"] == rep["registration"]["method"] == UNCORRECTED
    assert "registration uncorrected (destination = R working + t)" in out
    np.testing.assert_allclose(_numbers_after(out, "translation"),
                               rep["uncorrected"]["translation"], rtol=1e-9)
    np.testing.assert_allclose(_rot(*np.radians(_numbers_after(out, "rpy"))),
                               rep["uncorrected"]["rotation"], atol=1e-8)


def test_a_2d_registration_prints_a_yaw(tmp_path, capsys):
    rng = np.random.default_rng(1)
    holes = np.stack(np.meshgrid(np.arange(5) * 50.0, np.arange(4) * 50.0, indexing="ij"),
                     -1).reshape(-1, 2)
    c, s = math.cos(math.radians(-40)), math.sin(math.radians(-40))
    working = (holes - [800, 300]) @ np.array([[c, -s], [s, c]])
    write_fiducials(tmp_path / "f.csv", [f"H{k}" for k in range(len(holes))],
                    [w + rng.normal(0, 0.01, (2, 2)) for w in working], [h[None] for h in holes])
    assert cli.main(["register", str(tmp_path / "f.csv"), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "translation  x, y = " in out
    roll, pitch, yaw = _numbers_after(out, "rpy")
    assert (roll, pitch) == (0.0, 0.0) and yaw == pytest.approx(-40.0, abs=0.05)
    quaternion = _numbers_after(out, "quaternion")
    assert quaternion[:2] == [0.0, 0.0]
    assert 2 * math.degrees(math.atan2(quaternion[2], quaternion[3])) == pytest.approx(yaw,
                                                                                    abs=1e-6)


# --- every column named by its method --------------------------------------------------------

def _table(out):
    lines = out.splitlines()
    k = next(i for i, x in enumerate(lines) if x.strip().startswith("target "))
    rows = [x.split() for x in lines[k + 1:] if re.match(r"\s+T\d{4}\s", x)]
    return lines[k], rows


@pytest.mark.parametrize("options, used", [((), "kriging"), (("--decision", "off"), UNCORRECTED),
                                           (("--decision", "on"), "paper"),
                                           (("--interpolation", "kriging"), "kriging")])
def test_every_column_names_its_method_and_holds_that_methods_figures(cell, capsys, tmp_path,
                                                                      options, used):
    out = _register(capsys, cell, *options, "--json", tmp_path / "r.json").out
    rep = json.loads((tmp_path / "r.json").read_text())
    configured = rep["interpolation"]
    assert rep["decision"]["method"] == used
    head, rows = _table(out)
    # no bare TRE, TRE_u or TRE_c: each TRE names a method of CANDIDATES
    assert not re.search(r"TRE_|TRE(?! )", head.replace("exp. TRE", "exp.TRE")), head
    named = re.findall(r"(?:TRE|bound|\|eps\|) (\S+)", head)
    assert named and set(named) <= set(CANDIDATES), head
    # the header line says which interpolation the |eps| column is, and that targets get the
    # decision's method
    assert f"configured interpolation {configured}" in out
    assert f"the points to use are {used}'s (the decision): x, y, z in the destination " \
           "frame" in out
    # the point to use first, beside its expected error and bound, all of the decision's method
    assert re.match(rf"\s*target\s+x {used}\s+y {used}\s+z {used}\s+exp\. TRE {used}\s+"
                    rf"95% bound {used}\s+\|eps\| {configured}\s+hull\s", head), head
    tre_heads = re.findall(r"(?<!d)TRE (\S+)", head.replace("exp. TRE", ""))
    assert tre_heads[0] == used and len(tre_heads) == len(set(tre_heads))
    assert set(tre_heads) == {used, UNCORRECTED, configured}
    key = {used: "tre", UNCORRECTED: "tre_u", configured: "tre_c"}
    assert len(rows) == len(rep["targets"]) == 6
    for row, target in zip(rows, rep["targets"], strict=True):
        assert row[0] == target["id"]
        # the point to use as --json has it, 9 significant digits (the file's unit, mm)
        np.testing.assert_allclose([float(v) for v in row[1:4]], target["destination"],
                                   rtol=1e-8, atol=1e-6)
        assert float(row[4]) == pytest.approx(target["expected_tre"], rel=5e-4)
        assert float(row[5]) == pytest.approx(target["tre_bound"], rel=5e-4)
        assert float(row[6]) == pytest.approx(np.linalg.norm(target["correction"]), rel=5e-4)
        assert row[7] == ("in" if target["inside_hull"] else "OUT")
        for k, method in enumerate(tre_heads):
            assert float(row[8 + k]) == pytest.approx(target[key[method]], rel=5e-4)
    summary = next(x for x in out.splitlines() if "median TRE" in x)
    assert summary.strip().startswith(f"median TRE {used} ") and "TRE_" not in summary


def test_targets_without_truth_print_the_point_to_use_in_the_files_unit(cell, capsys, tmp_path):
    """The point to use is printed without truth too, in the unit of the files: the same cell
    in metres prints the millimetre points / 1000."""
    rep_mm = _register(capsys, cell, "--json", tmp_path / "mm.json")
    rep_mm = json.loads((tmp_path / "mm.json").read_text())
    metres = tmp_path / "metres"
    metres.mkdir()
    fid = np.genfromtxt(cell / "fiducials.csv", delimiter=",", names=True, dtype=None,
                        encoding="utf-8")
    write_fiducials(metres / "fiducials.csv", list(fid["id"]),
                    [np.array([[r["wx"], r["wy"], r["wz"]]]) / 1000 for r in fid],
                    [np.array([[r["dx"], r["dy"], r["dz"]]]) / 1000 for r in fid])
    tgt = np.genfromtxt(cell / "targets.csv", delimiter=",", names=True, dtype=None,
                        encoding="utf-8")
    write_targets(metres / "targets.csv", list(tgt["id"]),
                  np.stack([tgt["wx"], tgt["wy"], tgt["wz"]], -1) / 1000)
    out = _register(capsys, metres, "--unit", "m", "--json", tmp_path / "m.json").out
    rep_m = json.loads((tmp_path / "m.json").read_text())
    assert rep_m["decision"]["method"] == rep_mm["decision"]["method"] == "kriging"
    head, rows = _table(out)
    assert "TRE kriging" not in head.replace("exp. TRE", "") and "x kriging" in head
    assert "targets (m): the points to use are kriging's" in out
    assert len(rows) == 6
    for row, t_m, t_mm in zip(rows, rep_m["targets"], rep_mm["targets"], strict=True):
        assert row[0] == t_m["id"] == t_mm["id"] and len(row) == 8
        np.testing.assert_allclose([float(v) for v in row[1:4]], t_m["destination"], rtol=1e-8)
        np.testing.assert_allclose([float(v) for v in row[1:4]],
                                   np.array(t_mm["destination"]) / 1000, rtol=1e-6)


def test_a_2d_table_prints_the_points_x_and_y(capsys, tmp_path):
    plate = Path(__file__).resolve().parents[2] / "examples" / "plate2d"   # the repository's
    capsys.readouterr()
    assert cli.main(["register", str(plate / "fiducials.csv"), "--targets",
                     str(plate / "targets.csv"), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    rep = json.loads((tmp_path / "r.json").read_text())
    used = rep["decision"]["method"]
    head = next(x for x in out.splitlines() if x.strip().startswith("target "))
    assert re.match(rf"\s*target\s+x {used}\s+y {used}\s+exp\. TRE {used}\s", head), head
    assert "x, y in the destination frame" in out
    rows = {x.split()[0]: x.split() for x in out.splitlines()[out.splitlines().index(head) + 1:]
            if x.strip()}
    assert rep["targets"]
    for target in rep["targets"]:
        row = rows[target["id"]]
        np.testing.assert_allclose([float(v) for v in row[1:3]], target["destination"],
                                   rtol=1e-8, atol=1e-6)
        assert float(row[3]) == pytest.approx(target["expected_tre"], rel=5e-4)
        assert float(row[4]) == pytest.approx(target["tre_bound"], rel=5e-4)


def test_leave_one_out_names_its_methods(cell, capsys):
    out = _register(capsys, cell, "--loo").out
    line = next(x for x in out.splitlines() if "leave-one-out:" in x)
    assert "TRE_" not in line and "median TRE uncorrected" in line and " paper " in line


# --- units -----------------------------------------------------------------------------------

ALL_SPELLINGS = sorted(set(METRES_PER_UNIT) | set(UNIT_ALIASES))


def test_length_unit_reads_every_unit_and_alias_and_refuses_others():
    for unit in METRES_PER_UNIT:
        assert length_unit(unit) == unit
    assert length_unit("µm") == length_unit("\u03bcm") == "um" and length_unit("inch") == "in"
    assert {"m", "cm", "mm", "um", "in"} <= set(METRES_PER_UNIT)
    assert METRES_PER_UNIT["in"] == 0.0254 and METRES_PER_UNIT["um"] == 1e-6
    for bad in ("furlong", "MM", "", "inches", None):
        with pytest.raises(ValueError, match="unknown length unit"):
            length_unit(bad)


@pytest.mark.parametrize("spelling", ALL_SPELLINGS)
def test_a_register_report_in_each_unit_exports_to_metres(cell, capsys, tmp_path, spelling):
    out = _register(capsys, cell, "--unit", spelling, "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    unit = length_unit(spelling)
    assert rep["unit"] == unit and f"lengths in {unit}" in out.out
    assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.yaml")]) == 0
    cal = read_calibration(str(tmp_path / "c.yaml"))
    np.testing.assert_allclose(cal.translation,
                               np.array(rep["corrected"]["translation"])
                               * METRES_PER_UNIT[unit], rtol=1e-12)


@pytest.mark.parametrize("spelling", ALL_SPELLINGS)
def test_export_unit_of_a_report_without_one_takes_every_register_unit(cell, capsys, tmp_path,
                                                                       spelling):
    _register(capsys, cell, "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    del rep["unit"]
    (tmp_path / "r.json").write_text(json.dumps(rep))
    assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.yaml"),
                     "--unit", spelling]) == 0
    cal = read_calibration(str(tmp_path / "c.yaml"))
    np.testing.assert_allclose(cal.translation, np.array(rep["corrected"]["translation"])
                               * METRES_PER_UNIT[length_unit(spelling)], rtol=1e-12)


@pytest.mark.parametrize("spelling", ALL_SPELLINGS)
def test_plan_takes_the_units_register_takes(cell, capsys, tmp_path, spelling):
    """``plan --unit`` reads a unit as ``register`` does: an alias is its unit, in the text and
    the JSON."""
    capsys.readouterr()
    assert cli.main(["plan", str(cell / "fiducials.csv"), "--candidates",
                     str(cell / "candidates.csv"), "--count", "1", "--unit", spelling,
                     "--json", str(tmp_path / "p.json")]) == 0
    out = capsys.readouterr().out
    unit = length_unit(spelling)
    assert json.loads((tmp_path / "p.json").read_text())["unit"] == unit
    assert f"lengths in {unit}\n" in out, out
    assert re.search(rf"expected median target error now +[0-9.e+-]+ {unit}\n", out), out


@pytest.mark.parametrize("command", ["register", "export", "plan"])
def test_an_unknown_unit_is_one_line_naming_the_units(cell, capsys, command, tmp_path):
    source = cell / ("fiducials.csv" if command == "register" else "r.json")
    with pytest.raises(SystemExit) as exc:
        cli.main([command, str(source), "--unit", "furlong"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'furlong'" in err
    assert all(unit in err for unit in METRES_PER_UNIT), err


# --- export: the decision's registration ----------------------------------------------------

@pytest.mark.parametrize("options, applied", [((), True), (("--decision", "off"), False),
                                              (("--decision", "on"), True)])
def test_export_writes_the_registration_the_decision_chose(cell, capsys, tmp_path, options,
                                                           applied):
    """Without ``--registration``, export writes ``corrected`` only when the decision applies
    corrections, and says which; ``--registration`` writes the other, naming the decision's."""
    _register(capsys, cell, *options, "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["decision"]["apply"] is applied
    chosen, other = ("corrected", UNCORRECTED) if applied else (UNCORRECTED, "corrected")
    assert rep["registration"]["name"] == chosen          # what register printed
    for given, written in ((None, chosen), (other, other), (chosen, chosen)):
        out_file = tmp_path / f"{given}.yaml"
        assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(out_file)]
                        + ([] if given is None else ["--registration", given])) == 0
        lines = capsys.readouterr().out.splitlines()
        cal = read_calibration(str(out_file))
        assert cal.registration == written
        np.testing.assert_allclose(cal.translation,
                                   np.array(rep[written]["translation"]) * 1e-3, rtol=1e-12)
        its = (f"{rep['decision']['method']}, corrections "
               f"{'applied' if applied else 'not applied'}")
        assert lines[1] == (f"registration {chosen}: the decision's ({its}); --registration "
                            f"{other} exports the other" if given is None else
                            f"registration {given} (--registration); the decision's is "
                            f"{chosen} ({its})"), lines


def test_an_unapplied_decision_exports_the_transform_register_printed(cell, capsys, tmp_path):
    """A decision that applies no corrections (``--decision off``): export's default is the
    uncorrected transform, the one register printed as the registration."""
    _register(capsys, cell, "--decision", "off", "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.yaml")]) == 0
    cal = read_calibration(str(tmp_path / "c.yaml"))
    np.testing.assert_allclose(cal.translation, np.array(rep["registration"]["translation"])
                               * 1e-3, rtol=1e-12)
    np.testing.assert_allclose(cal.transform_matrix()[:3, :3],
                               _rot(*np.radians(rep["registration"]["rpy_deg"])), atol=1e-9)


# --- export --urdf ---------------------------------------------------------------------------

def _export_urdf(cell, capsys, tmp_path, *extra):
    _register(capsys, cell, "--unit", "in", "--json", tmp_path / "r.json")
    assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.yaml"),
                     "--urdf", str(tmp_path / "cal.urdf.xacro"), *extra]) == 0
    return capsys.readouterr().out, read_calibration(str(tmp_path / "c.yaml"))


def _origin_matrix(origin):
    xyz = [float(v) for v in origin.get("xyz").split()]
    rpy = [float(v) for v in origin.get("rpy").split()]
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = _rot(*rpy), xyz
    return m


def test_export_urdf_writes_a_fixed_joint_of_the_calibration(cell, capsys, tmp_path):
    out, cal = _export_urdf(cell, capsys, tmp_path, "--parent-frame", "base_link",
                            "--child-frame", "laser_tracker")
    root = ET.parse(tmp_path / "cal.urdf.xacro").getroot()
    assert root.tag == "robot"
    (joint,) = root.findall("joint")
    assert joint.get("name") == "base_link_to_laser_tracker" and joint.get("type") == "fixed"
    assert joint.find("parent").get("link") == "base_link"
    assert joint.find("child").get("link") == "laser_tracker"
    # URDF's origin, rebuilt by hand from xyz and rpy, is the calibration's transform (metres)
    np.testing.assert_allclose(_origin_matrix(joint.find("origin")), cal.transform_matrix(),
                               atol=1e-12)
    # the cell's numbers read as inches: metres in the file, the pose within its bias
    np.testing.assert_allclose(cal.translation, TRANSLATION_MM * 0.0254, atol=0.0254)
    np.testing.assert_allclose(np.degrees([float(v) for v in
                                           joint.find("origin").get("rpy").split()]),
                               ROLL_PITCH_YAW_DEG, atol=0.05)
    # the printed joint is the file's
    printed = out[out.index("<joint"):]
    assert ET.fromstring(printed).find("origin").attrib == joint.find("origin").attrib


def test_export_urdf_joint_name_and_frames_are_escaped(cell, capsys, tmp_path):
    parent, child = 'odd"<frame>&--', "tool0"
    _out, cal = _export_urdf(cell, capsys, tmp_path, "--parent-frame", parent,
                             "--child-frame", child, "--joint-name", "cell_a_tracker")
    root = ET.parse(tmp_path / "cal.urdf.xacro").getroot()   # well-formed XML
    joint = root.find("joint")
    assert joint.get("name") == "cell_a_tracker" and joint.find("parent").get("link") == parent
    assert "--" not in (tmp_path / "cal.urdf.xacro").read_text().split("<!--", 1)[1] \
        .split("-->", 1)[0]


def test_export_joint_name_without_urdf_is_refused(cell, capsys, tmp_path):
    _register(capsys, cell, "--json", tmp_path / "r.json")
    assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.yaml"),
                     "--joint-name", "j"]) == 2
    assert "--urdf" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


def test_xml_escapes():
    assert xml_attribute('a"<b>&c') == '"a&quot;&lt;b&gt;&amp;c"'
    assert xml_attribute("a\x1bb") == '"a\\x1bb"'
    assert "--" not in xml_comment("a--b---c-->") and xml_comment("a-b") == "a-b"


# --- a closed pipe ---------------------------------------------------------------------------

def _env():
    return {**os.environ, "PYTHONWARNINGS": "ignore"}


def test_register_piped_into_head_ends_quietly(tmp_path):
    """``rbc-registration register ... | head -1`` of a report far over a pipe's buffer."""
    folder = _cell(tmp_path, 3000)
    command = (f"{sys.executable} -m rbc_registration.cli register {folder / 'fiducials.csv'} "
               f"--targets {folder / 'targets.csv'} 2>{tmp_path / 'err'} | head -1; "
               f"echo \"status ${{PIPESTATUS[0]}}\"")
    proc = subprocess.run(["bash", "-c", command], capture_output=True, text=True, env=_env(),
                          timeout=120)
    first, status = proc.stdout.splitlines()
    assert first.startswith("Registration of 48 fiducials")
    assert status in ("status 0", f"status {BROKEN_PIPE_STATUS}"), status
    assert (tmp_path / "err").read_text() == ""


def _closed_stdout(argv, cwd):
    """Run the command with stdout a pipe whose reader has closed: its first write fails."""
    read, write = os.pipe()
    os.close(read)
    try:
        proc = subprocess.run([sys.executable, "-m", "rbc_registration.cli", *map(str, argv)],
                              stdout=write, stderr=subprocess.PIPE, text=True, env=_env(),
                              cwd=cwd, timeout=300)
    finally:
        os.close(write)
    return proc


def test_every_subcommand_that_prints_ends_quietly_on_a_closed_pipe(cell, tmp_path):
    bag = tmp_path / "bag"
    assert subprocess.run([sys.executable, "-m", "rbc_registration.cli", "synth-bag", "--cell",
                           "A", "--repeats", "2", "--quiet", str(bag)], capture_output=True,
                          env=_env(), timeout=300).returncode == 0
    assert subprocess.run([sys.executable, "-m", "rbc_registration.cli", "register",
                           cell / "fiducials.csv", "--json", tmp_path / "r.json"],
                          capture_output=True, env=_env(), timeout=300).returncode == 0
    commands = {
        "--help": ["--help"],
        "register": ["register", cell / "fiducials.csv", "--targets", cell / "targets.csv"],
        "export": ["export", tmp_path / "r.json", "--out", tmp_path / "c.yaml", "--urdf",
                   tmp_path / "c.urdf.xacro"],
        "plan": ["plan", cell / "fiducials.csv", "--candidates", cell / "candidates.csv",
                 "--count", "2"],
        "evaluate": ["evaluate", bag],
        "synth-bag": ["synth-bag", "--cell", "A", "--repeats", "2", tmp_path / "bag2"],
        "replay": ["replay", bag, "--wait", "0", "--rate", "1000"],
        "reproduce": ["reproduce", "--cells", "A", "--repeats", "2", "--out", tmp_path / "rep"],
    }
    for name, argv in commands.items():
        proc = _closed_stdout(argv, tmp_path)
        assert proc.returncode in (0, BROKEN_PIPE_STATUS), (name, proc.returncode, proc.stderr)
        assert "Broken pipe" not in proc.stderr and "Traceback" not in proc.stderr, \
            (name, proc.stderr)
        assert "error" not in proc.stderr.lower(), (name, proc.stderr)
