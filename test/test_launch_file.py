"""launch/registration.launch.py and launch/publish.launch.py.

`launch` / `launch_ros` are not on PyPI, so in the development venv the real launch test is
skipped. What always runs: the file's declared arguments and defaults (read from the file with
`ast` and compared with docs/BUILD.md), its plain-Python part (`node_parameters`), and
`generate_launch_description` plus its OpaqueFunction executed against small recording stand-ins
for the launch classes, so every line of the file runs and the Node it creates is checked.
"""

import ast
import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import types

import pytest

from rbc_registration.pipeline.state_dir import default_state_dir

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAUNCH_FILE = os.path.join(REPO, "launch", "registration.launch.py")
PUBLISH_FILE = os.path.join(REPO, "launch", "publish.launch.py")
EXPECTED_ARGUMENTS = ["namespace", "node_name", "working_frame", "destination_frame", "dimension",
                      "state_dir", "calibration_file", "params_file", "use_sim_time"]


def _load_launch_module(path=LAUNCH_FILE):
    spec = importlib.util.spec_from_file_location(
        os.path.basename(path).replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _arguments_from_ast(path=LAUNCH_FILE):
    """ARGUMENTS of a launch file, read without running it."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    for node in tree.body:
        if isinstance(node, ast.Assign) and [t.id for t in node.targets] == ["ARGUMENTS"]:
            return ast.literal_eval(node.value)
    raise AssertionError("no ARGUMENTS tuple in the launch file")


def test_declared_arguments_and_defaults():
    arguments = _arguments_from_ast()
    assert [a[0] for a in arguments] == EXPECTED_ARGUMENTS
    defaults = {name: default for name, default, _ in arguments}
    assert defaults["namespace"] == "" and defaults["node_name"] == "registration_node"
    assert defaults["state_dir"] == "auto" == _load_launch_module().AUTO
    for name in ("working_frame", "destination_frame", "dimension", "calibration_file",
                 "use_sim_time"):
        assert defaults[name] == "", name  # empty: params_file decides
    assert all(description for _, _, description in arguments)


def _launch_arguments_section():
    with open(os.path.join(REPO, "docs", "BUILD.md"), encoding="utf-8") as f:
        text = f.read()
    return re.split(r"\n#{2,3} ", text.split("### Launch arguments\n", 1)[1], maxsplit=1)[0]


def test_build_md_documents_every_argument_with_its_default():
    section = _launch_arguments_section().split("#### publish.launch.py", 1)[0]
    rows = [r for r in section.splitlines() if r.startswith("| `")]
    documented = {}
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        default = cells[1].strip("`")
        documented[cells[0].strip("`")] = "" if default == '""' else default
    assert documented == {name: default for name, default, _ in _arguments_from_ast()}


# --- the plain-Python part ---------------------------------------------------------------------

@pytest.fixture(autouse=True)
def _no_ros_home(monkeypatch):
    """The derived paths below are those of a user without ROS_HOME (the suite sets one)."""
    monkeypatch.delenv("ROS_HOME", raising=False)


def _values(**changes):
    module = _load_launch_module()
    values = {name: default for name, default, _ in module.ARGUMENTS}
    values["params_file"] = "/opt/cfg/registration_node.yaml"
    values.update(changes)
    return module, values


def test_defaults_set_only_the_derived_state_dir():
    module, values = _values()
    assert module.node_parameters(values) == (
        "/", {"state_dir": "~/.ros/rbc_registration/registration_node"})


def test_auto_state_dir_follows_ros_home_as_the_node_does(monkeypatch):
    """the launch file put the state under ~/.ros even with ROS_HOME set, while the
    node's own ``auto`` uses $ROS_HOME (rcl's rule)."""
    module, values = _values(namespace="cell_a")
    monkeypatch.setenv("ROS_HOME", "/data/ros")
    assert module.node_parameters(values)[1]["state_dir"] == \
        "/data/ros/rbc_registration/cell_a.registration_node"
    monkeypatch.delenv("ROS_HOME")
    assert module.node_parameters(values)[1]["state_dir"] == \
        "~/.ros/rbc_registration/cell_a.registration_node"
    # the environment the node gets (launch's SetEnvironmentVariable changes that one)
    assert module.node_parameters(values, None, {"ROS_HOME": "/srv/ros"})[1]["state_dir"] == \
        "/srv/ros/rbc_registration/cell_a.registration_node"


def test_two_cells_get_their_own_state_dirs():
    module, a = _values(namespace="cell_a")
    _, b = _values(namespace="cell_b")
    (ns_a, pa), (ns_b, pb) = module.node_parameters(a), module.node_parameters(b)
    assert (ns_a, ns_b) == ("/cell_a", "/cell_b")
    assert pa["state_dir"] == default_state_dir("/cell_a", "registration_node")
    assert pb["state_dir"] == default_state_dir("/cell_b", "registration_node")
    assert pa["state_dir"] != pb["state_dir"]


def test_pushed_namespace_applies_to_the_node_and_its_state_dir():
    module, values = _values(namespace="cell_a", node_name="reg")
    assert module.node_parameters(values, "/line1") == (
        "/line1/cell_a", {"state_dir": "~/.ros/rbc_registration/line1.cell_a.reg"})


def test_arguments_override_params_file_values():
    module, values = _values(working_frame="laser_tracker", destination_frame="base_link",
                             dimension="2", use_sim_time="True", state_dir="/var/lib/rbc/a",
                             calibration_file="/var/lib/rbc/a/cell_a.yaml")
    assert module.node_parameters(values)[1] == {
        "working_frame": "laser_tracker", "destination_frame": "base_link", "dimension": 2,
        "use_sim_time": True, "state_dir": "/var/lib/rbc/a",
        "calibration_file": "/var/lib/rbc/a/cell_a.yaml"}
    # a calibration's name is passed on as given: the node resolves it in its state_dir
    module, values = _values(calibration_file="line1")
    assert module.node_parameters(values)[1] == {
        "calibration_file": "line1", "state_dir": "~/.ros/rbc_registration/registration_node"}
    module, values = _values(state_dir="", use_sim_time="false")
    assert module.node_parameters(values)[1] == {"state_dir": "", "use_sim_time": False}


@pytest.mark.parametrize("changes, message", [
    ({"dimension": "4"}, "dimension:='4': must be 2 or 3"),
    ({"use_sim_time": "yes"}, "use_sim_time:='yes': must be true or false"),
    ({"namespace": "cell a"}, "namespace 'cell a': 'cell a' is not a valid ROS name token"),
    ({"node_name": "node-1"}, "node name 'node-1' is not valid"),
])
def test_bad_arguments_are_refused_with_the_reason(changes, message):
    module, values = _values(**changes)
    with pytest.raises(ValueError, match=re.escape(message)):
        module.node_parameters(values)


# --- generate_launch_description against recording stand-ins ----------------------------------

class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _LaunchConfiguration(_Recorded):
    def perform(self, context):
        return context.launch_configurations[self.args[0]]


def _stand_in_modules():
    names = {"launch": {"LaunchDescription": _Recorded},
             "launch.actions": {n: type(n, (_Recorded,), {})
                                for n in ("DeclareLaunchArgument", "OpaqueFunction", "LogInfo",
                                          "IncludeLaunchDescription")},
             "launch.launch_description_sources": {"PythonLaunchDescriptionSource": _Recorded},
             "launch.substitutions": {"PathJoinSubstitution": _Recorded,
                                      "LaunchConfiguration": _LaunchConfiguration},
             "launch_ros": {}, "launch_ros.actions": {"Node": type("Node", (_Recorded,), {})},
             "launch_ros.substitutions": {"FindPackageShare": _Recorded}}
    modules = {}
    for name, attrs in names.items():
        modules[name] = types.ModuleType(name)
        modules[name].__dict__.update(attrs)
    return modules


def test_generate_launch_description_declares_every_argument_then_builds_the_node(monkeypatch):
    for name, module in _stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    module = _load_launch_module()
    description = module.generate_launch_description()
    entities = description.args[0]
    declared = [e for e in entities if type(e).__name__ == "DeclareLaunchArgument"]
    assert [d.args[0] for d in declared] == EXPECTED_ARGUMENTS
    defaults = {d.args[0]: d.kwargs["default_value"] for d in declared}
    share = defaults.pop("params_file")
    assert share.args[0][0].args == ("rbc_registration",) and share.args[0][1:] == [
        "config", "registration_node.yaml"]
    assert defaults == {n: d for n, d, _ in module.ARGUMENTS if n != "params_file"}
    assert all(d.kwargs["description"] for d in declared)
    (opaque,) = [e for e in entities if type(e).__name__ == "OpaqueFunction"]
    assert entities[-1] is opaque  # after the declarations: their values are set when it runs

    configurations = {n: d for n, d, _ in module.ARGUMENTS}
    configurations.update(params_file="/opt/cfg/p.yaml", namespace="cell_b", dimension="2",
                          ros_namespace="/line1")
    context = types.SimpleNamespace(launch_configurations=configurations)
    log, node = opaque.kwargs["function"](context)
    assert node.kwargs == {
        "package": "rbc_registration", "executable": "registration_node",
        "namespace": "/line1/cell_b", "name": "registration_node",
        "parameters": ["/opt/cfg/p.yaml", {
            "dimension": 2,
            "state_dir": default_state_dir("cell_b", "registration_node", pushed="/line1")}],
        "output": "screen", "emulate_tty": True}
    assert log.kwargs["msg"] == ("/line1/cell_b/registration_node: state_dir "
                                 "~/.ros/rbc_registration/line1.cell_b.registration_node")


# --- publish.launch.py ---------------------------------------------------------------------------

def test_publish_launch_takes_only_a_required_calibration():
    assert [a[0] for a in _arguments_from_ast(PUBLISH_FILE)] == ["calibration"]
    assert all(len(a) == 2 and a[1] for a in _arguments_from_ast(PUBLISH_FILE))  # no default
    module = _load_launch_module(PUBLISH_FILE)
    assert module.included_arguments({"calibration": "line1"}) == {"calibration_file": "line1"}
    assert "calibration_file" in [a[0] for a in _arguments_from_ast()]


def test_publish_launch_includes_registration_launch_with_calibration_file(monkeypatch):
    for name, module in _stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    module = _load_launch_module(PUBLISH_FILE)
    entities = module.generate_launch_description().args[0]
    (declared,) = [e for e in entities if type(e).__name__ == "DeclareLaunchArgument"]
    assert declared.args == ("calibration",) and "default_value" not in declared.kwargs
    assert declared.kwargs["description"]
    (include,) = [e for e in entities if type(e).__name__ == "IncludeLaunchDescription"]
    assert entities[-1] is include
    (source,) = include.args
    assert os.path.samefile(source.args[0], LAUNCH_FILE)
    ((argument, value),) = include.kwargs["launch_arguments"]
    assert argument == "calibration_file" and value.args == ("calibration",)
    # what registration.launch.py then gives the node: the value as given
    configurations = {n: d for n, d, _ in _load_launch_module().ARGUMENTS}
    configurations.update(params_file="/opt/cfg/p.yaml", calibration_file="line1")
    context = types.SimpleNamespace(launch_configurations=configurations)
    (opaque,) = [e for e in _load_launch_module().generate_launch_description().args[0]
                 if type(e).__name__ == "OpaqueFunction"]
    _, node = opaque.kwargs["function"](context)
    assert node.kwargs["parameters"][1] == {
        "calibration_file": "line1", "state_dir": default_state_dir("/", "registration_node")}


def test_publish_launch_is_installed_beside_registration_launch():
    """setup.py's data_files install every launch/*.py into share/rbc_registration/launch,
    where publish.launch.py finds registration.launch.py."""
    with open(os.path.join(REPO, "setup.py"), encoding="utf-8") as f:
        assert "('share/' + package_name + '/launch', glob('launch/*.py'))" in f.read()
    from glob import glob
    assert {PUBLISH_FILE, LAUNCH_FILE} <= set(glob(os.path.join(REPO, "launch", "*.py")))
    packages = pytest.importorskip("ament_index_python.packages")
    try:
        share = packages.get_package_share_directory("rbc_registration")
    except (LookupError, ValueError) as exc:  # not installed in an ament index (a plain venv)
        pytest.skip(f"rbc_registration not in an ament index: {exc}")
    for name in ("publish.launch.py", "registration.launch.py"):
        assert os.path.isfile(os.path.join(share, "launch", name)), share


def test_build_md_documents_publish_launch():
    section = _launch_arguments_section().split("#### publish.launch.py", 1)[1]
    assert "calibration:=" in section and "calibration_file" in section


# --- the real thing, where ROS 2 launch is installed -------------------------------------------

def _launch_available():
    try:
        import launch
        import launch_ros  # noqa: F401
    except ImportError as exc:
        return f"launch/launch_ros not importable ({exc}); they are not on PyPI"
    if not hasattr(launch, "LaunchDescription"):  # the repository's launch/ folder, not ROS's
        return "launch is not ROS 2 launch (only this repository's launch/ folder)"
    if shutil.which("ros2") is None:
        return "no ros2 command on PATH"
    return ""


@pytest.mark.ros
@pytest.mark.skipif(bool(_launch_available()), reason=_launch_available() or "available")
def test_real_launch_two_cells_get_their_own_state_dirs(tmp_path, ros_context):
    """`ros2 launch` of this file twice, in two namespaces, with HOME in tmp_path: each node
    reports its own derived state_dir and creates it."""
    import rclpy
    from rcl_interfaces.srv import GetParameters

    env = dict(os.environ, HOME=str(tmp_path), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    procs = [subprocess.Popen(["ros2", "launch", LAUNCH_FILE, f"namespace:={ns}"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT,
                              start_new_session=True) for ns in ("cell_a", "cell_b")]
    node = rclpy.create_node("launch_test_client", context=ros_context)
    try:
        for ns in ("cell_a", "cell_b"):
            client = node.create_client(GetParameters, f"/{ns}/registration_node/get_parameters")
            assert client.wait_for_service(timeout_sec=60.0), f"/{ns}/registration_node"
            future = client.call_async(GetParameters.Request(names=["state_dir"]))
            end = time.monotonic() + 30.0
            while not future.done() and time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.1)
            assert future.done()
            state_dir = future.result().values[0].string_value
            assert state_dir == default_state_dir(ns, "registration_node")
            expanded = os.path.expanduser(state_dir.replace("~", str(tmp_path), 1))
            end = time.monotonic() + 30.0
            while not os.path.isdir(expanded) and time.monotonic() < end:
                time.sleep(0.1)
            assert os.path.isdir(expanded), expanded
    finally:
        node.destroy_node()
        for proc in procs:
            os.killpg(proc.pid, signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
