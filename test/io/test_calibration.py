"""Saved calibrations (rbc_registration.io.calibration): round trips, quaternions against scipy,
one test per validation rule with its message, and the exact static_transform_publisher line."""

import ast
import dataclasses
import math
import os
import re
import shlex

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rbc_registration.io.calibration import (MAX_FILE_BYTES, Calibration, Decision,
                                             calibration_from_registration, launch_snippet,
                                             matrix_from_quaternion, package_version,
                                             quaternion_from_matrix, read_calibration,
                                             static_transform_publisher_args,
                                             static_transform_publisher_command,
                                             write_calibration)

APPLY = Decision(mode="rho", method="paper", apply=True, reason="rho 3.1 >= 2.5")


def make(rotation=None, translation=(1.2, -0.4, 0.8), **overrides):
    """A calibration of a 3D registration, created at t = 1.7e9 s (2023-11-14T22:13:20Z)."""
    rotation = Rotation.from_euler("xyz", [0.1, -0.2, 0.3]).as_matrix() if rotation is None \
        else rotation
    kwargs = dict(parent_frame="world", child_frame="tracker", registration="corrected",
                  fre_rms=1.5e-5, decision=APPLY, sigma=5e-5, sigma_l=[1e-3, 2e-6, 1e-9],
                  expected_tre_rigid=1.2e-3, expected_tre_with_corrections=8e-5, n_fiducials=48,
                  clock=lambda: 1_700_000_000.0, version="0.1.0")
    kwargs.update(overrides)
    return calibration_from_registration(rotation, translation, **kwargs)


# --- round trips -------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(5))
def test_write_read_round_trip_3d(tmp_path, seed):
    rng = np.random.default_rng(seed)
    cal = make(Rotation.random(random_state=seed).as_matrix(), rng.normal(0, 2, 3),
               sigma=float(rng.uniform(1e-6, 1e-3)), expected_tre_rigid=None,
               expected_tre_with_corrections=None)
    path = str(tmp_path / "cal.yaml")
    write_calibration(path, cal)
    assert read_calibration(path) == cal  # every float bit-exact, every field
    assert sorted(os.listdir(tmp_path)) == ["cal.yaml"]  # no temporary file left behind


def test_write_read_round_trip_2d_unknown_sigma(tmp_path):
    angle = 2.1
    r2 = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    cal = make(r2, [0.25, -1.5], sigma=None, expected_tre_rigid=None,
               expected_tre_with_corrections=None,
               decision=Decision("rho", "paper", False, "no sigma: recommendation unknown"))
    assert (cal.dimension, cal.translation[2], cal.rotation[:2]) == (2, 0.0, (0.0, 0.0))
    assert cal.sigma is None and cal.sigma_axis is None
    path = str(tmp_path / "cal.yaml")
    write_calibration(path, cal)
    assert read_calibration(path) == cal
    np.testing.assert_allclose(cal.rotation_matrix()[:2, :2], r2, atol=1e-15)


def test_overwrite_replaces_the_file(tmp_path):
    path = str(tmp_path / "cal.yaml")
    write_calibration(path, make())
    second = make(translation=(0.0, 0.0, 0.0))
    write_calibration(path, second)
    assert read_calibration(path) == second
    assert sorted(os.listdir(tmp_path)) == ["cal.yaml"]


def test_failed_write_keeps_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    path = str(tmp_path / "cal.yaml")
    first = make()
    write_calibration(path, first)

    def broken_fsync(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="No space left"):
        write_calibration(path, make(translation=(9.0, 9.0, 9.0)))
    monkeypatch.undo()
    assert read_calibration(path) == first
    assert sorted(os.listdir(tmp_path)) == ["cal.yaml"]


def test_transform_maps_working_to_destination():
    rng = np.random.default_rng(3)
    r, t = Rotation.random(random_state=3).as_matrix(), rng.normal(0, 1, 3)
    cal = make(r, t)
    working = rng.normal(0, 1, (10, 3))
    destination = working @ r.T + t  # destination = R @ working + t
    homogeneous = np.column_stack([working, np.ones(10)])
    np.testing.assert_allclose(homogeneous @ cal.transform_matrix().T[:, :3], destination,
                               atol=1e-12)


def test_record_is_immutable_and_created_comes_from_the_clock():
    cal = make()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.parent_frame = "map"
    assert cal.created == "2023-11-14T22:13:20.000000Z"
    assert cal.sigma_axis == pytest.approx(5e-5 / math.sqrt(3), rel=1e-15)
    assert package_version() == "0.1.0"  # setup.py's version, from the installed metadata


# --- quaternions -------------------------------------------------------------------------------

def _same_rotation_quaternions(q, reference):
    q, reference = np.asarray(q), np.asarray(reference)
    return min(np.abs(q - reference).max(), np.abs(q + reference).max())  # q and -q agree


def test_quaternion_matrix_round_trip_3d_against_scipy():
    for k, rotation in enumerate(Rotation.random(200, random_state=1)):
        r = rotation.as_matrix()
        q = quaternion_from_matrix(r)
        assert q[3] >= 0.0, k
        assert abs(np.linalg.norm(q) - 1.0) < 1e-15
        assert _same_rotation_quaternions(q, rotation.as_quat()) < 1e-12, k
        np.testing.assert_allclose(matrix_from_quaternion(q), r, atol=1e-12)


def test_quaternion_matrix_round_trip_2d_against_scipy():
    for angle in np.random.default_rng(2).uniform(-math.pi, math.pi, 200):
        r2 = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        q = quaternion_from_matrix(r2)
        assert q[:2] == (0.0, 0.0) and q[3] >= 0.0
        assert _same_rotation_quaternions(q, Rotation.from_euler("z", angle).as_quat()) < 1e-12
        m = matrix_from_quaternion(q)
        np.testing.assert_allclose(m[:2, :2], r2, atol=1e-12)
        np.testing.assert_array_equal(m[2], [0.0, 0.0, 1.0])


@pytest.mark.parametrize("matrix, quaternion", [
    (np.eye(3), (0.0, 0.0, 0.0, 1.0)),
    (np.diag([-1.0, -1.0, 1.0]), (0.0, 0.0, 1.0, 0.0)),   # w = 0: the first non-zero is positive
    (np.diag([1.0, -1.0, -1.0]), (1.0, 0.0, 0.0, 0.0)),
    ([[0.0, -1.0], [1.0, 0.0]], (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))),
])
def test_quaternion_of_known_rotations(matrix, quaternion):
    assert quaternion_from_matrix(matrix) == quaternion


@pytest.mark.parametrize("matrix, message", [
    (np.diag([1.0, 1.0, -1.0]), "not a proper rotation matrix"),           # a reflection
    (np.diag([1.0, 1.0, 1.0 + 1e-5]), "not a proper rotation matrix"),     # not orthonormal
    (np.eye(4), r"must be a finite \(2, 2\) or \(3, 3\) matrix"),
    (np.full((3, 3), np.nan), r"must be a finite \(2, 2\) or \(3, 3\) matrix"),
])
def test_quaternion_from_matrix_refuses(matrix, message):
    with pytest.raises(ValueError, match=message):
        quaternion_from_matrix(matrix)


def test_translation_shape_must_match_the_rotation():
    with pytest.raises(ValueError, match=r"translation must have shape \(3,\)"):
        make(translation=(1.0, 2.0))


# --- validation: one test per rule, each with its message --------------------------------------

def _document(cal=None):
    return cal.to_mapping() if cal is not None else make().to_mapping()


def _set(doc, dotted, value):
    *parents, last = dotted.split(".")
    for key in parents:
        doc = doc[key]
    if value is _DELETE:
        del doc[last]
    else:
        doc[last] = value


_DELETE = object()


def _read_mutated(tmp_path, changes, base=None):
    doc = _document(base)
    for dotted, value in changes.items():
        _set(doc, dotted, value)
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return str(path), lambda: read_calibration(str(path))


RULES = [
    # (changes, the message after "<path>: ")
    ({"sigma_L": _DELETE}, "sigma_L: missing"),
    ({"rotation.w": _DELETE}, "rotation.w: missing"),
    ({"decision.reason": _DELETE}, "decision.reason: missing"),
    ({"colour": "red"}, "colour: unknown field (known: format, format_version"),
    ({"rotation.v": 0.0}, "rotation.v: unknown field (known: x, y, z, w)"),
    ({"format": "something_else"}, "format: must be 'rbc_registration_calibration' (not a "
                                   "calibration file?), got 'something_else'"),
    ({"format": _DELETE}, "format: must be 'rbc_registration_calibration' (not a calibration "
                          "file?), missing"),
    ({"format_version": 4}, "format_version: 4 is not supported (this reader knows versions 1, "
                            "2, 3)"),
    ({"units": "mm"}, "units: must be 'm' (all lengths are metres), got 'mm'"),
    ({"parent_frame": 12}, "parent_frame: must be a string, got 12"),
    ({"translation.x": "abc"}, "translation.x: must be a number, got 'abc'"),
    ({"translation": [1, 2, 3]}, "translation: must be a mapping with keys x, y, z, got [1, 2, 3]"),
    ({"fre_rms": True}, "fre_rms: must be a number, got True"),
    ({"n_fiducials": 4.5}, "n_fiducials: must be an integer, got 4.5"),
    ({"decision.apply": "yes"}, "decision.apply: must be true or false, got 'yes'"),
    ({"sigma_L": 0.001}, "sigma_L: must be a list, got 0.001"),
    ({"translation.y": float("nan")}, "translation.y: must be finite, got nan"),
    ({"translation.x": 1e300}, "translation.x: must be within ±1e+12 m (as any coordinate), got "
                               "1e+300"),
    ({"fre_rms": 1e13}, "fre_rms: must be within ±1e+12 m"),
    # PyYAML reads 5e-05 (no point) and 1.5e5 (no exponent sign) as text
    ({"fre_rms": "5e-05"}, "fre_rms: must be a number, got '5e-05' (YAML 1.1 reads it as text: "
                           "its floats need a decimal point and a signed exponent"),
    ({"fre_rms": float("inf")}, "fre_rms: must be finite, got inf"),
    ({"sigma_L": [1e-3, float("-inf")]}, "sigma_L[1]: must be finite, got -inf"),
    ({"expected_tre_rigid": -1e-4}, "expected_tre_rigid: must be >= 0 (a length in metres), got "
                                    "-0.0001"),
    ({"expected_tre_with_corrections": -1e-4}, "expected_tre_with_corrections: must be >= 0 (a "
                                               "length in metres), got -0.0001"),
    ({"rotation.w": 2.0}, "rotation: not a unit quaternion: its norm is"),
    ({"parent_frame": ""}, "parent_frame: must not be empty"),
    ({"child_frame": "world"}, "child_frame: must differ from parent_frame, both are 'world'"),
    ({"child_frame": "/tracker"}, "child_frame: must not start with '/' (tf2 refuses it), "
                                  "got '/tracker'"),
    ({"parent_frame": "robot base"}, "parent_frame: must not contain whitespace or control "
                                     "characters, got 'robot base'"),
    ({"dimension": 4}, "dimension: must be 2 or 3, got 4"),
    ({"registration": "best"}, "registration: must be one of corrected, uncorrected, got 'best'"),
    ({"decision.method": "spline"}, "decision.method: must be one of uncorrected, paper, kriging, "
                                    "got 'spline'"),
    ({"decision.method": "uncorrected"}, "decision.apply: true needs a correcting method (one of "
                                         "paper, kriging), got method 'uncorrected'"),
    ({"decision.mode": ""}, "decision.mode: must not be empty"),
    ({"sigma_axis": None}, "sigma_axis: must be null exactly when sigma is null"),
    ({"sigma_axis": 1e-5}, "sigma_axis: must be sigma / sqrt(dimension) = "),
    ({"n_fiducials": 2}, "n_fiducials: must be at least 3, got 2"),
    ({"created": "yesterday"}, "created: not an ISO 8601 time, got 'yesterday'"),
    ({"created": "2025-06-01T12:00:00+02:00"}, "created: must be in UTC (ending in Z or +00:00)"),
    ({"created": "2025-06-01T12:00:00"}, "created: must be in UTC (ending in Z or +00:00)"),
    ({"package_version": 1.0}, "package_version: must be a string, got 1.0"),
    ({"translation.x": 10 ** 400}, "translation.x: out of range, got an integer of 401 digits"),
    ({"fre_rms": 10 ** 400}, "fre_rms: out of range, got an integer of 401 digits"),
]


@pytest.mark.parametrize("changes, message", RULES, ids=[m.split(":")[0] + f"-{k}"
                                                          for k, (_, m) in enumerate(RULES)])
def test_each_validation_rule_names_the_file_and_the_field(tmp_path, changes, message):
    path, read = _read_mutated(tmp_path, changes)
    with pytest.raises(ValueError) as info:
        read()
    text = str(info.value)
    assert text.startswith(f"{path}: {message}"), text
    assert "\n" not in text


def test_2d_calibration_must_be_planar(tmp_path):
    base = make([[0.0, -1.0], [1.0, 0.0]], [0.5, 0.125])
    for dotted, message in (("rotation.x", "rotation.x: a 2D calibration is a rotation about z"),
                            ("translation.z", "translation.z: a 2D calibration is a rotation")):
        path, read = _read_mutated(tmp_path, {dotted: 1e-3, "rotation.w": 0.7071063}, base)
        with pytest.raises(ValueError, match=re.escape(f"{path}: {message}")):
            read()


def test_quaternion_within_tolerance_is_normalised(tmp_path):
    cal = make()
    q = np.array(cal.rotation) * (1.0 + 5e-7)  # |q| - 1 = 5e-7 <= 1e-6: accepted, normalised
    _, read = _read_mutated(tmp_path, dict(zip(("rotation.x", "rotation.y", "rotation.z",
                                                "rotation.w"), map(float, q))))
    got = read().rotation
    assert abs(np.linalg.norm(got) - 1.0) < 1e-15
    np.testing.assert_allclose(got, cal.rotation, atol=1e-15)
    q = np.array(cal.rotation) * (1.0 + 2e-6)  # beyond the tolerance: refused
    path, read = _read_mutated(tmp_path, dict(zip(("rotation.x", "rotation.y", "rotation.z",
                                                   "rotation.w"), map(float, q))))
    with pytest.raises(ValueError, match=re.escape(f"{path}: rotation: not a unit quaternion")):
        read()


def test_yaml_timestamp_is_accepted(tmp_path):
    path = tmp_path / "cal.yaml"
    write_calibration(str(path), make())
    text = path.read_text().replace("'2023-11-14T22:13:20.000000Z'", "2023-11-14T22:13:20.000000Z")
    assert "created: 2023-11-14T22:13:20.000000Z\n" in text  # unquoted: a YAML timestamp
    path.write_text(text)
    assert read_calibration(str(path)) == make()


@pytest.mark.parametrize("written, read_as", [("1:20", "80"), ("012", "10"), ("0x1f", "31"),
                                             ("1_000", "1000"), ("0:00:01.5", "1.5")])
def test_numbers_yaml_reads_otherwise_than_they_look_are_refused(tmp_path, written, read_as):
    """YAML 1.1 reads 1:20 as 80 (sexagesimal) and 012 as 10 (octal): a hand-edited
    translation would load another value silently."""
    path = tmp_path / "cal.yaml"
    write_calibration(str(path), make())
    text = path.read_text()
    line = next(x for x in text.splitlines() if x.lstrip().startswith("fre_rms:"))
    path.write_text(text.replace(line, line.split(":")[0] + f": {written}"))
    with pytest.raises(ValueError, match=re.escape(f"the number '{written}' is not plain decimal "
                                                   f"(YAML 1.1 reads it as {read_as}")):
        read_calibration(str(path))
    path.write_text(text)
    assert read_calibration(str(path)) == make()        # what the writer writes is plain


@pytest.mark.parametrize("content, message", [
    (b"- 1\n- 2\n", "the document must be a mapping of the fields of docs/CALIBRATION.md, got "
                    "[1, 2]"),
    (b"format: [unclosed\n", "not valid YAML at line 2, column 1"),
    (b"format: \xff\xfe\n", "not UTF-8 text (byte 8)"),
    (b"", "empty (no YAML document): not a calibration file"),
    (b"# only a comment\n", "empty (no YAML document): not a calibration file"),
    # a bare Python error naming neither file nor field, and an unclear one
    (b"n_fiducials: " + b"9" * 5000 + b"\n",
     "not valid YAML at line 1, column 14: a number of 5000 characters (at most 4000)"),
    (b"base: &b {x: 1.0, y: 2.0, z: 3.0}\ntranslation: {<<: *b}\n",
     "not valid YAML at line 2, column 15: a merge key (<<) is not read here: write the fields "
     "out"),
    (b"fre_rms: 0.1\nsigma: null\nfre_rms: 0.2\n",             # last-wins before
     "not valid YAML at line 3, column 1: found the key 'fre_rms' twice"),
])
def test_file_content_that_is_no_calibration(tmp_path, content, message):
    path = tmp_path / "cal.yaml"
    path.write_bytes(content)
    with pytest.raises(ValueError) as info:
        read_calibration(str(path))
    assert str(info.value).startswith(f"{path}: "), str(info.value)
    assert message in str(info.value)


def test_file_over_the_size_bound(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_bytes(b"#" * (MAX_FILE_BYTES + 1))
    with pytest.raises(ValueError, match=re.escape(f"{path}: larger than {MAX_FILE_BYTES} bytes")):
        read_calibration(str(path))


def test_not_a_regular_file(tmp_path):
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path}: not a regular file")):
        read_calibration(str(tmp_path))  # a directory
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # opening it must neither block nor read
    with pytest.raises(ValueError, match=re.escape(f"{fifo}: not a regular file")):
        read_calibration(str(fifo))
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path}/missing.yaml: cannot be read: "
                                                   "No such file or directory")):
        read_calibration(str(tmp_path / "missing.yaml"))


# --- static_transform_publisher ----------------------------------------------------------------

def test_exact_static_transform_publisher_line():
    cal = make(np.diag([-1.0, -1.0, 1.0]), (1.5, -0.25, 2.0))  # 180 degrees about z
    assert static_transform_publisher_command(cal) == (
        "ros2 run tf2_ros static_transform_publisher --x 1.5 --y -0.25 --z 2.0 --qx 0.0 "
        "--qy 0.0 --qz 1.0 --qw 0.0 --frame-id world --child-frame-id tracker")


def test_exact_static_transform_publisher_line_2d():
    cal = make([[0.0, -1.0], [1.0, 0.0]], (0.5, 1e-5), child_frame="plate")  # 90 degrees
    assert static_transform_publisher_args(cal) == [
        "--x", "0.5", "--y", "1e-05", "--z", "0.0", "--qx", "0.0", "--qy", "0.0",
        "--qz", "0.7071067811865476", "--qw", "0.7071067811865476",
        "--frame-id", "world", "--child-frame-id", "plate"]


def test_command_quotes_frames_for_the_shell_and_keeps_full_precision():
    cal = make(child_frame="tool#1")
    command = static_transform_publisher_command(cal)
    assert "--child-frame-id 'tool#1'" in command
    args = shlex.split(command)[4:]
    assert args == static_transform_publisher_args(cal)
    values = dict(zip(args[0::2], args[1::2]))
    assert tuple(float(values[f]) for f in ("--x", "--y", "--z")) == cal.translation
    assert tuple(float(values[f]) for f in ("--qx", "--qy", "--qz", "--qw")) == cal.rotation


def test_launch_snippet_is_python_with_the_same_arguments():
    cal = make()
    tree = ast.parse(launch_snippet(cal))
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and n.func.id == "Node"]
    assert len(calls) == 1
    keywords = {k.arg: ast.literal_eval(k.value) for k in calls[0].keywords}
    assert keywords == {"package": "tf2_ros", "executable": "static_transform_publisher",
                        "arguments": static_transform_publisher_args(cal)}


def test_the_file_carries_the_command_as_a_comment(tmp_path):
    cal = make()
    path = tmp_path / "cal.yaml"
    write_calibration(str(path), cal)
    assert f"# {static_transform_publisher_command(cal)}\n" in path.read_text()


def test_direct_construction_is_validated_too():
    cal = make()
    with pytest.raises(ValueError, match="child_frame: must differ from parent_frame"):
        dataclasses.replace(cal, child_frame="world")
    with pytest.raises(ValueError, match="decision.apply: must be true or false, got 1"):
        Decision("auto", "paper", 1, "")
    assert isinstance(dataclasses.replace(cal, sigma=None, sigma_axis=None), Calibration)


def test_yaml_alias_bomb_gives_a_short_message(tmp_path):
    doc = _document()
    doc["sigma_L"] = "BOMB"
    text = yaml.safe_dump(doc, sort_keys=False)
    assert "sigma_L: BOMB\n" in text
    levels = ["a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for prev, name in zip("abcdefgh", "bcdefghi"):
        levels.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    path = tmp_path / "cal.yaml"
    # 9**9 leaves if expanded; first as extra top-level keys, then inside sigma_L only
    path.write_text("\n".join(levels) + "\n" + text.replace("sigma_L: BOMB", "sigma_L: *i"))
    with pytest.raises(ValueError) as info:
        read_calibration(str(path))
    assert str(info.value).startswith(f"{path}: a: unknown field")
    nested = "sigma_L: " + " ".join(f"&{name} [" for name in "abcdefghi") + "1" + "]" * 9
    path.write_text(text.replace("sigma_L: BOMB", nested))
    with pytest.raises(ValueError) as info:
        read_calibration(str(path))
    assert str(info.value).startswith(f"{path}: sigma_L[0]: must be a number, got [[")
    assert len(str(info.value)) < len(str(path)) + 100


def test_the_example_in_docs_is_a_valid_file_written_by_this_module(tmp_path):
    docs = os.path.join(os.path.dirname(__file__), "..", "..", "docs", "CALIBRATION.md")
    with open(docs, encoding="utf-8") as f:
        example = f.read().split("```yaml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "example.yaml"
    write_calibration(str(path), make(np.diag([-1.0, -1.0, 1.0]), (1.5, -0.25, 2.0)))
    assert path.read_text() == example  # the documented example is exactly what is written


def test_a_version_1_file_is_read_its_expected_tre_as_the_decision_s(tmp_path):
    """Version 1 had one ``expected_tre``: the decision's method's held-out median, which needs
    the corrections; the rigid figure of its transform is unknown."""
    doc = make().to_mapping()
    doc = {**{k: v for k, v in doc.items() if not k.startswith("expected_tre")
              and k != "answers"}, "format_version": 1, "expected_tre": 8e-5}
    path = tmp_path / "v1.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    cal = read_calibration(str(path))
    assert (cal.expected_tre_rigid, cal.expected_tre_with_corrections) == (None, 8e-5)
    assert dataclasses.replace(cal, expected_tre_rigid=1.2e-3) == make()
    doc["expected_tre_rigid"] = 1e-3     # a version 2 key in a version 1 file
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(ValueError, match="expected_tre_rigid: unknown field"):
        read_calibration(str(path))


@pytest.mark.parametrize("extra, message", [
    ("? [a, b]\n: 1\n", "a key must be a name, got a list"),
    ("colour: {[1, 2]: x}\n", "a key must be a name, got a list"),
    ("? {a: 1}\n: 1\n", "a key must be a name, got a mapping"),
])
def test_a_key_that_is_a_list_or_a_mapping_is_one_line(tmp_path, extra, message):
    """such a key was a TypeError traceback (unhashable type: 'list')."""
    path = tmp_path / "cal.yaml"
    write_calibration(str(path), make())
    path.write_text(path.read_text() + extra)
    with pytest.raises(ValueError) as info:
        read_calibration(str(path))
    text = str(info.value)
    assert text.startswith(f"{path}: not valid YAML at line ") and text.endswith(message), text
    assert "\n" not in text


@pytest.mark.parametrize("field, written, message", [
    ("apply", "yes", "apply: yes is read by YAML 1.1 as true: write true or false for a "
                     "boolean, or quote a string: apply: 'yes'"),
    ("apply", "off", "apply: off is read by YAML 1.1 as false"),
    ("mode", "off", "mode: off is read by YAML 1.1 as false: write true or false for a boolean, "
                    "or quote a string: mode: 'off'"),
    ("mode", "On", "mode: On is read by YAML 1.1 as true"),
])
def test_yaml_1_1_booleans_other_than_true_and_false_are_refused(tmp_path, field, written,
                                                                  message):
    """``apply: yes`` was accepted as true (docs/CALIBRATION.md says it is refused),
    and ``mode: off`` (read as false) got no hint to quote it."""
    path = tmp_path / "cal.yaml"
    write_calibration(str(path), make(decision=Decision("on", "paper", True, "")))
    text = path.read_text()
    old = "apply: true" if field == "apply" else "mode: 'on'"   # the writer quotes 'on'
    assert old in text
    path.write_text(text.replace(old, f"{field}: {written}"))
    with pytest.raises(ValueError) as info:
        read_calibration(str(path))
    assert str(info.value).startswith(f"{path}: not valid YAML at line ") and message in str(
        info.value), info.value
    path.write_text(text.replace(old, f"{field}: 'off'" if field == "mode" else old))
    assert read_calibration(str(path)).decision.mode == ("off" if field == "mode" else "on")
