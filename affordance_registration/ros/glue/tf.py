# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""TF for the engine node: registrations and the shown candidate out, frame lookups in.

Out (``TfBroadcaster``): every registration is a frame ``<template>_<id>`` (``ball_valve_1``) on
``/tf_static``, parent the frame it was registered in (the cloud's); the shown candidate of the
selected object is ``affordance_candidate`` on ``/tf``. Each of their waypoints is a frame
``<object frame>/<waypoint>`` (``ball_valve_1/lever_grasp``, ``affordance_candidate/push``), and
its approach pose ``<object frame>/pre_<waypoint>``, parent the object's frame, at the joint
value the object has -- on ``/tf_static`` with a registration, on ``/tf`` with the candidate.
The static set goes out whole whenever it changes, as one TFMessage on a reliable,
transient-local publisher of depth 1 (what tf2_ros' static broadcaster does), so a late listener
gets exactly the current set: a frame undone, discarded or replaced by a load is gone from it.
(tf2_ros' StaticTransformBroadcaster is not used even where it is installed: it only ever adds
or replaces frames, so it could not drop an undone one. Note that a tf2 buffer already holding a
static frame keeps it until it restarts: tf2 has no way to retract a static transform.)

In (``TfListener``): frame lookups for clicks, view poses and the sensor frame, at the stamp of
the message that needs them. In a ROS install with tf2_ros, its Buffer and TransformListener; in
the pip-only install, a :class:`~affordance_registration.ros.glue.frames.TransformBuffer`: every
transform heard on ``/tf`` kept in time order per child frame for ``TF_CACHE_S`` (10 s), those on
``/tf_static`` for ever, looked up at a stamp (interpolated between two transforms), chains
followed both ways. An out-of-order old transform never replaces a newer one for current
lookups. Either way the ``static_transforms`` parameter is the fallback for what TF does not
know.

Without tf2_msgs (the pip-only install whose ``make setup`` could not build it) there is no TF
output and lookups use the parameter alone; the node says so once at start and runs.
"""

from __future__ import annotations

import threading

import numpy as np
from geometry_msgs.msg import TransformStamped

from ...core.memo import PerRecord
from ...core.transforms import invert
from ...core.waypoints import waypoint_poses
from .conversions import ConversionError, matrix_to_transform, transform_to_matrix
from .frames import TF_CACHE_S, FrameError, FrameGraph, FrameNotYet, TransformBuffer
from .qos import INPUT, LATCHED, latched

__all__ = [
    "CANDIDATE_FRAME",
    "TfBroadcaster",
    "TfListener",
    "registration_frame",
    "load_tf_message",
    "waypoint_frames",
]

CANDIDATE_FRAME = "affordance_candidate"
CANDIDATE_REPUBLISH_S = 1.0  # the candidate frame stays fresh for /tf listeners
# the QoS of tf2_ros' broadcasters and listeners (tf2_ros/qos.py)
STATIC_BROADCASTER_QOS = LATCHED
STATIC_LISTENER_QOS = latched(100)
DYNAMIC_QOS = INPUT


def registration_frame(template: str, registration_id: int) -> str:
    """The TF frame of a registration: ``<template>_<id>``."""
    return f"{template}_{registration_id}"


def waypoint_frames(library, fit, object_frame: str) -> list:
    """(child frame, T_object_child) of each waypoint of ``fit`` (a Registration or FitResult)
    and of its approach pose: ``<object_frame>/<name>``, ``<object_frame>/pre_<name>``."""
    if library is None or fit.template not in library:
        return []
    T_object_scene = invert(np.asarray(fit.T_scene_model, dtype=float))
    out = []
    for wp in waypoint_poses(library[fit.template], fit):
        out.append((f"{object_frame}/{wp.name}", T_object_scene @ wp.T))
        if wp.T_pre is not None:
            out.append((f"{object_frame}/pre_{wp.name}", T_object_scene @ wp.T_pre))
    return out


def load_tf_message():
    """tf2_msgs' TFMessage class, or None where tf2_msgs is not installed."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


def _transform(parent: str, child: str, T_parent_child: np.ndarray, stamp) -> TransformStamped:
    t = TransformStamped()
    t.header.frame_id, t.header.stamp, t.child_frame_id = parent, stamp, child
    t.transform = matrix_to_transform(T_parent_child)
    return t


def _registration_frames(reg, parent_frame: str, library) -> list:
    """(parent, child, T_parent_child) of a registration's frame and its waypoints' (none where
    it has no parent frame)."""
    parent = (reg.frame_id or parent_frame).lstrip("/")
    if not parent:
        return []
    child = registration_frame(reg.template, reg.id)
    return [(parent, child, np.asarray(reg.T_scene_model, dtype=float))] + [
        (child, name, T) for name, T in waypoint_frames(library, reg, child)
    ]


class TfBroadcaster:
    """Registrations on /tf_static and the shown candidate on /tf (see the module docstring).
    Without tf2_msgs every call is a no-op and ``available`` is False."""

    def __init__(self, node):
        self._node = node
        TFMessage = load_tf_message()
        self.available = TFMessage is not None
        self._static_key: tuple = ()
        self._static: dict[str, TransformStamped] = {}  # child -> transform as last sent
        self._candidate: list = []  # the candidate's transform and its waypoints'
        self._frames = PerRecord(_registration_frames)  # made once per registration

        if not self.available:
            node.get_logger().warning(
                "tf2_msgs is not installed: registrations are not "
                "published on TF (make setup builds it into the venv)"
            )
            return
        self._msg_type = TFMessage
        self._pub_static = node.create_publisher(TFMessage, "/tf_static", STATIC_BROADCASTER_QOS)
        self._pub_dynamic = node.create_publisher(TFMessage, "/tf", DYNAMIC_QOS)
        node.create_timer(CANDIDATE_REPUBLISH_S, self._republish_candidate)

    def publish_registrations(self, registered, parent_frame: str, stamp, library=None) -> bool:
        """Publish the full static set if it changed. ``registered``: records with ``template``,
        ``id``, ``T_scene_model`` (4x4, metres) and ``frame_id`` (the parent; ``parent_frame``
        where empty); with the template ``library``, their waypoints' frames too. A frame whose
        pose and parent did not change keeps its stamp. Returns whether a message went out."""
        if not self.available:
            return False
        frames = [f for fs in self._frames.values(registered, parent_frame, library) for f in fs]
        key = tuple((parent, child, T.tobytes()) for parent, child, T in frames)
        if key == self._static_key:
            return False
        previous = dict(zip((k[1] for k in self._static_key), self._static_key))
        transforms = {}
        for (parent, child, T), k in zip(frames, key):
            kept = self._static.get(child)
            transforms[child] = (
                kept
                if kept is not None and previous.get(child) == k
                else _transform(parent, child, T, stamp)
            )
        self._static, self._static_key = transforms, key
        self._pub_static.publish(self._msg_type(transforms=list(transforms.values())))
        return True

    def publish_candidate(self, candidate, parent_frame: str, stamp, library=None) -> None:
        """The shown candidate's frame (and, with the template ``library``, its waypoints') on
        /tf, republished every second while shown. ``candidate``: a FitResult, or None: no
        candidate is shown, so the frames stop being published."""
        if not self.available:
            return
        parent_frame = parent_frame.lstrip("/")
        if candidate is None or not parent_frame:
            self._candidate = []
            return
        self._candidate = [
            _transform(parent_frame, CANDIDATE_FRAME, candidate.T_scene_model, stamp)
        ]
        self._candidate += [
            _transform(CANDIDATE_FRAME, name, T, stamp)
            for name, T in waypoint_frames(library, candidate, CANDIDATE_FRAME)
        ]
        self._pub_dynamic.publish(self._msg_type(transforms=list(self._candidate)))

    def _republish_candidate(self) -> None:
        candidate = self._candidate
        if candidate:
            now = self._node.get_clock().now().to_msg()
            for t in candidate:
                t.header.stamp = now
            self._pub_dynamic.publish(self._msg_type(transforms=list(candidate)))


class TfListener:
    """``lookup(target, source, stamp)`` -> T_target_source (4x4) from tf2_ros where it is
    installed, else from the transforms heard on /tf and /tf_static; ``static`` (a FrameGraph:
    the static_transforms parameter, replaceable at any time) fills in what TF does not know."""

    def __init__(self, node, static: FrameGraph | None = None):
        self._lock = threading.Lock()
        self._frames = TransformBuffer()
        self._buffer = None
        self._bad_logged: set[str] = set()
        self._node = node
        self.static = static if static is not None else FrameGraph()
        try:
            import tf2_ros
        except ImportError:
            tf2_ros = None
        if tf2_ros is not None:
            self._buffer = tf2_ros.Buffer()
            self._tf2_listener = tf2_ros.TransformListener(self._buffer, node)
            return
        TFMessage = load_tf_message()
        if TFMessage is None:
            return
        node.create_subscription(TFMessage, "/tf", self._on_tf, DYNAMIC_QOS)
        node.create_subscription(
            TFMessage, "/tf_static", lambda msg: self._on_tf(msg, static=True), STATIC_LISTENER_QOS
        )

    def _on_tf(self, msg, static: bool = False) -> None:
        for t in msg.transforms:
            try:
                T = transform_to_matrix(t.transform)
            except ConversionError as exc:
                if t.child_frame_id not in self._bad_logged:  # once per frame
                    self._bad_logged.add(t.child_frame_id)
                    self._node.get_logger().warning(
                        f"ignored the transform of frame '{t.child_frame_id}' on TF: {exc}"
                    )
                continue
            stamp = t.header.stamp.sec + t.header.stamp.nanosec * 1e-9
            with self._lock:
                self._frames.set(t.header.frame_id, t.child_frame_id, T, stamp, static=static)

    def lookup(
        self, target: str, source: str, stamp: float | None = None, exact: bool = False
    ) -> np.ndarray:
        """T_target_source at ``stamp`` (s, a message's header stamp; None or 0: the latest).
        A stamp after the newest transform gets the newest -- or, with ``exact``, raises
        :class:`FrameNotYet` (the transform then is still on its way)."""
        target, source = target.lstrip("/"), source.lstrip("/")
        if not source or source == target:
            return np.eye(4)
        fallback = self.static
        if self._buffer is not None:
            return self._lookup_tf2(target, source, stamp, exact)
        behind: dict = {}
        with self._lock:
            graph = fallback.merged(self._frames.graph(stamp, exact, behind))
            try:
                return graph.lookup(target, source)
            except FrameError:
                if not (exact and stamp):
                    raise
                try:  # found with the newest transforms: not at the stamp
                    fallback.merged(self._frames.graph()).lookup(target, source)
                except FrameError:
                    raise
                if not behind:
                    raise FrameError(
                        f"TF has no transform from frame '{source}' to frame '{target}' at "
                        f"{stamp:.3f} s: older than it keeps ({TF_CACHE_S:g} s)"
                    ) from None
        raise FrameNotYet(
            f"TF reaches '{source}' from '{target}' only up to {max(behind.values()):.2f} s "
            f"before {stamp:.3f} s",
            behind=max(behind.values()),
        )

    def _lookup_tf2(self, target: str, source: str, stamp, exact: bool) -> np.ndarray:
        """The lookup through tf2_ros' buffer, ``static`` where it knows nothing."""
        from rclpy.time import Time

        at = Time(nanoseconds=int(stamp * 1e9)) if stamp else Time()
        try:
            try:
                tf = self._buffer.lookup_transform(target, source, at)
            except Exception as exc:
                if exact and "future" in str(exc):  # tf2's extrapolation into the future
                    raise FrameNotYet(f"TF has no transform at {stamp:.3f} s yet") from None
                if exact:
                    raise
                tf = self._buffer.lookup_transform(target, source, Time())  # the latest
            return transform_to_matrix(tf.transform)
        except FrameNotYet:
            raise
        except Exception:  # tf2 raises several lookup exceptions; fall back to the parameter
            return self.static.lookup(target, source)
