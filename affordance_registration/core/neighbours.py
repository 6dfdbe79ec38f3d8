# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Nearest-neighbour search: the one place that builds and queries KD-trees, and the surface
normals estimated from neighbourhoods.

Every stage that pairs points -- the crop's segmentation, ICP correspondences, the residual's
distances, a template's dense surface -- calls :func:`nearest` (or :func:`k_nearest` /
:func:`pairs_within`), so the tree is a change to this module alone.

The tree is pykdtree's (about half the time per query of scipy's ``cKDTree`` on the fitter's
queries, with the same neighbours and distances). pykdtree parallelises a query with OpenMP
over every core by default; on a loaded machine that made it many times *slower*, and the
fitter runs its own threads (:mod:`.registration.parallel`). So every query runs on one OpenMP
thread: the calling thread's OpenMP thread count is set to one for the query and put back
after it (through ``threadpoolctl``), leaving ``OMP_NUM_THREADS`` and every other library's
threads as the user set them. Setting and reading the count costs as much as a small query
itself, and a click makes hundreds: inside :func:`one_openmp_thread` (a fit holds it on each of
its threads) the count is set once for the block instead. The pairs within a radius (the
crop's segmentation) come from the compiled grid where the kernels are in use, else from
scipy's ``query_pairs``.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.spatial import cKDTree
from threadpoolctl import ThreadpoolController

from .compiled import DistanceGrid, NearestTree, grid_cell, kernels
from .compiled import pairs_within as compiled_pairs_within
from .memo import per_object

__all__ = [
    "KDTree",
    "build_tree",
    "tree_points",
    "nearest",
    "nearest_distances",
    "nearest_in",
    "compiled_tree_of",
    "k_nearest",
    "pairs_within",
    "pca_normals",
    "least_spread",
    "openmp_threads",
    "one_openmp_thread",
]

#: the OpenMP runtimes loaded with pykdtree (its wheel brings a private libgomp)
_OPENMP = tuple(ThreadpoolController().select(user_api="openmp").lib_controllers)


def openmp_threads() -> tuple:
    """The OpenMP thread count the calling thread would use in each OpenMP runtime loaded
    (pykdtree's among them) -- outside a query, as the user set it."""
    return tuple(lib.num_threads for lib in _OPENMP)


#: per thread: how deep in :func:`one_openmp_thread` blocks it is, and the counts before them
_pinned = threading.local()


@contextmanager
def one_openmp_thread():
    """The calling thread's OpenMP thread count at one while the block runs (nested blocks:
    the outermost sets it and puts back what it was), so that the queries in it need not set
    it each."""
    depth = getattr(_pinned, "depth", 0)
    if depth == 0:
        _pinned.before = [lib.num_threads for lib in _OPENMP]
        for lib, n in zip(_OPENMP, _pinned.before):
            if n != 1:
                lib.set_num_threads(1)
    _pinned.depth = depth + 1
    try:
        yield
    finally:
        _pinned.depth -= 1
        if _pinned.depth == 0:
            for lib, n in zip(_OPENMP, _pinned.before):
                if n != 1:
                    lib.set_num_threads(n)


def _query(tree: KDTree, points: np.ndarray, **kwargs):
    """``tree.query`` on one OpenMP thread (the calling thread's count restored after)."""
    if getattr(_pinned, "depth", 0):
        return tree.query(points, **kwargs)
    before = [lib.num_threads for lib in _OPENMP]
    for lib, n in zip(_OPENMP, before):
        if n != 1:
            lib.set_num_threads(1)
    try:
        return tree.query(points, **kwargs)
    finally:
        for lib, n in zip(_OPENMP, before):
            if n != 1:
                lib.set_num_threads(n)


def build_tree(points: np.ndarray) -> KDTree:
    """A KD-tree over ``points`` (N, 3) float64, metres."""
    return KDTree(np.ascontiguousarray(points, dtype=float))


def tree_points(tree: KDTree) -> np.ndarray:
    """The points (N, 3) a tree was built over, in their original order."""
    return tree.data.reshape(-1, 3)


def nearest(tree: KDTree, points: np.ndarray, upper: float = np.inf, parallel: bool = False):
    """Distance (N,) from each of ``points`` (N, 3) to its nearest tree point and that point's
    index (N,) int. Beyond ``upper`` the distance is inf and the index a valid but meaningless
    one (mask by ``np.isfinite`` of the distance). ``parallel`` is accepted for callers that
    mark their big queries; the query itself runs on the calling thread."""
    pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        return np.empty(0), np.empty(0, dtype=np.intp)
    d, i = _query(
        tree, pts, k=1, distance_upper_bound=float(upper) if np.isfinite(upper) else None
    )
    return d, np.minimum(i, tree.n - 1).astype(np.intp)


def nearest_distances(tree: KDTree, points: np.ndarray, upper: float, owner=None) -> np.ndarray:
    """The distances of :func:`nearest` (the same numbers, to the last bit), from a compiled
    grid over the tree's points (:class:`.compiled.DistanceGrid`) where one pays
    (:func:`.compiled.grid_cell`: a finite bound and light cells), kept with ``owner`` -- the
    object holding ``tree`` (a template's surface, a click's context) -- and built when first
    asked; else from the tree."""
    if owner is not None:
        pts = tree_points(tree)
        extent = per_object(
            owner,
            ("extent", id(tree)),
            lambda: float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0,
        )
        cell = grid_cell(pts, upper, extent)
        if cell is not None:
            grid = per_object(owner, ("grid", id(tree), cell), lambda: DistanceGrid(pts, cell))
            return grid.distances(points, upper)
        return nearest_in(owner, tree, points, upper)[0]
    return nearest(tree, points, upper)[0]


def nearest_in(owner, tree: KDTree, points: np.ndarray, upper: float = np.inf):
    """:func:`nearest` (the same numbers) from the compiled KD-tree over ``tree``'s points
    (:class:`.compiled.NearestTree`), kept with ``owner`` (the object holding ``tree``) and
    built when first asked, where the compiled kernels are in use; else from ``tree``."""
    compiled = compiled_tree_of(owner, tree)
    return nearest(tree, points, upper) if compiled is None else compiled.nearest(points, upper)


def compiled_tree_of(owner, tree: KDTree) -> NearestTree | None:
    """The compiled KD-tree over ``tree``'s points, kept with ``owner`` (the object holding
    ``tree``), or None where the compiled kernels are not in use."""
    if kernels() is None:
        return None
    return per_object(owner, ("tree", id(tree)), lambda: NearestTree(tree_points(tree)))


def k_nearest(tree: KDTree, points: np.ndarray, k: int) -> np.ndarray:
    """Indices (N, k) of the ``k`` nearest tree points of each of ``points`` (N, 3), nearest
    first (``k`` at most the tree's size)."""
    pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    _, idx = _query(tree, pts, k=k)
    return idx.reshape(len(pts), k).astype(np.intp)


def pairs_within(points: np.ndarray, radius: float) -> np.ndarray:
    """Index pairs (M, 2), i < j, of ``points`` (N, 3) at most ``radius`` (m) apart: the KD-tree's
    ``query_pairs``, or the same set from the compiled grid (:func:`.compiled.pairs_within`;
    a real click's segmentation asked this 8 ms of it, the grid answers in a fraction) where
    the kernels are in use. The order of the pairs is neither's to rely on."""
    k = kernels()
    if k is not None and 0.0 < radius < np.inf:
        return compiled_pairs_within(points, radius, k)
    return cKDTree(points).query_pairs(radius, output_type="ndarray")


def pca_normals(
    points: np.ndarray,
    k: int,
    tree: KDTree | None = None,
    at: np.ndarray | None = None,
    variation: bool = False,
):
    """Unit normals (N, 3) of a sampled surface: the direction of least spread of each point's
    ``k`` nearest neighbours (at most all points); the sign is arbitrary. ``tree``: a tree over
    ``points`` when one exists already. ``at`` (M, 3): the normals at these places instead,
    from their nearest ``points`` ((M, 3) returned). ``variation``: also each neighbourhood's
    surface variation (N,), its least spread over its total (0 on a plane, 1/3 at most; large
    on an edge or a corner), as (normals, variation)."""
    k = min(k, len(points))
    idx = k_nearest(
        tree if tree is not None else build_tree(points), points if at is None else at, k
    )
    # the neighbourhoods' means as ``mean(axis=1)`` sums them -- neighbour by neighbour, in
    # order -- but over (k, M, 3) gathered neighbours-first, where each step is one contiguous
    # add; ``np.take`` gathers rows several times faster than fancy indexing
    centre = np.take(points, idx.T, axis=0).sum(axis=0) / k
    nb = np.take(points, idx, axis=0)
    for j in range(3):  # less the means, column by column (broadcasting over a last axis
        nb[:, :, j] -= centre[:, j, None]  # of three is several times slower)
    return least_spread(np.swapaxes(nb, 1, 2) @ nb, variation)


#: :func:`least_spread` leaves to LAPACK the matrices whose two smallest eigenvalues are
#: closer than this fraction of the largest (a line-like neighbourhood: no clear normal)
CLOSE_EIGENVALUES = 1e-3


def least_spread(C: np.ndarray, variation: bool = False):
    """Unit eigenvectors (M, 3) of the smallest eigenvalue of symmetric positive semidefinite
    matrices C (M, 3, 3) (the sign is arbitrary), in closed form: the eigenvalues from the
    characteristic cubic (trigonometric solution), the vector as the largest cross product of
    two rows of C - lambda_min I. Six times faster than ``np.linalg.eigh`` on the fitter's
    neighbourhoods, within 1e-11 rad of it; where the two smallest eigenvalues are close (the
    cross products lose their digits) ``eigh`` answers. ``variation``: also the smallest
    eigenvalue over the trace (M,), as (vectors, variation)."""
    a, b, c = C[:, 0, 0], C[:, 1, 1], C[:, 2, 2]
    d, e, f = C[:, 0, 1], C[:, 0, 2], C[:, 1, 2]
    q = (a + b + c) / 3
    aq, bq, cq = a - q, b - q, c - q
    p = np.sqrt((aq * aq + bq * bq + cq * cq + 2 * (d * d + e * e + f * f)) / 6)
    ps = np.where(p > 0, p, 1.0)
    det = aq * (bq * cq - f * f) - d * (d * cq - f * e) + e * (d * f - bq * e)
    phi = np.arccos(np.clip(det / (2 * ps * ps * ps), -1.0, 1.0)) / 3
    lo = q + 2 * p * np.cos(phi + 2 * np.pi / 3)
    hi = q + 2 * p * np.cos(phi)
    A, B, Z = a - lo, b - lo, c - lo  # the diagonal of C - lo I
    crosses = (
        (d * f - e * B, e * d - A * f, A * B - d * d),  # rows 0 x 1,
        (d * Z - e * f, e * e - A * Z, A * f - d * e),  # 0 x 2,
        (B * Z - f * f, f * e - d * Z, d * f - B * e),
    )  # 1 x 2
    v, n2 = crosses[0], sum(x * x for x in crosses[0])
    for cand in crosses[1:]:
        m2 = sum(x * x for x in cand)
        larger = m2 > n2
        v, n2 = [np.where(larger, x, y) for x, y in zip(cand, v)], np.where(larger, m2, n2)
    norm = np.sqrt(n2)
    ok = (3 * q - hi - 2 * lo > CLOSE_EIGENVALUES * hi) & (norm > 0)  # (mid - lo)
    inv = 1.0 / np.where(ok, norm, 1.0)
    out = np.empty((len(C), 3))
    for k in range(3):
        out[:, k] = v[k] * inv
    if not ok.all():
        bad = np.flatnonzero(~ok)
        out[bad] = np.linalg.eigh(C[bad])[1][:, :, 0]
    if variation:
        return out, np.clip(lo, 0.0, None) / np.where(q > 0, 3 * q, 1.0)
    return out
