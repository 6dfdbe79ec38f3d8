# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The bench's "over ROS" row on the live graph: the engine node in its own process (from the
launch file), clicks and clouds from this one, the same fits in this process. Measured figures
are the bench's (no wall-clock bound here); this checks the row measures what it says."""

import math

from affordance_registration.evaluation.ros_latency import measure_node_latency


def test_the_over_ros_row_measures_the_live_node(ros_context, tmp_path):
    row = measure_node_latency([1000], 2, str(tmp_path), idle_s=1.0, log=lambda m: None)
    assert row["clicks"] == 2
    # both fits accepted: the last markers message draws the two registered objects -- by
    # reference (mesh files named, not triangles: those were 100-200 kB per object)
    assert row["objects_shown_last"] == 2
    assert 0 < row["markers_bytes_last"] <= row["markers_bytes_max"] < 20_000
    # each click was heard back in a status and in markers, and fitted here too
    assert row["node_click_to_status_s"] > 0 and row["in_process_fit_s"] > 0
    assert math.isfinite(row["click_to_status_over_fit"]) and row["click_to_status_over_fit"] > 0
    # the node's own fit time came back in its status (the fit inside the node over this one)
    assert math.isfinite(row["node_fit_over_fit"]) and row["node_fit_over_fit"] > 0
    assert row["status_to_markers_ms"] is not None and row["status_to_markers_ms"] >= 0
    # the engine's CPU time over the quiet spell (CPU, not wall clock: a loaded machine lowers
    # it): far below a core spinning (publishing on change, no polling loop)
    assert 0 <= row["idle_engine_cores"] < 0.25
