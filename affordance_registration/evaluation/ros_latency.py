# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine node's latencies over ROS, measured on the live graph (the bench's "over ROS"
row): the engine node runs from the package's launch file in its own process; this process
publishes simulated taskboard clouds and clicks, and hears ``~/status`` and ``~/markers`` as a
client does. For every click, on the same cloud and click, the same fit runs in this process on
the core engine (interleaved: node click, then the in-process one), so the row is a ratio on
one machine whatever its load:

* click -> status / in-process fit: from publishing the click to the ``~/status`` that shows
  its fit (the node's inputs handled), over the in-process ``AffordanceEngine.click`` on the same
  cloud and point (median of the per-click ratios); and the fit's own time in the node (the
  status's ``timing_s``) over the in-process one, which tells a fit slowed down in the node
  from work the node adds around it;
* status -> markers: from that status to the next ``~/markers`` message (median, ms);
* markers message size: the serialized size of each ``~/markers`` message (largest, and the
  one after the last accept, with that many objects shown);
* idle engine CPU: the node's CPU time over a quiet spell after the clicks (cores).
"""

from __future__ import annotations

import json
import os
import statistics
import threading
import time

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from ..core.engine import AffordanceEngine
from ..core.templates import TemplateLibrary
from ..ros.glue.conversions import pointcloud2_to_xyz
from ..ros.glue.qos import LATCHED
from ..ros.standins.spin import background_node
from .session import FRAME, NS, RosOperator, StatusWatch, cloud_message, start_engine
from .simulation import simulate_taskboard

__all__ = ["measure_node_latency", "MARKERS_TOPIC"]

MARKERS_TOPIC = f"{NS}/markers"


class _Arrivals:
    """Arrival times (monotonic s) of ``~/markers`` messages with their serialized sizes (bytes)
    and the objects whose candidate they draw, and of ``~/status`` messages with the selected
    object's id and whether the node had handled its inputs. A click's status and its markers
    are each found by what they show (an object not known before the click), not by the order
    the two callbacks ran in: on a loaded machine the markers' callback may run first.

    The markers are taken as they came (serialized) and read only when asked for: reading a
    MarkerArray of tens of objects into Python costs this process CPU that the node, fitting
    the click on the same cores, would otherwise lose to the measurement."""

    def __init__(self, node):
        self.markers: list[tuple[float, bytes]] = []
        self._drawn: dict[int, frozenset] = {}  # index -> candidates drawn (read once)
        self.status: list[tuple[float, int | None, bool, float | None]] = []
        self._cv = threading.Condition()
        node.create_subscription(MarkerArray, MARKERS_TOPIC, self._on_markers, LATCHED, raw=True)
        node.create_subscription(String, f"{NS}/status", self._on_status, LATCHED)

    def _on_status(self, msg):
        st = json.loads(msg.data)
        active = next((o["id"] for o in st.get("objects", []) if o.get("active")), None)
        fit_s = (st.get("timing_s") or {}).get("total")
        node = st.get("node") or {}
        # the inputs handled (a suggested view may still be due: it is not the click's)
        done = not (node.get("busy") or node.get("queued") or node.get("pending_refit"))
        with self._cv:
            self.status.append((time.monotonic(), active, done, fit_s))
            self._cv.notify_all()

    def _on_markers(self, raw: bytes):
        with self._cv:
            self.markers.append((time.monotonic(), raw))
            self._cv.notify_all()

    def _candidates(self, k: int) -> frozenset:
        """The objects whose candidate the ``k``-th markers message draws (read once)."""
        if k not in self._drawn:
            msg = deserialize_message(self.markers[k][1], MarkerArray)
            self._drawn[k] = frozenset(m.id for m in msg.markers if m.ns == "candidate")
        return self._drawn[k]

    def _first(self, pick, timeout: float):
        """What ``pick`` finds in the arrivals, waiting for new ones (up to ``timeout``)."""
        with self._cv:
            return self._cv.wait_for(pick, timeout)

    def status_showing(self, t0: float, known: set, timeout: float = 10.0) -> tuple | None:
        """(when it arrived, the node's fit time in it (s)) of the first status after ``t0``
        that selects an object not in ``known`` with the node's inputs handled (the status that
        shows a click's fit; a suggested view comes after it); waits up to ``timeout``."""
        return self._first(
            lambda: next(
                (
                    (t, fit_s)
                    for t, active, done, fit_s in self.status
                    if t >= t0 and done and active is not None and active not in known
                ),
                None,
            ),
            timeout,
        )

    def markers_showing(self, t0: float, known: set, timeout: float = 10.0) -> float | None:
        """When the first markers message after ``t0`` arrived that draws the candidate of an
        object not in ``known`` (the markers that show a click's fit); waits up to ``timeout``."""
        return self._first(
            lambda: next(
                (
                    t
                    for k, (t, _) in enumerate(self.markers)
                    if t >= t0 and self._candidates(k) - known
                ),
                None,
            ),
            timeout,
        )

    def heard(self) -> list[tuple[float, int]]:
        """(arrival, serialized size in bytes) of every markers message."""
        with self._cv:
            return [(t, len(raw)) for t, raw in self.markers]


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time (s) of process ``pid`` so far, from /proc."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as handle:
        fields = handle.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure_node_latency(
    seeds, max_clicks: int, out_dir: str, idle_s: float = 10.0, log=print
) -> dict:
    """Click the objects of the simulated taskboards ``seeds`` (up to ``max_clicks``) through a
    live engine node, accepting each fit, and measure the row's figures (module docstring)."""
    library = TemplateLibrary.load()
    local = AffordanceEngine(library)
    launcher = start_engine(out_dir)
    ratios, node_s, local_s, to_markers_ms, fit_ratios = [], [], [], [], []
    n, last_size, idle_cores = 0, None, None
    try:
        with background_node("affordance_latency_bench") as node:
            watch = StatusWatch(node)
            arrivals = _Arrivals(node)
            operator = RosOperator(node, watch)
            pub_points = node.create_publisher(PointCloud2, "/points", LATCHED)
            watch.wait(lambda st: True, 60, "the engine node")
            for seed in seeds:
                if n >= max_clicks:
                    break
                sim = simulate_taskboard(library, seed)
                received = ((watch.latest.get("node") or {}).get("cloud") or {}).get("received", 0)
                msg = cloud_message(sim.organized.reshape(-1, 3))
                pub_points.publish(msg)
                watch.wait(
                    lambda st: (
                        ((st.get("node") or {}).get("cloud") or {}).get("received", 0) > received
                    ),
                    30,
                    "the cloud",
                )
                local.set_scene(pointcloud2_to_xyz(msg)[0], frame_id=FRAME)
                for obj in sim.objects:
                    if obj.click is None or obj.visible_points < 200 or n >= max_clicks:
                        continue
                    n += 1
                    known = {o["id"] for o in (watch.latest or {}).get("objects", [])}
                    t0 = time.monotonic()
                    operator.click(obj.click)
                    # when the status that showed the fit arrived, and the markers that drew
                    # it: each found by what it shows (a loaded machine runs either first)
                    t_status, node_fit = arrivals.status_showing(t0, known) or (None, None)
                    t_markers = arrivals.markers_showing(t0, known)
                    if t_status is None:
                        t_status = time.monotonic()
                    t0_local = time.perf_counter()
                    local.click(obj.click)
                    local_s.append(time.perf_counter() - t0_local)
                    node_s.append(t_status - t0)
                    ratios.append(node_s[-1] / local_s[-1])
                    if node_fit:
                        fit_ratios.append(node_fit / local_s[-1])
                    if t_markers is not None:
                        to_markers_ms.append(max(0.0, t_markers - t_status) * 1000)
                    operator.accept()
                    local.accept()
                log(
                    f"  over ROS: {n} clicks, click -> status {statistics.median(ratios):.2f}x "
                    f"the in-process fit (median)"
                )
            shown = len((watch.latest or {}).get("registered", []))
            time.sleep(2.0)  # whatever the last accept set going, settles
            pid = launcher.procs[0].pid
            c0, t0 = _cpu_seconds(pid), time.monotonic()
            time.sleep(idle_s)
            idle_cores = (_cpu_seconds(pid) - c0) / (time.monotonic() - t0)
            sizes = [s for _, s in arrivals.heard()]
            last_size = sizes[-1] if sizes else None
    finally:
        launcher.stop()
    return {
        "clicks": n,
        "click_to_status_over_fit": statistics.median(ratios) if ratios else None,
        "node_click_to_status_s": statistics.median(node_s) if node_s else None,
        "in_process_fit_s": statistics.median(local_s) if local_s else None,
        "node_fit_over_fit": statistics.median(fit_ratios) if fit_ratios else None,
        "status_to_markers_ms": statistics.median(to_markers_ms) if to_markers_ms else None,
        "markers_bytes_max": max(sizes) if sizes else None,
        "markers_bytes_last": last_size,
        "objects_shown_last": shown,
        "idle_engine_cores": idle_cores,
    }
