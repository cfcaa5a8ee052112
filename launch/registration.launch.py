"""Start registration_node with config/registration_node.yaml (override: ``params_file:=...``)."""

import os


def generate_launch_description():
    # launch, launch_ros and ament_index are imported here only, so that importing or packaging
    # rbc_registration never needs them (they are not on PyPI).
    from ament_index_python.packages import get_package_share_directory
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node

    default_params = os.path.join(
        get_package_share_directory('rbc_registration'), 'config', 'registration_node.yaml')
    params_file = LaunchConfiguration('params_file')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='YAML file with the parameters of registration_node'),
        Node(
            package='rbc_registration',
            executable='registration_node',
            name='registration_node',
            parameters=[params_file],
            output='screen',
            emulate_tty=True,
        ),
    ])
