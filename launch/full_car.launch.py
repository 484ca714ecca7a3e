"""Launch the full car: plant, corner controllers or the modal controller, actuators, recorder.

``ros2 launch mr_suspension full_car.launch.py [modal:=true] [lockstep:=true] [record:=false]
[vehicle:=lisa_full_car] [road:=iso8608:road_class=C,speed=20] [duration:=10.0]``. The car's
nodes run in the launch namespace, each corner's controller and actuator in the corner's
namespace (``front_left``, ``front_right``, ``rear_left``, ``rear_right``) with the vehicle
``<vehicle>:<corner>``; the recorder records every corner's topics and ``body/imu`` into one
bag. The same nodes as ``mr-suspension nodes --full-car [--modal]``, each with its parameter
file from ``share/mr_suspension/config/nodes``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = 'mr_suspension'
CORNERS = ('front_left', 'front_right', 'rear_left', 'rear_right')


def parameter_file(node):
    """Path of the installed ``config/nodes/<node>.yaml``."""
    return os.path.join(get_package_share_directory(PACKAGE), 'config', 'nodes', f'{node}.yaml')


def generate_launch_description():
    """Return the full-car node set (module doc)."""
    lockstep = ParameterValue(LaunchConfiguration('lockstep'), value_type=bool)
    record = LaunchConfiguration('record')
    modal = LaunchConfiguration('modal')
    vehicle = LaunchConfiguration('vehicle')
    road = ParameterValue(LaunchConfiguration('road'), value_type=str)
    recorders = ParameterValue(PythonExpression(["1 if '", record, "' == 'true' else 0"]),
                               value_type=int)
    expect = ParameterValue(PythonExpression(["2 if '", record, "' == 'true' else 1"]),
                            value_type=int)
    body_imu = ParameterValue(PythonExpression(
        ["(1 if '", modal, "' == 'true' else 0) + (1 if '", record, "' == 'true' else 0)"]),
        value_type=int)
    actions = [
        DeclareLaunchArgument('modal', default_value='false',
                              description='the modal controller instead of four corner '
                                          'controllers'),
        DeclareLaunchArgument('lockstep', default_value='false',
                              description='true: simulated time, the simulator step order'),
        DeclareLaunchArgument('record', default_value='true',
                              description='record every corner and body/imu into one bag'),
        DeclareLaunchArgument('vehicle', default_value='lisa_full_car',
                              description='full-car parameter set (config/vehicles)'),
        DeclareLaunchArgument('road', default_value='{type: bump, height: 0.05, side: left}',
                              description='plant road (car_road.from_spec)'),
        DeclareLaunchArgument('duration', default_value='3.0', description='road length [s]'),
        Node(package=PACKAGE, executable='recorder', name='recorder',
             parameters=[parameter_file('recorder'),
                         {'lockstep': lockstep, 'namespaces': ','.join(CORNERS)}],
             condition=IfCondition(record), output='screen'),
        Node(package=PACKAGE, executable='modal_controller', name='modal_controller',
             parameters=[parameter_file('modal_controller'),
                         {'lockstep': lockstep, 'vehicle': ParameterValue(vehicle, value_type=str),
                          'recorders': recorders}],
             condition=IfCondition(modal), output='screen'),
    ]
    for corner in CORNERS:
        corner_vehicle = ParameterValue([vehicle, ':' + corner], value_type=str)
        actions += [
            Node(package=PACKAGE, executable='controller', name='controller', namespace=corner,
                 parameters=[parameter_file('controller'),
                             {'lockstep': lockstep, 'vehicle': corner_vehicle,
                              'recorders': recorders}],
                 condition=UnlessCondition(modal), output='screen'),
            Node(package=PACKAGE, executable='actuator', name='actuator', namespace=corner,
                 parameters=[parameter_file('actuator'),
                             {'lockstep': lockstep, 'vehicle': corner_vehicle,
                              'recorders': recorders}],
                 output='screen'),
        ]
    actions.append(
        Node(package=PACKAGE, executable='full_car_plant', name='full_car_plant',
             parameters=[parameter_file('full_car_plant'),
                         {'lockstep': lockstep, 'vehicle': ParameterValue(vehicle, value_type=str),
                          'expect_subscribers': expect, 'body_imu_subscribers': body_imu,
                          'road': road,
                          'duration': ParameterValue(LaunchConfiguration('duration'),
                                                     value_type=float)}],
             output='screen'))
    return LaunchDescription(actions)
