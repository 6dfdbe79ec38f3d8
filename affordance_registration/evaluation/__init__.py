# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Evaluation on real and simulated data with ground truth: readers for the shared real scans
(mOSD, PCL's milk carton), a label-based scoring of primitive fits, cluttered real scenes built
from them, and the bench rows they give. ROS-free, like ``core``; nothing here is run by a
click (the product never imports it)."""
