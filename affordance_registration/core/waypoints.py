# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""End-effector waypoints of a template and the paths along its joint (Affordance Templates'
end-effector waypoint trajectories), computed for a fitted or registered object.

A template declares waypoints in its YAML file::

    waypoints:
      - name: lever_grasp           # letters, digits, _ (not starting with pre_); unique
        end_effector: gripper       # the end effector it is for (several may have their own)
        part: lever                 # optional: a joint; the waypoint moves with its moving part
        position: [0.12, 0, 0.096]  # the file's units, like joint origins
        rpy: [3.141593, 0, 0]       # or quaternion: [x, y, z, w] (unit); default: identity
        approach: {direction: [0, 0, -1], distance: 0.08}   # optional: gives the pre_ pose
        pitch: 4.0                  # optional, on a prismatic part: it also turns (a screw)

``position``, the orientation and the approach direction are in the template frame -- or, with
``part``, in the template frame with that joint at zero: the waypoint then follows the joint's
estimated or corrected value. The approach ``direction`` is the way the end effector moves to
reach the waypoint; the ``pre_`` pose is the waypoint moved back against it by ``distance``
(file units), with the same orientation. A template's fitted scale scales positions (about its
origin), not approach distances. In a ``primitive:`` template positions are fractions of its
fitted dimensions -- a box's (x, y, z) edge lengths, a cylinder's (radius, radius, length) -- so
``[0, 0, 1]`` is the centre of a box's top face whatever its size; approach distances are metres.
``pitch`` (file units, on a prismatic part only) makes the part turn one full turn about the joint
axis (right-handed) per ``pitch`` of travel -- a handwheel on a rising stem, whose mesh the fit
cannot tell turned: the waypoint at the object's joint value is where the template puts it, and
the path from there is a helix.

The end effector's frame is the author's: the bundled templates use z along the approach
(pointing from the gripper into the object) and y across the closing fingers.

A path (:func:`trajectory`) takes a waypoint on a moving part from the object's current joint
value to a named state: the ``pre_`` pose (when the waypoint has an approach), the waypoint at
joint values from the current one to the state's, at most ``PATH_STEP_RAD`` (revolute) or
``PATH_STEP_M`` (prismatic) apart and evenly spaced, and the retreat (the state's waypoint moved
back along the approach). Pure numpy (no ROS).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import AffordanceError, TemplateError
from .transforms import axis_angle_matrix, make_T, matrix_to_quat_xyzw, template_vector

__all__ = [
    "Waypoint",
    "WaypointPose",
    "Trajectory",
    "parse_waypoints",
    "template_orientation",
    "waypoint_poses",
    "trajectory",
    "waypoints_dict",
    "MAX_WAYPOINTS",
    "PATH_STEP_RAD",
    "PATH_STEP_M",
]

MAX_WAYPOINTS = 32
MAX_NAME = 64
PATH_STEP_RAD = math.radians(5.0)  #: rad, the largest joint step between two poses of a path
PATH_STEP_M = 0.005  #: m, the same for a prismatic joint
MAX_PATH_POSES = 5000  #: a path longer than this is refused
QUATERNION_TOLERANCE = 1e-3  #: how far from 1 a quaternion's norm may be
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_KEYS = {"name", "end_effector", "part", "position", "rpy", "quaternion", "approach", "pitch"}


@dataclass(frozen=True)
class Waypoint:
    """A waypoint as its template declares it: ``T_parent_ee`` (4x4, metres -- for a primitive,
    its translation is in fractions of the dimensions) in the template frame or, with ``part``
    (a joint name), in the template frame with that joint at zero; ``approach`` a unit vector in
    the same frame (None: no pre_ pose), ``distance`` metres."""

    name: str
    end_effector: str
    T_parent_ee: np.ndarray = field(repr=False, compare=False)
    part: str | None = None
    approach: tuple | None = None
    distance: float = 0.0
    pitch: float | None = None  #: m of a prismatic part's travel per turn (a screw)


@dataclass(frozen=True)
class WaypointPose:
    """A waypoint of a fitted object: its pose and its ``pre_`` pose (None without an approach),
    4x4 in the frame the object's pose is given in; ``approach`` a unit vector there."""

    waypoint: Waypoint
    T: np.ndarray = field(repr=False)
    T_pre: np.ndarray | None = field(default=None, repr=False)
    approach: np.ndarray | None = field(default=None, repr=False)

    @property
    def name(self) -> str:
        return self.waypoint.name

    def to_dict(self) -> dict:
        def pose(T):
            return None if T is None else [[round(float(v), 9) for v in row] for row in T]

        wp = self.waypoint
        return {
            "name": wp.name,
            "end_effector": wp.end_effector,
            "part": wp.part,
            "pose": pose(self.T),
            "position": [round(float(v), 9) for v in self.T[:3, 3]],
            "orientation_xyzw": [round(float(v), 9) for v in matrix_to_quat_xyzw(self.T[:3, :3])],
            "pre_pose": pose(self.T_pre),
            "approach": None
            if self.approach is None
            else [round(float(v), 9) for v in self.approach],
            "distance": round(float(wp.distance), 9),
        }


@dataclass(frozen=True)
class Trajectory:
    """A path of one waypoint to a named state: ``poses`` (n, 4, 4) in the object's pose frame,
    ``joint_values`` (n,) the joint value each pose is at, ``kinds`` one of "approach", "path",
    "retreat" per pose."""

    waypoint: str
    state: str
    joint: str
    poses: np.ndarray = field(repr=False)
    joint_values: np.ndarray = field(repr=False)
    kinds: tuple = ()


# ---------------------------------------------------------------------------- the template file
def parse_waypoints(
    path: str, value, joints: tuple, scale: float, primitive: str | None = None
) -> tuple:
    """The ``waypoints`` key of a template file, checked: a :class:`TemplateError` naming the
    file and the key for the first problem. ``scale``: the file's units to metres."""

    def fail(key, msg):
        return TemplateError(f"{path}: key '{key}': {msg}")

    if value is None:
        return ()
    if not isinstance(value, list):
        raise fail("waypoints", "expected a list of waypoints")
    if len(value) > MAX_WAYPOINTS:
        raise fail("waypoints", f"{len(value)} waypoints; at most {MAX_WAYPOINTS}")
    by_joint = {j.name: j for j in joints}
    out, names = [], set()
    for i, spec in enumerate(value):
        key = f"waypoints[{i}]"
        if not isinstance(spec, dict):
            raise fail(key, "expected a mapping with name, end_effector and position")
        unknown = sorted(set(spec) - _KEYS)
        if unknown:
            raise fail(f"{key}.{unknown[0]}", f"unknown key (known: {', '.join(sorted(_KEYS))})")
        name = _name(spec.get("name"), f"{key}.name", fail)
        if name.startswith("pre_"):
            raise fail(f"{key}.name", "must not start with 'pre_' (the approach poses' prefix)")
        if name in names:
            raise fail(f"{key}.name", f"duplicate waypoint name '{name}'")
        names.add(name)
        key = f"waypoints.{name}"
        effector = _name(spec.get("end_effector"), f"{key}.end_effector", fail)
        part = spec.get("part")
        if part is not None:
            if primitive is not None or not by_joint:
                raise fail(f"{key}.part", f"'{part}': the template has no moving parts")
            if part not in by_joint:
                raise fail(
                    f"{key}.part",
                    f"no joint (moving part) named {part!r} (joints: {', '.join(by_joint)})",
                )
        if "position" not in spec:
            raise fail(f"{key}.position", "missing")
        unit = 1.0 if primitive is not None else scale
        position = template_vector(spec["position"], f"{key}.position", fail) * unit
        if float(np.linalg.norm(position)) > 100.0:
            raise fail(f"{key}.position", "more than 100 m from the template's origin")
        R = template_orientation(spec, key, fail)
        approach, distance = _approach(spec.get("approach"), f"{key}.approach", fail, unit)
        pitch = spec.get("pitch")
        if pitch is not None:
            if part is None or by_joint[part].type != "prismatic":
                raise fail(f"{key}.pitch", "only a waypoint on a prismatic part has a pitch")
            if (
                isinstance(pitch, bool)
                or not isinstance(pitch, (int, float))
                or not math.isfinite(pitch)
                or pitch == 0
                or abs(pitch) * unit < 1e-5
            ):
                raise fail(
                    f"{key}.pitch",
                    f"expected a non-zero length per turn (at least 0.01 mm), got {pitch!r}",
                )
            pitch = float(pitch) * unit
        out.append(
            Waypoint(
                name=name,
                end_effector=effector,
                T_parent_ee=make_T(R, position),
                part=part,
                approach=approach,
                distance=distance,
                pitch=pitch,
            )
        )
    return tuple(out)


def _name(value, key: str, fail) -> str:
    if not isinstance(value, str) or not _NAME.match(value) or len(value) > MAX_NAME:
        raise fail(
            key,
            f"expected a name of letters, digits and _ (starting with a letter, at "
            f"most {MAX_NAME} characters), got {value!r}",
        )
    return value


def template_orientation(spec: dict, key: str, fail) -> np.ndarray:
    """The rotation (3, 3) a template file's ``spec`` gives by ``rpy`` (fixed axes: roll, pitch,
    yaw; rad) or ``quaternion`` ([x, y, z, w], unit); the identity with neither. Anything else
    raises ``fail(key, message)``."""
    if "rpy" in spec and "quaternion" in spec:
        raise fail(f"{key}.rpy", "give either rpy or quaternion, not both")
    if "rpy" in spec:
        rpy = template_vector(spec["rpy"], f"{key}.rpy", fail)
        return Rotation.from_euler("xyz", rpy).as_matrix()  # fixed axes: roll, pitch, yaw
    if "quaternion" in spec:
        q = template_vector(spec["quaternion"], f"{key}.quaternion", fail, 4)
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise fail(
                f"{key}.quaternion", f"not a unit quaternion [x, y, z, w]: its norm is {norm:.6g}"
            )
        return Rotation.from_quat(q / norm).as_matrix()
    return np.eye(3)


def _approach(value, key: str, fail, unit: float):
    if value is None:
        return None, 0.0
    if not isinstance(value, dict) or set(value) != {"direction", "distance"}:
        raise fail(key, f"expected {{direction: [x, y, z], distance: D}}, got {value!r}")
    d = template_vector(value["direction"], f"{key}.direction", fail)
    if float(np.linalg.norm(d)) < 1e-9:
        raise fail(f"{key}.direction", "must not be zero")
    distance = value["distance"]
    if (
        isinstance(distance, bool)
        or not isinstance(distance, (int, float))
        or not math.isfinite(distance)
        or distance <= 0
    ):
        raise fail(f"{key}.distance", f"expected a positive number, got {distance!r}")
    if distance * unit > 10.0:
        raise fail(f"{key}.distance", f"{distance * unit:.3g} m: at most 10 m")
    return tuple(float(v) for v in d / np.linalg.norm(d)), float(distance * unit)


# ---------------------------------------------------------------------------- poses
def _turn(joint, angle: float) -> np.ndarray:
    """4x4 turn by ``angle`` about ``joint``'s axis line (template frame)."""
    axis, origin = np.asarray(joint.axis, float), np.asarray(joint.origin, float)
    R = axis_angle_matrix(axis, angle)
    return make_T(R, origin - R @ origin)


def _joint_motion(joint, q: float) -> np.ndarray:
    """4x4 motion of ``joint``'s moving part at value ``q`` from its zero pose (template frame,
    metres)."""
    if joint.type == "prismatic":
        return make_T(t=np.asarray(joint.axis, float) * q)
    return _turn(joint, q)


def _posed(
    template,
    wp: Waypoint,
    T_scene_model: np.ndarray,
    q: float,
    scale: float,
    dimensions: dict,
    q_ref: float | None = None,
) -> tuple:
    """(T, T_pre, approach) of ``wp`` with its joint at ``q`` (scene frame). A screw (``pitch``)
    turns from where it is at ``q_ref`` (None: ``q``): the fit does not see it turned."""
    T_local = np.array(wp.T_parent_ee, dtype=float)
    if template.primitive is not None:
        dims = dimensions or template.dimensions
        if template.primitive == "box":
            size = np.array([dims["x"], dims["y"], dims["z"]], float)
        else:
            size = np.array([dims["radius"], dims["radius"], dims["length"]], float)
        T_local[:3, 3] *= size
    M = np.eye(4)
    if wp.part is not None:
        joint = next(j for j in template.joints if j.name == wp.part)
        M = _joint_motion(joint, q)
        if wp.pitch is not None:  # turned about the axis line (travel keeps the line)
            M = _turn(joint, 2 * math.pi * (q - (q if q_ref is None else q_ref)) / wp.pitch) @ M
    T_model = M @ T_local
    T_model[:3, 3] *= scale
    T = np.asarray(T_scene_model, float) @ T_model
    if wp.approach is None:
        return T, None, None
    d = T[:3, :3] @ T_local[:3, :3].T @ np.asarray(wp.approach)
    T_pre = T.copy()
    T_pre[:3, 3] -= wp.distance * d
    return T, T_pre, d


def _fit_of(fit) -> tuple:
    """(template name, T_scene_model, joints, scale, dimensions) of a FitResult or
    Registration."""
    return (
        fit.template,
        np.asarray(fit.T_scene_model, float),
        dict(fit.joints or {}),
        float(fit.scale),
        dict(fit.dimensions or {}),
    )


def waypoint_poses(template, fit) -> tuple:
    """The waypoints of ``fit`` (a FitResult or Registration of ``template``) at its joint
    values, scale and dimensions: :class:`WaypointPose` records in the fit's frame."""
    _, T, joints, scale, dims = _fit_of(fit)
    out = []
    for wp in getattr(template, "waypoints", ()):
        q = float(joints.get(wp.part, 0.0)) if wp.part else 0.0
        T_wp, T_pre, d = _posed(template, wp, T, q, scale, dims)
        out.append(WaypointPose(wp, T_wp, T_pre, d))
    return tuple(out)


def waypoints_dict(library, fit) -> list:
    """The waypoints of ``fit`` as JSON-ready dicts ([] for a template not in ``library``)."""
    if fit.template not in library:
        return []
    return [w.to_dict() for w in waypoint_poses(library[fit.template], fit)]


def trajectory(template, fit, state: str, waypoint: str | None = None) -> Trajectory:
    """The path of ``waypoint`` (default: the template's first waypoint on a moving part) of
    ``fit`` from its current joint value to the named ``state`` (see the module docstring).
    :class:`AffordanceError` in one line when the state, the waypoint or its joint is not
    there."""
    states = template.states
    if state not in states:
        raise AffordanceError(
            f"{template.name} has no state {state!r} (states: {', '.join(states) or 'none'})"
        )
    moving = [w for w in template.waypoints if w.part is not None]
    if waypoint is None:
        if not moving:
            raise AffordanceError(
                f"{template.name} has no waypoint on a moving part: no path along a joint"
            )
        wp = moving[0]
    else:
        wp = next((w for w in template.waypoints if w.name == waypoint), None)
        if wp is None:
            names = ", ".join(w.name for w in template.waypoints) or "none"
            raise AffordanceError(
                f"{template.name} has no waypoint {waypoint!r} (waypoints: {names})"
            )
        if wp.part is None:
            raise AffordanceError(
                f"waypoint {wp.name!r} of {template.name} is fixed to the "
                f"template frame: it has no path along a joint"
            )
    if wp.part not in states[state]:
        raise AffordanceError(
            f"state {state!r} of {template.name} sets no value of joint "
            f"{wp.part!r} (waypoint {wp.name!r} moves with it)"
        )
    joint = next(j for j in template.joints if j.name == wp.part)
    _, T, joints, scale, dims = _fit_of(fit)
    q0 = float(np.clip(joints.get(wp.part, 0.0), joint.lower, joint.upper))
    q1 = float(states[state][wp.part])
    step = PATH_STEP_RAD if joint.type == "revolute" else PATH_STEP_M
    if wp.pitch is not None:  # a screw: 5 deg of its turn at most, too
        step = min(step, abs(wp.pitch) * PATH_STEP_RAD / (2 * math.pi))
    n = max(1, math.ceil(abs(q1 - q0) / step - 1e-9))
    if n + 3 > MAX_PATH_POSES:
        raise AffordanceError(
            f"the path to {state!r} would have {n + 1} poses (at most {MAX_PATH_POSES})"
        )
    qs = np.linspace(q0, q1, n + 1) if q1 != q0 else np.array([q0])
    posed = [_posed(template, wp, T, q, scale, dims, q0) for q in qs]
    poses, values, kinds = [p[0] for p in posed], list(qs), ["path"] * len(qs)
    if wp.approach is not None:
        poses = [posed[0][1]] + poses + [posed[-1][1]]
        values = [q0] + values + [q1]
        kinds = ["approach"] + kinds + ["retreat"]
    return Trajectory(
        waypoint=wp.name,
        state=state,
        joint=wp.part,
        poses=np.stack(poses),
        joint_values=np.asarray(values, float),
        kinds=tuple(kinds),
    )
