"""Issue 11, CLI data safety: an output option of any subcommand that names an input file (the
same file by path, symlink or hard link) is refused with one line, exit 2, before anything is
written; the input is left byte for byte as it was."""

import json
import os

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag
from rbc_registration.io.csv_io import write_fiducials, write_targets
from rbc_registration.io.evaluation import REPORT_FILES


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("safety")
    cell = make_cell("RA", seed=3)
    write_fiducials(d / "fiducials.csv", cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    write_targets(d / "targets.csv", cell.target_ids, cell.target_means * 1e-3,
                  cell.target_truth * 1e-3)
    write_bag(d / "bag", cell_messages(cell), "sqlite3", progress=False)
    write_bag(d / "bag.mcap", cell_messages(cell), "mcap", progress=False)
    mcap = next((d / "bag.mcap").glob("*.mcap"))
    assert cli.main(["register", str(d / "fiducials.csv"), "--json", str(d / "report.json")]) == 0
    return {"cell": cell, "dir": d, "fid": d / "fiducials.csv", "tgt": d / "targets.csv",
            "bag": d / "bag", "mcap": mcap, "report": d / "report.json"}


def _alias(path, how, tmp_path):
    """``path`` itself, a symlink to it, a relative spelling or a hard link."""
    if how == "same":
        return path
    if how == "relative":
        return os.path.relpath(path)
    alias = tmp_path / f"alias{path.suffix}"
    (os.symlink if how == "symlink" else os.link)(path, alias)
    return alias


CASES = [  # (argv with {placeholders}, the output option, the input it names)
    (["register", "{fid}", "--json", "{out}"], "--json", "fid"),
    (["register", "{fid}", "--targets", "{tgt}", "--json", "{out}"], "--json", "tgt"),
    (["evaluate", "{bag}", "--targets", "{tgt}", "--quiet", "--json", "{out}"], "--json", "tgt"),
    (["evaluate", "{mcap}", "--quiet", "--json", "{out}"], "--json", "mcap"),
    (["evaluate", "{bag}", "--quiet", "--out", "{out}"], "--out", "bag"),
    (["evaluate", "{mcap}", "--quiet", "--out", "{out}"], "--out", "mcap"),
    (["export", "{report}", "--out", "{out}"], "--out", "report"),
]


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink", "relative"])
@pytest.mark.parametrize("argv, option, victim", CASES,
                         ids=[f"{c[0][0]}-{c[1]}-{c[2]}" for c in CASES])
def test_an_output_onto_an_input_is_refused(tmp_path, capsys, monkeypatch, files, argv, option,
                                            victim, how):
    if how == "hardlink" and files[victim].is_dir():
        pytest.skip("directories cannot be hard-linked")
    monkeypatch.chdir(files["dir"])
    target = files[victim]
    before = sorted((p.name, p.stat().st_mtime_ns, p.read_bytes())
                    for p in ([target] if target.is_file() else target.iterdir()))
    names = {k: str(v) for k, v in files.items() if k != "cell"}
    alias = _alias(target, how, tmp_path)
    args = [a.format(**names, out=alias) for a in argv]
    assert cli.main(args) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert option in lines[0] and "input" in lines[0] and "refus" in lines[0], lines[0]
    assert "wrote" not in out
    after = sorted((p.name, p.stat().st_mtime_ns, p.read_bytes())
                   for p in ([target] if target.is_file() else target.iterdir()))
    assert after == before


@pytest.mark.parametrize("name", REPORT_FILES)
def test_an_output_directory_holding_an_input_is_refused(tmp_path, capsys, files, name):
    """``evaluate --out DIR`` writes DIR/report.json etc.: any of them may be an input (a
    review: cv_errors.png was not checked, and a targets file of that name was overwritten)."""
    out = tmp_path / "out"
    out.mkdir()
    victim = out / name
    cell = files["cell"]
    write_targets(victim, cell.target_ids, cell.target_means * 1e-3, cell.target_truth * 1e-3)
    content = victim.read_bytes()
    assert cli.main(["evaluate", str(files["bag"]), "--targets", str(victim), "--quiet"]) == 0
    assert cli.main(["evaluate", str(files["bag"]), "--targets", str(victim), "--quiet",
                     "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and name in err
    assert victim.read_bytes() == content
    assert [p.name for p in out.iterdir()] == [name]


def test_other_outputs_still_work(tmp_path, capsys, files):
    assert cli.main(["register", str(files["fid"]), "--json", str(tmp_path / "r.json")]) == 0
    assert cli.main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.yaml")]) == 0
    assert (tmp_path / "c.yaml").is_file()


def test_register_names_an_ignored_working_repeat_in_one_line(tmp_path, capsys):
    """A working-frame repeat far from its siblings: one warning line (id, row, distance), the
    row ignored as the node ignores an outlier; ``--outlier-distance`` sets the node's limit."""
    f = tmp_path / "f.csv"
    f.write_text("id,wx,wy,wz,dx,dy,dz\n" + "".join(
        f"{i},{x},{y},{z},{x + 10},{y},{z}\n{i},{x + 1e-4},{y},{z},{x + 10},{y},{z}\n"
        for i, (x, y, z) in enumerate([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)]))
        + "3,0.3,0,1,10,0,1\n")
    # --unit m: a cell 1 m across (in mm it is too small for a cell, another warning)
    assert cli.main(["register", str(f), "--unit", "m", "--json", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rbc-registration register: warning: "), err
    assert "row 12" in err[0] and "fiducial '3'" in err[0] and "point is 0.29995 from" in err[0]
    assert json.loads((tmp_path / "r.json").read_text())["n_measurements"] == 10
    assert cli.main(["register", str(f), "--unit", "m", "--outlier-distance", "0"]) == 0
    # the check off, the row is used: the scattered repeats and the misfit it makes are named
    kept = capsys.readouterr().err.strip().splitlines()
    assert len(kept) == 2 and "the frames do not match rigidly" in kept[0], kept
    assert kept[1].startswith("rbc-registration register: warning: fiducial(s) '3' (0.1732 m)")
    assert cli.main(["register", str(f), "--unit", "m", "--outlier-distance", "0.00001"]) == 0
    # a limit below the repeats' scatter: three rows named, the rest summed up in one line
    strict = capsys.readouterr().err.strip().splitlines()
    assert len(strict) == 4 and "6 of 11 rows ignored in all" in strict[3], strict


def test_two_outputs_onto_one_file_are_refused(tmp_path, capsys, files):
    """``plan --json same.png --figure same.png`` wrote the JSON, then the figure over it."""
    same = tmp_path / "same.png"
    assert cli.main(["plan", str(files["fid"]), "--candidates", str(files["tgt"]), "--json",
                     str(same), "--figure", str(same)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--figure" in err[0] and "are the same file" in err[0], err
    assert not same.exists()


def test_evaluate_json_onto_a_file_of_its_out_dir_is_refused(tmp_path, capsys, files):
    out = tmp_path / "out"
    assert cli.main(["evaluate", str(files["bag"]), "--quiet", "--out", str(out), "--json",
                     str(out / "report.md")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "one would overwrite the other" in err[0], err


@pytest.mark.parametrize("sub", ["register", "plan", "plan-figure", "evaluate", "export"])
def test_an_output_ending_in_a_separator_is_refused(tmp_path, capsys, files, sub):
    """``--json out/`` (and ``out/.``) wrote a file named ``out`` (``Path`` drops the
    separator)."""
    out = str(tmp_path / "out") + (os.sep if sub != "register" else os.sep + ".")
    args = {"register": ["register", str(files["fid"]), "--json", out],
            "plan": ["plan", str(files["fid"]), "--candidates", str(files["tgt"]), "--json", out],
            "plan-figure": ["plan", str(files["fid"]), "--candidates", str(files["tgt"]),
                            "--figure", out],
            "evaluate": ["evaluate", str(files["bag"]), "--quiet", "--json", out],
            "export": ["export", str(files["report"]), "--out", out]}[sub]
    with pytest.raises(SystemExit) as stop:
        cli.main(args)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "names a directory, not a file" in err[0], err
    assert not (tmp_path / "out").exists()


def test_register_warns_when_every_repeat_is_identical(tmp_path, capsys):
    """Each id's three rows identical (one measurement exported three times): sigma was
    7e-14 mm and rho 9e11 'apply'; exactly 0 it crashed the kriging candidate on an exactly
    rigid cell. Now sigma is unknown (as a given sigma of 0 is refused), with one warning line."""
    rng = np.random.default_rng(6)
    rows = "".join(f"p{k},{x:.4f},{y:.4f},{z:.4f},{x + 10:.4f},{y:.4f},{z:.4f}\n" * 3
                   for k, (x, y, z) in enumerate(rng.uniform(0, 1000, (12, 3))))
    f = tmp_path / "f.csv"
    f.write_text("id,wx,wy,wz,dx,dy,dz\n" + rows)
    assert cli.main(["register", str(f), "--json", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert sum("are identical to their first measurement" in line for line in err) == 1, err
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["sigma"] is None and report["sigma_source"] == "unknown", report["sigma"]
