# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Every input acts on its own object: a real engine process, interactive-marker feedback, clicks
and TF over real topics."""

import time

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from ros_helpers import engine_session
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import InteractiveMarkerFeedback

from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue.conversions import matrix_to_pose, xyz_to_pointcloud2
from affordance_registration.ros.standins.interactive import DRAG_EXPIRY_S

FRAME = "camera_depth_optical_frame"
NS = "/affordance_engine"
F = InteractiveMarkerFeedback


@pytest.fixture
def s(ros_context, tmp_path, library):
    with engine_session(
        tmp_path,
        {"refit_on_new_cloud": "false"},
        "own_object_tester",
        {
            "points": (PointCloud2, "/points", 1),
            "click": (PointStamped, "/clicked_point", 10),
            "feedback": (InteractiveMarkerFeedback, "/affordance_correction/feedback", 100),
        },
        sim=simulate_taskboard(library, 7),
    ) as s:
        s["pubs"]["points"].publish(xyz_to_pointcloud2(s["sim"].organized, FRAME))
        s["client"].wait_for(
            lambda: (s["client"].status() or {}).get("node", {}).get("cloud"), 30, "the cloud"
        )
        yield s


def _status(s):
    return s["client"].status() or {}


def _pose(s, obj_id):
    for o in _status(s).get("objects", []):
        if o["id"] == obj_id:
            return np.asarray(o["candidates"][o["shown"]]["pose"])
    return None


def _ids(st) -> set:
    return {o["id"] for o in st.get("objects", [])}


def _click(s, obj):
    """Click ``obj`` and wait for the object it opens: an id the status did not show before
    (the status is rate-limited, so the one read before the click may lag an accept behind)."""
    before = _ids(_status(s))
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, obj.click)
    s["pubs"]["click"].publish(msg)
    st = s["client"].wait_for(
        lambda: _ids(_status(s)) - before and _status(s)["node"]["idle"] and _status(s),
        180,
        "the fitted object",
    )
    return st["active_id"]


def _feedback(s, event, T, client):
    fb = InteractiveMarkerFeedback(
        client_id=client, marker_name="affordance_fit", event_type=event
    )
    fb.header.frame_id = FRAME
    fb.pose = matrix_to_pose(T)
    s["pubs"]["feedback"].publish(fb)


def _wait_log(s, text, timeout=30):
    s["client"].wait_for(lambda: text in s["proc"].output(), timeout, repr(text))


def test_a_silent_drag_is_cancelled_and_its_late_release_moves_nothing(s):
    sim = s["sim"]
    first = _click(s, sim.objects[0])
    before = _pose(s, first)
    moved = before.copy()
    moved[:3, 3] += [0.05, 0.0, 0.0]
    _feedback(s, F.MOUSE_DOWN, before, "/browser_a")
    _feedback(s, F.POSE_UPDATE, moved, "/browser_a")
    s["client"].wait_for(
        lambda: np.allclose(_pose(s, first), moved, atol=1e-6), 30, "the drag to move the object"
    )
    # browser A falls silent: after DRAG_EXPIRY_S the drag is cancelled, the object is back
    s["client"].wait_for(
        lambda: np.allclose(_pose(s, first), before, atol=1e-6),
        DRAG_EXPIRY_S + 30,
        "the silent drag to be cancelled",
    )
    _wait_log(s, "the unfinished drag was cancelled")
    # browser B opens another object; A's late release must not move it
    second = _click(s, sim.objects[2])
    assert second != first
    opened = _pose(s, second)
    far = opened.copy()
    far[:3, 3] += [0.0, 0.3, 0.0]
    _feedback(s, F.MOUSE_UP, far, "/browser_a")
    _wait_log(s, "after its drag was cancelled")
    time.sleep(0.5)
    assert np.allclose(_pose(s, second), opened, atol=1e-9)
    assert np.allclose(_pose(s, first), before, atol=1e-9)


def test_a_release_for_an_object_no_longer_selected_is_refused(s):
    sim = s["sim"]
    first = _click(s, sim.objects[1])
    before = _pose(s, first)
    _feedback(s, F.MOUSE_DOWN, before, "/browser_a")
    nudged = before.copy()
    nudged[:3, 3] += [0.0, 0.0, 0.01]
    _feedback(s, F.POSE_UPDATE, nudged, "/browser_a")
    s["client"].wait_for(lambda: np.allclose(_pose(s, first), nudged, atol=1e-6), 30, "the drag")
    second = _click(s, sim.objects[3])  # while A holds the drag (keep-alives below)
    _feedback(s, F.KEEP_ALIVE, nudged, "/browser_a")
    opened = _pose(s, second)
    away = opened.copy()
    away[:3, 3] += [0.2, 0.0, 0.0]
    _feedback(s, F.MOUSE_UP, away, "/browser_a")
    s["client"].wait_for(
        lambda: (
            f"release refused: it started on object {first}" in _status(s)["node"]["last_error"]
        ),
        30,
        "the refusal",
    )
    assert np.allclose(_pose(s, second), opened, atol=1e-9)


# ---------------------------------------------------------------------------- TF in time order
def _tf_message(parent, child, x, stamp_s):
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = parent, child
    t.header.stamp.sec = int(stamp_s)
    t.header.stamp.nanosec = int(round((stamp_s % 1) * 1e9))
    t.transform.translation.x = float(x)
    t.transform.rotation.w = 1.0
    return TFMessage(transforms=[t])


def test_an_old_tf_arriving_after_a_new_one_changes_nothing(ros_context, tmp_path, library):
    from tf2_msgs.msg import TFMessage

    sim = simulate_taskboard(library, 7)
    with engine_session(
        tmp_path,
        {"refit_on_new_cloud": "false"},
        "tf_order_tester",
        {
            "points": (PointCloud2, "/points", 1),
            "click": (PointStamped, "/clicked_point", 10),
            "tf": (TFMessage, "/tf", 100),
        },
    ) as s:
        s["pubs"]["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
        s["client"].wait_for(lambda: _status(s).get("node", {}).get("cloud"), 30, "the cloud")
        target = sim.objects[2]
        other = min(
            (o for o in sim.objects if o.template != target.template),
            key=lambda o: abs(np.linalg.norm(o.click - target.click) - 0.0),
        )
        shift = float(other.click[0] - target.click[0])
        # pointer_frame = the cloud frame moved by +0.1 m in x (stamp 100 s); an old message
        # (stamp 95 s) that would put the click on another object arrives afterwards
        s["pubs"]["tf"].publish(_tf_message(FRAME, "pointer_frame", 0.1, 100.0))
        time.sleep(0.3)
        s["pubs"]["tf"].publish(_tf_message(FRAME, "pointer_frame", 0.1 + shift, 95.0))
        time.sleep(0.5)
        msg = PointStamped()
        msg.header.frame_id = "pointer_frame"
        msg.point.x, msg.point.y, msg.point.z = map(float, target.click - [0.1, 0.0, 0.0])
        s["pubs"]["click"].publish(msg)  # no stamp: the latest transform
        st = s["client"].wait_for(lambda: _status(s).get("objects") and _status(s), 60, "the fit")
        assert st["objects"][0]["candidates"][0]["template"] == target.template
        assert np.allclose(st["objects"][0]["click"], target.click, atol=0.01)
        # a click stamped 95 s is taken in the frames of 95 s (a lookup at its stamp)
        msg.header.stamp.sec = 95
        msg.point.x, msg.point.y, msg.point.z = map(float, other.click - [0.1 + shift, 0, 0])
        s["pubs"]["click"].publish(msg)
        st = s["client"].wait_for(
            lambda: len(_status(s).get("objects", [])) == 2 and _status(s), 60, "the second fit"
        )
        assert np.allclose(st["objects"][1]["click"], other.click, atol=0.01)


def test_the_buffer_keeps_time_order_interpolates_and_forgets_after_its_cache():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from affordance_registration.ros.glue.frames import FrameError, TransformBuffer

    def T(x):
        out = np.eye(4)
        out[0, 3] = x
        return out

    @settings(max_examples=100, deadline=None)
    @given(st.permutations(list(range(1, 8))))
    def arrival_order_does_not_matter(order):
        buf = TransformBuffer(cache_s=100.0)
        for k in order:
            buf.set("a", "b", T(float(k)), stamp=float(k))
        assert buf.graph().lookup("a", "b")[0, 3] == 7.0  # the newest, whatever came last
        assert buf.graph(3.25).lookup("a", "b")[0, 3] == pytest.approx(3.25)
        assert buf.graph(99.0).lookup("a", "b")[0, 3] == 7.0

    arrival_order_does_not_matter()
    buf = TransformBuffer(cache_s=10.0)
    buf.set("a", "b", T(1.0), stamp=1.0)
    buf.set("a", "b", T(20.0), stamp=20.0)  # 1 s is now more than 10 s old: forgotten
    with pytest.raises(FrameError):
        buf.graph(1.0).lookup("a", "b")
    buf.set("a", "s", T(5.0), static=True)
    assert buf.graph(1.0).lookup("a", "s")[0, 3] == 5.0  # static: at every time


# ---------------------------------------------------------------------------- frame changes
def test_a_frame_change_re_expresses_the_open_object_and_the_registrations(
    ros_context, tmp_path, library
):
    from std_srvs.srv import Trigger

    from affordance_registration.core.transforms import pose_error, quat_xyzw_to_matrix

    sim = simulate_taskboard(library, 7)
    # camB sees the same scene from 8 cm to the side, turned 10 degrees about y
    c, s_ = np.cos(np.radians(10)), np.sin(np.radians(10))
    qy = (0.0, np.sin(np.radians(5)), 0.0, np.cos(np.radians(5)))
    T_B_A = np.eye(4)
    T_B_A[:3, :3] = quat_xyzw_to_matrix(qy)
    T_B_A[:3, 3] = [0.08, 0.0, 0.0]
    assert np.allclose(T_B_A[0, 0], c) and np.allclose(T_B_A[0, 2], s_)
    entry = f"camB {FRAME} 0.08 0 0 {qy[0]} {qy[1]} {qy[2]} {qy[3]}"
    with engine_session(
        tmp_path,
        {
            "refit_on_new_cloud": "false",
            "sensor_frame": FRAME,
            "static_transforms": f"['{entry}']",
        },
        "frame_change_tester",
        {"points": (PointCloud2, "/points", 1), "click": (PointStamped, "/clicked_point", 10)},
        sim=sim,
    ) as s:
        s["pubs"]["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
        s["client"].wait_for(lambda: _status(s).get("node", {}).get("cloud"), 30, "the cloud")
        accepted = _click(s, sim.objects[0])
        assert s["client"].call(Trigger, f"{NS}/accept", timeout=30).success
        reg_A = np.asarray(
            s["client"].wait_for(lambda: _status(s)["registered"], 30, "the registration")[0][
                "pose"
            ]
        )
        opened = _click(s, sim.objects[2])
        assert opened != accepted
        open_A = _pose(s, opened)
        pts = sim.organized.reshape(-1, 3)
        pts_B = pts @ T_B_A[:3, :3].T + T_B_A[:3, 3]
        s["pubs"]["points"].publish(xyz_to_pointcloud2(pts_B.astype(np.float32), "camB"))
        s["client"].wait_for(
            lambda: _status(s)["node"]["cloud"]["frame_id"] == "camB", 30, "the cloud in camB"
        )
        res = s["client"].call(Trigger, f"{NS}/refit", timeout=60)  # converts the new cloud
        assert res.success, res.message
        st = s["client"].wait_for(
            lambda: _status(s)["frame_id"] == "camB" and _status(s), 30, "the status in camB"
        )
        dt, _ = pose_error(
            _pose(s, opened), T_B_A @ open_A, library[sim.objects[2].template].symmetry
        )
        assert dt < 0.005, f"{dt * 1000:.1f} mm"
        reg = st["registered"][0]
        assert reg["frame_id"] == "camB"
        assert np.allclose(np.asarray(reg["pose"]), T_B_A @ reg_A, atol=1e-6)
        assert "re-expressed" in s["proc"].output()


def test_a_frame_change_without_a_transform_closes_the_open_objects(
    ros_context, tmp_path, library
):
    from std_srvs.srv import Trigger

    sim = simulate_taskboard(library, 7)
    with engine_session(
        tmp_path,
        {"refit_on_new_cloud": "false"},
        "frame_close_tester",
        {"points": (PointCloud2, "/points", 1), "click": (PointStamped, "/clicked_point", 10)},
        sim=sim,
    ) as s:
        s["pubs"]["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
        s["client"].wait_for(lambda: _status(s).get("node", {}).get("cloud"), 30, "the cloud")
        _click(s, sim.objects[0])
        assert s["client"].call(Trigger, f"{NS}/accept", timeout=30).success
        _click(s, sim.objects[2])
        pts = sim.organized.reshape(-1, 3)
        s["pubs"]["points"].publish(xyz_to_pointcloud2(pts.astype(np.float32), "camC"))
        s["client"].wait_for(
            lambda: _status(s)["node"]["cloud"]["frame_id"] == "camC", 30, "the cloud in camC"
        )
        s["client"].call(Trigger, f"{NS}/refit", timeout=60)
        st = s["client"].wait_for(
            lambda: _status(s)["frame_id"] == "camC" and _status(s), 30, "the status in camC"
        )
        assert st["objects"] == []
        assert "no transform between them is known: open object(s) 2 closed" in s["proc"].output()
        assert st["registered"][0]["frame_id"] == FRAME
        assert not s["client"].call(Trigger, f"{NS}/undo").success  # nothing to bring back


# ---------------------------------------------------------------------------- the station
def test_a_browser_that_disconnects_mid_drag_moves_nothing(ros_context, tmp_path, library):
    """A real station and engine; a websocket client of the station (the page's protocol)
    grabs the gizmo, drags it 8 cm and goes away without releasing: the object returns to where
    it was, the half-finished pose is not committed."""
    import msgspec
    import viser
    from browser_helpers import STATION_SECRET, free_port, station_argv
    from ros_helpers import NodeProcess
    from websockets.sync.client import connect

    sim = simulate_taskboard(library, 7)
    port = free_port()
    station = NodeProcess(station_argv(port), tmp_path / "station.log")
    try:
        with engine_session(
            tmp_path,
            {"refit_on_new_cloud": "false"},
            "disconnect_tester",
            {"points": (PointCloud2, "/points", 1), "click": (PointStamped, "/clicked_point", 10)},
            sim=sim,
        ) as s:
            s["client"].wait_for_subscribers(s["pubs"]["points"], count=2, timeout=120)
            assert station.wait_output("operator station on", 120), station.output()
            s["pubs"]["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
            s["client"].wait_for(lambda: _status(s).get("node", {}).get("cloud"), 30, "cloud")
            obj_id = _click(s, sim.objects[2])
            before = _pose(s, obj_id)
            ws = connect(
                f"ws://127.0.0.1:{port}/?token={STATION_SECRET}",
                subprotocols=[f"viser-v{viser.__version__}"],
                open_timeout=60,
            )
            # the station shows the cloud and the gizmo before a drag means anything
            assert station.wait_output("drawn: object", 120), station.output()[-2000:]
            time.sleep(1.0)
            moved = before[:3, 3] + [0.08, 0.0, 0.0]
            w, x, y, z = _wxyz(before)
            send = lambda m: ws.send(msgspec.msgpack.encode(m))  # noqa: E731
            # a page reports its camera first (viser counts a client from then on)
            send(
                {
                    "type": "ViewerCameraMessage",
                    "wxyz": [1.0, 0.0, 0.0, 0.0],
                    "position": [0.0, 0.0, 0.0],
                    "fov": 1.0,
                    "near": 0.01,
                    "far": 100.0,
                    "image_height": 600,
                    "image_width": 800,
                    "look_at": [0.0, 0.0, 1.0],
                    "up_direction": [0.0, -1.0, 0.0],
                }
            )
            time.sleep(1.0)
            send({"type": "TransformControlsDragStartMessage", "name": "/fit", "owner": ""})
            for f in np.linspace(0.1, 1.0, 10):
                send(
                    {
                        "type": "TransformControlsUpdateMessage",
                        "name": "/fit",
                        "wxyz": [w, x, y, z],
                        "position": [
                            float(v) for v in before[:3, 3] + f * (moved - before[:3, 3])
                        ],
                        "owner": "",
                    }
                )
                time.sleep(0.05)
            s["client"].wait_for(
                lambda: np.linalg.norm(_pose(s, obj_id)[:3, 3] - before[:3, 3]) > 0.05,
                60,
                "the drag to reach the engine",
            )
            ws.close()  # gone mid-drag, never released
            s["client"].wait_for(
                lambda: np.allclose(_pose(s, obj_id), before, atol=1e-6),
                DRAG_EXPIRY_S + 60,
                "the object back where the drag started",
            )
            assert "the unfinished drag was cancelled" in s["proc"].output()
            assert "a browser went away mid-drag: its drag is cancelled" in station.output()
            time.sleep(1.0)
            assert np.allclose(_pose(s, obj_id), before, atol=1e-6)  # and it stays there
    finally:
        station.interrupt(timeout=10)
        station.kill()
        print(station.output()[-2000:])


def _wxyz(T):
    from affordance_registration.core.transforms import matrix_to_quat_xyzw

    x, y, z, w = matrix_to_quat_xyzw(T[:3, :3])
    return float(w), float(x), float(y), float(z)
