"""The state directory (rbc_registration.pipeline.state_dir): its files, and the default state_dir
per node: one directory per namespace and
name, never shared, and launch_ros's namespace rules."""

import itertools
import os

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rbc_registration.pipeline.state_dir import (STATE_ROOT, check_node_name, default_state_dir,
                                             resolve_namespace, state_dir_name)


@pytest.mark.parametrize("namespace, pushed, expected", [
    ("", None, "/"),
    ("/", None, "/"),
    ("cell_a", None, "/cell_a"),
    ("/cell_a/", None, "/cell_a"),
    ("line1/cell_a", None, "/line1/cell_a"),
    ("cell_a", "/line1", "/line1/cell_a"),      # relative: under the pushed namespace
    ("cell_a", "line1", "/line1/cell_a"),
    ("/cell_a", "/line1", "/cell_a"),          # absolute: the pushed one does not apply
    ("", "/line1", "/line1"),
])
def test_resolve_namespace_as_launch_ros(namespace, pushed, expected):
    assert resolve_namespace(namespace, pushed) == expected


@pytest.mark.parametrize("namespace, message", [
    ("cell a", "namespace 'cell a': 'cell a' is not a valid ROS name token"),
    ("1cell", "namespace '1cell': '1cell' is not a valid ROS name token"),
    ("/a//b", "namespace '/a//b': '' is not a valid ROS name token"),
    ("cell-a", "namespace 'cell-a': 'cell-a' is not a valid ROS name token"),
    ("~/x", "namespace '~/x': '~' is not a valid ROS name token"),
])
def test_invalid_namespace(namespace, message):
    with pytest.raises(ValueError, match=message):
        resolve_namespace(namespace)


@pytest.mark.parametrize("name", ["", "2d_node", "node-1", "a/b", "cell.a", "x" * 256])
def test_invalid_node_name(name):
    with pytest.raises(ValueError, match="is not valid: letters, digits and '_'"):
        check_node_name(name)


def test_default_state_dir_examples():
    assert STATE_ROOT == "~/.ros/rbc_registration"
    assert default_state_dir("", "registration_node") == \
        "~/.ros/rbc_registration/registration_node"
    assert default_state_dir("/cell_a", "registration_node") == \
        "~/.ros/rbc_registration/cell_a.registration_node"
    assert default_state_dir("cell_a", "reg", pushed="/line1") == \
        "~/.ros/rbc_registration/line1.cell_a.reg"
    assert default_state_dir("cell_b", "reg", root="/var/lib/rbc") == "/var/lib/rbc/cell_b.reg"


def test_names_that_join_alike_with_underscores_stay_apart():
    # '_' joining would map both to a_b_c; '.' cannot occur in a ROS name
    assert state_dir_name("/a_b", "c") != state_dir_name("/a", "b_c")
    assert state_dir_name("/a", "b") != state_dir_name("/", "a_b")


_token = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,6}", fullmatch=True)
_node = st.tuples(st.lists(_token, max_size=3).map(tuple), _token)


@given(st.lists(_node, min_size=2, max_size=6, unique=True))
def test_different_nodes_never_share_a_directory(nodes):
    dirs = [default_state_dir("/" + "/".join(ns), name) for ns, name in nodes]
    assert len(set(dirs)) == len(dirs)
    for d in dirs:  # one directory level under the root, a valid file name
        name = os.path.basename(d)
        assert os.path.dirname(d) == STATE_ROOT and "/" not in name and name not in ("", ".", "..")


def test_two_cells_of_a_launch_example():
    cells = [("cell_a", "registration_node"), ("cell_b", "registration_node"),
             ("", "registration_node")]
    dirs = {default_state_dir(ns, name) for ns, name in cells}
    assert len(dirs) == 3
    for (a, b) in itertools.combinations(sorted(dirs), 2):
        assert not b.startswith(a + "/")  # neither is inside the other


def test_a_state_dir_is_resolved_once_and_names_every_file(tmp_path, monkeypatch):
    from rbc_registration.pipeline.settings import Settings
    from rbc_registration.pipeline.state_dir import StateDir

    monkeypatch.setenv("HOME", str(tmp_path))
    files = StateDir.resolve("~/cell_a")
    root = str(tmp_path / "cell_a")
    assert files.root == root
    assert (files.journal, files.snapshot, files.checkpoint, files.lock, files.calibration) == (
        f"{root}/journal.jsonl", f"{root}/calibration.json", f"{root}/checkpoint.json",
        f"{root}/lock", f"{root}/calibration.yaml")
    assert files.named_calibration("line3") == f"{root}/calibrations/line3.yaml"
    assert Settings.from_mapping({"state_dir": "~/cell_a"}).state_files == files
    assert Settings.from_mapping({"state_dir": ""}).state_files is None
    with pytest.raises(ValueError, match="state_dir is empty"):
        StateDir.resolve("")


def test_the_default_is_still_importable_where_launch_files_import_it():
    from rbc_registration.io import state_paths
    from rbc_registration.pipeline import state_dir

    assert state_paths.default_state_dir is state_dir.default_state_dir
