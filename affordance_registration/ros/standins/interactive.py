# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Interactive-marker server for RViz's Interactive Markers display, implemented from the
visualization_msgs definitions (the interactive_markers package is not on PyPI). In a ROS
install with interactive_markers, its ``InteractiveMarkerServer`` speaks the protocol instead
(:meth:`CorrectionMarkerServer.attach`); what is shown and the feedback handling stay here.

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

The server knows its host only as a :class:`MarkerHost` (what is shown, and where to send the
operator's input; the engine node is one), so it is tested without a node;
:meth:`CorrectionMarkerServer.attach` wires it to a node's topics and service.
"""

from __future__ import annotations

import math
import time
from typing import Protocol

import numpy as np
from geometry_msgs.msg import Quaternion
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import (
    InteractiveMarker,
    InteractiveMarkerControl,
    InteractiveMarkerFeedback,
    InteractiveMarkerPose,
    InteractiveMarkerUpdate,
    MenuEntry,
)
from visualization_msgs.srv import GetInteractiveMarkers

from ...core.errors import AffordanceError, bounded
from ...core.transforms import matrix_to_quat_xyzw, quat_xyzw_to_matrix
from ..glue.conversions import ConversionError, matrix_to_pose, pose_to_matrix
from ..glue.mesh_refs import template_markers
from ..glue.qos import INPUT
from ..glue.throttle import Throttle

__all__ = [
    "CorrectionMarkerServer",
    "MarkerHost",
    "MARKER_NAME",
    "JOINT_MARKER_NAME",
    "MENU",
    "DRAG_EXPIRY_S",
    "menu_of",
]

MARKER_NAME = "affordance_fit"
JOINT_MARKER_NAME = "affordance_joint"
MENU = (
    ("next_model", "Next model"),
    ("previous_model", "Previous model"),
    ("refit", "Refit"),
    ("accept", "Accept"),
    ("undo", "Undo"),
    ("discard", "Discard"),
)
KEEP_ALIVE_S = 0.5


def menu_of(candidate) -> list:
    """The marker's menu for the shown ``candidate``: [(action, argument, title)] -- MENU, and
    for a primitive a step up and down of each dimension ("dimension", (name, None, +-1))."""
    entries = [(action, None, title) for action, title in MENU]
    if candidate is not None and candidate.primitive is not None:
        for name in candidate.dimensions:
            entries += [
                ("dimension", (name, None, 1.0), f"{name} +"),
                ("dimension", (name, None, -1.0), f"{name} -"),
            ]
    return entries


#: a drag belongs to the client that started it, and to the object it started on, while that
#: client keeps sending feedback (poses or keep-alives); after this long without any the drag is
#: cancelled -- the object goes back where it started -- and another client may drag
DRAG_EXPIRY_S = 3.0
#: clients whose drag was cancelled, remembered so that their late release is refused
CANCELLED_MEMORY = 32
WARN_EVERY_S = 2.0
_S = math.sqrt(0.5)
# control frames whose x axis is the object's (or view's) x, y and z axis
AXES = {"x": (_S, 0.0, 0.0, _S), "y": (0.0, 0.0, _S, _S), "z": (0.0, -_S, 0.0, _S)}  # x,y,z,w


class MarkerHost(Protocol):
    """What the server reads from and sends to its host (the engine node implements it).

    ``active_object()``: the selected object (a TrackedObject) or None; ``frame()``: the frame of
    the shown poses; ``view_pose()``: T_scene_view (4x4) of the operator; ``template(name)``: an
    AffordanceTemplate; ``marker_pose(T_scene_model, release, object_id)``: the dragged pose of
    the shown fit of object ``object_id`` (the one the drag started on; ``release``: the drag
    ended, refit from it); ``marker_action(name, argument)``: a menu entry or (``"joint_value"``,
    q) from the joint marker; ``marker_cancel(object_id)``: a drag whose client fell silent ended
    without a release (the object goes back where it started); ``warn(text)``: a warning for the
    log.
    """

    def active_object(self): ...

    def frame(self) -> str: ...

    def view_pose(self) -> np.ndarray: ...

    def template(self, name: str): ...

    def marker_pose(
        self, T_scene_model: np.ndarray, release: bool, object_id: int | None
    ) -> None: ...

    def marker_action(self, name: str, argument) -> None: ...

    def marker_cancel(self, object_id: int | None) -> None: ...

    def warn(self, text: str) -> None: ...


class CorrectionMarkerServer:
    """The interactive-marker server of the engine node: marker building, sequence numbers, drag
    ownership and feedback handling. ``clock()`` (s) is injectable."""

    def __init__(
        self,
        host: MarkerHost,
        namespace: str = "/affordance_correction",
        orientation: str = "object",
        server_id: str = "affordance_engine",
        clock=time.monotonic,
    ):
        if not namespace.strip("/") or "/" in namespace.strip("/"):
            raise AffordanceError(
                f"interactive marker namespace must be one level like "
                f"/affordance_correction, got {namespace!r}"
            )
        if orientation not in ("object", "view"):
            raise AffordanceError("interactive_orientation must be 'object' or 'view'")
        self.host = host
        self.ns = "/" + namespace.strip("/")
        self.orientation = orientation
        self.server_id = f"{server_id}/{int(time.time() * 1e6):x}"
        self.clock = clock
        self.seq_num = 0
        self._sent: tuple | None = None  # identity of what the clients have
        self._markers: dict[str, InteractiveMarker] = {}
        #: (client id, last feedback time, object id the drag started on)
        self._drag: tuple[str, float, int | None] | None = None
        self._cancelled: dict[str, int | None] = {}  # client id -> object of its lost drag
        self._warnings = Throttle(WARN_EVERY_S, clock)
        self._publish_fn = None
        self._installed = None  # interactive_markers' server, where it is installed

    # ------------------------------------------------------------------ ROS wiring
    def attach(self, node) -> None:
        """Serve on ``node``: the update topic, the feedback subscription, the full-set service
        and the keep-alive timer -- through interactive_markers' server where it is installed
        (every marker inserted with :meth:`feedback` as its callback), else here."""
        try:
            from interactive_markers import InteractiveMarkerServer
        except ImportError:
            InteractiveMarkerServer = None
        if InteractiveMarkerServer is not None:
            self._installed = InteractiveMarkerServer(node, self.ns)
            return
        pub = node.create_publisher(InteractiveMarkerUpdate, f"{self.ns}/update", INPUT)
        self._publish_fn = pub.publish
        node.create_subscription(
            InteractiveMarkerFeedback, f"{self.ns}/feedback", self.feedback, INPUT
        )
        node.create_service(
            GetInteractiveMarkers, f"{self.ns}/get_interactive_markers", self._on_get
        )
        node.create_timer(KEEP_ALIVE_S, lambda: pub.publish(self.keep_alive()))

    def _on_get(self, request, response):
        response.sequence_number, response.markers = self.full_set()
        return response

    # ------------------------------------------------------------------ server -> clients
    def full_set(self) -> tuple[int, list]:
        """The current sequence number and every marker (the get_interactive_markers answer)."""
        return self.seq_num, list(self._markers.values())

    def keep_alive(self) -> InteractiveMarkerUpdate:
        return InteractiveMarkerUpdate(
            server_id=self.server_id, seq_num=self.seq_num, type=InteractiveMarkerUpdate.KEEP_ALIVE
        )

    def _update(self, markers=(), poses=(), erases=()) -> InteractiveMarkerUpdate:
        self.seq_num += 1
        upd = InteractiveMarkerUpdate(
            server_id=self.server_id,
            seq_num=self.seq_num,
            type=InteractiveMarkerUpdate.UPDATE,
            markers=list(markers),
            poses=list(poses),
            erases=list(erases),
        )
        if self._publish_fn is not None:
            self._publish_fn(upd)
        server = self._installed
        if server is not None:  # the same change set through interactive_markers
            for marker in markers:
                server.insert(marker, feedback_callback=self.feedback)
            for pose in poses:
                server.setPose(pose.name, pose.pose, pose.header)
            for name in erases:
                server.erase(name)
            server.applyChanges()
        return upd

    def sync(self) -> InteractiveMarkerUpdate | None:
        """Send what changed since the last change set (call after every change of the host's
        state); returns the update sent, or None when nothing changed."""
        obj = self.host.active_object()
        frame = self.host.frame()
        if obj is None:
            if not self._markers:
                return None
            names = list(self._markers)
            self._markers, self._sent = {}, None
            return self._update(erases=names)
        cand = obj.shown
        view_R = (
            self.host.view_pose()[:3, :3].round(6).tobytes() if self.orientation == "view" else b""
        )
        identity = (
            obj.id,
            obj.active,
            cand.template,
            frame,
            self.orientation,
            view_R,
            tuple(sorted(cand.joints.items())),
            round(cand.scale, 9),
        )
        pose_bytes = np.asarray(cand.T_scene_model).tobytes()
        if self._sent is not None and self._sent[0] == identity:
            if self._sent[1] == pose_bytes:
                return None
            poses = []
            for name, pose in self._poses(cand).items():
                self._markers[name].pose = pose
                p = InteractiveMarkerPose(name=name, pose=pose)
                p.header.frame_id = frame
                poses.append(p)
            self._sent = (identity, pose_bytes)
            return self._update(poses=poses)
        old = set(self._markers)
        self._markers = {MARKER_NAME: self._build(obj, frame)}
        if self.host.template(cand.template).joint is not None:
            self._markers[JOINT_MARKER_NAME] = self._build_joint(obj, frame)
        self._sent = (identity, pose_bytes)
        return self._update(
            markers=list(self._markers.values()), erases=sorted(old - set(self._markers))
        )

    def _poses(self, cand) -> dict:
        """Pose of each marker for the candidate: the fit at the object, the joint marker at the
        joint."""
        out = {MARKER_NAME: matrix_to_pose(cand.T_scene_model)}
        if JOINT_MARKER_NAME in self._markers:
            tpl = self.host.template(cand.template)
            out[JOINT_MARKER_NAME] = matrix_to_pose(
                cand.T_scene_model @ tpl.joint_frame(tpl.joint_value(cand.joints), cand.scale)
            )
        return out

    def _build_joint(self, obj, frame: str) -> InteractiveMarker:
        cand = obj.shown
        tpl = self.host.template(cand.template)
        joint = tpl.joint
        q = tpl.joint_value(cand.joints)
        im = InteractiveMarker()
        im.header.frame_id = frame
        im.name = JOINT_MARKER_NAME
        im.description = f"{joint.name} ({joint.type})"
        im.pose = matrix_to_pose(cand.T_scene_model @ tpl.joint_frame(q, cand.scale))
        im.scale = float(max(0.05, 0.6 * tpl.diameter * cand.scale))
        mode = (
            InteractiveMarkerControl.ROTATE_AXIS
            if joint.type == "revolute"
            else InteractiveMarkerControl.MOVE_AXIS
        )
        c = InteractiveMarkerControl(
            name="joint", interaction_mode=mode, orientation_mode=InteractiveMarkerControl.INHERIT
        )
        c.orientation = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)  # x: the joint axis
        im.controls.append(c)
        return im

    def _build(self, obj, frame: str) -> InteractiveMarker:
        cand = obj.shown
        tpl = self.host.template(cand.template)
        im = InteractiveMarker()
        im.header.frame_id = frame
        im.name = MARKER_NAME
        im.description = f"{cand.template} — rank {obj.active + 1}/{len(obj.candidates)}"
        im.pose = matrix_to_pose(cand.T_scene_model)
        im.scale = float(max(0.1, 1.2 * tpl.diameter))
        self._menu = menu_of(cand)
        im.menu_entries = [
            MenuEntry(id=i, parent_id=0, title=title, command="", command_type=MenuEntry.FEEDBACK)
            for i, (_, _, title) in enumerate(self._menu, start=1)
        ]
        if cand.primitive is not None and cand.dimensions:  # drawn at its size
            tpl = tpl.sized(cand.dimensions)
        visual = InteractiveMarkerControl(
            name="mesh", always_visible=True, interaction_mode=InteractiveMarkerControl.MENU
        )
        colour = ColorRGBA(r=0.95, g=0.75, b=0.1, a=0.6)
        # by reference where the template has mesh files (relative to the interactive marker)
        visual.markers += template_markers(
            tpl,
            np.eye(4),
            tpl.joint_value(cand.joints),
            cand.scale,
            "",
            "mesh",
            0,
            colour,
            colour,
            None,
        )
        im.controls.append(visual)
        R_view = self.host.view_pose()[:3, :3] if self.orientation == "view" else None
        for axis, q in AXES.items():
            for mode, prefix in (
                (InteractiveMarkerControl.MOVE_AXIS, "move"),
                (InteractiveMarkerControl.ROTATE_AXIS, "rotate"),
            ):
                c = InteractiveMarkerControl(name=f"{prefix}_{axis}", interaction_mode=mode)
                if R_view is not None:  # fixed in the cloud frame, along the view's axes
                    qx, qy, qz, qw = matrix_to_quat_xyzw(R_view @ quat_xyzw_to_matrix(q))
                    c.orientation_mode = InteractiveMarkerControl.FIXED
                else:
                    qx, qy, qz, qw = q
                    c.orientation_mode = InteractiveMarkerControl.INHERIT
                c.orientation = Quaternion(x=float(qx), y=float(qy), z=float(qz), w=float(qw))
                im.controls.append(c)
        return im

    # ------------------------------------------------------------------ clients -> server
    def _ignore(self, kind: str, text: str) -> None:
        """A throttled warning: at most one per ``kind`` every WARN_EVERY_S, whatever the text
        (so a storm of distinct client ids gives one line, not one each)."""
        if self._warnings.due(kind):
            self.host.warn(f"interactive marker feedback ignored: {bounded(text, 400)}")

    def _owner(self) -> str | None:
        """The client whose drag is in progress (None when nobody's). A drag whose client fell
        silent for DRAG_EXPIRY_S is cancelled here."""
        self.expire()
        return None if self._drag is None else self._drag[0]

    def expire(self) -> None:
        """Cancel the drag in progress if its client fell silent (the node calls this on its
        timer, so a drag is cancelled even when no more feedback comes)."""
        drag = self._drag
        if drag is None or self.clock() - drag[1] <= DRAG_EXPIRY_S:
            return
        self._drag = None
        self._cancelled[drag[0]] = drag[2]
        while len(self._cancelled) > CANCELLED_MEMORY:
            self._cancelled.pop(next(iter(self._cancelled)))
        self._ignore(
            "silent",
            f"client '{drag[0]}' fell silent for {DRAG_EXPIRY_S:g} s "
            f"mid-drag: the drag is cancelled",
        )
        self.host.marker_cancel(drag[2])

    def _active_id(self) -> int | None:
        obj = self.host.active_object()
        return None if obj is None else obj.id

    def feedback(self, fb: InteractiveMarkerFeedback) -> None:
        """Handle one feedback message from a client."""
        F = InteractiveMarkerFeedback
        owner = self._owner()
        if fb.event_type == F.KEEP_ALIVE:
            if owner == fb.client_id:
                self._drag = (owner, self.clock(), self._drag[2])
            return
        if fb.marker_name not in self._markers:
            self._ignore("marker", f"no marker named '{fb.marker_name}'")
            return
        if (
            owner is not None
            and fb.client_id != owner
            and fb.event_type in (F.POSE_UPDATE, F.MOUSE_UP)
        ):
            self._ignore("drag", f"client '{fb.client_id}' while '{owner}' is dragging")
            return
        if fb.event_type == F.MENU_SELECT:
            menu = getattr(self, "_menu", None) or menu_of(None)
            if not 1 <= fb.menu_entry_id <= len(menu):
                self._ignore("menu", f"unknown menu entry {fb.menu_entry_id}")
                return
            action, argument, _ = menu[fb.menu_entry_id - 1]
            self.host.marker_action(action, argument)
            return
        if fb.event_type == F.MOUSE_DOWN:
            self._cancelled.pop(fb.client_id, None)
            self._drag = (fb.client_id, self.clock(), self._active_id())
            return
        if fb.client_id in self._cancelled and owner != fb.client_id:
            # the rest of a drag that was cancelled: never applied to what is selected now
            if fb.event_type == F.MOUSE_UP:
                self._cancelled.pop(fb.client_id, None)
            self._ignore(
                "cancelled",
                f"{'release' if fb.event_type == F.MOUSE_UP else 'pose'} "
                f"from client '{fb.client_id}' after its drag was "
                f"cancelled (silent for {DRAG_EXPIRY_S:g} s)",
            )
            return
        if fb.event_type not in (F.POSE_UPDATE, F.MOUSE_UP):
            return
        frame = self._markers[fb.marker_name].header.frame_id
        if fb.header.frame_id and fb.header.frame_id.lstrip("/") != frame.lstrip("/"):
            self._ignore(
                "frame", f"pose in frame '{fb.header.frame_id}', the marker is in '{frame}'"
            )
            return
        try:
            T = pose_to_matrix(fb.pose)
        except ConversionError as exc:
            self._ignore("pose", f"malformed pose ({exc})")
            return
        release = fb.event_type == F.MOUSE_UP
        # the object the drag started on (a drag without MOUSE_DOWN starts on the shown one)
        target = self._drag[2] if owner == fb.client_id else self._active_id()
        if release or owner is None or owner == fb.client_id:
            self._drag = None if release else (fb.client_id, self.clock(), target)
        if fb.marker_name == JOINT_MARKER_NAME:
            if release:
                self._joint_released(T)
            return
        self.host.marker_pose(T, release, target)

    def _joint_released(self, T_scene_frame: np.ndarray) -> None:
        """The joint marker: RViz shows the drag itself; on release the joint takes the value
        the marker shows and the pose is refitted with it held."""
        obj = self.host.active_object()
        if obj is None:
            self._ignore("joint", "joint released with no object selected")
            return
        cand = obj.shown
        tpl = self.host.template(cand.template)
        if tpl.joint is None:
            self._ignore("joint", f"{cand.template} has no joint")
            return
        q = tpl.joint_value_from_frame(
            np.linalg.inv(cand.T_scene_model) @ T_scene_frame, cand.scale
        )
        self.host.marker_action("joint_value", q)
