# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The bench's browser row, on two clicks: the engine node and the station in their own processes,
a headless Chromium clicking objects of a simulated taskboard, each label timed on the page."""

import math

import pytest

from affordance_registration.evaluation.browser_latency import (
    chromium_missing,
    measure_browser_latency,
)

pytest.importorskip(
    "rclpy", reason="the browser row needs the ROS packages (pip install -e '.[ros]')"
)


@pytest.mark.skipif(bool(chromium_missing()), reason=chromium_missing() or "a browser is here")
def test_two_clicks_timed_on_the_page(tmp_path):
    logged = []
    row = measure_browser_latency([7, 8], 2, str(tmp_path), log=logged.append)
    assert row is not None and row["clicks"] == 2, logged
    # the page's own clock: the label came after the press, and within the wait the test allows
    assert 0 < row["click_to_label_s"] <= row["click_to_label_max_s"] < 120, row
    assert (
        math.isfinite(row["engine_click_to_status_s"]) and row["engine_click_to_status_s"] > 0
    ), row
    # each measured label is the fit of that click: the object's own template is named
    assert row["true_template_named"] >= 1, row["labels"]
    assert all(label.startswith(f"Shown: #{k}") for k, label in enumerate(row["labels"], 1)), row
    # and the bench prints the row it measured
    from affordance_registration.evaluation.bench import format_table

    table = format_table(
        {
            "rows": [],
            "refit": {"median_s": 0.01, "success": 1.0},
            "scenes": 1,
            "pose_tolerance": {"m": 0.005, "deg": 5.0},
            "machine": {"cpus": 2},
            "browser_latency": row,
        }
    )
    assert f"click -> label median {row['click_to_label_s']:.2f} s" in table, table


def test_a_live_graph_row_that_fails_is_left_out_with_its_reason(monkeypatch):
    """A row over the live graph that fails (here the page's wait running out, as a loaded
    machine's can) does not end the bench, whose other rows took many minutes: the row is left
    out, and the table says so with the reason."""
    from affordance_registration.evaluation import browser_latency
    from affordance_registration.evaluation.bench import format_table
    from affordance_registration.evaluation.bench_rows import browser_latency_bench

    def times_out(seeds, clicks, out_dir, log=print):
        raise TimeoutError("Locator.wait_for: Timeout 120000ms exceeded.\nCall log: ...")

    monkeypatch.setattr(browser_latency, "measure_browser_latency", times_out)
    logged = []
    row = browser_latency_bench([7], 2, logged.append)
    assert row == {
        "clicks": 0,
        "left_out": "TimeoutError: Locator.wait_for: Timeout 120000ms exceeded.",
    }
    assert any("left out" in line for line in logged), logged
    table = format_table(
        {
            "rows": [],
            "refit": {"median_s": 0.01, "success": 1.0},
            "scenes": 1,
            "pose_tolerance": {"m": 0.005, "deg": 5.0},
            "machine": {"cpus": 2},
            "browser_latency": row,
            "push_refit_ros": row,
        }
    )
    assert "the browser station: left out (TimeoutError: Locator.wait_for" in table, table
    assert "refit after a SpaceMouse push over ROS: left out (TimeoutError" in table, table
