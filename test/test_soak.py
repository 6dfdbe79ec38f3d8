# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A soak (marked long: run with AFFORDANCE_LONG_TESTS=1; AFFORDANCE_SOAK_S sets its length, 600 s
by default): a real engine process while clouds stream at 5 Hz, rounds of click, SpaceMouse push,
cycle, and accept / undo / discard. Every call is answered, memory is flat after the warm-up,
and no registration is lost (the autosaved file and a restart after kill -9 agree)."""

import os
import signal
import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, Twist
from ros_helpers import LATCHED, Client, engine_process, rss_mb
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from affordance_registration.core.engine import load_registrations
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import xyz_to_pointcloud2

FRAME = "camera_depth_optical_frame"
NS = "/affordance_engine"
SOAK_S = float(os.environ.get("AFFORDANCE_SOAK_S", "600"))

pytestmark = pytest.mark.skipif(
    os.environ.get("AFFORDANCE_LONG_TESTS") != "1",
    reason="a long soak: run with AFFORDANCE_LONG_TESTS=1",
)


def test_soak(ros_context, tmp_path, library):
    sim = simulate_taskboard(library, 7)
    proc = engine_process(tmp_path, {"refit_idle_s": 0.4})
    client = Client("soak_tester")
    stop = threading.Event()
    try:
        client.subscribe(String, f"{NS}/status", LATCHED)
        points = client.node.create_publisher(PointCloud2, "/points", 1)
        clicks = client.node.create_publisher(PointStamped, "/clicked_point", 10)
        twists = client.node.create_publisher(Twist, "/spacenav/twist", 10)
        for pub in (points, clicks, twists):
            client.wait_for_subscribers(pub, timeout=60)
        cloud = xyz_to_pointcloud2(sim.organized, FRAME)

        def stream():  # 5 Hz, the whole soak
            while not stop.is_set():
                points.publish(cloud)
                time.sleep(0.2)

        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        status = lambda: client.status(f"{NS}/status") or {}  # noqa: E731
        client.wait_for(lambda: status().get("node", {}).get("cloud"), 60, "the cloud")
        objs = [o for o in sim.objects if o.click is not None and o.visible_points >= 200]
        t0 = time.monotonic()
        calls = answered = rounds = 0
        expected = 0  # registrations we were told about
        rss = []
        while time.monotonic() - t0 < SOAK_S:
            obj = objs[rounds % len(objs)]
            n = len(status().get("objects", []))
            msg = PointStamped()
            msg.header.frame_id = FRAME
            msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
            clicks.publish(msg)
            client.wait_for(
                lambda: len(status().get("objects", [])) > n or status().get("active_id"),
                120,
                "the click's object",
            )
            tw = Twist()
            tw.linear.y = -0.3
            for _ in range(8):
                twists.publish(tw)
                time.sleep(1 / 30)
            twists.publish(Twist())
            for name in (
                "next_model",
                "previous_model",
                ("accept", "undo", "accept", "discard")[rounds % 4],
            ):
                calls += 1
                res = client.call(Trigger, f"{NS}/{name}", timeout=120)
                answered += 1
                if res.success and name == "accept":
                    expected += 1
                if res.success and name == "undo" and res.message.startswith("undid accept"):
                    expected -= 1
            rounds += 1
            rss.append((time.monotonic() - t0, rss_mb(proc.proc.pid)))
        st = client.wait_for(
            lambda: status().get("node", {}).get("idle") and status(), 120, "the engine to settle"
        )
        registered = len(st["registered"])
        warm = [m for t, m in rss if t >= SOAK_S / 3]
        print(
            f"soak {SOAK_S:.0f} s: {rounds} rounds, {answered}/{calls} calls answered, "
            f"{registered} registered (expected {expected}); memory after warm-up "
            f"{min(warm):.0f}-{max(warm):.0f} MB, peak {max(m for _, m in rss):.0f} MB"
        )
        assert answered == calls and rounds >= 10
        assert registered == expected
        assert max(warm) - min(warm) < 150, "memory grows after the warm-up"
        assert len(load_registrations(str(tmp_path / "registrations.yaml"))) == expected
        os.killpg(proc.proc.pid, signal.SIGKILL)
        proc.proc.wait(timeout=10)
    finally:
        stop.set()
        client.close()
        proc.interrupt()
        proc.kill()
    again = engine_process(tmp_path, name="engine_again")
    client = Client("soak_restart")
    try:
        client.subscribe(String, f"{NS}/status", LATCHED)
        st = client.wait_for(lambda: client.status(f"{NS}/status"), 120, "the restart")
        assert len(st["registered"]) == expected
    finally:
        client.close()
        again.interrupt()
        again.kill()
    assert np.isfinite(expected)
