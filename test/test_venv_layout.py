"""The install layout `ros2 run` and launch_ros look executables up in: `<prefix>/lib/<package>/
<executable>`, where `<prefix>` is the first entry of AMENT_PREFIX_PATH whose
`share/ament_index/resource_index/packages/<package>` exists (ament_index_python's
get_package_prefix; launch_ros's ExecutableInPackage joins `lib/<package>` to it). A colcon
install gets it from setup.cfg; the development venv from scripts/bootstrap.sh (symlinks).
launch and launch_ros are not on PyPI, so the rule is checked here, not by a launch."""

import importlib.metadata
import os
import subprocess

import pytest

PACKAGE = "rbc_registration"


def _package_prefix(package):
    """ament_index_python's rule: the first prefix of AMENT_PREFIX_PATH that indexes ``package``."""
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        if os.path.isfile(os.path.join(prefix, "share", "ament_index", "resource_index",
                                       "packages", package)):
            return prefix
    return None


PREFIX = _package_prefix(PACKAGE)
pytestmark = pytest.mark.skipif(PREFIX is None, reason=f"{PACKAGE} is not in an ament index on "
                                "AMENT_PREFIX_PATH (not a ROS or scripts/bootstrap.sh install)")


def _libexec(executable):
    return os.path.join(PREFIX, "lib", PACKAGE, executable)


def test_the_lookup_rule_is_ament_index_pythons():
    packages = pytest.importorskip("ament_index_python.packages")
    assert packages.get_package_prefix(PACKAGE) == PREFIX


def test_every_console_script_is_where_ros2_run_looks():
    scripts = sorted(e.name for e in importlib.metadata.distribution(PACKAGE).entry_points
                     if e.group == "console_scripts")
    assert "registration_node" in scripts
    for name in scripts:
        path = _libexec(name)
        assert os.path.isfile(path) and os.access(path, os.X_OK), path
    # `ros2 run` lists the executable files of that directory
    listed = sorted(f for f in os.listdir(os.path.join(PREFIX, "lib", PACKAGE))
                    if os.access(_libexec(f), os.X_OK))
    assert set(scripts) <= set(listed)


def test_the_cli_runs_from_there():
    out = subprocess.run([_libexec("rbc-registration"), "--help"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0 and "usage" in out.stdout.lower(), out.stderr


@pytest.mark.ros
def test_registration_node_runs_from_there():
    """The node's own start-up check answers (an invalid parameter: one FATAL line, exit 1), so
    the file launch_ros would start is this package's registration_node."""
    out = subprocess.run([_libexec("registration_node"), "--ros-args", "-p", "dimension:=4"],
                         capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"))
    assert out.returncode == 1, out.stdout + out.stderr
    assert "cannot start" in out.stdout + out.stderr
