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
from scipy.spatial import Delaunay, QhullError, cKDTree

from .neighbours import KDTree, build_tree, nearest, pairs_within, pca_normals
from .voxels import _minus

__all__ = ["segment", "segments_and_patches", "joined_insides", "SEGMENT_REACH", "SEGMENT_NEIGHBOURS",
           "SEGMENT_SMOOTH_DEG"]

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


def segment(points: np.ndarray, origin: np.ndarray | None, voxel: float,
            tree: KDTree | None = None) -> np.ndarray:
    """Segment labels (N,) of voxelized ``points`` (N, 3) cut at concave edges (see
    ``ClickContext.segments``); ``tree``: a tree over them when one exists."""
    return segments_and_patches(points, origin, voxel, tree)[0]


def segments_and_patches(points: np.ndarray, origin: np.ndarray | None, voxel: float,
                         tree: KDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The segment labels (N,) of :func:`segment` and the smooth patch labels (N,) they were
    joined from (``ClickContext.patches``), each numbered from 0."""
    P = points
    N = len(P)
    if N < 3:
        return np.zeros(N, np.int64), np.zeros(N, np.int64)
    n, variation = pca_normals(P, SEGMENT_NEIGHBOURS, tree, variation=True)
    towards = (origin - P) if origin is not None else (P - P.mean(axis=0))
    n[np.einsum("ij,ij->i", n, towards) < 0] *= -1      # towards the sensor, or outwards
    patch, core = _smooth_patches(P, n, variation, voxel)
    patch = np.unique(patch, return_inverse=True)[1]
    if not core.any():
        return np.zeros(N, np.int64), patch
    pairs = pairs_within(P, ADJACENT_REACH * voxel)
    pairs = pairs[patch[pairs[:, 0]] != patch[pairs[:, 1]]]
    if not len(pairs):
        return patch, patch
    A = np.concatenate([pairs[:, 0], pairs[:, 1]])       # each contact seen from both sides
    B = np.concatenate([pairs[:, 1], pairs[:, 0]])
    sides, group = np.unique(patch[A] * N + patch[B], return_inverse=True)
    voxels = np.bincount(np.unique(group * N + A) // N, minlength=len(sides))
    at = np.stack([np.bincount(group, weights=P[A, k], minlength=len(sides))
                   for k in range(3)], axis=1) / np.bincount(group)[:, None]
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
            planar[g] = u is not None and len(idx) >= 3 and \
                float(np.sqrt(np.mean(((P[idx] - mean_p[g]) @ u) ** 2))) <= PLANAR * voxel
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
        in_front = (planar[g] and ni @ -step > STEP * voxel) or \
            (planar[h] and nj @ step > STEP * voxel)
        convex = (ni - nj) @ step > 0 and not in_front
        # (one surface cut by the noise: nearly parallel, and in one plane)
        flat = ni @ nj >= math.cos(math.radians(CONCAVE_DEG)) and \
            max(abs(step @ ni), abs(step @ nj)) <= COPLANAR * voxel
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
    smooth = np.take(flat, a) & np.take(flat, b) & (
        np.einsum("ij,ij->i", np.take(n, a, axis=0), np.take(n, b, axis=0))
        >= math.cos(math.radians(SEGMENT_SMOOTH_DEG)))
    patch = _components(len(P), pairs[smooth])
    core = flat & (np.bincount(patch)[patch] >= MIN_PATCH)
    if core.any() and not core.all():
        _, j = nearest(build_tree(P[core]), P[~core])
        patch[~core] = patch[core][j]
    return patch, core


def _unit(v: np.ndarray):
    norm = float(np.linalg.norm(v))
    return v / norm if norm > 1e-9 else None


def _connected_to(points: np.ndarray, keep: np.ndarray, click: np.ndarray, gap: float,
                  reach: float) -> np.ndarray:
    """The kept points connected (steps <= ``gap``) to any kept point within ``reach`` of the
    click. (Occlusion splits one object into parts at different depths; reaching out from the
    click gathers them.)"""
    pts = np.compress(keep, points, axis=0)
    if len(pts) == 0:
        return pts
    seeds = np.linalg.norm(_minus(pts, click), axis=1) <= reach
    if not seeds.any():
        return pts[:0]
    labels = _gap_components(pts, gap)
    wanted = np.unique(labels[seeds])
    return np.compress(np.isin(labels, wanted), pts, axis=0)


#: the cluster's components are first those of the steps within this fraction of the gap (a
#: surface sampled at a voxel holds a sixth of its pairs within the gap there)
FIRST_GAP = 0.4


def _gap_components(points: np.ndarray, gap: float) -> np.ndarray:
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
    near, _ = nearest(build_tree(np.compress(outside, points, axis=0)), points,
                      gap * (1 + 1e-6))
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


#: a segment is the inside of another -- a mug's bottom and inner wall within its rim -- where
#: at least INSIDE_SHARE of its points, seen along the support's normal, lie within the other's
#: footprint (the convex hull of its points), the other rises more than INSIDE_RISE (m) above
#: its top, and the other's points surround it: they lie in at least INSIDE_SECTORS of 8
#: directions around its centre
INSIDE_SHARE = 0.9
INSIDE_RISE = 0.01
INSIDE_SECTORS = 6


def joined_insides(points: np.ndarray, labels: np.ndarray, clicked: int, normal: np.ndarray,
                   ) -> np.ndarray:
    """``labels`` (N,) of ``points`` (N, 3) with the clicked object's inside joined to it: the
    segment ``clicked`` is an object's inside (see INSIDE_SHARE) -- the object's segment and
    every other inside of it take the clicked label -- or the insides of the clicked segment
    join it. ``normal``: the support's (up). Unchanged where there is no such inside."""
    up = np.asarray(normal, float)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    flat = np.stack([points @ e1, points @ np.cross(up, e1)], axis=1)
    height = points @ up
    ids = np.unique(labels)
    if len(ids) < 2:
        return labels
    members = {int(k): np.flatnonzero(labels == k) for k in ids}
    tops = {k: float(np.percentile(height[m], 99)) for k, m in members.items()}

    def inside(k: int, outer: int) -> bool:
        if k == outer or len(members[outer]) < 4 or tops[outer] < tops[k] + INSIDE_RISE:
            return False
        ring = flat[members[outer]]
        try:
            hull = Delaunay(ring)
        except (QhullError, ValueError):
            return False
        mine = flat[members[k]]
        if np.mean(hull.find_simplex(mine) >= 0) < INSIDE_SHARE:
            return False
        around = ring - mine.mean(axis=0)
        sectors = np.unique(np.floor((np.arctan2(around[:, 1], around[:, 0]) + math.pi) /
                                     (math.pi / 4)).astype(np.int64) % 8)
        return len(sectors) >= INSIDE_SECTORS

    outer = next((k for k in members if inside(int(clicked), k)), int(clicked))
    out = np.array(labels)
    for k in members:
        if k == outer or k == clicked or inside(k, outer):
            out[members[k]] = clicked
    return out
