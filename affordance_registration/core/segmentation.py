# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Segmentation of the points around a click: the cluster connected to the click (steps of at
most a gap, reaching out from the click across occlusions), and the cluster's segments cut at
concave edges, where two touching surfaces meet (``ClickContext.segments``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from .neighbours import KDTree, build_tree, nearest, pairs_within, pca_normals
from .voxels import minus_point

__all__ = [
    "segment",
    "segments_and_patches",
    "joined_insides",
    "share_within",
    "SEGMENT_REACH",
    "SEGMENT_NEIGHBOURS",
    "SEGMENT_SMOOTH_DEG",
]

#: the cluster's segments (``ClickContext.segments``) are grown in two steps, as in locally
#: convex connected patches: smooth patches first -- voxels this many voxel edges apart are
#: neighbours, their normals and surface variation from SEGMENT_NEIGHBOURS points, joined where
#: both are flat (variation at most EDGE_VARIATION) and their normals within SEGMENT_SMOOTH_DEG;
#: the voxels on edges (a real sensor blurs a concave seam into a band of normals turning by a
#: few degrees a voxel, which joined two touching objects pair by pair) go to the nearest patch
#: of at least MIN_PATCH voxels
SEGMENT_REACH = 1.8
SEGMENT_NEIGHBOURS = 12
SEGMENT_SMOOTH_DEG = 15.0
EDGE_VARIATION = 0.03
MIN_PATCH = 3
#: ... then patches within ADJACENT_REACH voxel edges of each other (at CONTACT_VOXELS voxels
#: of each at least) are joined where they meet convexly or within CONCAVE_DEG of flat (and
#: within COPLANAR voxel edges of one plane: one surface the noise cut), judged
#: from each patch's flat voxels within LOCAL_REACH voxel edges of where they meet (their mean
#: normal and position): a box's faces stay one segment, two touching objects do not
ADJACENT_REACH = 3.0
CONTACT_VOXELS = 2
LOCAL_REACH = 10.0
CONCAVE_DEG = 10.0
COPLANAR = 2.0
#: ... and not where one of them is a plane (its flat voxels there within PLANAR voxel edges of
#: their mean plane, RMS) with the other's standing in front of it by more than STEP voxel
#: edges: a box standing on another's top face, where the test of the two sides' means --
#: each side's signed distance from the other's plane, summed -- nearly cancels (the side
#: face stands in front of the top face's plane, the top face lies behind the side's)
PLANAR = 0.3
STEP = 2.0


def segment(
    points: np.ndarray, origin: np.ndarray | None, voxel: float, tree: KDTree | None = None
) -> np.ndarray:
    """Segment labels (N,) of voxelized ``points`` (N, 3) cut at concave edges (see
    ``ClickContext.segments``); ``tree``: a tree over them when one exists."""
    return segments_and_patches(points, origin, voxel, tree)[0]


def segments_and_patches(
    points: np.ndarray, origin: np.ndarray | None, voxel: float, tree: KDTree | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The segment labels (N,) of :func:`segment` and the smooth patch labels (N,) they were
    joined from (``ClickContext.patches``), each numbered from 0."""
    P = points
    N = len(P)
    if N < 3:
        return np.zeros(N, np.int64), np.zeros(N, np.int64)
    n, variation = pca_normals(P, SEGMENT_NEIGHBOURS, tree, variation=True)
    towards = (origin - P) if origin is not None else (P - P.mean(axis=0))
    n[np.einsum("ij,ij->i", n, towards) < 0] *= -1  # towards the sensor, or outwards
    patch, core = _smooth_patches(P, n, variation, voxel)
    patch = np.unique(patch, return_inverse=True)[1]
    if not core.any():
        return np.zeros(N, np.int64), patch
    pairs = pairs_within(P, ADJACENT_REACH * voxel)
    pairs = pairs[patch[pairs[:, 0]] != patch[pairs[:, 1]]]
    if not len(pairs):
        return patch, patch
    A = np.concatenate([pairs[:, 0], pairs[:, 1]])  # each contact seen from both sides
    B = np.concatenate([pairs[:, 1], pairs[:, 0]])
    sides, group = np.unique(patch[A] * N + patch[B], return_inverse=True)
    voxels = np.bincount(np.unique(group * N + A) // N, minlength=len(sides))
    at = (
        np.stack(
            [np.bincount(group, weights=P[A, k], minlength=len(sides)) for k in range(3)], axis=1
        )
        / np.bincount(group)[:, None]
    )
    local = cKDTree(P).query_ball_point(at, LOCAL_REACH * voxel)
    mean_n, mean_p = np.zeros((len(sides), 3)), at.copy()
    planar = np.zeros(len(sides), bool)
    own = sides // N
    for g, idx in enumerate(local):
        idx = np.asarray(idx, np.int64)
        idx = idx[core[idx] & (patch[idx] == own[g])]
        if len(idx):
            mean_n[g], mean_p[g] = n[idx].mean(axis=0), P[idx].mean(axis=0)
            u = _unit(mean_n[g])
            planar[g] = (
                u is not None
                and len(idx) >= 3
                and float(np.sqrt(np.mean(((P[idx] - mean_p[g]) @ u) ** 2))) <= PLANAR * voxel
            )
    back = {int(k): g for g, k in enumerate(sides)}
    join = []
    for g, key in enumerate(sides):
        i, j = divmod(int(key), N)
        h = back[j * N + i]
        if i > j or voxels[g] < CONTACT_VOXELS or voxels[h] < CONTACT_VOXELS:
            continue
        ni, nj = _unit(mean_n[g]), _unit(mean_n[h])
        if ni is None or nj is None:
            continue
        step = mean_p[g] - mean_p[h]
        in_front = (planar[g] and ni @ -step > STEP * voxel) or (
            planar[h] and nj @ step > STEP * voxel
        )
        convex = (ni - nj) @ step > 0 and not in_front
        # (one surface cut by the noise: nearly parallel, and in one plane)
        flat = (
            ni @ nj >= math.cos(math.radians(CONCAVE_DEG))
            and max(abs(step @ ni), abs(step @ nj)) <= COPLANAR * voxel
        )
        if convex or flat:
            join.append((i, j))
    merged = _components(N, np.array(join, np.int64).reshape(-1, 2))[patch]
    return np.unique(merged, return_inverse=True)[1], patch


def _smooth_patches(P: np.ndarray, n: np.ndarray, variation: np.ndarray, voxel: float):
    """Smooth patch labels (N,) -- every voxel in one, edge voxels in their nearest's -- and
    which voxels are a patch's own flat ones (N,) bool."""
    pairs = pairs_within(P, SEGMENT_REACH * voxel)
    a, b = pairs[:, 0], pairs[:, 1]
    flat = variation <= EDGE_VARIATION
    smooth = (
        np.take(flat, a)
        & np.take(flat, b)
        & (
            np.einsum("ij,ij->i", np.take(n, a, axis=0), np.take(n, b, axis=0))
            >= math.cos(math.radians(SEGMENT_SMOOTH_DEG))
        )
    )
    patch = _components(len(P), pairs[smooth])
    core = flat & (np.bincount(patch)[patch] >= MIN_PATCH)
    if core.any() and not core.all():
        _, j = nearest(build_tree(P[core]), P[~core])
        patch[~core] = patch[core][j]
    return patch, core


def _unit(v: np.ndarray):
    norm = float(np.linalg.norm(v))
    return v / norm if norm > 1e-9 else None


def connected_to(
    points: np.ndarray, keep: np.ndarray, click: np.ndarray, gap: float, reach: float
) -> np.ndarray:
    """The kept points connected (steps <= ``gap``) to any kept point within ``reach`` of the
    click. (Occlusion splits one object into parts at different depths; reaching out from the
    click gathers them.)"""
    pts = np.compress(keep, points, axis=0)
    if len(pts) == 0:
        return pts
    seeds = np.linalg.norm(minus_point(pts, click), axis=1) <= reach
    if not seeds.any():
        return pts[:0]
    labels = gap_components(pts, gap)
    wanted = np.unique(labels[seeds])
    return np.compress(np.isin(labels, wanted), pts, axis=0)


#: the cluster's components are first those of the steps within this fraction of the gap (a
#: surface sampled at a voxel holds a sixth of its pairs within the gap there)
FIRST_GAP = 0.4


def gap_components(points: np.ndarray, gap: float) -> np.ndarray:
    """Component label (N,) of each of ``points`` (N, 3), joined by steps of at most ``gap``
    (m): the components of the steps within FIRST_GAP of it, joined where points of two of them
    are within the gap -- pairs looked for only among the points outside the largest one and
    those of it within the gap of them (every such step has an end outside it). The same
    components as those of every pair within the gap, for a fraction of the pairs."""
    n = len(points)
    first = _components(n, pairs_within(points, FIRST_GAP * gap))
    outside = first != np.argmax(np.bincount(first))
    if not outside.any():
        return first
    near, _ = nearest(build_tree(np.compress(outside, points, axis=0)), points, gap * (1 + 1e-6))
    idx = np.flatnonzero(outside | np.isfinite(near))
    pairs = pairs_within(np.take(points, idx, axis=0), gap)
    a, b = first[np.take(idx, pairs[:, 0])], first[np.take(idx, pairs[:, 1])]
    join = a != b
    return _components(n, np.stack([a[join], b[join]], axis=1))[first]


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component label (n,) of each of ``n`` nodes joined by the edges ``pairs``
    (M, 2). The graph goes to scipy as rows of neighbours (CSR) grouped by a stable sort of
    the first indices -- a radix sort for up to 65536 nodes -- rather than as coordinates,
    whose conversion sorts every row's neighbours as well (the slow part; the components do
    not need it)."""
    rows, cols = pairs[:, 0], pairs[:, 1]
    order = np.argsort(rows.astype(np.uint16) if n <= 65536 else rows, kind="stable")
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    graph = csr_matrix((np.ones(len(rows)), np.take(cols, order), indptr), shape=(n, n))
    return connected_components(graph, directed=False)[1]


#: a segment is an object's inside -- a mug's bottom within its walls -- where the cluster's
#: points near it (horizontally within twice its own reach and INSIDE_REACH m) that rise more
#: than INSIDE_RISE (m) above its top hold at least INSIDE_SHARE of its points within their
#: footprint (the convex hull, seen along the support's normal) and surround it: they lie in
#: at least INSIDE_SECTORS of 8 directions around its centre -- or the points of one segment
#: (at any reach) do so.
INSIDE_SHARE = 0.9
INSIDE_RISE = 0.01
INSIDE_REACH = 0.02
INSIDE_SECTORS = 6
#: Its object: the segments with at least half their points within the circle those rising
#: points lie on, grown by half WALL_OUT. Or a vessel's far inside wall, up to its rim: up to
#: WALL_MAX (m) in radius, at least 80% of its points within WALL_FIT (m) of the circle, their
#: median FAR_SIDE radii past the centre away from the sensor; its object's points lie within
#: WALL_OUT (m) outside that circle
WALL_MAX = 0.15
WALL_FIT = 0.004
FAR_SIDE = 0.3
WALL_OUT = 0.012
#: ... and the segments with points within RIM_REACH (m) of the wall's top are its rim's
RIM_REACH = 0.012
RIM_STEPS = 4  #: (segments joined to the rim in turn, at most this many times)


def joined_insides(
    points: np.ndarray,
    labels: np.ndarray,
    clicked: int,
    normal: np.ndarray,
    x_hint: np.ndarray,
    origin: np.ndarray | None = None,
) -> np.ndarray:
    """``labels`` (N,) of ``points`` (N, 3) with an inside joined to its object: where the
    segment ``clicked`` is an inside (see INSIDE_SHARE), it and the segments around it take
    the clicked label; else the segments inside the clicked one join it. ``normal``: the
    support's (up); ``x_hint``: a direction attached to the scan (the directions around are
    counted from it: the same answer in every frame); ``origin``: the sensor's (where the
    clicked segment is a vessel's far inside wall, up to its rim: :func:`_within_far_wall`).
    Unchanged where there is no such inside."""
    ids, counts = np.unique(labels, return_counts=True)
    if len(ids) < 2:
        return labels
    up = np.asarray(normal, float)
    e1 = np.asarray(x_hint, float) - (np.asarray(x_hint, float) @ up) * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    plane_axes = np.stack([e1, np.cross(up, e1)], axis=1)  # (3, 2): seen along ``up``
    flat = points @ plane_axes
    height = points @ up

    def around(k: int, others: np.ndarray, reach: float | None = None):
        """(whether segment ``k`` is an inside of the points ``others`` (bool mask) near it --
        within ``reach`` of its centre, by default twice its own and INSIDE_REACH -- the mask of
        the points rising round it)."""
        mine = labels == k
        centre = flat[mine].mean(axis=0)
        if reach is None:
            reach = (
                2.0 * float(np.percentile(np.linalg.norm(flat[mine] - centre, axis=1), 95))
                + INSIDE_REACH
            )
        ring = (
            (np.linalg.norm(flat - centre, axis=1) <= reach)
            & others
            & (height > np.percentile(height[mine], 99) + INSIDE_RISE)
        )
        if ring.sum() < 4 or share_within(flat[mine], flat[ring]) < INSIDE_SHARE:
            return False, ring
        off = flat[ring] - centre
        sectors = np.unique(
            np.floor((np.arctan2(off[:, 1], off[:, 0]) + math.pi) / (math.pi / 4)).astype(np.int64)
            % 8
        )
        return len(sectors) >= INSIDE_SECTORS, ring

    out = np.array(labels)
    # an inside of one segment (the walls one segment), or of those rising round it
    rings = [around(clicked, labels == k, np.inf) for k in ids if k != clicked]
    rings.append(around(clicked, labels != clicked))
    ring = np.zeros(len(labels), bool)
    for inside, r in rings:
        if inside:
            ring |= r
    within = np.zeros(len(labels), bool)
    if ring.sum() >= 3:  # (the rim's circle)
        centre, r = _circle_2d(flat[ring])
        if 0.0 < r <= WALL_MAX:
            within = np.linalg.norm(flat - centre, axis=1) <= r + WALL_OUT / 2
    rim_of = None
    if origin is not None:
        far = _within_far_wall(
            flat, height, labels == clicked, np.asarray(origin, float) @ plane_axes
        )
        if far.any():  # (and what meets the wall at its top: the rim, piece by piece)
            within |= far
            rim_of = np.array([clicked])
            for _ in range(RIM_STEPS):
                mine = np.isin(labels, rim_of)
                top = mine & (height >= np.percentile(height[mine], 99) - INSIDE_RISE)
                d, _ = cKDTree(points[top]).query(points, distance_upper_bound=RIM_REACH)
                grown = np.union1d(rim_of, labels[np.isfinite(d)])
                if len(grown) == len(rim_of):
                    break
                rim_of = grown
    if within.any():
        held = np.bincount(labels[within], minlength=int(ids.max()) + 1)[ids]
        for k, n, h in zip(ids, counts, held):
            if 2 * h >= n or (rim_of is not None and k in rim_of):
                out[labels == k] = clicked
        return out
    for k in ids:  # the clicked one's insides
        if k != clicked and around(int(k), labels == clicked, np.inf)[0]:
            out[labels == k] = clicked
    return out


#: m: a point this close outside a hull's edge is on it (rounding)
HULL_TOL = 1e-12


def share_within(points: np.ndarray, outline: np.ndarray) -> float:
    """The share of the 2-D ``points`` (N, 2) inside the convex hull of ``outline`` (M, 2): 0
    where the outline has no area (fewer than three points off one line). Inside: on the inner
    side of every edge of the hull (Qhull's unit outward normals and offsets), up to HULL_TOL --
    the triangulation's ``find_simplex`` answered the same at 15-40 times the cost."""
    try:
        eq = ConvexHull(outline).equations
    except (QhullError, ValueError):
        return 0.0
    inside = np.all(points @ eq[:, :2].T + eq[:, 2] <= HULL_TOL, axis=1)
    return float(np.mean(inside)) if len(points) else float("nan")


def _within_far_wall(
    flat: np.ndarray, height: np.ndarray, mine: np.ndarray, sensor: np.ndarray
) -> np.ndarray:
    """The points (mask) horizontally within a vessel whose far inside wall the segment
    ``mine`` is: its points above its lowest (``flat``: seen along the support's normal,
    ``height`` along it) lie on a circle (the algebraic fit, its points within WALL_FIT of it)
    on the side of its centre away from the ``sensor`` (``flat`` too) -- a can's side, seen
    from outside, lies on the near side -- the circle then grown by WALL_OUT. None such: all
    False."""
    none = np.zeros(len(flat), bool)
    wall = mine & (height > np.percentile(height[mine], 5) + INSIDE_RISE)
    if wall.sum() < 10:
        return none
    uv = flat[wall]
    centre, r = _circle_2d(uv)
    off = uv - centre
    dist = np.linalg.norm(off, axis=1)
    if not 0.0 < r <= WALL_MAX or np.mean(np.abs(dist - r) <= WALL_FIT) < 0.8:
        return none
    away = centre - sensor
    away /= max(float(np.linalg.norm(away)), 1e-9)
    if float(np.median(off @ away)) < FAR_SIDE * r:
        return none
    return np.linalg.norm(flat - centre, axis=1) <= r + WALL_OUT


def _circle_2d(uv: np.ndarray) -> tuple[np.ndarray, float]:
    """The algebraic (Kasa) circle through 2-D points ``uv`` (N, 2): (centre (2,), radius)."""
    sol = np.linalg.lstsq(
        np.column_stack([2 * uv, np.ones(len(uv))]), (uv**2).sum(axis=1), rcond=None
    )[0]
    return sol[:2], math.sqrt(max(float(sol[2] + sol[:2] @ sol[:2]), 0.0))
