# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Operator sessions over ROS: the simulated operator driving a live engine node through its
topics (recorded as a rosbag2 bag), and the replay of a recorded session into a live node -- the
product's demonstration (``make demo``) and a regression test.

Recorded topics: ``/points`` (the scan, thinned to its finite points), ``/clicked_point``,
``/spacenav/joy`` (button 0 = next model, 1 = accept), ``/spacenav/twist`` and
``/affordance_engine/status`` (what the node reported then).
"""

from __future__ import annotations

import json
import math
import os
import threading
import time

import numpy as np
import yaml
from geometry_msgs.msg import PointStamped, Twist, TwistStamped
from sensor_msgs.msg import Joy, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.corrections import R_VIEW_SPACENAV, view_from_optical
from ..core.errors import AffordanceError
from ..core.files import unreadable, write_atomically
from ..core.templates import TemplateLibrary
from ..core.transforms import pose_error
from ..ros.glue.conversions import pointcloud2_to_xyz, xyz_to_pointcloud2
from ..ros.glue.qos import LATCHED
from ..ros.standins.bag import bag_info, read_messages
from ..ros.standins.launcher import Launcher, package_share, parse_launch_file
from ..ros.standins.spin import background_node
from .simulation import (
    SimulatedOperator,
    failures,
    load_truth,
    operator_correction,
    simulate_taskboard,
    truth_joints,
)

NS = "/affordance_engine"
INPUT_TOPICS = ["/points", "/clicked_point", "/spacenav/joy", "/spacenav/twist"]
STATUS_TOPIC = f"{NS}/status"
#: a replayed registration this close to the recorded one reproduces it: a paced replay of a
#: session with stamped twists gives the recorded registrations to the last digit on the machine
#: that recorded it; the margin allows another CPU's rounding to tip a refit to a neighbouring
#: optimum (seen: 0.7 mm on the grab handle for a 0.2 mm different start)
REPLAY_TOL_M = 0.001
REPLAY_TOL_RAD = math.radians(1.0)
FRAME = "camera_depth_optical_frame"

__all__ = ["RosOperator", "record_session", "replay_session", "start_engine", "measure_push_refit"]


class StatusWatch:
    """Keeps every ~/status the node publishes (for waiting on it and for the session table)."""

    def __init__(self, node):
        self.history: list[dict] = []
        self._cv = threading.Condition()
        node.create_subscription(String, STATUS_TOPIC, self._on_status, LATCHED)

    def _on_status(self, msg):
        with self._cv:
            self.history.append(json.loads(msg.data))
            self._cv.notify_all()

    @property
    def latest(self) -> dict | None:
        with self._cv:
            return self.history[-1] if self.history else None

    def wait(self, predicate, timeout: float, what: str, after: int = 0) -> dict:
        """The first status (from index ``after`` on) satisfying ``predicate``."""
        deadline = time.monotonic() + timeout
        with self._cv:
            while True:
                for st in self.history[after:]:
                    if predicate(st):
                        return st
                after = len(self.history)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AffordanceError(f"timed out waiting for {what}")
                self._cv.wait(timeout=min(left, 0.2))

    def count(self) -> int:
        with self._cv:
            return len(self.history)


def _active(st: dict) -> dict | None:
    for o in st.get("objects", []):
        if o["active"]:
            return o
    return None


class RosOperator:
    """The simulated operator's controls as ROS messages (what a person does in RViz and with a
    SpaceMouse): the engine node is driven only through its topics."""

    def __init__(
        self,
        node,
        watch: StatusWatch,
        linear_gain: float = 0.1,
        angular_gain: float = 0.6,
        idle_s: float = 0.5,
        stamped: bool = False,
    ):
        """``stamped``: twists as TwistStamped (the engine runs with ``twist_stamped``)."""
        self.node, self.watch = node, watch
        self.linear_gain, self.angular_gain, self.idle_s = linear_gain, angular_gain, idle_s
        self.stamped = stamped
        self.pub_click = node.create_publisher(PointStamped, "/clicked_point", 10)
        self.pub_joy = node.create_publisher(Joy, "/spacenav/joy", 10)
        self.pub_twist = node.create_publisher(
            TwistStamped if stamped else Twist, "/spacenav/twist", 10
        )

    def _idle(self, st):
        node = st.get("node", {})
        return node.get("idle", node.get("busy") is None and node.get("queued") == 0)

    def click(self, point):
        n = self.watch.count()
        before = self.watch.latest or {}
        known = {o["id"] for o in before.get("objects", [])}
        msg = PointStamped()
        msg.header.frame_id = FRAME
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.point.x, msg.point.y, msg.point.z = map(float, point)
        self.pub_click.publish(msg)
        self.watch.wait(
            lambda st: (
                self._idle(st) and _active(st) is not None and _active(st)["id"] not in known
            ),
            60,
            "the fit of a click",
            after=n,
        )

    def shown(self):
        obj = _active(self.watch.latest or {})
        if obj is None:
            return None, None
        c = obj["candidates"][obj["shown"]]
        return c["template"], np.asarray(c["pose"], dtype=float)

    def _press(self, button: int):
        joy = Joy()
        joy.axes = [0.0] * 6
        joy.buttons = [0, 0]
        joy.buttons[button] = 1
        self.pub_joy.publish(joy)
        time.sleep(0.05)
        joy.buttons = [0, 0]
        self.pub_joy.publish(joy)

    def next_model(self):
        n = self.watch.count()
        obj = _active(self.watch.latest)
        self._press(0)
        self.watch.wait(
            lambda st: (
                _active(st) is not None and _active(st)["model_changes"] > obj["model_changes"]
            ),
            20,
            "the next model",
            after=n,
        )

    def push(self, linear, angular, duration, T_scene_view):
        """Hold the SpaceMouse cap: view-frame velocities -> spacenav axes at 30 Hz."""
        lin = R_VIEW_SPACENAV.T @ (np.asarray(linear) / self.linear_gain)
        ang = R_VIEW_SPACENAV.T @ (np.asarray(angular) / self.angular_gain)
        twist = Twist()
        twist.linear.x, twist.linear.y, twist.linear.z = map(float, lin)
        twist.angular.x, twist.angular.y, twist.angular.z = map(float, ang)
        # a 30 Hz device: with stamped twists, the stamps are the device's ticks (whatever this
        # process's scheduling does to when they are sent)
        t0, k = time.monotonic(), 0
        stamp0 = self.node.get_clock().now().nanoseconds
        while time.monotonic() - t0 < duration:
            self._publish_twist(twist, stamp0 + k * 1_000_000_000 // 30)
            k += 1
            time.sleep(max(0.0, t0 + k / 30 - time.monotonic()))
        self._publish_twist(Twist(), stamp0 + k * 1_000_000_000 // 30)  # released
        self._pushed_at = self.watch.count()

    def _publish_twist(self, twist: Twist, stamp_ns: int) -> None:
        if self.stamped:
            msg = TwistStamped(twist=twist)
            msg.header.frame_id = "spacenav"
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
            self.pub_twist.publish(msg)
        else:
            self.pub_twist.publish(twist)

    def refit(self):
        """The node refits by itself after the twists stop; wait for it."""
        self.watch.wait(
            lambda st: ": refit" in st.get("node", {}).get("last_message", "") and self._idle(st),
            20,
            "the refit after the push",
            after=getattr(self, "_pushed_at", 0),
        )

    def accept(self):
        n = self.watch.count()
        k = len((self.watch.latest or {}).get("registered", []))
        self._press(1)
        self.watch.wait(lambda st: len(st.get("registered", [])) > k, 20, "the accept", after=n)


def start_engine(out_dir: str, log=None, extra_args: dict | None = None) -> Launcher:
    """The engine node from the package's YAML launch file (as an operator station starts it)."""
    launch = os.path.join(
        package_share("affordance_registration"), "launch_configs", "affordance_engine.launch.yaml"
    )
    # a recorded or replayed session starts fresh: registrations an earlier run left in out_dir
    # must not count (the engine keeps that file as a backup when it first replaces it)
    args = {
        "registrations_file": os.path.join(os.path.abspath(out_dir), "registrations.yaml"),
        "resume": "false",
    }
    args.update(extra_args or {})
    # (the log is streamed: a FIFO or a device in its place is refused, not opened -- a FIFO
    # with no reader would block here for good)
    log_path = os.path.join(out_dir, "engine.log")
    why = unreadable(log_path, missing_ok=True)
    if why is not None:
        raise AffordanceError(f"{log_path}: {why}: not replaced")
    log_file = open(log_path, "w")
    launcher = Launcher(
        parse_launch_file(launch, args), log=log or (lambda m: None), output=log_file
    )
    launcher.start()
    return launcher


def cloud_message(points: np.ndarray) -> PointCloud2:
    finite = points[np.all(np.isfinite(points), axis=1)]
    return xyz_to_pointcloud2(finite.astype(np.float32), FRAME)


def record_session(out_dir: str, seed: int = 7, log=print) -> dict:
    """Simulate a taskboard, start the engine, let the simulated operator register every object
    through ROS topics while a bag records the session. Writes ``bag/`` and ``truth.yaml``."""
    from ..ros.standins.bag import Recorder

    library = TemplateLibrary.load()
    sim = simulate_taskboard(library, seed)
    os.makedirs(out_dir, exist_ok=True)
    bag_path = os.path.join(out_dir, "bag")
    if os.path.exists(bag_path):
        raise AffordanceError(f"{bag_path} exists already")
    write_atomically(
        {os.path.join(out_dir, "truth.yaml"): yaml.safe_dump(sim.truth(), sort_keys=False)}
    )
    # twists as TwistStamped: a replay integrates them over their recorded header stamps, so it
    # moves the objects exactly as the recording did, however the machine is loaded
    launcher = start_engine(out_dir, extra_args={"twist_stamped": "true"})
    rows = []
    try:
        with background_node("affordance_session_operator") as node:
            watch = StatusWatch(node)
            operator = RosOperator(node, watch, stamped=True)
            pub_points = node.create_publisher(PointCloud2, "/points", LATCHED)
            recorder = Recorder(node, bag_path, INPUT_TOPICS + [STATUS_TOPIC])
            deadline = time.monotonic() + 60
            while pub_points.get_subscription_count() < 1 and time.monotonic() < deadline:
                time.sleep(0.05)
            watch.wait(lambda st: True, 60, "the engine node")
            time.sleep(0.5)  # the recorder discovers the topics
            pub_points.publish(cloud_message(sim.organized.reshape(-1, 3)))
            watch.wait(
                lambda st: (st.get("node", {}).get("cloud") or {}).get("received"),
                30,
                "the cloud to arrive",
            )
            # a stricter operator than the replay test's 5 mm / 5 deg: a replay integrates the
            # recorded twists at its own timing, so its refits land near, not on, the recorded ones
            sim_operator = SimulatedOperator(
                library, tolerance_m=0.003, tolerance_rad=math.radians(3.0), seed=seed
            )
            view = view_from_optical(np.eye(4))
            for obj in sim.objects:
                if obj.click is None or obj.visible_points < 200:
                    continue
                rows.append(sim_operator.register(obj, operator, view))
                log(
                    f"  {obj.template}: {rows[-1]['model_changes']} model changes, "
                    f"{rows[-1]['corrections']} corrections, error {rows[-1]['error_mm']:.1f} mm"
                )
            time.sleep(0.5)
            counts = recorder.close()
    finally:
        launcher.stop()
    return {"rows": rows, "counts": counts, "bag": bag_path}


def _recorded_status(bag_path: str) -> list[dict]:
    """Every ~/status message recorded in a bag, decoded."""
    return [json.loads(m.data) for m in read_messages(bag_path, STATUS_TOPIC)]


def session_rows(status: dict, truth: dict, library) -> list[dict]:
    """The paper-style table from a node's status: per registered object its true template (the
    nearest true object), the template ranked first, model changes, corrections, fit time, final
    pose error, and the verdict: ``ok`` and ``why`` (the reasons it is wrong)."""
    rows = []
    for reg in status.get("registered", []):
        T = np.asarray(reg["pose"], dtype=float)
        match = min(
            truth["objects"],
            key=lambda t: np.linalg.norm(np.asarray(t["T_scene_model"])[:3, 3] - T[:3, 3]),
        )
        if reg["template"] == match["template"]:
            dt, dr = pose_error(
                T, np.asarray(match["T_scene_model"]), library[match["template"]].symmetry
            )
        else:
            dt, dr = float("inf"), float("inf")
        row = {
            "template": match["template"],
            "ranked_first": reg["ranked_first"],
            "shown": reg["template"],
            "model_changes": reg["model_changes"],
            "corrections": reg["corrections"],
            "fit_s": reg["fit_s"],
            "error_mm": dt * 1000,
            "error_deg": math.degrees(dr),
            "id": reg["id"],
        }
        why = failures(row)
        rows.append({**row, "ok": not why, "why": "; ".join(why)})
    return rows


def compare_with_recording(
    rows: list[dict], recorded: list[dict], live: list[dict], library
) -> list[dict]:
    """``rows`` with what differs from the recorded session: a registration more than the
    replay tolerance from the recorded one fails, and a recorded one that is missing adds a
    failing row."""
    out = [dict(r) for r in rows]
    for i, rec in enumerate(recorded):
        if i >= len(live):
            out.append(
                {
                    "template": rec["template"],
                    "ranked_first": rec["ranked_first"],
                    "shown": "-",
                    "model_changes": 0,
                    "corrections": 0,
                    "fit_s": 0.0,
                    "error_mm": float("inf"),
                    "error_deg": float("inf"),
                    "id": rec["id"],
                    "ok": False,
                    "why": "not registered in the replay",
                }
            )
            continue
        cur = live[i]
        if cur["template"] != rec["template"]:
            reason = f"recorded as {rec['template']}, replayed as {cur['template']}"
        else:
            dt, dr = pose_error(
                np.asarray(cur["pose"]), np.asarray(rec["pose"]), library[rec["template"]].symmetry
            )
            if dt <= REPLAY_TOL_M and dr <= REPLAY_TOL_RAD:
                continue
            reason = f"{dt * 1000:.1f} mm / {math.degrees(dr):.1f}° from the recorded registration"
        out[i]["why"] = "; ".join(w for w in (out[i]["why"], reason) if w)
        out[i]["ok"] = False
    return out


def replay_session(session_dir: str, out_dir: str, rate: float = 1.0, log=print) -> dict:
    """Play a recorded session into a live engine node started from the YAML launch file; save
    its registrations, compare them with the truth and with what the node reported when the
    session was recorded, and draw the result. Returns a summary (``ok`` is the verdict)."""
    from ..ros.standins.bag import Player, StatusPacer

    library = TemplateLibrary.load()
    truth = load_truth(os.path.join(session_dir, "truth.yaml"))
    bag_path = os.path.join(session_dir, "bag")
    recorded = _recorded_status(bag_path)
    os.makedirs(out_dir, exist_ok=True)
    stamped = any(
        t["topic"] == "/spacenav/twist" and t["type"].endswith("/TwistStamped")
        for t in bag_info(bag_path)["topics"]
    )
    launcher = start_engine(out_dir, extra_args={"twist_stamped": str(stamped).lower()})
    try:
        with background_node("affordance_session_replay") as node:
            watch = StatusWatch(node)
            # paced by the node: each input once the node has finished with the one before
            # (SpaceMouse bursts keep their recorded timing), so the replay does not depend on
            # how loaded the machine is
            player = Player(
                node,
                bag_path,
                rate=rate,
                topics=INPUT_TOPICS,
                pace=StatusPacer(node, STATUS_TOPIC),
            )
            watch.wait(lambda st: True, 60, "the engine node to start")
            if not player.wait_for_subscribers(30):
                raise AffordanceError("the engine node did not subscribe to the session's topics")
            time.sleep(0.3)
            t0 = time.monotonic()
            n = player.play()
            watch.wait(
                lambda st: (
                    len(st.get("registered", [])) >= len(recorded[-1]["registered"])
                    and st["node"]["busy"] is None
                ),
                60,
                "the last registration",
            )
            played_s = time.monotonic() - t0
            client = node.create_client(Trigger, f"{NS}/save")
            if not client.wait_for_service(timeout_sec=10):
                raise AffordanceError("the engine's ~/save service is not available")
            future = client.call_async(Trigger.Request())
            deadline = time.monotonic() + 10
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.02)
            saved = future.result().message if future.done() else "save did not answer"
            live = watch.latest
    finally:
        launcher.stop()
    # the verdict: against the truth, and against what the node reported when it was recorded
    rows = compare_with_recording(
        session_rows(live, truth, library), recorded[-1]["registered"], live["registered"], library
    )
    write_atomically({os.path.join(out_dir, "status.json"): json.dumps(live, indent=1)})
    from .render import render_verdict, write_png
    from .simulation import CameraIntrinsics

    picture = os.path.join(out_dir, "registrations.png")
    verdicts = {r["id"]: r for r in rows}
    regs = [
        {**r, "ok": verdicts[r["id"]]["ok"], "why": verdicts[r["id"]]["why"]}
        for r in live["registered"]
    ]
    truths = [
        (o["template"], o["T_scene_model"], o.get("joints") or {}, o.get("scale", 1.0))
        for o in truth["objects"]
        if o.get("click") is not None
    ]
    write_png(
        picture,
        render_verdict(
            _recorded_cloud(bag_path),
            regs,
            truths,
            library,
            CameraIntrinsics(**truth["intrinsics"]),
        ),
    )
    mismatches = [f"{r['template']}: {r['why']}" for r in rows if not r["ok"]]
    ok = bool(rows) and not mismatches
    return {
        "rows": rows,
        "mismatches": mismatches,
        "played": n,
        "played_s": played_s,
        "saved": saved,
        "picture": picture,
        "status": os.path.join(out_dir, "status.json"),
        "ok": ok,
    }


def _recorded_cloud(bag_path: str) -> np.ndarray:
    """The points of the first cloud recorded on /points."""
    for msg in read_messages(bag_path, "/points"):
        return pointcloud2_to_xyz(msg)[0]
    return np.zeros((0, 3))


def measure_push_refit(seeds, max_clicks: int, out_dir: str, rng_seed: int = 5, log=print) -> dict:
    """Over ROS, what the bench's refit row measures in the core: on simulated panels, click an
    object, push the shown fit with SpaceMouse twists (30 Hz) to the truth displaced by 1.5 cm
    and 8 degrees, let go, and let the node refit once the twists stop. Returns how often the
    refit lands within 5 mm / 5 degrees of the truth, and -- on the same clicks, from the same
    displaced poses -- how often the core's refit does."""
    from scipy.spatial.transform import Rotation

    from ..core.registration import Registrar
    from ..core.scene import Scene

    library = TemplateLibrary.load()
    registrar = Registrar(library)
    rng = np.random.default_rng(rng_seed)
    view = view_from_optical(np.eye(4))
    ros_ok = core_ok = n = 0
    # stamped twists: the push moves the object as far as a 30 Hz device would, whatever the
    # scheduling of this (measuring) process does to when the messages go out
    launcher = start_engine(out_dir, extra_args={"twist_stamped": "true"})
    try:
        with background_node("affordance_push_refit") as node:
            watch = StatusWatch(node)
            operator = RosOperator(node, watch, stamped=True)
            pub_points = node.create_publisher(PointCloud2, "/points", LATCHED)
            watch.wait(lambda st: True, 60, "the engine node")
            for seed in seeds:
                sim = simulate_taskboard(library, seed)
                received = ((watch.latest.get("node") or {}).get("cloud") or {}).get("received", 0)
                pub_points.publish(cloud_message(sim.organized.reshape(-1, 3)))
                watch.wait(
                    lambda st: (
                        ((st.get("node") or {}).get("cloud") or {}).get("received", 0) > received
                    ),
                    30,
                    "the cloud",
                )
                scene = Scene(sim.organized)
                for obj in sim.objects:
                    if obj.click is None or obj.visible_points < 200 or n >= max_clicks:
                        continue
                    n += 1
                    tpl = library[obj.template]
                    operator.click(obj.click)
                    template, T = operator.shown()
                    goal = operator_correction(obj.T_scene_model, tpl.centroid, rng)
                    ctx = registrar.prepare(scene, obj.click)
                    res = registrar.refit(ctx, obj.template, goal, truth_joints(tpl, obj))
                    core_ok += _within(res.T_scene_model, obj, library)
                    c_now = T[:3, :3] @ tpl.centroid + T[:3, 3]
                    c_goal = goal[:3, :3] @ tpl.centroid + goal[:3, 3]
                    rotvec = Rotation.from_matrix(goal[:3, :3] @ T[:3, :3].T).as_rotvec()
                    duration, R_sv = 0.5, view[:3, :3]  # twists are in the view's axes
                    operator.push(
                        R_sv.T @ (c_goal - c_now) / duration,
                        R_sv.T @ rotvec / duration,
                        duration,
                        view,
                    )
                    operator.refit()
                    template, T = operator.shown()
                    ros_ok += template == obj.template and _within(T, obj, library)
                    operator.accept()
                log(f"  push refit over ROS: {ros_ok}/{n} land (core: {core_ok}/{n})")
    finally:
        launcher.stop()
    return {"clicks": n, "ros_success": ros_ok / max(n, 1), "core_success": core_ok / max(n, 1)}


def _within(T: np.ndarray, obj, library) -> bool:
    dt, dr = pose_error(T, obj.T_scene_model, library[obj.template].symmetry)
    return not failures(
        {
            "template": obj.template,
            "shown": obj.template,
            "error_mm": dt * 1000,
            "error_deg": math.degrees(dr),
        }
    )
