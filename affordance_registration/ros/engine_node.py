"""The ``affordance_engine`` node: clouds, clicks, SpaceMouse twists/buttons and services in;
ranked fit markers, poses and status out. Thin: convert, call the engine, publish.

Threads: the executor (one thread, ``spin_once`` loop) runs subscriptions, services and a 20 Hz
timer that publishes whatever changed and starts idle refits; fitting a click runs on a worker
thread with a FIFO queue, so services and twists are served while a fit runs and a click that
arrives meanwhile is fitted next, not lost. Clouds are only stored on arrival (the latest one);
they are converted when a fit needs them, so a 1M-point 30 Hz camera cannot starve the node.
"""
from __future__ import annotations

import json
import math
import os
import queue
import threading
import time

import numpy as np
from geometry_msgs.msg import PointStamped, PoseArray, PoseStamped, Twist
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.task import Future
from sensor_msgs.msg import Joy, PointCloud2
from std_msgs.msg import ColorRGBA, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from ..core.corrections import view_from_optical
from ..core.engine import AffordanceEngine
from ..core.errors import AffordanceError, EngineStateError
from ..core.registration import FitSettings
from ..core.templates import TemplateLibrary
from .conversions import (likelihood_color, matrix_to_pose, mesh_marker,
                          pointcloud2_to_xyz, pose_stamped, pose_to_matrix, sphere_marker,
                          text_marker)
from .frames import FrameError, StaticFrames
from .interactive import CorrectionMarkerServer
from .spin import run_node

FIRST_TWIST_DT = 1.0 / 30.0
# spacenav/twist axes (x away from the user, y left, z up) -> view axes (x right, y up, z to the
# viewer): push right -> right on the screen, push away -> into the screen, lift -> up
R_VIEW_SPACENAV = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
REFIT_FIRST = ("accept", "next_model", "previous_model", "discard")
BUTTON_ACTIONS = ("next_model", "previous_model", "accept", "refit", "undo", "discard",
                  "joint_plus", "joint_minus")

# name: (default, description, (min, max) or choices or None)
PARAMETERS = {
    "templates_dir": ("", "template library directory ('' = the package's models/)", None),
    "fit_mode": ("auto", "auto: mounting plane prior + resting + random; mounted; free",
                 ("auto", "mounted", "free")),
    "estimate_joints": (True, "fit joint values (valve open/closed) and scale where templates "
                              "have them; false: rigid templates only", None),
    "voxel_size": (0.005, "voxel edge of the crop around a click (m)", (0.001, 0.05)),
    "weight_scale": (0.005, "d0 of the correspondence weight 1/(1+d/d0) (m)", (0.0005, 0.1)),
    "snap_distance": (0.03, "a click farther than this from the cloud is refused (m)", (0.001, 1.0)),
    "seed": (0, "random seed of the restarts", (0, 2**31 - 1)),
    "linear_gain": (0.1, "m/s per unit of spacenav/twist linear", (0.0, 10.0)),
    "angular_gain": (0.6, "rad/s per unit of spacenav/twist angular", (0.0, 20.0)),
    "twist_frame": ("spacenav", "axes of spacenav/twist: spacenav (REP-103 device axes: x away "
                    "from the user, y left, z up) or view (x right, y up, z to the viewer)",
                    ("spacenav", "view")),
    "max_twist_dt": (0.1, "longest time one twist message is integrated over (s)", (0.001, 1.0)),
    "refit_idle_s": (0.5, "refit after the twists stop for this long (s)", (0.05, 30.0)),
    "button_next_model": (0, "Joy button for next model (-1: none)", (-1, 63)),
    "button_accept": (1, "Joy button for accept (-1: none)", (-1, 63)),
    "button_previous_model": (-1, "Joy button for previous model (-1: none)", (-1, 63)),
    "button_refit": (-1, "Joy button for refit (-1: none)", (-1, 63)),
    "button_undo": (-1, "Joy button for undo (-1: none)", (-1, 63)),
    "button_discard": (-1, "Joy button for discard (-1: none)", (-1, 63)),
    "button_joint_plus": (-1, "Joy button stepping the shown object's joint up (-1: none)",
                          (-1, 63)),
    "button_joint_minus": (-1, "Joy button stepping the shown object's joint down (-1: none)",
                           (-1, 63)),
    "joint_axis": (-1, "Joy axis stepping the joint once per push past joint_axis_threshold, "
                       "in the push's direction (-1: none)", (-1, 63)),
    "joint_axis_threshold": (0.5, "how far joint_axis must be pushed to step", (0.05, 1.0)),
    "joint_step_deg": (5.0, "one joint step of a revolute joint (deg)", (0.1, 90.0)),
    "joint_step_mm": (2.0, "one joint step of a prismatic joint (mm)", (0.1, 100.0)),
    "static_transforms": ([], "'parent child x y z qx qy qz qw' entries used when tf2 is absent",
                          None),
    "registrations_file": ("affordance_registrations.yaml", "where ~/save writes (YAML)", None),
    "sensor_origin": ([0.0, 0.0, 0.0], "sensor position in the cloud frame (m)", None),
    "points_reliable": (True, "subscribe to points with reliable QoS (false: best effort, for "
                              "sensor drivers publishing with SensorDataQoS); read at start", None),
    "publish_rate": (20.0, "highest rate of marker/status updates (Hz)", (1.0, 100.0)),
    "interactive_namespace": ("/affordance_correction", "interactive marker server namespace "
                              "(one level); read at start", None),
    "interactive_orientation": ("object", "interactive marker controls aligned with the object "
                                "or the operator's view", ("object", "view")),
}
READ_ONLY = {"points_reliable", "interactive_namespace"}


MOVING_COLOR = ColorRGBA(r=1.0, g=0.35, b=0.1, a=0.9)


def _joint_text(tpl, joints: dict, state, scale: float) -> str:
    """' (closed, lever 88 deg, x1.10)' for labels; '' for a rigid template at scale 1."""
    parts = [state] if state else []
    for j in tpl.joints:
        if j.name in joints:
            v = joints[j.name]
            parts.append(f"{j.name} {math.degrees(v):.0f} deg" if j.type == "revolute"
                         else f"{j.name} {v * 1000:.1f} mm")
    if abs(scale - 1.0) > 1e-6:
        parts.append(f"x{scale:.2f}")
    return f" ({', '.join(parts)})" if parts else ""


def _descriptor(name, default, description, constraint) -> ParameterDescriptor:
    desc = ParameterDescriptor(description=description, read_only=name in READ_ONLY)
    if isinstance(constraint, tuple) and isinstance(constraint[0], str):
        desc.additional_constraints = "one of: " + ", ".join(constraint)
    elif isinstance(constraint, tuple):
        desc.additional_constraints = f"range [{constraint[0]}, {constraint[1]}]"
    return desc


class EngineNode(Node):
    def __init__(self, **kwargs):
        super().__init__("affordance_engine", **kwargs)
        for name, (default, description, constraint) in PARAMETERS.items():
            # an empty list would be declared as a byte array: declare string lists by type
            value = Parameter.Type.STRING_ARRAY if default == [] else default
            self.declare_parameter(name, value, _descriptor(name, default, description,
                                                            constraint))
        self._p = {name: self._value(name) for name in PARAMETERS}
        problem = self._check(self._p)
        if problem:
            raise AffordanceError(f"bad parameter: {problem}")
        self.library = self._load_library(self._p["templates_dir"])
        self.engine = AffordanceEngine(self.library, self._fit_settings(self._p))
        self._set_joint_steps(self._p)
        self.frames = StaticFrames(self._p["static_transforms"])
        self._tf = self._make_tf()
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._lock = threading.Lock()
        self._cloud_msg: PointCloud2 | None = None
        self._cloud_count = 0
        self._converted = 0
        self._cloud_frame = ""
        self._cloud_status_at = 0.0
        self._jobs: queue.Queue = queue.Queue()
        self._busy: str | None = None
        self._dirty = True
        self._last_publish = 0.0
        self._last_twist: float | None = None
        self._pending_refit = False
        self._buttons: list[int] = []
        self._joint_axis_sign = 0
        self._last_error = ""
        self._throttled: dict[str, float] = {}
        self._last_message = ""
        self._stop = threading.Event()

        cloud_qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                               reliability=ReliabilityPolicy.RELIABLE if self._p["points_reliable"]
                               else ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(PointCloud2, "points", self._on_cloud, cloud_qos)
        self.create_subscription(PointStamped, "clicked_point", self._on_click, 10)
        self.create_subscription(Twist, "spacenav/twist", self._on_twist, 10)
        self.create_subscription(Joy, "spacenav/joy", self._on_joy, 10)
        self.create_subscription(PoseStamped, "view_pose", self._on_view, 10)
        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_markers = self.create_publisher(MarkerArray, "~/markers", latched)
        self.pub_fit = self.create_publisher(PoseStamped, "~/fit", 10)
        self.pub_registered = self.create_publisher(PoseArray, "~/registered", latched)
        self.pub_status = self.create_publisher(String, "~/status", latched)
        for action in ("next_model", "previous_model", "refit", "accept", "undo", "discard",
                       "save", "joint_plus", "joint_minus"):
            self.create_service(Trigger, f"~/{action}", self._service(action))
        self.interactive = CorrectionMarkerServer(self, self._p["interactive_namespace"],
                                                  self._p["interactive_orientation"])
        self.create_timer(0.05, self._on_timer)
        self._worker = threading.Thread(target=self._work, name="fitting", daemon=True)
        self._worker.start()
        self.get_logger().info(f"ready: {len(self.library)} templates "
                               f"({', '.join(self.library)}); waiting for 'points' and clicks")

    # ------------------------------------------------------------------ parameters
    def _value(self, name: str):
        try:
            value = self.get_parameter(name).value
        except ParameterUninitializedException:   # a list declared by type, not overridden
            value = None
        return list(PARAMETERS[name][0]) if value is None else value

    @staticmethod
    def _check(values: dict) -> str | None:
        for name, value in values.items():
            if name not in PARAMETERS:
                continue
            default, _, constraint = PARAMETERS[name]
            if isinstance(default, bool):
                if not isinstance(value, bool):
                    return f"{name} must be true or false"
            elif isinstance(default, (int, float)) and not isinstance(default, bool):
                if not isinstance(value, (int, float)) or isinstance(value, bool) or \
                        not math.isfinite(value):
                    return f"{name} must be a number"
                if isinstance(default, int) and not float(value).is_integer():
                    return f"{name} must be an integer"
                lo, hi = constraint
                if not lo <= value <= hi:
                    return f"{name} = {value} is outside [{lo}, {hi}]"
            elif isinstance(constraint, tuple) and value not in constraint:
                return f"{name} must be one of {', '.join(constraint)}, got {value!r}"
        if "static_transforms" in values:
            try:
                StaticFrames(values["static_transforms"])
            except AffordanceError as exc:
                return str(exc)
        if "sensor_origin" in values:
            origin = values["sensor_origin"]
            if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
                return "sensor_origin must be 3 finite numbers"
        return None

    @staticmethod
    def _fit_settings(p: dict) -> FitSettings:
        return FitSettings(mode=p["fit_mode"], voxel=float(p["voxel_size"]),
                           weight_scale=float(p["weight_scale"]),
                           snap_distance=float(p["snap_distance"]), seed=int(p["seed"]),
                           articulated=bool(p["estimate_joints"]))

    def _set_joint_steps(self, p: dict) -> None:
        self.engine.joint_step_rad = math.radians(float(p["joint_step_deg"]))
        self.engine.joint_step_m = float(p["joint_step_mm"]) / 1000.0

    @staticmethod
    def _load_library(path: str) -> TemplateLibrary:
        return TemplateLibrary.load(path or None)

    def _on_set_parameters(self, params) -> SetParametersResult:
        new = dict(self._p)
        for param in params:
            if param.name in PARAMETERS:
                new[param.name] = [] if param.value is None else param.value
        problem = self._check({p.name: new[p.name] for p in params if p.name in PARAMETERS})
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        changed = {p.name for p in params}
        try:
            library = None
            if "templates_dir" in changed and new["templates_dir"] != self._p["templates_dir"]:
                library = self._load_library(new["templates_dir"])
            if library is not None or changed & {"fit_mode", "voxel_size", "weight_scale",
                                                 "snap_distance", "seed", "estimate_joints"}:
                self.engine.configure(self._fit_settings(new), library)
                self.library = self.engine.library
            if "static_transforms" in changed:
                self.frames = StaticFrames(new["static_transforms"])
            self._set_joint_steps(new)
            if "interactive_orientation" in changed:
                self.interactive.orientation = new["interactive_orientation"]
        except AffordanceError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self._p = new
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ frames
    def _make_tf(self):
        try:
            import tf2_ros
        except ImportError:
            return None
        buffer = tf2_ros.Buffer()
        listener = tf2_ros.TransformListener(buffer, self)
        return buffer, listener

    def _lookup(self, target: str, source: str) -> np.ndarray:
        """T_target_source from tf2 (if present) or the static transforms parameter."""
        target, source = target.lstrip("/"), source.lstrip("/")
        if not source or source == target:
            return np.eye(4)
        if self._tf is not None:
            from rclpy.time import Time
            from .conversions import transform_to_matrix
            try:
                tf = self._tf[0].lookup_transform(target, source, Time())
                return transform_to_matrix(tf.transform)
            except Exception:  # tf2 raises several lookup exceptions; fall back to static
                pass
        return self.frames.lookup(target, source)

    # ------------------------------------------------------------------ inputs
    def _on_cloud(self, msg: PointCloud2) -> None:
        n_fields = {f.name for f in msg.fields}
        expected = int(msg.row_step) * int(msg.height)
        if not {"x", "y", "z"} <= n_fields:
            self._error(f"dropped a PointCloud2 without x/y/z fields (has: "
                        f"{', '.join(sorted(n_fields)) or 'none'})")
            return
        if len(msg.data) != expected:
            self._error(f"dropped a PointCloud2 whose data ({len(msg.data)} bytes) disagrees "
                        f"with its header (height {msg.height} x row_step {msg.row_step} = "
                        f"{expected})")
            return
        with self._lock:
            prev = self._cloud_msg
            self._cloud_msg = msg
            self._cloud_count += 1
            self._cloud_frame = msg.header.frame_id
        now = time.monotonic()
        if prev is None or (prev.width, prev.height, prev.header.frame_id) != \
                (msg.width, msg.height, msg.header.frame_id):
            self.get_logger().info(f"cloud: {msg.width}x{msg.height} in '{msg.header.frame_id}'")
            self._dirty = True
        elif now - self._cloud_status_at >= 1.0:     # the status counts clouds at most at 1 Hz
            self._dirty = True
        if self._dirty:
            self._cloud_status_at = now

    def _ensure_scene(self) -> None:
        """Convert the latest cloud if it is newer than the scene (worker/executor thread)."""
        with self._lock:
            msg, count = self._cloud_msg, self._cloud_count
        if msg is None:
            raise EngineStateError("no point cloud received yet on 'points'")
        if count == self._converted:
            return
        self._converted = count
        try:
            pts, _ = pointcloud2_to_xyz(msg)
            self.engine.set_scene(pts, frame_id=msg.header.frame_id,
                                  sensor_origin=self._p["sensor_origin"])
        except AffordanceError as exc:
            if self.engine.has_scene:
                raise AffordanceError(f"the latest cloud is unusable ({exc}); still using the "
                                      f"previous one") from None
            raise

    def _on_click(self, msg: PointStamped) -> None:
        p = np.array([msg.point.x, msg.point.y, msg.point.z], dtype=float)
        frame = msg.header.frame_id
        if not np.all(np.isfinite(p)):
            self._error("ignored a clicked_point with NaN/inf coordinates")
            return
        self._jobs.put(("click", (p, frame)))
        self._dirty = True

    def _on_twist(self, msg: Twist) -> None:
        lin = np.array([msg.linear.x, msg.linear.y, msg.linear.z], dtype=float)
        ang = np.array([msg.angular.x, msg.angular.y, msg.angular.z], dtype=float)
        now = time.monotonic()
        if not (np.all(np.isfinite(lin)) and np.all(np.isfinite(ang))):
            self._error("ignored a spacenav/twist with NaN/inf values", throttle=2.0)
            return
        if not (np.any(lin) or np.any(ang)):
            return                                   # released: the idle timer takes over
        prev = self._last_twist
        # the first message of a burst counts as one frame of a 30 Hz device
        dt = FIRST_TWIST_DT if prev is None or now - prev > self._p["refit_idle_s"] else \
            min(now - prev, self._p["max_twist_dt"])
        self._last_twist = now
        if self._p["twist_frame"] == "spacenav":
            lin, ang = R_VIEW_SPACENAV @ lin, R_VIEW_SPACENAV @ ang
        try:
            self.engine.correct_twist(lin * self._p["linear_gain"], ang * self._p["angular_gain"],
                                      dt)
            self._pending_refit = True
            self._dirty = True
        except EngineStateError as exc:
            self._error(f"twist ignored: {exc}", throttle=2.0)

    def _on_joy(self, msg: Joy) -> None:
        buttons = list(msg.buttons)
        previous = self._buttons + [0] * (len(buttons) - len(self._buttons))
        self._buttons = buttons
        for action in BUTTON_ACTIONS:
            b = int(self._p[f"button_{action}"])
            if 0 <= b < len(buttons) and buttons[b] and not previous[b]:
                self._submit_action(action)
        a = int(self._p["joint_axis"])
        if 0 <= a < len(msg.axes):
            v = float(msg.axes[a])
            sign = 0 if not math.isfinite(v) or abs(v) < self._p["joint_axis_threshold"] \
                else (1 if v > 0 else -1)
            if sign and sign != self._joint_axis_sign:
                self._submit_action("joint_plus" if sign > 0 else "joint_minus")
            self._joint_axis_sign = sign

    def _on_view(self, msg: PoseStamped) -> None:
        try:
            T = pose_to_matrix(msg.pose)
            cloud_frame = self._cloud_frame or msg.header.frame_id
            T = self._lookup(cloud_frame, msg.header.frame_id) @ T
            self.engine.set_view(view_from_optical(T))
        except AffordanceError as exc:
            self._error(f"view_pose ignored: {exc}", throttle=2.0)

    # ------------------------------------------------------------------ actions
    def _settle_twists(self, action) -> None:
        """A refit still waiting for the twists to stop belongs to the object they moved: it
        runs before an action that leaves that object (accept, next/previous model, discard);
        undo, refit and joint steps make it moot."""
        if not self._pending_refit:
            return
        self._pending_refit = False
        if (action[0] if isinstance(action, tuple) else action) in REFIT_FIRST:
            self._jobs.put(("refit", None))

    def _service(self, action: str):
        async def callback(request, response):
            self._settle_twists(action)
            # after the clicks already queued, without blocking the executor meanwhile
            if self._jobs.empty() and self._busy is None:
                response.success, response.message = self._run_action(action)
                return response
            done = Future(executor=self.executor)
            self._jobs.put(("action", (action, done)))
            response.success, response.message = await done
            return response
        return callback

    def _submit_action(self, action: str) -> None:
        """A button or menu action: after the clicks already queued (a button pressed right
        after a click acts on that click's object)."""
        self._settle_twists(action)
        if self._jobs.empty() and self._busy is None:
            self._run_action(action)
        else:
            self._jobs.put(("action", (action, None)))

    def _run_action(self, action: str) -> tuple[bool, str]:
        try:
            if action == "save":
                msg = self.engine.save(os.path.expanduser(self._p["registrations_file"]))
            elif action == "refit":
                self._ensure_scene_quietly()
                msg = self.engine.refit()
            elif action in ("joint_plus", "joint_minus"):
                self._ensure_scene_quietly()
                msg = self.engine.correct_joint(steps=1.0 if action == "joint_plus" else -1.0)
            elif isinstance(action, tuple) and action[0] == "joint_value":
                self._ensure_scene_quietly()
                msg = self.engine.correct_joint(value=action[1])
            else:
                msg = getattr(self.engine, action)()
            self._info(msg)
            self._dirty = True
            return True, msg
        except AffordanceError as exc:
            name = action[0] if isinstance(action, tuple) else action
            self._error(f"{name.replace('_', ' ')}: {exc}")
            return False, str(exc)

    def _ensure_scene_quietly(self) -> None:
        try:
            self._ensure_scene()
        except AffordanceError as exc:
            self._error(str(exc), throttle=5.0)

    def _work(self) -> None:
        while not self._stop.is_set():
            try:
                kind, payload = self._jobs.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                if kind == "click":
                    point, frame = payload
                    self._busy = f"fitting a click ({self._jobs.qsize()} more queued)"
                    # progress goes out now, whatever the executor is busy with
                    self.pub_status.publish(String(data=json.dumps(self.status())))
                    self._ensure_scene()
                    cloud_frame = self.engine.frame_id
                    if frame and frame.lstrip("/") != cloud_frame.lstrip("/"):
                        try:
                            T = self._lookup(cloud_frame, frame)
                        except FrameError:
                            raise AffordanceError(f"click refused: it is in frame '{frame}' and "
                                                  f"no transform to the cloud frame "
                                                  f"'{cloud_frame}' is known") from None
                        point = T[:3, :3] @ point + T[:3, 3]
                    self._info(self.engine.click(point))
                elif kind == "refit":
                    self._ensure_scene_quietly()
                    self._info(self.engine.refit())
                elif kind == "action":
                    action, done = payload
                    try:
                        outcome = self._run_action(action)
                    except Exception as exc:   # the caller must get an answer regardless
                        outcome = (False, f"internal error: {exc!r}")
                    if done is not None:
                        done.set_result(outcome)
            except AffordanceError as exc:
                self._error(str(exc))
            except Exception as exc:   # a bug must not kill the worker
                self._error(f"internal error while handling {kind}: {exc!r}")
            finally:
                self._busy = None
                self._dirty = True

    # ------------------------------------------------------------------ output
    def _info(self, msg: str) -> None:
        self._last_message = msg
        self.get_logger().info(msg)

    def _error(self, msg: str, throttle: float | None = None) -> None:
        """Log an error; with ``throttle`` (s), the same message at most that often (as a
        warning: it repeats because of a stream of bad input)."""
        self._last_error = msg
        self._dirty = True
        if throttle:
            now = time.monotonic()
            if now - self._throttled.get(msg, -math.inf) < throttle:
                return
            self._throttled[msg] = now
            self.get_logger().warning(msg)
        else:
            self.get_logger().error(msg)

    def _on_timer(self) -> None:
        now = time.monotonic()
        if self._pending_refit and self._last_twist is not None and \
                now - self._last_twist >= self._p["refit_idle_s"]:
            self._pending_refit = False
            self._jobs.put(("refit", None))
        if self._dirty and now - self._last_publish >= 1.0 / self._p["publish_rate"]:
            self._dirty = False
            self._last_publish = now
            self.publish_all()

    def status(self) -> dict:
        st = self.engine.status()
        with self._lock:
            msg = self._cloud_msg
            st["node"] = {
                "busy": self._busy, "queued": self._jobs.qsize(),
                "cloud": None if msg is None else {
                    "frame_id": msg.header.frame_id, "width": msg.width, "height": msg.height,
                    "received": self._cloud_count},
                "last_message": self._last_message, "last_error": self._last_error}
        return st

    def publish_all(self) -> None:
        frame = self.engine.frame_id or self._cloud_frame
        stamp = self.get_clock().now().to_msg()
        state = self.engine.state
        markers = MarkerArray()
        clear = Marker()
        clear.action = Marker.DELETEALL
        markers.markers.append(clear)
        for obj in state.objects:
            c = obj.shown
            tpl = self.library[c.template]
            T = c.T_scene_model
            q = tpl.joint_value(c.joints)
            markers.markers.append(mesh_marker(tpl.mesh_at(q, c.scale), T, frame, "candidate",
                                               obj.id, likelihood_color(c.probability), stamp))
            moving = tpl.moving_mesh_at(q, c.scale)
            if moving is not None:    # the moving part where the fit put it, highlighted
                markers.markers.append(mesh_marker(moving, T, frame, "candidate_moving_part",
                                                   obj.id, MOVING_COLOR, stamp))
            top = T[:3, :3] @ tpl.centroid + T[:3, 3]
            label = (f"{c.template}{_joint_text(tpl, c.joints, c.state, c.scale)} — rank "
                     f"{obj.active + 1}/{len(obj.candidates)} — {c.probability:.2f}")
            markers.markers.append(text_marker(label, top - 0.6 * tpl.diameter *
                                               self._up(), frame, "candidate_label", obj.id,
                                               stamp))
            markers.markers.append(sphere_marker(obj.click, frame, "click", obj.id, stamp))
        for reg in state.registered:
            tpl = self.library[reg.template] if reg.template in self.library else None
            if tpl is None:
                continue
            q = tpl.joint_value(reg.joints)
            markers.markers.append(mesh_marker(tpl.mesh_at(q, reg.scale), reg.T_scene_model,
                                               frame, "registered", reg.id,
                                               ColorRGBA(r=0.3, g=0.5, b=1.0, a=0.9), stamp))
            moving = tpl.moving_mesh_at(q, reg.scale)
            if moving is not None:
                markers.markers.append(mesh_marker(moving, reg.T_scene_model, frame,
                                                   "registered_moving_part", reg.id,
                                                   MOVING_COLOR, stamp))
            text = f"{reg.template} #{reg.id}{_joint_text(tpl, reg.joints, reg.state, reg.scale)}"
            markers.markers.append(text_marker(text,
                                               reg.T_scene_model[:3, 3] - 0.5 * tpl.diameter *
                                               self._up(), frame, "registered_label", reg.id,
                                               stamp))
        self.pub_markers.publish(markers)
        active = self.engine.active_object()
        if active is not None:
            self.pub_fit.publish(pose_stamped(active.shown.T_scene_model, frame, stamp))
        arr = PoseArray()
        arr.header.frame_id, arr.header.stamp = frame, stamp
        arr.poses = [matrix_to_pose(r.T_scene_model) for r in state.registered]
        self.pub_registered.publish(arr)
        self.pub_status.publish(String(data=json.dumps(self.status())))
        self.interactive.sync()

    def _up(self) -> np.ndarray:
        """Screen-up direction in the cloud frame (for placing labels)."""
        return self.engine.view_pose()[:3, 1]

    def shutdown(self) -> None:
        self._stop.set()
        self._worker.join(timeout=1.0)


def main(args=None) -> int:
    """Console script ``affordance_engine`` (takes ``--ros-args``)."""
    return run_node(EngineNode, "affordance_engine", args, shutdown=lambda node: node.shutdown())


if __name__ == "__main__":
    raise SystemExit(main())
