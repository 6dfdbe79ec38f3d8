# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""ROS interface definitions the pip-only install builds itself (``build.py``).

ROS 2 Jazzy's PyPI wheels have no tf2_msgs, moveit_msgs or vision_msgs, so ``make setup``
generates the messages the package uses of them from the definitions under ``<package>/msg``
(written from the published Jazzy ones) with the rosidl wheels and a C/C++ compiler. In a ROS
install they come from the distribution and nothing here is used.
"""
