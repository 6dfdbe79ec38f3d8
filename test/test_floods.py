# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Floods are bounded: a real engine process flooded with clicks and huge strings over real topics
keeps answering the operator's service calls, with bounded memory and a bounded status."""

import os
import threading
import time

import pytest
from geometry_msgs.msg import PointStamped
from ros_helpers import engine_session, rss_mb
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from affordance_registration.core.operator import OperatorStream
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import xyz_to_pointcloud2

FRAME = "camera_depth_optical_frame"
NS = "/affordance_engine"


@pytest.fixture(scope="module")
def flooded(ros_context, tmp_path_factory, library):
    tmp = tmp_path_factory.mktemp("floods")
    # every fit takes at least 1 s (the engine node with a slow fitter): clicks at 10 Hz pile
    # up behind it
    with engine_session(
        tmp,
        {},
        "flood_tester",
        {
            "points": (PointCloud2, "/points", 1),
            "click": (PointStamped, "/clicked_point", 200),
            "select": (String, f"{NS}/select_model", 10),
            "cloud_bad": (PointCloud2, "/points", 1),
        },
        slow_fit_s=1.0,
        sim=simulate_taskboard(library, 7),
    ) as s:
        s["pubs"]["points"].publish(xyz_to_pointcloud2(s["sim"].organized, FRAME))
        s["client"].wait_for(
            lambda: (s["client"].status() or {}).get("node", {}).get("cloud"), 30, "the cloud"
        )
        yield s


def _click(obj, frame=FRAME):
    msg = PointStamped()
    msg.header.frame_id = frame
    msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
    return msg


def test_a_click_flood_leaves_a_service_call_answered_and_memory_bounded(flooded):
    s = flooded
    client, objs = s["client"], s["sim"].objects
    pid = s["proc"].proc.pid
    stop = threading.Event()
    sent = [0]
    peak = {"queued": 0, "rss": 0.0}

    def flood():
        for k in range(150):  # 150 clicks in 15 s from one client
            if stop.is_set():
                return
            s["pubs"]["click"].publish(_click(objs[k % 5]))
            sent[0] += 1
            st = client.status() or {}
            peak["queued"] = max(peak["queued"], st.get("node", {}).get("queued", 0))
            peak["rss"] = max(peak["rss"], rss_mb(pid))
            time.sleep(0.1)

    thread = threading.Thread(target=flood)
    thread.start()
    try:
        client.wait_for(lambda: sent[0] >= 40, 60, "the flood to be under way")
        t0 = time.monotonic()
        # answered in its turn: behind the fit under way and the click it acts on (the queue is
        # bounded, asserted below), not after the flood. The bound is an event wait, generous for
        # a busy machine (idle it answers in a few seconds); it raises if unanswered.
        res = client.call(Trigger, f"{NS}/next_model", timeout=90.0)
        answered_s = time.monotonic() - t0
        assert res.message, res
        print(f"next_model answered in {answered_s:.1f} s during the flood: {res.message}")
    finally:
        thread.join()
        stop.set()

    def finished():
        st = client.status() or {}
        node = st.get("node", {})
        return node.get("idle") and node["handled"].get("/clicked_point") == 150 and st

    st = client.wait_for(
        finished, 120, f"the engine to finish the flood ({(client.status() or {}).get('node')})"
    )
    assert peak["rss"] < 1024 and rss_mb(pid) < 1024
    assert peak["queued"] <= 4, peak
    handled = st["node"]["handled"]["/clicked_point"]
    assert handled == 150  # every click accounted for: fitted or superseded
    assert len(st["objects"]) < 40  # most were superseded before their fit started
    assert "superseded by a newer click" in s["proc"].output()


def test_huge_names_are_refused_and_the_status_stays_small(flooded):
    s = flooded
    client = s["client"]
    s["pubs"]["select"].publish(String(data="x" * (10 * 1024 * 1024)))
    client.wait_for(
        lambda: "select model refused" in client.status()["node"]["last_error"], 60, "the refusal"
    )
    s["pubs"]["click"].publish(_click(s["sim"].objects[0], frame="f" * (10 * 1024 * 1024)))
    client.wait_for(
        lambda: "click refused: its frame id" in client.status()["node"]["last_error"],
        60,
        "the click's refusal",
    )
    bad = xyz_to_pointcloud2(s["sim"].organized[:10, :10], "c" * (1024 * 1024))
    s["pubs"]["points"].publish(bad)
    client.wait_for(
        lambda: "dropped a PointCloud2" in client.status()["node"]["last_error"],
        60,
        "the cloud's refusal",
    )
    # a name the engine does not know, of a size it takes: echoed bounded
    s["pubs"]["select"].publish(String(data="y" * 250))
    time.sleep(0.5)
    msg = client.latest[f"{NS}/status"]
    assert len(msg.data) < 100_000
    time.sleep(1.0)
    assert os.path.getsize(s["proc"].log_path) < 1_000_000
    assert client.call(Trigger, f"{NS}/refit", timeout=30).message  # still answering


class _Engine:
    views_due = 0

    class state:
        registered = ()


def test_clicks_supersede_only_clicks_nothing_depends_on():
    stream = OperatorStream(_Engine())
    stream.click([0, 0, 1], source="a")
    stream.click([0, 0, 2], source="a")  # two quick clicks: both kept
    stream.view([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], source="v")
    stream.click([0, 0, 3], source="a")  # supersedes the second (only a view between)
    stream.click([0, 0, 4], source="b")  # another source: kept
    stream.click([0, 0, 5], source="b")
    stream.action("accept", source="s")
    stream.click([0, 0, 6], source="b")  # the accept belongs to b's click 5: kept
    kinds = [
        (i.kind, i.source, float(i.point[2]) if i.kind == "click" else None) for i in stream._queue
    ]
    assert kinds == [
        ("click", "a", 1.0),
        ("view", "v", None),
        ("click", "a", 3.0),
        ("click", "b", 4.0),
        ("click", "b", 5.0),
        ("action", "s", None),
        ("click", "b", 6.0),
    ]
    assert stream.status()["handled"] == {"a": 1}
