"""Node ``affordance_station``: the browser operator station, a plain ROS client of an engine node.

It serves a page with viser (``http://127.0.0.1:8080`` by default; the web client ships inside the
viser wheel) that shows the live cloud (thinned for display, coloured by intensity or depth), the
shown candidate of the selected object as its mesh with a label, the registrations in their own
colour and a status panel. On the page the operator

* clicks the cloud: the click ray is snapped to the nearest cloud point (``core.display.snap_ray``)
  and published on ``clicked_point`` in the cloud's frame;
* drags the gizmo on the shown fit: an interactive-marker feedback client of its own (MOUSE_DOWN,
  POSE_UPDATE, MOUSE_UP of ``affordance_fit`` on ``<interactive_namespace>/feedback``) -- the
  release is an absolute correction followed by a refit, as a drag in RViz;
* presses Next / Previous / Accept / Refit / Undo / Discard / Save / Joint - / Joint + (the engine's
  std_srvs/Trigger services) or picks a candidate by name (``<engine>/select_model``);
* looks around: the browser camera is published on ``view_pose`` (an optical frame in the cloud's
  frame), so SpaceMouse pushes move the object in the view the operator is looking at.

Everything it shows comes from the engine's documented outputs (``~/status``, ``~/markers``), so it
works with any engine node and template library. The scene and panel live in the server, so a
reload or a second browser shows the same state; actions are serialised by the engine.

Layout: message conversion and status formatting are plain functions (tested without
``rclpy.init``), the page (:class:`StationPage`) is the only code calling viser, and the node
(:class:`StationNode`) the only code calling rclpy; the geometry is in ``core/display.py``.
"""
from __future__ import annotations

import hashlib
import json
import math
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from geometry_msgs.msg import PointStamped, PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import InteractiveMarkerFeedback, Marker, MarkerArray

from ...core import display
from ...core.errors import AffordanceError
from ...core.labels import REFUSED_PREFIX, standing
from ...core.transforms import invert, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from ..glue import qos
from ..glue.conversions import (
    ConversionError,
    matrix_to_pose,
    pointcloud2_field,
    pointcloud2_to_xyz,
    pose_stamped,
    pose_to_matrix,
)
from ..glue.qos import INPUT, LATCHED
from ..standins.spin import run_node
from . import access as station_access

__all__ = ["StationNode", "StationPage", "PageHandlers", "MeshDrawing", "TextDrawing",
           "SphereDrawing", "apply_markers", "active_object", "candidate_label",
           "candidate_options", "status_markdown", "feedback_message", "click_message",
           "check_port", "gizmo_scale", "ACTIONS", "PARAMETERS", "main"]

#: the buttons, in page order: (engine service, button label)
#: a primitive's dimensions, each a field of the page (m)
DIMENSIONS = ("x", "y", "z", "radius", "length")
ACTIONS = (("previous_model", "Previous"), ("next_model", "Next"), ("accept", "Accept"),
           ("refit", "Refit"), ("undo", "Undo"), ("discard", "Discard"), ("save", "Save"),
           ("joint_minus", "Joint −"), ("joint_plus", "Joint +"))
#: parameters: name -> (default, description); checked by :func:`check_parameters`
PARAMETERS = {
    "host": ("127.0.0.1", "address the page is served on (0.0.0.0: every interface)"),
    "port": (8080, "TCP port of the page"),
    "engine": ("/affordance_engine", "the engine node's name: its ~/status, ~/markers, "
                                     "~/select_model and services"),
    "interactive_namespace": ("/affordance_correction", "the engine's interactive markers"),
    "points_reliable": (True, "reliable 'points' subscription (false: best effort, for drivers "
                              "that publish with SensorDataQoS)"),
    "display_points": (60000, "most cloud points sent to the page (the cloud is thinned)"),
    "point_size": (0.003, "m, drawn size of a cloud point"),
    "color_by": ("auto", "auto (intensity when the cloud has it, else depth) | depth | intensity"),
    "up": ("auto", "the world's up axis on the page: auto (-y for optical frames, else +z) | "
                   "+x | -x | +y | -y | +z | -z"),
    "fov_deg": (60.0, "vertical field of view of the page's camera"),
    "view_rate": (10.0, "Hz, highest rate of view_pose messages"),
    "cloud_rate": (2.0, "Hz, highest rate the page's cloud is replaced at"),
    "click_cone_deg": (0.5, "a click picks cloud points within this angle of its ray"),
    "access_secret": ("", "the secret the page and its websocket need ('' = the "
                          "AFFORDANCE_STATION_SECRET environment variable, else a random one "
                          "per start, shown in the URL the station logs); at least 16 characters"),
}
MARKER_NAME = "affordance_fit"          # the engine's interactive marker for the shown fit
MESH_MARGIN = 0.005                     # m: meshes are drawn this far out of their surface
REFUSED_RGB = (150, 150, 150)           # a candidate the verdict refuses: a grey outline ...
REFUSED_OPACITY = 0.5                   # ... half transparent
PENDING_RGB = (255, 140, 0)             # the click being fitted
PENDING_RADIUS = 0.008                  # m
DRAG_KEEP_ALIVE_S = 1.0                 # the engine drops a silent drag after 3 s
CALL_TIMEOUT_S = 120.0                  # a button's call unanswered this long is given up
UP_AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
           "+z": (0, 0, 1), "-z": (0, 0, -1)}


# ============================================================================ messages -> drawings
@dataclass(frozen=True)
class MeshDrawing:
    """A TRIANGLE_LIST marker: ``vertices`` (3F, 3) float32 in the marker's frame, ``faces``
    (F, 3) uint32, ``T`` (4, 4) its pose in the header frame, RGB ``color`` 0-255, ``opacity``."""

    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    T: np.ndarray = field(repr=False)
    color: tuple
    opacity: float
    frame: str

    @property
    def digest(self) -> str:
        """Identity of the geometry and colour (not the pose)."""
        h = hashlib.blake2b(self.vertices.tobytes(), digest_size=12)
        h.update(repr((self.color, round(self.opacity, 3))).encode())
        return h.hexdigest()


@dataclass(frozen=True)
class TextDrawing:
    text: str
    position: np.ndarray = field(repr=False)       # (3,) in the header frame
    frame: str


@dataclass(frozen=True)
class SphereDrawing:
    position: np.ndarray = field(repr=False)
    radius: float
    color: tuple
    frame: str


def _rgb(c) -> tuple:
    return tuple(int(round(255 * min(1.0, max(0.0, v)))) for v in (c.r, c.g, c.b))


def _drawing(m: Marker):
    frame = m.header.frame_id
    if m.type == Marker.TRIANGLE_LIST:
        n = len(m.points) // 3 * 3
        if n == 0:
            return None
        verts = np.array([(p.x, p.y, p.z) for p in m.points[:n]], dtype=np.float32)
        verts *= np.array([m.scale.x or 1.0, m.scale.y or 1.0, m.scale.z or 1.0],
                          dtype=np.float32)
        faces = np.arange(n, dtype=np.uint32).reshape(-1, 3)
        return MeshDrawing(verts, faces, pose_to_matrix(m.pose), _rgb(m.color),
                           float(m.color.a), frame)
    if m.type == Marker.TEXT_VIEW_FACING:
        p = m.pose.position
        return TextDrawing(m.text, np.array([p.x, p.y, p.z]), frame)
    if m.type == Marker.SPHERE:
        p = m.pose.position
        return SphereDrawing(np.array([p.x, p.y, p.z]), 0.5 * float(m.scale.x), _rgb(m.color),
                             frame)
    return None


def apply_markers(current: dict, msg: MarkerArray) -> dict:
    """The drawings after a MarkerArray: ``current`` maps (namespace, id) to a drawing;
    DELETEALL clears, DELETE removes, ADD/MODIFY sets (TRIANGLE_LIST, TEXT_VIEW_FACING and SPHERE;
    other types, and markers that cannot be converted, are left out). Returns a new dict."""
    out = dict(current)
    for m in msg.markers:
        key = (m.ns, int(m.id))
        if m.action == Marker.DELETEALL:
            out.clear()
        elif m.action == Marker.DELETE:
            out.pop(key, None)
        elif m.action == Marker.ADD:        # ADD == MODIFY
            try:
                drawing = _drawing(m)
            except ConversionError:
                drawing = None
            if drawing is None:
                out.pop(key, None)
            else:
                out[key] = drawing
    return out


# ============================================================================ status -> text
def active_object(status: dict | None) -> dict | None:
    """The selected object of an engine status (its ``objects`` entry), or None."""
    for obj in (status or {}).get("objects") or []:
        if obj.get("active"):
            return obj
    return None


def candidate_standing(obj: dict | None) -> tuple[str, bool]:
    """(verdict text, refused) of an object's shown candidate, from what the engine's status
    has per object (``no_match``) and per candidate (``fits``, ``probability``):
    ``core.labels.standing``. ('', False) without an object."""
    if not obj or not obj.get("candidates"):
        return "", False
    cands = obj["candidates"]
    shown = int(obj.get("shown", 0))
    primitive = 0 <= shown < len(cands) and cands[shown].get("primitive") is not None
    return standing(bool(obj.get("no_match")), shown,
                    [float(c.get("probability") or 0.0) for c in cands],
                    [c.get("fits") for c in cands], primitive, str(obj.get("verdict") or ""))


def candidate_label(obj: dict | None) -> str:
    """'#3 ball_valve (closed) — rank 1/5 — fits, 3.5x the next' for the shown candidate of an
    object; '#3 no template fits here — best guess gate_valve — rank 1/5' when the verdict
    refuses it; '' without an object."""
    if not obj or not obj.get("candidates"):
        return ""
    shown = int(obj.get("shown", 0))
    c = obj["candidates"][shown]
    state = f" ({c['state']})" if c.get("state") else ""
    text, _ = candidate_standing(obj)
    rank = f"rank {shown + 1}/{len(obj['candidates'])}"
    if text == REFUSED_PREFIX:
        return f"#{obj.get('id', '?')} {text} {c.get('template', '?')}{state} — {rank}"
    return f"#{obj.get('id', '?')} {c.get('template', '?')}{state} — {rank} — {text}"


def candidate_options(obj: dict | None) -> list[tuple[str, str]]:
    """(option text, template) of every ranked candidate of an object, best first."""
    out = []
    for i, c in enumerate((obj or {}).get("candidates") or []):
        verdict = {True: "fits", False: "does not fit"}.get(c.get("fits"), "not judged")
        out.append((f"{i + 1}. {c['template']} ({verdict})", c["template"]))
    return out


def status_markdown(status: dict | None, connected: bool, engine: str, cloud: str,
                    last_action: str, fitting: str = "", stale_error: bool = False) -> str:
    """The status panel: engine connection, a click being fitted (``fitting``), open object and
    its verdict, counts, fit time, what the engine is doing, its last message and error (left
    out when ``stale_error``: a later message came after it), the cloud, the reply to the last
    button."""
    lines = []
    if not connected:
        lines.append(f"**Engine not running**: nothing publishes {engine}/status (start "
                     f"`affordance_engine`; the page recovers when it comes up)")
    elif status is None:
        lines.append(f"**Engine**: {engine} is up, waiting for its status")
    else:
        node = status.get("node") or {}
        doing = node.get("busy") or ("refit pending" if node.get("pending_refit") else "idle")
        lines.append(f"**Engine**: {engine} — {doing}"
                     + (f", {node['queued']} queued" if node.get("queued") else ""))
    if fitting:
        lines.append(f"**Fitting**: {fitting}")
    st = status or {}
    obj = active_object(st)
    lines.append(f"**Open object**: {candidate_label(obj) if obj else 'none (click an object)'}")
    if obj and candidate_standing(obj)[1]:
        lines.append("**Verdict**: the shown candidate is refused (drawn as a grey outline); "
                     "Accept registers it anyway, marked as an operator override")
    counts = st.get("counts") or {}
    lines.append(f"**Objects**: {counts.get('objects', 0)} open, "
                 f"{counts.get('registered', len(st.get('registered') or []))} registered, "
                 f"{counts.get('undo', 0)} undo steps")
    fit_s = (st.get("timing_s") or {}).get("total")
    if fit_s is not None:
        lines.append(f"**Fit time**: {float(fit_s):.2f} s")
    node = st.get("node") or {}
    if node.get("last_message"):
        lines.append(f"**Last message**: {node['last_message']}")
    if node.get("last_error") and not stale_error:
        lines.append(f"**Last error**: {node['last_error']}")
    lines.append(f"**Cloud**: {cloud}")
    if last_action:
        lines.append(f"**Last action**: {last_action}")
    return "\n\n".join(lines)


# ============================================================================ page -> messages
def feedback_message(event_type: int, T_scene_model: np.ndarray, frame: str, client_id: str,
                     stamp=None) -> InteractiveMarkerFeedback:
    """Interactive-marker feedback on the engine's ``affordance_fit`` marker."""
    fb = InteractiveMarkerFeedback(client_id=client_id, marker_name=MARKER_NAME,
                                   event_type=event_type)
    fb.header.frame_id = frame
    if stamp is not None:
        fb.header.stamp = stamp
    fb.pose = matrix_to_pose(T_scene_model)
    return fb


def click_message(point: np.ndarray, frame: str, stamp=None) -> PointStamped:
    msg = PointStamped()
    msg.header.frame_id = frame
    if stamp is not None:
        msg.header.stamp = stamp
    msg.point.x, msg.point.y, msg.point.z = (float(v) for v in point)
    return msg


def check_port(host: str, port: int) -> None:
    """Raise AffordanceError when ``host:port`` cannot be listened on (in use, or no such
    address): the station serves exactly where it says, or not at all."""
    if not 1 <= int(port) <= 65535:
        raise AffordanceError(f"port must be within 1-65535, got {port}")
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET,
                       socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, int(port)))
        except OSError as exc:
            raise AffordanceError(f"cannot serve the page on {host}:{port}: {exc.strerror} "
                                  f"(choose another with -p port:=N / --port N)") from None


def check_parameters(p: dict) -> str:
    """'' when the station's parameters are usable, else what is wrong."""
    if p["up"] != "auto" and p["up"] not in UP_AXES:
        return f"up must be auto or one of {', '.join(UP_AXES)}, got {p['up']!r}"
    if p["color_by"] not in ("auto", "depth", "intensity"):
        return f"color_by must be auto, depth or intensity, got {p['color_by']!r}"
    if not 1000 <= int(p["display_points"]) <= 5_000_000:
        return f"display_points must be within 1000-5000000, got {p['display_points']}"
    for name, lo, hi in (("point_size", 1e-4, 1.0), ("fov_deg", 10.0, 120.0),
                         ("view_rate", 0.5, 60.0), ("cloud_rate", 0.1, 30.0),
                         ("click_cone_deg", 0.05, 10.0)):
        if not lo <= float(p[name]) <= hi:
            return f"{name} must be within {lo}-{hi}, got {p[name]}"
    for name in ("engine", "interactive_namespace"):
        if not str(p[name]).startswith("/") or str(p[name]).rstrip("/") == "":
            return f"{name} must be an absolute name like /affordance_engine, got {p[name]!r}"
    return ""


def gizmo_scale(vertices: np.ndarray) -> float:
    """Length (m) of the gizmo's arrows for a candidate mesh (vertices (N, 3) in its frame):
    0.8 of its largest extent, at least 8 cm."""
    return max(0.08, 0.8 * float(np.max(np.ptp(vertices, axis=0))))


def _wxyz(T: np.ndarray) -> np.ndarray:
    x, y, z, w = matrix_to_quat_xyzw(T[:3, :3])
    return np.array([w, x, y, z])


def _pose_of(handle) -> np.ndarray:
    w, x, y, z = (float(v) for v in handle.wxyz)
    T = np.eye(4)
    T[:3, :3] = quat_xyzw_to_matrix(np.array([x, y, z, w]))
    T[:3, 3] = np.asarray(handle.position, dtype=float)
    return T


# ============================================================================ the page (viser)
@dataclass(frozen=True)
class PageHandlers:
    """What the page sends to its host (called from viser's threads).

    ``click(origin, direction)``: a click ray in the world (cloud) frame; ``action(name)``: a
    button; ``select(template)``: a candidate picked by name; ``drag(phase, T_scene_model)``:
    the gizmo (phase start | update | end); ``camera(T_world_optical)``: a browser's camera.
    """

    click: Callable
    action: Callable
    select: Callable
    drag: Callable
    camera: Callable
    #: ``dimension(name, metres)``: a primitive's dimension set in its field
    dimension: Callable = lambda name, value: None


class StationPage:
    """The operator page: every viser call of the station is here."""

    def __init__(self, host: str, port: int, fov_deg: float, point_size: float,
                 handlers: PageHandlers):
        import viser  # here: only the station needs it
        self.h = handlers
        self.fov = math.radians(fov_deg)
        self.point_size = point_size
        self.server = viser.ViserServer(host=host, port=port, label="affordance station",
                                        verbose=False)
        self.server.initial_camera.fov = self.fov
        self._lock = threading.RLock()
        self._nodes: dict[str, tuple] = {}             # scene name -> (handle, digest)
        self._dragging = False
        self._gizmo = None
        self._gizmo_scale = 0.0
        self._view = None                              # (position, look_at, up) for new views
        self._unpointed: set = set()       # browsers not yet pointed at the first view
        self._options: dict[str, str] = {}
        gui = self.server.gui
        gui.add_markdown("**Affordance station** — click an object in the cloud to fit it; "
                         "drag the gizmo to correct the shown fit.")
        self.shown = gui.add_markdown("**Shown**: nothing selected")
        self.candidates = gui.add_dropdown("Candidate", options=("none",), initial_value="none")
        self.candidates.on_update(self._on_select)
        self.buttons = {}
        for action, label in ACTIONS:
            button = gui.add_button(label)
            button.on_click(lambda event, action=action: self.h.action(action))
            self.buttons[action] = button
        # a primitive's dimensions (m), shown while the shown candidate is one
        self.dimensions = {}
        for name in DIMENSIONS:
            box = gui.add_number(f"{name} (m)", initial_value=0.1, min=0.001, max=100.0,
                                 step=0.001, visible=False)
            box.on_update(lambda event, name=name: self._on_dimension(event, name))
            self.dimensions[name] = box
        self.status = gui.add_markdown("**Engine**: starting")
        self.server.scene.on_click()(self._on_click)
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    def stop(self) -> None:
        self.server.stop()

    # ------------------------------------------------------------------ browser -> host
    def _on_click(self, event) -> None:
        self.h.click(np.asarray(event.ray_origin, dtype=float),
                     np.asarray(event.ray_direction, dtype=float))

    def _on_select(self, event) -> None:
        if event.client is None:              # set by the station, not by an operator
            return
        template = self._options.get(self.candidates.value)
        if template:
            self.h.select(template)

    def _on_dimension(self, event, name: str) -> None:
        if event.client is None:              # set by the station, not by an operator
            return
        self.h.dimension(name, float(self.dimensions[name].value))

    def _on_connect(self, client) -> None:
        with self._lock:
            self._unpointed.add(client.client_id)
        client.camera.fov = self.fov

        @client.camera.on_update
        def _(camera) -> None:
            with self._lock:
                view = self._view if client.client_id in self._unpointed else None
            if view is not None and self._point_camera(client, view):
                with self._lock:
                    self._unpointed.discard(client.client_id)
            try:
                T = display.optical_pose(camera.wxyz, camera.position)
            except AffordanceError:
                return
            self.h.camera(T)

    def _on_disconnect(self, client) -> None:
        with self._lock:
            self._unpointed.discard(client.client_id)

    @staticmethod
    def _point_camera(client, view) -> bool:
        """Move a browser's camera to ``view``; False when it cannot be moved yet (viser knows a
        camera only once the browser has reported it: it is pointed on its next report)."""
        position, look_at, up = view
        try:
            client.camera.up_direction = tuple(up)
            client.camera.position = tuple(position)
            client.camera.look_at = tuple(look_at)
        except (AssertionError, ValueError):    # viser: "camera state not known yet"
            return False
        return True

    async def _on_gizmo(self, event) -> None:
        # async: viser runs it on its event loop, so the phases arrive in order
        phase = event.phase
        # one browser drags at a time; a drag "ended" because its browser went away (viser
        # synthesizes the end after removing the client) is cancelled, not released
        owner, cid = getattr(self, "_drag_client", None), event.client_id
        if phase == "start":
            if owner is not None and owner != cid and owner in self.server.get_clients():
                return
            self._drag_client = cid
        elif owner is not None and cid != owner:
            return
        if phase == "end":
            self._drag_client = None
            if cid is not None and cid not in self.server.get_clients():
                phase = "cancel"
        if phase == "start":
            self._dragging = True
        elif phase in ("end", "cancel"):
            self._dragging = False
        self.h.drag(phase, _pose_of(event.target))

    # ------------------------------------------------------------------ host -> browser
    def set_view(self, up: np.ndarray, position: np.ndarray, look_at: np.ndarray) -> None:
        """The world's up axis, and the first view of a cloud: for new browsers, and moves the
        cameras of the browsers already open."""
        self.server.scene.set_up_direction(tuple(float(v) for v in up))
        cam = self.server.initial_camera
        cam.up, cam.position, cam.look_at = tuple(up), tuple(position), tuple(look_at)
        with self._lock:
            self._view = (position, look_at, up)
            clients = dict(self.server.get_clients())
            self._unpointed |= set(clients)
        for cid, client in clients.items():
            if self._point_camera(client, (position, look_at, up)):
                with self._lock:
                    self._unpointed.discard(cid)

    def show_cloud(self, points: np.ndarray, colors: np.ndarray) -> None:
        self.server.scene.add_point_cloud("/cloud", points.astype(np.float32), colors,
                                          point_size=self.point_size, point_shape="square",
                                          precision="float32", point_shading="flat")

    def show_text(self, shown: str, status: str) -> None:
        if self.shown.content != shown:
            self.shown.content = shown
        if self.status.content != status:
            self.status.content = status

    def show_candidates(self, options: list[tuple[str, str]], shown: str | None) -> None:
        """The dropdown: the ranked candidates, the shown one selected."""
        texts = [text for text, _ in options] or ["none"]
        value = next((text for text, tpl in options if tpl == shown), texts[0])
        self._options = dict(options)
        if tuple(self.candidates.options) != tuple(texts):
            self.candidates.options = texts
        if self.candidates.value != value:
            self.candidates.value = value

    def show_dimensions(self, dimensions: dict | None) -> None:
        """The shown primitive's dimension fields (m), or none of them."""
        dimensions = dimensions or {}
        for name, box in self.dimensions.items():
            visible = name in dimensions
            if box.visible != visible:
                box.visible = visible
            if visible and abs(float(box.value) - float(dimensions[name])) > 1e-6:
                box.value = round(float(dimensions[name]), 4)

    def enable(self, connected: bool) -> None:
        for button in self.buttons.values():
            if button.disabled == connected:
                button.disabled = not connected

    def _mesh(self, name: str, d: MeshDrawing, T: np.ndarray, refused: bool = False) -> None:
        digest = d.digest + ("/refused" if refused else "")
        old = self._nodes.get(name)
        if old is not None and old[1] == digest:
            old[0].position, old[0].wxyz = T[:3, 3], _wxyz(T)
            return
        # opaque, its surface a few mm out: the fit shows in front of the points it was
        # fitted to (the pose sent back is the gizmo's, unaffected)
        vertices, faces = display.offset_surface(d.vertices, d.faces, MESH_MARGIN)
        # a candidate the verdict refuses is a translucent grey outline, not a solid fit
        style = {"wireframe": True, "opacity": REFUSED_OPACITY} if refused else {}
        handle = self.server.scene.add_mesh_simple(
            name, vertices, faces, color=REFUSED_RGB if refused else d.color, side="double",
            position=T[:3, 3], wxyz=_wxyz(T), **style)
        self._nodes[name] = (handle, digest)

    def show_pending_click(self, point: np.ndarray | None) -> None:
        """A marker and a "fitting…" label where the operator clicked, until the engine has
        handled the click (None removes them)."""
        with self._lock:
            for name in ("/pending/click", "/pending/label"):
                old = self._nodes.pop(name, None)
                if old is not None:
                    old[0].remove()
            if point is None:
                return
            p = np.asarray(point, dtype=float)
            self._nodes["/pending/click"] = (self.server.scene.add_icosphere(
                "/pending/click", radius=PENDING_RADIUS, color=PENDING_RGB, position=p), "")
            self._nodes["/pending/label"] = (self.server.scene.add_label(
                "/pending/label", "fitting…", position=p, anchor="bottom-center"), "")

    def _other(self, name: str, d) -> None:
        key = repr(d)
        if isinstance(d, TextDrawing):
            key = d.text + repr(np.round(d.position, 4).tolist())
        else:
            key = repr((np.round(d.position, 4).tolist(), d.radius, d.color))
        old = self._nodes.get(name)
        if old is not None and old[1] == key:
            return
        if isinstance(d, TextDrawing):
            handle = self.server.scene.add_label(name, d.text, position=d.position,
                                                 anchor="top-center")
        else:
            handle = self.server.scene.add_icosphere(name, radius=d.radius, color=d.color,
                                                     position=d.position)
        self._nodes[name] = (handle, key)

    def show_scene(self, drawings: dict, active_id: int | None, label: str,
                   refused: frozenset = frozenset()) -> None:
        """Draw the engine's markers: the active object's candidate under the gizmo (so a drag
        moves it in the browser at once), the rest where the engine put them; ``label`` replaces
        the active candidate's label text; the candidates of the objects in ``refused`` are
        drawn as outlines."""
        with self._lock:
            wanted = {name for name in self._nodes if name.startswith("/pending/")}
            fit = drawings.get(("candidate", active_id)) if active_id is not None else None
            if fit is not None and isinstance(fit, MeshDrawing):
                self._place_gizmo(fit)
            elif self._gizmo is not None and not self._dragging:
                self._gizmo.visible = False
            for (ns, mid), d in sorted(drawings.items(), key=lambda kv: (kv[0][0], kv[0][1])):
                active = mid == active_id and ns.startswith("candidate") and fit is not None
                if isinstance(d, MeshDrawing):
                    outline = mid in refused and ns.startswith("candidate")
                    if active:
                        name = f"/fit/{ns}"
                        self._mesh(name, d, invert(fit.T) @ d.T, outline)
                    else:
                        name = f"/objects/{ns}_{mid}"
                        self._mesh(name, d, d.T, outline)
                elif isinstance(d, TextDrawing):
                    if active and ns == "candidate_label":
                        d = TextDrawing(label, d.position, d.frame)
                    name = f"/labels/{ns}_{mid}"
                    self._other(name, d)
                else:
                    name = f"/objects/{ns}_{mid}"
                    self._other(name, d)
                wanted.add(name)
            for name in list(self._nodes):
                if name not in wanted:
                    handle, _ = self._nodes.pop(name)
                    handle.remove()

    def _place_gizmo(self, fit: MeshDrawing) -> None:
        scale = gizmo_scale(fit.vertices)
        if self._gizmo is None or abs(scale - self._gizmo_scale) > 1e-6:
            if self._dragging:
                return
            if self._gizmo is not None:
                self._gizmo.remove()
                self._nodes = {k: v for k, v in self._nodes.items() if not k.startswith("/fit/")}
            self._gizmo = self.server.scene.add_transform_controls(
                "/fit", scale=scale, depth_test=False, disable_sliders=True,
                position=fit.T[:3, 3], wxyz=_wxyz(fit.T))
            self._gizmo.on_update(self._on_gizmo)
            self._gizmo_scale = scale
        elif not self._dragging:
            self._gizmo.position, self._gizmo.wxyz = fit.T[:3, 3], _wxyz(fit.T)
        if not self._gizmo.visible:
            self._gizmo.visible = True


# ============================================================================ the node (rclpy)
@dataclass
class _Inbox:
    """What arrived for the page worker (guarded by the node's lock)."""

    cloud: PointCloud2 | None = None
    markers: list = field(default_factory=list)
    status: dict | None = None
    status_new: bool = False


class StationNode(Node):
    def __init__(self):
        super().__init__("affordance_station")
        p = {name: self.declare_parameter(name, default).value
             for name, (default, _) in PARAMETERS.items()}
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
        self._cloud_points = np.zeros((0, 3))
        self._cloud_frame = ""
        self._cloud_text = "none received yet on " + self.resolve_topic_name("points")
        self._cloud_shown_at = -math.inf
        self._thin_voxel = None                      # the last cloud's display voxel edge
        self._drawn_label = ""                       # the open object's label as last drawn
        self._drawn_refused = frozenset()            # objects last drawn as refused outlines
        self._first_view_frame = None
        self._last_action = ""
        self._view_pending = None
        self._view_sent_at = -math.inf
        self._view_sent = None                       # T_world_optical (4x4) last on view_pose
        self._view_readers = 0                       # view_pose subscriptions when last looked
        self._drag_id = f"affordance_station_{int(time.time() * 1e6):x}"
        self._drag_last = None                       # (T, time) of the drag in progress
        self._calls: deque = deque()                 # buttons waiting for the call in flight
        self._calling = None                         # (action, time sent) of the call in flight
        self._refresh = True
        self._pending = None               # (point, click note, handled count, time) being fitted
        self._pending_drawn = None
        self._seen_error = ("", "")        # (last_error, last_message when it first showed)

        self.create_subscription(
            PointCloud2, "points", self._on_cloud,
            qos.cloud(p["points_reliable"]))
        self.status_topic = f"{self.engine}/status"
        self.create_subscription(String, self.status_topic, self._on_status, LATCHED)
        markers_qos = qos.latched(10)
        self.create_subscription(MarkerArray, f"{self.engine}/markers", self._on_markers,
                                 markers_qos)
        self.pub_click = self.create_publisher(PointStamped, "clicked_point", INPUT)
        self.pub_view = self.create_publisher(PoseStamped, "view_pose", INPUT)
        self.pub_select = self.create_publisher(String, f"{self.engine}/select_model", INPUT)
        self.pub_dimension = self.create_publisher(String, f"{self.engine}/set_dimension", INPUT)
        ns = "/" + p["interactive_namespace"].strip("/")
        self.pub_feedback = self.create_publisher(InteractiveMarkerFeedback, f"{ns}/feedback",
                                                  INPUT)
        self.triggers = {action: self.create_client(Trigger, f"{self.engine}/{action}")
                        for action, _ in ACTIONS}
        # the operator only: an access secret, same-origin websockets, bounded frames and
        # message rates, no share tunnel, no outbound connections (ros/station/access.py)
        self.access = station_access.StationAccess(
            station_access.configured_secret(p["access_secret"]), p["host"], p["port"],
            log=self.get_logger().warning)
        station_access.forbid_outbound([p["host"]], log=self.get_logger().error)
        with station_access.guarded(self.access):
            self.page = StationPage(p["host"], p["port"], p["fov_deg"], p["point_size"],
                                    PageHandlers(click=self._click, action=self._action,
                                                 select=self._select, drag=self._drag,
                                                 camera=self._camera,
                                                 dimension=self._dimension))
        station_access.disable_share(self.page.server, self.get_logger().warning)
        self.access.port = self.page.port
        self.url = self.access.url()
        self._worker = threading.Thread(target=self._run, name="station-page", daemon=True)
        self._worker.start()
        self.get_logger().info(f"operator station on {self.url} (engine {self.engine})")

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
            points, frame = self._cloud_points, self._cloud_frame
        try:
            i = display.snap_ray(points, origin, direction,
                                 cone_rad=math.radians(self.p["click_cone_deg"]))
        except AffordanceError as exc:
            self._note(f"click ignored: {exc}")
            return
        if i is None:
            self._note("click missed the cloud: click on a point of the cloud"
                       if len(points) else "click ignored: no cloud received yet")
            return
        point = points[i]
        note = f"clicked ({', '.join(f'{v:.3f}' for v in point)}) in '{frame}'"
        with self._lock:     # fitting until the engine's status counts one more handled click
            self._pending = (point.copy(), note, self._clicks_handled(self._status),
                             time.monotonic())
        self.pub_click.publish(click_message(point, frame, self.get_clock().now().to_msg()))
        self._note(f"{note}: fitting")

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
            self._note(f"{action}: not sent, the engine's {client.srv_name} service is not "
                       f"available")
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
        except Exception as exc:          # the call failed in rclpy (engine gone mid-call)
            text = f"{action}: failed ({exc})"
        with self._lock:
            if self._calling is None or self._calling[0] != action:
                return                    # given up on already (see _step)
            self._calling = None
        self._note(text)
        self._next_call()

    def _give_up_calls(self, why: str) -> None:
        """Forget the call in flight and the queued ones (the engine went away or does not
        answer): the operator sees which were lost."""
        with self._lock:
            lost = ([self._calling[0]] if self._calling else []) + list(self._calls)
            self._calling, self._calls = None, deque()
        if lost:
            self._note(f"{', '.join(lost)}: no answer ({why})")

    def _select(self, template: str) -> None:
        self.pub_select.publish(String(data=template))
        self._note(f"select {template}: sent")

    def _dimension(self, name: str, value: float) -> None:
        if not math.isfinite(value) or value <= 0:
            self._note(f"{name}: {value!r} is not a size in metres")
            return
        self.pub_dimension.publish(String(data=f"{name}={value:.6g}"))
        self._note(f"{name} {value * 1000:.1f} mm: sent")

    def _drag(self, phase: str, T: np.ndarray) -> None:
        F = InteractiveMarkerFeedback
        if phase == "cancel":       # no keep-alives: the engine cancels the silent drag
            with self._lock:
                self._drag_last = None
            self._note("the dragging browser went away: its drag is cancelled")
            self.get_logger().info("a browser went away mid-drag: its drag is cancelled (not "
                                   "released)")
            return
        kind = {"start": F.MOUSE_DOWN, "update": F.POSE_UPDATE, "end": F.MOUSE_UP}.get(phase)
        if kind is None or not self._cloud_frame:
            return
        frame = self._frame()
        self.pub_feedback.publish(feedback_message(kind, T, frame, self._drag_id,
                                                   self.get_clock().now().to_msg()))
        with self._lock:
            self._drag_last = None if phase == "end" else (T, time.monotonic())
        if phase == "end":
            self._note("correction sent: refitting from the released pose")

    def _camera(self, T_world_optical: np.ndarray) -> None:
        with self._lock:
            self._view_pending = T_world_optical
        self._wake.set()

    def _note(self, text: str) -> None:
        with self._lock:
            self._last_action = text
            self._refresh = True
        self._wake.set()

    def _frame(self) -> str:
        return (self._status or {}).get("frame_id") or self._cloud_frame

    # ------------------------------------------------------------------ the page worker
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.1)
            self._wake.clear()
            try:
                self._step()
            except Exception as exc:        # the page must outlive one bad update
                self.get_logger().error(f"station: page update failed: {exc!r}")
                time.sleep(0.2)

    def _step(self) -> None:
        now = time.monotonic()
        with self._lock:
            inbox, self._inbox = self._inbox, _Inbox()
            view, drag = self._view_pending, self._drag_last
            refresh, self._refresh = self._refresh, False
        if inbox.cloud is not None:
            if now - self._cloud_shown_at >= 1.0 / self.p["cloud_rate"]:
                self._show_cloud(inbox.cloud)
                self._cloud_shown_at = now
                refresh = True
            else:                           # too soon: keep it for the next turn
                with self._lock:
                    if self._inbox.cloud is None:
                        self._inbox.cloud = inbox.cloud
        if inbox.status_new:
            self._status = inbox.status
            refresh = True
        with self._lock:
            pending = self._pending
            if pending is not None and (self._clicks_handled(self._status) > pending[2] or
                                        now - pending[3] > CALL_TIMEOUT_S):
                self._pending = None          # handled (fitted or refused): the status says
                if self._last_action == f"{pending[1]}: fitting":
                    self._last_action = ""    # what happened is in Shown and Last message
                refresh = True
            pending = self._pending
        point = None if pending is None else pending[0]
        if point is not self._pending_drawn:
            self.page.show_pending_click(point)
            self._pending_drawn = point
            self.get_logger().info("fitting marker shown" if pending else
                                   "fitting marker cleared")
        connected = self.count_publishers(self.status_topic) > 0
        if connected != self._connected:
            self._connected, refresh = connected, True
        with self._lock:
            calling = self._calling
        if calling is not None and (not connected or now - calling[1] > CALL_TIMEOUT_S):
            self._give_up_calls("the engine is not running" if not connected else
                                f"waited {CALL_TIMEOUT_S:.0f} s")
        if refresh:                     # the panel first: the meshes can take longer
            self._render_panel()
        for msg in inbox.markers:
            self._drawings = apply_markers(self._drawings, msg)
        if refresh or inbox.markers:
            self._render_scene()
        # view_pose is volatile and the camera is only reported when it moves: a subscriber that
        # joins after the browser's camera came to rest (an engine started later) gets the view
        # it would otherwise wait for until the operator moves the camera
        readers = self.pub_view.get_subscription_count()
        if readers > self._view_readers and view is None and self._view_sent is not None:
            with self._lock:
                if self._view_pending is None:
                    self._view_pending = self._view_sent
                view = self._view_pending
        self._view_readers = readers
        if view is not None and self._frame() and \
                now - self._view_sent_at >= 1.0 / self.p["view_rate"]:
            with self._lock:        # (a newer view the camera sent meanwhile stays pending)
                if self._view_pending is view:
                    self._view_pending = None
            self.pub_view.publish(pose_stamped(view, self._frame(),
                                               self.get_clock().now().to_msg()))
            self._view_sent_at, self._view_sent = now, view
        if drag is not None and now - drag[1] >= DRAG_KEEP_ALIVE_S:
            self.pub_feedback.publish(feedback_message(InteractiveMarkerFeedback.KEEP_ALIVE,
                                                       drag[0], self._frame(), self._drag_id))
            with self._lock:
                if self._drag_last is drag:
                    self._drag_last = (drag[0], now)

    def _render_panel(self) -> None:
        status = self._status if self._connected else None
        obj = active_object(self._status)
        label = candidate_label(obj)
        with self._lock:
            last_action = self._last_action
            pending = self._pending
        node = (self._status or {}).get("node") or {}
        error, message = node.get("last_error") or "", node.get("last_message") or ""
        if error != self._seen_error[0]:
            self._seen_error = (error, message)
        # an error goes stale once the engine reports something after it
        stale = bool(error) and message != self._seen_error[1]
        fitting = "" if pending is None else f"{pending[1]} — the engine is fitting it"
        self.page.show_text(f"**Shown**: {label}" if label else "**Shown**: nothing selected",
                            status_markdown(status, self._connected, self.engine,
                                            self._cloud_text, last_action, fitting, stale))
        self.page.show_candidates(candidate_options(obj),
                                  obj["candidates"][obj["shown"]]["template"] if obj else None)
        shown = obj["candidates"][obj["shown"]] if obj else {}
        self.page.show_dimensions(shown.get("dimensions") if shown.get("primitive") else None)
        self.page.enable(self._connected)

    def _render_scene(self) -> None:
        obj = active_object(self._status)
        label = candidate_label(obj)
        frame = self._frame()
        drawings = {k: d for k, d in self._drawings.items()
                    if not frame or not d.frame or d.frame.lstrip("/") == frame.lstrip("/")}
        refused = frozenset(o.get("id") for o in (self._status or {}).get("objects") or []
                            if candidate_standing(o)[1])
        self.page.show_scene(drawings, obj["id"] if obj else None, label, refused)
        if refused != self._drawn_refused:
            self._drawn_refused = refused
            self.get_logger().info(f"drawn as refused outlines: objects {sorted(refused)}")
        drawn = drawings.get(("candidate_label", obj["id"])) if obj else None
        if drawn is not None and drawn.text != self._drawn_label:
            # what the 3D view now draws for the open object (from the engine's markers; the
            # panel's label follows the status, which comes first)
            self._drawn_label = drawn.text
            self.get_logger().info(f"drawn: object {obj['id']} as {drawn.text}")

    def _show_cloud(self, msg: PointCloud2) -> None:
        try:
            pts, _ = pointcloud2_to_xyz(msg)
        except ConversionError as exc:
            self._cloud_text = f"the latest cloud is unusable ({exc})"
            self.get_logger().warning(f"points: {exc}")
            return
        finite = np.all(np.isfinite(pts), axis=1)
        if not finite.all():
            pts = pts[finite]
        thinned = display.thin(pts, int(self.p["display_points"]),
                               start_voxel=self._thin_voxel) if len(pts) else \
            display.Thinned(np.zeros(0, dtype=np.int64), 0.0)
        self._thin_voxel = thinned.voxel or None
        keep = thinned.indices
        values = None                   # the colour values of the shown points only
        if self.p["color_by"] in ("auto", "intensity"):
            values = pointcloud2_field(msg, "intensity")
            if values is not None:
                values = (values[finite] if not finite.all() else values)[keep]
        if values is None:
            if self.p["color_by"] == "intensity":
                self._cloud_text = "the cloud has no intensity field: coloured by depth"
            shown = pts[keep]
            values = np.sqrt(np.einsum("ij,ij->i", shown, shown))
        frame = msg.header.frame_id
        with self._lock:
            self._cloud_points, self._cloud_frame = pts, frame
        if frame != self._first_view_frame and len(pts):
            self._first_view_frame = frame
            up = np.array(UP_AXES[self.p["up"]] if self.p["up"] != "auto" else
                          ((0, -1, 0) if "optical" in frame else (0, 0, 1)), dtype=float)
            position, look_at = display.initial_view(pts, up, math.radians(self.p["fov_deg"]))
            self.page.set_view(up, position, look_at)
        self.page.show_cloud(pts[keep], display.scalar_colors(values))
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self._cloud_text = (f"{len(pts):,} points in '{frame}', {len(keep):,} shown "
                            f"(stamp {stamp:.3f})")

    def shutdown(self) -> None:
        self._stop.set()
        self._worker.join(timeout=2.0)
        self.page.stop()


def main(args=None) -> int:
    """Console script ``affordance_station`` (takes ``--ros-args``)."""
    return run_node(StationNode, "affordance_station", args,
                    shutdown=lambda node: node.shutdown())


if __name__ == "__main__":
    raise SystemExit(main())
