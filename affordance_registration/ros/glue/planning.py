# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What a robot's planning and perception stacks read of the engine: registrations as MoveIt
collision objects, open objects as vision_msgs detections.

**Collision objects** (``moveit_msgs/msg/CollisionObject`` on ``collision_object``, the topic
MoveIt's move_group listens on): each registration is an object whose id is its TF frame
(``ball_valve_3``), at its pose in the frame it was registered in, its shape its template's mesh
at its joint values and scale (``shape_msgs/Mesh``) or, for a box or cylinder primitive, a
``shape_msgs/SolidPrimitive`` at its fitted size, and its waypoints (and their approach poses)
as named subframes, so a planner targets ``ball_valve_3/lever_grasp``. :class:`CollisionObjects`
sends what changed since it last published: ADD for a new registration (or one whose shape
changed: ADD replaces), MOVE for one whose pose or frame changed with its shape (re-expressed in
another frame -- the fixed frame or the cloud's changed --, or accepted again after an undo and
a correction between two publications), REMOVE for one that is gone (an undo, a load that
replaced it).

**Detections** (``vision_msgs/msg/Detection3DArray``): one ``Detection3D`` per open object (its
id the object's), its ``results`` the ranked candidates -- the template's name as class id, the
probability as score, the pose with its covariance (:mod:`~affordance_registration.core.
detections`) -- and its ``bbox`` the box around the shown candidate.

Without moveit_msgs or vision_msgs (a pip-only install whose ``make setup`` could not build
them) nothing is published and the node says so once.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Vector3

from ...core.memo import PerRecord
from .conversions import matrix_to_pose
from .qos import INPUT
from .tf import registration_frame, waypoint_frames

__all__ = [
    "load_collision_object",
    "load_detection_array",
    "CollisionObjects",
    "collision_object",
    "detection_array",
    "COLLISION_TOPIC",
]

#: where MoveIt's move_group listens for collision objects
COLLISION_TOPIC = "collision_object"


def load_collision_object():
    """moveit_msgs' CollisionObject class, or None where moveit_msgs is not installed."""
    try:
        from moveit_msgs.msg import CollisionObject
    except ImportError:
        return None
    return CollisionObject


def load_detection_array():
    """vision_msgs' (Detection3DArray, Detection3D, ObjectHypothesisWithPose) classes, or None
    where vision_msgs is not installed."""
    try:
        from vision_msgs.msg import Detection3D, Detection3DArray, ObjectHypothesisWithPose
    except ImportError:
        return None
    return Detection3DArray, Detection3D, ObjectHypothesisWithPose


def _geometry(library, reg):
    """The template ``reg`` is drawn with (a primitive at its size)."""
    tpl = library[reg.template]
    return tpl.sized(reg.dimensions) if tpl.primitive is not None and reg.dimensions else tpl


def _shape(CollisionObject, library, reg, msg) -> None:
    """``reg``'s shape into ``msg`` (relative to the object's pose)."""
    from shape_msgs.msg import Mesh, MeshTriangle, SolidPrimitive

    tpl = _geometry(library, reg)
    if tpl.primitive is not None and tpl.dimensions:
        d = {k: float(v) * reg.scale for k, v in tpl.dimensions.items()}
        box = tpl.primitive == "box"
        shape = SolidPrimitive()
        if box:
            shape.type, shape.dimensions = SolidPrimitive.BOX, [d["x"], d["y"], d["z"]]
            height = d["z"]
        else:  # SolidPrimitive's cylinder: [height, radius], centred
            shape.type = SolidPrimitive.CYLINDER
            shape.dimensions = [d["length"], d["radius"]]
            height = d["length"]
        centre = np.eye(4)
        centre[2, 3] = height / 2  # the template frame is the centre of the base / end face
        msg.primitives, msg.primitive_poses = [shape], [matrix_to_pose(centre)]
        return
    mesh = tpl.mesh_at(tpl.joint_value(reg.joints), reg.scale)
    out = Mesh()
    out.vertices = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in mesh.vertices]
    out.triangles = [
        MeshTriangle(vertex_indices=np.asarray(f, dtype=np.uint32)) for f in mesh.faces
    ]
    msg.meshes, msg.mesh_poses = [out], [matrix_to_pose(np.eye(4))]


def collision_object(CollisionObject, reg, library, parent_frame: str, stamp, operation: int):
    """The collision object of registration ``reg`` (ADD: with its shape and subframes; MOVE:
    its pose alone; REMOVE: its id alone), in its own frame (``parent_frame`` where it has
    none)."""
    msg = CollisionObject()
    msg.header.frame_id = (reg.frame_id or parent_frame).lstrip("/")
    msg.header.stamp = stamp
    msg.id = registration_frame(reg.template, reg.id)
    msg.operation = operation
    if operation == CollisionObject.REMOVE:
        return msg
    msg.pose = matrix_to_pose(reg.T_scene_model)
    if operation == CollisionObject.MOVE:
        return msg
    _shape(CollisionObject, library, reg, msg)
    prefix = msg.id + "/"
    for name, T in waypoint_frames(library, reg, msg.id):
        msg.subframe_names.append(name[len(prefix) :])
        msg.subframe_poses.append(matrix_to_pose(T))
    return msg


class CollisionObjects:
    """The ``collision_object`` publisher of a node: :meth:`publish` sends what changed of the
    registrations since the last call (see the module docstring); ``enabled`` False removes
    what was sent and sends nothing more. Without moveit_msgs ``available`` is False and
    nothing is sent."""

    def __init__(self, node, enabled: bool = True):
        self._msg = load_collision_object()
        self.available = self._msg is not None
        self.enabled = bool(enabled)
        self._node = node
        #: id -> (shape key, pose bytes, frame) as the planning scene has it
        self._sent: dict[str, tuple] = {}
        self._added = PerRecord(
            lambda reg, library, frame: collision_object(
                self._msg, reg, library, frame, None, self._msg.ADD
            )
        )
        if not self.available:
            if self.enabled:
                node.get_logger().warning(
                    "moveit_msgs is not installed: registrations are not published as "
                    "collision objects (make setup builds it into the venv)"
                )
            return
        self._pub = node.create_publisher(self._msg, COLLISION_TOPIC, INPUT)

    def publish(self, registered, parent_frame: str, stamp, library) -> list:
        """Send the ADD, MOVE and REMOVE messages that bring the planning scene to
        ``registered``; returns them."""
        if not self.available:
            return []
        M = self._msg
        out = []
        current = {}
        if self.enabled and parent_frame:
            for reg, added in zip(
                registered, self._added.values(registered, library, parent_frame)
            ):
                if reg.template not in library:
                    continue
                key = (
                    reg.template,
                    tuple(sorted(reg.joints.items())),
                    round(float(reg.scale), 9),
                    tuple(sorted((reg.dimensions or {}).items())),
                )
                frame = added.header.frame_id
                entry = (key, np.asarray(reg.T_scene_model, float).tobytes(), frame)
                current[added.id] = entry
                sent = self._sent.get(added.id)
                if sent == entry:
                    continue
                if sent is not None and sent[0] == key:  # the same shape: moved
                    out.append(collision_object(M, reg, library, parent_frame, stamp, M.MOVE))
                else:
                    added.header.stamp = stamp
                    out.append(added)
        for gone in sorted(set(self._sent) - set(current)):
            msg = M(id=gone, operation=M.REMOVE)
            msg.header.frame_id, msg.header.stamp = self._sent[gone][2], stamp
            out.append(msg)
        self._sent = current
        for msg in out:
            self._pub.publish(msg)
        return out


def detection_array(classes, detections, frame: str, stamp):
    """A Detection3DArray in ``frame`` of ``detections``
    (:class:`~affordance_registration.core.detections.Detection`); ``classes``: what
    :func:`load_detection_array` returns."""
    Detection3DArray, Detection3D, ObjectHypothesisWithPose = classes
    msg = Detection3DArray()
    msg.header.frame_id, msg.header.stamp = frame, stamp
    for det in detections:
        d = Detection3D()
        d.header = msg.header
        d.id = str(det.object_id)
        for h in det.hypotheses:
            r = ObjectHypothesisWithPose()
            r.hypothesis.class_id = h.template
            r.hypothesis.score = float(h.score)
            r.pose.pose = matrix_to_pose(h.T_scene_model)
            r.pose.covariance = np.asarray(h.covariance, dtype=float).reshape(36)
            d.results.append(r)
        d.bbox.center = matrix_to_pose(det.T_scene_box)
        d.bbox.size = Vector3(x=float(det.size[0]), y=float(det.size[1]), z=float(det.size[2]))
        msg.detections.append(d)
    return msg
