# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""End-effector waypoints and paths along a joint: where they land on simulated scans fitted at
the estimated joint value, the geometry of the paths, and template files that declare them
wrongly."""

import math

import numpy as np
import pytest
import trimesh
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from affordance_registration.core.errors import AffordanceError, TemplateError
from affordance_registration.core.registration import FitResult, Registrar
from affordance_registration.core.scene import Scene
from affordance_registration.core.templates import TemplateLibrary, load_template
from affordance_registration.core.transforms import axis_angle_matrix, make_T
from affordance_registration.core.waypoints import (
    PATH_STEP_M,
    PATH_STEP_RAD,
    trajectory,
    waypoint_poses,
)
from affordance_registration.evaluation.simulation import simulate_taskboard

LEVERS = {"ball_valve": "lever_grasp", "quarter_turn_valve": "handle_grasp"}


@pytest.fixture(scope="module")
def library():
    return TemplateLibrary.load()


def _fit(template, T, q=None, scale=1.0, dimensions=None):
    joints = {} if q is None else {template.joints[0].name: q}
    return FitResult(
        template.name,
        T,
        0.001,
        1000.0,
        joints=joints,
        scale=scale,
        dimensions=dict(dimensions or {}),
        primitive=template.primitive,
    )


def _nearest(mesh, point):
    """(distance, outward unit normal of the nearest face) from ``point`` to ``mesh``'s
    surface (Open3D's closest-point query, independent of the code under test)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
    )
    hit = scene.compute_closest_points(o3d.core.Tensor(np.asarray([point], dtype=np.float32)))
    closest = hit["points"].numpy()[0].astype(float)
    return float(np.linalg.norm(closest - point)), mesh.face_normals[
        int(hit["primitive_ids"].numpy()[0])
    ]


def _random_pose(rng):
    R = axis_angle_matrix(rng.normal(size=3), rng.uniform(0, math.pi))
    return make_T(R, rng.uniform(-1, 1, 3))


# ---------------------------------------------------------------------------- the bundled library
def test_every_bundled_template_carries_its_waypoints(library):
    expected = {
        "ball_valve": {"lever_grasp"},
        "quarter_turn_valve": {"handle_grasp"},
        "gate_valve": {"rim_grasp"},
        "emergency_stop": {"push"},
        "grab_handle": {"bar_grasp", "bar_pull"},
        "box": {"top_grasp"},
        "cylinder": {"side_grasp"},
    }
    assert set(library) == set(expected)
    for name, names in expected.items():
        tpl = library[name]
        assert {w.name for w in tpl.waypoints} == names
        for w in tpl.waypoints:
            assert w.name in tpl.description, (name, w.name)  # documented there
            assert w.end_effector == "gripper"
    for name in ("ball_valve", "quarter_turn_valve", "gate_valve", "emergency_stop"):
        assert library[name].waypoints[0].part == library[name].joints[0].name


def test_waypoints_on_the_surface_of_the_part_they_grasp_at_every_joint_value(library):
    """At joint values across the range, each bundled waypoint lies on the surface of the part
    it moves with (within 1 mm) and its approach goes into that surface (the outward normal of
    the nearest face against it, within 10 deg)."""
    for name in ("ball_valve", "quarter_turn_valve", "gate_valve", "emergency_stop"):
        tpl = library[name]
        j = tpl.joints[0]
        for q in np.linspace(j.lower, j.upper, 4):
            (wp,) = waypoint_poses(tpl, _fit(tpl, np.eye(4), q))
            dist, normal = _nearest(tpl.moving_mesh_at(q), wp.T[:3, 3])
            assert dist < 0.001, (name, q, dist)
            # the handwheel's rim is a 16-sided tube: its faces tilt 11.25 deg off its crest
            limit = 12 if name == "gate_valve" else 10
            assert math.degrees(math.acos(np.clip(-normal @ wp.approach, -1, 1))) < limit


def test_primitive_grasps_follow_the_fitted_size(library):
    box, cyl = library["box"], library["cylinder"]
    T = make_T(axis_angle_matrix([0, 0, 1], 0.3), [0.5, -0.2, 0.1])
    (top,) = waypoint_poses(box, _fit(box, T, dimensions={"x": 0.3, "y": 0.2, "z": 0.12}))
    assert np.allclose(top.T[:3, 3], T[:3, :3] @ [0, 0, 0.12] + T[:3, 3])
    assert np.allclose(top.approach, -T[:3, 2])  # down onto the top face
    assert np.allclose(top.T_pre[:3, 3], top.T[:3, 3] + 0.1 * T[:3, 2])
    (side,) = waypoint_poses(cyl, _fit(cyl, np.eye(4), dimensions={"radius": 0.04, "length": 0.2}))
    assert np.allclose(side.T[:3, 3], [0.04, 0, 0.1])
    assert np.allclose(side.approach, [-1, 0, 0])  # towards the axis
    assert np.allclose(side.T[:3, 2], [-1, 0, 0], atol=1e-6)  # the gripper's z: the approach


# ---------------------------------------------------------------------------- simulated scans
@pytest.mark.parametrize("seed", [2901, 2902, 2903])
def test_lever_grasp_lands_on_the_lever_at_the_estimated_joint_value(library, seed):
    """Simulated panels with random lever angles: each valve is fitted from a click (pose and
    joint value estimated); its grasp waypoint, placed with the estimate, is within 5 mm of the
    true lever's surface, its approach within 10 deg of that surface's inward normal; the path
    to each state ends where the waypoint is with the joint at that state."""
    sim = simulate_taskboard(library, seed, articulated=True, templates=list(LEVERS))
    registrar = Registrar(library)
    scene = Scene(sim.organized)
    for obj in sim.objects:
        best = registrar.fit(scene, obj.click).candidates[0]
        assert best.template == obj.template
        tpl = library[obj.template]
        (wp,) = waypoint_poses(tpl, best)
        q_true = obj.joints[tpl.joints[0].name]
        lever = tpl.moving_mesh_at(q_true).copy().apply_transform(obj.T_scene_model)
        dist, normal = _nearest(lever, wp.T[:3, 3])
        assert dist < 0.005, (seed, obj.template, q_true, best.joints, dist)
        angle = math.degrees(math.acos(np.clip(-normal @ wp.approach, -1, 1)))
        assert angle < 10, (seed, obj.template, angle)
        for state, values in tpl.states.items():
            path = trajectory(tpl, best, state)
            at_state = _fit(tpl, best.T_scene_model, values[tpl.joints[0].name])
            (end,) = waypoint_poses(tpl, at_state)
            assert np.allclose(path.poses[-2], end.T, atol=1e-9)  # last before retreat
            assert np.allclose(path.poses[-1], end.T_pre, atol=1e-9)  # the retreat
            assert np.allclose(path.poses[1], wp.T, atol=1e-9)  # starts at the grasp
            assert np.allclose(path.poses[0], wp.T_pre, atol=1e-9)  # after the approach


# ---------------------------------------------------------------------------- path geometry
@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    seed=st.integers(0, 2**31),
    name=st.sampled_from(["ball_valve", "quarter_turn_valve", "gate_valve", "emergency_stop"]),
    frac=st.floats(0, 1),
    scale=st.floats(0.8, 1.25),
)
def test_every_path_pose_is_on_the_circle_or_line_of_the_joint(library, seed, name, frac, scale):
    """From any pose, joint value and scale, to every state: the path's poses lie on the circle
    about the joint axis (revolute), the line along it (prismatic) or the helix about it (a
    prismatic part with a pitch: the gate valve's wheel, 4 mm a turn), in the joint's sense,
    evenly spaced at most 5 deg / 5 mm apart, each with the part's orientation at its value."""
    tpl = library[name]
    j = tpl.joints[0]
    rng = np.random.default_rng(seed)
    T = _random_pose(rng)
    q0 = j.lower + frac * (j.upper - j.lower)
    fit = _fit(tpl, T, q0, scale)
    axis = T[:3, :3] @ np.asarray(j.axis)
    origin = T[:3, :3] @ (scale * np.asarray(j.origin)) + T[:3, 3]
    (start,) = waypoint_poses(tpl, fit)
    for state, values in tpl.states.items():
        path = trajectory(tpl, fit, state)
        along = path.poses[np.array(path.kinds) == "path"]
        qs = path.joint_values[np.array(path.kinds) == "path"]
        q1 = values[j.name]
        assert qs[0] == pytest.approx(q0) and qs[-1] == pytest.approx(q1)
        steps = np.abs(np.diff(qs))
        pitch = tpl.waypoints[0].pitch
        limit = PATH_STEP_RAD if j.type == "revolute" else PATH_STEP_M
        turn = (
            (lambda q: q - q0)
            if j.type == "revolute"
            else (lambda q: 0.0)
            if pitch is None
            else (lambda q: 2 * math.pi * (q - q0) / pitch)
        )
        assert np.all(steps <= limit + 1e-12) and (len(steps) == 0 or np.ptp(steps) < 1e-9)
        assert np.all(np.abs(np.diff([turn(q) for q in qs])) <= PATH_STEP_RAD + 1e-9)
        offset0 = start.T[:3, 3] - origin
        for P, q in zip(along, qs):
            R = axis_angle_matrix(axis, turn(q))
            assert np.allclose(P[:3, :3], R @ start.T[:3, :3], atol=1e-9)
            offset = P[:3, 3] - origin
            # along the axis: where it started (revolute) or moved by the joint's travel
            rise = 0.0 if j.type == "revolute" else (q - q0) * scale
            assert offset @ axis == pytest.approx(offset0 @ axis + rise, abs=1e-9)
            # about the axis: the start turned by the joint's (or the screw's) angle -- the
            # same distance from the axis (a circle, a helix), or no turn (a line)
            across, across0 = offset - (offset @ axis) * axis, offset0 - (offset0 @ axis) * axis
            assert np.allclose(across, R @ across0, atol=1e-9)


def test_path_requests_that_cannot_be_answered_say_why_in_one_line(library):
    valve, handle = library["ball_valve"], library["grab_handle"]
    fit = _fit(valve, np.eye(4), 0.2)
    for tpl, fitted, state, waypoint, words in [
        (valve, fit, "ajar", None, "no state 'ajar'"),
        (valve, fit, "closed", "nope", "no waypoint 'nope'"),
        (handle, _fit(handle, np.eye(4)), "open", None, "no state"),
    ]:
        with pytest.raises(AffordanceError) as info:
            trajectory(tpl, fitted, state, waypoint)
        assert words in str(info.value) and "\n" not in str(info.value)
    path = trajectory(valve, fit, "open")
    assert path.kinds[0] == "approach" and path.kinds[-1] == "retreat"
    assert path.joint_values[1] == pytest.approx(0.2) and path.joint_values[-2] == 0.0


# ---------------------------------------------------------------------------- bad template files
def _template(tmp_path, waypoints, joints=True, states=None, extra=None, joint_type="revolute"):
    trimesh.creation.box(extents=[0.1, 0.1, 0.05]).export(tmp_path / "box.stl")
    doc = {"name": "t", "mesh": "box.stl", "waypoints": waypoints}
    if joints:
        doc.update(
            base_mesh="box.stl",
            joints=[
                {
                    "name": "lever",
                    "type": joint_type,
                    "axis": [0, 0, 1],
                    "lower": 0,
                    "upper": 1.5,
                    "moving_mesh": "box.stl",
                }
            ],
        )
    if states is not None:
        doc["states"] = states
    doc.update(extra or {})
    path = tmp_path / "t.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


GOOD = {"name": "g", "end_effector": "gripper", "position": [0, 0, 0.05]}


@pytest.mark.parametrize(
    "waypoints,key,words",
    [
        ([dict(GOOD, part="wheel")], "waypoints.g.part", "no joint (moving part) named 'wheel'"),
        ([dict(GOOD, quaternion=[0, 0, 0, 2])], "waypoints.g.quaternion", "not a unit quaternion"),
        ([dict(GOOD, quaternion=[0, 0, 1])], "waypoints.g.quaternion", "4 finite numbers"),
        ([dict(GOOD, rpy=[0, 0, 0], quaternion=[0, 0, 0, 1])], "waypoints.g.rpy", "not both"),
        ([dict(GOOD, rpy=[0, "x", 0])], "waypoints.g.rpy", "expected 3 numbers"),
        ([{"name": "g", "end_effector": "gripper"}], "waypoints.g.position", "missing"),
        ([dict(GOOD, end_effector="")], "waypoints.g.end_effector", "expected a name"),
        ([dict(GOOD, name="pre_g")], "waypoints[0].name", "pre_"),
        ([dict(GOOD, name="a/b")], "waypoints[0].name", "expected a name"),
        ([GOOD, GOOD], "waypoints[1].name", "duplicate waypoint name 'g'"),
        ([dict(GOOD, tool="x")], "waypoints[0].tool", "unknown key"),
        (
            [dict(GOOD, approach={"direction": [0, 0, 0], "distance": 0.1})],
            "waypoints.g.approach.direction",
            "must not be zero",
        ),
        (
            [dict(GOOD, approach={"direction": [0, 0, 1], "distance": -1})],
            "waypoints.g.approach.distance",
            "positive",
        ),
        ([dict(GOOD, approach={"direction": [0, 0, 1]})], "waypoints.g.approach", "distance"),
        ([dict(GOOD, position=[1e6, 0, 0])], "waypoints.g.position", "100 m"),
        ([dict(GOOD, part="lever", pitch=0.004)], "waypoints.g.pitch", "prismatic part"),
        ([dict(GOOD, pitch=0.004)], "waypoints.g.pitch", "prismatic part"),
        ([dict(GOOD, name=f"w{i}") for i in range(33)], "waypoints", "at most 32"),
        ({"g": GOOD}, "waypoints", "a list"),
    ],
)
def test_a_bad_waypoint_is_one_line_naming_file_and_key(tmp_path, waypoints, key, words):
    path = _template(tmp_path, waypoints)
    with pytest.raises(TemplateError) as info:
        load_template(path)
    message = str(info.value)
    assert message.startswith(f"{path}: key '{key}'"), message
    assert words in message and "\n" not in message


def test_a_state_with_no_joint_and_a_part_without_joints_are_refused(tmp_path):
    path = _template(tmp_path, [GOOD], states={"open": {}})
    with pytest.raises(TemplateError, match=r"key 'states.open': names no joint value"):
        load_template(path)
    path = _template(tmp_path, [dict(GOOD, part="lever")], joints=False)
    with pytest.raises(
        TemplateError,
        match=r"key 'waypoints.g.part': 'lever': the template "
        r"has no moving parts",
    ):
        load_template(path)


@settings(max_examples=60, deadline=None)
@given(q=st.lists(st.floats(-2, 2, allow_nan=False), min_size=4, max_size=4))
def test_quaternions_are_taken_only_when_unit(tmp_path_factory, q):
    path = _template(tmp_path_factory.mktemp("q"), [dict(GOOD, quaternion=q)])
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) <= 1e-3:
        (wp,) = load_template(path).waypoints
        R = wp.T_parent_ee[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-9)
    else:
        with pytest.raises(TemplateError, match="not a unit quaternion"):
            load_template(path)


def test_a_screw_pitch_is_a_length_per_turn_in_file_units(tmp_path):
    for pitch in (0, -0.000001, "fine", True):
        path = _template(tmp_path, [dict(GOOD, part="lever", pitch=pitch)], joint_type="prismatic")
        with pytest.raises(TemplateError, match=r"key 'waypoints.g.pitch': expected a non-zero"):
            load_template(path)
    path = _template(
        tmp_path,
        [dict(GOOD, part="lever", pitch=-4)],
        joint_type="prismatic",
        extra={"mesh_scale": 0.001},
    )
    assert load_template(path).waypoints[0].pitch == pytest.approx(-0.004)  # a left-hand screw


def test_file_units_and_rpy_are_read_as_documented(tmp_path):
    """Positions and approach distances in the file's units (mesh_scale: 0.001 -> mm), roll
    pitch yaw about the fixed x, y, z axes."""
    path = _template(
        tmp_path,
        [
            dict(
                GOOD,
                position=[10, 20, 30],
                rpy=[0, 0, math.pi / 2],
                approach={"direction": [0, 0, -2], "distance": 50},
            )
        ],
        joints=False,
        extra={"mesh_scale": 0.001},
    )
    (wp,) = load_template(path).waypoints
    assert np.allclose(wp.T_parent_ee[:3, 3], [0.01, 0.02, 0.03])
    assert np.allclose(wp.T_parent_ee[:3, 0], [0, 1, 0], atol=1e-12)
    assert wp.approach == (0.0, 0.0, -1.0) and wp.distance == pytest.approx(0.05)


# ---------------------------------------------------------------------------- engine and file
def test_engine_status_path_and_saved_file_carry_the_waypoints(library, tmp_path):
    """A registered valve's waypoints are in the engine's status and the saved file (cloud
    frame), come back the same from the reloaded file, and its path to a state is asked for by
    object id; an unknown object or state is one line."""
    from affordance_registration.core.engine import AffordanceEngine, load_registrations
    from affordance_registration.core.errors import EngineStateError

    sim = simulate_taskboard(library, 2904, articulated=True, templates=["ball_valve"])
    engine = AffordanceEngine(library)
    engine.set_scene(sim.organized, frame_id="cam")
    engine.click(sim.objects[0].click)
    shown = engine.status()["objects"][0]
    assert [w["name"] for w in shown["waypoints"]] == ["lever_grasp"]
    engine.accept()
    (reg,) = engine.state.registered
    (status,) = engine.status()["registered"]
    (expected,) = waypoint_poses(library["ball_valve"], reg)
    assert np.allclose(status["waypoints"][0]["pose"], expected.T, atol=1e-8)
    assert np.allclose(status["waypoints"][0]["pre_pose"], expected.T_pre, atol=1e-8)
    path = trajectory(library["ball_valve"], reg, "closed")
    assert np.array_equal(engine.trajectory(reg.id, "closed").poses, path.poses)
    for object_id, state, words in [
        (99, "closed", "no object 99"),
        (reg.id, "ajar", "no state 'ajar'"),
    ]:
        with pytest.raises(AffordanceError) as info:
            engine.trajectory(object_id, state)
        assert words in str(info.value) and "\n" not in str(info.value)
    assert isinstance(
        pytest.raises(EngineStateError, engine.trajectory, 99, "open").value, EngineStateError
    )
    saved = tmp_path / "registrations.yaml"
    engine.save(str(saved))
    (entry,) = yaml.safe_load(saved.read_text())["registrations"]
    assert entry["frame_id"] == "cam"
    assert np.allclose(entry["waypoints"][0]["pose"], expected.T, atol=1e-8)
    (loaded,) = load_registrations(str(saved), library)
    (again,) = waypoint_poses(library["ball_valve"], loaded)
    assert np.allclose(again.T, expected.T, atol=1e-6)
    assert np.allclose(again.T_pre, expected.T_pre, atol=1e-6)


def test_markers_draw_each_waypoint_as_a_gripper(library):
    """The RViz markers of a state: a LINE_LIST per object whose finger tips are at the
    waypoint, 20 mm either side along its y, its approach a line from the pre_ pose."""
    from affordance_registration.core.tracked import EngineState, Registration
    from affordance_registration.ros.glue.markers import state_markers

    tpl = library["grab_handle"]
    T = make_T(axis_angle_matrix([1, 0, 0], 0.4), [0.2, 0.1, 0.9])
    reg = Registration(
        id=3,
        template="grab_handle",
        T_scene_model=T,
        likelihood=1.0,
        probability=1.0,
        residual=0.001,
        click=T[:3, 3],
    )
    arr = state_markers(EngineState(registered=(reg,)), library, "cam", None, np.array([0, 1, 0]))
    (m,) = [m for m in arr.markers if m.ns == "registered_waypoints"]
    assert m.id == 3 and m.header.frame_id == "cam" and len(m.points) == len(m.colors)
    pts = np.array([(p.x, p.y, p.z) for p in m.points])
    grasp, pull = waypoint_poses(tpl, reg)
    for wp in (grasp, pull):
        for side in (-1, 1):  # a finger tip at the waypoint, either side along its y
            tip = wp.T[:3, 3] + side * 0.02 * wp.T[:3, 1]
            assert np.min(np.linalg.norm(pts - tip, axis=1)) < 1e-6
    assert np.min(np.linalg.norm(pts - grasp.T_pre[:3, 3], axis=1)) < 1e-6  # the approach
    assert len(pts) == 2 * 10 + 2  # 5 segments a gripper, one approach (bar_pull none)
    # the station draws the same lines, in the marker's frame, with their colours
    from affordance_registration.ros.station.state import LineDrawing, apply_markers

    drawn = apply_markers({}, arr)[("registered_waypoints", 3)]
    assert isinstance(drawn, LineDrawing) and drawn.segments.shape == (len(pts) // 2, 2, 3)
    assert np.allclose(drawn.segments.reshape(-1, 3), pts, atol=1e-6)
    # bar_grasp's four gripper segments, its x axis in red, its approach line in grey
    assert tuple(drawn.colors[4, 0]) == (255, 26, 26)
    assert tuple(drawn.colors[5, 0]) == (178, 178, 178)


@settings(max_examples=200, deadline=None)
@given(text=st.text(max_size=300))
@example(text="\u00b2 closed")  # a digit to str.isdigit, not to int()
@example(text="12 closed lever_grasp")
def test_a_path_request_line_is_read_or_refused_in_one_line(text):
    """Any text on ~/path_request: read as 'ID STATE [WAYPOINT]' or refused with one line
    saying what the line should be -- never another exception."""
    from affordance_registration.ros.glue.paths import parse_path_request

    try:
        object_id, state, waypoint = parse_path_request(text)
    except AffordanceError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 300
        return
    words = text.split()
    assert object_id == int(words[0]) and state == words[1] and len(text) <= 256
    assert waypoint == (words[2] if len(words) == 3 else None)
