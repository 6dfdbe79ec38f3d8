# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station's waypoints toggle and path display in a real browser: the engine node, a
simulated scan and the station as separate processes, headless chromium driven by Playwright."""

from browser_helpers import (
    browser_page,
    canvas_box,
    chromium_missing,
    free_port,
    on_canvas,
    pixel,
    scan_argv,
    settled_view,
    station_argv,
    station_url,
    wait_text,
    wait_until,
)
from geometry_msgs.msg import PoseArray, PoseStamped
from ros_helpers import LATCHED, Client, engine_process
from std_msgs.msg import String

from affordance_registration.ros.glue.conversions import pose_to_matrix

FRAME = "camera_depth_optical_frame"
FOV_DEG = 60.0  # the station's default fov_deg


def test_station_toggles_waypoints_and_draws_the_path_to_a_state(
    tmp_path, library, panel_scene, ros_context, processes
):
    missing = chromium_missing()
    assert not missing, missing
    port = free_port()
    processes(scan_argv(seed=panel_scene.seed), "scan")
    processes(engine_process(tmp_path))
    station = processes(station_argv(port, display_points=60000), "station")
    client = Client("station_waypoints_test")
    client.subscribe(PoseStamped, "/view_pose", keep=True)
    client.subscribe(String, "/affordance_engine/status", LATCHED)
    client.subscribe(PoseArray, "/affordance_engine/path", LATCHED, keep=True)
    moving = [o for o in panel_scene.objects if any(w.part for w in library[o.template].waypoints)]
    truth = max(moving, key=lambda o: o.visible_points)
    try:
        assert station.wait_output("operator station on", 90), station.output()
        with browser_page(station_url(port)) as page:
            wait_text(page, r"Engine: /affordance_engine — idle")
            wait_text(page, rf"points in '{FRAME}'")
            T_view = pose_to_matrix(settled_view(client).pose)
            xy = pixel(T_view, FOV_DEG, canvas_box(page), truth.click)
            assert on_canvas(page, xy), f"the object's pixel {xy} is not on the 3D view"
            page.mouse.click(*xy)
            wait_text(page, rf"Shown: #1 {truth.template}\b")
            wait_until(lambda: "drawn: object 1 as" in station.output(), 60, "the fit drawn")

            # the shown candidate's grippers are drawn (one set: one object); the toggle hides
            # and shows them
            toggle = page.get_by_role("checkbox", name="Waypoints")
            toggle.click()
            wait_text(page, r"waypoints hidden \(1 drawn\)")
            toggle.click()
            wait_text(page, r"waypoints shown \(1 drawn\)")

            # the path to the state farthest from the shown one, as the engine answers it
            shown = client.wait_for(
                lambda: [o for o in client.status()["objects"] if o["active"]][0],
                30,
                "the open object",
            )
            state = next(
                s
                for s in library[truth.template].states
                if s != shown["candidates"][shown["shown"]]["state"]
            )
            # viser labels its fields beside them, not as their accessible names
            field = page.get_by_text("Path to state", exact=True).locator(
                "xpath=following::input[1]"
            )
            field.fill(state)
            field.press("Enter")
            page.get_by_role("button", name="Show path", exact=True).click()
            wait_text(page, rf"path drawn: \d+ poses in '{FRAME}'")
            answer = client.wait_for(
                lambda: client.history.get("/affordance_engine/path"), 30, "the engine's path"
            )[-1]
            assert answer.header.frame_id == FRAME and len(answer.poses) >= 3
            assert f"path drawn: {len(answer.poses)} poses" in station.output()

            # a state the template does not have: the engine's one line on the panel
            field.fill("ajar")
            field.press("Enter")
            page.get_by_role("button", name="Show path", exact=True).click()
            wait_text(page, r"path request refused: .*no state 'ajar'")
    finally:
        client.close()
