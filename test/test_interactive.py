# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The interactive-marker server against a protocol client written here that behaves as RViz's:
request the full set, then apply updates in seq_num order and detect gaps."""

import math
import os
import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from ros_helpers import LATCHED, Client, engine_process
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import (
    InteractiveMarkerControl,
    InteractiveMarkerFeedback,
    InteractiveMarkerUpdate,
    Marker,
)
from visualization_msgs.srv import GetInteractiveMarkers

from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import (
    matrix_to_pose,
    pose_to_matrix,
    xyz_to_pointcloud2,
)
from affordance_registration.ros.glue.throttle import Throttle

NS = "/affordance_correction"
FRAME = "camera_depth_optical_frame"


class ProtocolClient:
    """What RViz's Interactive Markers display does with a server."""

    def __init__(self, client: Client):
        self.client = client
        self.lock = threading.Lock()
        self.markers = {}
        self.seq = None
        self.server_id = None
        self.gaps = []
        self.pending = []
        self.keep_alives = 0
        client.node.create_subscription(
            InteractiveMarkerUpdate, f"{NS}/update", self._on_update, 100
        )
        self.feedback = client.node.create_publisher(
            InteractiveMarkerFeedback, f"{NS}/feedback", 100
        )

    def init(self):
        res = self.client.call(GetInteractiveMarkers, f"{NS}/get_interactive_markers")
        with self.lock:
            self.seq = res.sequence_number
            self.markers = {m.name: m for m in res.markers}
            for upd in sorted(self.pending, key=lambda u: u.seq_num):
                self._apply(upd)
            self.pending = []

    def _on_update(self, upd):
        with self.lock:
            if upd.type == InteractiveMarkerUpdate.KEEP_ALIVE:
                self.keep_alives += 1
                self.server_id = upd.server_id
                if self.seq is not None and upd.seq_num > self.seq:
                    self.gaps.append(("keep_alive_ahead", self.seq, upd.seq_num))
                return
            if self.seq is None:
                self.pending.append(upd)
                return
            self._apply(upd)

    def _apply(self, upd):
        if upd.seq_num <= self.seq:
            return  # already contained in the full set
        if upd.seq_num != self.seq + 1:
            self.gaps.append((self.seq, upd.seq_num))
        self.seq = upd.seq_num
        for m in upd.markers:
            self.markers[m.name] = m
        for p in upd.poses:
            self.markers[p.name].pose = p.pose
        for name in upd.erases:
            self.markers.pop(name, None)

    def send(
        self,
        event,
        pose=None,
        menu_entry_id=0,
        client_id="/rviz/InteractiveMarkers",
        name="affordance_fit",
    ):
        fb = InteractiveMarkerFeedback(
            client_id=client_id, marker_name=name, event_type=event, menu_entry_id=menu_entry_id
        )
        fb.header.frame_id = FRAME
        if pose is not None:
            fb.pose = pose
        self.feedback.publish(fb)


@pytest.fixture(scope="module")
def session(ros_context, tmp_path_factory, library):
    tmp = tmp_path_factory.mktemp("interactive")
    proc = engine_process(tmp, {"refit_idle_s": 0.4})
    client = Client("interactive_tester")
    client.subscribe(String, "/affordance_engine/status", LATCHED)
    proto = ProtocolClient(client)
    points = client.node.create_publisher(PointCloud2, "/points", 1)
    click = client.node.create_publisher(PointStamped, "/clicked_point", 10)
    sim = simulate_taskboard(library, 7)
    try:
        client.wait_for_subscribers(points, timeout=30)
        client.wait_for_subscribers(proto.feedback, timeout=30)
        proto.init()
        yield {
            "proc": proc,
            "client": client,
            "proto": proto,
            "points": points,
            "click": click,
            "sim": sim,
        }
    finally:
        client.close()
        proc.interrupt()
        proc.kill()
        print(proc.output()[-3000:])


def marker(s):
    with s["proto"].lock:
        return s["proto"].markers.get("affordance_fit")


def test_no_marker_until_a_click_then_mesh_and_six_controls(session):
    s = session
    assert marker(s) is None
    s["client"].wait_for(lambda: s["proto"].keep_alives >= 2, what="keep-alives")
    s["points"].publish(xyz_to_pointcloud2(s["sim"].organized, FRAME))
    s["client"].wait_for(
        lambda: (s["client"].status() or {}).get("node", {}).get("cloud"), what="the cloud"
    )
    obj = s["sim"].objects[1]
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
    s["click"].publish(msg)
    m = s["client"].wait_for(lambda: marker(s), timeout=30, what="the interactive marker")
    assert m.header.frame_id == FRAME and obj.template in m.description
    modes = sorted((c.name, c.interaction_mode) for c in m.controls)
    C = InteractiveMarkerControl
    assert [c for c in modes if c[1] in (C.MOVE_AXIS, C.ROTATE_AXIS)] == [
        ("move_x", C.MOVE_AXIS),
        ("move_y", C.MOVE_AXIS),
        ("move_z", C.MOVE_AXIS),
        ("rotate_x", C.ROTATE_AXIS),
        ("rotate_y", C.ROTATE_AXIS),
        ("rotate_z", C.ROTATE_AXIS),
    ]
    mesh = [c for c in m.controls if c.name == "mesh"][0]
    # the template by reference: its mesh file (and its moving part's), not triangles
    assert mesh.markers and all(
        v.type == Marker.MESH_RESOURCE
        and not v.points
        and v.mesh_resource.startswith("file://")
        and os.path.isfile(v.mesh_resource[len("file://") :])
        for v in mesh.markers
    )
    assert [e.title for e in m.menu_entries] == [
        "Next model",
        "Previous model",
        "Refit",
        "Accept",
        "Undo",
        "Discard",
    ]
    # the six axes: x, y, z of the object
    axes = {}
    for c in m.controls:
        if c.name.startswith("move_"):
            q = c.orientation
            from scipy.spatial.transform import Rotation

            axes[c.name[-1]] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()[:, 0]
    assert np.allclose(axes["x"], [1, 0, 0]) and np.allclose(axes["y"], [0, 1, 0])
    assert np.allclose(axes["z"], [0, 0, 1])


def test_dragging_3cm_off_and_releasing_refits_back_onto_the_object(session, library):
    s = session
    obj = s["sim"].objects[1]
    proto = s["proto"]
    T = pose_to_matrix(marker(s).pose)
    F = InteractiveMarkerFeedback
    proto.send(F.MOUSE_DOWN, matrix_to_pose(T))
    for k in range(1, 7):
        Tk = T.copy()
        Tk[:3, 3] += np.array([0.005, 0.0, 0.0]) * k  # 3 cm in 6 steps
        proto.send(F.POSE_UPDATE, matrix_to_pose(Tk))
        time.sleep(0.03)
    s["client"].wait_for(
        lambda: pose_to_matrix(marker(s).pose)[0, 3] - T[0, 3] > 0.025,
        what="the marker to follow the drag",
    )
    proto.send(F.MOUSE_UP, matrix_to_pose(Tk))
    sym = library[obj.template].symmetry
    s["client"].wait_for(
        lambda: pose_error(pose_to_matrix(marker(s).pose), obj.T_scene_model, sym)[0] < 0.005,
        timeout=60,
        what="the refit",
    )
    dt, dr = pose_error(pose_to_matrix(marker(s).pose), obj.T_scene_model, sym)
    assert dt < 0.005 and dr < math.radians(5)


def test_menu_next_model_changes_the_template(session):
    s = session
    before = marker(s).description
    s["proto"].send(InteractiveMarkerFeedback.MENU_SELECT, menu_entry_id=1)
    s["client"].wait_for(
        lambda: marker(s).description != before and "rank 2/" in marker(s).description,
        what="the next model",
    )
    s["proto"].send(InteractiveMarkerFeedback.MENU_SELECT, menu_entry_id=2)
    s["client"].wait_for(lambda: "rank 1/" in marker(s).description, what="back to rank 1")


def test_malformed_and_foreign_feedback_is_ignored(session):
    s = session
    proto, F = s["proto"], InteractiveMarkerFeedback
    before = pose_to_matrix(marker(s).pose)
    nan_pose = matrix_to_pose(np.eye(4))
    nan_pose.position.x = float("nan")
    proto.send(F.POSE_UPDATE, nan_pose)
    bad_q = matrix_to_pose(np.eye(4))
    bad_q.orientation.w = 3.0
    proto.send(F.POSE_UPDATE, bad_q)
    proto.send(F.POSE_UPDATE, matrix_to_pose(np.eye(4)), name="somebody_elses_marker")
    proto.send(F.MENU_SELECT, menu_entry_id=99)
    # a second client cannot hijack a drag in progress
    proto.send(F.MOUSE_DOWN, matrix_to_pose(before), client_id="/rviz_a")
    far = before.copy()
    far[:3, 3] += [0.2, 0, 0]
    proto.send(F.POSE_UPDATE, matrix_to_pose(far), client_id="/rviz_b")
    proto.send(F.MOUSE_UP, matrix_to_pose(before), client_id="/rviz_a")
    time.sleep(1.0)
    assert np.allclose(pose_to_matrix(marker(s).pose)[:3, 3], before[:3, 3], atol=0.01)
    res = s["client"].call(Trigger, "/affordance_engine/next_model")
    assert res.success  # still serving
    s["client"].call(Trigger, "/affordance_engine/previous_model")
    out = s["proc"].output()
    assert "malformed pose" in out and "no marker named 'somebody_elses_marker'" in out
    assert "while '/rviz_a' is dragging" in out


def test_discard_erases_the_marker_and_sequence_has_no_gaps(session):
    s = session
    assert s["client"].call(Trigger, "/affordance_engine/discard").success
    s["client"].wait_for(lambda: marker(s) is None, what="the erase")
    time.sleep(0.6)
    assert s["proto"].gaps == []
    assert s["proto"].seq >= 5


def test_joint_marker_turns_the_lever_and_follows_the_fit(session, library):
    """An articulated object gets a second marker on its joint (x along the axis, one
    ROTATE_AXIS control for a revolute joint). Releasing it turned by 0.1 rad sets the lever to
    that value (the status says so, the pose is refitted with it held) and both markers follow;
    discarding erases both, with no gap in the sequence."""
    s, proto, F = session, session["proto"], InteractiveMarkerFeedback
    tpl = library["ball_valve"]
    sim = simulate_taskboard(
        library, 3102, articulated=True, joints={"ball_valve": {"lever": math.pi / 4}}
    )
    obj = next(o for o in sim.objects if o.template == "ball_valve")
    s["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
    time.sleep(0.5)
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
    s["click"].publish(msg)

    def joint_marker():
        with proto.lock:
            return proto.markers.get("affordance_joint")

    def shown():
        st = s["client"].status() or {}
        active = [o for o in st.get("objects", []) if o["active"]]
        return active[0]["candidates"][active[0]["shown"]] if active else None

    s["client"].wait_for(
        lambda: joint_marker() is not None and (shown() or {}).get("template") == "ball_valve",
        timeout=30,
        what="the joint marker",
    )
    jm = joint_marker()
    assert [(c.name, c.interaction_mode) for c in jm.controls] == [
        ("joint", InteractiveMarkerControl.ROTATE_AXIS)
    ]
    q0 = shown()["joints"]["lever"]
    T_fit = np.asarray(shown()["pose"])
    s["client"].wait_for(
        lambda: np.allclose(
            pose_to_matrix(joint_marker().pose), T_fit @ tpl.joint_frame(q0), atol=1e-5
        ),
        what="the joint marker at the joint",
    )
    q1 = q0 + 0.1
    target = T_fit @ tpl.joint_frame(q1)
    proto.send(F.MOUSE_DOWN, matrix_to_pose(T_fit @ tpl.joint_frame(q0)), name="affordance_joint")
    proto.send(F.POSE_UPDATE, matrix_to_pose(target), name="affordance_joint")
    proto.send(F.MOUSE_UP, matrix_to_pose(target), name="affordance_joint")
    s["client"].wait_for(
        lambda: abs(shown()["joints"]["lever"] - q1) < 1e-6, what="the lever set from the marker"
    )
    T_new = np.asarray(shown()["pose"])
    s["client"].wait_for(
        lambda: np.allclose(
            pose_to_matrix(joint_marker().pose), T_new @ tpl.joint_frame(q1), atol=1e-5
        ),
        what="the joint marker at the new angle",
    )
    assert np.linalg.norm(T_new[:3, 3] - T_fit[:3, 3]) < 0.01  # the valve stayed put
    assert s["client"].call(Trigger, "/affordance_engine/discard").success
    s["client"].wait_for(lambda: joint_marker() is None and marker(s) is None, what="the erase")
    time.sleep(0.6)
    assert s["proto"].gaps == []


# ---------------------------------------------------------------------------- without a node
class Host:
    """The server's host (a MarkerHost) for tests without ROS: a real engine, and what the server
    sends."""

    def __init__(self, library, engine):
        self.library, self.engine = library, engine
        self.sent, self.warnings, self.cancelled = [], [], []

    def active_object(self):
        return self.engine.active_object()

    def frame(self):
        return FRAME

    def view_pose(self):
        return self.engine.view_pose()

    def template(self, name):
        return self.library[name]

    def marker_pose(self, T, release, object_id):
        self.sent.append(("pose", T, release))

    def marker_action(self, name, argument):
        self.sent.append(("action", name, argument))

    def marker_cancel(self, object_id):
        self.cancelled.append(object_id)

    def warn(self, text):
        self.warnings.append(text)


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_a_throttle_lets_one_line_per_key_through_each_period():
    """The rate limit of the node's, the marker server's and the SpaceMouse node's warnings."""
    clock = Clock()
    throttle = Throttle(2.0, clock)
    assert throttle.due("drag") and not throttle.due("drag") and throttle.due("menu")
    clock.t = 1.99
    assert not throttle.due("drag") and not throttle.due("menu")
    clock.t = 2.0
    assert throttle.due("drag") and not throttle.due("drag")
    clock.t = 3.99
    assert not throttle.due("drag") and throttle.due("menu")


def _feedback(event, T=None, client="/rviz_a", name="affordance_fit", menu=0):
    fb = InteractiveMarkerFeedback(
        client_id=client, marker_name=name, event_type=event, menu_entry_id=menu
    )
    fb.header.frame_id = FRAME
    if T is not None:
        fb.pose = matrix_to_pose(T)
    return fb


def test_server_through_its_host_without_a_node(library):
    """Change sets with consecutive sequence numbers, drags handed to the host, a second client
    locked out while the first one keeps sending and let in once it went silent, one warning per
    kind however many clients misbehave, menu entries and the joint marker as actions."""
    from affordance_registration.core.engine import AffordanceEngine
    from affordance_registration.ros.standins.interactive import (
        DRAG_EXPIRY_S,
        JOINT_MARKER_NAME,
        MARKER_NAME,
        CorrectionMarkerServer,
    )

    F = InteractiveMarkerFeedback
    sim = simulate_taskboard(
        library, 3102, articulated=True, joints={"ball_valve": {"lever": math.pi / 4}}
    )
    engine = AffordanceEngine(library)
    engine.set_scene(sim.organized, frame_id=FRAME)
    host, clock = Host(library, engine), Clock()
    server = CorrectionMarkerServer(host, "/affordance_correction", clock=clock)
    assert server.sync() is None and server.full_set() == (0, [])
    engine.click(next(o for o in sim.objects if o.template == "ball_valve").click)
    upd = server.sync()
    assert upd.seq_num == 1 and sorted(m.name for m in upd.markers) == [
        MARKER_NAME,
        JOINT_MARKER_NAME,
    ]
    assert server.sync() is None  # nothing changed: nothing sent
    T = engine.active_object().shown.T_scene_model
    T2 = T.copy()
    T2[:3, 3] += [0.01, 0.0, 0.0]
    engine.correct_pose(T2, drag=True)
    upd = server.sync()
    assert (
        upd.seq_num == 2
        and not upd.markers
        and {p.name for p in upd.poses} == {MARKER_NAME, JOINT_MARKER_NAME}
    )
    assert np.allclose(pose_to_matrix(upd.poses[0].pose), T2)
    # a drag by /rviz_a: its poses reach the host, a second client's do not
    server.feedback(_feedback(F.MOUSE_DOWN, T))
    server.feedback(_feedback(F.POSE_UPDATE, T2))
    for k in range(200):
        server.feedback(_feedback(F.POSE_UPDATE, T, client=f"/rviz_{k}"))
    assert len([w for w in host.warnings if "is dragging" in w]) == 1  # one line, not 200
    clock.t += DRAG_EXPIRY_S - 0.5
    server.feedback(_feedback(F.KEEP_ALIVE))  # /rviz_a still holds the mouse
    clock.t += DRAG_EXPIRY_S - 0.5
    server.feedback(_feedback(F.POSE_UPDATE, T, client="/rviz_b"))
    assert host.sent == [("pose", host.sent[0][1], False)]
    assert np.allclose(host.sent[0][1], T2)
    # /rviz_a never released and went silent: its drag is cancelled (the host puts the object
    # back), /rviz_b may drag now, and /rviz_a's late release is refused
    clock.t += DRAG_EXPIRY_S + 0.1
    server.expire()
    assert host.cancelled == [engine.active_object().id]
    server.feedback(_feedback(F.MOUSE_UP, T2, client="/rviz_a"))
    assert any("after its drag was cancelled" in w for w in host.warnings)
    server.feedback(_feedback(F.POSE_UPDATE, T, client="/rviz_b"))
    server.feedback(_feedback(F.MOUSE_UP, T, client="/rviz_b"))
    assert [(kind, release) for kind, _, release in host.sent[1:]] == [
        ("pose", False),
        ("pose", True),
    ]
    # malformed and foreign feedback: one warning per kind
    bad = _feedback(F.POSE_UPDATE, T, client="/rviz_c")
    bad.pose.position.x = float("nan")
    server.feedback(bad)
    server.feedback(bad)
    server.feedback(_feedback(F.POSE_UPDATE, T, name="somebody_elses_marker"))
    server.feedback(_feedback(F.MENU_SELECT, menu=99))
    assert sum("malformed pose" in w for w in host.warnings) == 1
    assert any("no marker named 'somebody_elses_marker'" in w for w in host.warnings)
    assert any("unknown menu entry 99" in w for w in host.warnings)
    n = len(host.sent)
    # the menu and the joint marker become actions
    server.feedback(_feedback(F.MENU_SELECT, menu=4))
    tpl = library["ball_valve"]
    cand = engine.active_object().shown
    q = tpl.joint_value(cand.joints) - 0.2
    server.feedback(
        _feedback(F.MOUSE_UP, cand.T_scene_model @ tpl.joint_frame(q), name=JOINT_MARKER_NAME)
    )
    assert host.sent[n] == ("action", "accept", None)
    assert host.sent[n + 1][:2] == ("action", "joint_value") and host.sent[n + 1][
        2
    ] == pytest.approx(q)
    engine.discard()
    upd = server.sync()
    assert upd.seq_num == 3 and sorted(upd.erases) == [MARKER_NAME, JOINT_MARKER_NAME]
    assert server.full_set() == (3, [])
