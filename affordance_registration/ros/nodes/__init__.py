# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ROS 2 nodes: the engine, the SpaceMouse driver's node (the station has its own package,
``ros.station``; the simulated sensor is an evaluation tool, ``evaluation.simulated_scan``)."""
