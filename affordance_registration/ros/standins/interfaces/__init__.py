# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""ROS interface definitions the pip-only install builds itself (``build.py``).

ROS 2 Jazzy's PyPI wheels have no tf2_msgs, so ``make setup`` generates it from the
definitions under ``tf2_msgs/msg`` with the rosidl wheels and a C/C++ compiler. In a ROS
install tf2_msgs comes from the distribution and nothing here is used.
"""
