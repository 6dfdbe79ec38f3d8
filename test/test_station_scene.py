# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A user with a file: ``affordance-registration station --scene FILE --units mm`` serves the
browser station on a PLY scan in millimetres with an engine of its own (no other node started
by the test), and an operator in a real browser (headless chromium) clicks an object, accepts
and saves it -- in metres, on the truth; an unsettled click there gets no "Move sensor here"
(nothing moves the sensor of a file) until something subscribes to the request. Also ``fit
--units`` and the units hint of a click error on the command line."""

import math
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml
from browser_helpers import (
    browser_page,
    canvas_box,
    chromium_missing,
    free_port,
    on_canvas,
    pixel,
    settled_view,
    wait_text,
    wait_until,
)
from geometry_msgs.msg import PoseStamped
from ros_helpers import Client, NodeProcess
from test_override import bare_wall_point

from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import POSE_TOL_M, POSE_TOL_RAD, ply_bytes
from affordance_registration.ros.glue.conversions import pose_to_matrix

CLI = [sys.executable, "-m", "affordance_registration.cli"]
#: records whether the page ever showed the "Fitting" line of the panel
SAW_FITTING = """() => { window.__sawFitting = false;
  new MutationObserver(() => { if (document.body.innerText.includes('Fitting:'))
    window.__sawFitting = true; }).observe(document.body,
    {subtree: true, childList: true, characterData: true}); }"""


@pytest.fixture
def mm_scan(tmp_path, panel_scene):
    """The panel scene written as a PLY in millimetres, and its best-visible object."""
    path = tmp_path / "scan_mm.ply"
    path.write_bytes(ply_bytes(panel_scene.points * 1000.0))
    return path, max(panel_scene.objects, key=lambda o: o.visible_points)


def _cli(*args, timeout=300):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def test_fit_units_mm_fits_a_millimetre_scan_like_the_metre_one(
    mm_scan, panel_scene, tmp_path, library
):
    path, obj = mm_scan
    metres = tmp_path / "scan_m.ply"
    metres.write_bytes(ply_bytes(panel_scene.points))
    import json

    got = {}
    for name, scene, unit in (("mm", path, 1000.0), ("m", metres, 1.0)):
        out = _cli(
            "fit", "--scene", scene, "--point", *(obj.click * unit), "--units", name, "--json"
        )
        assert out.returncode == 0, out.stderr
        got[name] = json.loads(out.stdout)
    for doc in got.values():
        best = doc["candidates"][0]
        assert best["template"] == obj.template
        dt, dr = pose_error(
            np.array(best["pose"]).reshape(4, 4), obj.T_scene_model, library[obj.template].symmetry
        )
        assert dt <= POSE_TOL_M and dr <= POSE_TOL_RAD
    # the output is in metres either way
    assert np.allclose(got["mm"]["point"], got["m"]["point"], atol=1e-6)


@pytest.mark.parametrize("click", ["at the object, read as metres", "far away"])
def test_a_click_error_on_a_millimetre_looking_scan_names_the_units(mm_scan, click):
    path, obj = mm_scan
    point = obj.click * 1000.0 if click.startswith("at") else [0.0, 0.0, 1.0]
    out = _cli("fit", "--scene", path, "--point", *point)
    assert out.returncode == 2 and out.stdout == ""
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "--units mm" in lines[0] and "units across" in lines[0], lines


def test_a_click_error_on_a_metre_scan_says_nothing_of_units(tmp_path, panel_scene):
    path = tmp_path / "scan_m.ply"
    path.write_bytes(ply_bytes(panel_scene.points))
    out = _cli("fit", "--scene", path, "--point", 0, 0, 5)
    assert out.returncode == 2 and "from the nearest scanned point" in out.stderr
    assert "units" not in out.stderr


def test_station_scene_refuses_a_bad_file_in_one_line(tmp_path):
    bad = tmp_path / "broken.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 5\nend_header\n1 2\n")
    for args in (
        ["--scene", bad],
        ["--scene", tmp_path / "missing.pcd"],
        ["--scene", bad, "--demo"],
    ):
        out = _cli("station", *args, "--port", free_port(), "--out", tmp_path / "out", timeout=120)
        lines = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(lines) == 1 and "error" in lines[0], out.stderr
    assert not (tmp_path / "out").exists()


def test_station_on_a_millimetre_ply_in_a_real_browser(
    tmp_path, mm_scan, library, panel_scene, ros_context
):
    missing = chromium_missing()
    assert not missing, missing
    path, obj = mm_scan
    port = free_port()
    out_dir = tmp_path / "out"
    station = NodeProcess(
        [
            *CLI,
            "station",
            "--scene",
            str(path),
            "--units",
            "mm",
            "--up=-y",
            "--port",
            str(port),
            "--out",
            str(out_dir),
        ],
        tmp_path / "station.log",
    )
    client = Client("station_scene_test")
    try:
        client.subscribe(PoseStamped, "/view_pose", keep=True)
        assert station.wait_output("operator station: http", 180), station.output()
        assert "scan_mm.ply (in mm) are running" in station.output()
        # the URL the command prints holds the station's access secret
        url = re.search(r"operator station: (http://\S+)", station.output()).group(1)
        assert url.startswith(f"http://127.0.0.1:{port}/?token=")
        with browser_page(url) as page:
            wait_text(page, r"Engine: /affordance_engine — idle")
            wait_text(page, r"points in 'scan'")
            view = settled_view(client)
            assert view.header.frame_id == "scan"
            T_view = pose_to_matrix(view.pose)
            # the panel says "Fitting" while the engine works on the click (seen by the page)
            page.evaluate(SAW_FITTING)
            xy = pixel(T_view, 60.0, canvas_box(page), obj.click)  # metres on the page
            assert on_canvas(page, xy), f"the object's pixel {xy} is not on the 3D view"
            page.mouse.click(*xy)
            wait_text(page, rf"Shown: #1 {obj.template}\b.*rank 1/\d+ — fits, \d+\.\dx the next")
            assert page.evaluate("window.__sawFitting === true")
            node_log = out_dir / "station_scene.log"  # every node's output
            # the "fitting…" marker only for a fit slower than fitting_marker_delay (0.5 s):
            # whether this one was depends on the machine's load; drawn, it went again
            log = node_log.read_text()
            assert log.count("fitting marker shown") <= 1
            if "fitting marker shown" in log:
                wait_until(
                    lambda: "fitting marker cleared" in node_log.read_text(),
                    60,
                    "the fitting marker cleared",
                )
            assert "Fitting:" not in page.locator("body").inner_text()
            page.get_by_role("button", name="Accept", exact=True).click()
            wait_text(page, r"Objects: 0 open, 1 registered")

            # bare panel wall: the best guess is labelled and drawn as refused, and accepting
            # it is an operator override
            wall = bare_wall_point(panel_scene)
            xy = pixel(T_view, 60.0, canvas_box(page), wall)
            assert on_canvas(page, xy), f"the wall's pixel {xy} is not on the 3D view"
            page.mouse.click(*xy)
            wait_text(page, r"Shown: #2 no template fits here — best guess \w+.* — rank 1/\d+")
            wait_text(page, r"Verdict: the shown candidate is refused")
            # unsettled, and the engine suggests a view -- but nothing moves the sensor of a
            # scan read from a file: no "Move sensor here"; it comes when something subscribes
            # to the request, and goes with it
            wait_text(page, r"Unsettled: .*suggested view: look from")
            button = page.get_by_role("button", name="Move sensor here", exact=True)
            assert not button.is_visible()
            mover = client.node.create_subscription(
                PoseStamped, "/sensor_view_request", lambda msg: None, 10
            )
            button.wait_for(state="visible", timeout=60_000)
            client.node.destroy_subscription(mover)
            button.wait_for(state="hidden", timeout=60_000)
            wait_until(
                lambda: "drawn as refused outlines: objects [2]" in node_log.read_text(),
                60,
                "the refused candidate drawn as an outline",
            )
            page.get_by_role("button", name="Accept", exact=True).click()
            wait_text(page, r"accept: ok — accepted \w+ as object 2 as an operator override")
            page.get_by_role("button", name="Save", exact=True).click()
            wait_text(page, r"save: ok — saved 2 registration")
        saved = yaml.safe_load((out_dir / "registrations.yaml").read_text())["registrations"]
        assert [r["template"] for r in saved][0] == obj.template
        assert [r["override"] for r in saved] == [False, True]
        dt, dr = pose_error(
            np.asarray(saved[0]["pose"], dtype=float),
            obj.T_scene_model,
            library[obj.template].symmetry,
        )
        assert dt <= POSE_TOL_M and dr <= POSE_TOL_RAD, (
            f"{dt * 1000:.1f} mm, {math.degrees(dr):.1f} deg"
        )
    finally:
        client.close()
        code, _ = station.interrupt(timeout=60)
        station.kill()
    assert code == 0, station.output()[-3000:]
