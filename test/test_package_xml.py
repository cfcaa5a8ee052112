"""package.xml: valid, its rosdep keys are the ones docs/BUILD.md lists, and crawling (catkin_pkg,
as rosdep does) sees the two packages of this repository and never vendor/tf2_msgs."""

import os
import re

import pytest

# catkin_pkg is a ROS build tool: not in the Ubuntu 24.04 venv of .ci/run (no ROS packages).
pytest.importorskip("catkin_pkg", reason="catkin_pkg (ROS build tooling) is not installed")

from catkin_pkg.package import parse_package  # noqa: E402
from catkin_pkg.packages import find_packages  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _keys(package):
    kinds = ("build_depends", "buildtool_depends", "exec_depends", "test_depends",
             "build_export_depends")
    return {d.name for kind in kinds for d in getattr(package, kind)}


def test_package_xml_is_valid_and_declares_the_python_tf2_module():
    package = parse_package(os.path.join(REPO, "package.xml"))
    package.validate()
    keys = _keys(package)
    assert {"tf2_ros_py", "tf2_msgs", "builtin_interfaces", "rcl_interfaces",
            "python3-rosbags-pip", "python3-yaml"} <= keys
    assert "tf2_ros" not in keys  # the C++ package: it does not install the Python module
    assert {d.name for d in package.test_depends} == {"python3-pytest", "python3-hypothesis"}


def test_build_md_lists_every_key():
    with open(os.path.join(REPO, "docs", "BUILD.md"), encoding="utf-8") as f:
        text = f.read()
    section = re.split(r"\n##+ ", text.split("### rosdep keys\n", 1)[1], maxsplit=1)[0]
    documented = set()
    for row in section.splitlines():
        if row.startswith("| `"):
            documented |= set(re.findall(r"`([^`]+)`", row.split("|")[1]))
    assert documented == _keys(parse_package(os.path.join(REPO, "package.xml")))


def test_crawling_finds_both_packages_and_never_the_vendored_one():
    names = {p.name for p in find_packages(REPO).values()}
    assert names == {"rbc_registration"}  # crawling stops at the root package.xml
    nested = {p.name for p in find_packages(os.path.join(REPO, "msg_docs")).values()}
    assert nested == {"rbc_registration_interfaces"}
    assert find_packages(os.path.join(REPO, "vendor")) == {}  # vendor/COLCON_IGNORE


def test_vendored_tf2_msgs_is_a_valid_interface_package():
    package = parse_package(os.path.join(REPO, "vendor", "tf2_msgs", "package.xml"))
    package.validate()
    assert package.name == "tf2_msgs"
    assert "rosidl_interface_packages" in {g.name for g in package.member_of_groups}
    assert {"action_msgs", "builtin_interfaces", "geometry_msgs"} <= _keys(package)
