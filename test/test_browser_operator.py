# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The bench's browser operator row on one real scan: a scripted operator registers every
object of mOSD's learn41 (a container standing on a round tin, a second tin) through the
station's page only -- click, read, Next where wrong, type a cylinder's size where it is off,
Accept, Save -- and what it reports is what the engine recorded."""

import pytest
import yaml

from affordance_registration.evaluation import realdata as rd
from affordance_registration.evaluation.bench import row_note
from affordance_registration.evaluation.browser_latency import chromium_missing
from affordance_registration.evaluation.browser_operator import (
    format_row,
    measure_browser_operator,
)

pytest.importorskip(
    "rclpy", reason="the browser row needs the ROS packages (pip install -e '.[ros]')"
)


@pytest.mark.skipif(bool(chromium_missing()), reason=chromium_missing() or "a browser is here")
def test_the_scripted_operator_registers_a_real_scan_through_the_page(tmp_path):
    if rd.osd_dir() is None:
        pytest.skip(rd.SKIP_REASON)
    logged = []
    row = measure_browser_operator((), 1, str(tmp_path), log=logged.append, scenes=("learn41",))
    assert row is not None and row["simulated"] is None, logged
    real = row["real"]
    assert real["objects"] == 2 and real["accepted"] == 2, logged
    assert real["right"] >= 1, logged  # the tin on its own passes the label rule
    saved = yaml.safe_load((tmp_path / "registrations.yaml").read_text())["registrations"]
    by_id = {r["id"]: r for r in saved}
    for rec in row["records"]:
        reg = by_id[rec["id"]]
        # what the operator did on the page is what reached the engine
        assert reg["model_changes"] == rec["model_changes"], (rec, reg)
        assert reg["corrections"] == rec["dimension_corrections"] + rec["pose_corrections"]
        assert reg["primitive"] == "cylinder" and rec["clicks"] == 1
        # timed on the page: the shown fit after the click, the registration after that
        assert 0 < rec["fit_s"] < rec["accept_s"], rec
    # the bench prints it, and its page says what the line measures
    (line,) = format_row(row)
    assert "2 of 2 objects accepted" in line and "learn41" in line, line
    assert row_note(line)[1] == "the scripted operator"
