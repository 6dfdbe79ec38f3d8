# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The browser operator station end to end, in a real browser: the engine node, a simulated scan
and the station run as separate processes; headless chromium (software WebGL) driven by
Playwright clicks, drags and presses buttons on the page like an operator."""

import math
import re

import numpy as np
import yaml
from browser_helpers import (
    browser_page,
    canvas_box,
    chromium_missing,
    drag,
    free_port,
    on_canvas,
    open_details,
    open_station,
    pixel,
    scan_argv,
    settled_view,
    station_argv,
    station_url,
    wait_text,
    wait_until,
)
from geometry_msgs.msg import PoseStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import LATCHED, Client, engine_process
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import POSE_TOL_M, POSE_TOL_RAD
from affordance_registration.ros.glue.conversions import pose_to_matrix
from affordance_registration.ros.station.page import gizmo_scale
from affordance_registration.ros.station.state import active_object, apply_markers

FRAME = "camera_depth_optical_frame"
FOV_DEG = 60.0  # the station's default fov_deg
MARKERS_QOS = QoSProfile(
    depth=10,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def _within(T, truth, library) -> tuple[bool, str]:
    dt, dr = pose_error(
        np.asarray(T, dtype=float), truth.T_scene_model, library[truth.template].symmetry
    )
    return (
        dt <= POSE_TOL_M and dr <= POSE_TOL_RAD,
        f"{dt * 1000:.1f} mm, {math.degrees(dr):.1f} deg",
    )


def _shown(status):
    obj = active_object(status)
    return None if obj is None else obj["candidates"][obj["shown"]]


def _drawn_fit(client, pose):
    """The open object's candidate mesh as the markers this client heard last draw it, once it
    is at ``pose`` (4x4)."""
    drawings = {}
    for msg in client.history["/affordance_engine/markers"]:
        drawings = apply_markers(drawings, msg)
    fit = drawings.get(("candidate", 1))
    return fit if fit is not None and np.allclose(fit.T, pose, atol=1e-5) else None


def _last_drawn(station) -> str:
    """The label the station last logged as drawn for object 1 ('' before any)."""
    return (re.findall(r"drawn: object 1 as (.*)", station.output()) or [""])[-1]


def test_operator_station_in_a_real_browser(
    tmp_path, library, panel_scene, ros_context, processes
):
    missing = chromium_missing()
    assert not missing, missing
    port = free_port()
    processes(scan_argv(seed=panel_scene.seed), "scan")
    # the "fitting…" marker drawn at once (by default only a fit slower than 0.5 s gets it)
    station = processes(
        station_argv(port, display_points=60000, fitting_marker_delay=0.0), "station"
    )
    client = Client("station_browser_test")
    client.subscribe(PoseStamped, "/view_pose", keep=True)
    client.subscribe(String, "/affordance_engine/status", LATCHED)
    client.subscribe(MarkerArray, "/affordance_engine/markers", MARKERS_QOS, keep=True)
    truth = max(panel_scene.objects, key=lambda o: o.visible_points)
    try:
        assert station.wait_output("operator station on", 90), station.output()
        with browser_page(station_url(port)) as page:
            # no engine yet: the page says so, and recovers when the engine comes up
            wait_text(page, "Engine not running")
            processes(engine_process(tmp_path))
            wait_text(page, r"Engine: /affordance_engine — idle")
            wait_text(page, rf"points in '{FRAME}'")

            # the page's camera, as the station publishes it on view_pose: the first view of a
            # sensor-frame cloud stands at the sensor, or behind it along its view to frame the
            # cloud; wait until it has settled there
            view = settled_view(client)
            assert view.header.frame_id == FRAME
            T_view = pose_to_matrix(view.pose)
            # a subscriber that joins once the camera is at rest (an engine started later) is
            # sent that view too, not left waiting until the operator moves the camera
            late = Client("station_browser_late")
            try:
                late.subscribe(PoseStamped, "/view_pose")
                got = late.wait_for(
                    lambda: late.latest.get("/view_pose"),
                    60,
                    "the view for a subscriber that joined late",
                )
                assert np.allclose(pose_to_matrix(got.pose), T_view, atol=1e-6)
            finally:
                late.close()

            # click the object's pixel once the engine (started after the station) holds the
            # cloud too -- else, on a loaded machine, the click beats its first cloud
            client.wait_for_cloud(90, "the engine's first cloud")
            xy = pixel(T_view, FOV_DEG, canvas_box(page), truth.click)
            assert on_canvas(page, xy), f"the object's pixel {xy} is not on the 3D view"
            page.mouse.click(*xy)
            wait_text(page, rf"Shown: #1 {truth.template}\b.*rank 1/\d+")
            # the page shows the status the station heard: this client hears it on its own
            c = client.wait_for(
                lambda: (
                    (_shown(client.status()) or {}).get("rank") == 1
                    and client.status()["node"]["idle"]
                    and _shown(client.status())
                ),
                60,
                "the fit in this client's status",
            )
            ok, err = _within(c["pose"], truth, library)
            assert c["template"] == truth.template and ok, err
            # the marker at the click went up with the click and down with its fit
            wait_until(
                lambda: "fitting marker cleared" in station.output(),
                60,
                "the fitting marker cleared",
            )
            log = station.output()
            assert log.index("fitting marker shown") < log.index("fitting marker cleared")

            # Next, Previous
            page.get_by_role("button", name="Next", exact=True).click()
            wait_text(page, r"Shown: #1 \w+.*rank 2/\d+")
            page.get_by_role("button", name="Previous", exact=True).click()
            wait_text(page, rf"Shown: #1 {truth.template}\b.*rank 1/\d+")
            # a candidate picked by name in the dropdown (~/select_model), and back
            for rank in (3, 1):
                page.locator(
                    "input[value^='1. '], input[value^='2. '], input[value^='3. ']"
                ).first.click()
                page.get_by_role("option", name=re.compile(rf"^{rank}\. ")).click()
                wait_text(page, rf"Shown: #1 \w+.*rank {rank}/\d+")
            wait_text(page, rf"Shown: #1 {truth.template}\b.*rank 1/\d+")
            client.wait_for(
                lambda: _shown(client.status())["rank"] == 1 and client.status()["node"]["idle"],
                60,
                "the first candidate again",
            )
            # the status comes before the markers: wait until this client has the markers of
            # that candidate and the page has drawn them (the station logs what it draws)
            # before grabbing its gizmo
            pose = np.asarray(_shown(client.status())["pose"])
            fit = client.wait_for(lambda: _drawn_fit(client, pose), 60, "the markers of the fit")
            wait_until(
                lambda: (
                    _last_drawn(station).startswith(truth.template)
                    and "rank 1/" in _last_drawn(station)
                ),
                90,
                "the page drawing the fit",
            )
            T = fit.T
            scale = gizmo_scale(fit.vertices)
            grab, goal = T @ [0.9 * scale, 0, 0, 1], T @ [0.9 * scale + 0.02, 0, 0, 1]
            box = canvas_box(page)
            n_markers = len(client.history["/affordance_engine/markers"])
            drag(
                page, pixel(T_view, FOV_DEG, box, grab[:3]), pixel(T_view, FOV_DEG, box, goal[:3])
            )
            status = client.wait_for(
                lambda: (
                    (active_object(client.status()) or {}).get("corrections", 0) >= 1
                    and ": refit" in client.status()["node"]["last_message"]
                    and client.status()["node"]["idle"]
                    and client.status()
                ),
                90,
                "the refit after the drag",
            )
            moved = [
                np.linalg.norm(d.T[:3, 3] - T[:3, 3])
                for msg in client.history["/affordance_engine/markers"][n_markers:]
                for (ns, mid), d in apply_markers({}, msg).items()
                if ns == "candidate"
            ]
            assert max(moved) >= 0.01, f"the drag moved the fit at most {max(moved) * 1000:.1f} mm"
            c = _shown(status)
            ok, err = _within(c["pose"], truth, library)
            assert c["template"] == truth.template and ok, f"refit after the drag: {err}"

            # Refit, Accept, Undo, Accept, Save: the saved registration is the truth (each step
            # waits for text the step before could not have shown)
            page.get_by_role("button", name="Refit", exact=True).click()
            wait_text(page, r"refit: ok — ")
            page.get_by_role("button", name="Accept", exact=True).click()
            wait_text(page, r"Objects: 0 open, 1 registered")
            page.get_by_role("button", name="Undo", exact=True).click()
            wait_text(page, r"undo: ok — undid accept")
            wait_text(page, r"Objects: 1 open, 0 registered")
            page.get_by_role("button", name="Accept", exact=True).click()
            wait_text(page, r"accept: ok — accepted")
            wait_text(page, r"Objects: 0 open, 1 registered")
            page.get_by_role("button", name="Save", exact=True).click()
            wait_text(page, r"save: ok — saved 1 registration")
            saved = yaml.safe_load((tmp_path / "registrations.yaml").read_text())
            regs = saved["registrations"]
            assert [r["template"] for r in regs] == [truth.template]
            ok, err = _within(regs[0]["pose"], truth, library)
            assert ok, f"saved registration: {err}"

            # a second browser shows the same state
            second = page.context.new_page()
            open_station(second, station_url(port))
            open_details(second)
            wait_text(second, r"Objects: 0 open, 1 registered")
            wait_text(second, r"save: ok — saved 1 registration")
    finally:
        client.close()


#: a frame id that is HTML: a script in an iframe that would run in the page's origin
HOSTILE_FRAME = (
    "<iframe srcdoc=\"<script>parent.window.__pwned=1;parent.document.title='pwned'</script>\">"
    "</iframe><b>bold</b>"
)


def test_a_frame_id_that_is_html_is_shown_as_text_and_its_script_never_runs(
    tmp_path, ros_context, processes
):
    """A PointStamped on clicked_point whose frame_id is HTML with a script: the engine refuses
    the click quoting the frame, the station shows that error -- as the text it is: no element
    of it is made, its script does not run (the page's title and globals stay as they were)."""
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import PointCloud2

    from affordance_registration.ros.glue.conversions import xyz_to_pointcloud2

    missing = chromium_missing()
    assert not missing, missing
    port = free_port()
    processes(engine_process(tmp_path))
    station = processes(station_argv(port), "station")
    client = Client("station_html_test")
    client.subscribe(String, "/affordance_engine/status", LATCHED)
    points = client.node.create_publisher(PointCloud2, "/points", 1)
    clicks = client.node.create_publisher(PointStamped, "/clicked_point", 10)
    try:
        client.wait_for_subscribers(points, timeout=60)
        client.wait_for_subscribers(clicks, timeout=60)
        grid = np.stack(np.meshgrid(np.linspace(-0.2, 0.2, 20), np.linspace(-0.2, 0.2, 20)), -1)
        cloud = np.concatenate([grid.reshape(-1, 2), np.ones((400, 1))], axis=1)
        points.publish(xyz_to_pointcloud2(cloud, "cam"))
        client.wait_for_cloud(60)
        assert station.wait_output("operator station on", 90), station.output()
        with browser_page(station_url(port)) as page:
            wait_text(page, r"Engine: /affordance_engine — idle")
            title = page.title()
            click = PointStamped()
            click.header.frame_id = HOSTILE_FRAME
            click.point.z = 1.0
            clicks.publish(click)
            # the engine's error, quoting the frame id as it is, shown as that text
            shown = wait_text(page, r"Last error: click refused: it is in frame '")
            assert page.locator("iframe").count() == 0, "the frame id became an iframe"
            assert page.locator("b", has_text="bold").count() == 0
            assert HOSTILE_FRAME in shown.inner_text()
            assert page.evaluate("typeof window.__pwned") == "undefined"
            assert page.title() == title != "pwned"
    finally:
        client.close()
