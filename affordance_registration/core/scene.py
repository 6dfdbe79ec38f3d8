"""Scenes: the scanned points, and the per-click preparation the fitting runs on.

A :class:`Scene` holds the finite points of one cloud (metres) in the sensor's frame (or with a
given sensor origin). No KD-tree is ever built over the whole scene: a click is snapped to the
surface by a vectorised nearest-point search, then :meth:`Scene.prepare_click` crops around it,
voxelizes, finds the dominant plane (RANSAC), keeps the cluster connected to the click and builds
a small range image for visibility tests (:class:`ClickContext`).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .errors import SceneError
from .neighbours import KDTree, build_tree, nearest, pairs_within, pca_normals
from .transforms import finite_vector

__all__ = ["Scene", "ClickContext", "Plane", "RangeImage", "voxel_downsample", "load_points"]


def load_points(path: str) -> tuple[np.ndarray, tuple | None]:
    """Read a scene file: PLY or PCD (Open3D), or an organized ``.npy`` array (H, W, 3).

    Returns (points (N, 3) float64 possibly with NaN rows, organized shape or None); see
    :func:`~affordance_registration.core.pointfiles.read_points` for the checks."""
    from .pointfiles import read_points
    f = read_points(path)
    return f.points, f.organized


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel of edge ``voxel`` (m). (N, 3) -> (M, 3)."""
    if len(points) == 0:
        return points.reshape(0, 3)
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    uniq, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.stack([np.bincount(inverse, weights=points[:, k], minlength=len(uniq))
                     for k in range(3)], axis=1)
    return sums / counts[:, None]


@dataclass(frozen=True)
class Plane:
    """Plane n . x + d = 0 with unit normal ``n`` facing the sensor."""

    normal: np.ndarray
    d: float
    inlier_fraction: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.d


class RangeImage:
    """Nearest observed depth per angular bin, as seen from the sensor origin.

    Bins are square in tangent space (x/z, y/z) with edge ``bin_size``; a lookup gives the observed
    depth along the ray through a point, or NaN where the sensor saw nothing in that bin.
    """

    def __init__(self, points: np.ndarray, origin: np.ndarray, bin_size: float):
        rel = points - origin
        z = rel[:, 2]
        keep = z > 1e-3
        rel, z = rel[keep], z[keep]
        self.origin = origin
        self.bin = float(bin_size)
        u, v = rel[:, 0] / z, rel[:, 1] / z
        self.u0, self.v0 = u.min() - self.bin, v.min() - self.bin
        iu = ((u - self.u0) / self.bin).astype(np.int64)
        iv = ((v - self.v0) / self.bin).astype(np.int64)
        self.nu, self.nv = int(iu.max()) + 2, int(iv.max()) + 2
        depth = np.full(self.nu * self.nv, np.inf)
        np.minimum.at(depth, iu * self.nv + iv, z)
        depth[np.isinf(depth)] = np.nan
        self.depth = depth

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(observed depth, point depth) for points (..., 3); observed is NaN when unknown."""
        rel = points - self.origin
        z = rel[..., 2]
        zs = np.where(z > 1e-3, z, 1e-3)
        iu = np.floor((rel[..., 0] / zs - self.u0) / self.bin).astype(np.int64)
        iv = np.floor((rel[..., 1] / zs - self.v0) / self.bin).astype(np.int64)
        inside = (iu >= 0) & (iu < self.nu) & (iv >= 0) & (iv < self.nv) & (z > 1e-3)
        flat = np.where(inside, iu * self.nv + iv, 0)
        obs = np.where(inside, self.depth[flat], np.nan)
        return obs, z


@dataclass
class ClickContext:
    """Everything the fitting needs around one click (built once, reused for refits).

    ``cluster`` are the voxelized points connected to the click with the dominant plane removed
    (the ICP target); ``crop`` all voxelized points of the crop (the scoring target); ``fine`` the
    full-resolution cluster points (the final refinement target).
    """

    click: np.ndarray
    radius: float
    voxel: float
    sensor_origin: np.ndarray
    crop: np.ndarray = field(repr=False)
    cluster: np.ndarray = field(repr=False)
    fine: np.ndarray = field(repr=False)
    plane: Plane | None
    plane_threshold: float
    range_image: RangeImage = field(repr=False)
    crop_tree: KDTree = field(repr=False)
    cluster_tree: KDTree = field(repr=False)
    fine_tree: KDTree = field(repr=False)
    fine_normals: np.ndarray = field(repr=False)

    def cluster_mean_near(self, point: np.ndarray, radius: float,
                          min_points: int = 1) -> np.ndarray | None:
        """Mean (3,) of the cluster points within ``radius`` (m) of ``point`` (3,), or None when
        fewer than ``min_points`` are."""
        near = np.linalg.norm(self.cluster - point, axis=1) <= radius
        if near.sum() < max(min_points, 1):
            return None
        return self.cluster[near].mean(axis=0)


class Scene:
    """The points of one scan, (N, 3) float64 metres, and the sensor origin in that frame.

    Non-finite rows (NaN holes of organized clouds) are no points: ``points`` holds the finite
    ones and ``dropped`` counts the others. Both are worked out on first use, not when the scene
    is made: a click crops the cloud first (:meth:`around`) and drops the holes inside the crop
    only, so a cloud that is replaced before anyone reads all of it never costs a pass over it.
    A scene with no finite point is an error.
    """

    #: rows looked at per step while checking that a cloud has a finite point at all
    _PROBE_ROWS = 65536

    def __init__(self, points, sensor_origin=None, frame_id: str = ""):
        try:
            pts = np.asarray(points, dtype=float)
        except (TypeError, ValueError):
            raise SceneError("scene points must be numbers") from None
        if pts.ndim == 3 and pts.shape[-1] == 3:
            pts = pts.reshape(-1, 3)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise SceneError(f"scene points must have shape (N, 3), got {pts.shape}")
        self._raw = pts
        self._points: np.ndarray | None = None
        if not any(np.isfinite(pts[i:i + self._PROBE_ROWS]).all(axis=1).any()
                   for i in range(0, len(pts), self._PROBE_ROWS)):
            raise SceneError("the scene has no finite points" +
                             (f" ({len(pts)} NaN/inf points dropped)" if len(pts) else ""))
        origin = np.zeros(3) if sensor_origin is None else np.asarray(sensor_origin, dtype=float)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise SceneError(f"sensor origin must be 3 finite numbers, got {sensor_origin!r}")
        self.sensor_origin = origin
        self.frame_id = frame_id

    @property
    def points(self) -> np.ndarray:
        """The finite points (N, 3) float64, m (one pass over the cloud, on first use)."""
        if self._points is None:
            self._points = np.ascontiguousarray(self._raw[np.isfinite(self._raw).all(axis=1)])
        return self._points

    @property
    def dropped(self) -> int:
        """How many rows of the cloud were not finite (holes)."""
        return len(self._raw) - len(self.points)

    @classmethod
    def from_file(cls, path: str, sensor_origin=None) -> "Scene":
        pts, _ = load_points(path)
        return cls(pts, sensor_origin=sensor_origin)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def size(self) -> int:
        """Rows of the cloud, holes included."""
        return len(self._raw)

    def around(self, point, radius: float) -> "Scene":
        """The part of the scene within ``radius`` (m) of ``point`` (3,): a scene of the finite
        points there, in the same frame with the same sensor origin, or None when there are none.
        One pass over the cloud (a slab along x, then the ball), holes never copied."""
        c = _point3(point, "click")
        pts = self._raw if self._points is None else self._points
        x = pts[:, 0]
        idx = np.flatnonzero((x >= c[0] - radius) & (x <= c[0] + radius))  # NaN: outside
        d = pts[idx] - c
        near = pts[idx[np.einsum("ij,ij->i", d, d) <= radius * radius]]
        if len(near) == 0:
            return None
        part = Scene.__new__(Scene)
        part._raw = part._points = np.ascontiguousarray(near)
        part.sensor_origin, part.frame_id = self.sensor_origin, self.frame_id
        return part

    def snap(self, click, max_distance: float = 0.03) -> np.ndarray:
        """The scene point nearest ``click`` (3,). Farther than ``max_distance`` is an error."""
        c = _point3(click, "click")
        d2 = np.einsum("ij,ij->i", self.points - c, self.points - c)
        i = int(np.argmin(d2))
        dist = math.sqrt(d2[i])
        if dist > max_distance:
            raise SceneError(f"the click ({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) is {dist * 100:.1f} cm "
                             f"from the nearest scanned point (limit {max_distance * 100:.1f} cm): "
                             f"click on the object's surface")
        return self.points[i].copy()

    def prepare_click(self, click, radius: float, voxel: float = 0.005,
                      plane_threshold: float = 0.006, min_plane_fraction: float = 0.15,
                      cluster_gap: float | None = None, seed: int = 0) -> ClickContext:
        """Crop ``radius`` around the (already snapped) click and prepare the fitting targets."""
        c = _point3(click, "click")
        d2 = np.einsum("ij,ij->i", self.points - c, self.points - c)
        raw = self.points[d2 <= radius * radius]
        if len(raw) < 10:
            raise SceneError(f"only {len(raw)} scanned points within {radius:.2f} m of the click")
        crop = voxel_downsample(raw, voxel)
        plane = _ransac_plane(crop, plane_threshold, min_plane_fraction, self.sensor_origin, seed)
        gap = cluster_gap if cluster_gap is not None else 0.025
        keep = np.ones(len(crop), bool) if plane is None else plane.distance(crop) > plane_threshold
        cluster = _connected_to(crop, keep, c, gap, reach=max(0.3 * radius, 3 * voxel))
        if len(cluster) < 10:       # nothing off the plane near the click: fit to the whole crop
            cluster = crop
            plane_for_fine = None
        else:
            plane_for_fine = plane
        # full-resolution points of the cluster's voxels (final refinement target)
        cluster_tree = build_tree(cluster)
        near, _ = nearest(cluster_tree, raw, voxel)
        fine = raw[np.isfinite(near)]
        if plane_for_fine is not None:
            fine = fine[plane_for_fine.distance(fine) > plane_threshold]
        if len(fine) < 10:
            fine = cluster
        depth = max(float(np.linalg.norm(c - self.sensor_origin)), 0.2)
        range_image = RangeImage(raw, self.sensor_origin, bin_size=voxel / depth)
        fine_tree = build_tree(fine)
        ctx = ClickContext(click=c, radius=float(radius), voxel=float(voxel),
                           sensor_origin=self.sensor_origin, crop=crop, cluster=cluster, fine=fine,
                           plane=plane_for_fine, plane_threshold=plane_threshold,
                           range_image=range_image, crop_tree=build_tree(crop),
                           cluster_tree=cluster_tree, fine_tree=fine_tree,
                           fine_normals=pca_normals(fine, 12, fine_tree))
        return ctx


def _point3(value, what: str) -> np.ndarray:
    return finite_vector(value, what, SceneError)


def _ransac_plane(points: np.ndarray, threshold: float, min_fraction: float,
                  origin: np.ndarray, seed: int, hypotheses: int = 96) -> Plane | None:
    """Dominant plane by vectorised RANSAC + least-squares refit; None if it holds fewer than
    ``min_fraction`` of the points."""
    n = len(points)
    if n < 50:
        return None
    rng = np.random.default_rng(seed)
    sub = points if n <= 3000 else points[rng.choice(n, 3000, replace=False)]
    tri = sub[rng.integers(0, len(sub), size=(hypotheses, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norm[ok, None]
    ds = -np.einsum("ij,ij->i", normals, tri[ok, 0])
    counts = (np.abs(sub @ normals.T + ds) < threshold).sum(axis=0)
    best = int(np.argmax(counts))
    normal, d = normals[best], ds[best]
    for _ in range(2):   # least-squares refit on the inliers
        inl = points[np.abs(points @ normal + d) < threshold]
        if len(inl) < 3:
            return None
        centre = inl.mean(axis=0)
        _, _, vt = np.linalg.svd(inl - centre, full_matrices=False)
        normal = vt[2]
        d = -normal @ centre
    frac = float(np.mean(np.abs(points @ normal + d) < threshold))
    if frac < min_fraction:
        return None
    if normal @ (origin - centre) < 0:
        normal, d = -normal, -d
    return Plane(normal=normal, d=float(d), inlier_fraction=frac)


def _connected_to(points: np.ndarray, keep: np.ndarray, click: np.ndarray, gap: float,
                  reach: float) -> np.ndarray:
    """The kept points connected (steps <= ``gap``) to any kept point within ``reach`` of the
    click. (Occlusion splits one object into parts at different depths; reaching out from the
    click gathers them.)"""
    pts = points[keep]
    if len(pts) == 0:
        return pts
    seeds = np.linalg.norm(pts - click, axis=1) <= reach
    if not seeds.any():
        return pts[:0]
    pairs = pairs_within(pts, gap)
    graph = coo_matrix((np.ones(len(pairs), bool), (pairs[:, 0], pairs[:, 1])),
                       shape=(len(pts), len(pts)))
    _, labels = connected_components(graph, directed=False)
    wanted = np.unique(labels[seeds])
    return pts[np.isin(labels, wanted)]
