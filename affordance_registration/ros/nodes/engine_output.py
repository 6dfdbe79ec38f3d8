# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What the engine node publishes, from one outbox.

The operator stream, its scene feed and the node's own callbacks put what came of each input
and that something changed into the :class:`~affordance_registration.core.inputs.Outbox`;
its ``wake`` triggers a guard condition, and :class:`EngineOutput` drains it in the executor
thread: every outcome is logged (successes as info, failures as errors, or as warnings
throttled per kind for inputs that come in streams) and then, at most ``publish_rate`` times a
second (a change that comes too soon goes out once the period is over: nothing polls),
``~/status``, ``~/fit``, ``~/suggested_view``, ``~/registered``, TF, the registrations as
MoveIt collision objects (``collision_object``), the open objects as vision_msgs detections
(``~/detections``), ``~/markers`` and the interactive markers are published from the engine's
state (:mod:`~affordance_registration.ros.glue.planning`).
"""

from __future__ import annotations

import json
import time

import numpy as np
from geometry_msgs.msg import PoseArray, PoseStamped
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from ...core.detections import Detections
from ...core.errors import bounded
from ..glue.conversions import matrix_to_pose, pose_stamped
from ..glue.markers import registered_markers_memo, state_markers
from ..glue.planning import CollisionObjects, detection_array, load_detection_array
from ..glue.qos import LATCHED
from ..glue.tf import TfBroadcaster
from ..glue.throttle import Throttle

__all__ = ["EngineOutput", "STREAMED", "THROTTLE_S", "MAX_MESSAGE"]

#: inputs whose errors repeat with a stream of bad messages: logged as throttled warnings
STREAMED = ("twist", "joy", "view", "pose", "cloud", "queue", "select_model", "click", "path")
THROTTLE_S = 2.0
#: the longest log line / status message the node writes about one input
MAX_MESSAGE = 2000


class EngineOutput:
    """The engine node's publishers and what they publish (see the module docstring).

    Given the ``node`` (to make publishers, log and stamp), the ``engine``, its ``stream``, the
    ``clouds`` slot, the registrations' ``saver``, the input topics (counted in the status from
    the start) and the interactive-marker server to keep in sync (None: set it later, before
    the executor spins); its guard condition becomes the wake of the stream's outbox.
    ``publish_rate`` (Hz) and ``collisions.enabled`` (``collision_objects``) may be changed at
    any time."""

    def __init__(
        self,
        node,
        engine,
        stream,
        clouds,
        saver,
        inputs,
        interactive,
        publish_rate,
        collision_objects: bool = True,
    ):
        self._node, self.engine, self.stream = node, engine, stream
        self.clouds, self.saver, self.interactive = clouds, saver, interactive
        self.outbox = stream.outbox
        self.publish_rate = float(publish_rate)
        self._inputs = tuple(inputs)
        self._log = node.get_logger()
        self._warnings = Throttle(THROTTLE_S)
        self._last_error = ""
        self._last_message = ""
        self._dirty = True
        self._last_publish = 0.0
        self._publish_later = None  # the one-shot timer of a change that came too soon
        self._drawn = registered_markers_memo()  # each registration's markers, made once
        #: what ~/markers last drew: (state, library, frame, view up)
        self._markers_of: tuple = (None, None, None, None)
        self.tf = TfBroadcaster(node)
        self.collisions = CollisionObjects(node, collision_objects)
        self._detection_classes = load_detection_array()
        self._detections = Detections()
        self.pub_detections = None
        if self._detection_classes is None:
            self._log.warning(
                "vision_msgs is not installed: open objects are not published as detections "
                "(make setup builds it into the venv)"
            )
        else:
            self.pub_detections = node.create_publisher(
                self._detection_classes[0], "~/detections", 10
            )
        self.pub_markers = node.create_publisher(MarkerArray, "~/markers", LATCHED)
        self.pub_fit = node.create_publisher(PoseStamped, "~/fit", 10)
        self.pub_registered = node.create_publisher(PoseArray, "~/registered", LATCHED)
        self.pub_status = node.create_publisher(String, "~/status", LATCHED)
        #: where the sensor should look from to settle the selected object (optical frame)
        self.pub_view = node.create_publisher(PoseStamped, "~/suggested_view", LATCHED)
        self.guard = node.create_guard_condition(self.on_wake)
        self.outbox.connect(self.guard.trigger)

    # ------------------------------------------------------------------ the outbox
    def on_wake(self) -> None:
        drained = self.outbox.drain()
        for outcome in drained.outcomes:
            self._say(outcome.kind, outcome.ok, outcome.message, outcome.benign)
        if drained.busy:  # a long step started: the status says so at once
            self.pub_status.publish(String(data=json.dumps(self.status())))
        self._dirty |= drained.changed or bool(drained.outcomes)
        self._publish_when_due()

    def _say(self, kind: str, ok: bool, message: str, benign: bool = False) -> None:
        """Log an outcome: a success as info; a failure as an error -- a ``benign`` one (the
        action does not apply now: nothing selected, nothing to undo) as a warning, and for
        inputs that come in streams (``STREAMED`` kinds) at most one line per kind every
        THROTTLE_S, as a warning."""
        message = bounded(message, MAX_MESSAGE)
        if ok:
            self._last_message = message
            self._log.info(message)
            return
        self._last_error = message
        if benign:
            self._log.warning(message)
        elif kind in STREAMED:
            if self._warnings.due(kind):
                self._log.warning(message)
        else:
            self._log.error(message)

    def _publish_when_due(self) -> None:
        if not self._dirty:
            return
        wait = 1.0 / self.publish_rate - (time.monotonic() - self._last_publish)
        if wait > 0:  # too soon after the last one: once the period is over
            if self._publish_later is None:
                self._publish_later = self._node.create_timer(wait, self._on_publish_later)
            return
        self._dirty = False
        self._last_publish = time.monotonic()
        self.publish_all()

    def _on_publish_later(self) -> None:
        timer, self._publish_later = self._publish_later, None
        if timer is not None:
            self._node.destroy_timer(timer)
        self._publish_when_due()

    # ------------------------------------------------------------------ what is published
    def frame(self) -> str:
        """The frame of everything the node reports: the scene's, else the frame the next scene
        will be in (the fixed frame, else the latest cloud's)."""
        if self.engine.frame_id:
            return self.engine.frame_id
        if self.stream.feed.fixed_frame:
            return self.stream.feed.fixed_frame
        cloud, _ = self.clouds.latest()
        return cloud.frame if cloud is not None else ""

    def status(self) -> dict:
        st = self.engine.status()
        # before the first scene, the fixed frame it will be in (the station draws the cloud there)
        st["frame_id"] = st["frame_id"] or self.stream.feed.fixed_frame
        stream = self.stream.status()
        cloud, count = self.clouds.latest()
        # every input topic from the start (a paced player waits for the topics it finds
        # here); clouds are stored when they arrive: received is handled
        handled = {topic: 0 for topic in self._inputs}
        handled.update(stream["handled"])
        handled[self.clouds.source] = count
        st["node"] = {
            "busy": stream["busy"],
            "queued": stream["queued"],
            "idle": stream["idle"],
            "pending_refit": stream["pending_refit"],
            "views_due": stream["views_due"],
            "received": stream["received"],
            "handled": handled,
            "cloud": None
            if cloud is None
            else {
                "frame_id": cloud.frame,
                "width": cloud.width,
                "height": cloud.height,
                "received": count,
            },
            "last_message": self._last_message,
            "last_error": self._last_error,
            "registrations_file": self.saver.status(),
        }
        return st

    def publish_all(self) -> None:
        frame = self.frame()
        stamp = self._node.get_clock().now().to_msg()
        state = self.engine.state
        library = self.engine.library
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
        self.tf.publish_registrations(state.registered, frame, stamp, library)
        self.tf.publish_candidate(None if active is None else active.shown, frame, stamp, library)
        self.collisions.publish(state.registered, frame, stamp, library)
        # the status before the markers: it is small, and a client showing it (the station's
        # label) need not wait for the meshes to be built, sent and read
        self.pub_status.publish(String(data=json.dumps(self.status())))
        # the markers draw the engine's state (immutable: a change is a new state) with the
        # library in the frame and the view: a change of the queue or the node alone, as a
        # click's while its fit runs, leaves them as they are
        drawn = (state, library, frame, tuple(np.round(up, 9)))
        last = self._markers_of
        if last[0] is not state or last[1] is not library or last[2:] != drawn[2:]:
            self.pub_markers.publish(state_markers(state, library, frame, stamp, up, self._drawn))
            if self.pub_detections is not None and (last[0] is not state or last[2] != frame):
                self.pub_detections.publish(
                    detection_array(
                        self._detection_classes, self._detections.of(self.engine), frame, stamp
                    )
                )
            self._markers_of = drawn
        if self.interactive is not None:
            self.interactive.sync()
        self.outbox.published()  # (the stream waits for this before a suggested view)
