# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Measure the browser station's latencies (not a test; run it by hand):

    .venv/bin/python test/station_latency.py [--clicks N] [--clouds N]
        [--screenshot docs/station.png]

* click -> label: a click on an object's pixel in headless chromium until the page shows that
  click's label (the fit included), on the page's own clock (pointerdown -> the text in the
  DOM), over the objects of simulated taskboards; split into the engine's part (clicked_point
  -> its status, heard by this process) and the rest (browser, station);
* cloud -> page: a 1M-point cloud published until the page shows its stamp (conversion,
  thinning to the display budget, websocket transfer and the browser's update included; the
  moment the text appeared in the DOM, not when Playwright noticed).

The engine node, the simulated scan and the station run as separate processes, as in the
browser test. Prints the medians. ``--screenshot PATH`` instead writes the README's picture
(docs/station.png):
two objects accepted, a third one shown.
"""

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="ar_roslog_"))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from browser_helpers import (  # noqa: E402
    browser_page,
    canvas_box,
    free_port,
    on_canvas,
    pixel,
    scan_argv,
    settled_view,
    station_argv,
    station_url,
    wait_text,
)
from geometry_msgs.msg import PointStamped, PoseStamped  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from ros_helpers import LATCHED, Client, NodeProcess, engine_process  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from affordance_registration.core.templates import TemplateLibrary  # noqa: E402
from affordance_registration.evaluation.browser_latency import OBSERVE  # noqa: E402
from affordance_registration.evaluation.simulation import simulate_taskboard  # noqa: E402
from affordance_registration.ros.glue.conversions import pose_to_matrix, xyz_to_pointcloud2  # noqa: E402

FRAME = "camera_depth_optical_frame"


def screenshot(page, T_view, box, library, args) -> int:
    """The README's picture: two objects accepted (blue), a third one shown with its label and
    gizmo."""
    sim = simulate_taskboard(library, args.seed)
    objs = sorted(
        (
            o
            for o in sim.objects
            if o.click is not None
            and o.visible_points >= 200
            and on_canvas(page, pixel(T_view, 60.0, box, o.click))
        ),
        key=lambda o: -o.visible_points,
    )[:3]
    for k, obj in enumerate(objs, start=1):
        page.mouse.click(*pixel(T_view, 60.0, box, obj.click))
        wait_text(page, rf"Shown: #{k} ")
        if k < len(objs):
            page.get_by_role("button", name="Accept", exact=True).click()
            wait_text(page, rf"{k} registered")
    try:  # the browser's notice about software WebGL is not part of the station
        note = page.get_by_text("Software WebGL rendering detected")
        note.wait_for(timeout=10000)
        note.locator("xpath=ancestor::*[.//button][1]").locator("button").first.click()
        note.wait_for(state="hidden", timeout=10000)
    except Exception as exc:
        print(f"(the software-WebGL notice stays: {exc!r})"[:200])
    time.sleep(3.0)
    page.screenshot(path=args.screenshot)
    print(f"wrote {args.screenshot}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clicks", type=int, default=10)
    ap.add_argument("--clouds", type=int, default=5)
    ap.add_argument("--display-points", type=int, default=60000)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--screenshot", default=None)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="ar_station_latency_"))
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    port = free_port()
    procs = [
        NodeProcess(scan_argv(seed=args.seed), tmp / "scan.log"),
        engine_process(tmp),
        NodeProcess(station_argv(port, display_points=args.display_points), tmp / "station.log"),
    ]
    client = Client("station_latency")
    client.subscribe(PoseStamped, "/view_pose", keep=True)
    heard = {}  # when the click and the status with its object reached this process
    client.node.create_subscription(
        PointStamped, "/clicked_point", lambda m: heard.setdefault("click", time.monotonic()), 10
    )

    def on_status(msg):
        st = json.loads(msg.data)
        if any(o["id"] == heard.get("object") for o in st.get("objects", [])):
            heard.setdefault("status", time.monotonic())

    client.node.create_subscription(String, "/affordance_engine/status", on_status, LATCHED)
    library = TemplateLibrary.load()
    try:
        assert procs[2].wait_output("operator station on", 90), procs[2].output()
        with browser_page(station_url(port)) as page:
            wait_text(page, r"Engine: /affordance_engine — idle")
            wait_text(page, rf"points in '{FRAME}'")
            view = settled_view(client)
            T_view = pose_to_matrix(view.pose)
            box = canvas_box(page)
            if args.screenshot:
                return screenshot(page, T_view, box, library, args)
            clicks, parts, k, seed = [], [], 0, args.seed
            while len(clicks) < args.clicks:
                sim = simulate_taskboard(library, seed)
                if seed != args.seed:  # the next scene, as a new cloud
                    pub = client.node.create_publisher(PointCloud2, "/points", 1)
                    client.wait_for_subscribers(pub, 2)
                    pub.publish(xyz_to_pointcloud2(sim.organized, FRAME))
                    wait_text(page, rf"{len(sim.points):,} points in")
                    time.sleep(1.0)
                for obj in sim.objects:
                    if obj.click is None or obj.visible_points < 200 or len(clicks) >= args.clicks:
                        continue
                    xy = pixel(T_view, 60.0, box, obj.click)
                    if not on_canvas(page, xy):  # under the panel: not clickable
                        continue
                    k += 1
                    heard.clear()
                    heard["object"] = k
                    page.evaluate(OBSERVE, f"Shown: #{k} ")
                    t0 = time.monotonic()
                    page.mouse.click(*xy)
                    wait_text(page, rf"Shown: #{k} ")
                    # when the page showed it: the page's own clock (a mutation observer), not
                    # Playwright's polling
                    clicks.append(page.evaluate("window.__arShown - window.__arClick") / 1000)
                    engine = heard["status"] - heard["click"]
                    parts.append((engine, clicks[-1] - engine))
                    print(
                        f"click {k} ({obj.template}): label after {clicks[-1]:.2f} s (engine: "
                        f"clicked_point -> status {engine:.2f} s; page and station: "
                        f"{clicks[-1] - engine:.2f} s)",
                        flush=True,
                    )
                    time.sleep(0.5)
                seed += 1
            if args.screenshot:
                page.screenshot(path=args.screenshot)
            pub = client.node.create_publisher(PointCloud2, "/points", 1)
            client.wait_for_subscribers(pub, 2)
            rng = np.random.default_rng(0)
            base = sim.points
            big = np.vstack(
                [
                    base + rng.normal(scale=0.001, size=base.shape)
                    for _ in range(math.ceil(1_000_000 / len(base)))
                ]
            )[:1_000_000]
            msg = xyz_to_pointcloud2(big.astype(np.float32), FRAME)
            clouds = []
            for i in range(args.clouds):
                time.sleep(1.5)
                msg.header.stamp.sec, msg.header.stamp.nanosec = 1000 + i, 0
                page.evaluate(OBSERVE, f"stamp {1000 + i}.000")
                t0 = time.monotonic()
                pub.publish(msg)
                wait_text(page, rf"1,000,000 points in .*stamp {1000 + i}\.000")
                shown_after = (
                    time.monotonic()
                    - t0
                    - page.evaluate("(performance.now() - window.__arShown) / 1000")
                )
                clouds.append(shown_after)
                print(f"1M cloud {i + 1}: on the page after {clouds[-1]:.2f} s", flush=True)
        print(
            f"click -> label: median {statistics.median(clicks):.2f} s over {len(clicks)} "
            f"clicks (min {min(clicks):.2f}, max {max(clicks):.2f})"
        )
        print(
            "click -> label, medians of its parts: the engine (clicked_point -> its status, "
            "the fit included) %.2f s, the page and the station (the rest) %.2f s"
            % tuple(statistics.median(p[i] for p in parts) for i in range(2))
        )
        print(
            f"1M-point cloud -> page: median {statistics.median(clouds):.2f} s over "
            f"{len(clouds)} clouds (min {min(clouds):.2f}, max {max(clouds):.2f}); display "
            f"budget {args.display_points} points"
        )
    finally:
        client.close()
        for p in procs:
            p.interrupt(timeout=10)
            p.kill()
        rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
