"""Nearest-neighbour search: the one place that builds and queries KD-trees (scipy's cKDTree
today), and the surface normals estimated from neighbourhoods.

Every stage that pairs points -- the crop's segmentation, ICP correspondences, the residual's
distances, a template's dense surface -- calls :func:`nearest` (or :func:`k_nearest` /
:func:`pairs_within`), so a faster tree is a change to this module alone.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["KDTree", "build_tree", "tree_points", "nearest", "k_nearest", "pairs_within",
           "pca_normals"]

KDTree = cKDTree
#: a ``parallel`` query of at least this many points uses every core (thread start-up costs
#: more than it saves below a few thousand points)
PARALLEL_QUERIES = 8000


def build_tree(points: np.ndarray) -> KDTree:
    """A KD-tree over ``points`` (N, 3) float64, metres."""
    return cKDTree(points)


def tree_points(tree: KDTree) -> np.ndarray:
    """The points (N, 3) a tree was built over, in their original order."""
    return tree.data


def nearest(tree: KDTree, points: np.ndarray, upper: float = np.inf, parallel: bool = False):
    """Distance (N,) from each of ``points`` (N, 3) to its nearest tree point and that point's
    index (N,) int. Beyond ``upper`` the distance is inf and the index a valid but meaningless
    one (mask by ``np.isfinite`` of the distance). ``parallel``: a big query (at least
    ``PARALLEL_QUERIES`` points) uses every core."""
    n = len(points)
    d, i = tree.query(points, k=1, distance_upper_bound=upper,
                      workers=-1 if parallel and n >= PARALLEL_QUERIES else 1)
    return d, np.minimum(i, tree.n - 1)


def k_nearest(tree: KDTree, points: np.ndarray, k: int) -> np.ndarray:
    """Indices (N, k) of the ``k`` nearest tree points of each of ``points`` (N, 3), nearest
    first (``k`` at most the tree's size)."""
    _, idx = tree.query(points, k=k)
    return idx.reshape(len(points), k)


def pairs_within(tree: KDTree, radius: float) -> np.ndarray:
    """Index pairs (M, 2) of the tree's points closer than ``radius`` (m) to each other."""
    return tree.query_pairs(radius, output_type="ndarray")


def pca_normals(points: np.ndarray, k: int, tree: KDTree | None = None) -> np.ndarray:
    """Unit normals (N, 3) of a sampled surface: the direction of least spread of each point's
    ``k`` nearest neighbours (at most all points); the sign is arbitrary. ``tree``: a tree over
    ``points`` when one exists already."""
    k = min(k, len(points))
    idx = k_nearest(tree if tree is not None else build_tree(points), points, k)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return np.ascontiguousarray(vecs[:, :, 0])
