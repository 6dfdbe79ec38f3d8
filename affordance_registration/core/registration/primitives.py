# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Primitive templates (a box, a cylinder): the pose *and* the dimensions from the clicked object.

An object outside the library is often a box or a can. Its primitive is measured, not searched
for: the clicked object's points (the clicked segment of the cluster, ``ClickContext.segments``:
a convex object is one segment, the neighbours it touches are others) are laid out in a frame
from the surface it stands on -- +z along the support's normal -- and

* a box's footprint is the smallest rectangle around the points projected onto the support
  (its edges' directions tried), its height the top of the points above the support (its base
  on the support when the points reach down to it, else at their lowest);
* a cylinder stands (axis along the normal: a circle fitted to the side points' footprint) or
  lies (axis across the normal, along the direction the surface normals leave out -- or, for a
  short wide one showing its end face, across that: a circle fitted to the points seen along
  the axis); the one with the lower residual is kept.

Without a support the object's principal axes take its place. The best of the ways it may stand
is then refined at its measured size (the fine stage, the pose only); dimensions are clipped to
the template's ranges, and a primitive is judged (:func:`.scoring.judge`) like any candidate.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..neighbours import build_tree
from ..plane import reaches_behind
from ..scene import ClickContext, ransac_plane
from ..segmentation import segments_and_patches, share_within
from ..templates import AffordanceTemplate
from ..transforms import make_T
from .explains import ObjectVoxels
from .icp import fine_stage
from .model import ModelCache
from .results import FitResult
from .scoring import open_share, result
from .settings import FitSettings

__all__ = [
    "fit_primitive",
    "refine_primitive",
    "object_points",
    "object_voxels",
    "truncated",
    "past_crop",
    "stacked",
]

#: the primitives within this share of the best one's likelihood (as measured) are refined
REFINE_SHARE = 0.8

#: points this close to the support (m) reach down to it: the base lies on the support
BASE_REACH = 0.03
#: extents are read between these percentiles of the points (mixed pixels at the edges), or
#: of a top face's points up to this one (they end at the edge)
LOW, HIGH = 1.0, 99.0
EDGE = 99.8
#: a cylinder's side points: normals within this of perpendicular to the axis (cosine)
SIDE_COS = 0.5
#: a primitive the sensor sees into through at least this share of its surface is open (a
#: mug's top): its pose is not refined at its measured size
OPEN_SHARE = 0.03
#: a box's face points: normals within this of the face's (cosine); a face is seen with at
#: least FACE_POINTS of them
FACE_COS = 0.8
FACE_POINTS = 20
#: a box's top face points lie within this (m) of its top
TOP_BAND = 0.01
#: more than this share of a box's points past its top face's edge (by TOP_BAND) are more
#: than mixed pixels: the top face seen is not all of the box's top there
PAST_TOP = 0.05
#: at most this many of the object's points are measured (an even subset)
MEASURE_POINTS = 2000
#: rounds of pose refinement (the fine stage) and measuring again before the final measure
REFINE_ROUNDS = 0
#: an object's sides are seen where at least this share of its points face sideways
SIDES_SEEN = 0.05
#: a click on the crop's dominant plane: the support is a plane holding at least this fraction
#: of the points off it, the click above it
FLOOR_FRACTION = 0.15
#: planes the click lies behind (another object's face in front of it) are set aside this many
#: times in the search for the surface the clicked object stands on
FLOOR_TRIES = 3
#: a stack the segments did not part (boxes standing on each other, a side of one flush with
#: the other's): the object's up-facing points lie at heights more than TOP_BAND apart, each
#: level holding at least this share of its points (and FACE_POINTS)
STACK_SHARE = 0.03
#: ... and not one within another: a lower level with at least this share of its points inside
#: the outline (seen from above) of a level over it is a vessel's inside bottom within its rim
#: (a handle's arm may lie between them) -- a stack's lower top face shows round the upper
#: box's footprint
INSIDE_SHARE = 0.5
#: the clicked object reaching this fraction of the crop's radius from the click is cut off by
#: the crop (a wall, a table, an object larger than the library's templates): not measured
TRUNCATED = 0.95


def fit_primitive(
    ctx: ClickContext,
    template: AffordanceTemplate,
    cache: ModelCache,
    settings: FitSettings,
    dimensions: dict | None = None,
    T_init: np.ndarray | None = None,
    measured=None,
    refine: bool = True,
) -> FitResult:
    """The primitive ``template`` fitted to the clicked object: pose and dimensions measured
    from the object's points (and, with REFINE_ROUNDS, the pose refined and the dimensions
    measured again in the refined frame). ``dimensions`` (and ``T_init``, the pose to refine
    from): the operator's, kept as given -- only the pose is refined. ``measured``: what
    :func:`object_points` gives for this click (computed when None). ``refine`` False: the
    measured pose as it is (:func:`refine_primitive` refines it later)."""
    points, normals, support, up = measured if measured is not None else object_points(ctx)
    if dimensions is not None:
        T = (
            _as_pose(T_init)
            if T_init is not None
            else next(_hypotheses(template.primitive, points, normals, up, support, ctx.frame))[0]
        )
        return _refined(ctx, template, cache, settings, T, template.clip_dimensions(dimensions))
    best = None
    for T, dims in _hypotheses(template.primitive, points, normals, up, support, ctx.frame):
        for _ in range(REFINE_ROUNDS):
            res = _refined(ctx, template, cache, settings, T, template.clip_dimensions(dims))
            T, dims = _measure_in(
                template.primitive, res.T_scene_model, points, normals, up, support
            )
        res = _refined(
            ctx, template, cache, settings, T, template.clip_dimensions(dims), refine=False
        )
        if best is None or res.likelihood > best.likelihood:
            best = res
    return refine_primitive(ctx, template, cache, settings, best) if refine else best


def refine_primitive(
    ctx: ClickContext,
    template: AffordanceTemplate,
    cache: ModelCache,
    settings: FitSettings,
    res: FitResult,
) -> FitResult:
    """A measured primitive ``res``, its pose refined at its measured size (a real scan's mixed
    pixels and a lip or a rounded edge leave the measured pose a few millimetres off), where
    that explains the scan better. An open one (a mug seen into: at least OPEN_SHARE of its
    surface, :func:`.scoring.open_share`) keeps its measured pose: its closed surface would be
    pulled onto what is seen inside it."""
    if (
        open_share(ctx, cache.model(template.sized(res.dimensions)), res.T_scene_model, settings)
        >= OPEN_SHARE
    ):
        return res
    refined = _refined(ctx, template, cache, settings, res.T_scene_model, res.dimensions)
    return refined if refined.likelihood > res.likelihood else res


def _refined(ctx, template, cache, settings, T, dims, refine: bool = True) -> FitResult:
    """The primitive at ``dims`` from pose ``T``: refined locally (the pose only), scored."""
    model = cache.model(template.sized(dims))
    R, t, iterations, converged = T[:3, :3], T[:3, 3], 0, None
    if refine:
        fit = fine_stage(ctx, model, R, t, settings.stages.refit, settings, hold_joint=True)
        R, t, iterations, converged = fit.R[0], fit.t[0], fit.iterations, fit.converged[0]
    res = result(ctx, model, R, t, settings, iterations, converged)
    return replace(res, primitive=template.primitive, dimensions=model.template.dimensions)


def truncated(ctx: ClickContext, measured) -> bool:
    """Whether the clicked object's points (``measured``: :func:`object_points`) reach the edge
    of the crop."""
    return float(np.max(np.linalg.norm(measured[0] - ctx.click, axis=1))) >= TRUNCATED * ctx.radius


def past_crop(ctx: ClickContext, past: bool, judged: list) -> list:
    """The ``judged`` primitives, refused where the clicked object runs ``past`` the crop of
    ``ctx`` (:func:`truncated`): a wall, or an object larger than the crop."""
    if not past:
        return judged
    why = (
        f"the clicked surface runs past the {ctx.radius:.2f} m around the click: "
        "it cannot be measured"
    )
    return [
        replace(r, fits=False, reason=f"{r.reason}; {why}" if r.reason else why) for r in judged
    ]


def object_points(ctx: ClickContext):
    """The clicked object's full-resolution points, their normals (towards the sensor), the
    surface it stands on (a :class:`~..scene.Plane`, or None) and the object's up direction
    (None: unknown): the points whose nearest cluster voxel lies in the clicked object's voxels
    (:func:`object_voxels`)."""
    region = object_voxels(ctx)
    mine = region.member(ctx.fine)
    if mine.sum() < 10:
        mine[:] = True
    points, normals = ctx.fine[mine], np.array(ctx.fine_normals[mine])
    towards = (
        (ctx.sensor_origin - points)
        if ctx.sensor_origin is not None
        else (points - points.mean(axis=0))
    )  # outwards without a viewpoint
    normals[np.einsum("ij,ij->i", normals, towards) < 0] *= -1
    if len(points) > MEASURE_POINTS:  # an even subset measures as well
        keep = np.linspace(0, len(points) - 1, MEASURE_POINTS).astype(np.int64)
        points, normals = points[keep], normals[keep]
    support, up = region.support, region.up
    return points, normals, support, (_up(support, points) if up is None else up)


def object_voxels(ctx: ClickContext) -> ObjectVoxels:
    """The clicked object's voxels: the clicked segment of the cluster. Where the click is on
    the crop's dominant plane (a box's large face), that plane is the object's and the cluster
    holds what it stands on too: the support is looked for among the points off that face
    (:func:`_floor`: a table under a box's top face, or across from its side), and the object
    is cut from what lies above it; without one the face is the object's top. Where the crop
    has no dominant plane, or one the click lies behind (the face of a larger box in front of a
    smaller one standing on it), the support is looked for among the cluster's other segments
    (none there: that plane, if any, stays the support). A support the clicked object reaches
    behind (:func:`~..plane.reaches_behind`) is none: the floor is looked for among the
    cluster's other segments, and without one the object stands on nothing known."""
    cluster, labels, patches, support = ctx.cluster, ctx.segments, ctx.patches, ctx.support
    clicked = ctx.clicked_segment
    thr = ctx.plane_threshold
    up = None
    if (
        ctx.plane is None
        and support is not None
        and abs(support.distance(ctx.click[None])[0]) <= 2 * thr
    ):
        # (without a floor, the face is the object's top: +z out of it, the base unseen)
        face, support, up = support, None, np.asarray(support.normal, float)
        floor = _floor(ctx, cluster[np.abs(face.distance(cluster)) > thr])
        if floor is not None:
            above = floor.distance(cluster) > thr
            if above.sum() >= 10:
                cluster = cluster[above]
                labels, patches = segments_and_patches(cluster, ctx.sensor_origin, ctx.voxel)
                clicked = labels[int(np.argmin(np.linalg.norm(cluster - ctx.click, axis=1)))]
                support, up = floor, None
    elif ctx.sensor_origin is not None and (
        support is None or support.distance(ctx.click[None])[0] < -2 * thr
    ):
        off = labels != clicked
        if support is not None:
            off &= np.abs(support.distance(cluster)) > thr
        floor = _floor(ctx, cluster[off])
        if floor is not None:  # (none found: a plane in front still gives the axis)
            support = floor
    if support is not None and reaches_behind(support, cluster[labels == clicked], thr):
        # the object reaches behind that plane: it stands on something else, if on anything
        # the cluster shows (a plane the object reaches behind too is not that either)
        others = (labels != clicked) & (np.abs(support.distance(cluster)) > thr)
        support, up = _floor(ctx, cluster[others]), None
        if support is not None and reaches_behind(support, cluster[labels == clicked], thr):
            support = None
    tree = build_tree(cluster) if cluster is not ctx.cluster else ctx.cluster_tree
    return ObjectVoxels(cluster, tree, labels, patches, int(clicked), ctx.voxel, support, up)


def stacked(ctx: ClickContext, measured):
    """The clicked box of a stack the segments took for one object: where the clicked
    object's up-facing points (``measured``: :func:`object_points`' tuple) lie at two or more
    heights over its support (levels more than TOP_BAND apart, each at least STACK_SHARE of
    the points), the part between the level tops below and above the click -- standing on
    the support or on the level below it. Returns (``ctx`` with its clicked segment cut there
    (:meth:`ClickContext.with_clicked_part`), the part's ``measured`` tuple), or None: one
    level, no support, a level within one over it (INSIDE_SHARE: a mug's inside bottom
    within its rim), or too few points in the part."""
    points, normals, support, up = measured
    if support is None or up is None:
        return None
    sign = 1.0 if float(np.asarray(support.normal) @ up) > 0 else -1.0
    height = sign * support.distance(points)
    facing = normals @ up > FACE_COS
    order = np.argsort(height[facing], kind="stable")
    tops, where = height[facing][order], points[facing][order]
    split = np.flatnonzero(np.diff(tops) > TOP_BAND) + 1
    big = (
        [
            (g, at)
            for g, at in zip(np.split(tops, split), np.split(where, split))
            if len(g) >= max(FACE_POINTS, STACK_SHARE * len(points))
        ]
        if len(tops)
        else []
    )
    levels = [g for g, _ in big]
    if len(levels) < 2 or any(
        _within(low, high, up, ctx.frame[:, 0]) >= INSIDE_SHARE
        for i, (_, low) in enumerate(big)
        for _, high in big[i + 1 :]
    ):
        return None
    cuts = [float(np.percentile(g, EDGE)) for g in levels[:-1]]  # each lower level's top
    k = int(np.searchsorted(cuts, sign * float(support.distance(ctx.click[None])[0])))
    lo, hi = (cuts[k - 1] if k else -np.inf), (cuts[k] if k < len(cuts) else np.inf)
    part = (height > lo) & (height <= hi)
    if part.sum() < FACE_POINTS:
        return None
    base = (
        support
        if k == 0
        else replace(support, d=float(support.d - sign * np.median(levels[k - 1])))
    )
    on_cluster = sign * support.distance(ctx.cluster)
    cut = ctx.with_clicked_part((on_cluster > lo) & (on_cluster <= hi))
    return cut, (points[part], normals[part], base, up)


def _within(points: np.ndarray, outline: np.ndarray, up: np.ndarray, x_hint) -> float:
    """The share of ``points`` inside the convex outline of ``outline``'s points, both seen
    along ``up`` (:func:`~..segmentation.share_within`)."""
    B = np.stack(_basis(np.asarray(up, float), x_hint), axis=1)
    return share_within(points @ B, outline @ B)


def _floor(ctx: ClickContext, points: np.ndarray):
    """The surface the clicked object stands on, among ``points`` (off the object): the largest
    plane holding at least ``FLOOR_FRACTION`` of them with the click more than two plane
    thresholds on its sensor's side; a plane the click lies behind is set aside (its points
    taken out) and the next largest looked for, up to ``FLOOR_TRIES`` planes. None: none."""
    thr, left = ctx.plane_threshold, points
    for attempt in range(FLOOR_TRIES):
        if len(left) < 50:
            return None
        plane = ransac_plane(
            left,
            thr,
            min(1.0, FLOOR_FRACTION * len(points) / len(left)),
            ctx.sensor_origin,
            attempt,
        )
        if plane is None:
            return None
        if plane.distance(ctx.click[None])[0] > 2 * thr:
            return plane
        left = left[np.abs(plane.distance(left)) > thr]
    return None


def _hypotheses(
    kind: str, points: np.ndarray, normals: np.ndarray, up, support, frame: np.ndarray
):
    """(T_scene_model, dimensions) measured for each way the primitive may stand: a box
    upright on the support, its yaw from its side faces; a cylinder upright (its x along the
    x of ``frame``, the frame attached to the scan around the click: the same fit in every
    scene frame), and lying along the direction its normals leave out."""
    if up is None:  # no support: the points' least spread, seen side up
        c = points - points.mean(axis=0)
        up = np.linalg.eigh(c.T @ c)[1][:, 0]
        if up @ normals.mean(axis=0) < 0:
            up = -up
    if kind == "box":
        x = _yaw_axis(points, normals, up, frame[:, 0])
        yield _measure_in(kind, _frame(x, up, points.mean(axis=0)), points, normals, up, support)
        return
    yield _measure_in(
        kind, _frame(frame[:, 0], up, points.mean(axis=0)), points, normals, up, support
    )
    axis = _least_normal_direction(normals)
    axis = axis - (axis @ up) * up
    if np.linalg.norm(axis) > 1e-6:
        axis /= np.linalg.norm(axis)
        yield _measure_in(kind, _frame(up, axis, points.mean(axis=0)), points, normals, None, None)
        # a short, wide one lying (a tin on its side) shows its end face more than its side:
        # its axis is then the across direction the normals favour
        across = np.cross(up, axis)
        yield _measure_in(
            kind, _frame(up, across, points.mean(axis=0)), points, normals, None, None
        )


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


def _frame(x_hint, z, origin) -> np.ndarray:
    """A pose with +z along ``z`` and x along ``x_hint`` (made perpendicular), at ``origin``."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    x, y = _basis(z, x_hint)
    return make_T(np.stack([x, y, z], axis=1), origin)


def _yaw_axis(points, normals, up, x_hint) -> np.ndarray:
    """A box's x direction about ``up``: the side faces' normals (their angle folded four
    times onto one direction), else the footprint's smallest enclosing rectangle."""
    x0, y0 = _basis(up, x_hint)
    side = np.abs(normals @ up) < SIDE_COS
    if side.sum() >= FACE_POINTS:
        a = np.arctan2(normals[side] @ y0, normals[side] @ x0)
        theta = math.atan2(np.sin(4 * a).sum(), np.cos(4 * a).sum()) / 4
    else:
        uv = np.stack([points @ x0, points @ y0], axis=1)
        areas = []
        for angle in _edge_angles(uv):
            c, s = math.cos(angle), math.sin(angle)
            rot = uv @ np.array([[c, -s], [s, c]])
            lo, hi = np.percentile(rot, [LOW, HIGH], axis=0)
            areas.append((float(np.prod(hi - lo)), angle))
        theta = min(areas)[1]
    return math.cos(theta) * x0 + math.sin(theta) * y0


def _edge_angles(uv: np.ndarray) -> np.ndarray:
    """Directions (rad, within 90 deg) of the 2-D convex hull's edges: a smallest enclosing
    rectangle has a side along one of them."""
    from scipy.spatial import ConvexHull

    try:
        hull = uv[ConvexHull(uv).vertices]
    except Exception:  # collinear points
        return np.array([0.0])
    d = np.roll(hull, -1, axis=0) - hull
    return np.unique(np.round(np.mod(np.arctan2(d[:, 1], d[:, 0]), math.pi / 2), 4))


def _bounds(along: np.ndarray, face_pos, face_neg, top=None) -> tuple[float, float]:
    """The extent (lo, hi) of the points ``along`` an axis: a face seen on either side is
    where its points' median lies (a face's noise averages out), an unseen one where the
    points end -- the points of the ``top`` face where it is seen (a top face has no mixed
    pixels along its edges' outside), else all of them (percentiles, past mixed pixels). Where
    more than ``PAST_TOP`` of the points lie past the top face's edge (by ``TOP_BAND``), the
    top seen is not all of the object's top there -- a carton's ridge between its roof's
    slopes, a top face half hidden by an object in front: there all of them."""
    lo, hi = np.percentile(along, [LOW, HIGH])
    if top is not None and top.sum() >= FACE_POINTS:
        lo_top, hi_top = np.percentile(along[top], [100 - EDGE, EDGE])
        if np.mean(along < lo_top - TOP_BAND) < PAST_TOP:
            lo = lo_top
        if np.mean(along > hi_top + TOP_BAND) < PAST_TOP:
            hi = hi_top
    if face_pos.sum() >= FACE_POINTS:
        hi = float(np.median(along[face_pos]))
    if face_neg.sum() >= FACE_POINTS:
        lo = float(np.median(along[face_neg]))
    return float(lo), float(hi)


def _measure_in(kind: str, T: np.ndarray, points, normals, up, support):
    """The primitive measured in the frame ``T`` (its axes kept, its origin found): a box's
    faces and a cylinder's side and end; the base on the support where the points reach down
    to it. Returns (T_scene_model, dimensions)."""
    R = T[:3, :3]
    local, nl = (points - T[:3, 3]) @ R, normals @ R
    z = local[:, 2]
    top = nl[:, 2] > FACE_COS
    if top.sum() >= FACE_POINTS:  # the highest of the faces up (a mug's inside bottom faces up)
        top &= z >= np.percentile(z[top], HIGH) - TOP_BAND
    lo_z, hi_z = _bounds(z, top, nl[:, 2] < -FACE_COS)
    if support is not None and up is not None:
        floor = float(-(support.d + support.normal @ T[:3, 3]) / (support.normal @ up))
        sides = np.abs(nl[:, 2]) < SIDE_COS
        # it stands on the support where its points reach down to it, or where its sides
        # are not seen (from above) -- seen sides ending higher up stand on something else
        if lo_z - floor <= BASE_REACH or sides.sum() < max(FACE_POINTS, SIDES_SEEN * len(nl)):
            lo_z = floor
    if kind == "box":
        # (the top face's points are those at its height: a lower box's top face the clicked
        # one stands on faces up too)
        top &= z >= hi_z - TOP_BAND
        lo_x, hi_x = _bounds(local[:, 0], nl[:, 0] > FACE_COS, nl[:, 0] < -FACE_COS, top)
        lo_y, hi_y = _bounds(local[:, 1], nl[:, 1] > FACE_COS, nl[:, 1] < -FACE_COS, top)
        size = [hi_x - lo_x, hi_y - lo_y]
        centre = np.array([(lo_x + hi_x) / 2, (lo_y + hi_y) / 2, lo_z])
        axes = R
        if size[1] > size[0]:  # x along the longer edge
            axes = np.stack([R[:, 1], -R[:, 0], R[:, 2]], axis=1)
            size = size[::-1]
        dims = {"x": float(size[0]), "y": float(size[1]), "z": float(max(hi_z - lo_z, 1e-3))}
        return make_T(axes, T[:3, 3] + R @ centre), dims
    side = np.abs(nl[:, 2]) < SIDE_COS
    use = side if side.sum() >= FACE_POINTS else np.ones(len(local), bool)
    c2, r = _circle(local[use, :2])
    lo_xy, hi_xy = local[:, :2].min(axis=0), local[:, :2].max(axis=0)
    if not (np.isfinite(r) and np.all(np.abs(c2 - (lo_xy + hi_xy) / 2) <= hi_xy - lo_xy)):
        c2, r = (lo_xy + hi_xy) / 2, float(np.max(hi_xy - lo_xy) / 2)  # a failed circle
    centre = np.array([c2[0], c2[1], lo_z])
    return make_T(R, T[:3, 3] + R @ centre), {
        "radius": float(r),
        "length": float(max(hi_z - lo_z, 1e-3)),
    }


def _circle(uv: np.ndarray):
    """Centre (2,) and radius of the circle through 2-D points: the algebraic fit, then
    geometric (Gauss-Newton) steps, the points farther than 3 sigma from it left out."""
    A = np.column_stack([2 * uv, np.ones(len(uv))])
    b = (uv**2).sum(axis=1)
    sol = _least_squares(A, b)
    c = sol[:2]
    r = math.sqrt(max(sol[2] + c @ c, 1e-12))
    keep = np.ones(len(uv), bool)
    for _ in range(10):
        d = uv[keep] - c
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        J = np.column_stack([-d / dist[:, None], -np.ones(len(d))])
        step = _least_squares(J, -(dist - r))
        c, r = c + step[:2], r + step[2]
        res = np.abs(np.linalg.norm(uv - c, axis=1) - r)
        keep = res <= max(3 * float(np.std(res[keep])), 1e-4)
        if np.linalg.norm(step) < 1e-7 or keep.sum() < 5:
            break
    return c, abs(float(r))


def _least_squares(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x minimising |A x - b| for a tall, well-conditioned A (N, 3): the normal equations."""
    try:
        return np.linalg.solve(A.T @ A, A.T @ b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _least_normal_direction(normals: np.ndarray) -> np.ndarray:
    """The direction the normals leave out (least spread of them): a cylinder's axis."""
    return np.linalg.eigh(normals.T @ normals)[1][:, 0]


def _as_pose(T) -> np.ndarray:
    return np.asarray(T, dtype=float).reshape(4, 4)
