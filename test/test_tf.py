# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""TF: the tf2_msgs that `make setup` builds (Jazzy's type hash and wire format), and a live
engine node's frames over real topics -- registrations on /tf_static, the shown candidate on
/tf, clicks in a frame known only from /tf_static -- plus the node without tf2_msgs."""

import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PointStamped, PoseArray, PoseStamped, TransformStamped, Twist
from rcl_interfaces.srv import ListParameters
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from ros_helpers import LATCHED, Client, NodeProcess, engine_process
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from affordance_registration.core.transforms import invert, make_T, pose_error, quat_xyzw_to_matrix
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import (
    matrix_to_transform,
    pose_to_matrix,
    transform_to_matrix,
    xyz_to_pointcloud2,
)

FRAME = "camera_depth_optical_frame"
NS = "/affordance_engine"
TF_ONLY = "tf_only_frame"  # known to the engine only from /tf_static (published here)
TF_ROOT = "tf_test_root"
TOL_M, TOL_RAD = 0.005, math.radians(5)
ROOT = Path(__file__).resolve().parents[1]
STATIC_QOS = QoSProfile(
    depth=100,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
JAZZY = get_typestore(Stores.ROS2_JAZZY)


def tf2_msgs():
    try:
        from tf2_msgs import msg
    except ImportError as exc:
        pytest.fail(
            f"tf2_msgs is not importable ({exc}): `make setup` did not build it -- see its output"
        )
    return msg


# ------------------------------------------------------------------ the generated package
def test_generated_type_hashes_equal_jazzys(ros_context):
    """The hash a publisher advertises (what tf2_ros nodes elsewhere check) is Jazzy's, as
    rosbags computes it from its own copy of the Jazzy definitions."""
    msg = tf2_msgs()
    client = Client("tf2_msgs_hash_checker")
    try:
        for cls, name in (
            (msg.TFMessage, "tf2_msgs/msg/TFMessage"),
            (msg.TF2Error, "tf2_msgs/msg/TF2Error"),
        ):
            topic = f"/hash_check_{cls.__name__.lower()}"
            client.node.create_publisher(cls, topic, 1)
            info = client.node.get_publishers_info_by_topic(topic)
            assert info and info[0].topic_type == name
            assert str(info[0].topic_type_hash) == JAZZY.hash_rihs01(name)
    finally:
        client.close()


def test_generated_messages_have_jazzys_wire_format():
    """Bytes from the generated typesupport decode with rosbags' CDR reader and back."""
    msg = tf2_msgs()
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = "map", "ventil_ä_1"
    t.header.stamp.sec, t.header.stamp.nanosec = 17, 250
    t.transform = matrix_to_transform(
        make_T(quat_xyzw_to_matrix([0.0, 0.6, 0.0, 0.8]), [1.0, -2.0, 0.25])
    )
    out = JAZZY.deserialize_cdr(
        serialize_message(msg.TFMessage(transforms=[t, t])), "tf2_msgs/msg/TFMessage"
    )
    assert len(out.transforms) == 2 and out.transforms[1].child_frame_id == "ventil_ä_1"
    assert out.transforms[0].header.stamp.nanosec == 250
    assert out.transforms[0].transform.rotation.y == pytest.approx(0.6)
    assert out.transforms[0].transform.translation.z == pytest.approx(0.25)
    Err = JAZZY.types["tf2_msgs/msg/TF2Error"]
    raw = JAZZY.serialize_cdr(
        Err(error=msg.TF2Error.TIMEOUT_ERROR, error_string="late"), "tf2_msgs/msg/TF2Error"
    )
    back = deserialize_message(bytes(raw), msg.TF2Error)
    assert (back.error, back.error_string) == (5, "late")


def test_build_failure_is_one_line_and_installs_nothing(tmp_path):
    """A machine where the build cannot run: one line, status 1, nothing half-installed."""
    env = dict(os.environ, CXX="/nonexistent/g++")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "affordance_registration.ros.standins.interfaces.build",
            "--prefix",
            str(tmp_path),
            "--force",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    lines = done.stdout.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, (done.stdout, done.stderr)
    assert lines[0].startswith("tf2_msgs not built:") and "C++ compiler" in lines[0]
    assert done.stderr == ""
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ a live node
@pytest.fixture(scope="module")
def live(ros_context, tmp_path_factory, library):
    msg = tf2_msgs()
    tmp = tmp_path_factory.mktemp("tf_node")
    client = Client("tf_tester")
    # another publisher of static frames: FRAME and TF_ONLY both hang off TF_ROOT, so reaching
    # TF_ONLY from FRAME follows one transform up and one down
    T_root_cam = make_T(
        quat_xyzw_to_matrix([0.0, 0.0, math.sin(0.3), math.cos(0.3)]), [0.4, -0.1, 0.2]
    )
    T_root_tfonly = make_T(
        quat_xyzw_to_matrix([math.sin(0.4), 0.0, 0.0, math.cos(0.4)]), [-0.3, 0.25, 0.9]
    )
    static_pub = client.node.create_publisher(msg.TFMessage, "/tf_static", LATCHED)
    static = []
    for child, T in ((FRAME, T_root_cam), (TF_ONLY, T_root_tfonly)):
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = TF_ROOT, child
        t.transform = matrix_to_transform(T)
        static.append(t)
    static_pub.publish(msg.TFMessage(transforms=static))
    client.subscribe(msg.TFMessage, "/tf_static", STATIC_QOS, keep=True)
    client.subscribe(msg.TFMessage, "/tf", 100, keep=True)
    client.subscribe(String, f"{NS}/status", LATCHED)
    client.subscribe(PoseStamped, f"{NS}/fit")
    proc = engine_process(tmp, {"refit_idle_s": 0.4})
    pubs = {
        "points": client.node.create_publisher(PointCloud2, "/points", 1),
        "click": client.node.create_publisher(PointStamped, "/clicked_point", 10),
        "twist": client.node.create_publisher(Twist, "/spacenav/twist", 10),
    }
    sim = simulate_taskboard(library, 11)
    try:
        for pub in pubs.values():
            client.wait_for_subscribers(pub, timeout=30)
        # the engine has matched the static frames published above (transient local)
        client.wait_for(
            lambda: any(
                i.node_name == "affordance_engine"
                for i in client.node.get_subscriptions_info_by_topic("/tf_static")
            ),
            30,
            "the engine's /tf_static subscription",
        )
        pubs["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
        client.wait_for(
            lambda: (status(client)["node"]["cloud"] or {}).get("width") == 640, 30, "the cloud"
        )
        yield {
            "proc": proc,
            "client": client,
            "pubs": pubs,
            "sim": sim,
            "msg": msg,
            "T_cam_tfonly": invert(T_root_cam) @ T_root_tfonly,
        }
    finally:
        client.close()
        proc.interrupt()
        proc.kill()
        print(proc.output()[-3000:])


def status(client) -> dict:
    return client.status(f"{NS}/status") or {
        "objects": [],
        "registered": [],
        "node": {"cloud": None, "last_error": ""},
    }


def engine_static_sets(client) -> list[dict]:
    """The /tf_static messages from the engine (those without the test's own frames), each as
    child -> TransformStamped, oldest first."""
    sets = []
    for m in list(client.history.get("/tf_static", [])):
        children = {t.child_frame_id: t for t in m.transforms}
        if TF_ONLY not in children:
            sets.append(children)
    return sets


def click(s, point, frame=FRAME):
    msg = PointStamped()
    msg.header.frame_id = frame
    msg.point.x, msg.point.y, msg.point.z = (float(v) for v in point)
    s["pubs"]["click"].publish(msg)


def fit_object(s, obj, frame=FRAME, point=None) -> dict:
    """Click and wait for the new object (ids are never reused); returns it."""
    st = status(s["client"])
    seen = max([o["id"] for o in st["objects"] + st["registered"]], default=0)
    click(s, obj.click if point is None else point, frame)
    return s["client"].wait_for(
        lambda: next((o for o in status(s["client"])["objects"] if o["id"] > seen), None),
        60,
        f"the fit of a click in {frame}",
    )


def candidate_transforms(client) -> list:
    return [
        t
        for m in list(client.history.get("/tf", []))
        for t in m.transforms
        if t.child_frame_id == "affordance_candidate"
    ]


def test_accepted_object_is_a_frame_on_tf_static(live, library):
    s, client = live, live["client"]
    obj = s["sim"].objects[0]
    assert fit_object(s, obj)["candidates"][0]["template"] == obj.template
    res = client.call(Trigger, f"{NS}/accept")
    assert res.success, res.message
    reg = client.wait_for(
        lambda: status(client)["registered"] and status(client)["registered"][-1],
        what="the registration",
    )
    child = f"{reg['template']}_{reg['id']}"
    frames = client.wait_for(
        lambda: next((f for f in reversed(engine_static_sets(client)) if child in f), None),
        what=f"{child} on /tf_static",
    )
    t = frames[child]
    assert t.header.frame_id == FRAME
    T = transform_to_matrix(t.transform)
    assert np.allclose(T, np.asarray(reg["pose"]), atol=1e-6)
    dt, dr = pose_error(T, obj.T_scene_model, library[obj.template].symmetry)
    assert dt < TOL_M and dr < TOL_RAD, (dt, dr)
    # the engine's /tf_static publisher is transient local and advertises Jazzy's hash
    info = [
        i
        for i in client.node.get_publishers_info_by_topic("/tf_static")
        if i.node_name == "affordance_engine"
    ]
    assert len(info) == 1
    assert info[0].qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert str(info[0].topic_type_hash) == JAZZY.hash_rihs01("tf2_msgs/msg/TFMessage")
    s["child"], s["T_child"] = child, T


def late_static_sets(s) -> list[dict]:
    """What a listener that subscribes now receives from the engine on /tf_static."""
    late = Client("tf_late_listener")
    try:
        late.subscribe(s["msg"].TFMessage, "/tf_static", STATIC_QOS, keep=True)
        return late.wait_for(lambda: engine_static_sets(late), 30, "the latched static set")
    finally:
        late.close()


def test_a_late_listener_still_gets_the_frame(live):
    s = live
    assert "child" in s, "needs test_accepted_object_is_a_frame_on_tf_static"
    sets = late_static_sets(s)
    assert len(sets) == 1 and s["child"] in sets[0]
    T = transform_to_matrix(sets[0][s["child"]].transform)
    assert np.allclose(T, s["T_child"], atol=1e-9)


def test_undo_takes_the_frame_off_tf_static(live):
    s, client = live, live["client"]
    assert "child" in s, "needs test_accepted_object_is_a_frame_on_tf_static"
    n = len(engine_static_sets(client))
    res = client.call(Trigger, f"{NS}/undo")
    assert res.success, res.message
    latest = client.wait_for(
        lambda: len(engine_static_sets(client)) > n and [engine_static_sets(client)[-1]],
        what="the new static set",
    )[0]
    assert s["child"] not in latest
    sets = late_static_sets(s)
    assert len(sets) == 1 and s["child"] not in sets[0]


def test_candidate_frame_follows_a_correction(live, library):
    """The undone object is open again: its shown fit is affordance_candidate on /tf; a
    SpaceMouse push moves the frame, and after the refit it sits where ~/fit says."""
    s, client = live, live["client"]
    obj = s["sim"].objects[0]

    def shown_pose():
        active = [o for o in status(client)["objects"] if o["active"]]
        return np.asarray(active[0]["candidates"][active[0]["shown"]]["pose"]) if active else None

    def candidate_at(T):
        tfs = candidate_transforms(client)
        return (
            bool(tfs)
            and tfs[-1].header.frame_id == FRAME
            and np.allclose(transform_to_matrix(tfs[-1].transform), T, atol=1e-6)
        )

    before = client.wait_for(
        lambda: (lambda T: T is not None and [T])(shown_pose()), what="the open object"
    )[0]
    client.wait_for(lambda: candidate_at(before), what="affordance_candidate at the shown fit")
    client.history["/tf"] = []
    twist = Twist()
    twist.linear.y = -0.5  # about 1.5 cm to the right on the screen
    for _ in range(9):  # a 0.3 s push at the device's 30 Hz
        s["pubs"]["twist"].publish(twist)
        time.sleep(1 / 30)
    s["pubs"]["twist"].publish(Twist())
    client.wait_for(
        lambda: (
            max(
                (
                    np.linalg.norm(transform_to_matrix(t.transform)[:3, 3] - before[:3, 3])
                    for t in candidate_transforms(client)
                ),
                default=0,
            )
            > 0.004
        ),
        what="the candidate frame to move with the push",
    )
    # the refit lands back on the object and the frame follows it there
    client.wait_for(
        lambda: (
            lambda T: (
                T is not None
                and pose_error(T, obj.T_scene_model, library[obj.template].symmetry)[0] < TOL_M
                and candidate_at(T)
            )
        )(shown_pose()),
        30,
        "the frame at the refitted pose",
    )
    assert client.call(Trigger, f"{NS}/discard").success


def test_click_in_a_frame_known_only_from_tf_static(live):
    s, client = live, live["client"]
    obj = s["sim"].objects[1]
    p_cam = np.asarray(obj.click, dtype=float)
    T_tfonly_cam = invert(s["T_cam_tfonly"])
    p_tfonly = T_tfonly_cam[:3, :3] @ p_cam + T_tfonly_cam[:3, 3]
    assert np.linalg.norm(p_tfonly - p_cam) > 0.3  # the transform matters
    # the engine learns TF_ONLY from /tf_static once discovery has matched it with the
    # publisher (on a busy machine, maybe after this test starts): a click before that is
    # refused with a line naming the frame; click again until it is not
    deadline = time.monotonic() + 60
    while True:
        st = status(client)
        seen = max([o["id"] for o in st["objects"] + st["registered"]], default=0)
        refusals = st["node"].get("received", {}).get("/clicked_point", 0)
        click(s, p_tfonly, TF_ONLY)
        outcome = client.wait_for(
            lambda: (
                next((("fit", o) for o in status(client)["objects"] if o["id"] > seen), None)
                or (
                    status(client)["node"]["handled"].get("/clicked_point", 0) > refusals
                    and TF_ONLY in status(client)["node"]["last_error"]
                    and ("refused", None)
                )
            ),
            60,
            f"the click in {TF_ONLY}",
        )
        if outcome[0] == "fit" or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert outcome[0] == "fit", status(client)["node"]["last_error"]
    new = outcome[1]
    assert new["candidates"][0]["template"] == obj.template
    assert np.linalg.norm(np.asarray(new["click"]) - p_cam) < 0.005
    assert client.call(Trigger, f"{NS}/discard").success


def test_waypoints_are_frames_under_the_object_and_a_path_is_answered(live, library):
    """The shown candidate's waypoints are frames under ``affordance_candidate`` on /tf; once
    accepted, under the registration's frame on /tf_static, where the status says (cloud
    frame) and on the lever of the scene; ``~/path_request`` is answered on ``~/path`` in the
    cloud frame, and refused in one line for an unknown object or state."""
    s, client = live, live["client"]
    obj = next(o for o in s["sim"].objects if o.template == "ball_valve")
    assert fit_object(s, obj)["candidates"][0]["template"] == "ball_valve"
    names = {"affordance_candidate/lever_grasp", "affordance_candidate/pre_lever_grasp"}
    seen = client.wait_for(
        lambda: [
            t
            for m in list(client.history.get("/tf", []))
            for t in m.transforms
            if t.child_frame_id in names
        ],
        30,
        "the candidate's waypoint frames on /tf",
    )
    assert {t.header.frame_id for t in seen} == {"affordance_candidate"}
    assert client.call(Trigger, f"{NS}/accept").success
    reg = client.wait_for(
        lambda: status(client)["registered"] and status(client)["registered"][-1],
        what="the registration",
    )
    child = f"{reg['template']}_{reg['id']}"
    frames = client.wait_for(
        lambda: next(
            (f for f in reversed(engine_static_sets(client)) if f"{child}/lever_grasp" in f), None
        ),
        30,
        f"{child}/lever_grasp on /tf_static",
    )
    T_cam_obj = transform_to_matrix(frames[child].transform)
    (wp,) = reg["waypoints"]
    for name, key in (("lever_grasp", "pose"), ("pre_lever_grasp", "pre_pose")):
        t = frames[f"{child}/{name}"]
        assert t.header.frame_id == child
        T_cam_wp = T_cam_obj @ transform_to_matrix(t.transform)
        assert np.allclose(T_cam_wp, np.asarray(wp[key]), atol=1e-6)
    # the autosaved registrations file carries them too, in the cloud frame
    saved = yaml.safe_load(open(status(client)["node"]["registrations_file"]["path"]))
    entry = next(r for r in saved["registrations"] if r["id"] == reg["id"])
    assert entry["frame_id"] == FRAME
    assert np.allclose(entry["waypoints"][0]["pose"], np.asarray(wp["pose"]), atol=1e-8)
    # on the lever of the simulated scene (joint and pose as estimated)
    lever = library["ball_valve"].moving_mesh_at(obj.joints.get("lever", 0.0)).copy()
    lever.apply_transform(obj.T_scene_model)
    from affordance_registration.core.meshes import mesh_distance

    assert mesh_distance(lever, np.asarray(wp["position"])[None])[0] < 0.005
    # the path to closed, in the cloud frame: approach, the grasp, ..., the retreat
    client.subscribe(PoseArray, f"{NS}/path", LATCHED)
    request = client.node.create_publisher(String, f"{NS}/path_request", 10)
    client.wait_for_subscribers(request, timeout=30)
    request.publish(String(data=f"{reg['id']} closed"))
    path = client.wait_for(lambda: client.latest.get(f"{NS}/path"), 30, "the path")
    assert path.header.frame_id == FRAME
    poses = [pose_to_matrix(p) for p in path.poses]
    q0 = reg["joints"]["lever"]
    assert len(poses) == 3 + max(1, math.ceil((math.pi / 2 - q0) / math.radians(5) - 1e-9))
    assert np.allclose(poses[0], np.asarray(wp["pre_pose"]), atol=1e-6)
    assert np.allclose(poses[1], np.asarray(wp["pose"]), atol=1e-6)
    axis, centre = T_cam_obj[:3, 2], T_cam_obj[:3, :3] @ [0, 0, 0.085] + T_cam_obj[:3, 3]
    radius = [np.linalg.norm(np.cross(P[:3, 3] - centre, axis)) for P in poses[1:-1]]
    assert np.ptp(radius) < 1e-6 and radius[0] > 0.1  # on the lever's circle
    for line, words in (
        ("99 closed", "no object 99"),
        (f"{reg['id']} ajar", "no state 'ajar'"),
        ("closed", "expected 'OBJECT_ID STATE"),
    ):
        request.publish(String(data=line))
        error = client.wait_for(
            lambda: (
                words in status(client)["node"]["last_error"]
                and status(client)["node"]["last_error"]
            ),
            30,
            f"refusal of {line!r}",
        )
        assert error.startswith("path request refused: ") and "\n" not in error
    assert client.call(Trigger, f"{NS}/undo").success


def test_msg_docs_list_every_declared_parameter(live):
    client = live["client"]
    res = client.call(ListParameters, f"{NS}/list_parameters")
    declared = {
        n
        for n in res.result.names  # less what rclpy declares on every node
        if n not in ("use_sim_time", "start_type_description_service")
        and not n.startswith("qos_overrides.")
    }
    assert len(declared) > 20
    text = (ROOT / "msg_docs" / "README.md").read_text()
    node = text[text.index("## Node `affordance_engine`") :]
    table = node[node.index("### Parameters") :]
    table = table[: table.index("\n### ", 5)]
    documented = set()
    for line in table.splitlines():
        if line.startswith("| `"):
            documented |= set(re.findall(r"`([a-z_0-9.]+)`", line.split("|")[1]))
    assert declared - documented == set(), "declared but not in msg_docs"
    assert documented - declared == set(), "in msg_docs but not declared"


# ------------------------------------------------------------------ without tf2_msgs
def test_node_runs_without_tf2_msgs(ros_context, tmp_path):
    """tf2_msgs hidden (as where `make setup` could not build it): the node says so once,
    serves, and has no TF publisher."""
    hide = tmp_path / "hide" / "tf2_msgs"
    hide.mkdir(parents=True)
    (hide / "__init__.py").write_text("raise ImportError('hidden by the test')\n")
    env = {
        "PYTHONPATH": os.pathsep.join(
            [str(tmp_path / "hide")]
            + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
        )
    }
    proc = NodeProcess(
        [
            sys.executable,
            "-m",
            "affordance_registration.ros.nodes.engine_node",
            "--ros-args",
            "-r",
            "__node:=engine_without_tf",
            "-p",
            f"registrations_file:={tmp_path / 'registrations.yaml'}",
        ],
        tmp_path / "engine.log",
        env=env,
    )
    client = Client("no_tf_tester")
    try:
        assert proc.wait_output("ready:", timeout=60), proc.output()
        assert proc.output().count("tf2_msgs is not installed") == 1
        res = client.call(Trigger, "/engine_without_tf/accept", timeout=30)
        assert not res.success and "no object selected" in res.message
        assert not [
            i
            for i in client.node.get_publishers_info_by_topic("/tf_static")
            if i.node_name == "engine_without_tf"
        ]
    finally:
        client.close()
        code, _ = proc.interrupt()
        proc.kill()
    assert code == 0, proc.output()
