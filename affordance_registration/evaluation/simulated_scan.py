# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Node ``affordance_simulated_scan``: publishes a simulated depth-camera scan of a taskboard on
``points`` -- a sensor for trying the engine and the browser station without one
(``affordance-registration station --demo``) -- and moves that sensor where it is asked to.

The scan is the organized cloud of :func:`~affordance_registration.evaluation.simulation.
simulate_taskboard` (NaN where the sensor saw nothing) in ``frame_id``, published reliable and
transient-local, again whenever a subscriber joins (a volatile subscription, as the engine's and
the station's, only hears what is published after it matched), and every 1/``rate`` s when
``rate`` > 0. ``frame_id`` is the simulator's first camera (its optical frame) and stays where it
is: it is the fixed frame the clouds are in. Where the sensor is now is the frame
``sensor_frame``, published on ``/tf_static`` (parent ``frame_id``; the identity until the sensor
moves, or ``sensor_pose``), so an engine with ``sensor_frame`` set to it knows where each scan was
taken from.

A request on ``sensor_view_request`` (geometry_msgs/PoseStamped: an optical frame -- z forward,
x right, y down -- in ``frame_id``, as the engine's ``~/suggested_view`` and the station's "Move
sensor here" button give it) moves the sensor there: the scene is rendered again from that pose
(new sensor noise), the sensor's new pose goes out on ``/tf_static`` and, once its readers have
received it (at most :data:`ACK_TIMEOUT_S`), the new cloud on ``points``. A request that is not
a pose in ``frame_id``, that puts the sensor behind or inside the panel (less than
:data:`MIN_CLEARANCE_M` in front of it), farther than :data:`MAX_RANGE_M` from the panel's
centre, or from where the sensor would see fewer than :data:`MIN_POINTS` points of the
taskboard is refused with one log line; the sensor stays where it was. Requests that come
in a burst (or while a scan is being rendered) are not queued up: the latest is moved to, once
none came for :data:`MOVE_SETTLE_S` (a steady stream: every :data:`MOVE_LATEST_S`).

Parameters: ``seed`` (7), ``layout`` (panel | table), ``frame_id``
(``camera_depth_optical_frame``), ``sensor_frame`` (``simulated_camera_optical_frame``),
``first_view`` (``camera``: the simulator's camera; ``KIND:TEMPLATE``, e.g.
``edge-on:quarter_turn_valve``: the sensor starts on the viewpoint bench row's hard first view
of that object, :func:`~.viewpoints.hard_view`), ``sensor_pose`` ('' = as ``first_view`` says;
else ``"x y z qx qy qz qw"`` in ``frame_id``: the sensor starts there), ``rate`` (0 Hz: once).
"""

from __future__ import annotations

import time

import numpy as np
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.duration import Duration
from rclpy.node import Node

from ..core.errors import AffordanceError
from ..core.templates import TemplateLibrary
from ..core.transforms import invert, make_T, quat_xyzw_to_matrix
from ..ros.glue.cloud_publisher import LatchedCloudPublisher
from ..ros.glue.conversions import (
    ConversionError,
    matrix_to_transform,
    pose_to_matrix,
    xyz_to_pointcloud2,
)
from ..ros.glue.qos import INPUT, LATCHED
from ..ros.glue.tf import load_tf_message
from ..ros.standins.spin import run_node
from .simulation import DepthCamera, simulate_taskboard
from .viewpoints import KINDS, hard_view, taskboard_meshes

__all__ = [
    "SimulatedScanNode",
    "view_problem",
    "render_organized",
    "parse_pose",
    "first_view",
    "check_first_view",
    "main",
    "REQUEST_TOPIC",
    "MIN_CLEARANCE_M",
    "MAX_RANGE_M",
    "MIN_POINTS",
]

REQUEST_TOPIC = "sensor_view_request"  #: where the sensor is asked to move to
MIN_CLEARANCE_M = 0.05  #: the sensor stays at least this far in front of the panel
MAX_RANGE_M = 3.0  #: and at most this far from the panel's centre
MIN_POINTS = 1000  #: a view that sees fewer points of the taskboard is refused
ACK_TIMEOUT_S = 2.0  #: the longest wait for the sensor's pose to be received
MOVE_CHECK_S = 0.05  #: s between looks for a request to move to
MOVE_SETTLE_S = 0.2  #: ... moved to once no newer one came for this long
MOVE_LATEST_S = 1.0  #: ... or, at the latest, this long after the oldest waiting came


def parse_pose(text: str) -> np.ndarray:
    """``"x y z qx qy qz qw"`` (metres, a unit quaternion) as a 4x4."""
    try:
        values = [float(v) for v in str(text).split()]
    except ValueError:
        values = []
    if len(values) != 7 or not np.all(np.isfinite(values)):
        raise AffordanceError(
            f"sensor_pose must be 'x y z qx qy qz qw' (7 finite numbers), got {text!r}"
        )
    q = np.array(values[3:])
    if abs(np.linalg.norm(q) - 1.0) > 0.01:
        raise AffordanceError(f"sensor_pose: the quaternion is not unit length ({text!r})")
    return make_T(quat_xyzw_to_matrix(q / np.linalg.norm(q)), values[:3])


def check_first_view(text: str, library: TemplateLibrary) -> tuple[str, str] | None:
    """``first_view`` as (kind, template), None for ``camera``; AffordanceError naming what is
    wrong (not ``KIND:TEMPLATE`` of a kind of :data:`~.viewpoints.KINDS` and a template the
    taskboard has)."""
    text = str(text).strip()
    if text == "camera":
        return None
    kind, _, template = text.partition(":")
    placed = [n for n in library if library[n].primitive is None]
    if kind not in KINDS or template not in placed:
        raise AffordanceError(
            f"first view must be 'camera' or KIND:TEMPLATE with KIND one of "
            f"{', '.join(KINDS)} and TEMPLATE one of {', '.join(placed)}, got "
            f"{text[:80]!r}"
        )
    return kind, template


def first_view(sim, kind: str, template: str) -> np.ndarray:
    """The hard first view ``kind`` of the object ``template`` of ``sim`` (the scene frame), as
    the viewpoint bench row draws it for that object."""
    k = next(i for i, o in enumerate(sim.objects) if o.template == template)
    return hard_view(sim, k, kind, np.random.default_rng(sim.seed * 100 + k))


def view_problem(T_scene_board: np.ndarray, T_scene_sensor: np.ndarray) -> str:
    """Why the sensor may not be put at ``T_scene_sensor`` (4x4, the scene frame) in front of a
    taskboard whose panel is at ``T_scene_board`` ('' when it may): behind or inside the panel,
    or absurdly far from it."""
    p = invert(T_scene_board)[:3, :] @ np.append(T_scene_sensor[:3, 3], 1.0)
    if p[2] < MIN_CLEARANCE_M:
        return (
            f"it is {'inside' if p[2] > -0.02 else 'behind'} the panel ({p[2]:.3f} m in front "
            f"of it; at least {MIN_CLEARANCE_M} m)"
        )
    if np.linalg.norm(p) > MAX_RANGE_M:
        return f"it is {np.linalg.norm(p):.1f} m from the panel (at most {MAX_RANGE_M} m)"
    return ""


def render_organized(meshes, T_scene_sensor: np.ndarray, rng, camera: DepthCamera | None = None):
    """The organized scan (H, W, 3) float32 -- NaN where nothing was seen -- of ``meshes``
    ((trimesh, T_scene_mesh)) from the optical frame ``T_scene_sensor``, in the scene frame, and
    its labels (H, W): the index of the mesh each pixel hit, -1 for none. ``rng`` None: without
    noise."""
    camera = camera or DepthCamera()
    T_sensor_scene = invert(T_scene_sensor)
    organized, labels = camera.render([(m, T_sensor_scene @ T) for m, T in meshes], rng)
    flat = (
        organized.reshape(-1, 3).astype(float) @ T_scene_sensor[:3, :3].T + T_scene_sensor[:3, 3]
    )
    return flat.reshape(organized.shape).astype(np.float32), labels


class SimulatedScanNode(Node):
    def __init__(self):
        super().__init__("affordance_simulated_scan")
        seed = int(self.declare_parameter("seed", 7).value)
        layout = str(self.declare_parameter("layout", "panel").value)
        self.frame = str(self.declare_parameter("frame_id", "camera_depth_optical_frame").value)
        self.sensor_frame = str(
            self.declare_parameter("sensor_frame", "simulated_camera_optical_frame").value
        ).strip()
        start = str(self.declare_parameter("sensor_pose", "").value).strip()
        view = str(self.declare_parameter("first_view", "camera").value)
        rate = float(self.declare_parameter("rate", 0.0).value)
        if seed < 0:
            raise AffordanceError(f"seed must be >= 0, got {seed}")
        if layout not in ("panel", "table"):
            raise AffordanceError(f"layout must be 'panel' or 'table', got {layout!r}")
        if not 0.0 <= rate <= 30.0:
            raise AffordanceError(f"rate must be within 0-30 Hz, got {rate}")
        if not self.sensor_frame or self.sensor_frame.lstrip("/") == self.frame.lstrip("/"):
            raise AffordanceError(
                f"sensor_frame must name a frame other than frame_id '{self.frame}'"
            )
        library = TemplateLibrary.load()
        hard = check_first_view(view, library)
        self.sim = simulate_taskboard(library, seed, layout=layout)
        self.meshes = taskboard_meshes(self.sim, library)
        self.T_sensor = np.eye(4)
        self._moves = 0
        organized = self.sim.organized
        if start or hard:
            T = parse_pose(start) if start else first_view(self.sim, *hard)
            problem = view_problem(self.sim.T_scene_board, T)
            if problem:
                raise AffordanceError(f"sensor_pose: {problem}")
            organized = self._render(T)
            self.T_sensor = T
        TFMessage = load_tf_message()
        self._tf = (
            None
            if TFMessage is None
            else (TFMessage, self.create_publisher(TFMessage, "/tf_static", LATCHED))
        )
        self._publish_sensor()
        self.cloud = LatchedCloudPublisher(self, xyz_to_pointcloud2(organized, self.frame))
        self._pending = None  # the latest request not yet moved to
        self.create_subscription(PoseStamped, REQUEST_TOPIC, self._on_request, INPUT)
        self.create_timer(MOVE_CHECK_S, self._move)
        if rate > 0:
            self.create_timer(1.0 / rate, self.cloud.publish)
        n = int(np.all(np.isfinite(organized.reshape(-1, 3)), axis=1).sum())
        self.get_logger().info(
            f"simulated {layout} scan (seed {seed}): {n} points in "
            f"'{self.frame}' on {self.cloud.topic_name}, the sensor at "
            f"'{self.sensor_frame}'; moves on requests on "
            f"{self.resolve_topic_name(REQUEST_TOPIC)}"
        )

    def _render(self, T: np.ndarray) -> np.ndarray:
        self._moves += 1
        return render_organized(
            self.meshes, T, np.random.default_rng(self.sim.seed * 1000 + self._moves)
        )[0]

    def _publish_sensor(self) -> None:
        """The sensor's pose in the cloud frame on /tf_static (the whole set: one frame)."""
        if self._tf is None:
            return
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = self.frame, self.sensor_frame
        t.header.stamp = self.get_clock().now().to_msg()
        t.transform = matrix_to_transform(self.T_sensor)
        TFMessage, pub = self._tf
        pub.publish(TFMessage(transforms=[t]))
        # the engine looks the sensor up when it uses a cloud: the pose is received (acked by
        # every reliable reader, e.g. the engine's TF listener) before the cloud goes out
        pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))

    def _refuse(self, why: str) -> None:
        self.get_logger().warning(f"{REQUEST_TOPIC}: not moved: {why}")

    def _on_request(self, msg: PoseStamped) -> None:
        frame = msg.header.frame_id.lstrip("/")
        if frame != self.frame.lstrip("/"):
            shown = frame if len(frame) <= 80 else frame[:80] + "..."
            self._refuse(f"the pose is in '{shown}', not in the cloud's frame '{self.frame}'")
            return
        try:
            T = pose_to_matrix(msg.pose)
        except ConversionError as exc:
            self._refuse(str(exc))
            return
        problem = view_problem(self.sim.T_scene_board, T)
        if problem:
            self._refuse(f"the pose ({', '.join(f'{v:.3f}' for v in T[:3, 3])}): {problem}")
            return
        now = time.monotonic()  # the latest request wins (see _move)
        self._pending = (T, now, now if self._pending is None else self._pending[2])

    def _move(self) -> None:
        """Move to the latest request once no newer one came for MOVE_SETTLE_S (or the oldest
        waiting came MOVE_LATEST_S ago): a burst of requests (read one per turn of the executor,
        between renders) is one move, and a steady stream of them moves once a second."""
        now = time.monotonic()
        if self._pending is None or (
            now - self._pending[1] < MOVE_SETTLE_S and now - self._pending[2] < MOVE_LATEST_S
        ):
            return
        T, self._pending = self._pending[0], None
        organized = self._render(T)
        n = int(np.all(np.isfinite(organized.reshape(-1, 3)), axis=1).sum())
        if n < MIN_POINTS:
            self._refuse(
                f"from there the sensor would see {n} points of the taskboard (fewer "
                f"than {MIN_POINTS})"
            )
            return
        self.T_sensor = T
        self._publish_sensor()  # where the scan is taken from, before the scan
        self.cloud.msg = xyz_to_pointcloud2(organized, self.frame)
        self.cloud.publish()
        self.get_logger().info(
            f"moved the sensor to ({', '.join(f'{v:.3f}' for v in T[:3, 3])})"
            f" in '{self.frame}': {n} points on {self.cloud.topic_name}"
        )


def main(args=None) -> int:
    """Console script ``affordance_simulated_scan`` (takes ``--ros-args``)."""
    return run_node(SimulatedScanNode, "affordance_simulated_scan", args)


if __name__ == "__main__":
    raise SystemExit(main())
