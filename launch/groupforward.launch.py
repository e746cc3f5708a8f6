"""ROS 2 launch file: start the groupforward node with a config file.

    ros2 launch launch/groupforward.launch.py config:=launch/groupforward.yaml

By default the node is a plain executable speaking rmw_zenoh's wire format; run it beside a router
(`ros2 run rmw_zenoh_cpp rmw_zenohd`) and set RMW_IMPLEMENTATION=rmw_zenoh_cpp for the other nodes.
A build with the `ros2` feature (`make ros2`) joins the sourced ROS 2 graph natively instead:

    ros2 launch launch/groupforward.launch.py transport:=ros2 binary:=launch/ros2/groupforward
"""

import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration

HERE = os.path.dirname(os.path.abspath(__file__))


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('config', default_value=os.path.join(HERE, 'groupforward.yaml'),
                              description='groupforward YAML config'),
        DeclareLaunchArgument('binary', default_value='groupforward',
                              description='path of the groupforward executable'),
        DeclareLaunchArgument('transport', default_value='zenoh',
                              description='zenoh (rmw_zenoh wire format) or ros2 (native, rcl)'),
        ExecuteProcess(
            cmd=[LaunchConfiguration('binary'), 'run', '--config', LaunchConfiguration('config'),
                 '--transport', LaunchConfiguration('transport')],
            output='screen',
        ),
    ])
