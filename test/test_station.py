# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station without a browser and without rclpy.init: ray -> cloud point snapping, the browser
camera -> view_pose conversion, display thinning and colours, and the message/status helpers."""

import math
import socket
import unicodedata

import numpy as np
import pytest
from browser_helpers import rendered_panel
from geometry_msgs.msg import Point
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import InteractiveMarkerFeedback, Marker, MarkerArray

from affordance_registration.core import display
from affordance_registration.core.corrections import view_from_optical
from affordance_registration.core.errors import AffordanceError
from affordance_registration.ros.glue.conversions import (
    pointcloud2_colors,
    pointcloud2_field,
    pointcloud2_to_xyz,
    pose_stamped,
    pose_to_matrix,
    xyz_to_pointcloud2,
)
from affordance_registration.ros.station.node import feedback_message
from affordance_registration.ros.station.page import gizmo_scale
from affordance_registration.ros.station.parameters import PARAMETERS, check_parameters, check_port
from affordance_registration.ros.station.state import (
    HEADLINE_MAX,
    MeshDrawing,
    SphereDrawing,
    TextDrawing,
    active_object,
    apply_markers,
    candidate_label,
    candidate_options,
    drag_moved,
    fitting_marker,
    headline,
    short_label,
    shown_markdown,
    status_markdown,
)


def _grid(n=200, spacing=0.005, z=1.0):
    u, v = np.meshgrid(np.arange(n) - n / 2, np.arange(n) - n / 2)
    return np.column_stack([u.ravel() * spacing, v.ravel() * spacing, np.full(n * n, z)])


# ------------------------------------------------------------------ ray -> nearest cloud point
def test_a_click_on_an_object_picks_the_object_not_the_wall_behind_it():
    wall = _grid(z=1.0)
    box = _grid(n=20, spacing=0.004, z=0.8) + [0.1, 0.05, 0.0]  # 8 cm patch, 20 cm in front
    pts = np.vstack([wall, box])
    origin = np.zeros(3)
    i = display.snap_ray(pts, origin, box[210] - origin)
    assert i >= len(wall) and np.linalg.norm(pts[i] - box[210]) < 0.004
    # beside the patch: the wall
    target = np.array([-0.2, -0.1, 1.0])
    i = display.snap_ray(pts, origin, target)
    assert i < len(wall) and np.linalg.norm(pts[i] - target) < 0.005


def test_a_click_into_the_void_picks_nothing():
    pts = _grid(n=50)  # 25 cm patch at 1 m
    assert display.snap_ray(pts, np.zeros(3), [1.0, 0.0, 1.0]) is None  # 45 deg off
    assert display.snap_ray(pts, np.zeros(3), [0.0, 0.0, -1.0]) is None  # behind the camera
    assert display.snap_ray(np.zeros((0, 3)), np.zeros(3), [0.0, 0.0, 1.0]) is None
    with pytest.raises(AffordanceError):
        display.snap_ray(pts, np.zeros(3), [0.0, 0.0, 0.0])
    with pytest.raises(AffordanceError):
        display.snap_ray(pts, [np.nan, 0, 0], [0.0, 0.0, 1.0])


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-0.4, 0.4),
    st.floats(-0.4, 0.4),
    st.floats(-0.5, 0.5),
    st.floats(-0.5, 0.5),
    st.floats(0.2, 1.5),
)
def test_snapping_lands_next_to_where_the_ray_meets_the_surface(x, y, ox, oy, oz):
    """A plane of points 5 mm apart seen from anywhere in front of it, up to 60 degrees off its
    normal: the snapped point is a neighbour of the ray's intersection with the plane (at grazing
    angles the points just in front of it cover it on the screen, as they do for the eye)."""
    pts = _grid(n=200, spacing=0.005, z=2.0)
    origin = np.array([ox, oy, 2.0 - oz])
    hit = np.array([x, y, 2.0])
    d = hit - origin
    assume(d[2] / np.linalg.norm(d) >= math.cos(math.radians(60)))
    i = display.snap_ray(pts, origin, d)
    assert i is not None and np.linalg.norm(pts[i] - hit) <= 1.5 * 0.005


# ------------------------------------------------------------------ browser camera -> view_pose
def test_viser_camera_is_the_optical_frame_of_the_view():
    """A camera at p looking at q with up u: q is in the middle of the picture, a point above q
    (along u) higher on it, one to the right (the view frame's x) further right; the pose the
    station publishes on view_pose is that optical frame, so the engine's view frame maps a push
    to the right onto the screen's right."""
    p, q, up = np.array([0.3, -0.2, 0.1]), np.array([0.0, 0.1, 1.0]), np.array([0.0, -1.0, 0.0])
    T = display.look_at_pose(p, q, up)
    # the same rotation through an independent reference (scipy), as viser's wxyz
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    T_cam = display.optical_pose([w, x, y, z], p)
    np.testing.assert_allclose(T_cam, T, atol=1e-9)
    W, H, fov = 1100, 700, math.radians(60)
    centre = display.project(T_cam, fov, W, H, q)[0]
    np.testing.assert_allclose(centre, [W / 2, H / 2], atol=1e-6)
    above = display.project(T_cam, fov, W, H, q + 0.05 * up)[0]
    assert above[1] < H / 2 - 10 and abs(above[0] - W / 2) < 10
    R_view = view_from_optical(T_cam)[:3, :3]
    right = display.project(T_cam, fov, W, H, q + 0.05 * R_view[:, 0])[0]
    assert right[0] > W / 2 + 10 and abs(right[1] - H / 2) < 10
    msg = pose_stamped(T_cam, "camera_depth_optical_frame")
    np.testing.assert_allclose(pose_to_matrix(msg.pose), T_cam, atol=1e-9)
    with pytest.raises(AffordanceError):
        display.optical_pose([2.0, 0, 0, 0], p)
    with pytest.raises(AffordanceError):
        display.look_at_pose(p, p, up)


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.floats(-1, 1), min_size=3, max_size=3),
    st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    st.floats(20, 100),
    st.floats(0, 1100),
    st.floats(0, 700),
)
def test_a_pixel_ray_projects_back_onto_its_pixel(position, quat, fov_deg, u, v):
    q = np.asarray(quat) / np.linalg.norm(quat)
    T = display.optical_pose(q, position)
    origin, direction = display.pixel_ray(T, math.radians(fov_deg), 1100, 700, (u, v))
    np.testing.assert_allclose(origin, position, atol=1e-12)
    uv = display.project(T, math.radians(fov_deg), 1100, 700, origin + 2.0 * direction)[0]
    np.testing.assert_allclose(uv, [u, v], atol=1e-6)


def test_the_first_view_stands_at_the_sensor_or_above_a_map():
    cloud = _grid(z=1.0)
    position, target = display.initial_view(cloud, [0, -1, 0])
    np.testing.assert_allclose(position, 0.0)
    assert abs(target[2] - 1.0) < 1e-9
    room = np.random.default_rng(0).uniform(-3, 3, (5000, 3))  # origin inside
    position, target = display.initial_view(room, [0, 0, 1])
    assert position[2] > target[2] + 1.0


@given(st.floats(20, 100), st.floats(0.5, 5.0), st.floats(0.2, 3.0))
def test_the_first_view_of_a_sensor_cloud_frames_it(fov_deg, distance, half_width):
    """Stepped back from the sensor along the view until 99% of the cloud is in the picture
    (at least the page's narrower field of view), and no farther than it takes."""
    fov = math.radians(fov_deg)
    g = np.linspace(-half_width, half_width, 41)
    x, y = np.meshgrid(g, g)
    cloud = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, distance)])
    position, target = display.initial_view(cloud, [0, -1, 0], fov)
    assert abs(position[0]) < 1e-9 and abs(position[1]) < 1e-9 and position[2] <= 0
    rel = cloud - position
    off_axis = np.arctan2(np.linalg.norm(rel[:, :2], axis=1), rel[:, 2])
    inside = np.mean(off_axis <= 0.5 * fov + 1e-9)
    assert inside >= 0.99 - 1e-9
    if position[2] < -1e-9:  # it stepped back: not more than to get 99% in
        assert np.mean(off_axis <= 0.5 * fov * 0.97) < 0.99


# ------------------------------------------------------------------ display thinning, colours
@settings(max_examples=40, deadline=None)
@given(
    st.integers(1, 30000),
    st.integers(1000, 20000),
    st.integers(0, 1000),
    st.none() | st.floats(1e-5, 10.0),
)
def test_thinning_keeps_at_most_the_budget_and_only_cloud_points(n, budget, seed, start):
    """Whatever voxel edge it starts from (the station passes the previous cloud's)."""
    pts = np.random.default_rng(seed).normal(size=(n, 3)) * [1.0, 0.5, 0.01]
    keep = display.thin(pts, budget, start_voxel=start).indices
    assert len(keep) <= budget and len(np.unique(keep)) == len(keep)
    assert keep.min() >= 0 and keep.max() < n
    if n <= budget:
        assert len(keep) == n


def test_a_cloud_over_the_budget_is_thinned_evenly_not_dropped():
    pts = _grid(n=600, spacing=0.002)  # 360k points on a 1.2 m square
    keep = display.thin(pts, 50000).indices
    assert 0.5 * 50000 <= len(keep) <= 50000
    cells = {tuple(c) for c in np.floor(pts[keep, :2] / 0.05).astype(int)}
    assert len(cells) == 24 * 24  # every 5 cm cell keeps points
    with pytest.raises(AffordanceError):
        display.thin(pts, 0)


def test_scalar_colors_run_from_near_to_far():
    c = display.scalar_colors(np.array([0.5, 0.75, 1.0, 1.25, 1.5, np.nan]))
    assert c.dtype == np.uint8 and c.shape == (6, 3)
    brightness = c[:5].astype(int).sum(axis=1)
    assert np.all(np.diff(brightness) > 0)  # near dark, far light
    assert tuple(c[5]) == (128, 128, 128)


def test_meshes_are_drawn_just_outside_their_surface():
    import trimesh

    box = trimesh.creation.box(extents=(0.2, 0.1, 0.05))
    soup = box.vertices[box.faces].reshape(-1, 3)  # as a TRIANGLE_LIST marker has it
    v, f = display.offset_surface(soup, np.arange(len(soup)).reshape(-1, 3), 0.003)
    shell = trimesh.Trimesh(v, f)
    assert len(v) == 8 and shell.is_watertight  # welded, then moved out
    # every corner moved outwards, 3 mm along its normal
    assert np.all(np.linalg.norm(v, axis=1) > np.linalg.norm(box.vertices, axis=1).max())
    np.testing.assert_allclose(
        np.linalg.norm(
            v
            - box.vertices[
                np.argmin(np.linalg.norm(v[:, None] - box.vertices[None], axis=2), axis=1)
            ],
            axis=1,
        ),
        0.003,
        atol=1e-6,
    )


@settings(max_examples=30)
@given(st.integers(1, 50), st.integers(0, 2**31))
def test_a_clouds_own_colours_go_through_pointcloud2(n, seed):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3))
    colors = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    msg = xyz_to_pointcloud2(points, "scan", colors=colors)
    assert [f.name for f in msg.fields] == ["x", "y", "z", "rgb"] and msg.point_step == 16
    np.testing.assert_array_equal(pointcloud2_colors(msg), colors)
    np.testing.assert_allclose(pointcloud2_to_xyz(msg)[0], points.astype(np.float32))
    assert pointcloud2_colors(xyz_to_pointcloud2(points, "scan")) is None


def test_a_scan_files_own_colours_are_read(tmp_path):
    """A PCD's rgb (a packed float) or rgba (a packed unsigned int), a PLY's red green blue,
    ASCII or binary."""
    import open3d as o3d

    from affordance_registration.core.pointfiles import read_points

    pts = np.random.default_rng(0).random((5, 3))
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30], [200, 100, 50]])
    packed = (rgb[:, 0] << 16 | rgb[:, 1] << 8 | rgb[:, 2]).astype(np.uint32)
    head = "VERSION 0.7\nFIELDS x y z {}\nSIZE 4 4 4 4\nTYPE F F F {}\nCOUNT 1 1 1 1\n"
    head += "WIDTH 5\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 5\nDATA ascii\n"
    values = {"rgb": [repr(float(v)) for v in packed.view(np.float32)]}
    values["rgba"] = [str(int(v) | 0xFF000000) for v in packed]
    for field, kind in (("rgb", "F"), ("rgba", "U")):
        path = tmp_path / f"{field}.pcd"
        rows = [f"{p[0]} {p[1]} {p[2]} {v}" for p, v in zip(pts, values[field])]
        path.write_text(head.format(field, kind) + "\n".join(rows) + "\n")
        np.testing.assert_array_equal(read_points(str(path)).colors, rgb)
    ply = tmp_path / "rgb.ply"
    props = "".join(f"property float {c}\n" for c in "xyz")
    props += "".join(f"property uchar {c}\n" for c in ("red", "green", "blue"))
    rows = [f"{p[0]} {p[1]} {p[2]} {c[0]} {c[1]} {c[2]}" for p, c in zip(pts, rgb)]
    ply.write_text(
        f"ply\nformat ascii 1.0\nelement vertex 5\n{props}end_header\n" + "\n".join(rows) + "\n"
    )
    np.testing.assert_array_equal(read_points(str(ply)).colors, rgb)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    cloud.colors = o3d.utility.Vector3dVector(rgb / 255.0)
    for name in ("binary.pcd", "binary.ply"):
        o3d.io.write_point_cloud(str(tmp_path / name), cloud, write_ascii=False)
        np.testing.assert_array_equal(read_points(str(tmp_path / name)).colors, rgb)
    plain = tmp_path / "plain.pcd"
    plain.write_text(
        head.replace(" {}", "")
        .replace("SIZE 4 4 4 4", "SIZE 4 4 4")
        .replace("COUNT 1 1 1 1", "COUNT 1 1 1")
        + "\n".join(f"{p[0]} {p[1]} {p[2]}" for p in pts)
        + "\n"
    )
    assert read_points(str(plain)).colors is None


def test_pointcloud2_field_reads_intensity_in_any_layout():
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(6, 3)).astype(np.float32)
    inten = np.arange(6, dtype=np.uint16) * 1000
    for big in (False, True):
        e = ">" if big else "<"
        rec = np.zeros(
            6,
            dtype=[
                ("x", e + "f4"),
                ("y", e + "f4"),
                ("z", e + "f4"),
                ("pad", "u1", 2),
                ("intensity", e + "u2"),
                ("pad2", "u1", 4),
            ],
        )
        rec["x"], rec["y"], rec["z"], rec["intensity"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], inten
        msg = PointCloud2(
            height=2,
            width=3,
            point_step=rec.itemsize,
            row_step=3 * rec.itemsize + 4,
            is_bigendian=big,
        )
        msg.fields = [
            PointField(name=n, offset=rec.dtype.fields[n][1], datatype=t, count=1)
            for n, t in (("x", 7), ("y", 7), ("z", 7), ("intensity", 4))
        ]
        rows = rec.tobytes()
        step = 3 * rec.itemsize
        msg.data = b"".join(rows[r * step : (r + 1) * step] + b"\0" * 4 for r in range(2))
        pts, _ = pointcloud2_to_xyz(msg)
        np.testing.assert_allclose(pts, xyz)
        np.testing.assert_array_equal(pointcloud2_field(msg, "intensity"), inten)
        assert pointcloud2_field(msg, "rgb") is None


# ------------------------------------------------------------------ markers, status, messages
def _mesh_marker(ns, mid, x):
    m = Marker(ns=ns, id=mid, type=Marker.TRIANGLE_LIST, action=Marker.ADD)
    m.header.frame_id = "cam"
    m.pose.position.x, m.pose.orientation.w = x, 1.0
    m.scale.x = m.scale.y = m.scale.z = 1.0
    m.color = ColorRGBA(r=1.0, g=0.5, b=0.0, a=0.8)
    m.points = [
        Point(x=0.0, y=0.0, z=0.0),
        Point(x=0.1, y=0.0, z=0.0),
        Point(x=0.0, y=0.2, z=0.0),
        Point(x=9.0, y=9.0, z=9.0),
    ]  # a stray 4th point
    return m


def test_markers_become_drawings_and_deleteall_clears():
    text = Marker(
        ns="candidate_label",
        id=1,
        type=Marker.TEXT_VIEW_FACING,
        action=Marker.ADD,
        text="ball_valve",
    )
    text.pose.position.y = 0.3
    sphere = Marker(ns="click", id=1, type=Marker.SPHERE, action=Marker.ADD)
    sphere.scale.x = 0.012
    arrow = Marker(ns="other", id=1, type=Marker.ARROW, action=Marker.ADD)
    d = apply_markers(
        {}, MarkerArray(markers=[_mesh_marker("candidate", 1, 0.5), text, sphere, arrow])
    )
    assert set(d) == {("candidate", 1), ("candidate_label", 1), ("click", 1)}
    mesh = d[("candidate", 1)]
    assert isinstance(mesh, MeshDrawing) and mesh.faces.shape == (1, 3)
    assert mesh.T[0, 3] == 0.5 and mesh.color == (255, 128, 0) and mesh.frame == "cam"
    # the gizmo stays within the object's outline (0.45 of its 0.2 m), at least 3 cm
    assert abs(gizmo_scale(mesh.vertices) - 0.09) < 1e-6 and gizmo_scale(mesh.vertices[:1]) == 0.03
    assert isinstance(d[("candidate_label", 1)], TextDrawing)
    assert isinstance(d[("click", 1)], SphereDrawing) and d[("click", 1)].radius == 0.006
    moved = apply_markers(d, MarkerArray(markers=[_mesh_marker("candidate", 1, 0.7)]))
    assert moved[("candidate", 1)].digest == mesh.digest  # same geometry, new pose
    deleted = apply_markers(
        d, MarkerArray(markers=[Marker(ns="click", id=1, action=Marker.DELETE)])
    )
    assert ("click", 1) not in deleted and ("candidate", 1) in deleted
    cleared = apply_markers(
        d,
        MarkerArray(markers=[Marker(action=Marker.DELETEALL), _mesh_marker("registered", 2, 0.0)]),
    )
    assert set(cleared) == {("registered", 2)}


STATUS = {
    "frame_id": "cam",
    "active_id": 3,
    "objects": [
        {
            "id": 3,
            "active": True,
            "shown": 1,
            "corrections": 0,
            "no_match": False,
            "verdict": "fits",
            "candidates": [
                {
                    "rank": 1,
                    "template": "gate_valve",
                    "probability": 0.45,
                    "fits": True,
                    "state": "closed",
                },
                {
                    "rank": 2,
                    "template": "ball_valve",
                    "probability": 0.15,
                    "fits": False,
                    "state": None,
                },
            ],
        }
    ],
    "registered": [],
    "counts": {"objects": 1, "registered": 0, "undo": 2},
    "timing_s": {"total": 0.21},
    "node": {
        "busy": None,
        "queued": 0,
        "idle": True,
        "last_message": "object 3: ...",
        "last_error": "click refused",
    },
}


def test_labels_and_the_status_panel():
    obj = STATUS["objects"][0]
    assert candidate_label(obj) == "#3 ball_valve — rank 2/2 — does not fit, 0.33x the best"
    first = dict(obj, shown=0)
    assert candidate_label(first) == "#3 gate_valve (closed) — rank 1/2 — fits, 3.0x the next"
    refused = dict(first, no_match=True, verdict="no template fits here")
    assert (
        candidate_label(refused)
        == "#3 no template fits here — best guess gate_valve (closed) — rank 1/2"
    )
    assert candidate_label(None) == ""
    assert [t for _, t in candidate_options(obj)] == ["gate_valve", "ball_valve"]
    assert [t for t, _ in candidate_options(obj)] == [
        "1. gate_valve (fits)",
        "2. ball_valve (does not fit)",
    ]
    tags, md = rendered_panel(
        status_markdown(STATUS, True, "/affordance_engine", "10 points", "next_model: ok")
    )
    assert tags == {"p", "strong"}
    for text in (
        "/affordance_engine — idle",
        "rank 2/2",
        "1 open, 0 registered",
        "0.21 s",
        "click refused",
        "10 points",
        "next_model: ok",
        "refused",
    ):
        assert text in md
    assert "Fitting" not in md
    _, md = rendered_panel(
        status_markdown(
            dict(STATUS, objects=[first]),
            True,
            "/affordance_engine",
            "",
            "",
            fitting="clicked (0.1, 0.2, 0.3)",
            stale_error=True,
        )
    )
    assert "Fitting: clicked (0.1, 0.2, 0.3)" in md
    assert "click refused" not in md and "refused" not in md  # a fit, and a stale error
    down = status_markdown(STATUS, False, "/affordance_engine", "10 points", "")
    assert down.startswith("**Engine not running**")


def test_the_headline_is_one_sentence_saying_what_is_shown_and_what_to_do():
    obj = STATUS["objects"][0]
    first = dict(obj, shown=0)
    said = headline(dict(STATUS, objects=[first]), True, "/affordance_engine")
    assert said == (
        "#3 gate_valve (closed): fits, 3.0x the next. Accept, Next, or drag the gizmo to "
        "correct it."
    )
    assert short_label(first) == "#3 gate_valve (closed) — fits"
    refused = dict(first, no_match=True)
    assert headline(dict(STATUS, objects=[refused]), True, "/e").startswith(
        "#3: no template fits here (best guess gate_valve (closed))."
    )
    assert short_label(refused) == "#3 best guess gate_valve (closed) — no fit"
    unsettled = dict(first, ambiguity={"settled": False, "reasons": ["a second pose"]})
    said = headline(dict(STATUS, objects=[unsettled]), True, "/e")
    assert "unsettled (Details says why)" in said and "a second pose" not in said
    box = dict(
        first,
        no_match=True,
        candidates=[
            {"template": "box", "primitive": "box", "fits": True, "probability": 0.3},
            *first["candidates"],
        ],
        verdict="no template fits here; fitted as a box 0.21 x 0.12 x 0.08 m",
    )
    assert headline(dict(STATUS, objects=[box]), True, "/e").startswith(
        "#3: a box 0.21 x 0.12 x 0.08 m (no template fits here). Correct its size below"
    )
    assert short_label(box) == "#3 box 0.21 x 0.12 x 0.08 m"
    nothing = dict(STATUS, objects=[], counts={"registered": 2})
    assert headline(nothing, True, "/e") == (
        "No object open: click one in the cloud to fit it; 2 registered, Save writes them."
    )
    assert headline(STATUS, True, "/e", fitting=True) == "Fitting your click…"
    assert headline(STATUS, True, "/e", alert="accept: refused — nothing") == (
        "Accept: refused — nothing"
    )
    assert headline(STATUS, False, "/affordance_engine").startswith("Engine not running")


_TEXT = st.text(min_size=0, max_size=300)


@settings(max_examples=200)
@given(
    _TEXT,
    _TEXT,
    st.booleans(),
    st.booleans(),
    st.none() | st.booleans(),
    st.sampled_from([None, "box", "cylinder"]),
    st.integers(0, 3),
    st.booleans(),
    _TEXT,
    st.booleans(),
)
def test_the_headline_is_never_longer_than_one_short_sentence(
    template, state, no_match, unsettled, fits, primitive, shown, fitting, alert, connected
):
    candidates = [
        {"template": template, "state": state, "fits": fits, "primitive": primitive}
        for _ in range(shown + 1)
    ]
    obj = {
        "id": 10**9,
        "active": True,
        "shown": shown,
        "no_match": no_match,
        "verdict": "no template fits here; fitted as " + template,
        "candidates": candidates,
        "ambiguity": {"settled": not unsettled},
    }
    status = dict(STATUS, objects=[obj])
    said = headline(status, connected, "/" + template, fitting, alert)
    assert 0 < len(said) <= HEADLINE_MAX and "\n" not in said
    assert len(short_label(obj)) <= 120


@given(st.floats(-0.2, 0.2), st.floats(-0.2, 0.2), st.floats(-30, 30))
def test_a_gizmo_press_that_does_not_move_the_fit_is_no_drag(dx, dy, deg):
    A = np.eye(4)
    A[:3, 3] = [0.3, -0.1, 0.9]
    B = A.copy()
    B[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
    B[:3, 3] += [dx, dy, 0.0]
    moved = math.hypot(dx, dy) > 0.001 or abs(deg) > 0.5
    assume(abs(math.hypot(dx, dy) - 0.001) > 1e-9 and abs(abs(deg) - 0.5) > 1e-6)
    assert drag_moved(A, B) == moved
    assert not drag_moved(A, A)


def _table_scan(tilt_deg: float, seed: int = 0):
    """A Kinect-like scan in an optical frame that does not say so (y down, z forward): a
    camera pitched ``tilt_deg`` down looks at a table 1.2 m ahead on its axis, a box on it."""
    rng = np.random.default_rng(seed)
    t = math.radians(tilt_deg)
    up = np.array([0.0, -math.cos(t), -math.sin(t)])  # the table's normal, in the camera
    forward = np.array([0.0, -math.sin(t), math.cos(t)])  # along the table, away
    centre = np.array([0.0, 0.0, 1.2])
    side = np.cross(up, forward)
    a, b = rng.uniform(-0.5, 0.5, (2, 6000))
    table = (
        centre + np.outer(a, side) + np.outer(b, forward) + rng.normal(0, 0.002, (6000, 1)) * up
    )
    u, v, w = rng.uniform(-0.05, 0.05, (3, 800))
    box = centre + np.outer(u, side) + np.outer(v, forward) + np.outer(w + 0.05, up)
    return np.vstack([table, box]), up, centre


@given(st.floats(25.0, 65.0))
@settings(max_examples=15)
def test_a_tables_normal_is_up_where_the_frame_does_not_say(tilt_deg):
    points, up, centre = _table_scan(tilt_deg)
    got, why = display.first_up(points, np.zeros(3))
    assert math.degrees(math.acos(min(1.0, got @ up))) < 3, why
    # the support under a click on the box is the table; not where it turns the view over
    under = display.support_under(points, centre + 0.05 * up, np.zeros(3), got)
    assert under is not None and under @ up > 0.99
    assert display.support_under(points, centre, np.zeros(3), -up) is None
    # a frame that says it is optical keeps the camera's up
    assert np.allclose(display.first_up(points, np.zeros(3), optical=True)[0], [0, -1, 0])


def test_a_wall_seen_head_on_is_not_a_floor():
    g = np.linspace(-0.6, 0.6, 80)
    x, y = np.meshgrid(g, g)
    wall = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 1.0)])
    got, why = display.first_up(wall, np.zeros(3))
    assert np.allclose(got, [0, 0, 1]) and "+z" in why
    assert display.support_under(wall, [0.0, 0.0, 1.0], np.zeros(3), [0, -1, 0]) is None


@given(st.floats(0.0, 1e4), st.floats(0.0, 600.0), st.floats(0.0, 600.0))
def test_the_fitting_marker_waits_its_delay_and_goes_with_the_click(sent_at, waited, delay):
    assume(abs(waited - delay) > 1e-6)  # (sent_at + waited - sent_at is rounded)
    point = np.array([0.1, 0.2, 0.3])
    drawn = fitting_marker(point, sent_at, sent_at + waited, delay)
    # drawn (the very same point: the station redraws only when it changes) exactly when the
    # click has waited its delay; a delay of 0 draws it at once; no click, no marker
    assert (drawn is point) == (waited >= delay) and (drawn is None) == (waited < delay)
    assert fitting_marker(point, sent_at, sent_at, 0.0) is point
    assert fitting_marker(None, sent_at, sent_at + waited, delay) is None


def test_gizmo_feedback_is_an_interactive_marker_client():
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.2, 0.3]
    fb = feedback_message(InteractiveMarkerFeedback.MOUSE_UP, T, "cam", "station_1")
    assert (fb.marker_name, fb.client_id, fb.header.frame_id) == (
        "affordance_fit",
        "station_1",
        "cam",
    )
    np.testing.assert_allclose(pose_to_matrix(fb.pose), T)


def test_parameters_and_port_are_checked():
    good = {name: default for name, (default, _) in PARAMETERS.items()}
    assert check_parameters(good) == ""
    for name, bad in (
        ("up", "sideways"),
        ("display_points", 10),
        ("fov_deg", 170.0),
        ("engine", "affordance_engine"),
        ("color_by", "rainbow"),
        ("sensor_origin", [0.0, 0.0]),
        ("fitting_marker_delay", -0.1),
    ):
        assert name in check_parameters(dict(good, **{name: bad}))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(AffordanceError, match="cannot serve"):
            check_port("127.0.0.1", s.getsockname()[1])
    with pytest.raises(AffordanceError, match="1-65535"):
        check_port("127.0.0.1", 70000)


def _with(status: dict, path: tuple, value) -> dict:
    """A deep copy of ``status`` with ``value`` at ``path`` (keys and list indices)."""
    import copy

    out = copy.deepcopy(status)
    where = out
    for key in path[:-1]:
        where = where[key]
    where[path[-1]] = value
    return out


#: every text of an engine status that reaches the panel: (path in the status, the panel's
#: line before it)
_STATUS_TEXTS = {
    ("node", "busy"): "Engine: /affordance_engine — ",
    ("node", "queued"): "idle, ",
    ("node", "last_message"): "Last message: ",
    ("node", "last_error"): "Last error: ",
    ("objects", 0, "candidates", 1, "template"): "#3 ",
    ("objects", 0, "candidates", 1, "state"): "ball_valve (",
    ("objects", 0, "id"): "Shown: #",
    ("counts", "objects"): "Objects: ",
    ("counts", "registered"): "open, ",
    ("counts", "undo"): "registered, ",
}
_UNSETTLED = {
    "ambiguity": {"settled": False, "reasons": ["x"]},
    "suggested_view": {"text": "y"},
}


@settings(max_examples=300, deadline=None)
@given(
    where=st.sampled_from(
        sorted(_STATUS_TEXTS, key=str)
        + ["reason", "view", "engine", "cloud", "last_action", "fitting"]
    ),
    value=st.text(min_size=1, max_size=40)
    | st.sampled_from(
        [
            '<iframe srcdoc="<script>parent.document.title=1</script>"></iframe>',
            "<img src=x onerror=alert(1)>",
            "[link](javascript:alert(1))",
            "**bold** _it_ `code` ~~s~~ | a | b |",
            "&lt;b&gt; &amp; &#60;",
            "# heading\n- item\n1. one\n\n    code",
            "<!-- a comment --> <?php ?> <![CDATA[x]]>",
            "a\\\nb  \nc\r\nd",
            "http://example.com www.example.com a@b.c",
        ]
    ),
)
def test_any_text_from_outside_renders_as_that_text(where, value):
    """Whatever text reaches the panel from outside the station -- any field of the engine's
    status (anyone on the graph may publish one), a reason or suggested view, the engine's name,
    the cloud's line (its frame id), a note quoting a service reply -- is rendered as exactly
    that text (line breaks as spaces), never as markup: the only tags are the panel's own."""
    status, engine, cloud, last_action, fitting = STATUS, "/affordance_engine", "c", "a", ""
    if where in _STATUS_TEXTS:
        status, before = _with(STATUS, where, value), _STATUS_TEXTS[where]
    elif where in ("reason", "view"):
        status = _with(STATUS, ("objects", 0, "ambiguity"), _UNSETTLED["ambiguity"])
        status = _with(status, ("objects", 0, "suggested_view"), _UNSETTLED["suggested_view"])
        path = ("reasons", 0) if where == "reason" else ("text",)
        key = "ambiguity" if where == "reason" else "suggested_view"
        status = _with(status, ("objects", 0, key, *path), value)
        before = "Unsettled: " if where == "reason" else "suggested view: "
    else:
        engine = value if where == "engine" else engine
        cloud = value if where == "cloud" else cloud
        last_action = value if where == "last_action" else last_action
        fitting = value if where == "fitting" else fitting
        before = {
            "engine": "Engine: ",
            "cloud": "Cloud: ",
            "last_action": "Last action: ",
            "fitting": "Fitting: ",
        }[where]
    line = " ".join(f"{before}{_one_line(value)}".split())
    tags, text = rendered_panel(status_markdown(status, True, engine, cloud, last_action, fitting))
    assert tags <= {"p", "strong"} and line in text, (tags, line, text)
    # the Shown line: the shown candidate's label, as it is
    tags, text = rendered_panel(shown_markdown(active_object(status)))
    label = candidate_label(active_object(status))
    assert tags <= {"p", "strong"} and text == " ".join(f"Shown: {_one_line(label)}".split())


def _one_line(value: str) -> str:
    """``value`` as the panel shows it: line breaks and control characters as spaces."""
    return "".join(" " if unicodedata.category(c) in ("Cc", "Zl", "Zp") else c for c in value)


def test_a_scan_files_viewpoint_is_where_the_station_looks_from(tmp_path):
    """`station --scene` hands the file's VIEWPOINT (in its units) to the engine and the
    station as sensor_origin: the first view looks from there."""
    from affordance_registration.ros.station.scene import read_scan

    rows = "\n".join(f"{x} {y} 1500" for x in range(-20, 21) for y in range(-20, 21))
    head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1681\n"
    path = tmp_path / "scan.pcd"
    path.write_text(
        head + "HEIGHT 1\nVIEWPOINT 10 20 30 1 0 0 0\nPOINTS 1681\nDATA ascii\n" + rows
    )
    scan = read_scan(str(path), "mm")
    np.testing.assert_allclose(scan.sensor_origin, [0.01, 0.02, 0.03])
    assert scan.colors is None and scan.points.shape == (1681, 3)
    position, _ = display.initial_view(
        scan.points, [0, -1, 0], math.radians(60), scan.sensor_origin
    )
    assert np.allclose(position, scan.sensor_origin)  # (the scan fits the view from there)
