# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The operator page the station serves: every viser call of the station is here
(:class:`StationPage`); what the browser does reaches the station through :class:`PageHandlers`."""

from __future__ import annotations

import contextlib
import math
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core import display
from ...core.errors import AffordanceError
from ...core.transforms import invert, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from .state import LineDrawing, MeshDrawing, TextDrawing

__all__ = [
    "StationPage",
    "PageHandlers",
    "gizmo_scale",
    "ACTIONS",
    "DIMENSIONS",
    "LABEL_ANCHOR",
    "DETAILS",
]

#: a primitive's dimensions, each a field of the page (m)
DIMENSIONS = ("x", "y", "z", "radius", "length")
#: the buttons, in page order: (engine service, button label)
ACTIONS = (
    ("previous_model", "Previous"),
    ("next_model", "Next"),
    ("accept", "Accept"),
    ("refit", "Refit"),
    ("undo", "Undo"),
    ("discard", "Discard"),
    ("save", "Save"),
    ("joint_minus", "Joint −"),
    ("joint_plus", "Joint +"),
)
MESH_MARGIN = 0.005  # m: meshes are drawn this far out of their surface
REFUSED_RGB = (150, 150, 150)  # a candidate the verdict refuses: a grey outline ...
REFUSED_OPACITY = 0.5  # ... half transparent
PENDING_RGB = (255, 140, 0)  # the click being fitted
PENDING_RADIUS = 0.008  # m
PATH_RGB = (255, 60, 200)  # the path the engine answered
LINE_PX = 3.0  # width of the waypoints' and the path's lines (pixels)
#: the 3D labels hang left of and below their point: the panel lies over the right of the view,
#: so a label never runs under it (one centred on an object near the panel did)
LABEL_ANCHOR = "top-right"
#: the folder holding the reasons (engine state, why a fit is unsettled, counts, the cloud, the
#: last reply): closed by default, the headline says what matters in one sentence
DETAILS = "Details"
#: the gizmo's arrows reach this fraction of the shown candidate's largest extent from its
#: centre, so its handles stay within the object's own outline on the screen whatever the zoom
#: (at 0.8 of it and drawn over everything, its rings covered the neighbours: a click meant for
#: one moved the shown fit instead); at least GIZMO_MIN_M
GIZMO_FRACTION = 0.45
GIZMO_MIN_M = 0.03


def gizmo_scale(vertices: np.ndarray) -> float:
    """Length (m) of the gizmo's arrows for a candidate mesh (vertices (N, 3) in its frame):
    GIZMO_FRACTION of its largest extent, at least GIZMO_MIN_M."""
    return max(GIZMO_MIN_M, GIZMO_FRACTION * float(np.max(np.ptp(vertices, axis=0))))


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
    #: ``path(state)``: the path of the shown object's waypoint to the named state asked for
    path: Callable = lambda state: None
    #: ``waypoints(shown, drawn)``: the waypoints toggle changed (``drawn``: grippers drawn)
    waypoints: Callable = lambda shown, drawn: None
    #: ``move_sensor()``: "Move sensor here" pressed (send the suggested view)
    move_sensor: Callable = lambda: None
    #: ``colors(depth)``: the "Depth colours" toggle changed (True: colour the cloud by depth)
    colors: Callable = lambda depth: None


class StationPage:
    """The operator page: every viser call of the station is here."""

    def __init__(
        self,
        host: str,
        port: int,
        fov_deg: float,
        point_size: float,
        handlers: PageHandlers,
        depth_colors: bool = False,
    ):
        import io

        import viser  # here: only the station needs it

        self.h = handlers
        self.fov = math.radians(fov_deg)
        self.point_size = point_size
        # viser prints a banner with its address, which answers 403 without the access secret:
        # the station prints the one URL that works itself (StationNode)
        with contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(
                host=host, port=port, label="affordance station", verbose=False
            )
        self.server.initial_camera.fov = self.fov
        self._lock = threading.RLock()
        self._nodes: dict[str, tuple] = {}  # scene name -> (handle, digest)
        self._dragging = False
        self._gizmo = None
        self._gizmo_scale = 0.0
        self._view = None  # (position, look_at, up) for new views
        self._unpointed: set = set()  # browsers not yet pointed at the first view
        self._options: dict[str, str] = {}
        gui = self.server.gui
        # one sentence: what is shown, its verdict, what the operator can do (state.headline)
        self.headline = gui.add_markdown("Click an object in the cloud to fit it.")
        self.candidates = gui.add_dropdown("Candidate", options=("none",), initial_value="none")
        self.candidates.on_update(self._on_select)
        self.buttons = {}
        for action, label in ACTIONS:
            button = gui.add_button(label)
            button.on_click(lambda event, action=action: self.h.action(action))
            self.buttons[action] = button
        # shown while the open object is unsettled and the engine suggests where to look from
        self.move_sensor = gui.add_button(
            "Move sensor here",
            visible=False,
            hint="ask whatever moves the sensor to scan from the suggested view",
        )
        self.move_sensor.on_click(lambda event: self.h.move_sensor())
        # a primitive's dimensions (m), shown while the shown candidate is one; to 0.1 mm (the
        # page keeps as many decimals as the step has: at 0.001 a typed 0.0669 became 0.066)
        self.dimensions = {}
        for name in DIMENSIONS:
            box = gui.add_number(
                f"{name} (m)", initial_value=0.1, min=0.001, max=100.0, step=0.0001, visible=False
            )
            box.on_update(lambda event, name=name: self._on_dimension(event, name))
            self.dimensions[name] = box
        # the engine's waypoints (grippers) on or off; the path of the shown object's waypoint
        # to a named state, as the engine answers it
        self.waypoints = gui.add_checkbox("Waypoints", initial_value=True)
        self.waypoints.on_update(self._on_waypoints)
        self.path_state = gui.add_text("Path to state", initial_value="")
        self.path_button = gui.add_button("Show path")
        self.path_button.on_click(lambda event: self.h.path(str(self.path_state.value).strip()))
        # the scan's own colours, or depth colours (the shapes stand out in a dull scan)
        self.depth_colors = gui.add_checkbox("Depth colours", initial_value=bool(depth_colors))
        self.depth_colors.on_update(lambda event: self.h.colors(bool(self.depth_colors.value)))
        # the reasons, on demand
        with gui.add_folder(DETAILS, expand_by_default=False):
            self.status = gui.add_markdown("**Engine**: starting")
            self.show_view = gui.add_checkbox("Suggested view", initial_value=False)
            self.show_view.on_update(self._on_show_view)
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
        self.h.click(
            np.asarray(event.ray_origin, dtype=float), np.asarray(event.ray_direction, dtype=float)
        )

    def _on_select(self, event) -> None:
        if event.client is None:  # set by the station, not by an operator
            return
        template = self._options.get(self.candidates.value)
        if template:
            self.h.select(template)

    def _on_dimension(self, event, name: str) -> None:
        if event.client is None:  # set by the station, not by an operator
            return
        self.h.dimension(name, float(self.dimensions[name].value))

    def _on_show_view(self, event) -> None:
        shown = bool(self.show_view.value)
        with self._lock:
            for name, (handle, _) in self._nodes.items():
                if "suggested_view" in name:
                    handle.visible = shown

    def _visible(self, name: str) -> bool:
        """Whether a drawing the toggles govern is shown: the waypoints ("Waypoints"), a
        suggested view's frustum ("Suggested view" in the details)."""
        if "_waypoints_" in name:
            return bool(self.waypoints.value)
        if "suggested_view" in name:
            return bool(self.show_view.value)
        return True

    def _on_waypoints(self, event) -> None:
        shown = bool(self.waypoints.value)
        with self._lock:
            handles = [h for name, (h, _) in self._nodes.items() if "_waypoints_" in name]
            for handle in handles:
                handle.visible = shown
        self.h.waypoints(shown, len(handles))

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
        except (AssertionError, ValueError):  # viser: "camera state not known yet"
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

    def set_up(self, up: np.ndarray) -> None:
        """The world's up axis, for new browsers and the open ones, without moving their
        cameras (each rolls its view upright about its line of sight)."""
        up = tuple(float(v) for v in up)
        self.server.scene.set_up_direction(up)
        self.server.initial_camera.up = up
        with self._lock:
            if self._view is not None:
                self._view = (self._view[0], self._view[1], np.asarray(up))
            clients = dict(self.server.get_clients())
        for client in clients.values():
            with contextlib.suppress(AssertionError, ValueError):  # camera not known yet
                client.camera.up_direction = up

    def show_cloud(self, points: np.ndarray, colors: np.ndarray) -> None:
        self.server.scene.add_point_cloud(
            "/cloud",
            points.astype(np.float32),
            colors,
            point_size=self.point_size,
            point_shape="square",
            precision="float32",
            point_shading="flat",
        )

    def show_text(self, headline: str, status: str) -> None:
        """The headline (one sentence) and the details (the reasons)."""
        if self.headline.content != headline:
            self.headline.content = headline
        if self.status.content != status:
            self.status.content = status

    def flush(self) -> None:
        """Send what the page was told so far in a message window of its own."""
        self.server.flush()

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

    def show_move_sensor(self, shown: bool) -> None:
        """The "Move sensor here" button, shown or hidden."""
        if self.move_sensor.visible != shown:
            self.move_sensor.visible = shown

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
            name,
            vertices,
            faces,
            color=REFUSED_RGB if refused else d.color,
            side="double",
            position=T[:3, 3],
            wxyz=_wxyz(T),
            **style,
        )
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
            self._nodes["/pending/click"] = (
                self.server.scene.add_icosphere(
                    "/pending/click", radius=PENDING_RADIUS, color=PENDING_RGB, position=p
                ),
                "",
            )
            self._nodes["/pending/label"] = (
                self.server.scene.add_label(
                    "/pending/label", "fitting…", position=p, anchor="bottom-center"
                ),
                "",
            )

    def show_path(self, points: np.ndarray | None) -> None:
        """The path the engine answered: its poses' positions (N, 3) in the cloud frame as a
        polyline (None or fewer than 2: none)."""
        with self._lock:
            old = self._nodes.pop("/path", None)
            if old is not None:
                old[0].remove()
            if points is None or len(points) < 2:
                return
            p = np.asarray(points, dtype=np.float32)
            segments = np.stack([p[:-1], p[1:]], axis=1)
            colors = np.broadcast_to(np.array(PATH_RGB, np.uint8), segments.shape).copy()
            self._nodes["/path"] = (
                self.server.scene.add_line_segments(
                    "/path", segments, colors, thickness=LINE_PX, thickness_units="screen"
                ),
                "",
            )

    def _other(self, name: str, d) -> None:
        key = repr(d)
        if isinstance(d, TextDrawing):
            key = d.text + repr(np.round(d.position, 4).tolist())
        elif isinstance(d, LineDrawing):
            key = d.segments.tobytes() + d.colors.tobytes()
        else:
            key = repr((np.round(d.position, 4).tolist(), d.radius, d.color))
        old = self._nodes.get(name)
        if old is not None and old[1] == key:
            return
        if isinstance(d, TextDrawing):
            handle = self.server.scene.add_label(
                name, d.text, position=d.position, anchor=LABEL_ANCHOR
            )
        elif isinstance(d, LineDrawing):  # waypoint grippers, a view (as their toggles say)
            handle = self.server.scene.add_line_segments(
                name,
                d.segments,
                d.colors,
                thickness=LINE_PX,
                thickness_units="screen",
                visible=self._visible(name),
            )
        else:
            handle = self.server.scene.add_icosphere(
                name, radius=d.radius, color=d.color, position=d.position
            )
        self._nodes[name] = (handle, key)

    def show_scene(
        self, drawings: dict, active_id: int | None, label: str, refused: frozenset = frozenset()
    ) -> None:
        """Draw the engine's markers: the active object's candidate under the gizmo (so a drag
        moves it in the browser at once), the rest where the engine put them; ``label`` replaces
        the active candidate's label text; the candidates of the objects in ``refused`` are
        drawn as outlines."""
        with self._lock:
            wanted = {name for name in self._nodes if name.startswith(("/pending/", "/path"))}
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
                "/fit",
                scale=scale,
                depth_test=False,
                disable_sliders=True,
                position=fit.T[:3, 3],
                wxyz=_wxyz(fit.T),
            )
            self._gizmo.on_update(self._on_gizmo)
            self._gizmo_scale = scale
        elif not self._dragging:
            self._gizmo.position, self._gizmo.wxyz = fit.T[:3, 3], _wxyz(fit.T)
        if not self._gizmo.visible:
            self._gizmo.visible = True
