# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The browser station's click -> label over the live graph (the bench's browser row).

The engine node (from the package's launch file) and the operator station run in their own
processes; this process publishes simulated taskboard clouds and drives a headless Chromium
(Debian's ``chromium``, through Playwright: the test extras) at the station's page. For each
click on an object's pixel it measures, on the page's own clock, the time from the mouse press
to the moment the page shows that click's label ("Shown: #k ..."; a mutation observer, not
Playwright's polling): the fit, the engine's status, the station and the browser's update
included. The engine's part (``/clicked_point`` -> the status that shows the fit, as heard by
this process) is reported beside it. Each click is made on a page at rest, as an operator's is:
once the station has sent the previous fit's meshes and the page has drawn no frame for
QUIET_MS (clicked into the frames of the result just shown, a click on software WebGL waited for
them).

Without Playwright or the browser the row is left out with its reason
(:func:`chromium_missing`). The station's browser tests share this module's launch settings and
page geometry (test/browser_helpers.py).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass

import numpy as np

__all__ = [
    "CHROMIUM",
    "CHROMIUM_ARGS",
    "VIEWPORT",
    "BrowserSession",
    "Heard",
    "browser_session",
    "at_sensor",
    "chromium_missing",
    "measure_browser_latency",
    "on_canvas",
    "open_details",
    "page_pixel",
    "settle",
    "show_cloud",
    "station_command",
    "station_process",
    "wait_listening",
    "wait_page_text",
]

CHROMIUM = os.environ.get("AFFORDANCE_CHROMIUM", "/usr/bin/chromium")
#: headless Chromium with software WebGL (no GPU here), nothing fetched from the network
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
VIEWPORT = {"width": 1100, "height": 700}
#: the page camera's vertical field of view (deg), as the station draws it
FOV_DEG = 60.0
#: records on the page when a text first appears (window.__arShown, ms) and when the next mouse
#: press happened (window.__arClick)
OBSERVE = """text => {
  if (window.__arObserver) window.__arObserver.disconnect();
  window.__arShown = null; window.__arClick = null;
  document.addEventListener('pointerdown', () => { window.__arClick ??= performance.now(); },
                            {once: true, capture: true});
  const seen = () => { if (window.__arShown === null && document.body.innerText.includes(text))
                         window.__arShown = performance.now(); };
  window.__arObserver = new MutationObserver(seen);
  window.__arObserver.observe(document.body,
                                     {subtree: true, childList: true, characterData: true});
}"""

#: resolves once the page's main thread has run no long task (a drawn frame, on software WebGL)
#: for ``ms`` milliseconds (a check that ran late counts as one: the thread was held)
QUIET = """ms => new Promise(resolve => {
  let last = performance.now(), prev = last;
  const seen = new PerformanceObserver(list => { for (const e of list.getEntries())
    last = Math.max(last, e.startTime + e.duration); });
  seen.observe({type: 'longtask'});
  const check = () => {
    const now = performance.now();
    if (now - prev > 100) last = now;
    prev = now;
    if (now - last >= ms) { seen.disconnect(); resolve(); } else setTimeout(check, 25);
  };
  setTimeout(check, 25);
})"""
#: the page counts as settled after this long without a drawn frame (ms)
QUIET_MS = 300
#: the station's output, in the row's folder (what it draws is read from it)
STATION_LOG = "station.log"


def chromium_missing(chromium: str = CHROMIUM) -> str:
    """'' when a headless Chromium can be driven here, else why not (one line)."""
    if not os.access(chromium, os.X_OK):
        return (
            f"{chromium} not found: `make test` installs Debian's chromium (as root), or "
            f"apt-get install chromium (AFFORDANCE_CHROMIUM names another)"
        )
    try:
        import playwright  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install -e '.[test]')"
    return ""


def station_command(port: int, secret: str | None, **params) -> list[str]:
    """The operator station's command line on ``port`` with ``access_secret`` (None: none
    given, a random one per start) and more ROS parameters."""
    argv = [
        sys.executable,
        "-m",
        "affordance_registration.ros.station.node",
        "--ros-args",
        "-p",
        f"port:={port}",
    ]
    if secret is not None:
        argv += ["-p", f"access_secret:={secret}"]
    for key, value in params.items():
        argv += ["-p", f"{key}:={value}"]
    return argv


def page_pixel(T_world_optical, box: dict, point, fov_deg: float = FOV_DEG) -> tuple[float, float]:
    """Page coordinates of a world point seen through the page's camera (``box``: the canvas's
    bounding box on the page)."""
    from ..core.display import project

    uv = project(
        T_world_optical,
        math.radians(fov_deg),
        box["width"],
        box["height"],
        np.asarray(point, dtype=float)[None],
    )[0]
    return float(box["x"] + uv[0]), float(box["y"] + uv[1])


def on_canvas(page, xy: tuple) -> bool:
    """Whether the page point shows the 3D view (not the panel or the edge of the page)."""
    if not all(math.isfinite(v) for v in xy):  # behind the camera
        return False
    return bool(
        page.evaluate(
            "([x, y]) => { const e = document.elementFromPoint(x, y); "
            "return e !== null && e.tagName === 'CANVAS'; }",
            list(xy),
        )
    )


def at_sensor(T: np.ndarray) -> bool:
    """The station's first view of a cloud in a sensor frame: on the line through the frame's
    origin along the camera's z axis, at or behind the origin."""
    p, z = T[:3, 3], T[:3, 2]
    return bool(np.linalg.norm(np.cross(p, z)) < 1e-3 and p @ z <= 1e-6)


class Heard:
    """What this process hears: the station's camera (``/view_pose``), when a click and the
    status that shows a given object arrived, and how many clouds the engine has received (its
    status: the station shows a cloud from its own subscription, and a click the engine gets
    before the cloud is refused)."""

    def __init__(self, node, status_topic: str):
        from geometry_msgs.msg import PointStamped, PoseStamped
        from std_msgs.msg import String

        from ..ros.glue.qos import LATCHED

        self._cv = threading.Condition()
        self.views: list = []
        self.times: dict = {}
        self.expect: int | None = None
        self.clouds = 0
        node.create_subscription(PoseStamped, "/view_pose", self._on_view, 10)
        node.create_subscription(PointStamped, "/clicked_point", self._on_click, 10)
        node.create_subscription(String, status_topic, self._on_status, LATCHED)

    def _on_view(self, msg):
        from ..ros.glue.conversions import pose_to_matrix

        with self._cv:
            self.views.append((time.monotonic(), pose_to_matrix(msg.pose)))
            self._cv.notify_all()

    def _on_click(self, msg):
        with self._cv:
            self.times.setdefault("click", time.monotonic())

    def _on_status(self, msg):
        st = json.loads(msg.data)
        ids = {o.get("id") for o in st.get("objects", [])}
        cloud = (st.get("node") or {}).get("cloud") or {}
        with self._cv:
            if self.expect in ids:
                self.times.setdefault("status", time.monotonic())
            self.clouds = max(self.clouds, int(cloud.get("received", 0)))
            self._cv.notify_all()

    def engine_holds(self, clouds: int, timeout_s: float = 90.0) -> None:
        """Wait until the engine has received more than ``clouds`` clouds."""
        with self._cv:
            if not self._cv.wait_for(lambda: self.clouds > clouds, timeout_s):
                raise TimeoutError("the engine did not receive the cloud")

    def arm(self, object_id: int) -> None:
        with self._cv:
            self.times, self.expect = {}, object_id

    def settled_view(self, timeout_s: float = 90.0) -> np.ndarray:
        """The page's camera once it stands at the sensor (or behind it along its view) and has
        sent nothing new for a second."""
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while True:
                if (
                    self.views
                    and at_sensor(self.views[-1][1])
                    and time.monotonic() - self.views[-1][0] >= 1.0
                ):
                    return self.views[-1][1]
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError("the page's camera did not settle at the sensor")
                self._cv.wait(min(left, 0.2))


def show_cloud(page, pub, msg, shown: str, timeout_s: float = 120.0, every_s: float = 10.0):
    """Publish the cloud ``msg`` until the page shows it (the text ``shown``): once the engine
    and the station both read the topic, and again while the page has not shown it -- their
    cloud readers are volatile (best effort where ``points_reliable`` is off), so one cloud
    published before they matched, or one a best-effort reader dropped, never reaches them; a
    sensor's stream would send the next."""
    deadline = time.monotonic() + timeout_s
    while pub.get_subscription_count() < 2:  # the engine's reader and the station's
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"{pub.get_subscription_count()} of the engine and the station "
                f"read the cloud topic after {timeout_s:.0f} s"
            )
        time.sleep(0.05)
    while True:
        pub.publish(msg)
        left = deadline - time.monotonic()
        try:  # (never 0: Playwright's timeout 0 waits for ever)
            return wait_page_text(page, shown, min(every_s, max(left, 1.0)))
        except TimeoutError:
            if time.monotonic() + 1.0 >= deadline:
                raise


def wait_page_text(page, pattern: str, timeout_s: float = 120.0) -> None:
    """Wait until the page shows ``pattern`` (a regular expression); a TimeoutError that says
    what the page showed instead."""
    import re

    from playwright.sync_api import TimeoutError as PageTimeout

    try:
        page.get_by_text(re.compile(pattern)).first.wait_for(
            state="visible", timeout=timeout_s * 1000
        )
    except PageTimeout:
        shown = " | ".join(page.inner_text("body").split("\n"))[:300]
        raise TimeoutError(
            f"the page did not show {pattern!r} in {timeout_s:.0f} s; it showed: {shown}"
        ) from None


def open_details(page) -> None:
    """Open the panel's Details folder: the engine's state, the shown candidate's full label,
    the cloud and the last reply (the headline above it says one sentence)."""
    import re

    from ..ros.station.page import DETAILS

    page.get_by_text(DETAILS, exact=True).first.click()
    page.get_by_text(re.compile(r"^Engine")).first.wait_for(state="visible")


def settle(page, out_dir: str, drawn: int, timeout_s: float = 30.0) -> None:
    """Wait until the station has logged drawing object ``drawn`` (0: none yet) and then the
    page has drawn no frame for QUIET_MS: the next click lands on a page at rest, as an
    operator's does, not in the frames of the result just shown (on software WebGL each holds
    the page's main thread for 100-400 ms). A station that never logs it is waited for
    ``timeout_s``, not for ever."""
    path = os.path.join(out_dir, STATION_LOG)
    deadline = time.monotonic() + timeout_s
    while drawn and time.monotonic() < deadline:
        with open(path, errors="replace") as f:
            if f"drawn: object {drawn} as" in f.read():
                break
        time.sleep(0.05)
    page.evaluate(QUIET, QUIET_MS)


@contextlib.contextmanager
def station_process(port: int, secret: str, out_dir: str, params: dict):
    log = open(os.path.join(out_dir, STATION_LOG), "w")
    proc = subprocess.Popen(
        station_command(port, secret, **params), stdout=log, stderr=subprocess.STDOUT
    )
    try:
        yield proc
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(2)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def wait_listening(port: int, proc, timeout_s: float = 90.0) -> None:
    import socket

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the station exited ({proc.returncode}) before it served a page")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
            return
        time.sleep(0.1)
    raise TimeoutError("the station served no page")


@dataclass
class BrowserSession:
    """A live engine node and station, a headless Chromium at the station's page (its details
    open) and this process's ROS node: what it hears (``heard``) and its cloud publisher
    (``points``, latched)."""

    node: object
    heard: Heard
    points: object
    page: object
    out_dir: str


@contextlib.contextmanager
def browser_session(out_dir: str, display_points: int = 60000, chromium: str = CHROMIUM):
    """A :class:`BrowserSession`: the engine from the package's launch file (its registrations
    in ``out_dir``), the station in its own process, Chromium with a fresh profile; all stopped
    at the end. Raise where no browser can be driven (:func:`chromium_missing`)."""
    missing = chromium_missing(chromium)
    if missing:
        raise RuntimeError(missing)
    import secrets
    import socket

    from playwright.sync_api import sync_playwright
    from sensor_msgs.msg import PointCloud2

    from ..ros.glue.qos import LATCHED
    from ..ros.standins.spin import background_node
    from .session import NS, start_engine

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    secret = secrets.token_urlsafe(24)
    profile = tempfile.mkdtemp(prefix="ar_chromium_")
    launcher = start_engine(out_dir)
    try:
        with (
            background_node("affordance_browser_bench") as node,
            station_process(port, secret, out_dir, {"display_points": display_points}) as station,
            sync_playwright() as pw,
        ):
            heard = Heard(node, f"{NS}/status")
            pub = node.create_publisher(PointCloud2, "/points", LATCHED)
            wait_listening(port, station)
            ctx = pw.chromium.launch_persistent_context(
                profile,
                executable_path=chromium,
                headless=True,
                args=CHROMIUM_ARGS,
                viewport=VIEWPORT,
            )
            try:
                page = ctx.new_page()
                page.set_default_timeout(120_000)
                page.goto(f"http://127.0.0.1:{port}/?token={secret}")
                open_details(page)
                wait_page_text(page, f"Engine: {NS} — idle")
                yield BrowserSession(node, heard, pub, page, out_dir)
            finally:
                ctx.close()
    finally:
        launcher.stop()
        shutil.rmtree(profile, ignore_errors=True)


def measure_browser_latency(
    seeds,
    max_clicks: int,
    out_dir: str,
    log=print,
    display_points: int = 60000,
    chromium: str = CHROMIUM,
) -> dict | None:
    """Click the objects of the simulated taskboards ``seeds`` (up to ``max_clicks``, each
    object with at least 200 visible points that the page shows) in a headless Chromium at a
    live station, and measure click -> label (module docstring). None where no browser can be
    driven here (:func:`chromium_missing` says why)."""
    if chromium_missing(chromium):
        log(f"  browser row left out: {chromium_missing(chromium)}")
        return None
    from ..core.templates import TemplateLibrary
    from .session import FRAME, cloud_message
    from .simulation import simulate_taskboard

    library = TemplateLibrary.load()
    clicks, engine, templates, right = [], [], [], 0
    with browser_session(out_dir, display_points, chromium) as b:
        page, heard = b.page, b.heard
        k, T_view, box = 0, None, None
        for seed in seeds:
            if len(clicks) >= max_clicks:
                break
            sim = simulate_taskboard(library, seed)
            n_points = int(np.all(np.isfinite(sim.organized.reshape(-1, 3)), axis=1).sum())
            clouds = heard.clouds
            show_cloud(
                page,
                b.points,
                cloud_message(sim.organized.reshape(-1, 3)),
                rf"{n_points:,} points in '{FRAME}'",
            )
            heard.engine_holds(clouds)
            T_view = heard.settled_view()
            box = page.locator("canvas").first.bounding_box()
            for obj in sim.objects:
                if obj.click is None or obj.visible_points < 200 or len(clicks) >= max_clicks:
                    continue
                xy = page_pixel(T_view, box, obj.click)
                if not on_canvas(page, xy):  # under the panel: not clickable
                    continue
                k += 1
                heard.arm(k)
                # an operator clicks a page that shows the last result: wait until the
                # station has sent the last fit's meshes and the page has drawn them
                settle(page, out_dir, k - 1)
                page.evaluate(OBSERVE, f"Shown: #{k} ")
                page.mouse.click(*xy)
                wait_page_text(page, rf"Shown: #{k} ")
                clicks.append(page.evaluate("window.__arShown - window.__arClick") / 1000)
                shown = page.get_by_text(f"Shown: #{k} ").first.inner_text()
                templates.append(shown)
                right += obj.template in shown
                t = heard.times
                part = ""
                if "click" in t and "status" in t:
                    engine.append(t["status"] - t["click"])
                    part = f" (the engine's part {engine[-1]:.2f} s)"
                log(f"  browser click {k} ({obj.template}): label after {clicks[-1]:.2f} s{part}")
    return {
        "clicks": len(clicks),
        "click_to_label_s": statistics.median(clicks) if clicks else None,
        "click_to_label_max_s": max(clicks) if clicks else None,
        "engine_click_to_status_s": statistics.median(engine) if engine else None,
        "labels": templates,
        "true_template_named": right,
        "display_points": display_points,
    }
