# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Geometry of an operator's view of a cloud: thinning a cloud for display, colouring it, picking
the cloud point under a click ray, the pinhole camera of a browser view, and which way is up in
a scan.

Pure numpy (no ROS, no viewer): the browser station (``ros/station/node.py``) calls these, and the
tests check them without a browser.

Camera convention: a view's camera is an **optical** frame -- x right on the screen, y down, z
into the screen (OpenCV, and the ``view_pose`` the engine node takes). ``T_world_optical`` maps
camera coordinates to the world (the cloud's frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import AffordanceError
from .plane import ransac_plane
from .transforms import finite_vector, make_T

__all__ = [
    "thin",
    "Thinned",
    "scalar_colors",
    "offset_surface",
    "snap_ray",
    "optical_pose",
    "look_at_pose",
    "project",
    "pixel_ray",
    "initial_view",
    "first_up",
    "support_under",
    "SUPPORT_SLANT_DEG",
    "SUPPORT_TURN_DEG",
]

#: a plane is a floor or a table -- the world's up is its normal -- only where the sensor sees it
#: at a slant: its normal at least this far from the line of sight to it (a wall or a mounting
#: panel is seen head-on; a table from a camera looking down at it, at 30-60 degrees)
SUPPORT_SLANT_DEG = 20.0
#: the plane under a click replaces the up axis of the first view only within this angle of it
#: (a panel the objects are mounted on, seen at a slant, is not the floor)
SUPPORT_TURN_DEG = 65.0
#: the plane fits of the up axis: inlier band (m), least share of the points, the crop around a
#: click (m)
UP_PLANE_BAND = 0.012
UP_PLANE_SHARE = 0.3
SUPPORT_RADIUS = 0.3

#: colour map of :func:`scalar_colors`: near/low (dark slate) -> far/high (light sand), muted so
#: that the fitted meshes (green..red, orange, blue) stand out against the cloud
_STOPS = np.array(
    [[55, 62, 78], [95, 105, 120], [145, 150, 155], [190, 185, 170], [230, 222, 200]], dtype=float
)


def _voxel_keys(offsets: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 key per point: the voxel of edge ``voxel`` it falls in. ``offsets`` (N, 3) are
    the points minus their minimum (non-negative, so truncation is the floor)."""
    keys = (offsets * np.float32(1.0 / voxel)).astype(np.int64)
    dims = keys.max(axis=0) + 1
    return (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]


def _one_per_voxel(keys: np.ndarray) -> np.ndarray:
    """Indices of one point per distinct voxel key (one sort)."""
    order = np.argsort(keys)
    k = keys[order]
    first = np.empty(len(k), dtype=bool)
    first[:1] = True
    np.not_equal(k[1:], k[:-1], out=first[1:])
    return order[first]


@dataclass(frozen=True)
class Thinned:
    """A cloud thinned for display: ``indices`` (M,) into the cloud, and the voxel edge (m) they
    were taken at (0 when the cloud was within the budget) -- the start for the next cloud of
    the same stream."""

    indices: np.ndarray
    voxel: float


def thin(
    points: np.ndarray, budget: int, iterations: int = 6, start_voxel: float | None = None
) -> Thinned:
    """At most ``budget`` points of ``points`` (N, 3) for display: one point of the cloud per
    occupied voxel, the voxel edge chosen so that M is close to (not above) the budget. A cloud
    within the budget is returned whole; a cloud is never dropped, only thinned.

    The voxel edge starts at ``start_voxel`` (the previous cloud's :attr:`Thinned.voxel`: a
    stream of similar clouds then costs one pass; a hint far off -- another kind of cloud --
    is dropped after that pass) or from the extent of a surface-like cloud, and is corrected
    by sqrt(count / budget) per iteration (one sort each, which gives the
    indices too); should the voxels not get there, the fullest set found is strided down to the
    budget. Non-finite rows must have been removed.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise AffordanceError(f"points must be (N, 3), got {pts.shape}")
    budget = int(budget)
    if budget < 1:
        raise AffordanceError(f"the display budget must be at least 1 point, got {budget}")
    n = len(pts)
    if n <= budget:
        return Thinned(np.arange(n), 0.0)
    pts = pts.astype(np.float32, copy=False)
    offsets = pts - pts.min(axis=0)
    extent = np.sort(offsets.max(axis=0))[::-1].astype(float)
    floor = extent[0] / 2e6  # at most 2e6 cells a side: the keys fit in int64
    estimate = max(math.sqrt(max(extent[0] * extent[1], 1e-12) / budget), 1e-6, floor)
    hinted = start_voxel is not None and math.isfinite(start_voxel) and start_voxel > 0
    voxel = max(float(start_voxel), floor) if hinted else estimate
    best = None  # (indices, voxel) of the fullest set in budget
    fewest = None  # the smallest set over the budget
    for attempt in range(iterations):
        idx = _one_per_voxel(_voxel_keys(offsets, voxel))
        count = len(idx)
        if count <= budget and (best is None or count > len(best[0])):
            best = (idx, voxel)
        elif count > budget and (fewest is None or count < len(fewest[0])):
            fewest = (idx, voxel)
        if budget * 0.7 <= count <= budget:
            break
        if attempt == 0 and hinted and not budget / 4 <= count <= 2 * budget:
            voxel = estimate  # a different cloud: the hint says little
            continue
        voxel = max(voxel * math.sqrt(count / budget) * (1.04 if count > budget else 0.98), floor)
    idx, voxel = best if best is not None else fewest
    if len(idx) > budget:
        idx = np.sort(idx)[np.linspace(0, len(idx) - 1, budget).astype(np.int64)]
    return Thinned(np.sort(idx), voxel)


def offset_surface(
    vertices: np.ndarray, faces: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """A mesh's surface moved ``margin`` (m) outwards along its vertex normals: drawn on the
    surface it was fitted to, it shows in front of that surface's points instead of hiding
    among them. ``vertices`` (V, 3), ``faces`` (F, 3) (a triangle soup is welded first); returns
    (vertices (V', 3) float32, faces (F', 3) uint32)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=float), np.asarray(faces), process=True)
    if len(mesh.faces) == 0:
        return np.asarray(vertices, dtype=np.float32), np.asarray(faces, dtype=np.uint32)
    shell = mesh.vertices + margin * mesh.vertex_normals
    return shell.astype(np.float32), mesh.faces.astype(np.uint32)


def scalar_colors(values: np.ndarray, low: float = 2.0, high: float = 98.0) -> np.ndarray:
    """RGB colours (N, 3) uint8 of a scalar per point (depth, intensity): the ``low``..``high``
    percentile range mapped onto a dark -> light scale (brightness grows with the value).
    Non-finite values are mid grey."""
    v = np.asarray(values, dtype=float).reshape(-1)
    out = np.full((len(v), 3), 128, dtype=np.uint8)  # mid grey: no value
    finite = np.isfinite(v)
    if not finite.any():
        return out
    lo, hi = np.percentile(v[finite], [low, high])
    s = np.clip((v[finite] - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * (len(_STOPS) - 1)
    i = np.minimum(s.astype(np.int64), len(_STOPS) - 2)
    f = (s - i)[:, None]
    out[finite] = np.round(_STOPS[i] * (1 - f) + _STOPS[i + 1] * f).astype(np.uint8)
    return out


def snap_ray(
    points: np.ndarray,
    origin,
    direction,
    cone_rad: float = math.radians(0.5),
    max_rad: float = math.radians(3.0),
) -> int | None:
    """The cloud point a click ray picks: index into ``points`` (N, 3), or None when no point lies
    within ``max_rad`` of the ray (a click into the void).

    Points within ``cone_rad`` of the ray (at least 1.5x the closest point's angle) are the
    candidates; the nearest candidate along the ray is the surface the operator sees, and of the
    candidates no more than 3 cone radii behind it, the one closest to the ray is picked. So a
    click on an object picks the object, not the wall behind it, however the points are spaced.
    ``origin`` (3,) and ``direction`` (3,) are in the points' frame; angles in radians.
    """
    o = finite_vector(origin, "ray origin", AffordanceError)
    d = finite_vector(direction, "ray direction", AffordanceError)
    norm = np.linalg.norm(d)
    if norm < 1e-12:
        raise AffordanceError("the ray direction is zero")
    d = d / norm
    pts = np.asarray(points, dtype=float)
    if len(pts) == 0:
        return None
    v = pts - o
    t = v @ d
    perp = np.sqrt(np.maximum(np.einsum("ij,ij->i", v, v) - t * t, 0.0))
    ahead = t > 1e-9
    if not ahead.any():
        return None
    angle = np.full(len(pts), np.inf)
    angle[ahead] = np.arctan2(perp[ahead], t[ahead])
    best = float(angle.min())
    if best > max_rad:
        return None
    cone = max(cone_rad, 1.5 * best)
    cand = np.flatnonzero(angle <= cone)
    front = float(t[cand].min())
    near = cand[t[cand] <= front + 3.0 * math.tan(cone) * front]
    return int(near[np.argmin(perp[near])])


def optical_pose(wxyz, position) -> np.ndarray:
    """T_world_optical (4, 4) of a camera given as a unit quaternion (w, x, y, z) and a position:
    the convention of viser's camera (look along +z, up is -y, right is +x)."""
    w, x, y, z = finite_vector(wxyz, "camera orientation", AffordanceError, length=4)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(n - 1.0) > 0.01:
        raise AffordanceError(f"camera orientation is not a unit quaternion (norm {n:.3f})")
    w, x, y, z = w / n, x / n, y / n, z / n
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return make_T(R, finite_vector(position, "camera position", AffordanceError))


def look_at_pose(position, target, up) -> np.ndarray:
    """T_world_optical of a camera at ``position`` looking at ``target`` with ``up`` pointing up
    on the screen."""
    p = finite_vector(position, "camera position", AffordanceError)
    z = finite_vector(target, "look-at point", AffordanceError) - p
    if np.linalg.norm(z) < 1e-12:
        raise AffordanceError("the camera looks at its own position")
    z /= np.linalg.norm(z)
    u = finite_vector(up, "up direction", AffordanceError)
    y = -(u - (u @ z) * z)
    if np.linalg.norm(y) < 1e-9:
        raise AffordanceError("the up direction is parallel to the viewing direction")
    y /= np.linalg.norm(y)
    return make_T(np.column_stack([np.cross(y, z), y, z]), p)


def _focal(fov_y: float, height: float) -> float:
    if not 0 < fov_y < math.pi:
        raise AffordanceError(f"the vertical field of view must be in (0, pi) rad, got {fov_y}")
    return 0.5 * height / math.tan(0.5 * fov_y)


def project(
    T_world_optical: np.ndarray, fov_y: float, width: float, height: float, points: np.ndarray
) -> np.ndarray:
    """Pixel coordinates (N, 2) (u right, v down, origin at the top-left corner) of world points
    (N, 3) in a pinhole view of vertical field of view ``fov_y`` (rad) and ``width`` x ``height``
    pixels (square pixels). Points behind the camera get NaN."""
    T = np.asarray(T_world_optical, dtype=float)
    p = (np.atleast_2d(np.asarray(points, dtype=float)) - T[:3, 3]) @ T[:3, :3]
    f = _focal(fov_y, height)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.column_stack(
            [f * p[:, 0] / p[:, 2] + 0.5 * width, f * p[:, 1] / p[:, 2] + 0.5 * height]
        )
    uv[p[:, 2] <= 0] = np.nan
    return uv


def pixel_ray(
    T_world_optical: np.ndarray, fov_y: float, width: float, height: float, uv
) -> tuple[np.ndarray, np.ndarray]:
    """The world ray (origin (3,), unit direction (3,)) through pixel ``uv`` of the view (the
    inverse of :func:`project`)."""
    T = np.asarray(T_world_optical, dtype=float)
    f = _focal(fov_y, height)
    u, v = finite_vector(uv, "pixel", AffordanceError, length=2)
    d = T[:3, :3] @ np.array([(u - 0.5 * width) / f, (v - 0.5 * height) / f, 1.0])
    return T[:3, 3].copy(), d / np.linalg.norm(d)


def initial_view(
    points: np.ndarray, up, fov: float | None = None, sensor=None
) -> tuple[np.ndarray, np.ndarray]:
    """Where a first view of a cloud stands and looks: (camera position (3,), look-at point (3,)).

    A cloud seen from ``sensor`` (3,; default the frame's origin: a sensor frame) -- the sensor
    lies outside the cloud's bounding box, within 20 m of it -- is viewed from there, stepped
    back along the view, with ``fov`` (rad, the page's narrower field of view), as far as it
    takes for 99% of the points to be in the picture (a sensor's field of view is often wider
    than the page's); any other cloud (a map) from above and in front of its centre -- ``up``
    (3,) is the world's up -- at 1.5 times its size.
    """
    o = np.zeros(3) if sensor is None else finite_vector(sensor, "sensor origin", AffordanceError)
    pts = np.asarray(points, dtype=float) - o
    if len(pts) == 0:
        return o + np.array([1.0, 1.0, 1.0]), o
    target = np.median(pts, axis=0)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    outside = bool(np.any((lo > 0) | (hi < 0)))
    if outside and np.linalg.norm(target) < 20.0:
        if fov is None or np.linalg.norm(target) < 1e-9:
            return o.copy(), o + target
        d = target / np.linalg.norm(target)
        depth = pts @ d  # along the view
        lateral = np.linalg.norm(pts - np.outer(depth, d), axis=1)
        back = float(np.percentile(lateral / math.tan(0.5 * fov) - depth, 99))
        return o - max(back, 0.0) * d, o + target
    u = finite_vector(up, "up direction", AffordanceError)
    u /= max(np.linalg.norm(u), 1e-12)
    side = np.cross(u, [1.0, 0.0, 0.0])
    if np.linalg.norm(side) < 1e-6:
        side = np.cross(u, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    size = max(float(np.linalg.norm(hi - lo)), 0.5)
    return o + target + 1.5 * size * (0.6 * u + 0.8 * side), o + target


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _slanted_support(points: np.ndarray, sensor) -> np.ndarray | None:
    """The unit normal (towards the sensor) of the dominant plane of ``points`` (N, 3), when it
    holds UP_PLANE_SHARE of them and the sensor sees it at a slant (SUPPORT_SLANT_DEG); else
    None."""
    pts = np.asarray(points, dtype=float)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    origin = None if sensor is None else np.asarray(sensor, dtype=float)
    plane = ransac_plane(pts, UP_PLANE_BAND, UP_PLANE_SHARE, origin, seed=0, hypotheses=200)
    if plane is None:
        return None
    if origin is not None:
        on = pts[np.abs(plane.distance(pts)) < UP_PLANE_BAND]
        sight = origin - on.mean(axis=0)
        if _angle_deg(plane.normal, sight) < SUPPORT_SLANT_DEG:
            return None
    return np.asarray(plane.normal, dtype=float)


def first_up(points: np.ndarray, sensor=None, optical: bool = False) -> tuple[np.ndarray, str]:
    """The up axis (3,) of a first view of a scan, and why: a cloud in an optical frame (a
    camera's, by its name: z forward, y down) has the camera's up, -y; else the normal of the
    dominant plane of ``points`` where the ``sensor`` (3,; None: unknown) sees it at a slant --
    the table or floor a scan was taken of (a Kinect file in a frame called ``scan`` is an
    optical frame that does not say so); else +z (REP-103)."""
    if optical:
        return np.array([0.0, -1.0, 0.0]), "an optical frame (the camera's up, -y)"
    normal = _slanted_support(points, sensor)
    if normal is not None:
        return normal, "the dominant plane of the scan, seen at a slant (a table or floor)"
    return np.array([0.0, 0.0, 1.0]), "+z (no plane of the scan looks like a floor)"


def support_under(points: np.ndarray, click, sensor, up) -> np.ndarray | None:
    """The up axis the plane under a click gives: the unit normal (towards the ``sensor``) of
    the dominant plane within SUPPORT_RADIUS of ``click`` when the sensor sees it at a slant and
    it lies within SUPPORT_TURN_DEG of the current ``up``; else None (keep ``up``)."""
    pts = np.asarray(points, dtype=float)
    c = finite_vector(click, "click", AffordanceError)
    near = pts[np.sum((pts - c) ** 2, axis=1) <= SUPPORT_RADIUS**2]
    normal = _slanted_support(near, sensor)
    if normal is None or _angle_deg(normal, np.asarray(up, dtype=float)) > SUPPORT_TURN_DEG:
        return None
    return normal
