# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ``affordance_engine`` node: clouds, clicks, SpaceMouse twists/buttons, view poses, marker
feedback and service calls in; ranked fit markers, poses and status out. Thin: convert, hand to
the core, publish.

Every operator input goes into one :class:`~affordance_registration.core.operator.OperatorStream`
and is handled in arrival order by one worker thread (so an action right after a click acts on
that click's object however long the fit takes). The executor thread only converts messages,
answers service calls when the stream has handled them (async callbacks: the executor is never
blocked), and publishes what changed as soon as it changed (a guard condition wakes it; at most
``publish_rate`` times a second). Clouds are only
stored on arrival (the latest one) and converted when a fit needs it, so a 1M-point 30 Hz camera
cannot starve the node.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time

import numpy as np
from geometry_msgs.msg import PointStamped, PoseArray, PoseStamped, Twist, TwistStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import Joy, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from ...core.corrections import view_from_optical
from ...core.engine import AffordanceEngine
from ...core.errors import AffordanceError, EngineStateError, bounded
from ...core.operator import ACTIONS, OperatorStream
from ...core.persistence import RegistrationStore
from ...core.scene import NO_VIEWPOINT
from ...core.templates import TemplateLibrary
from ..glue import params, qos
from ..glue.conversions import (
    ConversionError,
    header_stamp_s,
    matrix_to_pose,
    parse_dimension,
    pointcloud2_layout,
    pointcloud2_to_xyz,
    pose_stamped,
    pose_to_matrix,
    source_stamp_s,
)
from ..glue.frames import FrameError, StaticFrames, T_frame_optical
from ..glue.markers import registered_markers_memo, state_markers
from ..glue.paths import PathRequests
from ..glue.qos import INPUT as INPUT_QOS
from ..glue.qos import LATCHED
from ..glue.qos import SERVICES as SERVICE_QOS
from ..glue.tf import TfBroadcaster, TfListener
from ..glue.throttle import Throttle
from ..standins.interactive import CorrectionMarkerServer
from ..standins.spin import run_node

SERVICES = (
    "next_model",
    "previous_model",
    "refit",
    "accept",
    "undo",
    "discard",
    "save",
    "joint_plus",
    "joint_minus",
)
#: inputs whose errors repeat with a stream of bad messages: logged as throttled warnings
STREAMED = ("twist", "joy", "view", "pose", "cloud", "queue", "select_model", "click", "path")
THROTTLE_S = 2.0
#: how often a drag whose client fell silent is looked for (s)
DRAG_WATCH_S = 0.5
#: the longest frame id, template name or other name taken from a message (longer: refused)
MAX_NAME = 256
#: the longest log line / status message the node writes about one input
MAX_MESSAGE = 2000


class EngineNode(Node):
    """The engine node. It is the host of its operator stream (``OperatorHost``: the scene, the
    click's frame, the outcomes, the registrations file) and of its interactive-marker server
    (``MarkerHost``: what is shown, and the marker input into the stream)."""

    def __init__(self, **kwargs):
        super().__init__("affordance_engine", **kwargs)
        self._p = params.declare(self)
        for line in params.unknown_overrides(self._parameter_overrides):
            self.get_logger().warning(line)
        self.library = TemplateLibrary.load(self._p["templates_dir"] or None)
        self.engine = AffordanceEngine(self.library, params.fit_settings(self._p))
        self._set_joint_steps(self._p)
        self._store = RegistrationStore(params.registrations_path(self._p["registrations_file"]))
        self._unsaved = False  # registrations changed and not written (autosave off)
        self._resume()
        self.frames = StaticFrames(self._p["static_transforms"])
        self._tf = self._make_tf()
        self._tf_out = TfBroadcaster(self)
        self._drawn = registered_markers_memo()  # each registration's markers, made once
        #: what ~/markers last drew: (state, library, frame, view up)
        self._markers_of: tuple = (None, None, None, None)

        self._lock = threading.Lock()
        self._cloud_msg: PointCloud2 | None = None
        self._cloud_count = 0
        self._converted = 0
        self._cloud_status_at = 0.0
        self._dropped = ""  # why the latest cloud was refused ("" if it was not)
        self._dirty = True
        self._last_publish = 0.0
        self._publish_later = None  # the one-shot timer of a change that came too soon
        self._publish_guard = self.create_guard_condition(self._on_publish)
        self._last_error = ""
        self._last_message = ""
        self._warnings = Throttle(THROTTLE_S)
        self._stop = threading.Event()
        self.stream = OperatorStream(self.engine, params.operator_settings(self._p), host=self)

        cloud_qos = qos.cloud(self._p["points_reliable"])
        self._sub_points = self.create_subscription(
            PointCloud2, "points", self._on_cloud, cloud_qos
        )
        self._sub_click = self.create_subscription(
            PointStamped, "clicked_point", self._on_click, INPUT_QOS
        )
        self._sub_twist = self.create_subscription(
            TwistStamped if self._p["twist_stamped"] else Twist,
            "spacenav/twist",
            self._on_twist,
            INPUT_QOS,
        )
        self._sub_joy = self.create_subscription(Joy, "spacenav/joy", self._on_joy, INPUT_QOS)
        self._sub_view = self.create_subscription(
            PoseStamped, "view_pose", self._on_view, INPUT_QOS
        )
        self._sub_select = self.create_subscription(
            String, "~/select_model", self._on_select, INPUT_QOS
        )
        self._sub_dimension = self.create_subscription(
            String, "~/set_dimension", self._on_dimension, INPUT_QOS
        )
        self._input_subscriptions = (
            self._sub_click,
            self._sub_twist,
            self._sub_joy,
            self._sub_view,
            self._sub_select,
            self._sub_dimension,
        )
        self.pub_markers = self.create_publisher(MarkerArray, "~/markers", LATCHED)
        self.pub_fit = self.create_publisher(PoseStamped, "~/fit", 10)
        self.pub_registered = self.create_publisher(PoseArray, "~/registered", LATCHED)
        self.pub_status = self.create_publisher(String, "~/status", LATCHED)
        self.paths = PathRequests(self)  # ~/path_request -> ~/path
        #: where the sensor should look from to settle the selected object (optical frame)
        self.pub_view = self.create_publisher(PoseStamped, "~/suggested_view", LATCHED)
        # service calls wait for the stream without holding the default callback group: the
        # subscriptions and the publishing timer keep running meanwhile
        services = ReentrantCallbackGroup()
        for action in SERVICES:
            self.create_service(
                Trigger,
                f"~/{action}",
                self._service(action),
                qos_profile=SERVICE_QOS,
                callback_group=services,
            )
        self.interactive = CorrectionMarkerServer(
            self,
            self._p["interactive_namespace"],
            self._p["interactive_orientation"],
            server_id=self.get_fully_qualified_name(),
        )
        self.interactive.attach(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # a silent drag is cancelled, not left hanging (a watchdog: publishing does not poll)
        self.create_timer(DRAG_WATCH_S, self.interactive.expire)
        self._name_checks = 0
        self._name_timer = self.create_timer(1.0, self._check_name)
        self._worker = threading.Thread(
            target=self.stream.run, args=(self._stop,), name="operator-stream", daemon=True
        )
        self._worker.start()
        self.changed()  # the first status goes out once the executor spins
        self.get_logger().info(
            f"ready: {len(self.library)} templates "
            f"({', '.join(self.library)}); waiting for 'points' and clicks"
        )

    # ------------------------------------------------------------------ registrations file
    def _resume(self) -> None:
        """Resume the session from ``registrations_file`` (unless ``resume`` is off). A file
        that is not a registrations file stops the start with one line: it is never replaced
        unread."""
        path = self._store.path
        if not self._p["resume"]:
            if os.path.lexists(path):
                self.get_logger().info(
                    f"fresh session (resume is off): {path} is kept as a "
                    f"backup when it is first replaced"
                )
            return
        try:
            regs = self._store.resume(self.library)
        except AffordanceError as exc:
            raise AffordanceError(
                f"cannot resume the session: {exc} (fix or move the file, or "
                f"start a fresh session with resume:=false: the file is then "
                f"kept as a backup)"
            ) from None
        self.engine.resume(regs)
        if regs:
            self.get_logger().info(f"resumed {len(regs)} registration(s) from {path}")

    def persist(self, explicit: bool) -> str:
        """Write the registrations (stream worker): for ``~/save`` (``explicit``), and after
        every change when ``autosave`` is on. Returns the reply's words."""
        if not explicit and not self._p["autosave"]:
            self._unsaved = True
            return ""
        regs = self.engine.state.registered
        path, backup = self._store.write(regs, self.engine.frame_id, self.library)
        self._unsaved = False
        self.changed()
        text = f"saved {len(regs)} registration(s) to {path}" if explicit else f"saved to {path}"
        return text + (f" (the file it replaced is kept as {backup})" if backup else "")

    # ------------------------------------------------------------------ parameters
    def _set_joint_steps(self, p: dict) -> None:
        self.engine.joint_step_rad = math.radians(float(p["joint_step_deg"]))
        self.engine.joint_step_m = float(p["joint_step_mm"]) / 1000.0
        self.engine.dimension_step_m = float(p["dimension_step_mm"]) / 1000.0

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        new = dict(self._p)
        changed = {p.name for p in parameters if p.name in params.PARAMETERS}
        for p in parameters:
            if p.name in changed:
                new[p.name] = [] if p.value is None else p.value
        problem = params.check({name: new[name] for name in changed})
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        try:
            return self._apply_parameters(new, changed)
        except AffordanceError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        except Exception as exc:  # the caller always gets an answer, with the reason
            return SetParametersResult(
                successful=False, reason=f"internal error: {exc.__class__.__name__}: {exc}"
            )

    def _apply_parameters(self, new: dict, changed: set) -> SetParametersResult:
        """Use validated new values: a new library or fitting settings rebuild the registrar
        (refused while objects are open), the rest applies from the next input on."""
        library = None
        if "templates_dir" in changed and new["templates_dir"] != self._p["templates_dir"]:
            library = TemplateLibrary.load(new["templates_dir"] or None)
        if library is not None or changed & params.FIT_PARAMETERS:
            self.engine.configure(params.fit_settings(new), library)
            self.library = self.engine.library
        if "static_transforms" in changed:
            self.frames = StaticFrames(new["static_transforms"])
        if (
            "registrations_file" in changed
            and new["registrations_file"] != self._p["registrations_file"]
        ):
            self._store = RegistrationStore(params.registrations_path(new["registrations_file"]))
            self._unsaved = bool(self.engine.state.registered)
        if changed & {"sensor_frame", "sensor_origin", "static_transforms"}:
            self._converted = -1  # the next fit converts the cloud again
        self.stream.configure(params.operator_settings(new))
        self._set_joint_steps(new)
        if "interactive_orientation" in changed:
            self.interactive.orientation = new["interactive_orientation"]
        self._p = new
        self.changed()
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ frames
    def _make_tf(self) -> TfListener:
        return TfListener(self)

    def _lookup(self, target: str, source: str, stamp: float | None = None) -> np.ndarray:
        """T_target_source from TF (tf2_ros, or /tf and /tf_static) at ``stamp`` (s, the
        header stamp of the message that needs it; None: the latest) and the static
        transforms parameter."""
        return self._tf.lookup(target, source, fallback=self.frames, stamp=stamp)

    def frame(self) -> str:
        """The frame of everything the node reports: the scene's, else the latest cloud's."""
        if self.engine.frame_id:
            return self.engine.frame_id
        with self._lock:
            return self._cloud_msg.header.frame_id if self._cloud_msg is not None else ""

    def to_scene_frame(
        self, point: np.ndarray, frame: str, stamp: float | None = None
    ) -> np.ndarray:
        """A click given in ``frame`` at ``stamp`` expressed in the scene's frame (stream
        worker)."""
        cloud_frame = self.engine.frame_id
        if not frame or frame.lstrip("/") == cloud_frame.lstrip("/"):
            return point
        try:
            T = self._lookup(cloud_frame, frame, stamp)
        except FrameError:
            raise AffordanceError(
                f"click refused: it is in frame '{frame}' and no transform to "
                f"the cloud frame '{cloud_frame}' is known"
            ) from None
        return T[:3, :3] @ point + T[:3, 3]

    # ------------------------------------------------------------------ inputs
    def _on_cloud(self, msg: PointCloud2) -> None:
        try:  # the header checked now; the points read when needed
            if len(msg.header.frame_id) > MAX_NAME:
                raise ConversionError(
                    f"its frame id has {len(msg.header.frame_id):,} "
                    f"characters (at most {MAX_NAME})"
                )
            pointcloud2_layout(msg)
        except ConversionError as exc:
            frame = bounded(msg.header.frame_id, 80)
            self._dropped = f"the last PointCloud2 (frame '{frame}') was dropped: {exc}"
            self._error("cloud", f"dropped a PointCloud2 in '{frame}': {exc}")
            return
        self._dropped = ""
        with self._lock:
            prev = self._cloud_msg
            self._cloud_msg = msg
            self._cloud_count += 1
        now = time.monotonic()
        if prev is None or (prev.width, prev.height, prev.header.frame_id) != (
            msg.width,
            msg.height,
            msg.header.frame_id,
        ):
            self.get_logger().info(f"cloud: {msg.width}x{msg.height} in '{msg.header.frame_id}'")
            self.changed()
        elif now - self._cloud_status_at >= 1.0:  # the status counts clouds at most at 1 Hz
            self.changed()
        if self._dirty:
            self._cloud_status_at = now
        self.stream.new_cloud()

    def refresh_scene(self) -> None:
        """Make the engine's scene the latest cloud (stream worker). An unusable newer cloud is
        reported and the previous scene kept; with no previous scene it is an error."""
        with self._lock:
            msg, count = self._cloud_msg, self._cloud_count
        if msg is None:
            raise EngineStateError(
                f"no usable point cloud yet on '{self._sub_points.topic_name}'"
                + (f": {self._dropped}" if self._dropped else "")
            )
        if count == self._converted and self.engine.has_scene:
            return  # (a cloud that was unusable with no scene is tried again: its
        self._converted = count  # sensor frame may have reached TF since)
        try:
            pts, _ = pointcloud2_to_xyz(msg)
            origin, T_optical = self._sensor(msg.header.frame_id, header_stamp_s(msg.header))
            old, new = self.engine.frame_id.lstrip("/"), msg.header.frame_id.lstrip("/")
            if old and new and old != new:  # only for a cloud that is used
                self._change_frame(old, new, header_stamp_s(msg.header))
            self.engine.set_scene(
                pts, frame_id=msg.header.frame_id, sensor_origin=origin, T_scene_optical=T_optical
            )
        except AffordanceError as exc:
            if not self.engine.has_scene:
                raise AffordanceError(
                    f"the cloud in '{msg.header.frame_id}' is unusable: {exc}"
                ) from None
            self._error(
                "cloud", f"the latest cloud is unusable ({exc}); still using the previous one"
            )

    def _change_frame(self, old: str, new: str, stamp: float | None) -> None:
        """The cloud's frame changed (stream worker): what the engine holds is re-expressed in
        the new frame through TF, or the open objects are closed when no transform is known --
        never left in the old frame's numbers under the new frame's name."""
        try:
            T_new_old = self._lookup(new, old, stamp)
        except FrameError:
            self._error(
                "frame",
                self.engine.close_open_objects(
                    f"the cloud's frame changed from '{bounded(old)}' to '{bounded(new)}' and no "
                    f"transform between them is known"
                ),
            )
            return
        self.report("frame", True, self.engine.reexpress(T_new_old, new))

    def _sensor(self, cloud_frame: str, stamp: float | None = None):
        """(sensor origin or "none", the sensor's optical pose 4x4) in ``cloud_frame``: from the
        ``sensor_frame`` parameter through TF, or the ``sensor_origin`` parameter; the pose is
        the default view for twists."""
        name = self._p["sensor_frame"].strip()
        if name.lower() == NO_VIEWPOINT:
            return NO_VIEWPOINT, T_frame_optical(cloud_frame)
        if not name:
            T = T_frame_optical(cloud_frame)
            T[:3, 3] = self._p["sensor_origin"]
            return list(self._p["sensor_origin"]), T
        try:
            T_cloud_sensor = self._lookup(cloud_frame, name, stamp)
        except FrameError:
            raise AffordanceError(
                f"the sensor frame '{name}' has no known transform to the "
                f"cloud frame '{cloud_frame}' (publish it on TF, or give it "
                f"in static_transforms)"
            ) from None
        return T_cloud_sensor[:3, 3].copy(), T_cloud_sensor @ T_frame_optical(name)

    def _on_click(self, msg: PointStamped) -> None:
        if len(msg.header.frame_id) > MAX_NAME:
            self._error(
                "click",
                f"click refused: its frame id has "
                f"{len(msg.header.frame_id):,} characters (at most {MAX_NAME})",
            )
            return
        p = np.array([msg.point.x, msg.point.y, msg.point.z], dtype=float)
        self.stream.click(
            p,
            msg.header.frame_id,
            source=self._sub_click.topic_name,
            stamp=header_stamp_s(msg.header),
        )
        self.changed()  # the status shows what is queued

    def _on_twist(self, msg, info=None) -> None:
        """A Twist (held for the time since the previous one by the publisher's source time
        stamps) or a TwistStamped (by its header stamps)."""
        stamp = source_stamp_s(info)
        if isinstance(msg, TwistStamped):
            header_stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            stamp, msg = (header_stamp if header_stamp > 0 else stamp), msg.twist
        self.stream.twist(
            [msg.linear.x, msg.linear.y, msg.linear.z],
            [msg.angular.x, msg.angular.y, msg.angular.z],
            stamp=stamp,
            source=self._sub_twist.topic_name,
        )
        self.changed()

    def _on_joy(self, msg: Joy) -> None:
        self.stream.joy(msg.buttons, msg.axes, source=self._sub_joy.topic_name)
        self.changed()

    def _on_view(self, msg: PoseStamped) -> None:
        try:
            T = pose_to_matrix(msg.pose)
            T = (
                self._lookup(
                    self.frame() or msg.header.frame_id,
                    msg.header.frame_id,
                    header_stamp_s(msg.header),
                )
                @ T
            )
        except AffordanceError as exc:
            self._error("view", f"view_pose ignored: {exc}")
            return
        self.stream.view(view_from_optical(T), source=self._sub_view.topic_name)
        self.changed()

    def _on_select(self, msg: String) -> None:
        if len(msg.data) > MAX_NAME:
            self._error(
                "select_model",
                f"select model refused: the name has "
                f"{len(msg.data):,} characters (at most {MAX_NAME})",
            )
            return
        self.stream.action("select_model", msg.data.strip(), source=self._sub_select.topic_name)
        self.changed()

    def _on_dimension(self, msg: String) -> None:
        """``~/set_dimension``: "NAME=VALUE" sets the shown primitive's dimension (m), "NAME+"
        / "NAME-" steps it by ``dimension_step_mm``; then the pose is refit with it held."""
        try:
            argument = parse_dimension(msg.data)
        except AffordanceError as exc:
            self._error("dimension", f"~/set_dimension: {exc}")
            return
        self.stream.action("dimension", argument, source=self._sub_dimension.topic_name)
        self.changed()

    def _service(self, action: str):
        """A service answered once the stream has handled its action. rclpy resumes a waiting
        callback only when its executor goes round, so the reply wakes it."""

        async def callback(request, response):
            done = Future(executor=self.executor)
            executor = self.executor

            def reply(ok, message):
                done.set_result((ok, message))
                executor.wake()

            self.stream.action(action, source=f"~/{action}", reply=reply)
            self.changed()
            response.success, response.message = await done
            return response

        return callback

    def _check_name(self) -> None:
        """Warn once if another node of this name runs in this namespace (both would serve
        the same services and topics); looked at for the first 10 s, as discovery completes."""
        self._name_checks += 1
        ns, name = self.get_namespace(), self.get_name()
        twins = sum(1 for n, s in self.get_node_names_and_namespaces() if (n, s) == (name, ns))
        if twins > 1:
            self.get_logger().warning(
                f"another node named {self.get_fully_qualified_name()} is running: both serve "
                f"its services and topics and either may answer; give one another name "
                f"(--ros-args -r __node:=NAME) or namespace"
            )
        if twins > 1 or self._name_checks >= 10:
            self._name_timer.cancel()

    # ------------------------------------------------------------------ the marker server's host
    def active_object(self):
        return self.engine.active_object()

    def view_pose(self) -> np.ndarray:
        return self.engine.view_pose()

    def template(self, name: str):
        return self.library[name]

    def marker_pose(self, T_scene_model: np.ndarray, release: bool, object_id: int | None) -> None:
        self.stream.pose(T_scene_model, release, source="marker_feedback", target=object_id)

    def marker_action(self, name: str, argument) -> None:
        self.stream.action(name, argument, source="marker_feedback")

    def marker_cancel(self, object_id: int | None) -> None:
        self.stream.cancel_drag(object_id, source="marker_feedback")

    def warn(self, text: str) -> None:
        self.get_logger().warning(text)

    # ------------------------------------------------------------------ the stream's host, output
    def busy(self, text: str | None) -> None:
        """A long step started: the status says so at once."""
        self.pub_status.publish(String(data=json.dumps(self.status())))

    def report(self, kind: str, ok: bool, message: str, benign: bool = False) -> None:
        """An outcome of the stream: successes are logged as info; failures as errors, or as
        warnings throttled per kind for inputs that come in streams; a ``benign`` refusal (the
        action does not apply now: nothing selected, nothing to undo) as a warning."""
        message = bounded(message, MAX_MESSAGE)
        if ok:
            self._last_message = message
            self.get_logger().info(message)
        else:
            self._error(
                kind,
                f"{kind.replace('_', ' ')}: {message}" if kind in ACTIONS else message,
                benign,
            )

    def _error(self, kind: str, msg: str, benign: bool = False) -> None:
        """Log an error; a ``benign`` refusal as a warning; for inputs that come in streams
        (``STREAMED`` kinds), at most one line per kind every THROTTLE_S, as a warning."""
        msg = bounded(msg, MAX_MESSAGE)
        self._last_error = msg
        self.changed()
        if benign:
            self.get_logger().warning(msg)
        elif kind in STREAMED:
            if self._warnings.due(kind):
                self.get_logger().warning(msg)
        else:
            self.get_logger().error(msg)

    def changed(self) -> None:
        """Something the status, markers or TF show changed (from any thread): publish it at
        once, at most ``publish_rate`` times a second -- the guard condition wakes the
        executor, nothing polls."""
        self._dirty = True
        self._publish_guard.trigger()

    def _on_publish(self) -> None:
        if not self._dirty:
            return
        wait = 1.0 / self._p["publish_rate"] - (time.monotonic() - self._last_publish)
        if wait > 0:  # too soon after the last one: once the period is over
            if self._publish_later is None:
                self._publish_later = self.create_timer(wait, self._on_publish_later)
            return
        self._dirty = False
        self._last_publish = time.monotonic()
        self.publish_all()

    def _on_publish_later(self) -> None:
        timer, self._publish_later = self._publish_later, None
        if timer is not None:
            self.destroy_timer(timer)
        self._on_publish()

    def status(self) -> dict:
        st = self.engine.status()
        stream = self.stream.status()
        with self._lock:
            msg = self._cloud_msg
            # every input topic from the start (a paced player waits for the topics it finds
            # here); clouds are stored when they arrive: received is handled
            handled = {sub.topic_name: 0 for sub in self._input_subscriptions}
            handled.update(stream["handled"])
            handled[self._sub_points.topic_name] = self._cloud_count
            st["node"] = {
                "busy": stream["busy"],
                "queued": stream["queued"],
                "idle": stream["idle"],
                "pending_refit": stream["pending_refit"],
                "received": stream["received"],
                "handled": handled,
                "cloud": None
                if msg is None
                else {
                    "frame_id": msg.header.frame_id,
                    "width": msg.width,
                    "height": msg.height,
                    "received": self._cloud_count,
                },
                "last_message": self._last_message,
                "last_error": self._last_error,
                "registrations_file": {
                    "path": self._store.path,
                    "saved": self._store.count,
                    "unsaved": self._unsaved,
                    "backup": self._store.last_backup,
                },
            }
        return st

    def publish_all(self) -> None:
        frame = self.frame()
        stamp = self.get_clock().now().to_msg()
        state = self.engine.state
        up = self.engine.view_pose()[:3, 1]  # labels go below the objects on the screen
        active = self.engine.active_object()
        if active is not None:
            self.pub_fit.publish(pose_stamped(active.shown.T_scene_model, frame, stamp))
            if active.suggested_view is not None:
                self.pub_view.publish(
                    pose_stamped(active.suggested_view.T_scene_optical, frame, stamp)
                )
        arr = PoseArray()
        arr.header.frame_id, arr.header.stamp = frame, stamp
        arr.poses = [matrix_to_pose(r.T_scene_model) for r in state.registered]
        self.pub_registered.publish(arr)
        self._tf_out.publish_registrations(state.registered, frame, stamp, self.library)
        self._tf_out.publish_candidate(
            None if active is None else active.shown, frame, stamp, self.library
        )
        # the status before the markers: it is small, and a client showing it (the station's
        # label) need not wait for the meshes to be built, sent and read
        self.pub_status.publish(String(data=json.dumps(self.status())))
        # the markers draw the engine's state (immutable: a change is a new state) with the
        # library in the frame and the view: a change of the queue or the node alone, as a
        # click's while its fit runs, leaves them as they are
        drawn = (state, self.library, frame, tuple(np.round(up, 9)))
        last = self._markers_of
        if last[0] is not state or last[1] is not self.library or last[2:] != drawn[2:]:
            self.pub_markers.publish(
                state_markers(state, self.library, frame, stamp, up, self._drawn)
            )
            self._markers_of = drawn
        self.interactive.sync()

    def shutdown(self) -> None:
        self._stop.set()
        self._worker.join(timeout=1.0)
        if self._unsaved:  # autosave off: what was accepted is not lost either
            try:
                self.get_logger().info(self.persist(True) + " (at shutdown)")
            except AffordanceError as exc:
                self.get_logger().error(f"registrations NOT saved at shutdown: {exc}")


def main(args=None) -> int:
    """Console script ``affordance_engine`` (takes ``--ros-args``)."""
    return run_node(EngineNode, "affordance_engine", args, shutdown=lambda node: node.shutdown())


if __name__ == "__main__":
    raise SystemExit(main())
