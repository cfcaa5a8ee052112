"""Issue 11, bounds: zero, negative, huge and NaN values of the numeric options end in one clear
line and exit 2 (never a traceback, a hang or an allocation of gigabytes), and targets in
another unit than the fiducials (every target out of the hull by a factor ~1000) get one warning
line naming the likely unit mismatch."""

import json
import os
import resource
import subprocess
import sys

import numpy as np
import pytest

from rbc_registration import cli
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag
from rbc_registration.io.csv_io import write_fiducials, write_targets


def _limits():
    # A bound that is missing must not take the machine down: 3 GB of address space.
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))


@pytest.mark.parametrize("args, message", [
    (["reproduce", "--repeats", "1"], "--repeats: must be an integer in [2, 10000], got '1'"),
    (["reproduce", "--repeats", "1000000000"], "--repeats: must be an integer in [2, 10000]"),
    (["reproduce", "--instantaneous", "0"], "--instantaneous: must be an integer in [1, "),
    (["reproduce", "--instantaneous", "-1"], "--instantaneous: must be an integer in [1, "),
    (["reproduce", "--seed", "-1"], "--seed: must be an integer in [0, "),
    (["synth-bag", "--cell", "RA", "{tmp}/b1", "--repeats", "1000000000"],
     "--repeats: must be an integer in [1, 10000]"),
    (["synth-bag", "--cell", "RA", "{tmp}/b2", "--period", "1e300"], "--period: must be in"),
    (["synth-bag", "--cell", "RA", "{tmp}/b3", "--period", "1e-300"], "--period: must be in"),
    (["synth-bag", "--cell", "RA", "{tmp}/b4", "--seed", "-3"], "--seed: must be an integer in"),
    (["replay", "{tmp}/bag", "--rate", "1e-12"], "--rate: must be in [0.001, 1e+06]"),
    (["replay", "{tmp}/bag", "--rate", "nan"], "--rate: must be in"),
    (["replay", "{tmp}/bag", "--wait", "inf"], "--wait: must be in [0, 3600]"),
    (["replay", "{tmp}/bag", "--wait", "nan"], "--wait: must be in [0, 3600]"),
    (["replay", "{tmp}/bag", "--wait", "-1"], "--wait: must be in [0, 3600]"),
    (["register", "{tmp}/f.csv", "--outlier-distance", "nan"], "--outlier-distance: must be"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_out_of_range_numbers_are_one_clear_line(tmp_path, args, message):
    argv = [a.format(tmp=tmp_path) for a in args]
    if argv[0] == "reproduce":
        argv += ["--cells", "RA", "--out", str(tmp_path / "out")]
    if argv[0] == "replay":      # a real bag: the bad values must not reach the player
        write_bag(tmp_path / "bag", cell_messages(make_cell("RA", seed=0)), progress=False)
    proc = subprocess.run([sys.executable, "-m", "rbc_registration.cli", *argv],
                          capture_output=True, text=True, timeout=120, preexec_fn=_limits,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert message in lines[0] and lines[0].startswith(f"rbc-registration {args[0]}: error: ")
    assert not (tmp_path / "out").exists()          # refused before anything was written


@pytest.fixture(scope="module")
def mm_cell(tmp_path_factory):
    d = tmp_path_factory.mktemp("units")
    cell = make_cell("A", seed=0, repeats=2)
    write_fiducials(d / "f.csv", cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    return d, cell


@pytest.mark.parametrize("scale, warned", [(1e-3, True), (1e3, True), (1.0, False)])
def test_targets_in_another_unit_get_one_warning_line(tmp_path, capsys, mm_cell, scale, warned):
    d, cell = mm_cell
    write_targets(tmp_path / "t.csv", cell.target_ids, cell.target_means * scale)
    assert cli.main(["register", str(d / "f.csv"), "--targets", str(tmp_path / "t.csv"),
                     "--json", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    report = json.loads((tmp_path / "r.json").read_text())
    if not warned:
        assert err == [] and any(t["inside_hull"] for t in report["targets"])
        return
    assert not any(t["inside_hull"] for t in report["targets"])
    assert len(err) == 1 and err[0].startswith("rbc-registration register: warning: ")
    assert "unit" in err[0] and f"{len(cell.target_ids)} targets" in err[0]
    ratio = float(err[0].split("~")[1].split("x")[0])
    assert 300 <= ratio <= 3000                      # "~1e+03x": the factor, roughly


def test_a_few_targets_out_of_the_hull_are_no_unit_mismatch(tmp_path, capsys, mm_cell):
    d, cell = mm_cell
    far = cell.target_means.copy()
    far[:, 0] += np.ptp(cell.fiducial_truth[:, 0]) * 1.5   # out, but the same unit
    write_targets(tmp_path / "t.csv", cell.target_ids, far)
    assert cli.main(["register", str(d / "f.csv"), "--targets", str(tmp_path / "t.csv")]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("scale, warned", [(1e3, True), (1.0, False)])
def test_target_truth_in_another_unit_gets_a_warning(tmp_path, capsys, mm_cell, scale, warned):
    """The truth columns of TARGETS.csv (or a bag's targets) were never compared with the
    fiducials: truth in another unit gave 'median TRE 320 m' without a word."""
    d, cell = mm_cell
    write_targets(tmp_path / "t.csv", cell.target_ids, cell.target_means,
                  cell.target_truth * scale)
    assert cli.main(["register", str(d / "f.csv"), "--targets", str(tmp_path / "t.csv")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert [line for line in err if "the targets' truth" in line and "unit mismatch" in line] \
        == (err if warned else []), err
    assert len(err) == (1 if warned else 0), err


@pytest.mark.parametrize("command", ["synth-bag", "evaluate"])
@pytest.mark.parametrize("name", ["my node!", "", "9lives", "a//b", "x" * 256, "a" * 229])
def test_a_bad_node_name_is_one_clear_line(tmp_path, capsys, command, name):
    """``synth-bag --node-name "my node!"`` wrote a bag whose topics no ROS graph takes (replay
    then ended in an rclpy traceback): ROS name rules, one line, exit 2."""
    args = ["--cell", "RA"] if command == "synth-bag" else []
    with pytest.raises(SystemExit) as done:
        cli.main([command, str(tmp_path / "bag"), *args, "--node-name", name, "--quiet"])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a valid ROS node name" in err[0], err
    assert not (tmp_path / "bag").exists()


@pytest.mark.parametrize("args, message", [
    (["--working-frame", ""], "argument --working-frame: '': a frame id must not be empty"),
    (["--working-frame", "my tracker"], "must not contain whitespace"),
    (["--destination-frame", "/world"], "must not start with '/' (tf2 refuses it)"),
    (["--working-frame", "world"], "--destination-frame must differ from --working-frame, "
                                   "both are 'world'"),
])
def test_synth_bag_refuses_a_frame_the_node_refuses(tmp_path, capsys, args, message):
    """``synth-bag`` wrote bags with frames '' or 'a b', or both 'world', which the
    node (its frame parameters, the same rule) cannot be started with to replay them."""
    code = 0
    try:
        code = cli.main(["synth-bag", str(tmp_path / "bag"), "--cell", "RA", "--quiet", *args])
    except SystemExit as done:
        code = done.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "bag").exists()


def test_the_longest_node_name_gives_topics_rcl_takes():
    """A 250-character name passed and its replay ended in rclpy's InvalidTopicNameException
    traceback (topics at most 255 - 8 characters)."""
    from rbc_registration.io.bag.records import (MAX_NODE_NAME_LENGTH, Topics, node_name_error,
                                                 topic_name_error)
    name = "a" * MAX_NODE_NAME_LENGTH
    assert node_name_error(name) == "" and node_name_error("/" + name + "/") == ""
    assert [topic_name_error(t) for t in Topics.for_node(name)] == [""] * 4
    assert max(len(t) for t in Topics.for_node(name)) == 247
    assert node_name_error(name + "a") and topic_name_error("/" + "a" * 247)


def test_a_namespaced_node_name_is_accepted(tmp_path):
    assert cli.main(["synth-bag", str(tmp_path / "bag"), "--cell", "RA", "--node-name",
                     "cell_a/reg", "--quiet"]) == 0
    assert cli.main(["evaluate", str(tmp_path / "bag"), "--node-name", "/cell_a/reg",
                     "--quiet"]) == 0


def test_a_named_topic_brings_its_namespace_to_the_topics_not_named(tmp_path):
    """A bag of /cell_a/reg with --fiducial-topic (no --node-name): the targets come from
    /cell_a/reg/targets (they were read from /registration_node/targets and lost silently)."""
    bag = tmp_path / "bag"
    assert cli.main(["synth-bag", str(bag), "--cell", "RA", "--node-name", "cell_a/reg",
                     "--quiet"]) == 0
    named, full = tmp_path / "named.json", tmp_path / "full.json"
    assert cli.main(["evaluate", str(bag), "--fiducial-topic", "/cell_a/reg/fiducial_pairs",
                     "--json", str(named), "--quiet"]) == 0
    assert cli.main(["evaluate", str(bag), "--node-name", "/cell_a/reg", "--json", str(full),
                     "--quiet"]) == 0
    a, b = (json.loads(p.read_text()) for p in (named, full))
    assert a["targets"] and a["targets"] == b["targets"]


@pytest.mark.parametrize("options, targets", [
    (["--fiducial-topic", "/cell_a/reg/fiducial_pairs"], "/cell_a/reg/targets"),
    (["--working-topic", "/tracker/point", "--destination-topic", "/tracker/robot"],
     "/tracker/targets"),
    # /robot_point is in the root, so the two share no namespace; the
    # targets were read from /tracker/targets (absent) and the bag's own lost without a word
    (["--working-topic", "/tracker/point", "--destination-topic", "/robot_point"],
     "/registration_node/targets"),
    (["--fiducial-topic", "/pairs"], "/registration_node/targets"),
])
def test_topics_not_named_follow_a_namespace_only_when_the_named_ones_share_one(options,
                                                                                 targets):
    from rbc_registration.cli import build_parser
    from rbc_registration.cli.evaluate import topics_from_args

    topics, _ = topics_from_args(build_parser().parse_args(["evaluate", "bag", *options]))
    assert topics.targets == targets


def test_reproduce_onto_a_file_is_one_line_naming_the_option(tmp_path, capsys):
    """`reproduce --out FILE` ended in a bare `[Errno 17] File exists`."""
    (tmp_path / "f.csv").write_text("id\n")
    assert cli.main(["reproduce", "--cells", "RA", "--out", str(tmp_path / "f.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"rbc-registration reproduce: error: --out {tmp_path / 'f.csv'} cannot be "
                   "written: it exists and is not a directory"]
