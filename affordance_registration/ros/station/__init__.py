# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The browser operator station: the node (ROS side), the page it serves, its access rules, and
the file-scan publisher behind ``station --scene``."""
