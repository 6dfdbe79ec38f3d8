# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ``affordance_engine`` node: clouds, clicks, SpaceMouse twists/buttons, view poses, marker
feedback and service calls in; ranked fit markers, poses and status out. Convert, hand to the
core, publish.

**Convert**: :class:`EngineNode` turns each message into an input of the core's
:class:`~affordance_registration.core.operator.OperatorStream` (a cloud into a
:class:`~affordance_registration.core.inputs.Cloud` in the latest-cloud slot: stored on arrival,
its points read only when a fit needs them, so a 1M-point 30 Hz camera cannot starve the node).
**Core**: the stream handles every input in arrival order on one worker thread (so an action
right after a click acts on that click's object however long the fit takes); it is given what it
needs -- a scene feed with the latest cloud and TF's lookup, the registrations file -- and never
calls back into the node. **Publish**: what came of each input goes into one outbox, which
:class:`~affordance_registration.ros.nodes.engine_output.EngineOutput` drains and publishes in
the executor thread. Service calls are answered when the stream has handled them (async
callbacks: the executor is never blocked). The interactive-marker server reads the engine and
sends its feedback into the stream through :class:`MarkerBridge`.
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np
from geometry_msgs.msg import PointStamped, PoseStamped, Twist, TwistStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import Joy, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ...core.corrections import view_from_optical
from ...core.engine import AffordanceEngine
from ...core.errors import AffordanceError, bounded
from ...core.inputs import Cloud, LatestCloud, Outbox
from ...core.operator import OperatorStream
from ...core.persistence import Autosave, RegistrationStore
from ...core.scene_feed import SceneFeed, Sensor
from ...core.templates import TemplateLibrary
from ..glue import params, qos
from ..glue.conversions import (
    ConversionError,
    header_stamp_s,
    parse_dimension,
    pointcloud2_layout,
    pointcloud2_to_xyz,
    pose_to_matrix,
    source_stamp_s,
)
from ..glue.frames import StaticFrames
from ..glue.paths import PathRequests
from ..glue.qos import INPUT as INPUT_QOS
from ..glue.qos import SERVICES as SERVICE_QOS
from ..glue.tf import TfListener
from ..standins.interactive import CorrectionMarkerServer
from ..standins.spin import run_node
from .engine_output import EngineOutput

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
#: how often a drag whose client fell silent is looked for (s)
DRAG_WATCH_S = 0.5
#: the longest frame id, template name or other name taken from a message (longer: refused)
MAX_NAME = 256


class EngineNode(Node):
    """The engine node: its parameters, and its subscriptions and services converting messages
    into inputs of the operator stream (see the module docstring)."""

    def __init__(self, **kwargs):
        super().__init__("affordance_engine", **kwargs)
        self._p = params.declare(self)
        for line in params.unknown_overrides(self._parameter_overrides):
            self.get_logger().warning(line)
        self.library = TemplateLibrary.load(self._p["templates_dir"] or None)
        self.engine = AffordanceEngine(self.library, params.fit_settings(self._p))
        self.saver = Autosave(
            RegistrationStore(
                params.registrations_path(self._p["registrations_file"]),
                holder=f"the engine {self.get_fully_qualified_name()}",
            ),
            self._p["autosave"],
        )
        self._resume()
        self._tf = TfListener(self, StaticFrames(self._p["static_transforms"]))
        self.outbox = Outbox()
        cloud_qos = qos.cloud(self._p["points_reliable"])
        self._sub_points = self.create_subscription(
            PointCloud2, "points", self._on_cloud, cloud_qos
        )
        self.clouds = LatestCloud(self._sub_points.topic_name)
        self._cloud_status_at = 0.0
        self.feed = SceneFeed(
            self.clouds,
            self._tf.lookup,
            self._sensor(self._p),
            self.outbox,
            fixed_frame=self._p["fixed_frame"],
        )
        self.stream = OperatorStream(
            self.engine,
            params.operator_settings(self._p),
            feed=self.feed,
            outbox=self.outbox,
            saver=self.saver,
        )
        self._stop = threading.Event()

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
        inputs = (
            self._sub_click,
            self._sub_twist,
            self._sub_joy,
            self._sub_view,
            self._sub_select,
            self._sub_dimension,
        )
        self.output = EngineOutput(
            self,
            self.engine,
            self.stream,
            self.clouds,
            self.saver,
            [sub.topic_name for sub in inputs],
            None,
            self._p["publish_rate"],
            self._p["collision_objects"],
        )
        self.paths = PathRequests(self, self.engine, self.outbox, self.output.frame)
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
            MarkerBridge(self.engine, self.stream, self.output.frame, self.get_logger()),
            self._p["interactive_namespace"],
            self._p["interactive_orientation"],
            server_id=self.get_fully_qualified_name(),
        )
        self.interactive.attach(self)
        self.output.interactive = self.interactive
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # a silent drag is cancelled, not left hanging (a watchdog: publishing does not poll)
        self.create_timer(DRAG_WATCH_S, self.interactive.expire)
        self._name_checks = 0
        self._name_timer = self.create_timer(1.0, self._check_name)
        self._worker = threading.Thread(
            target=self.stream.run, args=(self._stop,), name="operator-stream", daemon=True
        )
        self._worker.start()
        self.outbox.changed()  # the first status goes out once the executor spins
        self.get_logger().info(
            f"ready: {len(self.library)} templates "
            f"({', '.join(self.library)}); waiting for 'points' and clicks"
        )

    # ------------------------------------------------------------------ registrations file
    def _resume(self) -> None:
        """Resume the session from ``registrations_file`` (unless ``resume`` is off). A file
        that is not a registrations file stops the start with one line: it is never replaced
        unread."""
        store = self.saver.store
        path = store.path
        if not self._p["resume"]:
            if os.path.lexists(path):
                self.get_logger().info(
                    f"fresh session (resume is off): {path} is kept as a "
                    f"backup when it is first replaced"
                )
            return
        try:
            regs = store.resume(self.library)
        except AffordanceError as exc:
            raise AffordanceError(
                f"cannot resume the session: {exc} (fix or move the file, or "
                f"start a fresh session with resume:=false: the file is then "
                f"kept as a backup)"
            ) from None
        self.engine.resume(regs)
        if regs:
            self.get_logger().info(f"resumed {len(regs)} registration(s) from {path}")

    # ------------------------------------------------------------------ parameters
    @staticmethod
    def _sensor(p: dict) -> Sensor:
        return Sensor(p["sensor_frame"], tuple(float(v) for v in p["sensor_origin"]))

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
            self._tf.static = StaticFrames(new["static_transforms"])
        self.saver.enabled = bool(new["autosave"])
        if changed & {"sensor_frame", "sensor_origin", "static_transforms", "fixed_frame"}:
            # the next fit makes the scene from the latest cloud again
            self.feed.configure(self._sensor(new), new["fixed_frame"], again=True)
        self.stream.configure(params.operator_settings(new))
        if "interactive_orientation" in changed:
            self.interactive.orientation = new["interactive_orientation"]
        self.output.publish_rate = float(new["publish_rate"])
        self.output.collisions.enabled = bool(new["collision_objects"])
        self._p = new
        self.outbox.changed()
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ inputs
    def _refuse(self, kind: str, message: str) -> None:
        """A message that cannot become an input: one line (through the outbox)."""
        self.outbox.outcome(kind, False, message)

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
            self.clouds.refuse(f"the last PointCloud2 (frame '{frame}') was dropped: {exc}")
            self._refuse("cloud", f"dropped a PointCloud2 in '{frame}': {exc}")
            return
        cloud = Cloud(
            msg.header.frame_id,
            header_stamp_s(msg.header),
            lambda: pointcloud2_to_xyz(msg)[0],
            msg.width,
            msg.height,
        )
        prev = self.clouds.put(cloud)
        now = time.monotonic()
        if prev is None or (prev.width, prev.height, prev.frame) != (
            cloud.width,
            cloud.height,
            cloud.frame,
        ):
            self.get_logger().info(f"cloud: {msg.width}x{msg.height} in '{msg.header.frame_id}'")
            self._cloud_status_at = now
            self.outbox.changed()
        elif now - self._cloud_status_at >= 1.0:  # the status counts clouds at most at 1 Hz
            self._cloud_status_at = now
            self.outbox.changed()
        self.stream.new_cloud()

    def _on_click(self, msg: PointStamped) -> None:
        if len(msg.header.frame_id) > MAX_NAME:
            self._refuse(
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
        self.outbox.changed()  # the status shows what is queued

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
        self.outbox.changed()

    def _on_joy(self, msg: Joy) -> None:
        self.stream.joy(msg.buttons, msg.axes, source=self._sub_joy.topic_name)
        self.outbox.changed()

    def _on_view(self, msg: PoseStamped) -> None:
        try:
            T = pose_to_matrix(msg.pose)
            T = (
                self._tf.lookup(
                    self.output.frame() or msg.header.frame_id,
                    msg.header.frame_id,
                    header_stamp_s(msg.header),
                )
                @ T
            )
        except AffordanceError as exc:
            self._refuse("view", f"view_pose ignored: {exc}")
            return
        self.stream.view(view_from_optical(T), source=self._sub_view.topic_name)
        self.outbox.changed()

    def _on_select(self, msg: String) -> None:
        if len(msg.data) > MAX_NAME:
            self._refuse(
                "select_model",
                f"select model refused: the name has "
                f"{len(msg.data):,} characters (at most {MAX_NAME})",
            )
            return
        self.stream.action("select_model", msg.data.strip(), source=self._sub_select.topic_name)
        self.outbox.changed()

    def _on_dimension(self, msg: String) -> None:
        """``~/set_dimension``: "NAME=VALUE" sets the shown primitive's dimension (m), "NAME+"
        / "NAME-" steps it by ``dimension_step_mm``; then the pose is refit with it held."""
        try:
            argument = parse_dimension(msg.data)
        except AffordanceError as exc:
            self._refuse("dimension", f"~/set_dimension: {exc}")
            return
        self.stream.action("dimension", argument, source=self._sub_dimension.topic_name)
        self.outbox.changed()

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
            self.outbox.changed()
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

    def shutdown(self) -> None:
        self._stop.set()
        self._worker.join(timeout=1.0)
        if self.saver.unsaved:  # autosave off: what was accepted is not lost either
            try:
                self.get_logger().info(self.saver.persist(self.engine, True) + " (at shutdown)")
            except AffordanceError as exc:
                self.get_logger().error(f"registrations NOT saved at shutdown: {exc}")
        self.saver.store.close()  # the file's lock, for the next engine


class MarkerBridge:
    """The interactive-marker server's host (a
    :class:`~affordance_registration.ros.standins.interactive.MarkerHost`): what is shown, read
    from the ``engine``; the operator's drags and menu entries, sent into the ``stream``;
    ``frame()``: the frame the markers are in."""

    def __init__(self, engine, stream, frame, logger):
        self.engine, self.stream, self.frame, self._log = engine, stream, frame, logger

    def active_object(self):
        return self.engine.active_object()

    def view_pose(self) -> np.ndarray:
        return self.engine.view_pose()

    def template(self, name: str):
        return self.engine.library[name]

    def marker_pose(self, T_scene_model: np.ndarray, release: bool, object_id: int | None) -> None:
        self.stream.pose(T_scene_model, release, source="marker_feedback", target=object_id)

    def marker_action(self, name: str, argument) -> None:
        self.stream.action(name, argument, source="marker_feedback")

    def marker_cancel(self, object_id: int | None) -> None:
        self.stream.cancel_drag(object_id, source="marker_feedback")

    def warn(self, text: str) -> None:
        self._log.warning(text)


def main(args=None) -> int:
    """Console script ``affordance_engine`` (takes ``--ros-args``)."""
    return run_node(EngineNode, "affordance_engine", args, shutdown=lambda node: node.shutdown())


if __name__ == "__main__":
    raise SystemExit(main())
