# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""An operator's view of a real scan in the browser station: mOSD's learn4 (a Kinect looking
down at two cereal boxes side by side on a table; a PCD in a frame called ``scan``, fields
``label x y z rgba``) opened with the package's launch file, an engine of its own started without
``registrations_file``, and an operator in headless chromium.

The scan is drawn in its own colours (a red box is red; "Depth colours" switches to the depth
scale), the right way up (the table's normal points up on the screen); a click says one short
sentence and keeps the reasons in the closed Details; the 3D label stays out from under the
panel; a click beside the shown fit fits what is there instead of grabbing the gizmo; Accept with
nothing selected is a warning, not an error; Save writes the registrations into ROS_HOME, not
the folder the nodes were started from. The tests run in order on one station (each takes up
where the one before left the page)."""

import io
import math
import os
import sys
import time
from dataclasses import dataclass

import numpy as np
import pytest
import yaml
from browser_helpers import (
    STATION_SECRET,
    browser_page,
    canvas_box,
    chromium_missing,
    free_port,
    on_canvas,
    pixel,
    settled_view,
    station_url,
    wait_text,
    wait_until,
)
from geometry_msgs.msg import PoseStamped
from ros_helpers import LATCHED, Client, NodeProcess
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from affordance_registration.evaluation import realdata as rd
from affordance_registration.ros.glue.conversions import pose_to_matrix
from affordance_registration.ros.station.access import SECRET_ENV
from affordance_registration.ros.station.state import (
    HEADLINE_MAX,
    active_object,
    apply_markers,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAUNCH = os.path.join(ROOT, "launch_configs", "station_scene.launch.yaml")
CLI = [sys.executable, "-m", "affordance_registration.cli"]
SCENE = "learn4"
STATUS = "/affordance_engine/status"
MARKERS = "/affordance_engine/markers"
FOV = 60.0
#: the panel's visible text: every line of the viser control panel (its scroll area)
PANEL_TEXT = """() => { const h = [...document.querySelectorAll('.mantine-ScrollArea-content')]
  .filter(e => e.getBoundingClientRect().width > 0);
  return h.length ? h[0].innerText : ''; }"""
#: the panel's rectangle on the page
PANEL_RECT = """() => { const h = [...document.querySelectorAll('.mantine-ScrollArea-content')]
  .filter(e => e.getBoundingClientRect().width > 0);
  const r = h[0].getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; }"""


@dataclass
class RealStation:
    page: object
    client: Client
    nodes: NodeProcess
    cloud: rd.LabelledCloud
    ros_home: str
    cwd: str


@pytest.fixture(scope="module")
def station(ros_context, tmp_path_factory):
    folder = rd.osd_dir()
    if folder is None:
        pytest.skip(rd.SKIP_REASON)
    missing = chromium_missing()
    assert not missing, missing
    tmp = tmp_path_factory.mktemp("real_station")
    cwd, ros_home = tmp / "started_here", tmp / "ros_home"
    cwd.mkdir()
    port = free_port()
    path = os.path.join(folder, f"{SCENE}.pcd")
    nodes = NodeProcess(
        [*CLI, "launch", LAUNCH, f"scene:={path}", f"port:={port}"],
        tmp / "nodes.log",
        env={"ROS_HOME": str(ros_home), SECRET_ENV: STATION_SECRET},
        cwd=str(cwd),
    )
    client = Client("real_station_test")
    client.subscribe(PoseStamped, "/view_pose", keep=True)
    client.subscribe(String, STATUS, LATCHED)
    client.subscribe(MarkerArray, MARKERS, LATCHED, keep=True)
    try:
        assert nodes.wait_output("operator station on", 180), nodes.output()[-3000:]
        with browser_page(station_url(port), details=False) as page:
            yield RealStation(page, client, nodes, rd.read_labelled_pcd(path), str(ros_home), cwd)
    finally:
        client.close()
        nodes.interrupt(timeout=60)
        nodes.kill()


def _screen(page) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(int)


def _patch(image: np.ndarray, xy, half: int = 4) -> np.ndarray:
    """The median colour of the (2 half + 1)^2 pixels around page point ``xy``."""
    x, y = int(round(xy[0])), int(round(xy[1]))
    return np.median(image[y - half : y + half + 1, x - half : x + half + 1].reshape(-1, 3), 0)


def _red_spot(cloud: rd.LabelledCloud):
    """A point of a red patch of the scan (its 9 x 9 pixels all red in the file's colours) on a
    labelled object, nearest the middle of that object, and the patch's colour."""
    import open3d as o3d
    from scipy.ndimage import minimum_filter

    read = o3d.t.io.read_point_cloud(os.path.join(rd.osd_dir(), f"{cloud.name}.pcd"))
    image = read.point.colors.numpy().astype(int).reshape(*cloud.shape, 3)
    redness = minimum_filter(image[..., 0] - np.maximum(image[..., 1], image[..., 2]), size=9)
    red = (redness > 60) & cloud.valid & (cloud.object_ids > 0)
    rows, cols = np.nonzero(red)
    assert len(rows), f"{cloud.name} has no red patch"
    r, c = np.median(rows), np.median(cols)
    i = int(np.argmin((rows - r) ** 2 + (cols - c) ** 2))
    r, c = rows[i], cols[i]
    patch = image[r - 4 : r + 5, c - 4 : c + 5].reshape(-1, 3)
    return cloud.points[r, c], np.median(patch, axis=0), int(cloud.object_ids[r, c])


def _rested_view(client: Client) -> np.ndarray:
    """The page's camera once it has sent nothing new for a second."""

    def rested():
        hist = client.history.get("/view_pose") or []
        n = len(hist)
        time.sleep(1.0)
        return hist[-1] if hist and len(client.history["/view_pose"]) == n else None

    return pose_to_matrix(wait_until(rested, 60, "the page's camera at rest").pose)


def _said(page) -> list:
    """What the panel says: its visible paragraphs (the markdown), top first."""
    return [
        p.inner_text().strip()
        for p in page.locator(".mantine-ScrollArea-content p").all()
        if p.is_visible() and p.inner_text().strip()
    ]


def test_the_scan_opens_in_its_own_colours_the_right_way_up(station):
    page = station.page
    station.client.wait_for_cloud(120)
    view = pose_to_matrix(settled_view(station.client).pose)
    # the right way up: the table's normal (towards the sensor) points straight up on the screen
    normal, _ = rd.fit_plane(rd.table_points(station.cloud))
    on_screen = normal - (normal @ view[:3, 2]) * view[:3, 2]
    roll = math.degrees(
        math.acos(np.clip(-view[:3, 1] @ on_screen / np.linalg.norm(on_screen), -1, 1))
    )
    assert roll < 10, f"the table's normal is {roll:.0f} deg from up on the screen"
    # its own colours: the red box is drawn red, as the file has it
    spot, rgb, _ = _red_spot(station.cloud)
    xy = pixel(view, FOV, canvas_box(page), spot)
    assert on_canvas(page, xy), f"the red box's pixel {xy} is not on the 3D view"
    shown = wait_until(
        lambda: (c := _patch(_screen(page), xy))[0] - max(c[1], c[2]) > 40 and c.tolist(),
        60,
        "the red box drawn red",
    )
    assert np.all(np.abs(shown - rgb) < 60), f"drawn {shown}, the file's {rgb}"
    # "Depth colours" switches to the depth scale (a grey ramp) and back
    page.get_by_text("Depth colours").first.click()
    grey = wait_until(
        lambda: np.ptp(c := _patch(_screen(page), xy)) < 40 and c.tolist(), 60, "depth colours"
    )
    assert np.ptp(grey) < 40, grey
    page.get_by_text("Depth colours").first.click()
    wait_until(
        lambda: (c := _patch(_screen(page), xy))[0] - max(c[1], c[2]) > 40, 60, "its own colours"
    )


def test_a_click_says_one_short_sentence_and_keeps_the_reasons_on_demand(station):
    page, client = station.page, station.client
    spot, _, _ = _red_spot(station.cloud)
    view = _rested_view(client)
    xy = pixel(view, FOV, canvas_box(page), spot)
    page.mouse.click(*xy)
    client.wait_for(lambda: active_object(client.status(STATUS)), 120, "the click's fit")
    wait_until(lambda: "#1" in page.evaluate(PANEL_TEXT), 60, "the fit on the page")
    # one sentence is what the panel says: no paragraph, no engine state, no cloud until asked
    said = _said(page)
    assert "box" in said[0] and all(len(p) <= HEADLINE_MAX for p in said), said
    assert not [p for p in said if p.startswith(("Engine", "Objects", "Cloud"))], said
    page.get_by_text("Details", exact=True).first.click()
    wait_text(page, r"^Engine: /affordance_engine")
    wait_text(page, r"^Shown: #1 ")
    page.get_by_text("Details", exact=True).first.click()
    # the up axis is now the table under the click (the first click's support plane)
    wait_until(
        lambda: "the support plane under the first click" in station.nodes.output(),
        30,
        "the up axis from the plane under the first click",
    )


def _drawing(client: Client, key: tuple):
    """The engine's marker ``key`` (namespace, id) as the station draws it, once it is there."""

    def drawn():
        drawings = {}
        for msg in client.history.get(MARKERS) or []:
            drawings = apply_markers(drawings, msg)
        return drawings.get(key)

    return wait_until(drawn, 60, f"the engine's marker {key}")


def _old_gizmo_spot(fit, view, page, cloud: rd.LabelledCloud):
    """A page point beside the shown fit (``fit``: its mesh as drawn) that the gizmo's arrows
    covered when they reached 0.8 of its size from its centre (at least 8 cm): 0.6 of that
    along one of its axes, where the scan point in front is not the fitted object's (a
    neighbour or the table) -- or None."""
    T = fit.T
    reach = 0.6 * max(0.08, 0.8 * float(np.max(np.ptp(fit.vertices, axis=0))))
    valid = cloud.valid.reshape(-1)
    step = max(1, int(valid.sum()) // 60000)
    pts = cloud.points.reshape(-1, 3)[valid][::step]
    ids = cloud.object_ids.reshape(-1)[valid][::step]
    box = canvas_box(page)
    uv = np.array([pixel(view, FOV, box, p) for p in pts])
    depth = (pts - view[:3, 3]) @ view[:3, 2]
    own = int(np.bincount(ids[np.linalg.norm(pts - T[:3, 3], axis=1) < 0.05]).argmax())
    for axis in range(3):
        xy = pixel(view, FOV, box, T[:3, 3] + reach * T[:3, axis])
        if not on_canvas(page, xy):
            continue
        near = np.linalg.norm(uv - np.asarray(xy), axis=1) < 3
        if near.any() and ids[near][np.argmin(depth[near])] != own:  # the point in front
            return xy
    return None


def test_a_click_beside_the_shown_fit_fits_what_is_there(station):
    page, client = station.page, station.client
    first = client.wait_for(lambda: active_object(client.status(STATUS)), 60, "the open object")
    view = _rested_view(client)
    xy = _old_gizmo_spot(_drawing(client, ("candidate", first["id"])), view, page, station.cloud)
    assert xy is not None, "no spot beside the object on the scan"
    page.mouse.click(*xy)

    def handled():  # a second object fitted, or the first one moved (what the click did)
        st = client.status(STATUS)
        kept = next(o for o in st["objects"] if o["id"] == first["id"])
        moved = kept["corrections"] or not np.allclose(
            kept["candidates"][kept["shown"]]["pose"],
            first["candidates"][first["shown"]]["pose"],
            atol=1e-6,
        )
        return (len(st["objects"]) > 1 or moved) and (st, kept)

    st, kept = wait_until(handled, 120, "the click handled")
    # the shown fit was not moved, corrected or refitted by the click: a new object was fitted
    assert kept["corrections"] == 0 and len(st["objects"]) == 2, kept
    assert np.allclose(
        kept["candidates"][kept["shown"]]["pose"],
        first["candidates"][first["shown"]]["pose"],
        atol=1e-6,
    )
    wait_text(page, r"^#2\b")  # the headline is on the new one


def _white(image: np.ndarray, rows: slice, cols: slice) -> float:
    """The share of columns in ``cols`` whose pixels in ``rows`` include a label's background (a
    translucent white: light and grey, not the page's pure white)."""
    patch = image[rows, cols]
    label = np.all((patch >= 225) & (patch <= 250), axis=2) & (np.ptp(patch, axis=2) <= 8)
    return float(np.mean(np.any(label, axis=0)))


def test_the_3d_label_stays_out_from_under_the_panel(station):
    page, client = station.page, station.client
    obj = client.wait_for(lambda: active_object(client.status(STATUS)), 60, "the open object")
    anchor = _drawing(client, ("candidate_label", obj["id"])).position
    panel = page.evaluate(PANEL_RECT)
    # the operator pans the view until the label's point stands 60 px left of the panel
    start = pixel(_rested_view(client), FOV, canvas_box(page), anchor)
    end = (panel[0] - 60, start[1])
    page.mouse.move(*start)
    page.mouse.down(button="right")
    for k in range(1, 13):
        page.mouse.move(start[0] + k / 12 * (end[0] - start[0]), start[1])
        time.sleep(0.05)
    page.mouse.up(button="right")
    x, y = pixel(_rested_view(client), FOV, canvas_box(page), anchor)
    assert panel[0] - 90 < x < panel[0] - 30, f"the label's point at x {x:.0f}, panel {panel}"
    image = _screen(page)
    x, y = int(round(x)), int(round(y))
    rows = slice(y - 20, y + 20)  # the label hangs by its top (or bottom) from its point
    # drawn: its white left of its point; not under the panel: none from 10 px right of it on
    assert _white(image, rows, slice(x - 40, x - 10)) > 0.6, "no label drawn at its point"
    beside = _white(image, rows, slice(x + 10, int(panel[0]) - 1))
    assert beside < 0.3, f"the label runs right of its point into the panel ({beside:.0%})"


def test_accept_with_nothing_selected_is_a_warning_and_save_writes_into_ros_home(station):
    page, client = station.page, station.client
    # accept the open objects, the shown one first: then nothing is selected
    for _ in range(len(client.status(STATUS)["objects"])):
        n = len(client.status(STATUS)["registered"])
        page.get_by_role("button", name="Accept", exact=True).click()
        client.wait_for(
            lambda n=n: len(client.status(STATUS)["registered"]) > n, 60, "one more registered"
        )
    assert active_object(client.status(STATUS)) is None
    page.get_by_role("button", name="Accept", exact=True).click()

    def refusals():
        return [
            line
            for line in station.nodes.output().splitlines()
            if "[affordance_engine]" in line and "no object selected" in line
        ]

    lines = wait_until(refusals, 60, "the engine's refusal")
    assert all(line.startswith("[WARN]") for line in lines), lines
    wait_text(page, r"^Accept: refused — no object selected")  # the headline says so
    # Save: into ROS_HOME, nothing into the folder the nodes were started from
    page.get_by_role("button", name="Save", exact=True).click()
    saved = os.path.join(station.ros_home, "affordance_registrations.yaml")
    wait_until(lambda: os.path.isfile(saved), 60, f"{saved} written")
    with open(saved, encoding="utf-8") as handle:
        assert len(yaml.safe_load(handle)["registrations"]) == 2
    assert os.listdir(station.cwd) == [], os.listdir(station.cwd)
