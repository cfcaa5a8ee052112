"""Start one registration_node (one cell): ``ros2 launch rbc_registration registration.launch.py``.

Arguments (``name:=value``; ``ros2 launch ... --show-args`` lists them): see ARGUMENTS below and
docs/BUILD.md. Each node gets its own ``state_dir`` by default,
``$ROS_HOME/rbc_registration/<namespace tokens>.<node_name>`` (``ROS_HOME`` default ``~/.ros``)
(:func:`rbc_registration.pipeline.state_dir.default_state_dir`), so two cells never share a
journal::

    ros2 launch rbc_registration registration.launch.py namespace:=cell_a
    ros2 launch rbc_registration registration.launch.py namespace:=cell_b dimension:=2
    ros2 launch rbc_registration registration.launch.py calibration_file:=/path/cell_a.yaml

``publish.launch.py`` is this file with ``calibration_file`` only (``calibration:=NAME_OR_PATH``).

Parameters: ``params_file`` first, then the arguments given here (an empty argument leaves the
file's value; ``state_dir`` is always set here: ``auto`` by default, ``''`` for no
persistence). The functions above ``generate_launch_description`` are plain Python (tested
without ROS by test/test_launch_file.py).
"""

from typing import Mapping, Optional

from rbc_registration.pipeline.state_dir import default_state_dir, resolve_namespace, state_root

PACKAGE = "rbc_registration"
EXECUTABLE = "registration_node"
AUTO = "auto"  # state_dir:=auto (the default): derived from the namespace and the node name

# (name, default, description), literals only (test/test_launch_file.py reads them with ast).
# A default of '' means "not set here: params_file decides".
ARGUMENTS = (
    ("namespace", "", "Namespace of the node, e.g. cell_a (relative ones go under an enclosing "
                      "PushRosNamespace); empty: the root namespace"),
    ("node_name", "registration_node", "Name of the node"),
    ("working_frame", "", "working_frame parameter (frame of the tracker's points); empty: "
                          "from params_file (config default: tracker)"),
    ("destination_frame", "", "destination_frame parameter (robot base or world); empty: from "
                              "params_file (config default: world)"),
    ("dimension", "", "dimension parameter, 2 or 3; empty: from params_file (config default: 3)"),
    ("state_dir", "auto", "Journal and snapshot directory (set here, it overrides params_file's "
                        "state_dir). 'auto': $ROS_HOME/rbc_registration/<namespace "
                        "tokens>.<node_name> (ROS_HOME default ~/.ros), one per node, as the "
                        "node derives it itself; '' (empty): no persistence; otherwise that "
                        "directory"),
    ("calibration_file", "", "calibration_file parameter: a calibration file's path, or a "
                             "calibration's name (state_dir/calibrations/NAME.yaml), loaded at "
                             "start and published until a live model is built; empty: from "
                             "params_file (config default: none)"),
    ("params_file", "<share>/config/registration_node.yaml",
     "YAML parameter file of registration_node (default: the package's "
     "config/registration_node.yaml)"),
    ("use_sim_time", "", "true: the node clock follows /clock; false: system time; empty: from "
                         "params_file (config default: false)"),
)
_BOOLEANS = {"true": True, "false": False}


def node_parameters(values: Mapping[str, str], pushed_namespace: Optional[str] = None,
                    environ: Optional[Mapping[str, str]] = None) -> tuple[str, dict]:
    """The node's absolute namespace and the parameters the arguments set (on top of
    params_file), from the arguments' string values.

    :param values: every name of :data:`ARGUMENTS` -> its value (launch configurations).
    :param pushed_namespace: the namespace of an enclosing ``PushRosNamespace``, if any.
    :param environ: the environment the node will get (launch's ``context.environment``, which
        ``SetEnvironmentVariable`` changes; default ``os.environ``): its ``ROS_HOME``.
    :return: ``(namespace, overrides)``; ``overrides`` holds only what is set here.
    :raises ValueError: naming the argument, for a bad namespace, node name, dimension or
        use_sim_time.

    ``calibration_file`` is passed on as given: the node resolves a name and validates the file.
    """
    namespace = resolve_namespace(values["namespace"], pushed_namespace)
    name = values["node_name"]
    overrides: dict = {}
    for as_given in ("working_frame", "destination_frame", "calibration_file"):
        if values[as_given]:
            overrides[as_given] = values[as_given]
    if values["dimension"]:
        if values["dimension"] not in ("2", "3"):
            raise ValueError(f"dimension:={values['dimension']!r}: must be 2 or 3 (or empty)")
        overrides["dimension"] = int(values["dimension"])
    if values["use_sim_time"]:
        flag = values["use_sim_time"].strip().lower()
        if flag not in _BOOLEANS:
            raise ValueError(f"use_sim_time:={values['use_sim_time']!r}: must be true or false "
                             "(or empty)")
        overrides["use_sim_time"] = _BOOLEANS[flag]
    state_dir = values["state_dir"]
    overrides["state_dir"] = (default_state_dir(namespace, name, root=state_root(environ))
                              if state_dir == AUTO else state_dir)
    return namespace, overrides


def _launch_setup(context, *args, **kwargs):
    """OpaqueFunction: the Node, once the arguments' values are known."""
    from launch.actions import LogInfo
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node

    values = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    namespace, overrides = node_parameters(
        values, context.launch_configurations.get("ros_namespace"),
        getattr(context, "environment", None))
    where = overrides["state_dir"] or "(none: no persistence)"
    return [
        LogInfo(msg=f"{namespace.rstrip('/')}/{values['node_name']}: state_dir {where}"),
        Node(
            package=PACKAGE,
            executable=EXECUTABLE,
            namespace=namespace,
            name=values["node_name"],
            parameters=[values["params_file"], overrides],
            output="screen",
            emulate_tty=True,
        ),
    ]


def generate_launch_description():
    # launch and launch_ros are imported here only, so that importing or packaging
    # rbc_registration never needs them (they are not on PyPI).
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.substitutions import PathJoinSubstitution
    from launch_ros.substitutions import FindPackageShare

    defaults = {name: default for name, default, _ in ARGUMENTS}
    defaults["params_file"] = PathJoinSubstitution(
        [FindPackageShare(PACKAGE), "config", "registration_node.yaml"])
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=defaults[name], description=description)
         for name, _, description in ARGUMENTS]
        + [OpaqueFunction(function=_launch_setup)])
