# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine's state drawn as RViz markers (``~/markers``): the shown candidate of each open
object, its moving part, its label and the click; registered objects in their own colour.
Templates are drawn by reference (:mod:`.mesh_refs`): a mesh file's URI or a primitive shape. An
object where no template fits (the verdict) is grey and its label starts "no template fits
here". Each waypoint is drawn as a small gripper (namespaces ``candidate_waypoints`` and
``registered_waypoints``, one LINE_LIST per object): two fingers closing along the waypoint's y
with their tips at the waypoint, the palm and a stem back along its -z, its x axis in red, and a
grey line from the ``pre_`` pose (the approach). For an unsettled object, the frustum of the view
that would settle it (``suggested_view``)."""

from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ...core.labels import REFUSED_PREFIX, standing
from ...core.memo import PerRecord
from ...core.registration import describe_primitive, verdict
from ...core.waypoints import waypoint_poses
from .conversions import likelihood_color, new_marker, sphere_marker, text_marker
from .mesh_refs import template_markers

__all__ = [
    "state_markers",
    "registered_markers_memo",
    "joint_text",
    "waypoint_marker",
    "frustum_marker",
    "MOVING_COLOR",
    "REGISTERED_COLOR",
    "VIEW_COLOR",
]

MOVING_COLOR = ColorRGBA(r=1.0, g=0.35, b=0.1, a=0.9)
NO_MATCH_COLOR = ColorRGBA(r=0.55, g=0.55, b=0.55, a=0.6)  #: no template fits here
REGISTERED_COLOR = ColorRGBA(r=0.3, g=0.5, b=1.0, a=0.9)
GRIPPER_COLOR = ColorRGBA(r=1.0, g=0.85, b=0.1, a=1.0)
X_AXIS_COLOR = ColorRGBA(r=1.0, g=0.1, b=0.1, a=1.0)
APPROACH_COLOR = ColorRGBA(r=0.7, g=0.7, b=0.7, a=0.8)
#: the gripper drawn at a waypoint, segments in its frame (m): fingers, palm, stem
GRIPPER_SEGMENTS = (
    ((0, -0.02, -0.03), (0, -0.02, 0)),
    ((0, 0.02, -0.03), (0, 0.02, 0)),
    ((0, -0.02, -0.03), (0, 0.02, -0.03)),
    ((0, 0, -0.03), (0, 0, -0.06)),
)
X_AXIS = ((0, 0, -0.03), (0.02, 0, -0.03))


def waypoint_marker(library, fit, frame: str, ns: str, marker_id: int, stamp) -> Marker | None:
    """The waypoints of ``fit`` (a FitResult or Registration) as one LINE_LIST in ``frame``
    (see the module docstring); None when its template has none."""
    if fit.template not in library:
        return None
    poses = waypoint_poses(library[fit.template], fit)
    if not poses:
        return None
    m = new_marker(Marker.LINE_LIST, frame, ns, marker_id, stamp)
    m.scale.x = 0.003  # line width (m)
    m.color = GRIPPER_COLOR
    for wp in poses:
        segments = [(GRIPPER_COLOR, GRIPPER_SEGMENTS), (X_AXIS_COLOR, (X_AXIS,))]
        for colour, pairs in segments:
            for pair in pairs:
                for p in pair:
                    q = wp.T[:3, :3] @ np.asarray(p, float) + wp.T[:3, 3]
                    m.points.append(Point(x=float(q[0]), y=float(q[1]), z=float(q[2])))
                    m.colors.append(colour)
        if wp.T_pre is not None:
            for q in (wp.T_pre[:3, 3], wp.T[:3, 3]):
                m.points.append(Point(x=float(q[0]), y=float(q[1]), z=float(q[2])))
                m.colors.append(APPROACH_COLOR)
    return m


VIEW_COLOR = ColorRGBA(r=1.0, g=0.9, b=0.2, a=0.9)  #: a suggested view's frustum
#: a suggested view's frustum: this deep (m) and this wide / high per metre of depth (about a
#: depth camera's 75 x 65 degrees)
FRUSTUM_DEPTH, FRUSTUM_HALF_X, FRUSTUM_HALF_Y = 0.15, 0.77, 0.64


def frustum_marker(
    T_scene_optical: np.ndarray, frame: str, ns: str, marker_id: int, stamp
) -> Marker:
    """A camera frustum (LINE_LIST) at an optical-frame pose (z forward, x right, y down): the
    four edges from the centre and the far rectangle, and a tick at its top edge (y up)."""
    d, hx, hy = FRUSTUM_DEPTH, FRUSTUM_HALF_X * FRUSTUM_DEPTH, FRUSTUM_HALF_Y * FRUSTUM_DEPTH
    corners = [(-hx, -hy, d), (hx, -hy, d), (hx, hy, d), (-hx, hy, d)]
    segments = [((0, 0, 0), c) for c in corners]
    segments += [(corners[k], corners[(k + 1) % 4]) for k in range(4)]
    segments.append(((0.0, -hy, d), (0.0, -1.4 * hy, d)))
    m = new_marker(Marker.LINE_LIST, frame, ns, marker_id, stamp)
    m.scale.x = 0.005
    m.color = VIEW_COLOR
    R, t = np.asarray(T_scene_optical, float)[:3, :3], np.asarray(T_scene_optical, float)[:3, 3]
    for a, b in segments:
        for q in (a, b):
            x, y, z = R @ np.asarray(q, float) + t
            pt = Point(x=float(x), y=float(y), z=float(z))
            m.points.append(pt)
    return m


def _geometry(library, template: str, dimensions: dict):
    """The template a candidate or registration is drawn with (a primitive at its size)."""
    tpl = library[template]
    return tpl.sized(dimensions) if tpl.primitive is not None and dimensions else tpl


def joint_text(tpl, joints: dict, state, scale: float, size=None) -> str:
    """' (closed, lever 88 deg, x1.10)' for labels, ' (a box 0.21 x 0.12 x 0.08 m)' for a
    primitive (``size``: its candidate or registration); '' for a rigid template at scale 1."""
    parts = [state] if state else []
    if size is not None and getattr(size, "primitive", None):
        parts.append(describe_primitive(size))
    for j in tpl.joints:
        if j.name in joints:
            v = joints[j.name]
            parts.append(
                f"{j.name} {math.degrees(v):.0f} deg"
                if j.type == "revolute"
                else f"{j.name} {v * 1000:.1f} mm"
            )
    if abs(scale - 1.0) > 1e-6:
        parts.append(f"x{scale:.2f}")
    return f" ({', '.join(parts)})" if parts else ""


def _object_markers(tpl, T, joints, scale, frame, ns, marker_id, colour, stamp) -> list:
    """The template at its joint values and scale (by reference where it has mesh files), and
    its moving part highlighted."""
    return template_markers(
        tpl, T, tpl.joint_value(joints), scale, frame, ns, marker_id, colour, MOVING_COLOR, stamp
    )


def _registered_markers(reg, library, frame: str) -> tuple | None:
    """What is drawn of a registration whatever the view, unstamped: its template's markers (by
    reference, at its joint values, scale and size), its waypoints' gripper (or None), its
    label's text and how far below its origin the label goes (half its diameter, m). None for
    a template the library does not hold."""
    if reg.template not in library:
        return None
    tpl = _geometry(library, reg.template, reg.dimensions)
    return (
        _object_markers(
            tpl,
            reg.T_scene_model,
            reg.joints,
            reg.scale,
            frame,
            "registered",
            reg.id,
            REGISTERED_COLOR,
            None,
        ),
        waypoint_marker(library, reg, frame, "registered_waypoints", reg.id, None),
        f"{reg.template} #{reg.id}{joint_text(tpl, reg.joints, reg.state, reg.scale, reg)}",
        0.5 * tpl.diameter,
    )


def registered_markers_memo() -> PerRecord:
    """A memo for :func:`state_markers`: each registration's view-independent markers made once
    (a registration is immutable), for a publisher that draws the state again and again."""
    return PerRecord(_registered_markers)


def state_markers(
    state, library, frame: str, stamp, up: np.ndarray, memo: PerRecord | None = None
) -> MarkerArray:
    """A DELETEALL, then the open objects' shown candidates and the registrations of ``state``
    (an :class:`~affordance_registration.core.engine.EngineState`). ``up`` (3,) is the screen's
    up direction in ``frame`` (labels go below the objects). ``memo``
    (:func:`registered_markers_memo`): the registrations' markers as made for an earlier call,
    stamped ``stamp`` (they are the same messages)."""
    markers = MarkerArray()
    clear = Marker()
    clear.action = Marker.DELETEALL
    markers.markers.append(clear)
    for obj in state.objects:
        c = obj.shown
        tpl = _geometry(library, c.template, c.dimensions)
        T = c.T_scene_model
        colour = NO_MATCH_COLOR if obj.no_match else likelihood_color(c.probability)
        markers.markers += _object_markers(
            tpl, T, c.joints, c.scale, frame, "candidate", obj.id, colour, stamp
        )
        top = T[:3, :3] @ tpl.centroid + T[:3, 3]
        said, _ = standing(
            obj.no_match,
            obj.active,
            [r.probability for r in obj.candidates],
            [r.fits for r in obj.candidates],
            c.primitive is not None,
            verdict(obj.candidates),
        )
        name = f"{c.template}{joint_text(tpl, c.joints, c.state, c.scale, c)}"
        rank = f"rank {obj.active + 1}/{len(obj.candidates)}"
        label = (
            f"{said} {name} — {rank}" if said == REFUSED_PREFIX else f"{name} — {rank} — {said}"
        )
        markers.markers.append(
            text_marker(
                label, top - 0.6 * tpl.diameter * up, frame, "candidate_label", obj.id, stamp
            )
        )
        markers.markers.append(sphere_marker(obj.click, frame, "click", obj.id, stamp))
        gripper = waypoint_marker(library, c, frame, "candidate_waypoints", obj.id, stamp)
        if gripper is not None:
            markers.markers.append(gripper)
        if obj.suggested_view is not None:
            markers.markers.append(
                frustum_marker(
                    obj.suggested_view.T_scene_optical, frame, "suggested_view", obj.id, stamp
                )
            )
    drawn = (memo or registered_markers_memo()).values(state.registered, library, frame)
    for reg, made in zip(state.registered, drawn):
        if made is None:
            continue
        meshes, gripper, text, below = made
        if stamp is not None:
            for m in meshes if gripper is None else meshes + [gripper]:
                m.header.stamp = stamp
        markers.markers += meshes
        markers.markers.append(
            text_marker(
                text,
                reg.T_scene_model[:3, 3] - below * up,
                frame,
                "registered_label",
                reg.id,
                stamp,
            )
        )
        if gripper is not None:
            markers.markers.append(gripper)
    return markers
