# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Depth-camera simulation of taskboard scenes with ground truth.

A scene is rendered by ray casting (Open3D ``RaycastingScene``) from a pinhole camera with the
intrinsics of a real sensor. Occlusion between objects, self-occlusion and back faces come out of
the ray casting; the sensor model adds depth noise that grows with distance and incidence angle
and drops returns at grazing angles.

Frames: ``board`` has its origin at the centre of the panel surface, +z out of the panel. The
scene frame is the camera's optical frame (x right, y down, z forward), which is the frame of the
cloud a ROS driver publishes.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np
import trimesh
import yaml

from ..core.errors import AffordanceError
from ..core.files import read_yaml, write_atomically
from ..core.templates import TemplateLibrary, mesh_distance
from ..core.transforms import axis_angle_matrix, invert, make_T

__all__ = [
    "CameraIntrinsics",
    "NoiseModel",
    "FaultModel",
    "DepthCamera",
    "SimulatedObject",
    "SimulatedScene",
    "simulate_taskboard",
    "write_scene",
    "load_truth",
    "mesh_distance",
    "ply_bytes",
    "SimulatedOperator",
    "failures",
    "operator_correction",
    "truth_joints",
    "POSE_TOL_M",
    "POSE_TOL_RAD",
    "PANEL_SIZE",
    "panel_mesh",
    "KINECT_NFOV",
    "SIZED",
    "sized_library",
]

MAX_TRUTH_BYTES = 20_000_000  #: a truth.yaml larger than this is not one (bytes)
#: a registration is right when its template is the true one and its pose is within these of the
#: truth (symmetry-aware): the paper's and the benchmark's success criterion
POSE_TOL_M = 0.005
POSE_TOL_RAD = math.radians(5.0)


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def fov_deg(self) -> tuple[float, float]:
        return (
            math.degrees(2 * math.atan(self.width / (2 * self.fx))),
            math.degrees(2 * math.atan(self.height / (2 * self.fy))),
        )


#: Azure Kinect depth camera, NFOV unbinned mode: 640x576 pixels, about 75 x 65 degrees.
KINECT_NFOV = CameraIntrinsics(width=640, height=576, fx=417.0, fy=452.0, cx=319.5, cy=287.5)


@dataclass(frozen=True)
class NoiseModel:
    """Axial depth noise of a time-of-flight / structured-light sensor (after Nguyen et al. 2012):

    sigma(z, theta) = a + b * (z - z0)^2 + c / sqrt(z) * theta^2 / (pi/2 - theta)^2   [m]

    with theta the incidence angle. Returns with theta above ``drop_start_deg`` are dropped with a
    probability rising linearly to 1 at ``drop_full_deg``.
    """

    a: float = 0.0012
    b: float = 0.0019
    z0: float = 0.4
    c: float = 0.0001
    drop_start_deg: float = 70.0
    drop_full_deg: float = 85.0

    def sigma(self, z: np.ndarray, theta: np.ndarray | float = 0.0) -> np.ndarray:
        theta = np.minimum(np.asarray(theta, dtype=float), math.radians(89.0))
        return (
            self.a
            + self.b * (np.asarray(z) - self.z0) ** 2
            + self.c / np.sqrt(z) * theta**2 / (math.pi / 2 - theta) ** 2
        )


@dataclass(frozen=True)
class FaultModel:
    """What real depth cameras do to a scan besides :class:`NoiseModel`'s noise (the paper's
    Kinect run failed on such distortion). Every option is a documented knob; ``off`` values
    (0) switch one fault off.

    * ``flying_pixels``: probability that a pixel on a depth edge (a step of more than
      ``edge_jump`` m to a neighbour) returns a mixed depth -- a point anywhere between the
      foreground and the background (labelled -2 in the label image: no object's);
    * ``distortion``: RMS (m) of a smooth depth error across the image (a sum of
      ``distortion_waves`` random low-frequency waves, at most that many cycles across it):
      1 mm RMS swings by about 5 mm from trough to peak;
    * ``dark_patches`` dark patches of radius up to ``dark_radius`` pixels at random places,
      where a return drops with probability ``dark_dropout``;
    * ``grazing_start_deg``: returns drop at grazing angles from this incidence on (rising to
      certain at ``NoiseModel.drop_full_deg``; the clean model starts at its own
      ``drop_start_deg``; at or beyond ``drop_full_deg``: off);
    * ``noise_scale``: the range-dependent noise of :class:`NoiseModel` times this.
    """

    flying_pixels: float = 0.6
    edge_jump: float = 0.02
    distortion: float = 0.001
    distortion_waves: int = 3
    dark_patches: int = 6
    dark_radius: int = 40
    dark_dropout: float = 0.7
    grazing_start_deg: float = 60.0
    noise_scale: float = 1.5


class DepthCamera:
    """Renders organized point clouds of posed meshes by ray casting; ``faults`` (a
    :class:`FaultModel`) adds what real depth cameras do to a scan."""

    def __init__(
        self,
        intrinsics: CameraIntrinsics = KINECT_NFOV,
        noise: NoiseModel | None = None,
        faults: FaultModel | None = None,
    ):
        self.intrinsics = intrinsics
        self.noise = noise if noise is not None else NoiseModel()
        self.faults = faults
        u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
        #: the ray through each pixel, (H, W, 3) in the optical frame, scaled to z = 1 (a hit's
        #: distance along it is its depth); read-only
        self.ray_directions = np.stack(
            [
                (u - intrinsics.cx) / intrinsics.fx,
                (v - intrinsics.cy) / intrinsics.fy,
                np.ones_like(u, dtype=float),
            ],
            axis=-1,
        )
        self.ray_directions.setflags(write=False)

    def render(
        self,
        meshes,
        rng: np.random.Generator | None,
        max_range: float = 4.0,
        return_normals: bool = False,
    ):
        """Cast one ray per pixel.

        ``meshes``: sequence of (trimesh.Trimesh, T_cam_mesh 4x4). Returns ``(points, labels)``:
        points (H, W, 3) float32 in the camera optical frame with NaN where there is no return,
        labels (H, W) int32 with the index of the mesh hit, -1 for none. ``rng=None`` renders
        without noise or dropouts. ``return_normals`` adds the (H, W, 3) surface normals.
        """
        import open3d as o3d  # local: ray casting is the only user

        scene = o3d.t.geometry.RaycastingScene()
        for mesh, T in meshes:
            verts = np.asarray(mesh.vertices) @ T[:3, :3].T + T[:3, 3]
            scene.add_triangles(
                o3d.core.Tensor(verts.astype(np.float32)),
                o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
            )
        H, W = self.intrinsics.height, self.intrinsics.width
        dirs = self.ray_directions
        rays = np.concatenate([np.zeros((H, W, 3)), dirs], axis=-1).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        depth = hit["t_hit"].numpy().astype(float)
        labels = hit["geometry_ids"].numpy().astype(np.int64)
        normals = hit["primitive_normals"].numpy().astype(float)
        valid = np.isfinite(depth) & (depth < max_range)
        labels = np.where(valid, labels, -1).astype(np.int32)
        if rng is not None:
            d_unit = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
            cos_in = np.abs(np.einsum("hwi,hwi->hw", normals, d_unit))
            theta = np.arccos(np.clip(cos_in, 0.0, 1.0))
            z = np.where(valid, depth, 1.0)
            depth = depth + rng.normal(size=depth.shape) * self.noise.sigma(z, theta)
            start, full = map(math.radians, (self.noise.drop_start_deg, self.noise.drop_full_deg))
            p_drop = np.clip((theta - start) / (full - start), 0.0, 1.0)
            valid &= rng.random(size=depth.shape) >= p_drop
            labels = np.where(valid, labels, -1).astype(np.int32)
            if self.faults is not None:
                depth, valid, labels = self._faults(depth, valid, labels, theta, z, rng)
        points = dirs * np.where(valid, depth, np.nan)[..., None]
        if return_normals:
            return points.astype(np.float32), labels, normals
        return points.astype(np.float32), labels

    def _faults(self, depth, valid, labels, theta, z, rng: np.random.Generator):
        """The :class:`FaultModel`'s faults on a noisy depth image (H, W): more noise, grazing
        and dark-patch dropouts, a smooth distortion, flying pixels on depth edges."""
        f = self.faults
        H, W = depth.shape
        depth = depth + rng.normal(size=depth.shape) * self.noise.sigma(z, theta) * math.sqrt(
            max(f.noise_scale**2 - 1.0, 0.0)
        )
        start, full = map(math.radians, (f.grazing_start_deg, self.noise.drop_full_deg))
        if start < full:
            valid &= rng.random(size=depth.shape) >= np.clip(
                (theta - start) / (full - start), 0, 1
            )
        v, u = np.mgrid[0:H, 0:W]
        for _ in range(f.dark_patches):
            cu, cv = rng.uniform(0, W), rng.uniform(0, H)
            r = rng.uniform(0.3, 1.0) * f.dark_radius
            dark = (u - cu) ** 2 + (v - cv) ** 2 <= r * r
            valid &= ~(dark & (rng.random(size=depth.shape) < f.dark_dropout))
        if f.distortion > 0 and f.distortion_waves > 0:
            field = np.zeros(depth.shape)
            for _ in range(f.distortion_waves):
                k = rng.uniform(-f.distortion_waves, f.distortion_waves, size=2) * 2 * math.pi
                field += np.cos(k[0] * u / W + k[1] * v / H + rng.uniform(0, 2 * math.pi))
            depth = depth + f.distortion * field / math.sqrt(f.distortion_waves / 2)
        labels = np.where(valid, labels, -1).astype(np.int32)
        if f.flying_pixels > 0:
            d = np.where(valid, depth, np.nan)
            mixed = np.zeros(depth.shape, bool)
            new = depth.copy()
            for axis in (0, 1):  # each pixel against its next neighbour down / right
                a = d
                nb = np.roll(a, -1, axis=axis)
                edge = np.isfinite(a) & np.isfinite(nb) & (np.abs(a - nb) > f.edge_jump)
                if axis == 0:
                    edge[-1, :] = False
                else:
                    edge[:, -1] = False
                fly = edge & ~mixed & (rng.random(size=depth.shape) < f.flying_pixels)
                lam = rng.uniform(size=depth.shape)
                new = np.where(fly, lam * a + (1 - lam) * nb, new)
                mixed |= fly
            depth = new
            labels = np.where(mixed, -2, labels).astype(np.int32)
        return depth, valid, labels


@dataclass(frozen=True)
class SimulatedObject:
    """Ground truth of one object in a simulated scene."""

    template: str
    T_scene_model: np.ndarray = field(repr=False)
    click: np.ndarray | None = field(repr=False)  # a point of its visible surface (3,), or None
    visible_points: int
    joints: dict = field(default_factory=dict)  # joint name -> value (rad or m)
    scale: float = 1.0
    state: str | None = None


@dataclass(frozen=True)
class SimulatedScene:
    """A rendered scene. ``organized`` (H, W, 3) float32 has NaN where the sensor saw nothing."""

    seed: int
    layout: str
    organized: np.ndarray = field(repr=False)
    labels: np.ndarray = field(repr=False)
    objects: tuple
    T_scene_board: np.ndarray = field(repr=False)
    intrinsics: CameraIntrinsics

    @property
    def points(self) -> np.ndarray:
        """The finite points (N, 3) float64, scene (camera optical) frame, metres."""
        flat = self.organized.reshape(-1, 3)
        return flat[np.all(np.isfinite(flat), axis=1)].astype(float)

    def truth(self) -> dict:
        """The content of ``truth.yaml``."""
        i = self.intrinsics
        return {
            "seed": self.seed,
            "layout": self.layout,
            "frame": "camera optical frame (x right, y down, z forward), metres",
            "intrinsics": {
                "width": i.width,
                "height": i.height,
                "fx": i.fx,
                "fy": i.fy,
                "cx": i.cx,
                "cy": i.cy,
            },
            "T_scene_board": _rows(self.T_scene_board),
            "objects": [
                {
                    "template": o.template,
                    "T_scene_model": _rows(o.T_scene_model),
                    "click": None if o.click is None else [round(float(v), 6) for v in o.click],
                    "visible_points": int(o.visible_points),
                    "joints": {k: round(float(v), 9) for k, v in o.joints.items()},
                    "scale": round(float(o.scale), 9),
                    "state": o.state,
                }
                for o in self.objects
            ],
        }


def _rows(T: np.ndarray) -> list:
    return [[round(float(v), 9) for v in row] for row in T]


PANEL_SIZE = (1.0, 0.6, 0.02)


def panel_mesh() -> trimesh.Trimesh:
    """The taskboard's panel in its own frame: its top face at z = 0, +z out of it."""
    return trimesh.creation.box(
        extents=PANEL_SIZE, transform=make_T(np.eye(3), [0, 0, -PANEL_SIZE[2] / 2])
    )


def _camera_pose(rng: np.random.Generator) -> np.ndarray:
    """T_board_cam: 0.6-1.3 m from a point near the panel centre, up to 40 deg off its normal."""
    dist = rng.uniform(0.6, 1.3)
    alpha = math.radians(rng.uniform(0.0, 40.0))
    phi = rng.uniform(0.0, 2 * math.pi)
    target = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.06, 0.06), 0.0])
    position = target + dist * np.array(
        [math.sin(alpha) * math.cos(phi), math.sin(alpha) * math.sin(phi), math.cos(alpha)]
    )
    z = target - position
    z /= np.linalg.norm(z)
    up = np.array([0.0, 1.0, 0.0])
    y = -(up - z * (up @ z))
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1) @ axis_angle_matrix(
        [0, 0, 1], math.radians(rng.uniform(-10, 10))
    )
    return make_T(R, position)


def _place(radii, rng, half_x, half_y, gap=0.015, tries=4000):
    for _ in range(50):
        placed = []
        for r in radii:
            for _ in range(tries):
                p = np.array(
                    [rng.uniform(-half_x + r, half_x - r), rng.uniform(-half_y + r, half_y - r)]
                )
                if all(np.linalg.norm(p - q) >= r + rq + gap for q, rq in placed):
                    placed.append((p, r))
                    break
            else:
                break
        if len(placed) == len(radii):
            return [p for p, _ in placed]
    raise AffordanceError("could not place the objects on the panel without overlap")


def simulate_taskboard(
    library: TemplateLibrary,
    seed: int,
    *,
    layout: str = "panel",
    templates=None,
    camera: DepthCamera | None = None,
    articulated: bool = False,
    joints: dict | None = None,
    scales: dict | None = None,
) -> SimulatedScene:
    """Render a seeded taskboard: a 1 m x 0.6 m panel with every template but the primitives
    (or the named ``templates``) at a random position.

    ``layout="panel"``: objects are mounted on the panel (template +z along the panel normal) with
    a random rotation about their z axis. ``layout="table"``: the panel is a table top and objects
    lie on it, each resting on one of its stable facets (chosen by facet area) with a random
    rotation about the vertical -- the case without a mounting prior.

    ``articulated``: revolute joints take a uniform value within their limits, prismatic ones a
    random named state (an e-stop pressed or released), and templates with a scale range a
    uniform scale in it; ``truth.yaml`` records them. Otherwise every template is rendered as
    its YAML mesh (joint values zero, scale 1). ``joints`` ({template: {joint: value}}) and
    ``scales`` ({template: scale}) set chosen values instead of random ones. The camera is
    0.6-1.3 m away, up to 40 degrees off the panel normal.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise AffordanceError(f"seed must be a non-negative integer, got {seed!r}")
    if layout not in ("panel", "table"):
        raise AffordanceError(f"layout must be 'panel' or 'table', got {layout!r}")
    names = (
        [n for n in library if library[n].primitive is None]
        if templates is None
        else list(templates)
    )
    if not names:
        raise AffordanceError("no templates to place")
    rng = np.random.default_rng(int(seed))
    camera = camera or DepthCamera()
    joints, scales = _joint_values_and_scales(
        library, names, rng, articulated, joints or {}, scales or {}
    )
    rotations = _orientations(library, names, layout, rng)
    meshes_at = [
        library[n].mesh_at(next(iter(q.values()), 0.0), sc)
        for n, q, sc in zip(names, joints, scales)
    ]
    radii = []
    for mesh, R in zip(meshes_at, rotations):
        verts = np.asarray(mesh.vertices) @ R.T
        radii.append(float(np.linalg.norm(verts[:, :2], axis=1).max()))
    half_x, half_y = PANEL_SIZE[0] / 2, PANEL_SIZE[1] / 2
    positions = _place(radii, rng, half_x, half_y)
    T_board_cam = _camera_pose(rng)
    T_cam_board = invert(T_board_cam)
    meshes = [(panel_mesh(), T_cam_board)]
    poses = []
    for mesh, R, p in zip(meshes_at, rotations, positions):
        lift = -float((np.asarray(mesh.vertices) @ R.T)[:, 2].min()) if layout == "table" else 0.0
        T_cam_model = T_cam_board @ make_T(R, [p[0], p[1], lift])
        poses.append(T_cam_model)
        meshes.append((mesh, T_cam_model))
    organized, labels = camera.render(meshes, rng)
    objects = []
    for k, (name, T) in enumerate(zip(names, poses), start=1):
        pts = organized[labels == k].astype(float)
        q = joints[k - 1]
        objects.append(
            SimulatedObject(
                template=name,
                T_scene_model=T,
                click=_click(pts, rng),
                visible_points=int(len(pts)),
                joints=q,
                scale=scales[k - 1],
                state=library[name].nearest_state(q) if q else None,
            )
        )
    return SimulatedScene(
        seed=int(seed),
        layout=layout,
        organized=organized,
        labels=labels,
        objects=tuple(objects),
        T_scene_board=T_cam_board,
        intrinsics=camera.intrinsics,
    )


def _joint_values_and_scales(
    library: TemplateLibrary,
    names,
    rng: np.random.Generator,
    articulated: bool,
    chosen_joints: dict,
    chosen_scales: dict,
):
    """Each object's joint values ({joint: value}) and scale: random within the limits and the
    scale range (``articulated``, a prismatic joint at a random named state) unless chosen."""
    joints, scales = [], []
    for name in names:
        tpl = library[name]
        q = {}
        if articulated and tpl.joint is not None:
            j = tpl.joint
            if j.type == "revolute" or not tpl.states:
                q[j.name] = float(rng.uniform(j.lower, j.upper))
            else:
                state = sorted(tpl.states)[rng.integers(len(tpl.states))]
                q[j.name] = float(tpl.states[state].get(j.name, 0.0))
        if name in chosen_joints:
            q = {str(k): float(v) for k, v in chosen_joints[name].items()}
        joints.append(q)
        lo_hi = tpl.scale_range if articulated else None
        sc = float(rng.uniform(*lo_hi)) if lo_hi else 1.0
        scales.append(float(chosen_scales.get(name, sc)))
    return joints, scales


def _orientations(library: TemplateLibrary, names, layout: str, rng: np.random.Generator):
    """Each object's orientation on the board: a random yaw, and on a table resting on one of
    its stable facets (chosen by facet area)."""
    rotations = []
    for name in names:
        yaw = axis_angle_matrix([0, 0, 1], rng.uniform(0, 2 * math.pi))
        if layout == "panel":
            rotations.append(yaw)
        else:
            rest = library[name].resting_rotations()
            k = rng.choice(len(rest), p=np.array([w for _, w in rest]))
            rotations.append(yaw @ rest[k][0])
    return rotations


def _click(pts: np.ndarray, rng: np.random.Generator):
    """An operator's click on an object's visible points (N, 3): one of the quarter nearest
    their median; None when none is visible."""
    if not len(pts):
        return None
    centre = np.median(pts, axis=0)
    order = np.argsort(np.linalg.norm(pts - centre, axis=1))
    near = order[: max(1, len(order) // 4)]
    return pts[rng.choice(near)]


#: the templates the articulated scenes may also show in sizes (see :func:`sized_library`)
SIZED = {"grab_handle": (0.8, 1.25)}


def sized_library(library: TemplateLibrary) -> TemplateLibrary:
    """The library with the grab handle allowed to come in sizes (``scale: [0.8, 1.25]``):
    the bundled templates have no scale range (scale estimation costs rigid accuracy, see the
    README), so the scenes with scaled objects (tests, the bench's scale rows) use this variant."""
    return TemplateLibrary(
        [library[n].with_scale_range(SIZED[n]) if n in SIZED else library[n] for n in library]
    )


def ply_bytes(points: np.ndarray) -> bytes:
    """Binary little-endian PLY of (N, 3) points as float32."""
    pts = np.ascontiguousarray(points, dtype="<f4")
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment affordance_registration scene\n"
        f"element vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n"
    )
    return header.encode("ascii") + pts.tobytes()


def write_scene(scene: SimulatedScene, out_dir: str) -> dict:
    """Write ``scene.ply``, ``scene_organized.npy`` and ``truth.yaml`` into ``out_dir``.

    Everything is written to temporary files first and renamed into place at the end, so a
    failure leaves no half-finished output. Returns the paths written."""
    out_dir = os.path.abspath(out_dir)
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise AffordanceError(f"cannot create output folder {out_dir}: {exc.strerror}") from None
    if not os.access(out_dir, os.W_OK):
        raise AffordanceError(f"output folder {out_dir} is not writable")
    payloads = {
        "scene.ply": ply_bytes(scene.points),
        "truth.yaml": yaml.safe_dump(scene.truth(), sort_keys=False).encode(),
    }
    import io

    buf = io.BytesIO()
    np.save(buf, scene.organized)
    payloads["scene_organized.npy"] = buf.getvalue()
    try:
        written = write_atomically(
            {os.path.join(out_dir, name): data for name, data in payloads.items()}
        )
    except OSError as exc:
        raise AffordanceError(f"cannot write into {out_dir}: {exc.strerror}") from None
    paths = dict(zip(payloads, written))
    return paths


def load_truth(path: str) -> dict:
    """Read a ``truth.yaml``; poses come back as 4x4 arrays and clicks as (3,) arrays."""
    doc = read_yaml(path, AffordanceError, max_bytes=MAX_TRUTH_BYTES, kind="truth file")
    try:
        for obj in doc.get("objects", []):
            obj["T_scene_model"] = np.asarray(obj["T_scene_model"], dtype=float).reshape(4, 4)
            if obj.get("click") is not None:
                obj["click"] = np.asarray(obj["click"], dtype=float).reshape(3)
        doc["T_scene_board"] = np.asarray(doc["T_scene_board"], dtype=float).reshape(4, 4)
    except (AttributeError, KeyError, TypeError, ValueError):  # (a wrong size: reshape's)
        raise AffordanceError(
            f"{path}: not a truth file (4x4 T_scene_model, T_scene_board)"
        ) from None
    return doc


def operator_correction(
    T_true: np.ndarray,
    centroid,
    rng: np.random.Generator,
    move: float = 0.015,
    turn: float = math.radians(8.0),
) -> np.ndarray:
    """The benchmark's operator correction: ``T_true`` (4x4) turned by ``turn`` (rad) about a
    random axis through the object's centre (``centroid``, model frame) and moved ``move`` (m)
    in a random direction -- a rough drag the refit should bring back."""
    dR = axis_angle_matrix(rng.normal(size=3), turn)
    off = rng.normal(size=3)
    off *= move / np.linalg.norm(off)
    centre = T_true[:3, :3] @ np.asarray(centroid, float) + T_true[:3, 3]
    return make_T(dR @ T_true[:3, :3], dR @ (T_true[:3, 3] - centre) + centre + off)


def truth_joints(template, obj) -> dict:
    """The joint values a fitted candidate of ``obj`` carries: the truth's, the joint at zero
    when the truth names none."""
    return dict(obj.joints) or ({template.joint.name: 0.0} if template.joint is not None else {})


def failures(
    row: dict, tolerance_m: float = POSE_TOL_M, tolerance_rad: float = POSE_TOL_RAD
) -> list[str]:
    """Why a registered object (a row with the true ``template``, the ``shown`` one and its
    ``error_mm`` / ``error_deg`` from the truth) is wrong: empty when it is right."""
    if row["shown"] != row["template"]:
        return [f"registered as {row['shown']}"]
    reasons = []
    if not row["error_mm"] <= tolerance_m * 1000:
        reasons.append(f"{row['error_mm']:.1f} mm > {tolerance_m * 1000:.0f} mm")
    if not row["error_deg"] <= math.degrees(tolerance_rad):
        reasons.append(f"{row['error_deg']:.1f}° > {math.degrees(tolerance_rad):.0f}°")
    return reasons


class SimulatedOperator:
    """Plays the operator of the paper on a scene with ground truth.

    For each object: click its visible surface; while the shown template is wrong, press "next
    model"; while the shown pose is off by more than the tolerance, push the SpaceMouse toward the
    true pose (a bounded twist in the view frame, a deliberately imperfect push) and let the
    engine refit; then accept. ``actions`` is anything with ``click(point)``,
    ``shown() -> (template, T_scene_model)``, ``next_model()``, ``push(linear, angular, duration,
    T_scene_view)`` and ``refit()`` and ``accept()`` -- the core engine or a ROS client.
    """

    def __init__(
        self,
        library: TemplateLibrary,
        tolerance_m: float = POSE_TOL_M,
        tolerance_rad: float = POSE_TOL_RAD,
        max_speed: float = 0.05,
        max_turn_rate: float = 0.6,
        push_fraction: float = 0.8,
        max_pushes: int = 6,
        seed: int = 0,
    ):
        self.library = library
        self.tol_m, self.tol_rad = tolerance_m, tolerance_rad
        self.max_speed, self.max_turn_rate = max_speed, max_turn_rate
        self.push_fraction, self.max_pushes = push_fraction, max_pushes
        self.rng = np.random.default_rng(seed)

    def error(self, template: str, T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
        from ..core.transforms import pose_error

        return pose_error(T, T_true, self.library[template].symmetry)

    def _closest_truth(self, template: str, T: np.ndarray, T_true: np.ndarray) -> np.ndarray:
        """The symmetric equivalent of the true pose closest to ``T``."""
        from ..core.transforms import rotation_angle

        sym = self.library[template].symmetry
        if sym is None:
            return T_true
        cands = [T_true @ S for S in sym.transforms]
        return min(cands, key=lambda C: float(rotation_angle(C[:3, :3].T @ T[:3, :3])))

    def register(self, obj: SimulatedObject, actions, T_scene_view: np.ndarray) -> dict:
        """Register one object; returns what it took (model changes, pushes, final error)."""
        from scipy.spatial.transform import Rotation

        t0 = time.perf_counter()
        actions.click(obj.click)
        fit_s = time.perf_counter() - t0
        first_template, _ = actions.shown()
        changes = 0
        n_templates = len(self.library)
        while actions.shown()[0] != obj.template and changes < n_templates:
            actions.next_model()
            changes += 1
        pushes = 0
        template, T = actions.shown()
        centroid = self.library[template].centroid if template in self.library else np.zeros(3)
        while template == obj.template and pushes < self.max_pushes:
            dt_err, dr_err = self.error(template, T, obj.T_scene_model)
            if dt_err <= self.tol_m and dr_err <= self.tol_rad:
                break
            goal = self._closest_truth(template, T, obj.T_scene_model)
            c_now = T[:3, :3] @ centroid + T[:3, 3]
            c_goal = goal[:3, :3] @ centroid + goal[:3, 3]
            rotvec = Rotation.from_matrix(goal[:3, :3] @ T[:3, :3].T).as_rotvec()
            frac = self.push_fraction * self.rng.uniform(0.85, 1.15)
            move, turn = (c_goal - c_now) * frac, rotvec * frac
            duration = max(
                np.linalg.norm(move) / self.max_speed,
                np.linalg.norm(turn) / self.max_turn_rate,
                0.1,
            )
            R_sv = T_scene_view[:3, :3]
            actions.push(
                R_sv.T @ move / duration, R_sv.T @ turn / duration, duration, T_scene_view
            )
            actions.refit()
            pushes += 1
            template, T = actions.shown()
        dt_err, dr_err = (
            self.error(template, T, obj.T_scene_model)
            if template == obj.template
            else (float("inf"), float("inf"))
        )
        actions.accept()
        return {
            "template": obj.template,
            "ranked_first": first_template,
            "shown": template,
            "model_changes": changes,
            "corrections": pushes,
            "fit_s": fit_s,
            "error_mm": dt_err * 1000,
            "error_deg": math.degrees(dr_err),
            "ok": template == obj.template and dt_err <= self.tol_m and dr_err <= self.tol_rad,
        }
