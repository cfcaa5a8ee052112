"""``rbc-registration evaluate``: the same numbers as ``register`` on the same data as CSV, the
node's ingestion (pairing, ids by proximity, rejections), dimension inference, the report
directory, and no rclpy. No ROS graph."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.core.constants import M_PER_MM
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io import escape
from rbc_registration.io.bag.records import DEFAULT_TOPICS, OutMessage
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag
from rbc_registration.io.csv_io import write_fiducials, write_targets
from rbc_registration.io.evaluation import REPORT_FILES

M = M_PER_MM  # the synthetic cells are in mm; bags and these CSVs are in metres


def cell_csv(cell, folder: Path) -> tuple[Path, Path]:
    """FIDUCIALS.csv and TARGETS.csv of a cell, in metres, every measurement a row."""
    fid, tgt = folder / "FIDUCIALS.csv", folder / "TARGETS.csv"
    write_fiducials(fid, cell.fiducial_ids, [w * M for w in cell.fiducial_measurements],
                    [t[None, :] * M for t in cell.fiducial_truth])
    rows = [(tid, w * M, t * M) for tid, ws, t in zip(cell.target_ids, cell.target_measurements,
                                                      cell.target_truth) for w in ws]
    write_targets(tgt, [r[0] for r in rows], np.array([r[1] for r in rows]),
                  np.array([r[2] for r in rows]))
    return fid, tgt


def run_json(argv, path: Path) -> dict:
    assert cli.main(argv + ["--json", str(path)]) == 0
    return json.loads(path.read_text())


def assert_same_numbers(a, b, path="report", rtol=1e-9, atol=1e-15):
    """Equal structure; numbers equal to rounding (running sums vs np.mean)."""
    if isinstance(a, dict):
        for key in a:
            assert key in b, f"{path}.{key} missing"
            assert_same_numbers(a[key], b[key], f"{path}.{key}", rtol, atol)
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b)):
            assert_same_numbers(x, y, f"{path}[{k}]", rtol, atol)
    elif isinstance(a, float) and isinstance(b, float):
        assert b == pytest.approx(a, rel=rtol, abs=atol), path
    else:
        assert a == b, path


REGISTER_KEYS = ("dim", "n_fiducials", "n_measurements", "restoration", "steps",
                 "interpolation", "sigma", "sigma_axis", "sigma_source", "sigma_L", "rho",
                 "recommendation", "decision", "uncorrected", "corrected", "fiducials", "targets",
                 "summary")


#: Report values that depend on the kriging hyper-parameter fit (when the decision chooses
#: kriging, the point to use and its error too): per target, and in the summary.
FITTED = ("destination", "tre", "expected_tre", "tre_bound")
FITTED_SUMMARY = ("tre_median", "fraction_within_bound")


def exact_part(report):
    out = {k: report[k] for k in REGISTER_KEYS if k != "decision"}
    out["targets"] = [{k: v for k, v in t.items() if k not in FITTED} for t in out["targets"]]
    out["summary"] = {k: v for k, v in out["summary"].items() if k not in FITTED_SUMMARY}
    return out


def fitted_part(report):
    return {"decision": report["decision"],
            "targets": [{k: t[k] for k in FITTED} for t in report["targets"]],
            "summary": {k: report["summary"][k] for k in FITTED_SUMMARY}}


@pytest.mark.parametrize("name, repeats, storage", [("RA", None, "sqlite3"),
                                                    ("A", 3, "mcap")])
def test_evaluate_bag_equals_register_csv(tmp_path, capsys, name, repeats, storage):
    cell = make_cell(name, seed=2, repeats=repeats)
    bag = tmp_path / "bag"
    write_bag(bag, cell_messages(cell), storage, progress=False)
    fid, tgt = cell_csv(cell, tmp_path)
    reg = run_json(["register", str(fid), "--targets", str(tgt), "--unit", "m"],
                   tmp_path / "register.json")
    ev = run_json(["evaluate", str(bag), "--quiet"], tmp_path / "evaluate.json")
    assert_same_numbers(exact_part(reg), exact_part(ev))
    # The decision and the expected errors go through the kriging fit (L-BFGS-B stops within its
    # tolerance, so inputs equal to rounding give hyper-parameters equal to ~1e-7).
    assert_same_numbers(fitted_part(reg), fitted_part(ev), rtol=1e-5)
    assert ev["dim"] == cell.spec.dimension
    assert len(ev["targets"]) == len(cell.target_ids) and "tre_u" in ev["targets"][0]
    out = capsys.readouterr().out
    assert "rho" in out and ev["recommendation"] in out


def test_targets_csv_and_loo_and_model_options_match_register(tmp_path):
    cell = make_cell("A", seed=4, repeats=2)
    bag = tmp_path / "bag"
    write_bag(bag, [m for m in cell_messages(cell) if m.topic != DEFAULT_TOPICS.targets],
              progress=False)
    fid, tgt = cell_csv(cell, tmp_path)
    opts = ["--sigma-axis", "0.0002", "--interpolation", "kriging", "--restoration",
            "closed-form", "--decision", "rho"]
    reg = run_json(["register", str(fid), "--targets", str(tgt), "--unit", "m", "--loo"] + opts,
                   tmp_path / "r.json")
    ev = run_json(["evaluate", str(bag), "--targets", str(tgt), "--loo", "--quiet"] + opts,
                  tmp_path / "e.json")
    assert_same_numbers({k: reg[k] for k in REGISTER_KEYS + ("loo",)}, ev, rtol=1e-7)
    assert ev["sigma_source"] == "given" and ev["interpolation"] == "kriging"
    assert ev["sigma_axis"] == pytest.approx(2e-4) and ev["sigma"] == pytest.approx(2e-4 * 3 ** .5)
    assert ev["decision"]["mode"] == "rho" and ev["decision"]["rho"] == pytest.approx(ev["rho"])


def test_point_pairs_give_the_model_of_fiducial_pairs(tmp_path):
    """The PointStamped streams go through the node's stamp pairing and id-by-proximity."""
    cell = make_cell("A", seed=3, repeats=3)
    write_bag(tmp_path / "pairs", cell_messages(cell), progress=False)
    write_bag(tmp_path / "points", cell_messages(cell, points=True), progress=False)
    a = run_json(["evaluate", str(tmp_path / "pairs"), "--quiet"], tmp_path / "a.json")
    b = run_json(["evaluate", str(tmp_path / "points"), "--quiet"], tmp_path / "b.json")
    assert [f["id"] for f in b["fiducials"]][:2] == ["auto-0000", "auto-0001"]
    for f in a["fiducials"] + b["fiducials"]:
        f.pop("id")
    assert_same_numbers({k: a[k] for k in REGISTER_KEYS}, b)


def test_rejections_are_counted_like_the_node(tmp_path):
    cell = make_cell("RA", seed=0)
    msgs = list(cell_messages(cell))
    msgs[3] = msgs[3]._replace(frame_id="camera")                          # wrong frame
    msgs[4] = msgs[4]._replace(xyz=(float("nan"), 0.0, 0.0))               # non-finite
    bag = tmp_path / "bag"
    write_bag(bag, msgs, progress=False)
    report = run_json(["evaluate", str(bag), "--quiet"], tmp_path / "e.json")
    assert report["bag"]["rejected"] == {"frame": 1, "nonfinite": 1, "outlier": 0,
                                         "malformed": 0, "stale": 0, "ambiguous": 0,
                                         "duplicate": 0, "conflict": 0}
    assert report["n_fiducials"] == len(cell.fiducial_ids) - 2


def test_a_rejected_message_or_a_target_does_not_make_a_2d_bag_3d(tmp_path, capsys):
    """one FiducialPair in another frame (rejected) with z = 0.5 made the RA bag 3D,
    then refused as coplanar; so did a target's z."""
    msgs = list(cell_messages(make_cell("RA", seed=0)))
    stray = OutMessage(DEFAULT_TOPICS.fiducial_pairs, "pair", msgs[0].stamp_ns + 1, "camera",
                       (0.1, 0.2, 0.5), "X", "world", (0.1, 0.2, 0.5))
    targets = [m._replace(xyz=m.xyz[:2] + (0.001,)) if m.topic == DEFAULT_TOPICS.targets
               else m for m in msgs]
    # and one with empty frame ids, which the node takes as its frames
    unframed = [m._replace(frame_id="", destination_frame="") for m in msgs]
    for name, bag_msgs in (("stray", [msgs[0], stray] + msgs[1:]), ("target_z", targets),
                           ("unframed", unframed)):
        write_bag(tmp_path / name, bag_msgs, progress=False)
        assert cli.main(["evaluate", str(tmp_path / name), "--quiet"]) == 0, name
        assert "dimension 2: every z of the measurements is 0" in capsys.readouterr().out


def test_dimension_inference_and_override(tmp_path, capsys):
    write_bag(tmp_path / "ra", cell_messages(make_cell("RA", seed=0)), progress=False)
    write_bag(tmp_path / "a", cell_messages(make_cell("A", seed=0, repeats=2)), progress=False)
    assert cli.main(["evaluate", str(tmp_path / "ra"), "--quiet"]) == 0
    assert "dimension 2: every z of the measurements is 0" in capsys.readouterr().out
    assert cli.main(["evaluate", str(tmp_path / "a"), "--quiet"]) == 0
    assert "dimension 3: the measurements have non-zero z" in capsys.readouterr().out
    report = run_json(["evaluate", str(tmp_path / "a"), "--quiet", "--dim", "2"],
                      tmp_path / "e.json")
    assert "dimension 2 (given)" in capsys.readouterr().out and report["dim"] == 2


def test_report_directory(tmp_path, capsys):
    bag = tmp_path / "bag"
    write_bag(bag, cell_messages(make_cell("RA", seed=1)), "mcap", progress=False)
    out = tmp_path / "report"
    assert cli.main(["evaluate", str(bag), "--out", str(out), "--quiet"]) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"report.json", "report.md", "mismatch_histograms.png", "fiducial_map.png",
                     "tre_per_target.png", "delta_tre.png", "cv_errors.png"}
    # Every file written is one evaluate checks against the inputs before writing (unchecked,
    # a hard link of one such name to an input would be overwritten).
    assert names <= set(REPORT_FILES)
    md = (out / "report.md").read_text()
    assert "| sigma | sigma_axis | sigma_L0 | rho |" in md
    assert "![delta_tre.png](delta_tre.png)" in md
    rep = json.loads((out / "report.json").read_text())
    dec = rep["decision"]
    assert "## Decision" in md and f"targets get **{dec['method']}**" in md
    # the reason, escaped like all text, its lengths (held-out medians) in mm as the report's
    reason_mm = dec["reason"]
    for c in dec["cv"].values():
        if c["median"] is not None:
            reason_mm = reason_mm.replace(f" {c['median']:.3g}", f" {1e3 * c['median']:.3g}")
    assert reason_mm != dec["reason"] and escape.markdown(reason_mm) in md
    assert "![cv_errors.png](cv_errors.png)" in md
    for name in dec["cv"]:
        assert f"| {name} | {1e3 * dec['cv'][name]['median']:.4g} |" in md
    assert "| target | TRE | expected TRE | 95 % bound |" in md
    assert json.loads((out / "report.json").read_text())["unit"] == "m"


def test_targets_without_truth_give_no_tre(tmp_path, capsys):
    cell = make_cell("RA", seed=0)
    nan = (float("nan"),) * 3
    msgs = [m._replace(destination=nan) if m.topic == DEFAULT_TOPICS.targets else m
            for m in cell_messages(cell)]
    write_bag(tmp_path / "bag", msgs, progress=False)
    report = run_json(["evaluate", str(tmp_path / "bag"), "--quiet"], tmp_path / "e.json")
    assert len(report["targets"]) == 80 and "tre_u" not in report["targets"][0]
    assert "targets have no truth" in capsys.readouterr().out


def test_a_one_id_targets_csv_is_checked_by_outlier_distance(tmp_path, capsys):
    """Rows of one target id 0.4 m apart were averaged (a one-id file has no spacing of its
    own); evaluate checks them by the node's outlier_distance, as it checks the bag's targets."""
    write_bag(tmp_path / "bag", cell_messages(make_cell("RA", seed=0)), progress=False)
    tgt = tmp_path / "t.csv"
    tgt.write_text("id,wx,wy\nT,0.1,0.1\nT,0.5,0.1\n")
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--targets", str(tgt), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "outlier_distance 0.01" in err and "row 3" in err and len(err.strip().splitlines()) == 1
    tgt.write_text("id,wx,wy\nT,0.1,0.1\nT,0.105,0.1\n")                 # 5 mm: one target
    report = run_json(["evaluate", str(tmp_path / "bag"), "--targets", str(tgt), "--quiet"],
                      tmp_path / "e.json")
    assert [t["id"] for t in report["targets"]] == ["T"]           # the two rows averaged


def test_too_few_fiducials_is_a_clear_error(tmp_path, capsys):
    msgs = [OutMessage(DEFAULT_TOPICS.fiducial_pairs, "pair", k * 20_000_000, "tracker",
                       (k * 0.1, 0.0, 0.0), f"F{k}", "world", (k * 0.1, 1.0, 0.0))
            for k in range(1, 4)]
    write_bag(tmp_path / "bag", msgs, progress=False)
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no model: 3 enabled fiducials, need min_fiducials=4" in err
    assert "Traceback" not in err


def test_evaluate_and_synth_bag_never_import_rclpy(tmp_path):
    code = ("import sys; from rbc_registration.cli import main; "
            f"assert main(['synth-bag', '--cell', 'RA', {str(tmp_path / 'b')!r}, '--quiet']) == 0;"
            f"assert main(['evaluate', {str(tmp_path / 'b')!r}, '--quiet']) == 0; "
            "assert 'rclpy' not in sys.modules, 'rclpy imported'")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr


def test_a_bag_in_millimetres_gets_a_warning(tmp_path, capsys):
    """A bag recorded in mm read as metres: outlier_distance (0.01 m) then cut its repeats and
    sigma was 0.006 instead of 0.11, without a word. It is warned about now."""
    def mm(m):
        return m._replace(xyz=tuple(1e3 * v for v in m.xyz),
                          destination=tuple(1e3 * v for v in m.destination))
    bag = tmp_path / "bag"
    write_bag(bag, [mm(m) for m in cell_messages(make_cell("RA", seed=0))], progress=False)
    assert cli.main(["evaluate", str(bag), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: the fiducials' RMS distance from their centroid is" in err
    assert "ROS data are in metres (REP 103)" in err


def test_point_stamps_that_repeat_are_noted(tmp_path, capsys):
    msgs = [m._replace(stamp_ns=0) for m in cell_messages(make_cell("RA", seed=0), points=True)]
    bag = tmp_path / "bag"
    write_bag(bag, msgs, progress=False)
    cli.main(["evaluate", str(bag), "--quiet"])
    out = capsys.readouterr().out
    assert out.count("point stamps repeat") == 2, out      # once per stream


def test_exact_duplicate_pairs_are_dropped_with_one_warning(tmp_path, capsys):
    """A bag recorded twice (every FiducialPair again, same id, stamp and points) counted each
    message as a repeat: sigma halved, or 0 with rho inf for single measurements. The
    duplicates are dropped with one warning line naming their count and topic."""
    msgs = list(cell_messages(make_cell("RA", seed=0)))
    pairs = [m for m in msgs if m.topic == DEFAULT_TOPICS.fiducial_pairs]
    write_bag(tmp_path / "once", msgs, progress=False)
    write_bag(tmp_path / "twice", msgs + pairs, progress=False)
    once = run_json(["evaluate", str(tmp_path / "once"), "--quiet"], tmp_path / "1.json")
    assert "warning" not in capsys.readouterr().err
    twice = run_json(["evaluate", str(tmp_path / "twice"), "--quiet"], tmp_path / "2.json")
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert (f"warning: bag {tmp_path / 'twice'}: {len(pairs)} exact duplicate message(s) "
            f"dropped") in err[0]
    assert twice["n_measurements"] == once["n_measurements"] == len(pairs)
    assert_same_numbers(exact_part(once), exact_part(twice))
    assert twice["bag"]["messages"][DEFAULT_TOPICS.fiducial_pairs] == 2 * len(pairs)


def test_point_topics_recorded_twice_give_the_model_of_the_bag_recorded_once(tmp_path, capsys):
    """both point topics recorded twice (each message right after its copy) made
    every point one with two candidates within pair_slop: every measurement was refused as
    ambiguous and there was no model. The copies are duplicates, dropped with one line."""
    msgs = list(cell_messages(make_cell("RA", seed=0), points=True))
    doubled = [c for m in msgs for c in ([m, m] if m.topic in (DEFAULT_TOPICS.working_point,
                                                              DEFAULT_TOPICS.destination_point)
                                         else [m])]
    write_bag(tmp_path / "once", msgs, progress=False)
    write_bag(tmp_path / "twice", doubled, progress=False)
    once = run_json(["evaluate", str(tmp_path / "once"), "--quiet"], tmp_path / "1.json")
    assert "warning" not in capsys.readouterr().err
    twice = run_json(["evaluate", str(tmp_path / "twice"), "--quiet"], tmp_path / "2.json")
    err = capsys.readouterr().err.strip().splitlines()
    copies = len(doubled) - len(msgs)
    assert len(err) == 1 and f"{copies} exact duplicate message(s) dropped" in err[0], err
    assert twice["n_measurements"] == once["n_measurements"] == copies // 2
    assert twice["bag"]["rejected"].get("ambiguous", 0) == 0
    assert_same_numbers(exact_part(once), exact_part(twice))


def test_one_id_and_stamp_with_other_points_is_refused(tmp_path, capsys):
    msgs = list(cell_messages(make_cell("RA", seed=0)))
    first = next(m for m in msgs if m.topic == DEFAULT_TOPICS.fiducial_pairs)
    other = first._replace(xyz=(first.xyz[0] + 1e-4,) + first.xyz[1:])
    write_bag(tmp_path / "bag", msgs + [other], progress=False)
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"{tmp_path / 'bag'}: fiducial {first.fiducial_id!r} at stamp " in err[0]
    assert " s: other points than an accepted measurement with that stamp (working " in err[0]
    assert err[0].endswith("which one is right is not known (stamp each measurement with its own "
                           "acquisition time, or leave the stamp 0); remove the wrong message")
    assert "Traceback" not in err[0]


def test_unstamped_pairs_are_never_duplicates():
    """Stamp 0 (not stamped) tells no measurement apart: such messages are all kept (the
    accumulator's duplicate rule, which evaluate and the node share)."""
    from rbc_registration.pipeline.inputs import PairMessage
    from rbc_registration.pipeline.offline import accumulate
    from rbc_registration.pipeline.settings import Settings

    settings = Settings.from_mapping({"outlier_distance": 0.0})
    m = PairMessage(0, 0.0, "F", (1.0, 2.0, 0.0), "tracker", (1.0, 2.0, 0.0), "world", 0)
    acc = accumulate([m, m, m._replace(working=(1.1, 2.0, 0.0))], settings)
    assert acc.fiducials.n_measurements == 3 and acc.rejected["duplicate"] == 0
    stamped = m._replace(stamp_s=1.0, stamp_ns=1_000_000_000)
    acc = accumulate([stamped, stamped, stamped._replace(fiducial_id="G")], settings)
    assert acc.rejected["duplicate"] == 1 and acc.fiducials.ids == ("F", "G")


def test_warnings_are_in_report_json_and_report_md(tmp_path, capsys):
    """The warnings went to stderr only: report.json and report.md did not say that
    the bag looks like millimetres, or which fiducial stands out. Each is in both now, once."""
    def mm(m):
        return m._replace(xyz=tuple(1e3 * v for v in m.xyz),
                          destination=tuple(1e3 * v for v in m.destination))
    bag, out = tmp_path / "bag", tmp_path / "out"
    write_bag(bag, [mm(m) for m in cell_messages(make_cell("RA", seed=0))], progress=False)
    report = run_json(["evaluate", str(bag), "--quiet", "--out", str(out)], tmp_path / "e.json")
    err = capsys.readouterr().err
    assert report["warnings"] and all(w in err for w in report["warnings"])
    assert any("the fiducials' RMS distance from their centroid is" in w
               for w in report["warnings"])
    assert json.loads((out / "report.json").read_text())["warnings"] == report["warnings"]
    md = (out / "report.md").read_text()
    assert all(f"**Warning**: {escape.markdown(w)}" in md for w in report["warnings"])


def test_a_blunder_is_warned_once_and_reported(tmp_path, capsys):
    """One fiducial's points 5 mm off (a wrong hole): one warning line (the model state's; the
    check ran twice before), in the reports too."""
    fid = DEFAULT_TOPICS.fiducial_pairs
    msgs = [m._replace(xyz=(m.xyz[0] + 0.005,) + m.xyz[1:])
            if m.topic == fid and m.fiducial_id == "F100" else m
            for m in cell_messages(make_cell("RA", seed=0))]
    write_bag(tmp_path / "bag", msgs, progress=False)
    report = run_json(["evaluate", str(tmp_path / "bag"), "--quiet"], tmp_path / "e.json")
    err = capsys.readouterr().err
    assert err.count("held-out error") == 1 and "fiducial F100: held-out error" in err, err
    assert len(report["warnings"]) == 1 and "fiducial F100: held-out error" in report["warnings"][0]


def test_a_wild_new_fiducial_is_left_out_warned_and_reported(tmp_path, capsys):
    """One fiducial's working point typed 1e7 m off: the model could not be built (the node's
    rule, pipeline.state.build_state): the model of the others, one warning, report.json's
    bag.left_out."""
    fid = DEFAULT_TOPICS.fiducial_pairs
    msgs = [m._replace(xyz=(1e7,) + m.xyz[1:])
            if m.topic == fid and m.fiducial_id == "F100" else m
            for m in cell_messages(make_cell("RA", seed=0))]
    write_bag(tmp_path / "bag", msgs, progress=False)
    report = run_json(["evaluate", str(tmp_path / "bag"), "--quiet"], tmp_path / "e.json")
    err = capsys.readouterr().err
    assert err.count("left out of the model") == 1 and "fiducial 'F100' (1e+07 m)" in err, err
    assert report["bag"]["left_out"] == ["F100"] and report["n_fiducials"] == len(
        make_cell("RA", seed=0).fiducial_ids) - 1
    assert any("fiducial 'F100' (1e+07 m)" in w for w in report["warnings"])


def test_a_swapped_target_truth_is_warned_and_reported(tmp_path, capsys):
    msgs = list(cell_messages(make_cell("RA", seed=0)))
    tgt = [k for k, m in enumerate(msgs) if m.topic == DEFAULT_TOPICS.targets]
    a, b = tgt[2], tgt[5]
    assert msgs[a].fiducial_id != msgs[b].fiducial_id
    msgs[a], msgs[b] = (msgs[a]._replace(destination=msgs[b].destination),
                        msgs[b]._replace(destination=msgs[a].destination))
    write_bag(tmp_path / "bag", msgs, progress=False)
    report = run_json(["evaluate", str(tmp_path / "bag"), "--quiet"], tmp_path / "e.json")
    err = capsys.readouterr().err
    assert err.count("uncorrected TRE over 20 x the median of the targets") == 1, err
    line = [w for w in report["warnings"] if "uncorrected TRE over" in w]
    assert len(line) == 1 and f"{msgs[a].fiducial_id!r} (" in line[0] \
        and f"{msgs[b].fiducial_id!r} (" in line[0]


def test_targets_without_truth_get_a_table_of_corrections(tmp_path):
    cell = make_cell("RA", seed=0)
    nan = (float("nan"),) * 3
    msgs = [m._replace(destination=nan) if m.topic == DEFAULT_TOPICS.targets else m
            for m in cell_messages(cell)]
    write_bag(tmp_path / "bag", msgs, progress=False)
    out = tmp_path / "out"
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--quiet", "--out", str(out)]) == 0
    md = (out / "report.md").read_text()
    report = json.loads((out / "report.json").read_text())
    assert "## Targets" in md and "TRE_u" not in md
    first = report["targets"][0]
    eps = 1e3 * float(np.linalg.norm(first["correction"]))
    assert f"| {first['id']} | {eps:.4g} | {1e3 * first['expected_tre']:.4g} |" in md
    assert md.count("\n| T") == len(cell.target_ids) == 80


def test_targets_without_truth_beside_targets_with_it(tmp_path, capsys):
    """one target message with a NaN destination dropped the truth of every target
    (no TRE at all). Now TRE is computed for the targets with truth, the others are n/a, the
    summary is over those with truth, and one note names the count."""
    cell = make_cell("RA", seed=0)
    blind = {cell.target_ids[3], cell.target_ids[10]}
    nan = (float("nan"),) * 3
    full = list(cell_messages(cell))
    write_bag(tmp_path / "all", full, progress=False)
    write_bag(tmp_path / "part", [m._replace(destination=nan) if m.topic == DEFAULT_TOPICS.targets
                                  and m.fiducial_id in blind else m for m in full],
              progress=False)
    ref = run_json(["evaluate", str(tmp_path / "all"), "--quiet"], tmp_path / "a.json")
    out = tmp_path / "out"
    got = run_json(["evaluate", str(tmp_path / "part"), "--quiet", "--out", str(out)],
                   tmp_path / "p.json")
    text = capsys.readouterr().out
    assert text.count("2 of 80 targets have no truth") == 1, text
    by_id = {t["id"]: t for t in got["targets"]}
    for t in ref["targets"]:
        if t["id"] in blind:
            assert by_id[t["id"]]["tre"] is None and by_id[t["id"]]["tre_u"] is None
            assert by_id[t["id"]]["correction"] == t["correction"]
        else:
            assert (by_id[t["id"]]["tre_u"], by_id[t["id"]]["tre_c"]) == (t["tre_u"], t["tre_c"])
    kept = [t for t in got["targets"] if t["tre_u"] is not None]
    assert len(kept) == 78
    assert got["summary"]["tre_u_median"] == pytest.approx(np.median([t["tre_u"] for t in kept]))
    assert got["summary"]["tre_median"] == pytest.approx(np.median([t["tre"] for t in kept]))
    md = (out / "report.md").read_text()
    assert "of 78 targets with truth (2 without: TRE n/a)" in md
    assert (out / "tre_per_target.png").is_file()


def test_a_reused_out_directory_keeps_no_figure_of_the_earlier_report(tmp_path):
    """``--out`` reused for a bag without truth kept the earlier bag's TRE figures
    beside the new report. Files that are not the report's own are left alone."""
    cell = make_cell("RA", seed=0)
    write_bag(tmp_path / "truth", cell_messages(cell), progress=False)
    nan = (float("nan"),) * 3
    write_bag(tmp_path / "blind", [m._replace(destination=nan) if m.topic ==
                                   DEFAULT_TOPICS.targets else m for m in cell_messages(cell)],
              progress=False)
    out = tmp_path / "out"
    assert cli.main(["evaluate", str(tmp_path / "truth"), "--quiet", "--out", str(out)]) == 0
    assert (out / "tre_per_target.png").is_file() and (out / "delta_tre.png").is_file()
    (out / "notes.txt").write_text("mine\n")
    assert cli.main(["evaluate", str(tmp_path / "blind"), "--quiet", "--out", str(out)]) == 0
    left = {p.name for p in out.iterdir()}
    assert left == {"report.json", "report.md", "mismatch_histograms.png", "fiducial_map.png",
                    "cv_errors.png", "notes.txt"}, left
    assert left - {"notes.txt"} <= set(REPORT_FILES)


def test_report_md_quotes_the_reason_in_mm(tmp_path):
    write_bag(tmp_path / "bag", cell_messages(make_cell("RA", seed=0)), progress=False)
    out = tmp_path / "out"
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--quiet", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    md = (out / "report.md").read_text()
    cv = report["decision"]["cv"]
    best = cv[report["decision"]["method"]]["median"]
    metres = f"median error {best:.3g} vs {cv['uncorrected']['median']:.3g}"
    assert metres in report["decision"]["reason"]
    assert escape.markdown(f"median error {1e3 * best:.3g} vs "
                           f"{1e3 * cv['uncorrected']['median']:.3g}") in md
    assert escape.markdown(metres) not in md


def test_ambiguous_points_are_refused_with_one_warning(tmp_path, capsys):
    """Point streams 20 ms apart with the default 20 ms pair_slop (synth-bag's earlier
    default), the destination clock 12 ms ahead: nearest in time paired them silently; now the
    ambiguous points are refused, counted, and one warning line names the topics, the count
    and the hint. At 50 ms (the default now) nothing is ambiguous and the report is that of
    the FiducialPair bag."""
    cell = make_cell("RA", seed=0)
    msgs = [m._replace(stamp_ns=m.stamp_ns + 12_000_000) if m.topic.endswith("destination_point")
            else m for m in cell_messages(cell, period_s=0.02, points=True)]
    write_bag(tmp_path / "near", msgs, progress=False)
    assert cli.main(["evaluate", str(tmp_path / "near"), "--quiet"]) == 2   # no model
    err = capsys.readouterr().err
    assert "ambiguous" in err and "Traceback" not in err
    write_bag(tmp_path / "half", msgs[:4] + [m for m in cell_messages(cell, points=True,
                                                                      start_ns=2 * 10**18)],
              progress=False)
    rep = run_json(["evaluate", str(tmp_path / "half"), "--quiet"], tmp_path / "h.json")
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if "ambiguous" in x]
    assert len(lines) == 1 and rep["bag"]["rejected"]["ambiguous"] >= 1, err
    assert (f"point(s) of {DEFAULT_TOPICS.working_point} and {DEFAULT_TOPICS.destination_point}"
            " refused as ambiguous") in lines[0]
    assert "lower pair_slop below half the measurement period" in lines[0]
    assert lines[0].split("warning: ", 1)[1] in rep["warnings"]
    write_bag(tmp_path / "points", cell_messages(cell, points=True), progress=False)
    write_bag(tmp_path / "pairs", cell_messages(cell), progress=False)
    a = run_json(["evaluate", str(tmp_path / "pairs"), "--quiet"], tmp_path / "a.json")
    b = run_json(["evaluate", str(tmp_path / "points"), "--quiet"], tmp_path / "b.json")
    assert "ambiguous" not in capsys.readouterr().err and b["bag"]["rejected"]["ambiguous"] == 0
    for f in a["fiducials"] + b["fiducials"]:
        f.pop("id")
    assert_same_numbers({k: a[k] for k in REGISTER_KEYS}, b)


def test_point_mode_sample_is_said_to_be_paired_by_stamps(tmp_path, capsys):
    """-p point_mode:=sample was ignored without a word: a bag has no ~/take_sample calls."""
    cell = make_cell("A", seed=0)
    bag = tmp_path / "points"
    write_bag(bag, cell_messages(cell, points=True), progress=False)
    out = tmp_path / "r.json"
    assert cli.main(["evaluate", str(bag), "--quiet", "-p", "point_mode:=sample",
                     "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("point_mode 'sample': a bag does not record the ~/take_sample calls") == 1
    assert any("point_mode 'sample'" in w for w in json.loads(out.read_text())["warnings"])
    assert cli.main(["evaluate", str(bag), "--quiet"]) == 0
    assert "point_mode" not in capsys.readouterr().err


def test_outputs_into_the_bag_or_unwritable_are_refused_before_reading(tmp_path, capsys):
    """--json BAG/x.json wrote into the bag directory, and a --json in a missing
    directory failed after the whole evaluation with a raw Errno."""
    cell = make_cell("A", seed=0)
    bag = tmp_path / "bag"
    write_bag(bag, cell_messages(cell), progress=False)
    before = sorted(p.name for p in bag.iterdir())
    cases = [(["--json", str(bag / "x.json")], "is inside the input bag"),
             (["--out", str(bag / "report")], "is inside the input bag"),
             (["--json", str(tmp_path)], "cannot be written: it is a directory"),
             (["--out", str(bag / "metadata.yaml")], "is inside the input bag")]
    (tmp_path / "file").write_text("x")
    cases += [(["--out", str(tmp_path / "file")],
               "cannot be written: it exists and is not a directory"),
              (["--json", str(tmp_path / "file" / "r.json")],
               f"cannot be written: {tmp_path / 'file'} is not a directory")]
    for args, why in cases:
        assert cli.main(["evaluate", str(bag), "--quiet", *args]) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0] and "reading" not in err[0], (args, err)
    assert sorted(p.name for p in bag.iterdir()) == before
    out = tmp_path / "new" / "deeper"                       # outputs create their parents
    assert cli.main(["evaluate", str(bag), "--quiet", "--out", str(out), "--json",
                     str(tmp_path / "new2" / "r.json")]) == 0
    assert (out / "report.json").exists() and (tmp_path / "new2" / "r.json").exists()


def test_a_bag_whose_messages_are_mostly_rejected_says_why(tmp_path, capsys):
    """a points bag whose destination stream came 60 s late lost 99.6 % of its points
    (the pairing buffer) with warnings: [] and exit 0; now one warning names the share, the
    reasons and the first message (the model is built from the rest, as the node's would be)."""
    msgs = list(cell_messages(make_cell("RA", seed=0)))
    n = sum(m.topic == DEFAULT_TOPICS.fiducial_pairs for m in msgs)
    stray = [OutMessage(DEFAULT_TOPICS.fiducial_pairs, "pair", 10**15 + k * 10**6, "camera",
                        (0.1, 0.2, 0.0), f"X{k}", "world", (0.1, 0.2, 0.0))
             for k in range(n // 5)]
    write_bag(tmp_path / "bag", msgs + stray, progress=False)
    report = run_json(["evaluate", str(tmp_path / "bag"), "--quiet"], tmp_path / "e.json")
    (line,) = [w for w in report["warnings"] if "input message(s) rejected" in w]
    assert line.startswith(f"{n // 5} of {n + n // 5} input message(s) rejected (frame "
                           f"{n // 5}), e.g. frame: "), line
    assert "working frame must be 'tracker', got 'camera'" in line
    assert line in capsys.readouterr().err


def tilted(messages, degrees):
    """``messages`` with every working-frame point turned ``degrees`` about x (a plate tilted
    in the tracker's frame); destination points unchanged."""
    a = np.radians(degrees)
    turn = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    working = (DEFAULT_TOPICS.fiducial_pairs, DEFAULT_TOPICS.working_point, DEFAULT_TOPICS.targets)
    for m in messages:
        yield m._replace(xyz=tuple(float(v) for v in turn @ m.xyz)) if m.topic in working else m


@pytest.mark.parametrize("points", [False, True])
def test_a_tilted_plate_bag_read_in_2d_is_named(tmp_path, capsys, points):
    """A bag of a plate tilted 3 degrees in the working frame, read in 2D: the same warning as
    a CSV file (core/rigid/scale.dropped_z_warning, through the node's ingestion, so for
    FiducialPair
    and point topics alike: the point topics had none); level (0 degrees) none."""
    cell = make_cell("RA", seed=0)
    for name, degrees in (("tilted", 3.0), ("level", 0.0)):
        write_bag(tmp_path / name, tilted(cell_messages(cell, points=points), degrees),
                  progress=False)
    named = "read in 2D, the frames' xy planes are 3 degrees apart"
    assert cli.main(["evaluate", str(tmp_path / "tilted"), "--quiet", "--dim", "2"]) == 0
    assert capsys.readouterr().err.count(named) == 1
    assert cli.main(["evaluate", str(tmp_path / "level"), "--quiet", "--dim", "2"]) == 0
    assert "read in 2D" not in capsys.readouterr().err
