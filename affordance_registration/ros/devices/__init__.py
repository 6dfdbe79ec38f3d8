# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Input devices without ROS: the SpaceMouse HID driver (its ROS node is
``ros.nodes.spacemouse_node``)."""
