"""ROS 2 launch file: start the groupforward node with a config file.

    ros2 launch launch/groupforward.launch.py config:=launch/groupforward.yaml

The node is a plain executable speaking rmw_zenoh's wire format; run it beside a router
(`ros2 run rmw_zenoh_cpp rmw_zenohd`) and set RMW_IMPLEMENTATION=rmw_zenoh_cpp for the other nodes.
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
        ExecuteProcess(
            cmd=[LaunchConfiguration('binary'), 'run', '--config', LaunchConfiguration('config')],
            output='screen',
        ),
    ])
