"""A fiducial whose held-out error stands out (a mistyped coordinate) is named in one warning
line by register and evaluate (core/decision/evaluation.py ``blunders``)."""

import numpy as np

from rbc_registration import cli
from rbc_registration.core.decision.evaluation import BLUNDER_FACTOR, blunders
from rbc_registration.core.model import ModelConfig, build_model
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.csv_io import write_fiducials, write_targets


def single(name="A", seed=0):
    cell = make_cell(name, seed=seed, repeats=1)
    return cell, np.array([m[0] for m in cell.fiducial_measurements]), cell.fiducial_truth.copy()


def test_sound_cells_have_no_blunder_and_one_typo_is_found():
    """F050's dx typed 1414.1945 for 1441.1945 (27 mm) made the median TRE 4.6x worse
    with no word; its held-out error was 90x the median."""
    for name in ("A", "B"):
        for seed in range(3):
            cell, x, y = single(name, seed)
            assert blunders(build_model(x, y, ModelConfig(dimension=3))) == []
    cell, x, y = single("A", 0)
    y[50, 0] -= 27.0
    model = build_model(x, y, ModelConfig(dimension=3), ids=cell.fiducial_ids)
    found = blunders(model)[0]           # the worst; neighbours predicted from it may follow
    assert found.fiducial_id == cell.fiducial_ids[50]
    assert found.error > BLUNDER_FACTOR * found.median and 20 < found.error < 35


def test_register_names_the_blunder_in_one_warning_line(tmp_path, capsys):
    cell, x, y = single("A", 0)
    y[50, 0] -= 27.0
    f = tmp_path / "f.csv"
    write_fiducials(f, cell.fiducial_ids, [p[None] for p in x], [p[None] for p in y])
    assert cli.main(["register", str(f)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"rbc-registration register: warning: fiducial {cell.fiducial_ids[50]}: held-out error "
        f"2"), err
    assert "x the median of the fiducials" in err[0] and "check its points first" in err[0]
    y[50, 0] += 27.0
    write_fiducials(f, cell.fiducial_ids, [p[None] for p in x], [p[None] for p in y])
    assert cli.main(["register", str(f)]) == 0
    assert capsys.readouterr().err == ""


def test_register_names_the_fiducial_a_model_cannot_be_built_with(tmp_path, capsys):
    """One coordinate typed 1e10 mm off: the core's reason (degenerate geometry or "frames in
    different units") now names the fiducial that stands out
    (core/decision/evaluation.gross_misfits)."""
    cell, x, y = single("A", 0)
    x[50, 0] += 1e10
    f = tmp_path / "f.csv"
    write_fiducials(f, cell.fiducial_ids, [p[None] for p in x], [p[None] for p in y])
    assert cli.main(["register", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rbc-registration register: error: "), err
    assert f"; likely through fiducial '{cell.fiducial_ids[50]}' (1e+10 mm): distances to the " \
           f"other fiducials differ between the frames by that much" in err[0]
    assert err[0].endswith(": a typo or a wrong hole? fix or remove its rows")


def test_a_swapped_target_truth_is_named_in_one_warning_line(tmp_path, capsys):
    """two targets' truth rows swapped gave a TRE of the distance between them with
    no word; sound targets of every cell stay below the line (also the default RA/B checks)."""
    for name in ("A", "B", "RA"):
        cell, x, y = single(name, 0)
        f, t = tmp_path / "f.csv", tmp_path / "t.csv"
        write_fiducials(f, cell.fiducial_ids, [p[None] for p in x], [p[None] for p in y])
        working = np.array([m[0] for m in cell.target_measurements])
        truth = cell.target_truth.copy()
        write_targets(t, cell.target_ids, working, truth)
        assert cli.main(["register", str(f), "--targets", str(t)]) == 0
        assert capsys.readouterr().err == "", name
    truth[[2, 5]] = truth[[5, 2]]
    write_targets(t, cell.target_ids, working, truth)
    assert cli.main(["register", str(f), "--targets", str(t)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    ids = sorted([cell.target_ids[2], cell.target_ids[5]])
    assert len(err) == 1 and err[0].startswith("rbc-registration register: warning: targets "), err
    assert all(f"{i!r} (" in err[0] for i in ids)
    assert "uncorrected TRE over 20 x the median of the targets" in err[0]
    assert err[0].endswith("or swapped with another target's? check the truth of these targets")


def test_register_warns_of_frames_that_do_not_match_rigidly_and_of_one_scattered_repeat(
        tmp_path, capsys):
    """dz in metres with the rest in mm (FRE 213 mm on a 1 m cell, the
    restoration unconverged), and one repeat 5 mm off, were registered without a word."""
    cell, x, y = single("A", 0)
    f = tmp_path / "f.csv"
    write_fiducials(f, cell.fiducial_ids, [p[None] for p in x], [p[None] * [1, 1, 1e-3] for p in y])
    assert cli.main(["register", str(f)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert [e[:70] for e in err] == [
        "rbc-registration register: warning: the frames do not match rigidly: t",
        "rbc-registration register: warning: the restoration did not converge i"], err
    rng = np.random.default_rng(0)
    work = [p + rng.normal(scale=0.02, size=(3, 3)) for p in x]
    work[7][1, 2] += 5.0
    write_fiducials(f, cell.fiducial_ids, work, [np.repeat(p[None], 3, axis=0) for p in y])
    assert cli.main(["register", str(f)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"rbc-registration register: warning: fiducial(s) '{cell.fiducial_ids[7]}' ("), err
