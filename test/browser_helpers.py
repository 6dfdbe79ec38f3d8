# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A real browser for the station's tests: Debian's chromium (headless, software WebGL) driven by
Playwright, with a fresh profile each time. Playwright's own browser download is not used."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import sys
import tempfile
import time
from html.parser import HTMLParser

from affordance_registration.evaluation.browser_latency import (  # noqa: E402,F401
    CHROMIUM,
    VIEWPORT,
    at_sensor,
    chromium_missing,
    on_canvas,
    open_details,
    page_pixel,
    station_command,
)
from affordance_registration.evaluation.browser_latency import CHROMIUM_ARGS as ARGS  # noqa: E402


class _PanelHTML(HTMLParser):
    """The tags and the text of a rendered panel."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tags: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)

    def handle_data(self, data):
        self.text.append(data)


def rendered_panel(markdown: str) -> tuple[set[str], str]:
    """(the HTML tags, the text with runs of white space as one space) of the station panel's
    ``markdown`` as a CommonMark renderer that passes raw HTML through (as viser's does) makes
    them: markdown-it, viser's dependency rich's own, with GFM's tables and strikethrough."""
    from markdown_it import MarkdownIt

    html = MarkdownIt("commonmark", {"html": True}).enable(["table", "strikethrough"])
    parsed = _PanelHTML()
    parsed.feed(html.render(markdown))
    parsed.close()
    return set(parsed.tags), " ".join("".join(parsed.text).split())


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def browser_page(url: str, timeout_s: float = 120.0, details: bool = True):
    """A page of a fresh headless chromium at ``url``, once the station's panel is there; with
    ``details``, its Details folder opened (the engine state, counts, cloud and last reply the
    tests read)."""
    from playwright.sync_api import sync_playwright

    profile = tempfile.mkdtemp(prefix="ar_chromium_")
    try:
        with sync_playwright() as p:
            ctx = p.chromium.launch_persistent_context(
                profile, executable_path=CHROMIUM, headless=True, args=ARGS, viewport=VIEWPORT
            )
            try:
                page = ctx.new_page()
                page.set_default_timeout(timeout_s * 1000)
                open_station(page, url)
                if details:
                    open_details(page)
                try:
                    yield page
                except BaseException:
                    shot = os.path.join(
                        tempfile.gettempdir(), f"ar_station_failure_{os.getpid()}.png"
                    )
                    with contextlib.suppress(Exception):
                        page.screenshot(path=shot)
                        sys.stderr.write(f"the page at the failure: {shot}\n")
                        sys.stderr.write(page.locator("body").inner_text()[:3000] + "\n")
                    raise
            finally:
                ctx.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def open_station(page, url: str) -> None:
    page.goto(url)
    page.get_by_text("Affordance station").first.wait_for()


def wait_text(page, pattern: str, timeout_s: float = 120.0):
    """The first visible element whose text matches the regular expression ``pattern``."""
    loc = page.get_by_text(re.compile(pattern)).first
    loc.wait_for(state="visible", timeout=timeout_s * 1000)
    return loc


def canvas_box(page) -> dict:
    return page.locator("canvas").first.bounding_box()


def pixel(T_world_optical, fov_deg: float, box: dict, point) -> tuple[float, float]:
    """Page coordinates of a world point seen through the page's camera."""
    return page_pixel(T_world_optical, box, point, fov_deg)


def drag(page, start: tuple, end: tuple, steps: int = 12) -> None:
    """Press at ``start``, move to ``end`` in steps, release (a person dragging)."""
    page.mouse.move(*start)
    page.mouse.down()
    for k in range(1, steps + 1):
        f = k / steps
        page.mouse.move(start[0] + f * (end[0] - start[0]), start[1] + f * (end[1] - start[1]))
        time.sleep(0.05)
    time.sleep(0.2)
    page.mouse.up()


#: the access secret the test stations are started with (see station_url)
STATION_SECRET = "test-station-secret-0123456789"


def station_url(port: int, secret: str = STATION_SECRET) -> str:
    """The URL an operator of a station started by :func:`station_argv` opens."""
    return f"http://127.0.0.1:{port}/?token={secret}"


def station_argv(port: int, **params) -> list[str]:
    return station_command(port, params.pop("access_secret", STATION_SECRET), **params)


def scan_argv(seed: int = 7, **params) -> list[str]:
    argv = [
        sys.executable,
        "-m",
        "affordance_registration.evaluation.simulated_scan",
        "--ros-args",
        "-p",
        f"seed:={seed}",
    ]
    for key, value in params.items():
        argv += ["-p", f"{key}:={value}"]
    return argv


def wait_until(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def settled_view(client, topic: str = "/view_pose", timeout_s: float = 90.0):
    """The page's camera once it stands at the sensor or behind it along its view (the
    station's first view of a cloud in a sensor frame) and has not moved for a second: the last
    ``view_pose`` a :class:`ros_helpers.Client` subscribed to ``topic`` (with ``keep=True``)
    heard."""
    from affordance_registration.ros.glue.conversions import pose_to_matrix

    def settled():
        hist = client.history.get(topic) or []
        if not hist or not at_sensor(pose_to_matrix(hist[-1].pose)):
            return None
        n = len(hist)
        time.sleep(1.0)
        return hist[-1] if len(client.history[topic]) == n else None

    return wait_until(settled, timeout_s, "the page's camera at the sensor")
