# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The loop of ``station --demo`` over ROS: the simulated scan node (its own process) starts on a
hard first view of the demo's taskboard -- the quarter-turn valve seen edge-on (76-85 deg off
the panel's normal), which the engine (its own process) fits wrong and calls unsettled --; a
request on ``sensor_view_request`` with the engine's suggested view moves the simulated sensor
there, its new scan and pose reach the engine (the sensor's frame on TF), and the click is
fitted anew: the right template, within the pose tolerance, settled. Bad requests are refused
in one log line each and the node keeps running."""

import math
import sys
import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, PoseStamped
from ros_helpers import LATCHED, Client, NodeProcess, engine_process
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from affordance_registration.core.errors import AffordanceError
from affordance_registration.core.transforms import matrix_to_quat_xyzw, pose_error
from affordance_registration.evaluation.simulated_scan import (
    check_first_view,
    parse_pose,
    render_organized,
    view_problem,
)
from affordance_registration.evaluation.simulation import (
    POSE_TOL_M,
    POSE_TOL_RAD,
    simulate_taskboard,
)
from affordance_registration.evaluation.viewpoints import hard_view, taskboard_meshes
from affordance_registration.ros.glue.conversions import pose_stamped, transform_to_matrix
from affordance_registration.ros.glue.tf import STATIC_LISTENER_QOS, load_tf_message

FRAME = "camera_depth_optical_frame"
SENSOR = "simulated_camera_optical_frame"
SEED = 7  # the demo's taskboard
NS = "/affordance_engine"


def pose_text(T) -> str:
    return " ".join(f"{v:.9f}" for v in (*T[:3, 3], *matrix_to_quat_xyzw(T[:3, :3])))


def edge_on_case(library):
    """The demo taskboard's quarter-turn valve seen edge-on, as the viewpoint bench row scans
    it first: (sim, T_scene_sensor, the click -- its visible point nearest its median --,
    truth). (Fitted wrong and unsettled under every sensor noise tried.)"""
    sim = simulate_taskboard(library, SEED)
    k = next(i for i, o in enumerate(sim.objects) if o.template == "quarter_turn_valve")
    T = hard_view(sim, k, "edge-on", np.random.default_rng(SEED * 100 + k))
    organized, labels = render_organized(taskboard_meshes(sim, library), T, None)
    mine = organized[labels == k + 1].astype(float)
    click = mine[int(np.argmin(np.linalg.norm(mine - np.median(mine, axis=0), axis=1)))]
    return sim, T, click, sim.objects[k]


def click_on(client, pub, status, point, within: float = 60.0) -> None:
    """Click ``point`` and wait for its fit. An engine that has not yet heard the sensor's frame
    on TF (its transient-local /tf_static reader may match after the cloud's) cannot use the
    cloud and refuses the click in one line saying which transform it lacks: the click is sent
    again then (a quarter second after the refusal), until it is fitted or ``within`` seconds
    have passed."""
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, point)

    def handled() -> int:
        return int(((status().get("node") or {}).get("handled") or {}).get("/clicked_point", 0))

    deadline, tries = time.monotonic() + within, 0
    while time.monotonic() < deadline:
        tries += 1
        before = handled()
        pub.publish(msg)
        client.wait_for(
            lambda: handled() > before and status()["node"]["idle"], 120, "the click to be handled"
        )
        if status().get("objects"):
            return
        assert (
            "no transform" in status()["node"]["last_error"]
            or "has no known transform" in status()["node"]["last_error"]
        ), status()["node"]
        time.sleep(0.25)
    raise AssertionError(f"the click was refused {tries} times: {status()['node']}")


def test_view_problem_refuses_poses_inside_behind_and_far_from_the_panel(library):
    sim = simulate_taskboard(library, SEED)
    B = sim.T_scene_board

    def at(x, y, z):
        T = np.eye(4)
        T[:3, 3] = B[:3, :3] @ [x, y, z] + B[:3, 3]
        return T

    assert view_problem(B, at(0.1, 0.0, 0.8)) == ""
    assert "inside the panel" in view_problem(B, at(0.0, 0.0, -0.01))
    assert "behind the panel" in view_problem(B, at(0.0, 0.0, -0.5))
    assert "m from the panel" in view_problem(B, at(0.0, 0.0, 3.5))


def test_first_view_and_sensor_pose_are_checked(library):
    assert check_first_view("camera", library) is None
    assert check_first_view("far:gate_valve", library) == ("far", "gate_valve")
    for bad in ("edge-on", "edge-on:box", "sideways:gate_valve", ""):
        with pytest.raises(AffordanceError, match="first view must be"):
            check_first_view(bad, library)
    T = parse_pose("0.1 0.2 0.3 0 0 0.7071068 0.7071068")
    assert np.allclose(T[:3, 3], [0.1, 0.2, 0.3]) and np.allclose(T[:3, 0], [0, 1, 0])
    for bad in ("1 2 3", "0 0 0 0 0 0 2", "0 0 nan 0 0 0 1", "a b c d e f g"):
        with pytest.raises(AffordanceError, match="sensor_pose"):
            parse_pose(bad)


def test_a_requested_view_rescans_and_the_click_settles(ros_context, tmp_path, library):
    sim, T_first, click, truth = edge_on_case(library)
    scan = NodeProcess(
        [
            sys.executable,
            "-m",
            "affordance_registration.evaluation.simulated_scan",
            "--ros-args",
            "-p",
            f"seed:={SEED}",
            "-p",
            "first_view:=edge-on:quarter_turn_valve",
        ],
        tmp_path / "scan.log",
    )
    engine = engine_process(tmp_path, {"sensor_frame": SENSOR})
    client = Client("sensor_move_tester")
    try:
        client.subscribe(PointCloud2, "/points", LATCHED, keep=True)
        client.subscribe(String, f"{NS}/status", LATCHED)
        client.subscribe(load_tf_message(), "/tf_static", STATIC_LISTENER_QOS)

        def sensor_pose():
            """The sensor's pose the scan node last published on /tf_static."""
            tf = client.latest.get("/tf_static")
            t = next(
                (t for t in (tf.transforms if tf else []) if t.child_frame_id == SENSOR), None
            )
            return (
                None
                if t is None or t.header.frame_id != FRAME
                else transform_to_matrix(t.transform)
            )

        client.wait_for(lambda: sensor_pose() is not None, 90, "the sensor's frame on TF")
        assert np.allclose(sensor_pose(), T_first, atol=1e-6)
        pub_click = client.node.create_publisher(PointStamped, "/clicked_point", 10)
        pub_view = client.node.create_publisher(PoseStamped, "/sensor_view_request", 10)
        client.wait_for_subscribers(pub_click, timeout=90)
        client.wait_for_subscribers(pub_view, timeout=90)
        status = lambda: client.status(f"{NS}/status") or {}  # noqa: E731
        client.wait_for(lambda: status().get("node", {}).get("cloud"), 90, "the first cloud")
        click_on(client, pub_click, status, click)
        o = status()["objects"][0]
        assert o["ambiguity"]["settled"] is False, o["ambiguity"]
        first = o["candidates"][0]
        dt, da = pose_error(
            np.asarray(first["pose"]), truth.T_scene_model, library[truth.template].symmetry
        )
        assert not (
            first["template"] == truth.template and dt <= POSE_TOL_M and da <= POSE_TOL_RAD
        ), "the hard first view was fitted right: no test"
        T_view = np.asarray(o["suggested_view"]["pose"])
        clouds = len(client.history["/points"])

        # bad requests: one line each, no move, the node keeps running
        inside = T_view.copy()
        inside[:3, 3] = sim.T_scene_board[:3, 3]
        far = T_view.copy()
        far[:3, 3] = T_view[:3, 3] + 10.0 * (T_view[:3, 3] - sim.T_scene_board[:3, 3])
        away = T_view @ np.diag([1.0, -1.0, -1.0, 1.0])  # looking away from the board
        nan = pose_stamped(T_view, FRAME)
        nan.pose.position.x = math.nan
        for bad, line in (
            (nan, "not moved: pose has NaN"),
            (pose_stamped(T_view, "map"), "not moved: the pose is in 'map'"),
            (pose_stamped(inside, FRAME), "the panel (0.000 m in front"),
            (pose_stamped(far, FRAME), "m from the panel (at most 3.0 m)"),
            (pose_stamped(away, FRAME), "would see 0 points of the taskboard"),
        ):
            pub_view.publish(bad)
            assert scan.wait_output(line, 60), scan.output()[-2000:]
        assert scan.proc.poll() is None
        assert scan.output().count("not moved:") == 5
        assert len(client.history["/points"]) == clouds

        # the suggested view: a new cloud from there, the click fitted anew, settled and right
        pub_view.publish(pose_stamped(T_view, FRAME))
        client.wait_for(lambda: len(client.history["/points"]) > clouds, 90, "the new cloud")
        assert scan.wait_output("moved the sensor to", 5)
        assert np.allclose(sensor_pose(), T_view, atol=1e-6)  # where the engine reads it

        def settled():
            objs = status().get("objects") or []
            return (
                objs
                and objs[0]["ambiguity"]
                and objs[0]["ambiguity"]["settled"]
                and "fitted again on the new cloud" in status()["node"]["last_message"]
            )

        client.wait_for(settled, 120, "the click to settle on the new cloud")
        best = status()["objects"][0]["candidates"][0]
        dt, da = pose_error(
            np.asarray(best["pose"]), truth.T_scene_model, library[truth.template].symmetry
        )
        assert best["template"] == truth.template, best["template"]
        assert dt <= POSE_TOL_M and da <= POSE_TOL_RAD, (dt, math.degrees(da))
        assert status()["objects"][0]["suggested_view"] is None
        assert status()["node"]["cloud"]["frame_id"] == FRAME

        # a flood of requests is not queued up: the latest is moved to (a bad one last marks
        # when all have been read)
        moved = scan.output().count("moved the sensor to")
        for _ in range(30):
            pub_view.publish(pose_stamped(T_view, FRAME))
        pub_view.publish(pose_stamped(T_view, "flood_end"))
        assert scan.wait_output("the pose is in 'flood_end'", 60), scan.output()[-2000:]
        client.wait_for(
            lambda: scan.output().count("moved the sensor to") > moved,
            60,
            "the move after the flood",
        )
        assert scan.output().count("moved the sensor to") - moved <= 10
        assert scan.proc.poll() is None
    finally:
        client.close()
        for proc in (engine, scan):
            proc.interrupt(timeout=10)
            proc.kill()
        print(engine.output()[-3000:])
        print(scan.output()[-3000:])
