# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Node ``affordance_station``: the browser operator station, a plain ROS client of an engine node.

It serves a page with viser (``http://127.0.0.1:8080`` by default; the web client ships inside the
viser wheel; the URL with its access secret is printed on the terminal, first) that shows the
live cloud (thinned for display, in its own colours -- an ``rgb`` / ``rgba`` field -- else by
intensity or depth; "Depth colours" switches to depth), the shown candidate of the selected
object as its mesh with a short label, the registrations in their own colour, and a panel that
says one sentence (what is shown, its verdict, what the operator can do) with the reasons in its
closed "Details". A scan opens the right way up: an optical frame has the camera's up; any other
the normal of its dominant plane where the sensor sees it at a slant (a table); the support plane
under the first click then sets it (``core.display``). On the page the operator

* clicks the cloud: the click ray is snapped to the nearest cloud point (``core.display.snap_ray``)
  and published on ``clicked_point`` in the cloud's frame (the engine's fixed frame, when it has
  one: each cloud is drawn there, through TF at its stamp);
* drags the gizmo on the shown fit (it stays within the object's outline, so a click beside it
  lands on the cloud): an interactive-marker feedback client of its own (MOUSE_DOWN,
  POSE_UPDATE, MOUSE_UP of ``affordance_fit`` on ``<interactive_namespace>/feedback``) -- the
  release is an absolute correction followed by a refit, as a drag in RViz; a press on a handle
  that does not move the fit sends nothing;
* presses Next / Previous / Accept / Refit / Undo / Discard / Save / Joint - / Joint + (the
  engine's std_srvs/Trigger services) or picks a candidate by name (``<engine>/select_model``);
* sees the engine's waypoint grippers (the "Waypoints" toggle hides them) and, with "Show path",
  the path of the selected object's waypoint to the state typed in "Path to state" (``paths.py``);
* presses "Move sensor here" (shown while the open object is unsettled, the engine suggests a
  view and something subscribes to ``sensor_view_request`` -- nothing does for a scan read from
  a file; the view's frustum is drawn with "Suggested view" in the details): that view goes out
  on ``sensor_view_request`` (geometry_msgs/PoseStamped, an optical frame in the cloud's frame)
  for whatever moves the sensor (in ``station --demo``, the simulated scan node);
* looks around: the browser camera is published on ``view_pose`` (an optical frame in the cloud's
  frame), so SpaceMouse pushes move the object in the view the operator is looking at.

Everything it shows comes from the engine's documented outputs (``~/status``, ``~/markers``), so it
works with any engine node and template library. The scene and panel live in the server, so a
reload or a second browser shows the same state; actions are serialised by the engine.

Layout: what the page shows is computed by plain functions in ``state.py`` (tested without
``rclpy.init``), the page (``page.py``, :class:`~.page.StationPage`) is the only code calling
viser, and the node (this module, :class:`StationNode`) the only code calling rclpy; the geometry
is in ``core/display.py``, the access rules in ``access.py``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from geometry_msgs.msg import PointStamped, PoseStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import InteractiveMarkerFeedback, MarkerArray

from ...core import display
from ...core.errors import AffordanceError
from ...core.knobs import described
from ..glue import qos
from ..glue.conversions import (
    ConversionError,
    matrix_to_pose,
    point_stamped,
    pointcloud2_colors,
    pointcloud2_field,
    pointcloud2_to_xyz,
    pose_stamped,
    stamped,
)
from ..glue.qos import INPUT, LATCHED
from ..glue.tf import TfListener
from ..standins.spin import run_node
from . import access as station_access
from .markup import text
from .page import ACTIONS, PageHandlers, StationPage
from .parameters import PARAMETERS, STATION_TABLE, UP_AXES, check_parameters, check_port
from .paths import StationPaths
from .state import (
    active_object,
    apply_markers,
    candidate_options,
    candidate_standing,
    drag_moved,
    fitting_marker,
    headline,
    short_label,
    status_markdown,
    suggested_pose,
)

__all__ = [
    "StationNode",
    "feedback_message",
    "click_message",
    "check_port",
    "check_parameters",
    "PARAMETERS",
    "main",
]

MARKER_NAME = "affordance_fit"  # the engine's interactive marker for the shown fit
DRAG_KEEP_ALIVE_S = 1.0  # the engine drops a silent drag after 3 s
CALL_TIMEOUT_S = 120.0  # a button's call unanswered this long is given up


# ============================================================================ page -> messages
def feedback_message(
    event_type: int, T_scene_model: np.ndarray, frame: str, client_id: str, stamp=None
) -> InteractiveMarkerFeedback:
    """Interactive-marker feedback on the engine's ``affordance_fit`` marker."""
    return stamped(
        InteractiveMarkerFeedback(
            client_id=client_id,
            marker_name=MARKER_NAME,
            event_type=event_type,
            pose=matrix_to_pose(T_scene_model),
        ),
        frame,
        stamp,
    )


def click_message(point: np.ndarray, frame: str, stamp=None) -> PointStamped:
    """The click on ``clicked_point``: a cloud point in the cloud's frame."""
    return point_stamped(point, frame, stamp)


# ============================================================================ the node (rclpy)
@dataclass
class _Inbox:
    """What arrived for the page worker (guarded by the node's lock)."""

    cloud: PointCloud2 | None = None
    markers: list = field(default_factory=list)
    status: dict | None = None
    status_new: bool = False


@dataclass
class _CloudShown:
    """The cloud as the page shows it (the page worker's; ``points`` and ``frame`` are read by
    clicks too, under the node's lock)."""

    text: str  #: the status panel's line on it
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    frame: str = ""
    shown_at: float = -math.inf  #: monotonic time it was last replaced
    thin_voxel: float | None = None  #: its display voxel edge
    first_view_frame: str | None = None  #: the frame the browsers were last pointed in
    message: PointCloud2 | None = None  #: the cloud shown (drawn again in a new engine frame)
    #: the shown (thinned) points, their colours by depth and their own (the scan's, or its
    #: intensity's; None without): the "Depth colours" toggle switches between them
    shown: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.float32))
    depth_rgb: np.ndarray | None = None
    own_rgb: np.ndarray | None = None
    up: np.ndarray | None = None  #: the page's up axis in this frame
    up_from_click: bool = False  #: the support plane under a click has set it
    sensor: np.ndarray = field(default_factory=lambda: np.zeros(3))  #: in ``frame``


@dataclass
class _ViewOut:
    """The browser camera on ``view_pose`` (``pending`` guarded by the node's lock)."""

    pending: np.ndarray | None = None  #: T_world_optical (4x4) not yet sent
    sent_at: float = -math.inf
    sent: np.ndarray | None = None  #: T_world_optical last sent
    readers: int = 0  #: view_pose subscriptions when last looked


@dataclass
class _Drawn:
    """What the page last drew, so that a change is drawn (and logged) once."""

    label: str = ""  #: the open object's label
    headline: str = ""  #: the panel's sentence
    refused: frozenset = frozenset()  #: objects drawn as refused outlines
    pending: np.ndarray | None = None  #: the click drawn as being fitted


class _PendingClick(NamedTuple):
    """A click sent to the engine and not yet handled by it."""

    point: np.ndarray
    note: str  #: what the panel says about it
    handled: int  #: the engine's count of handled clicks when it was sent
    sent_at: float  #: monotonic time it was sent


class StationNode(Node):
    def __init__(self):
        super().__init__("affordance_station")
        p = {
            name: self.declare_parameter(
                name,
                d.default,
                ParameterDescriptor(description=described(d), additional_constraints=d.rule),
            ).value
            for name, d in STATION_TABLE.items()
        }
        p["sensor_origin"] = [float(v) for v in p["sensor_origin"]]
        problem = check_parameters(p)
        if problem:
            raise AffordanceError(problem)
        self.p = p
        self.engine = "/" + p["engine"].strip("/")
        check_port(p["host"], p["port"])
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._inbox = _Inbox()
        self._drawings: dict = {}
        self._status: dict | None = None
        self._connected = False
        self._movers = False  # something subscribes to sensor_view_request
        self._cloud = _CloudShown("none received yet on " + self.resolve_topic_name("points"))
        self._drawn = _Drawn()
        self._last_action = ""
        self._view = _ViewOut()
        self._drag_id = f"affordance_station_{int(time.time() * 1e6):x}"
        self._drag_last = None  # (T, time) of the drag in progress
        self._calls: deque = deque()  # buttons waiting for the call in flight
        self._calling = None  # (action, time sent) of the call in flight
        self._refresh = True
        self._pending: _PendingClick | None = None  # the click being fitted
        self._seen_error = ("", "")  # (last_error, last_message when it first showed)
        self._alert = ""  # what went wrong with the operator's last action (the headline)
        self._depth_colors = p["color_by"] == "depth"
        self._recolor = False  # the "Depth colours" toggle changed
        self._drag_start = None  # the gizmo's pose when pressed, until it moved (no drag yet)

        self.create_subscription(
            PointCloud2, "points", self._on_cloud, qos.cloud(p["points_reliable"])
        )
        #: the cloud is drawn in the engine's frame (its fixed frame, when it has one)
        self._tf = TfListener(self)
        self.status_topic = f"{self.engine}/status"
        self.create_subscription(String, self.status_topic, self._on_status, LATCHED)
        markers_qos = qos.latched(10)
        self.create_subscription(
            MarkerArray, f"{self.engine}/markers", self._on_markers, markers_qos
        )
        self.pub_click = self.create_publisher(PointStamped, "clicked_point", INPUT)
        self.pub_view = self.create_publisher(PoseStamped, "view_pose", INPUT)
        self.pub_select = self.create_publisher(String, f"{self.engine}/select_model", INPUT)
        self.pub_dimension = self.create_publisher(String, f"{self.engine}/set_dimension", INPUT)
        self.pub_sensor = self.create_publisher(PoseStamped, "sensor_view_request", INPUT)
        ns = "/" + p["interactive_namespace"].strip("/")
        self.pub_feedback = self.create_publisher(
            InteractiveMarkerFeedback, f"{ns}/feedback", INPUT
        )
        self.triggers = {
            action: self.create_client(Trigger, f"{self.engine}/{action}") for action, _ in ACTIONS
        }
        # the operator only: an access secret, same-origin websockets, bounded frames and
        # message rates, no share tunnel, no outbound connections (ros/station/access.py)
        self.access = station_access.StationAccess(
            station_access.configured_secret(p["access_secret"]),
            p["host"],
            p["port"],
            log=self.get_logger().warning,
        )
        station_access.forbid_outbound([p["host"]], log=self.get_logger().error)
        with station_access.guarded(self.access):
            self.page = StationPage(
                p["host"],
                p["port"],
                p["fov_deg"],
                p["point_size"],
                depth_colors=self._depth_colors,
                handlers=PageHandlers(
                    click=self._click,
                    action=self._action,
                    select=self._select,
                    drag=self._drag,
                    camera=self._camera,
                    dimension=self._dimension,
                    move_sensor=self._move_sensor,
                    path=lambda state: self.paths.request(state),
                    waypoints=lambda shown, drawn: self.paths.toggled(shown, drawn),
                    colors=self._colors,
                ),
            )
        self.paths = StationPaths(self)  # "Show path" -> <engine>/path_request, <engine>/path
        station_access.disable_share(self.page.server, self.get_logger().warning)
        self.access.port = self.page.port
        self.url = self.access.url()
        # the secret: printed to the terminal that started the station and kept in a 0600
        # file; never through the ROS logger (/rosout, the ROS log folder) nor a parameter
        self.undeclare_parameter("access_secret")
        try:
            self.url_file = station_access.keep_url(self.url, self.access.port)
            kept = f"; its URL with the access secret is kept in {self.url_file}"
        except OSError as exc:
            self.url_file, kept = None, f"; its URL could not be kept in a file ({exc})"
        print(f"operator station: {self.url}", flush=True)
        self._worker = threading.Thread(target=self._run, name="station-page", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"operator station on {self.access.url(secret=False)} (engine {self.engine}){kept}"
        )

    # ------------------------------------------------------------------ ROS -> inbox
    def _on_cloud(self, msg: PointCloud2) -> None:
        with self._lock:
            self._inbox.cloud = msg
        self._wake.set()

    def _on_status(self, msg: String) -> None:
        try:
            status = json.loads(msg.data)
        except ValueError:
            self.get_logger().warning(f"{self.status_topic}: not JSON; ignored")
            return
        if not isinstance(status, dict):
            return
        with self._lock:
            self._inbox.status, self._inbox.status_new = status, True
        self._wake.set()

    def _on_markers(self, msg: MarkerArray) -> None:
        with self._lock:
            self._inbox.markers.append(msg)
        self._wake.set()

    # ------------------------------------------------------------------ page -> ROS
    def _click(self, origin: np.ndarray, direction: np.ndarray) -> None:
        with self._lock:
            points, frame = self._cloud.points, self._cloud.frame
        try:
            i = display.snap_ray(
                points, origin, direction, cone_rad=math.radians(self.p["click_cone_deg"])
            )
        except AffordanceError as exc:
            self._note(f"click ignored: {exc}", failed=True)
            return
        if i is None:
            self._note(
                "click missed the cloud: click on a point of the cloud"
                if len(points)
                else "click ignored: no cloud received yet",
                failed=True,
            )
            return
        point = points[i]
        note = f"clicked ({', '.join(f'{v:.3f}' for v in point)}) in '{frame}'"
        with self._lock:  # fitting until the engine's status counts one more handled click
            self._pending = _PendingClick(
                point.copy(), note, self._clicks_handled(self._status), time.monotonic()
            )
        self.pub_click.publish(click_message(point, frame, self.get_clock().now().to_msg()))
        self._note(f"{note}: fitting")
        if self.p["up"] == "auto":
            self._up_from_support(point)

    def _clicks_handled(self, status: dict | None) -> int:
        """How many clicks on this station's topic the engine's status says it has handled."""
        handled = ((status or {}).get("node") or {}).get("handled") or {}
        return int(handled.get(self.pub_click.topic_name, 0) or 0)

    def _action(self, action: str) -> None:
        """A button: its service is called once the station's previous call was answered, so
        the engine gets the buttons in the order they were pressed (calls to different services
        are not ordered on the wire)."""
        client = self.triggers[action]
        if not client.service_is_ready():
            self._note(
                f"{action}: not sent, the engine's {client.srv_name} service is not available",
                failed=True,
            )
            return
        with self._lock:
            self._calls.append(action)
            ahead = self._calling[0] if self._calling else None
        self._note(f"{action}: sent" if ahead is None else f"{action}: after {ahead}")
        self._next_call()

    def _next_call(self) -> None:
        with self._lock:
            if self._calling is not None or not self._calls:
                return
            action = self._calls.popleft()
            self._calling = (action, time.monotonic())
        future = self.triggers[action].call_async(Trigger.Request())
        future.add_done_callback(lambda f: self._on_reply(action, f))

    def _on_reply(self, action: str, future) -> None:
        try:
            res = future.result()
            text = f"{action}: {'ok' if res.success else 'refused'} — {res.message}"
            failed = not res.success
        except Exception as exc:  # the call failed in rclpy (engine gone mid-call)
            text, failed = f"{action}: failed ({exc})", True
        with self._lock:
            if self._calling is None or self._calling[0] != action:
                return  # given up on already (see _step)
            self._calling = None
        self._note(text, failed=failed)
        self._next_call()

    def _give_up_calls(self, why: str) -> None:
        """Forget the call in flight and the queued ones (the engine went away or does not
        answer): the operator sees which were lost."""
        with self._lock:
            lost = ([self._calling[0]] if self._calling else []) + list(self._calls)
            self._calling, self._calls = None, deque()
        if lost:
            self._note(f"{', '.join(lost)}: no answer ({why})", failed=True)

    def _select(self, template: str) -> None:
        self.pub_select.publish(String(data=template))
        self._note(f"select {template}: sent")

    def _dimension(self, name: str, value: float) -> None:
        if not math.isfinite(value) or value <= 0:
            self._note(f"{name}: {value!r} is not a size in metres", failed=True)
            return
        self.pub_dimension.publish(String(data=f"{name}={value:.6g}"))
        self._note(f"{name} {value * 1000:.1f} mm: sent")

    def _move_sensor(self) -> None:
        """The suggested view of the open object on ``sensor_view_request``."""
        T, frame = suggested_pose(active_object(self._status)), self._frame()
        if T is None or not frame:
            self._note(
                "Move sensor here: not sent, the open object has no suggested view", failed=True
            )
            return
        self.pub_sensor.publish(pose_stamped(T, frame, self.get_clock().now().to_msg()))
        where = ", ".join(f"{v:.3f}" for v in T[:3, 3])
        self._note(
            f"Move sensor here: sent ({where}) in '{frame}' on "
            f"{self.pub_sensor.topic_name}"
            + ("" if self.pub_sensor.get_subscription_count() else " (nothing subscribes to it)")
        )

    def _drag(self, phase: str, T: np.ndarray) -> None:
        """The gizmo: a drag goes to the engine once it has moved the fit (``drag_moved``); a
        press on a handle that does not move it sends nothing, so it neither moves nor refits
        the shown fit."""
        F = InteractiveMarkerFeedback
        if phase == "cancel":  # no keep-alives: the engine cancels the silent drag
            with self._lock:
                started, self._drag_last, self._drag_start = self._drag_last, None, None
            if started is None:
                return
            self._note("the dragging browser went away: its drag is cancelled")
            self.get_logger().info(
                "a browser went away mid-drag: its drag is cancelled (not released)"
            )
            return
        if phase not in ("start", "update", "end") or not self._cloud.frame:
            return
        with self._lock:
            if phase == "start":
                self._drag_start, self._drag_last = T, None
                return
            started = self._drag_last is not None
            begin = (
                not started
                and self._drag_start is not None
                and phase == "update"
                and drag_moved(self._drag_start, T)
            )
            if phase == "end":
                self._drag_start, self._drag_last = None, None
            elif started or begin:
                self._drag_last = (T, time.monotonic())
        frame = self._frame()
        stamp = self.get_clock().now().to_msg()
        if begin:
            self.pub_feedback.publish(
                feedback_message(F.MOUSE_DOWN, T, frame, self._drag_id, stamp)
            )
        if phase == "update" and (started or begin):
            self.pub_feedback.publish(
                feedback_message(F.POSE_UPDATE, T, frame, self._drag_id, stamp)
            )
        elif phase == "end" and started:
            self.pub_feedback.publish(feedback_message(F.MOUSE_UP, T, frame, self._drag_id, stamp))
            self._note("correction sent: refitting from the released pose")
            self.get_logger().info("gizmo released: correction sent")
        elif phase == "end":
            self.get_logger().info("gizmo pressed without moving it: no correction")

    def _camera(self, T_world_optical: np.ndarray) -> None:
        with self._lock:
            self._view.pending = T_world_optical
        self._wake.set()

    def _note(self, text: str, failed: bool = False) -> None:
        """What happened to the operator's last action (the details' "Last action"); when it
        ``failed``, the headline says so until the next action."""
        with self._lock:
            self._last_action = text
            self._alert = text if failed else ""
            self._refresh = True
        self._wake.set()

    def _frame(self) -> str:
        return (self._status or {}).get("frame_id") or self._cloud.frame

    # ------------------------------------------------------------------ the page worker
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.1)
            self._wake.clear()
            try:
                self._step()
            except Exception as exc:  # the page must outlive one bad update
                self.get_logger().error(f"station: page update failed: {exc!r}")
                time.sleep(0.2)

    def _step(self) -> None:
        """One turn of the page worker: take what arrived, update the page, send what is due."""
        now = time.monotonic()
        with self._lock:
            inbox, self._inbox = self._inbox, _Inbox()
            view, drag = self._view.pending, self._drag_last
            refresh, self._refresh = self._refresh, False
            recolor, self._recolor = self._recolor, False
        if recolor and inbox.cloud is None:
            self._draw_cloud()
        refresh = self._take_cloud(inbox.cloud, now) or refresh
        if inbox.status_new:
            self._status = inbox.status
            refresh = True
            scene = (self._status or {}).get("frame_id")
            if scene and self._cloud.message is not None and scene != self._cloud.frame:
                self._show_cloud(self._cloud.message)  # the engine's frame changed: drawn there
        refresh = self._settle_pending_click(now) or refresh
        refresh = self._watch_engine(now) or refresh
        refresh = self._watch_movers() or refresh
        if refresh:
            # the panel first, in a message window of its own: the browser applies a window
            # that touches only the panel at once, one with scene changes (the fitting marker,
            # the meshes) at its next frame
            self._render_panel()
            self.page.flush()
        self._draw_pending_click(now)
        for msg in inbox.markers:
            self._drawings = apply_markers(self._drawings, msg)
        if refresh or inbox.markers:
            self._render_scene()
        self._send_view(view, now)
        self._keep_drag_alive(drag, now)

    def _take_cloud(self, cloud: PointCloud2 | None, now: float) -> bool:
        """Show a new cloud, at most ``cloud_rate`` times a second (one that comes too soon is
        kept for a later turn); True when the page changed."""
        if cloud is None:
            return False
        if now - self._cloud.shown_at >= 1.0 / self.p["cloud_rate"]:
            self._show_cloud(cloud)
            self._cloud.shown_at = now
            return True
        with self._lock:
            if self._inbox.cloud is None:
                self._inbox.cloud = cloud
        return False

    def _settle_pending_click(self, now: float) -> bool:
        """Forget the click being fitted once the engine's status counts it handled (fitted or
        refused) or it waited too long; True when the panel must change."""
        with self._lock:
            pending = self._pending
            if pending is None or not (
                self._clicks_handled(self._status) > pending.handled
                or now - pending.sent_at > CALL_TIMEOUT_S
            ):
                return False
            self._pending = None
            if self._last_action == f"{pending.note}: fitting":
                self._last_action = ""  # what happened is in Shown and Last message
            return True

    def _draw_pending_click(self, now: float) -> None:
        """The "fitting…" marker once the click has waited ``fitting_marker_delay`` for its
        fit: a fast fit's label comes without it (on software WebGL each drawn frame holds the
        page for a few hundred ms, and the label would wait for it); the panel says "Fitting"
        at once."""
        with self._lock:
            pending = self._pending
        point = (
            None
            if pending is None
            else fitting_marker(
                pending.point, pending.sent_at, now, float(self.p["fitting_marker_delay"])
            )
        )
        if point is not self._drawn.pending:
            self.page.show_pending_click(point)
            self._drawn.pending = point
            self.get_logger().info(
                "fitting marker shown" if point is not None else "fitting marker cleared"
            )

    def _watch_engine(self, now: float) -> bool:
        """Whether the engine is up (its status has a publisher); the button calls it does not
        answer are given up. True when the connection changed."""
        connected = self.count_publishers(self.status_topic) > 0
        changed = connected != self._connected
        self._connected = connected
        with self._lock:
            calling = self._calling
        if calling is not None and (not connected or now - calling[1] > CALL_TIMEOUT_S):
            self._give_up_calls(
                "the engine is not running" if not connected else f"waited {CALL_TIMEOUT_S:.0f} s"
            )
        return changed

    def _watch_movers(self) -> bool:
        """Whether something moves the sensor: a subscriber to ``sensor_view_request`` ("Move
        sensor here" is offered only then). True when that changed."""
        movers = self.pub_sensor.get_subscription_count() > 0
        changed, self._movers = movers != self._movers, movers
        return changed

    def _send_view(self, view: np.ndarray | None, now: float) -> None:
        """The browser's camera on ``view_pose``, at most ``view_rate`` times a second."""
        # view_pose is volatile and the camera is only reported when it moves: a subscriber that
        # joins after the browser's camera came to rest (an engine started later) gets the view
        # it would otherwise wait for until the operator moves the camera
        readers = self.pub_view.get_subscription_count()
        if readers > self._view.readers and view is None and self._view.sent is not None:
            with self._lock:
                if self._view.pending is None:
                    self._view.pending = self._view.sent
                view = self._view.pending
        self._view.readers = readers
        if (
            view is None
            or not self._frame()
            or now - self._view.sent_at < 1.0 / self.p["view_rate"]
        ):
            return
        with self._lock:  # (a newer view the camera sent meanwhile stays pending)
            if self._view.pending is view:
                self._view.pending = None
        self.pub_view.publish(pose_stamped(view, self._frame(), self.get_clock().now().to_msg()))
        self._view.sent_at, self._view.sent = now, view

    def _keep_drag_alive(self, drag: tuple | None, now: float) -> None:
        """A gizmo held still still owns its drag: a keep-alive every DRAG_KEEP_ALIVE_S."""
        if drag is None or now - drag[1] < DRAG_KEEP_ALIVE_S:
            return
        self.pub_feedback.publish(
            feedback_message(
                InteractiveMarkerFeedback.KEEP_ALIVE, drag[0], self._frame(), self._drag_id
            )
        )
        with self._lock:
            if self._drag_last is drag:
                self._drag_last = (drag[0], now)

    def _render_panel(self) -> None:
        status = self._status if self._connected else None
        obj = active_object(self._status)
        with self._lock:
            last_action, alert = self._last_action, self._alert
            pending = self._pending
        node = (self._status or {}).get("node") or {}
        error, message = node.get("last_error") or "", node.get("last_message") or ""
        if error != self._seen_error[0]:
            self._seen_error = (error, message)
        # an error goes stale once the engine reports something after it
        stale = bool(error) and message != self._seen_error[1]
        fitting = "" if pending is None else f"{pending.note} — the engine is fitting it"
        said = headline(status, self._connected, self.engine, pending is not None, alert)
        self.page.show_text(
            text(said),
            status_markdown(
                status, self._connected, self.engine, self._cloud.text, last_action, fitting, stale
            ),
        )
        if said != self._drawn.headline:
            self._drawn.headline = said
            self.get_logger().info(f"panel: {said}")
        self.page.show_candidates(
            candidate_options(obj), obj["candidates"][obj["shown"]]["template"] if obj else None
        )
        shown = obj["candidates"][obj["shown"]] if obj else {}
        self.page.show_dimensions(shown.get("dimensions") if shown.get("primitive") else None)
        self.page.enable(self._connected)
        self.page.show_move_sensor(
            self._connected and self._movers and suggested_pose(obj) is not None
        )

    def _render_scene(self) -> None:
        obj = active_object(self._status)
        label = short_label(obj)
        frame = self._frame()
        drawings = {
            k: d
            for k, d in self._drawings.items()
            if not frame or not d.frame or d.frame.lstrip("/") == frame.lstrip("/")
        }
        refused = frozenset(
            o.get("id")
            for o in (self._status or {}).get("objects") or []
            if candidate_standing(o)[1]
        )
        self.page.show_scene(drawings, obj["id"] if obj else None, label, refused)
        if refused != self._drawn.refused:
            self._drawn.refused = refused
            self.get_logger().info(f"drawn as refused outlines: objects {sorted(refused)}")
        drawn = drawings.get(("candidate_label", obj["id"])) if obj else None
        if drawn is not None and drawn.text != self._drawn.label:
            # what the 3D view now draws for the open object (from the engine's markers; the
            # panel's label follows the status, which comes first)
            self._drawn.label = drawn.text
            self.get_logger().info(f"drawn: object {obj['id']} as {drawn.text}")

    def _show_cloud(self, msg: PointCloud2) -> None:
        self._cloud.message = msg
        try:
            pts, _ = pointcloud2_to_xyz(msg)
        except ConversionError as exc:
            self._cloud.text = f"the latest cloud is unusable ({exc})"
            self.get_logger().warning(f"points: {exc}")
            return
        finite = np.all(np.isfinite(pts), axis=1)
        if not finite.all():
            pts = pts[finite]
        sensor = self._sensor_origin()
        frame = msg.header.frame_id
        scene = (self._status or {}).get("frame_id") or frame
        if scene.lstrip("/") != frame.lstrip("/"):  # the engine's fixed frame: drawn in it
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            try:
                T = self._tf.lookup(scene, frame, stamp or None)
            except AffordanceError as exc:
                self._cloud.text = f"the cloud in '{frame}' is not placed in '{scene}' ({exc})"
                return
            pts = pts @ T[:3, :3].T + T[:3, 3]
            sensor = T[:3, :3] @ sensor + T[:3, 3]
            frame = scene
        thinned = (
            display.thin(pts, int(self.p["display_points"]), start_voxel=self._cloud.thin_voxel)
            if len(pts)
            else display.Thinned(np.zeros(0, dtype=np.int64), 0.0)
        )
        self._cloud.thin_voxel = thinned.voxel or None
        keep = thinned.indices
        shown = pts[keep]
        own, note = self._own_colors(msg, finite, keep)
        self._cloud.shown, self._cloud.own_rgb = shown, own
        self._cloud.depth_rgb = display.scalar_colors(np.linalg.norm(shown - sensor, axis=1))
        with self._lock:
            self._cloud.points, self._cloud.frame, self._cloud.sensor = pts, frame, sensor
        if frame != self._cloud.first_view_frame and len(pts):
            self._cloud.first_view_frame = frame
            self.get_logger().info(f"cloud drawn in '{frame}' (from '{msg.header.frame_id}')")
            self._first_view(shown, frame, sensor)
        self._draw_cloud()
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self._cloud.text = (
            f"{len(pts):,} points in '{frame}', {len(keep):,} shown (stamp {stamp:.3f})" + note
        )

    def _own_colors(self, msg: PointCloud2, finite: np.ndarray, keep: np.ndarray):
        """(the shown points' own colours -- the scan's ``rgb`` / ``rgba``, else its intensity
        as a scale -- or None, and a note for the details) as ``color_by`` asks."""
        mode = self.p["color_by"]
        if mode in ("auto", "rgb"):
            rgb = pointcloud2_colors(msg)
            if rgb is not None:
                return (rgb[finite] if not finite.all() else rgb)[keep], ", its own colours"
        if mode in ("auto", "intensity"):
            values = pointcloud2_field(msg, "intensity")
            if values is not None:
                values = (values[finite] if not finite.all() else values)[keep]
                return display.scalar_colors(values), ", coloured by intensity"
        if mode in ("rgb", "intensity"):
            return None, f" (it has no {mode} field: coloured by depth)"
        return None, ""

    def _draw_cloud(self) -> None:
        own = self._cloud.own_rgb
        depth = self._depth_colors or own is None
        self.page.show_cloud(self._cloud.shown, self._cloud.depth_rgb if depth else own)

    def _colors(self, depth: bool) -> None:
        """The "Depth colours" toggle (viser's thread): the page worker redraws the cloud."""
        with self._lock:
            self._depth_colors = bool(depth)
            self._recolor = True
        self._wake.set()

    def _sensor_origin(self) -> np.ndarray:
        return np.asarray(self.p["sensor_origin"], dtype=float)

    def _first_view(self, shown: np.ndarray, frame: str, sensor: np.ndarray) -> None:
        """Point the browsers at a cloud in a new frame: its up axis (``up``, or with ``auto``
        what the scan says: display.first_up) and a view from the ``sensor`` (in ``frame``:
        display.initial_view)."""
        if self.p["up"] != "auto":
            up, why = np.array(UP_AXES[self.p["up"]], dtype=float), f"up {self.p['up']}"
        else:
            up, why = display.first_up(shown, sensor, optical="optical" in frame)
        self._cloud.up, self._cloud.up_from_click = up, self.p["up"] != "auto"
        position, look_at = display.initial_view(
            shown, up, math.radians(self.p["fov_deg"]), sensor=sensor
        )
        self.page.set_view(up, position, look_at)
        self.get_logger().info(
            f"first view of '{frame}': up ({', '.join(f'{v:.3f}' for v in up)}), {why}"
        )

    def _up_from_support(self, point: np.ndarray) -> None:
        """The first click in a frame (``up`` auto): the plane under it, where the scan shows
        one, is the world's up axis from now on (display.support_under)."""
        with self._lock:
            if self._cloud.up_from_click or self._cloud.up is None:
                return
            self._cloud.up_from_click = True
            points, up, sensor = self._cloud.points, self._cloud.up, self._cloud.sensor
        normal = display.support_under(points, point, sensor, up)
        if normal is None:
            self.get_logger().info("no support plane under the first click: the up axis stays")
            return
        self._cloud.up = normal
        self.page.set_up(normal)
        self.get_logger().info(
            f"up ({', '.join(f'{v:.3f}' for v in normal)}): the support plane under the "
            f"first click"
        )

    def shutdown(self) -> None:
        self._stop.set()
        self._worker.join(timeout=2.0)
        self.page.stop()
        if self.url_file is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.url_file)


def main(args=None) -> int:
    """Console script ``affordance_station`` (takes ``--ros-args``)."""
    return run_node(StationNode, "affordance_station", args, shutdown=lambda node: node.shutdown())


if __name__ == "__main__":
    raise SystemExit(main())
