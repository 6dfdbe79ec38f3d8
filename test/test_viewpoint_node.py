# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Viewpoint advice over ROS: a real engine node in its own process gets a scan of the gate
valve's handwheel seen edge-on; its status says the click is unsettled and why -- at once, the
suggested view following in a later status (it is not on the click's path) --, it publishes
``~/suggested_view`` and a camera frustum on ``~/markers``; a new cloud scanned from the suggested
view (the simulator renders it; the sensor origin given as the node's parameter) is fitted anew
and settles the click."""

import json
import math

import numpy as np
from geometry_msgs.msg import PointStamped, PoseStamped
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from ros_helpers import LATCHED, engine_session
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from affordance_registration.core.registration.viewpoint import optical_pose
from affordance_registration.core.transforms import invert, pose_error
from affordance_registration.evaluation.simulation import (
    POSE_TOL_M,
    POSE_TOL_RAD,
    simulate_taskboard,
)
from affordance_registration.evaluation.viewpoints import scan, taskboard_meshes
from affordance_registration.ros.glue.conversions import pose_to_matrix, xyz_to_pointcloud2
from affordance_registration.ros.glue.qos import latched

FRAME = "world"
NS = "/affordance_engine"


def _edge_on(sim, k: int) -> np.ndarray:
    to_board = invert(sim.T_scene_board)
    centre = to_board[:3, :3] @ sim.objects[k].T_scene_model[:3, 3] + to_board[:3, 3]
    target = centre + np.array([0.0, 0.0, 0.02])
    a = math.radians(84.0)
    pos = target + 0.9 * np.array([math.sin(a), 0.0, math.cos(a)])
    return sim.T_scene_board @ optical_pose(pos, target, np.array([0.0, 0.0, -1.0]))


def _origin_param(origin) -> Parameter:
    return Parameter(
        name="sensor_origin",
        value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE_ARRAY,
            double_array_value=[float(v) for v in origin],
        ),
    )


def test_an_unsettled_click_gets_a_suggested_view_and_the_view_settles_it(
    ros_context, tmp_path, library
):
    sim = simulate_taskboard(library, 7)
    k = next(i for i, o in enumerate(sim.objects) if o.template == "gate_valve")
    obj = sim.objects[k]
    meshes = taskboard_meshes(sim, library)
    pts, labels, origin = scan(meshes, _edge_on(sim, k), np.random.default_rng(1))
    mine = pts[labels == k + 1]
    point = mine[int(np.argmin(np.linalg.norm(mine - obj.T_scene_model[:3, 3], axis=1)))]
    origin_text = "[" + ", ".join(f"{v:.6f}" for v in origin) + "]"
    with engine_session(
        tmp_path,
        {"sensor_origin": origin_text},
        "viewpoint_tester",
        {"points": (PointCloud2, "/points", 1), "click": (PointStamped, "/clicked_point", 10)},
        [
            (PoseStamped, f"{NS}/suggested_view", LATCHED, False),
            (MarkerArray, f"{NS}/markers", LATCHED, False),
            (String, f"{NS}/status", latched(100), True),  # every status, in order
        ],
    ) as s:
        client = s["client"]

        def status():
            return client.status(f"{NS}/status") or {}

        s["pubs"]["points"].publish(xyz_to_pointcloud2(pts.astype(np.float32), FRAME))
        client.wait_for(lambda: status().get("node", {}).get("cloud"), 30, "the cloud")
        msg = PointStamped()
        msg.header.frame_id = FRAME
        msg.point.x, msg.point.y, msg.point.z = map(float, point)
        s["pubs"]["click"].publish(msg)
        client.wait_for(
            lambda: status().get("objects") and status()["node"]["idle"], 60, "the fit"
        )
        # the click's status went out first: the object, unsettled, no view yet (one due) and
        # the whole click's time; then a status with the view, and the view's time apart
        heard = [json.loads(m.data) for m in client.history[f"{NS}/status"]]
        shown = [st for st in heard if st.get("objects")]
        first, last = shown[0], shown[-1]
        o = first["objects"][0]
        assert o["ambiguity"]["settled"] is False and o["suggested_view"] is None
        assert first["node"]["views_due"] == 1 and not first["node"]["idle"]
        t = first["timing_s"]
        assert t["total"] >= t["prepare"] + t["fit"] + t["ambiguity"] - 1e-5
        assert "suggest_view" not in t
        assert last["objects"][0]["suggested_view"] is not None and last["node"]["idle"]
        assert last["timing_s"]["suggest_view"] > 0 and last["timing_s"]["total"] == t["total"]
        o = status()["objects"][0]
        amb = o["ambiguity"]
        assert amb["settled"] is False and amb["reasons"], amb
        assert {"weakly_held", "rival_pose"} & set(amb["kinds"])
        view = o["suggested_view"]
        assert view is not None and 0.5 - 1e-6 <= view["distance"] <= 1.5 + 1e-6
        T_view = np.asarray(view["pose"])
        # ~/suggested_view: that pose, in the cloud's frame
        client.wait_for(
            lambda: (
                f"{NS}/suggested_view" in client.latest
                and np.allclose(
                    pose_to_matrix(client.latest[f"{NS}/suggested_view"].pose), T_view, atol=1e-5
                )
            ),
            30,
            "~/suggested_view",
        )
        assert client.latest[f"{NS}/suggested_view"].header.frame_id == FRAME
        # ~/markers: a camera frustum there (4 edges from the centre, the far rectangle, a tick)

        def frustum():
            arr = client.latest.get(f"{NS}/markers")
            return [m for m in (arr.markers if arr else []) if m.ns == "suggested_view"]

        client.wait_for(lambda: frustum(), 30, "the frustum marker")
        m = frustum()[0]
        assert m.type == Marker.LINE_LIST and len(m.points) == 18 and m.header.frame_id == FRAME
        apex = np.array([m.points[0].x, m.points[0].y, m.points[0].z])
        assert np.allclose(apex, T_view[:3, 3], atol=1e-6)

        # the sensor moves there: its new scan, with its origin, is fitted anew and settles it
        req = SetParameters.Request(parameters=[_origin_param(T_view[:3, 3])])
        assert client.call(SetParameters, f"{NS}/set_parameters", req).results[0].successful
        p2, _, _ = scan(meshes, T_view, np.random.default_rng(2))
        s["pubs"]["points"].publish(xyz_to_pointcloud2(p2.astype(np.float32), FRAME))

        def settled():
            objs = status().get("objects") or []
            return objs and objs[0]["ambiguity"] and objs[0]["ambiguity"]["settled"]

        client.wait_for(settled, 60, "the click to settle on the new cloud")
        o = status()["objects"][0]
        assert "fitted again on the new cloud" in status()["node"]["last_message"]
        best = o["candidates"][0]
        dt, da = pose_error(
            np.asarray(best["pose"]), obj.T_scene_model, library[obj.template].symmetry
        )
        assert best["template"] == obj.template and dt <= POSE_TOL_M and da <= POSE_TOL_RAD
        assert o["suggested_view"] is None


def test_the_station_panel_says_why_a_click_is_unsettled_and_where_to_look_from():
    from browser_helpers import rendered_panel

    from affordance_registration.ros.station.state import status_markdown

    obj = {
        "id": 1,
        "active": True,
        "shown": 0,
        "no_match": False,
        "verdict": "fits",
        "candidates": [
            {
                "rank": 1,
                "template": "gate_valve",
                "probability": 0.4,
                "fits": True,
                "joints": {},
                "scale": 1.0,
                "state": None,
                "primitive": None,
                "dimensions": None,
            }
        ],
        "ambiguity": {
            "settled": False,
            "kinds": ["weakly_held"],
            "reasons": ["the scan barely holds gate_valve along one motion"],
        },
        "suggested_view": {"text": "look from (0.1, 0.2, 0.3), 0.50 m from the object"},
    }
    _, md = rendered_panel(status_markdown({"objects": [obj], "active_id": 1}, True, NS, "", ""))
    assert "Unsettled: the scan barely holds gate_valve along one motion" in md
    assert "suggested view: look from (0.1, 0.2, 0.3)" in md
    settled = dict(
        obj, ambiguity={"settled": True, "kinds": [], "reasons": []}, suggested_view=None
    )
    assert "Unsettled" not in status_markdown(
        {"objects": [settled], "active_id": 1}, True, NS, "", ""
    )


def test_the_station_draws_the_suggested_views_frustum():
    """The frustum marker becomes line segments on the station's page (its real viser server,
    no browser), at the suggested pose."""
    import socket

    from affordance_registration.ros.glue.markers import frustum_marker
    from affordance_registration.ros.station.page import PageHandlers, StationPage
    from affordance_registration.ros.station.state import LineDrawing, apply_markers

    T = optical_pose(
        np.array([0.3, -0.2, 0.1]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    )
    arr = MarkerArray(markers=[frustum_marker(T, FRAME, "suggested_view", 4, None)])
    drawings = apply_markers({}, arr)
    d = drawings[("suggested_view", 4)]
    assert isinstance(d, LineDrawing) and d.segments.shape == (9, 2, 3)
    assert np.allclose(d.segments[0, 0], T[:3, 3])
    far = d.segments[4:8].reshape(-1, 3)  # the far rectangle, 0.15 m along the view
    assert np.allclose((far - T[:3, 3]) @ T[:3, 2], 0.15)
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    handlers = PageHandlers(*[lambda *a, **k: None] * len(PageHandlers.__dataclass_fields__))
    page = StationPage("127.0.0.1", port, 60.0, 0.003, handlers)
    try:
        page.show_scene(drawings, None, "")
        assert "/objects/suggested_view_4" in page._nodes
        page.show_scene({}, None, "")
        assert "/objects/suggested_view_4" not in page._nodes
    finally:
        page.stop()
