# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Stand-ins for ROS 2 packages that are not on PyPI: a launcher (launch), rosbag2 recording and
playback, an interactive-marker server, the tf2_msgs interface build, node spinning."""
