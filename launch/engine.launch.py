# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine node with its parameter file, for ``ros2 launch affordance_registration
engine.launch.py`` in a ROS 2 install (launch_ros); the same arguments as
``launch_configs/affordance_engine.launch.yaml``, which the pip-only install starts with
``affordance-registration launch``, plus ``fixed_frame`` and ``collision_objects``::

    ros2 launch affordance_registration engine.launch.py points:=/camera/depth/points \\
        fixed_frame:=odom
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "affordance_registration"

#: name -> (default, description); strings are passed as strings, "true"/"false" as booleans
ARGUMENTS = {
    "points": ("points", "the PointCloud2 topic"),
    "clicked_point": ("clicked_point", "the clicks (RViz Publish Point)"),
    "params": (
        os.path.join(
            get_package_share_directory(PACKAGE),
            "launch_configs",
            "affordance_engine.params.yaml",
        ),
        "the node's parameter file",
    ),
    "registrations_file": ("affordance_registrations.yaml", "the session's registrations"),
    "twist_stamped": ("false", "spacenav/twist is TwistStamped"),
    "resume": ("true", "continue the session in registrations_file"),
    "settings_file": ("", "fitting settings (YAML) replacing the fit.* defaults"),
    "fixed_frame": ("", "the frame objects live in (odom, map); '' = the cloud's"),
    "collision_objects": ("true", "publish registrations as MoveIt collision objects"),
}
BOOLEANS = ("twist_stamped", "resume", "collision_objects")
STRINGS = ("registrations_file", "settings_file", "fixed_frame")


def generate_launch_description() -> LaunchDescription:
    args = [
        DeclareLaunchArgument(name, default_value=default, description=doc)
        for name, (default, doc) in ARGUMENTS.items()
    ]
    overrides = {
        name: ParameterValue(
            LaunchConfiguration(name), value_type=bool if name in BOOLEANS else str
        )
        for name in BOOLEANS + STRINGS
    }
    engine = Node(
        package=PACKAGE,
        executable="affordance_engine",
        name="affordance_engine",
        output="screen",
        parameters=[LaunchConfiguration("params"), overrides],
        remappings=[
            ("points", LaunchConfiguration("points")),
            ("clicked_point", LaunchConfiguration("clicked_point")),
        ],
    )
    return LaunchDescription([*args, engine])
