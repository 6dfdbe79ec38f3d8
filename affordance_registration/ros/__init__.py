# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ROS 2 side, by role: ``nodes`` (the engine and SpaceMouse nodes), ``station`` (the browser
operator station), ``glue`` (messages, markers, TF, parameters, QoS), ``standins`` (what ROS 2
packages missing from PyPI would provide) and ``devices`` (drivers without ROS)."""
