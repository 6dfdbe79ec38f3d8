"""Primitive templates (a box, a cylinder): the pose *and* the dimensions from the clicked object.

An object outside the library is often a box or a can. Its primitive is measured, not searched
for: the clicked object's points (the clicked segment of the cluster, ``ClickContext.segments``:
a convex object is one segment, the neighbours it touches are others) are laid out in a frame
from the surface it stands on -- +z along the support's normal -- and

* a box's footprint is the smallest rectangle around the points projected onto the support
  (its edges' directions tried), its height the top of the points above the support (its base
  on the support when the points reach down to it, else at their lowest);
* a cylinder stands (axis along the normal: a circle fitted to the side points' footprint) or
  lies (axis across the normal, along the direction the surface normals leave out: a circle
  fitted to the points seen along the axis); the one with the lower residual is kept.

Without a support the object's principal axes take its place. The measured primitive is then
refined like an operator's correction (:func:`.refit.refit`: local ICP, the pose only), and its
dimensions measured again in the refined frame. Dimensions are clipped to the template's ranges;
a primitive is judged (:func:`.scoring.judge`) like any candidate.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..neighbours import build_tree, nearest
from ..scene import ClickContext, _ransac_plane, segment
from ..templates import AffordanceTemplate
from ..transforms import make_T
from .model import ModelCache
from .icp import fine_stage
from .results import FitResult
from .scoring import result
from .settings import FitSettings

__all__ = ["fit_primitive", "object_points"]

#: points this close to the support (m) reach down to it: the base lies on the support
BASE_REACH = 0.03
#: extents are read between these percentiles of the points (mixed pixels at the edges)
LOW, HIGH = 1.0, 99.0
#: a cylinder's side points: normals within this of perpendicular to the axis (cosine)
SIDE_COS = 0.5
#: a click on the crop's dominant plane: the support is a plane across it holding at least
#: this fraction of the points off it, turned at least FLOOR_ANGLE (deg) from it
FLOOR_FRACTION = 0.15
FLOOR_ANGLE = 60.0
#: measure, refine, measure again: this many rounds
ROUNDS = 2


def fit_primitive(ctx: ClickContext, template: AffordanceTemplate, cache: ModelCache,
                  settings: FitSettings, dimensions: dict | None = None,
                  T_init: np.ndarray | None = None) -> FitResult:
    """The primitive ``template`` fitted to the clicked object: pose and dimensions measured
    from the object's points, then the pose refined. ``dimensions`` (and ``T_init``, the
    pose to refine from): the operator's, kept as given -- only the pose is refined."""
    points, normals, support = object_points(ctx)
    if dimensions is not None:
        T = _as_pose(T_init) if T_init is not None else \
            next(_hypotheses(ctx, template.primitive, points, normals, support))[0]
        return _refined(ctx, template, cache, settings, T, template.clip_dimensions(dimensions))
    best = None
    for T, dims in _hypotheses(ctx, template.primitive, points, normals, support):
        for _ in range(ROUNDS):
            res = _refined(ctx, template, cache, settings, T, template.clip_dimensions(dims))
            T = res.T_scene_model
            dims = _extents(template.primitive, T, points)
        res = _refined(ctx, template, cache, settings, T, template.clip_dimensions(dims),
                       refine=False)
        if best is None or res.likelihood > best.likelihood:
            best = res
    return best


def _refined(ctx, template, cache, settings, T, dims, refine: bool = True) -> FitResult:
    """The primitive at ``dims`` from pose ``T``: refined locally (the pose only), scored."""
    model = cache.model(template.sized(dims))
    R, t, iterations, converged = T[:3, :3], T[:3, 3], 0, None
    if refine:
        fit = fine_stage(ctx, model, R, t, settings.refit_fine, settings, hold_joint=True)
        R, t, iterations, converged = fit.R[0], fit.t[0], fit.iterations, fit.converged[0]
    res = result(ctx, model, R, t, settings, iterations, converged)
    return replace(res, primitive=template.primitive, dimensions=model.template.dimensions)


def object_points(ctx: ClickContext):
    """The clicked object's full-resolution points, their normals and the surface it stands
    on (a :class:`~..scene.Plane`, or None): the points whose nearest cluster voxel lies in
    the clicked segment of the cluster. Where the click is on the crop's dominant plane (a
    box's large face), that plane is the object's and the cluster holds what it stands on
    too: the largest plane across it (FLOOR_FRACTION of the points off the face, turned at
    least FLOOR_ANGLE from it) is the support, and the object is cut from what lies above it."""
    cluster, labels, support = ctx.cluster, ctx.segments, ctx.support
    clicked = labels[int(np.argmin(ctx._cluster_to_click))]
    if ctx.plane is None and support is not None and \
            abs(support.distance(ctx.click[None])[0]) <= 2 * ctx.plane_threshold:
        off = np.abs(support.distance(cluster)) > ctx.plane_threshold
        floor = _ransac_plane(cluster[off], ctx.plane_threshold, FLOOR_FRACTION,
                              ctx.sensor_origin, 0) if off.sum() >= 50 else None
        if floor is not None and abs(floor.normal @ support.normal) < \
                math.cos(math.radians(FLOOR_ANGLE)):
            side = np.sign(floor.distance(ctx.click[None])[0]) or 1.0
            above = side * floor.distance(cluster) > ctx.plane_threshold
            if above.sum() >= 10:
                cluster = cluster[above]
                labels = segment(cluster, ctx.sensor_origin, ctx.voxel)
                clicked = labels[int(np.argmin(np.linalg.norm(cluster - ctx.click, axis=1)))]
                support = floor
    tree = build_tree(cluster) if cluster is not ctx.cluster else ctx.cluster_tree
    d, idx = nearest(tree, ctx.fine, ctx.voxel)
    mine = np.isfinite(d)
    mine[mine] = labels[idx[mine]] == clicked
    if mine.sum() < 10:
        return ctx.fine, ctx.fine_normals, support
    return ctx.fine[mine], ctx.fine_normals[mine], support


def _hypotheses(ctx: ClickContext, kind: str, points: np.ndarray, normals: np.ndarray,
                support):
    """(T_scene_model, dimensions) measured for each way the primitive may stand."""
    up = _up(support, points)
    if kind == "box":
        yield _box(points, up, support, ctx)
        return
    yield _standing_cylinder(points, normals, up, support, ctx)
    axis = _least_normal_direction(normals)
    if up is not None:
        axis = axis - (axis @ up) * up
        if np.linalg.norm(axis) < 1e-6:
            return
        axis /= np.linalg.norm(axis)
    yield _lying_cylinder(points, normals, axis, up)


def _up(support, points: np.ndarray) -> np.ndarray | None:
    """The support's normal on the object's side, or None without a support."""
    if support is None:
        return None
    n = np.asarray(support.normal, float)
    return n if np.mean(support.distance(points)) >= 0 else -n


def _basis(z: np.ndarray, x_hint: np.ndarray | None = None):
    """Unit x, y perpendicular to z (x along ``x_hint`` projected, where given)."""
    x = np.array([1.0, 0.0, 0.0]) if x_hint is None else np.asarray(x_hint, float)
    x = x - (x @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    return x, np.cross(z, x)


def _frame_up(points: np.ndarray, up: np.ndarray | None, support, ctx: ClickContext):
    """(z, base height, heights) of the object: +z along ``up`` (or the points' least spread
    towards the sensor without a support); heights of the points above the support (or
    above their lowest)."""
    if up is None:
        c = points - points.mean(axis=0)
        z = np.linalg.eigh(c.T @ c)[1][:, 0]
        toward = (ctx.sensor_origin - points.mean(axis=0)) if ctx.sensor_origin is not None \
            else -points.mean(axis=0)
        if z @ toward < 0:
            z = -z
        h = points @ z
        return z, 0.0, h - np.percentile(h, LOW)     # the base on the far side
    h = support.distance(points) * (1.0 if up @ support.normal > 0 else -1.0)
    low = float(np.percentile(h, LOW))
    return up, (0.0 if low <= BASE_REACH else low), h


def _box(points: np.ndarray, up, support, ctx: ClickContext):
    z, base, h = _frame_up(points, up, support, ctx)
    x0, y0 = _basis(z, ctx.frame[:, 0])
    uv = np.stack([points @ x0, points @ y0], axis=1)
    best = None
    for angle in _edge_angles(uv):
        c, s = math.cos(angle), math.sin(angle)
        rot = uv @ np.array([[c, -s], [s, c]])
        lo, hi = np.percentile(rot, [LOW, HIGH], axis=0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0]:
            best = (area, angle, lo, hi)
    _, angle, lo, hi = best
    c, s = math.cos(angle), math.sin(angle)
    ex, ey = c * x0 + s * y0, -s * x0 + c * y0
    size = hi - lo
    centre2 = (lo + hi) / 2
    if size[1] > size[0]:                          # x along the longer edge
        ex, ey, size = ey, -ex, size[::-1]
    top = float(np.percentile(h, HIGH))
    origin = _on_axis(points, z, centre2[0] * (c * x0 + s * y0) + centre2[1] * (-s * x0 + c * y0),
                      h, base)
    dims = {"x": float(size[0]), "y": float(size[1]), "z": max(top - base, 1e-3)}
    return make_T(np.stack([ex, ey, z], axis=1), origin), dims


def _on_axis(points, z, in_plane, h, base):
    """The point at height ``base`` above the support below the in-plane position
    ``in_plane`` (the sum of its x, y components)."""
    heights = points @ z - h                       # the support's level along z, per point
    return in_plane + (float(np.median(heights)) + base) * z


def _edge_angles(uv: np.ndarray) -> np.ndarray:
    """Directions (rad, within 90 deg) of the 2-D convex hull's edges: a smallest enclosing
    rectangle has a side along one of them."""
    from scipy.spatial import ConvexHull
    try:
        hull = uv[ConvexHull(uv).vertices]
    except Exception:          # collinear points
        return np.array([0.0])
    d = np.roll(hull, -1, axis=0) - hull
    return np.unique(np.round(np.mod(np.arctan2(d[:, 1], d[:, 0]), math.pi / 2), 4))


def _circle(uv: np.ndarray):
    """Centre (2,) and radius of the circle through 2-D points: the algebraic fit, then a few
    geometric (Gauss-Newton) steps."""
    A = np.column_stack([2 * uv, np.ones(len(uv))])
    b = (uv ** 2).sum(axis=1)
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    c = sol[:2]
    r = math.sqrt(max(sol[2] + c @ c, 1e-12))
    for _ in range(10):
        d = uv - c
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        J = np.column_stack([-d / dist[:, None], -np.ones(len(uv))])
        step = np.linalg.lstsq(J, -(dist - r), rcond=None)[0]
        c, r = c + step[:2], r + step[2]
        if np.linalg.norm(step) < 1e-7:
            break
    return c, abs(r)


def _standing_cylinder(points, normals, up, support, ctx: ClickContext):
    z, base, h = _frame_up(points, up, support, ctx)
    x, y = _basis(z, ctx.frame[:, 0])
    side = np.abs(normals @ z) < SIDE_COS
    use = points[side] if side.sum() >= 10 else points
    c2, r = _circle(np.stack([use @ x, use @ y], axis=1))
    top = float(np.percentile(h, HIGH))
    origin = _on_axis(points, z, c2[0] * x + c2[1] * y, h, base)
    return make_T(np.stack([x, y, z], axis=1), origin), \
        {"radius": float(r), "length": max(top - base, 1e-3)}


def _least_normal_direction(normals: np.ndarray) -> np.ndarray:
    """The direction the normals leave out (least spread of them): a cylinder's axis."""
    return np.linalg.eigh(normals.T @ normals)[1][:, 0]


def _lying_cylinder(points, normals, axis, up):
    z = axis / np.linalg.norm(axis)
    x, y = _basis(z, up)
    c2, r = _circle(np.stack([points @ x, points @ y], axis=1))
    along = points @ z
    lo, hi = np.percentile(along, [LOW, HIGH])
    origin = c2[0] * x + c2[1] * y + lo * z
    return make_T(np.stack([x, y, z], axis=1), origin), \
        {"radius": float(r), "length": float(max(hi - lo, 1e-3))}


def _extents(kind: str, T: np.ndarray, points: np.ndarray) -> dict:
    """The dimensions the object's points give in the primitive's frame ``T`` (its centre
    and axes kept): a box's extents about its centre, a cylinder's radius (median distance
    from the axis of the side points) and length."""
    local = (points - T[:3, 3]) @ T[:3, :3]
    lo, hi = np.percentile(local, [LOW, HIGH], axis=0)
    if kind == "box":
        half = np.maximum(np.abs(lo[:2]), np.abs(hi[:2]))
        return {"x": float(2 * half[0]), "y": float(2 * half[1]), "z": float(max(hi[2], 1e-3))}
    return {"radius": float(np.percentile(np.linalg.norm(local[:, :2], axis=1), 90)),
            "length": float(max(hi[2], 1e-3))}


def _as_pose(T) -> np.ndarray:
    return np.asarray(T, dtype=float).reshape(4, 4)
