"""Interactive-marker server for RViz's Interactive Markers display, implemented from the
visualization_msgs definitions (the interactive_markers package is not on PyPI).

Protocol, for a one-level namespace ``ns`` (parameter ``interactive_namespace``):

* service ``ns/get_interactive_markers``: the full current set and the current sequence number;
* topic ``ns/update`` (reliable, depth 100): UPDATE messages whose ``seq_num`` grows by exactly one
  per change set -- a new or changed marker in ``markers``, a pose-only change in ``poses``, a
  removal in ``erases`` -- and a KEEP_ALIVE every 0.5 s with the current ``seq_num`` and the stable
  ``server_id``;
* topic ``ns/feedback`` (subscribed): POSE_UPDATE moves the shown fit live; MOUSE_UP takes the
  pose as an absolute correction and refits; MENU_SELECT runs the engine action of the entry.

One marker, ``affordance_fit``, sits on the shown candidate of the selected object: its mesh as the
visual (with the menu), six controls (move and rotate about x, y, z) oriented with the object or
with the operator's view (parameter ``interactive_orientation``: object | view). It follows every
change made elsewhere and disappears when nothing is selected.

A template with a joint gets a second marker, ``affordance_joint``, on the joint (x along the joint
axis): one control, rotating about the axis (revolute) or moving along it (prismatic). RViz moves
a whole interactive marker whichever of its controls is dragged, so the joint needs a marker of
its own. Releasing it sets the joint value it shows (clamped to the limits) and refits the pose
with that value held.
"""
from __future__ import annotations

import math
import time

import numpy as np
from geometry_msgs.msg import Quaternion
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import (InteractiveMarker, InteractiveMarkerControl,
                                    InteractiveMarkerFeedback, InteractiveMarkerPose,
                                    InteractiveMarkerUpdate, MenuEntry)
from visualization_msgs.srv import GetInteractiveMarkers

from ..core.errors import AffordanceError
from ..core.transforms import matrix_to_quat_xyzw
from .conversions import ConversionError, matrix_to_pose, mesh_marker, pose_to_matrix

MARKER_NAME = "affordance_fit"
JOINT_MARKER_NAME = "affordance_joint"
MENU = (("next_model", "Next model"), ("previous_model", "Previous model"), ("refit", "Refit"),
        ("accept", "Accept"), ("undo", "Undo"), ("discard", "Discard"))
KEEP_ALIVE_S = 0.5
_S = math.sqrt(0.5)
# control frames whose x axis is the object's (or view's) x, y and z axis
AXES = {"x": (_S, 0.0, 0.0, _S), "y": (0.0, 0.0, _S, _S), "z": (0.0, -_S, 0.0, _S)}  # x,y,z,w


class CorrectionMarkerServer:
    """The interactive-marker server of the engine node (all callbacks on its executor)."""

    def __init__(self, node, namespace: str = "/affordance_correction",
                 orientation: str = "object"):
        self.node = node
        self.ns = "/" + namespace.strip("/")
        if not namespace.strip("/") or "/" in namespace.strip("/"):
            raise AffordanceError(f"interactive marker namespace must be one level like "
                                  f"/affordance_correction, got {namespace!r}")
        if orientation not in ("object", "view"):
            raise AffordanceError("interactive_orientation must be 'object' or 'view'")
        self.orientation = orientation
        self.server_id = f"{node.get_fully_qualified_name()}/{int(time.time() * 1e6):x}"
        self.seq_num = 0
        self._sent: tuple | None = None          # identity of what the clients have
        self._markers: dict[str, InteractiveMarker] = {}
        self._drag_client: str | None = None
        self._throttled: dict[str, float] = {}
        update_qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.RELIABLE)
        self.pub = node.create_publisher(InteractiveMarkerUpdate, f"{self.ns}/update", update_qos)
        node.create_subscription(InteractiveMarkerFeedback, f"{self.ns}/feedback",
                                 self._on_feedback, update_qos)
        node.create_service(GetInteractiveMarkers, f"{self.ns}/get_interactive_markers",
                            self._on_get)
        node.create_timer(KEEP_ALIVE_S, self._keep_alive)

    # ------------------------------------------------------------------ server -> clients
    def _on_get(self, request, response):
        response.sequence_number = self.seq_num
        response.markers = list(self._markers.values())
        return response

    def _keep_alive(self) -> None:
        self.pub.publish(InteractiveMarkerUpdate(server_id=self.server_id, seq_num=self.seq_num,
                                                 type=InteractiveMarkerUpdate.KEEP_ALIVE))

    def _publish(self, markers=(), poses=(), erases=()) -> None:
        self.seq_num += 1
        self.pub.publish(InteractiveMarkerUpdate(
            server_id=self.server_id, seq_num=self.seq_num, type=InteractiveMarkerUpdate.UPDATE,
            markers=list(markers), poses=list(poses), erases=list(erases)))

    def sync(self) -> None:
        """Send what changed since the last change set (called after every engine change)."""
        obj = self.node.engine.active_object()
        frame = self.node.engine.frame_id or self.node._cloud_frame
        if obj is None:
            if self._markers:
                names = list(self._markers)
                self._markers, self._sent = {}, None
                self._publish(erases=names)
            return
        cand = obj.shown
        view_R = self.node.engine.view_pose()[:3, :3].round(6).tobytes() \
            if self.orientation == "view" else b""
        identity = (obj.id, obj.active, cand.template, frame, self.orientation, view_R,
                    tuple(sorted(cand.joints.items())), round(cand.scale, 9))
        pose_bytes = np.asarray(cand.T_scene_model).tobytes()
        if self._sent is not None and self._sent[0] == identity:
            if self._sent[1] != pose_bytes:
                poses = []
                for name, pose in self._poses(cand).items():
                    self._markers[name].pose = pose
                    p = InteractiveMarkerPose(name=name, pose=pose)
                    p.header.frame_id = frame
                    poses.append(p)
                self._publish(poses=poses)
                self._sent = (identity, pose_bytes)
            return
        old = set(self._markers)
        self._markers = {MARKER_NAME: self._build(obj, frame)}
        tpl = self.node.library[cand.template]
        if tpl.joint is not None:
            self._markers[JOINT_MARKER_NAME] = self._build_joint(obj, frame)
        self._sent = (identity, pose_bytes)
        self._publish(markers=list(self._markers.values()),
                      erases=sorted(old - set(self._markers)))

    def _poses(self, cand) -> dict:
        """Pose of each marker for the candidate: the fit at the object, the joint marker at the
        joint."""
        out = {MARKER_NAME: matrix_to_pose(cand.T_scene_model)}
        if JOINT_MARKER_NAME in self._markers:
            tpl = self.node.library[cand.template]
            out[JOINT_MARKER_NAME] = matrix_to_pose(
                cand.T_scene_model @ tpl.joint_frame(tpl.joint_value(cand.joints), cand.scale))
        return out

    def _build_joint(self, obj, frame: str) -> InteractiveMarker:
        cand = obj.shown
        tpl = self.node.library[cand.template]
        joint = tpl.joint
        q = tpl.joint_value(cand.joints)
        im = InteractiveMarker()
        im.header.frame_id = frame
        im.name = JOINT_MARKER_NAME
        im.description = f"{joint.name} ({joint.type})"
        im.pose = matrix_to_pose(cand.T_scene_model @ tpl.joint_frame(q, cand.scale))
        im.scale = float(max(0.05, 0.6 * tpl.diameter * cand.scale))
        mode = (InteractiveMarkerControl.ROTATE_AXIS if joint.type == "revolute"
                else InteractiveMarkerControl.MOVE_AXIS)
        c = InteractiveMarkerControl(name="joint", interaction_mode=mode,
                                     orientation_mode=InteractiveMarkerControl.INHERIT)
        c.orientation = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)     # x: the joint axis
        im.controls.append(c)
        return im

    def _build(self, obj, frame: str) -> InteractiveMarker:
        cand = obj.shown
        tpl = self.node.library[cand.template]
        im = InteractiveMarker()
        im.header.frame_id = frame
        im.name = MARKER_NAME
        im.description = f"{cand.template} — rank {obj.active + 1}/{len(obj.candidates)}"
        im.pose = matrix_to_pose(cand.T_scene_model)
        im.scale = float(max(0.1, 1.2 * tpl.diameter))
        im.menu_entries = [MenuEntry(id=i, parent_id=0, title=title, command="",
                                     command_type=MenuEntry.FEEDBACK)
                           for i, (_, title) in enumerate(MENU, start=1)]
        visual = InteractiveMarkerControl(name="mesh", always_visible=True,
                                          interaction_mode=InteractiveMarkerControl.MENU)
        mesh = mesh_marker(tpl.mesh_at(tpl.joint_value(cand.joints), cand.scale), np.eye(4), "", "mesh", 0,
                           ColorRGBA(r=0.95, g=0.75, b=0.1, a=0.6))
        mesh.header.frame_id = ""          # relative to the interactive marker
        visual.markers.append(mesh)
        im.controls.append(visual)
        R_view_in_object = None
        if self.orientation == "view":
            R_view_in_object = self.node.engine.view_pose()[:3, :3]
        for axis, q in AXES.items():
            for mode, prefix in ((InteractiveMarkerControl.MOVE_AXIS, "move"),
                                 (InteractiveMarkerControl.ROTATE_AXIS, "rotate")):
                c = InteractiveMarkerControl(name=f"{prefix}_{axis}", interaction_mode=mode)
                if R_view_in_object is not None:
                    from scipy.spatial.transform import Rotation
                    R = R_view_in_object @ Rotation.from_quat(q).as_matrix()
                    qx, qy, qz, qw = matrix_to_quat_xyzw(R)
                    c.orientation_mode = InteractiveMarkerControl.FIXED
                else:
                    qx, qy, qz, qw = q
                    c.orientation_mode = InteractiveMarkerControl.INHERIT
                c.orientation = Quaternion(x=float(qx), y=float(qy), z=float(qz), w=float(qw))
                im.controls.append(c)
        return im

    # ------------------------------------------------------------------ clients -> server
    def _ignore(self, why: str) -> None:
        now = time.monotonic()
        if now - self._throttled.get(why, -math.inf) >= 2.0:
            self._throttled[why] = now
            self.node.get_logger().warning(f"interactive marker feedback ignored: {why}")

    def _on_feedback(self, fb: InteractiveMarkerFeedback) -> None:
        F = InteractiveMarkerFeedback
        if fb.event_type == F.KEEP_ALIVE:
            return
        if fb.marker_name not in self._markers:
            self._ignore(f"no marker named '{fb.marker_name}'")
            return
        if self._drag_client is not None and fb.client_id != self._drag_client and \
                fb.event_type in (F.POSE_UPDATE, F.MOUSE_UP):
            self._ignore(f"client '{fb.client_id}' while '{self._drag_client}' is dragging")
            return
        if fb.event_type == F.MENU_SELECT:
            if not 1 <= fb.menu_entry_id <= len(MENU):
                self._ignore(f"unknown menu entry {fb.menu_entry_id}")
                return
            self.node._submit_action(MENU[fb.menu_entry_id - 1][0])
            return
        if fb.event_type == F.MOUSE_DOWN:
            self._drag_client = fb.client_id
            return
        if fb.event_type not in (F.POSE_UPDATE, F.MOUSE_UP):
            return
        marker = self._markers[fb.marker_name]
        frame = marker.header.frame_id
        if fb.header.frame_id and fb.header.frame_id.lstrip("/") != frame.lstrip("/"):
            self._ignore(f"pose in frame '{fb.header.frame_id}', the marker is in '{frame}'")
            return
        try:
            T = pose_to_matrix(fb.pose)
        except ConversionError as exc:
            self._ignore(f"malformed pose ({exc})")
            return
        if fb.marker_name == JOINT_MARKER_NAME:
            self._on_joint_feedback(fb, T)
            return
        try:
            self.node.engine.correct_pose(T, drag=True)
        except AffordanceError as exc:
            self._ignore(str(exc))
            return
        self.node._dirty = True
        if fb.event_type == F.MOUSE_UP:
            self._drag_client = None
            self.node._info(f"marker released: refitting {marker.description}")
            self.node._jobs.put(("refit", None))

    def _on_joint_feedback(self, fb: InteractiveMarkerFeedback, T_scene_frame: np.ndarray) -> None:
        """The joint marker: RViz shows the drag itself; on release the joint takes the value
        the marker shows and the pose is refitted with it held."""
        if fb.event_type != InteractiveMarkerFeedback.MOUSE_UP:
            return
        self._drag_client = None
        obj = self.node.engine.active_object()
        if obj is None:
            self._ignore("joint released with no object selected")
            return
        cand = obj.shown
        tpl = self.node.library[cand.template]
        if tpl.joint is None:
            self._ignore(f"{cand.template} has no joint")
            return
        q = tpl.joint_value_from_frame(np.linalg.inv(cand.T_scene_model) @ T_scene_frame,
                                       cand.scale)
        self.node._submit_action(("joint_value", q))
