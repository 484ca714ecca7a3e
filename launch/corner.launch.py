"""Launch one corner: plant, controller, actuator and recorder in the corner's namespace.

``ros2 launch mr_suspension corner.launch.py [namespace:=front_left] [lockstep:=true]
[record:=false] [road:=iso8608:road_class=C,speed=20] [duration:=10.0]`` starts the same
nodes as ``mr-suspension nodes``, each with its parameter file from
``share/mr_suspension/config/nodes``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = 'mr_suspension'


def parameter_file(node):
    """Path of the installed ``config/nodes/<node>.yaml``."""
    return os.path.join(get_package_share_directory(PACKAGE), 'config', 'nodes', f'{node}.yaml')


def generate_launch_description():
    """Plant, controller, actuator and (with ``record``) the recorder of one corner."""
    namespace = LaunchConfiguration('namespace')
    lockstep = ParameterValue(LaunchConfiguration('lockstep'), value_type=bool)
    record = LaunchConfiguration('record')
    recorders = ParameterValue(PythonExpression(["1 if '", record, "' == 'true' else 0"]),
                               value_type=int)
    expect = ParameterValue(PythonExpression(["2 if '", record, "' == 'true' else 1"]),
                            value_type=int)
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='front_left',
                              description='corner namespace'),
        DeclareLaunchArgument('lockstep', default_value='false',
                              description='true: simulated time, the simulator step order'),
        DeclareLaunchArgument('record', default_value='true',
                              description='record the corner topics into a rosbag2 bag'),
        DeclareLaunchArgument('road', default_value='{type: bump, height: 0.05}',
                              description='plant road (road.from_spec)'),
        DeclareLaunchArgument('duration', default_value='3.0', description='road length [s]'),
        Node(package=PACKAGE, executable='recorder', name='recorder', namespace=namespace,
             parameters=[parameter_file('recorder'), {'lockstep': lockstep}],
             condition=IfCondition(record), output='screen'),
        Node(package=PACKAGE, executable='controller', name='controller', namespace=namespace,
             parameters=[parameter_file('controller'),
                         {'lockstep': lockstep, 'recorders': recorders}], output='screen'),
        Node(package=PACKAGE, executable='actuator', name='actuator', namespace=namespace,
             parameters=[parameter_file('actuator'),
                         {'lockstep': lockstep, 'recorders': recorders}], output='screen'),
        Node(package=PACKAGE, executable='plant', name='plant', namespace=namespace,
             parameters=[parameter_file('plant'),
                         {'lockstep': lockstep, 'expect_subscribers': expect,
                          'road': ParameterValue(LaunchConfiguration('road'), value_type=str),
                          'duration': ParameterValue(LaunchConfiguration('duration'),
                                                     value_type=float)}],
             output='screen'),
    ])
