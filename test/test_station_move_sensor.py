# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station's "Move sensor here" in a real browser, the whole loop of ``station --demo`` as a
newcomer runs it: ``affordance-registration station --demo --first-view
edge-on:quarter_turn_valve`` starts the simulated scan (on a hard first view: the demo
taskboard's quarter-turn valve seen edge-on), the engine and the station as separate processes;
headless chromium driven by Playwright. The button is there only while the open object is
unsettled with a suggested view; pressing it publishes exactly that view on
``/sensor_view_request``; the simulated sensor moves there, the engine fits the click anew and
it settles, and the button goes. A client without the station's access secret is refused in
one log line and publishes nothing."""

import sys
import urllib.error
import urllib.request

import numpy as np
import pytest
from browser_helpers import (
    STATION_SECRET,
    browser_page,
    chromium_missing,
    free_port,
    station_url,
    wait_text,
    wait_until,
)
from geometry_msgs.msg import PointStamped, PoseStamped
from ros_helpers import LATCHED, Client, NodeProcess
from std_msgs.msg import String
from test_sensor_move import FRAME, click_on, edge_on_case

from affordance_registration.ros.glue.conversions import pose_to_matrix
from affordance_registration.ros.station.access import SECRET_ENV

NS = "/affordance_engine"
REQUEST = "/sensor_view_request"


def test_move_sensor_here_sends_the_suggested_view_and_the_loop_settles_the_click(
    tmp_path, library, ros_context, processes
):
    missing = chromium_missing()
    assert not missing, missing
    _, _, click, truth = edge_on_case(library)
    port = free_port()
    out = tmp_path / "out"
    demo = processes(
        NodeProcess(
            [
                sys.executable,
                "-m",
                "affordance_registration.cli",
                "station",
                "--demo",
                "--first-view",
                "edge-on:quarter_turn_valve",
                "--port",
                str(port),
                "--out",
                str(out),
            ],
            tmp_path / "demo.log",
            env={SECRET_ENV: STATION_SECRET},
        )
    )

    def nodes() -> str:
        """The nodes' output (the demo writes it to station_demo.log)."""
        path = out / "station_demo.log"
        return path.read_text() if path.exists() else ""

    client = Client("station_move_sensor_test")
    client.subscribe(String, f"{NS}/status", LATCHED)
    client.subscribe(PoseStamped, f"{NS}/suggested_view", LATCHED)
    client.subscribe(PoseStamped, REQUEST, keep=True)
    pub_click = client.node.create_publisher(PointStamped, "/clicked_point", 10)
    try:
        assert demo.wait_output("operator station: ", 180), demo.output()
        client.wait_for_subscribers(pub_click, timeout=90)
        with browser_page(station_url(port)) as page:
            wait_text(page, r"Engine: /affordance_engine — idle")
            wait_text(page, rf"points in '{FRAME}'")
            button = page.get_by_role("button", name="Move sensor here", exact=True)
            assert not button.is_visible()  # nothing open: no suggestion

            click_on(client, pub_click, lambda: client.status(f"{NS}/status") or {}, click)
            wait_text(page, r"Unsettled: .*suggested view: look from")
            obj = client.wait_for(
                lambda: client.status(f"{NS}/status")["objects"][0], 30, "the open object"
            )
            assert obj["ambiguity"]["settled"] is False
            T_view = np.asarray(obj["suggested_view"]["pose"])
            button.wait_for(state="visible", timeout=60_000)

            button.click()
            sent = client.wait_for(lambda: client.history.get(REQUEST), 30, "the request")
            assert len(sent) == 1 and sent[0].header.frame_id == FRAME
            assert np.allclose(pose_to_matrix(sent[0].pose), T_view, atol=1e-8)
            engine_view = client.latest[f"{NS}/suggested_view"]
            assert np.allclose(
                pose_to_matrix(sent[0].pose), pose_to_matrix(engine_view.pose), atol=1e-6
            )
            wait_text(page, rf"Move sensor here: sent \(.*\) in '{FRAME}' on {REQUEST}$")

            # the simulated sensor moves, the click is fitted anew and settles: no button
            wait_until(
                lambda: "[affordance_simulated_scan]: moved the sensor to" in nodes(),
                90,
                "the simulated sensor to move",
            )
            wait_text(page, rf"Shown: #1 {truth.template} .*— rank 1/")
            wait_until(
                lambda: (
                    "fitted again on the new cloud"
                    in (client.status(f"{NS}/status")["node"]["last_message"])
                ),
                120,
                "the refit on the new cloud",
            )
            button.wait_for(state="hidden", timeout=60_000)
            assert client.status(f"{NS}/status")["objects"][0]["ambiguity"]["settled"]
            assert page.get_by_text("Unsettled").count() == 0

            # only the operator: without the access secret, the page is refused (one line)
            with pytest.raises(urllib.error.HTTPError) as refused:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10)
            assert refused.value.code == 403
            wait_until(lambda: "station: refused '/' from" in nodes(), 30, "the refusal")
            assert len(client.history[REQUEST]) == 1
    finally:
        client.close()


def test_the_suggested_pose_is_offered_only_for_an_unsettled_object_with_a_usable_view():
    from affordance_registration.core.registration.viewpoint import optical_pose
    from affordance_registration.ros.station.state import suggested_pose

    T = optical_pose(
        np.array([0.3, -0.2, 0.1]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    )
    obj = {
        "ambiguity": {"settled": False, "kinds": ["rival_template"], "reasons": ["..."]},
        "suggested_view": {"pose": T.tolist(), "text": "look from ..."},
    }
    assert np.array_equal(suggested_pose(obj), T)
    assert suggested_pose(None) is None
    assert suggested_pose(dict(obj, ambiguity={"settled": True})) is None
    assert suggested_pose(dict(obj, ambiguity=None)) is None  # an older engine
    assert suggested_pose(dict(obj, ambiguity="unsettled")) is None
    assert suggested_pose(dict(obj, suggested_view=None)) is None  # no view found
    for bad in ([[1, 2], [3, 4]], [["a"] * 4] * 4, (np.eye(4) * np.nan).tolist(), "pose"):
        assert suggested_pose(dict(obj, suggested_view={"pose": bad})) is None, bad
