# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A camera on a moving robot, and what a planner and a perception consumer read: a real engine
node with ``fixed_frame: odom``, its clouds in the camera's optical frame and the camera's pose
on /tf, published here. Between two clouds of one simulated scene the camera moves 0.3 m and
turns 20 deg: the registration made before the move stays where it was in odom, and an object
clicked after it is fitted where it is. Registrations go out as MoveIt collision objects (ADD,
MOVE, REMOVE), open objects as vision_msgs detections, ranked, with covariances."""

import math
import time

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PointStamped, TransformStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.serialization import deserialize_message, serialize_message
from ros_helpers import LATCHED, Client, engine_process
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from affordance_registration.core.detections import UNHELD_VARIANCE, pose_covariance
from affordance_registration.core.transforms import (
    axis_angle_matrix,
    invert,
    make_T,
    pose_error,
    quat_xyzw_to_matrix,
)
from affordance_registration.evaluation.simulation import DepthCamera, simulate_taskboard
from affordance_registration.evaluation.viewpoints import taskboard_meshes
from affordance_registration.ros.glue.conversions import (
    matrix_to_transform,
    pose_to_matrix,
    xyz_to_pointcloud2,
)

NS = "/affordance_engine"
CAMERA = "camera_depth_optical_frame"
FIXED = "odom"
TOL_M, TOL_RAD = 0.005, math.radians(5)
#: the camera's first pose on the robot's odometry frame (looking forward and down)
T_ODOM_CAM1 = make_T(quat_xyzw_to_matrix([-0.62, 0.6, -0.34, 0.36]), [0.4, -0.2, 0.9])
#: the move between the two clouds: 0.3 m along the camera's x, turned 20 deg about its y
T_CAM1_CAM2 = make_T(axis_angle_matrix([0, 1, 0], math.radians(-20)), [0.3, 0.0, 0.0])
#: the RIHS01 type hashes of the published ROS 2 Jazzy definitions (moveit_msgs 2.6.0,
#: object_recognition_msgs 2.0.0, vision_msgs 4.1.1), as rosbags' typestore computes them
JAZZY_HASHES = {
    "object_recognition_msgs/msg/ObjectType": (
        "RIHS01_5eb3ee3976403366d7c50d7dbee8bec96b3bced1e752674a7194a35841632134"
    ),
    "moveit_msgs/msg/CollisionObject": (
        "RIHS01_74b0acd6d56be032bf4f764b2c2633f50588b5fb2bd71e97206c59052747cf7e"
    ),
    "vision_msgs/msg/ObjectHypothesis": (
        "RIHS01_51da43cec11c01957a64d1e05a24acd18aae7745ec30b74348ad5f6d634f7f90"
    ),
    "vision_msgs/msg/BoundingBox3D": (
        "RIHS01_bbb73a65c163d7f9bb29009c7bde9f7faa576bd2d23299c4511d19230dab4698"
    ),
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "RIHS01_41c12344c0396c48b81df12467c192d99b2a0eb1463c5c37194e4223251c80bc"
    ),
    "vision_msgs/msg/Detection3D": (
        "RIHS01_ddd703be132ab0b69d33121f1bb034132bfbb3b0ac5f9fb1516005ba1c8a265b"
    ),
    "vision_msgs/msg/Detection3DArray": (
        "RIHS01_793f5eab9595ac1c0da07873cc859db42eae51f0ee76056db8562515d830e018"
    ),
}


def interfaces():
    """The built message classes (a failure, not a skip: `make setup` builds them)."""
    try:
        from moveit_msgs.msg import CollisionObject
        from tf2_msgs.msg import TFMessage
        from vision_msgs.msg import Detection3D, Detection3DArray, ObjectHypothesisWithPose
    except ImportError as exc:
        pytest.fail(f"{exc}: `make setup` did not build the interfaces -- see its output")
    return CollisionObject, TFMessage, Detection3DArray, Detection3D, ObjectHypothesisWithPose


def stamp_of(t: float):
    from builtin_interfaces.msg import Time

    return Time(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))


# ---------------------------------------------------------------------------- the live node
@pytest.fixture(scope="module")
def moving(ros_context, tmp_path_factory, library):
    CollisionObject, TFMessage, Detection3DArray, _, _ = interfaces()
    tmp = tmp_path_factory.mktemp("moving_camera")
    sim = simulate_taskboard(library, 7)
    # the second cloud: the same scene seen from the moved camera, in its optical frame
    meshes = taskboard_meshes(sim, library)
    T_cam2_cam1 = invert(T_CAM1_CAM2)
    second, labels = DepthCamera().render(
        [(m, T_cam2_cam1 @ T) for m, T in meshes], np.random.default_rng(2)
    )
    client = Client("moving_camera_tester")
    client.subscribe(String, f"{NS}/status", LATCHED)
    client.subscribe(TFMessage, "/tf_static", LATCHED, keep=True)
    client.subscribe(CollisionObject, "/collision_object", 100, keep=True)
    client.subscribe(Detection3DArray, f"{NS}/detections", 10, keep=True)
    proc = engine_process(tmp, {"fixed_frame": FIXED, "refit_on_new_cloud": "false"})
    pubs = {
        "points": client.node.create_publisher(PointCloud2, "/points", 1),
        "click": client.node.create_publisher(PointStamped, "/clicked_point", 10),
        "tf": client.node.create_publisher(TFMessage, "/tf", 100),
        "tf_static": client.node.create_publisher(TFMessage, "/tf_static", LATCHED),
    }
    try:
        for pub in pubs.values():
            client.wait_for_subscribers(pub, timeout=30)
        yield {
            "proc": proc,
            "client": client,
            "pubs": pubs,
            "sim": sim,
            "second": second,
            "second_labels": labels,
            "msg": TFMessage,
            "t1": float(int(time.time())),
        }
    finally:
        client.close()
        proc.interrupt()
        proc.kill()
        print(proc.output()[-3000:])


def status(s) -> dict:
    return s["client"].status() or {"objects": [], "registered": [], "node": {}}


def publish_camera(s, T_odom_cam, t: float) -> None:
    tf = TransformStamped()
    tf.header.frame_id, tf.child_frame_id, tf.header.stamp = FIXED, CAMERA, stamp_of(t)
    tf.transform = matrix_to_transform(T_odom_cam)
    s["pubs"]["tf"].publish(s["msg"](transforms=[tf]))


def publish_cloud(s, organized, t: float) -> int:
    """Publish a cloud in the camera frame stamped ``t``; returns the engine's count of it."""
    count = (status(s)["node"].get("cloud") or {}).get("received", 0)
    msg = xyz_to_pointcloud2(organized, CAMERA)
    msg.header.stamp = stamp_of(t)
    s["pubs"]["points"].publish(msg)
    s["client"].wait_for(
        lambda: (status(s)["node"].get("cloud") or {}).get("received", 0) > count,
        30,
        "the cloud",
    )
    return count + 1


def click(s, point, t: float, camera=None) -> dict:
    """Click ``point`` (camera frame) stamped ``t``; returns the object it opens. A click the
    engine refuses because the camera's transform has not reached it yet (discovery may hold
    back the first TF messages) is made again, the transform published again first."""
    st = status(s)
    seen = max([o["id"] for o in st["objects"] + st["registered"]], default=0)
    msg = PointStamped()
    msg.header.frame_id, msg.header.stamp = CAMERA, stamp_of(t)
    msg.point.x, msg.point.y, msg.point.z = (float(v) for v in point)
    deadline = time.monotonic() + 60
    while True:
        handled = status(s)["node"].get("handled", {}).get("/clicked_point", 0)
        s["pubs"]["click"].publish(msg)
        outcome = s["client"].wait_for(
            lambda: (
                next((o for o in status(s)["objects"] if o["id"] > seen), None)
                or (
                    status(s)["node"]["handled"].get("/clicked_point", 0) > handled
                    and status(s)["node"]["idle"]
                    and "TF" in status(s)["node"]["last_error"]
                    and "refused"
                )
            ),
            120,
            "the fit of the click",
        )
        if outcome != "refused" or time.monotonic() > deadline:
            assert outcome != "refused", status(s)["node"]["last_error"]
            return outcome
        if camera is not None:
            publish_camera(s, camera, t)
        time.sleep(0.5)


def shown_pose(obj: dict) -> np.ndarray:
    return np.asarray(obj["candidates"][obj["shown"]]["pose"])


def collision(s) -> list:
    return list(s["client"].history.get("/collision_object", []))


def test_a_registration_stays_put_in_odom_while_the_camera_moves(moving, library):
    """Cloud 1 at t1 with the camera at T_ODOM_CAM1; ball valve clicked and accepted: it is in
    odom where the scene has it. The camera moves (0.3 m, 20 deg) and cloud 2 comes at t2: the
    registration does not move (1 mm), and the gate valve clicked in cloud 2 is fitted within
    5 mm / 5 deg of where it is. Registrations are TF children of odom."""
    s, sim = moving, moving["sim"]
    t1, t2 = s["t1"], s["t1"] + 2.0
    client = s["client"]
    client.wait_for(
        lambda: any(
            i.node_name == "affordance_engine"
            for i in client.node.get_subscriptions_info_by_topic("/tf")
        ),
        30,
        "the engine's /tf subscription",
    )
    publish_camera(s, T_ODOM_CAM1, t1)
    publish_cloud(s, sim.organized, t1)
    valve = next(o for o in sim.objects if o.template == "ball_valve")
    first = click(s, valve.click, t1, T_ODOM_CAM1)
    assert first["candidates"][0]["template"] == "ball_valve"
    truth = T_ODOM_CAM1 @ valve.T_scene_model
    dt, dr = pose_error(shown_pose(first), truth, library["ball_valve"].symmetry)
    assert dt < TOL_M and dr < TOL_RAD, (dt, dr)
    assert client.call(Trigger, f"{NS}/accept").success
    reg = client.wait_for(lambda: status(s)["registered"] and status(s)["registered"][0])
    assert reg["frame_id"] == FIXED and status(s)["frame_id"] == FIXED
    before = np.asarray(reg["pose"])
    # the robot moves; the camera's new pose reaches TF, then its cloud
    T_odom_cam2 = T_ODOM_CAM1 @ T_CAM1_CAM2
    publish_camera(s, T_odom_cam2, t2)
    publish_cloud(s, s["second"], t2)
    k = next(i for i, o in enumerate(sim.objects) if o.template == "gate_valve")
    pixels = s["second"][s["second_labels"] == k + 1].astype(float)
    point = pixels[np.argmin(np.linalg.norm(pixels - pixels.mean(axis=0), axis=1))]
    second = click(s, point, t2, T_odom_cam2)
    assert second["candidates"][0]["template"] == "gate_valve"
    truth = T_ODOM_CAM1 @ sim.objects[k].T_scene_model
    dt, dr = pose_error(shown_pose(second), truth, library["gate_valve"].symmetry)
    assert dt < TOL_M and dr < TOL_RAD, (dt, dr)
    # the click went through TF at its stamp: it lies on the gate valve where odom has it
    assert (
        np.linalg.norm(
            np.asarray(second["click"]) - (T_odom_cam2[:3, :3] @ point + T_odom_cam2[:3, 3])
        )
        < 0.01
    )
    after = np.asarray(status(s)["registered"][0]["pose"])
    assert np.linalg.norm(after[:3, 3] - before[:3, 3]) < 0.001
    assert pose_error(after, before)[1] < math.radians(0.1)
    frames = client.wait_for(
        lambda: next(
            (
                {t.child_frame_id: t for t in m.transforms}
                for m in reversed(client.history.get("/tf_static", []))
                if f"ball_valve_{reg['id']}" in {t.child_frame_id for t in m.transforms}
            ),
            None,
        ),
        30,
        "the registration on /tf_static",
    )
    assert frames[f"ball_valve_{reg['id']}"].header.frame_id == FIXED
    saved = yaml.safe_load(open(status(s)["node"]["registrations_file"]["path"]))
    assert saved["frame_id"] == FIXED and saved["registrations"][0]["frame_id"] == FIXED
    s["valve"], s["gate"] = reg, second


def test_a_cloud_tf_cannot_place_is_refused_and_the_scene_kept(moving):
    """A cloud stamped long before anything TF holds: one line, and the click after it is still
    fitted on the scene it had."""
    s = moving
    assert "gate" in s, "needs the moving camera test"
    old = s["t1"] - 60.0
    publish_cloud(s, s["second"][::2, ::2], old)
    assert s["client"].call(Trigger, f"{NS}/refit").success  # refits on the scene it has
    error = s["client"].wait_for(
        lambda: (
            "the latest cloud" in status(s)["node"]["last_error"]
            and status(s)["node"]["last_error"]
        ),
        30,
        "the refusal",
    )
    assert "still using the previous one" in error and CAMERA in error, error
    assert "\n" not in error


def test_collision_objects_follow_accept_undo_and_the_frame(moving, library):
    """The accepted valve was ADDed (its mesh, its pose in odom, its waypoints as subframes);
    accepting the gate valve ADDs it; an undo REMOVEs it; accepted again after a correction, it
    is ADDed where the correction put it; with the fixed frame set to map (odom hangs off
    map on /tf_static), both are MOVEd there."""
    s, client = moving, moving["client"]
    M = interfaces()[0]
    valve_id = f"ball_valve_{s['valve']['id']}"
    added = client.wait_for(
        lambda: next((m for m in collision(s) if m.id == valve_id and m.operation == M.ADD), 0),
        30,
        "the valve's ADD",
    )
    assert added.header.frame_id == FIXED
    assert np.allclose(pose_to_matrix(added.pose), np.asarray(s["valve"]["pose"]), atol=1e-6)
    assert len(added.meshes) == 1 and not added.primitives
    mesh = added.meshes[0]
    tpl = library["ball_valve"]
    lever = s["valve"]["joints"]["lever"]
    expected = tpl.mesh_at(lever, s["valve"]["scale"])
    assert len(mesh.vertices) == len(expected.vertices) and len(mesh.triangles) == len(
        expected.faces
    )
    assert {"lever_grasp", "pre_lever_grasp"} == set(added.subframe_names)
    (wp,) = s["valve"]["waypoints"]
    T_obj = pose_to_matrix(added.pose)
    sub = pose_to_matrix(added.subframe_poses[added.subframe_names.index("lever_grasp")])
    assert np.allclose(T_obj @ sub, np.asarray(wp["pose"]), atol=1e-6)
    # the gate valve: accept (ADD), undo (REMOVE)
    gate_id = f"gate_valve_{s['gate']['id']}"
    n = len(collision(s))
    assert client.call(Trigger, f"{NS}/accept").success
    add = client.wait_for(lambda: next((m for m in collision(s)[n:] if m.id == gate_id), 0))
    assert add.operation == M.ADD and add.header.frame_id == FIXED
    n = len(collision(s))
    assert client.call(Trigger, f"{NS}/undo").success
    gone = client.wait_for(lambda: next((m for m in collision(s)[n:] if m.id == gate_id), 0))
    assert gone.operation == M.REMOVE
    # a correction (the joint stepped and the pose refit), then accepted again
    assert client.call(Trigger, f"{NS}/joint_plus").success
    n = len(collision(s))
    assert client.call(Trigger, f"{NS}/accept").success
    again = client.wait_for(lambda: next((m for m in collision(s)[n:] if m.id == gate_id), 0))
    assert again.operation == M.ADD
    stem = s["gate"]["candidates"][s["gate"]["shown"]]["joints"]["stem"] + 0.002  # one step
    reg = client.wait_for(
        lambda: next(
            (
                r
                for r in status(s)["registered"]
                if r["id"] == s["gate"]["id"] and abs(r["joints"]["stem"] - stem) < 1e-6
            ),
            None,
        ),
        30,
        "the corrected registration",
    )
    assert np.allclose(pose_to_matrix(again.pose), np.asarray(reg["pose"]), atol=1e-6)
    moved = [a.x - b.x for a, b in zip(again.meshes[0].vertices, add.meshes[0].vertices)]
    assert max(np.abs(moved)) > 0  # its mesh at the new joint value
    assert not any(m.id == valve_id for m in collision(s)[n:])  # the valve is left alone
    # the fixed frame becomes map: both registrations move there, their shapes unchanged
    T_map_odom = make_T(axis_angle_matrix([0, 0, 1], 0.5), [2.0, -1.0, 0.0])
    tf = TransformStamped(child_frame_id=FIXED)
    tf.header.frame_id = "map"
    tf.transform = matrix_to_transform(T_map_odom)
    s["pubs"]["tf_static"].publish(s["msg"](transforms=[tf]))
    n = len(collision(s))
    value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="map")
    res = client.call(
        SetParameters,
        f"{NS}/set_parameters",
        SetParameters.Request(parameters=[Parameter(name="fixed_frame", value=value)]),
    )
    assert res.results[0].successful, res.results[0].reason
    # the next scene is made in map: the second cloud again, and a click on the emergency stop
    t2 = s["t1"] + 2.0
    publish_cloud(s, s["second"], t2)
    k = next(i for i, o in enumerate(s["sim"].objects) if o.template == "emergency_stop")
    pixels = s["second"][s["second_labels"] == k + 1].astype(float)
    s["estop"] = click(
        s, pixels[np.argmin(np.linalg.norm(pixels - pixels.mean(axis=0), axis=1))], t2
    )
    moved = client.wait_for(
        lambda: (
            {m.id: m for m in collision(s)[n:]}
            if {valve_id, gate_id} <= {m.id for m in collision(s)[n:]}
            else None
        ),
        60,
        "the MOVEs",
    )
    for m in moved.values():
        assert m.operation == M.MOVE and m.header.frame_id == "map"
        assert not m.meshes and not m.primitives and not m.subframe_names
    T_valve_map = T_map_odom @ np.asarray(s["valve"]["pose"])
    assert np.allclose(pose_to_matrix(moved[valve_id].pose), T_valve_map, atol=1e-6)
    assert status(s)["frame_id"] == "map"
    # turned off: the planning scene is emptied
    value = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=False)
    n = len(collision(s))
    res = client.call(
        SetParameters,
        f"{NS}/set_parameters",
        SetParameters.Request(parameters=[Parameter(name="collision_objects", value=value)]),
    )
    assert res.results[0].successful, res.results[0].reason
    removed = client.wait_for(
        lambda: len(collision(s)) >= n + 2 and collision(s)[n:], 30, "the REMOVEs"
    )
    assert {m.id for m in removed} == {valve_id, gate_id}
    assert all(m.operation == M.REMOVE for m in removed)


def test_detections_rank_the_candidates_with_covariances(moving):
    """The open emergency stop is one Detection3D: its results the ranked candidates (in rank
    order, scores the probabilities, the poses the status shows), each with a symmetric positive
    semi-definite covariance, small for the shown fit, and a box around the shown fit."""
    s, client = moving, moving["client"]
    assert "estop" in s, "needs the collision objects test"
    obj = s["estop"]
    detections = client.wait_for(
        lambda: next(
            (
                m
                for m in reversed(client.history.get(f"{NS}/detections", []))
                if any(d.id == str(obj["id"]) for d in m.detections)
            ),
            None,
        ),
        30,
        "the detection",
    )
    assert detections.header.frame_id == status(s)["frame_id"]
    det = next(d for d in detections.detections if d.id == str(obj["id"]))
    # in rank order (a template that fits before the measured primitives, whose probabilities
    # are over their own pool), each scored with its probability
    assert [r.hypothesis.class_id for r in det.results] == [
        c["template"] for c in obj["candidates"]
    ]
    assert det.results[0].hypothesis.class_id == "emergency_stop"
    for r, c in zip(det.results, obj["candidates"]):
        assert r.hypothesis.score == pytest.approx(c["probability"], abs=1e-6)
        assert np.allclose(pose_to_matrix(r.pose.pose), np.asarray(c["pose"]), atol=1e-6)
        cov = np.asarray(r.pose.covariance).reshape(6, 6)
        assert np.allclose(cov, cov.T, atol=1e-12)
        assert np.linalg.eigvalsh(cov).min() > -1e-12
    best = np.asarray(det.results[0].pose.covariance).reshape(6, 6)
    assert 0 < best[0, 0] < 0.005**2 and 0 < best[1, 1] < 0.005**2  # mm-level, the fit's
    box = pose_to_matrix(det.bbox.center)
    shown = shown_pose(obj)
    assert np.linalg.norm(box[:3, 3] - shown[:3, 3]) < 0.2
    assert min(det.bbox.size.x, det.bbox.size.y, det.bbox.size.z) > 0.005
    assert client.call(Trigger, f"{NS}/discard").success
    client.wait_for(
        lambda: not client.history[f"{NS}/detections"][-1].detections, 30, "no detection"
    )


# ---------------------------------------------------------------------------- without a node
def test_built_messages_round_trip_and_carry_jazzys_hashes(ros_context):
    """CollisionObject and Detection3DArray through rclpy's serializer and back, field for
    field; every built type advertises the hash of its published Jazzy definition."""
    CollisionObject, _, Detection3DArray, Detection3D, ObjectHypothesisWithPose = interfaces()
    from geometry_msgs.msg import Pose
    from object_recognition_msgs.msg import ObjectType
    from shape_msgs.msg import Mesh, MeshTriangle, SolidPrimitive
    from vision_msgs.msg import BoundingBox3D, ObjectHypothesis

    co = CollisionObject(id="ball_valve_3", operation=CollisionObject.ADD)
    co.header.frame_id = "odom"
    co.type.key = "k"
    co.primitives = [SolidPrimitive(type=SolidPrimitive.CYLINDER, dimensions=[0.2, 0.05])]
    co.pose.position.x = 1.25
    co.meshes = [Mesh(triangles=[MeshTriangle(vertex_indices=[0, 1, 2])])]
    co.subframe_names = ["lever_grasp"]
    co.subframe_poses = [Pose()]
    co.subframe_poses[0].position.x = 0.5
    back = deserialize_message(serialize_message(co), CollisionObject)
    assert back == co and back.operation == CollisionObject.ADD
    arr = Detection3DArray()
    d = Detection3D(id="4")
    h = ObjectHypothesisWithPose()
    h.hypothesis.class_id, h.hypothesis.score = "ball_valve", 0.75
    h.pose.covariance = np.arange(36, dtype=float)
    d.results = [h]
    d.bbox.size.z = 0.3
    arr.detections = [d]
    back = deserialize_message(serialize_message(arr), Detection3DArray)
    assert back == arr and list(back.detections[0].results[0].pose.covariance) == list(range(36))
    client = Client("interface_hash_checker")
    try:
        for cls in (
            ObjectType,
            CollisionObject,
            ObjectHypothesis,
            BoundingBox3D,
            ObjectHypothesisWithPose,
            Detection3D,
            Detection3DArray,
        ):
            name = f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
            topic = f"/hash_check_{cls.__name__.lower()}"
            client.node.create_publisher(cls, topic, 1)
            info = client.node.get_publishers_info_by_topic(topic)
            assert info and info[0].topic_type == name
            assert str(info[0].topic_type_hash) == JAZZY_HASHES[name], name
    finally:
        client.close()


@settings(max_examples=40)
@given(
    st.integers(0, 2**32 - 1),
    st.floats(0.0005, 0.02),
)
def test_pose_covariance_is_the_residual_scaled_inverse_in_pose_coordinates(seed, residual):
    """The covariance from the Hessian in the settledness check's coordinates (a rotation about
    the samples' centroid scaled by their RMS radius, then a translation) equals sigma^2
    (J^T J)^-1 computed directly in the pose's coordinates (the origin's motion, then the
    rotation): J's rows [n, (x - t) x n]."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(60, 3)) * rng.uniform(0.02, 0.2, size=3) + rng.normal(size=3)
    N = rng.normal(size=(60, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    q = rng.normal(size=4)
    T = make_T(quat_xyzw_to_matrix(q / np.linalg.norm(q)), rng.normal(size=3))
    c = X.mean(axis=0)
    L = math.sqrt(((X - c) ** 2).sum(axis=1).mean())
    J = np.concatenate([np.cross(X - c, N) / L, N], axis=1)
    got = pose_covariance((J.T @ J, c, L), T, residual)
    Jp = np.concatenate([N, np.cross(X - T[:3, 3], N)], axis=1)
    want = residual**2 * np.linalg.inv(Jp.T @ Jp)
    assert np.allclose(got, want, rtol=1e-6, atol=1e-12 * residual**2)
    assert np.allclose(pose_covariance(None, T, residual), np.eye(6) * UNHELD_VARIANCE)


def test_the_station_draws_the_cloud_in_the_fixed_frame(moving, tmp_path):
    """A station on the engine (its fixed frame now map): the camera's cloud is drawn in map,
    through TF at its stamp, as the engine's markers are."""
    from browser_helpers import free_port, station_argv
    from ros_helpers import NodeProcess

    s, client = moving, moving["client"]
    assert status(s)["frame_id"] == "map", "needs the collision objects test"
    port = free_port()
    station = NodeProcess(station_argv(port), tmp_path / "station.log")
    try:
        assert station.wait_output("operator station on", 120), station.output()
        client.wait_for_subscribers(s["pubs"]["points"], count=2, timeout=120)
        client.wait_for_subscribers(s["pubs"]["tf"], count=2, timeout=120)
        t3 = s["t1"] + 4.0
        publish_camera(s, T_ODOM_CAM1 @ T_CAM1_CAM2, t3)
        time.sleep(0.5)  # (the cloud is drawn with the newest transform it has)
        publish_cloud(s, s["second"], t3)
        assert station.wait_output(f"cloud drawn in 'map' (from '{CAMERA}')", 60), (
            station.output()[-2000:]
        )
    finally:
        station.interrupt(timeout=10)
        station.kill()
        print(station.output()[-2000:])
