"""pipeline/named: ``target_frames`` entries (NAME:X,Y,Z) and calibration names, each refusal in
one line naming the entry and what is wrong; the node's settings run the same rules."""

import os
import re

import pytest

from rbc_registration.io.calibration_model import (CALIBRATIONS_DIR, named_calibration_path,
                                                   resolve_calibration_file)
from rbc_registration.pipeline.named import (MAX_TARGET_FRAMES, TargetFrame,
                                             calibration_name_problem, is_calibration_name,
                                             parse_target_frames)
from rbc_registration.pipeline.settings import Settings


def test_entries_are_parsed_in_order():
    frames, error = parse_target_frames(["peg_a:0.42,0.1,0.05", "hole/b:-1,2e-3,0"])
    assert error is None
    assert frames == (TargetFrame("peg_a", (0.42, 0.1, 0.05)),
                      TargetFrame("hole/b", (-1.0, 0.002, 0.0)))
    assert parse_target_frames([]) == ((), None) and parse_target_frames(None) == ((), None)


@pytest.mark.parametrize("value, message", [
    ("peg:1,2,3", r"target_frames must be a list of strings NAME:X,Y,Z"),
    (["peg:1,2"], r"target_frames\[0\] 'peg:1,2' must be NAME:X,Y,Z"),
    (["1,2,3"], r"target_frames\[0\] '1,2,3' must be NAME:X,Y,Z"),
    (["a:1,2,3", 7], r"target_frames\[1\] must be a string NAME:X,Y,Z, got '7'"),
    (["peg:1,x,3"], r"target_frames\[0\] 'peg:1,x,3': X,Y,Z must be numbers"),
    (["peg:1,nan,3"], r"coordinates must be finite and within"),
    ([":1,2,3"], r"target_frames\[0\]: the name is a tf frame id: it "),
    (["a:1,2,3", "a:0,0,0"], r"target_frames\[1\]: the name 'a' is given twice"),
    (["t:0,0,0"] * (MAX_TARGET_FRAMES + 1), rf"{MAX_TARGET_FRAMES + 1} entries, at most"),
])
def test_bad_entries_are_refused_naming_the_entry(value, message):
    frames, error = parse_target_frames(value)
    assert frames == () and error is not None and "\n" not in error
    assert re.search(message, error), error
    with pytest.raises(ValueError, match=message):
        Settings.from_mapping({"state_dir": "", "target_frames": value})


def test_a_target_frame_may_not_be_a_frame_of_the_node():
    with pytest.raises(ValueError, match=r"target_frames\[0\]: the name 'tracker' is "
                                         r"working_frame"):
        Settings.from_mapping({"state_dir": "", "target_frames": ["tracker:0,0,0"]})
    s = Settings.from_mapping({"state_dir": "", "target_frames": ["peg:0,0,0"]})
    assert s.target_frames == ("peg:0,0,0",)


@pytest.mark.parametrize("name", ["cell_a", "line-1", "v2.3", "A"])
def test_calibration_names(name, tmp_path):
    assert calibration_name_problem(name) is None and is_calibration_name(name)
    path = named_calibration_path(str(tmp_path), name)
    assert path == os.path.join(str(tmp_path), CALIBRATIONS_DIR, f"{name}.yaml")
    assert resolve_calibration_file(name, str(tmp_path)) == path
    assert Settings.from_mapping({"state_dir": str(tmp_path), "calibration_name": name,
                                  "calibration_file": name}).calibration_name == name


@pytest.mark.parametrize("name, message", [
    ("../up", "a calibration name is 1-100 letters"), (".hidden", "not starting with '.'"),
    ("-x", "not starting with '.' or '-'"), ("a b", "a calibration name is 1-100"),
    ("x" * 101, "a calibration name is 1-100"), ("cell.yaml", "has no .yaml"),
])
def test_bad_calibration_names_are_refused(name, message, tmp_path):
    assert message in calibration_name_problem(name)
    with pytest.raises(ValueError, match="calibration_name: "):
        Settings.from_mapping({"state_dir": str(tmp_path), "calibration_name": name})
    with pytest.raises(ValueError):
        named_calibration_path(str(tmp_path), name)


def test_a_path_is_not_a_name(tmp_path):
    for path in ("cal.yaml", "dir/cal", "~/cal", "/abs/cal.yml"):
        assert not is_calibration_name(path)
    assert resolve_calibration_file("cal.yaml", "") == os.path.abspath("cal.yaml")
    assert resolve_calibration_file("~/c.yaml", "") == os.path.expanduser("~/c.yaml")
    with pytest.raises(ValueError, match="is a calibration name, read from "
                                         "state_dir/calibrations/, but state_dir is empty"):
        resolve_calibration_file("cell_a", "")
    with pytest.raises(ValueError, match="but state_dir is empty: give the file's path"):
        Settings.from_mapping({"state_dir": "", "calibration_file": "cell_a"})
    with pytest.raises(ValueError, match=r"calibration_file 'a b' is a calibration name"):
        Settings.from_mapping({"state_dir": str(tmp_path), "calibration_file": "a b"})
