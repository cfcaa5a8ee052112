"""Publish a saved calibration: ``ros2 launch rbc_registration publish.launch.py
calibration:=NAME_OR_PATH``.

``calibration`` (required) is a calibration file's path, or the name of one ``~/save`` wrote with
``calibration_name`` NAME (``state_dir/calibrations/NAME.yaml``); it is passed unchanged to the
node's ``calibration_file`` parameter. Everything else is registration.launch.py's defaults
(``config/registration_node.yaml``, ``state_dir:=auto``, the root namespace, node
``registration_node``): the node publishes the calibration on ``~/transform`` (or
``~/transform_uncorrected``) and ``/tf_static`` from the start, publish-only while no live model
is built (docs/BUILD.md, msg_docs/README.md "Saved calibrations")::

    ros2 launch rbc_registration publish.launch.py calibration:=line1
    ros2 launch rbc_registration publish.launch.py calibration:=/path/cell_a.yaml
"""

import os

INCLUDED = "registration.launch.py"   # beside this file, in the source tree and when installed

# (name, description), literals only (test/test_launch_file.py reads them with ast). No default:
# the argument is required.
ARGUMENTS = (
    ("calibration", "A calibration file's path, or a calibration's name "
                    "(state_dir/calibrations/NAME.yaml): the node's calibration_file"),
)


def included_arguments(values):
    """The arguments given to registration.launch.py: ``calibration`` as ``calibration_file``.

    :param values: ``calibration`` -> its value (a substitution or a string).
    """
    return {"calibration_file": values["calibration"]}


def generate_launch_description():
    # launch is imported here only (not on PyPI), as in registration.launch.py.
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
    from launch.launch_description_sources import PythonLaunchDescriptionSource
    from launch.substitutions import LaunchConfiguration

    values = {name: LaunchConfiguration(name) for name, _ in ARGUMENTS}
    return LaunchDescription(
        [DeclareLaunchArgument(name, description=description) for name, description in ARGUMENTS]
        + [IncludeLaunchDescription(
            PythonLaunchDescriptionSource(
                os.path.join(os.path.dirname(os.path.abspath(__file__)), INCLUDED)),
            launch_arguments=list(included_arguments(values).items()))])
