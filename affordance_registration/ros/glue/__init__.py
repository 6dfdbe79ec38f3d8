# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Message glue between ROS messages and core: point cloud and pose conversions, markers, TF
and static frames, the engine node's parameters, the QoS profiles."""
