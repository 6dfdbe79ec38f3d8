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

from .neighbours import KDTree, build_tree, nearest, pairs_within, pca_normals
from .voxels import _minus

__all__ = ["segment", "SEGMENT_REACH", "SEGMENT_NEIGHBOURS", "SEGMENT_FLAT_DEG"]

#: the cluster's segments (``ClickContext.segments``): voxels this many voxel edges apart are
#: neighbours, their normals from SEGMENT_NEIGHBOURS points; a pair stays joined where the
#: normals are within SEGMENT_FLAT_DEG (one surface, with a real sensor's noise) or meet
#: convexly
SEGMENT_REACH = 1.8
SEGMENT_NEIGHBOURS = 12
SEGMENT_FLAT_DEG = 20.0


def segment(points: np.ndarray, origin: np.ndarray | None, voxel: float,
            tree: KDTree | None = None) -> np.ndarray:
    """Segment labels (N,) of voxelized ``points`` (N, 3) cut at concave edges (see
    ``ClickContext.segments``); ``tree``: a tree over them when one exists."""
    P = points
    if len(P) < 3:
        return np.zeros(len(P), np.int64)
    n = pca_normals(P, SEGMENT_NEIGHBOURS, tree)
    towards = (origin - P) if origin is not None else (P - P.mean(axis=0))
    n[np.einsum("ij,ij->i", n, towards) < 0] *= -1      # towards the sensor, or outwards
    pairs = pairs_within(P, SEGMENT_REACH * voxel)
    a, b = pairs[:, 0], pairs[:, 1]
    step = np.take(P, a, axis=0) - np.take(P, b, axis=0)
    na, nb = np.take(n, a, axis=0), np.take(n, b, axis=0)
    flat = np.einsum("ij,ij->i", na, nb) >= math.cos(math.radians(SEGMENT_FLAT_DEG))
    convex = np.einsum("ij,ij->i", na - nb, step) > 0
    return _components(len(P), pairs[flat | convex])


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
