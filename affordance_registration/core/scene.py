"""Scenes: the scanned points, and the per-click preparation the fitting runs on.

A :class:`Scene` holds the finite points of one cloud (metres) in any frame -- a camera optical
frame, ``base_link``, ``map`` -- and where the sensor was in that frame (``sensor_origin``), or
:data:`NO_VIEWPOINT` for a cloud with no single viewpoint (an accumulated map). No KD-tree is
ever built over the whole scene: a click is snapped to the surface by a vectorised
nearest-point search, then :meth:`Scene.prepare_click` crops around it, voxelizes, finds the
dominant plane (RANSAC; kept only where the surface it cuts is flat, not a slab through a curved
object), keeps the cluster connected to the click -- off the plane, less the plane's own points
that the scan's noise lifted past its threshold -- and builds a small range image for visibility
tests (:class:`ClickContext`).

Nothing here assumes an axis: the voxel grid, the range image's bins and every random draw of
the fit are laid out in a frame attached to the scan around the click (``ClickContext.frame``:
its z towards the sensor, its x along the main axis of the points), so fitting a rigidly moved
scene (its points, click and sensor origin) gives the rigidly moved answer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from .errors import SceneError
from .neighbours import KDTree, build_tree, k_nearest, nearest, pairs_within, pca_normals
from .transforms import align_z_to, finite_vector

__all__ = ["Scene", "ClickContext", "Plane", "RangeImage", "voxel_downsample", "load_points",
           "local_frame", "segment", "NO_VIEWPOINT"]

#: a click within this many plane thresholds of the dominant plane is on it: the plane is then
#: the clicked object's surface (or a bare wall), not a surface it is mounted on
ON_PLANE = 1.5
#: a support plane is flat: at least this fraction of its inliers have a surface normal (PCA of
#: FLAT_NEIGHBOURS crop points, a patch of about 3 voxels' radius) within FLAT_DEG of the
#: plane's. A slab cut through a curved object (the back of a statue holds 40% of its crop
#: within the plane threshold) has a third of its inliers so; a wall or table under depth-camera
#: faults over nine tenths.
FLAT_FRACTION = 0.7
FLAT_DEG = 25.0
FLAT_NEIGHBOURS = 30
FLAT_SAMPLES = 300       #: points near the plane whose normals are looked at (evenly spread)
#: the support's own points -- flat, their normals along the plane's -- are looked for this many
#: plane thresholds from it; their spread sigma (a depth camera's noise) widens the band taken
#: off the support for the cluster to SUPPORT_SIGMAS sigma, between one and SUPPORT_REACH
#: thresholds (a clean scan: the threshold)
SUPPORT_REACH = 3.0
SUPPORT_SIGMAS = 3.0
#: the scan's noise around a click (``ClickContext.noise``): the spread off their plane of
#: this many nearest full-resolution neighbours, at up to NOISE_SAMPLES places
NOISE_NEIGHBOURS = 16
NOISE_SAMPLES = 300
#: the cluster's segments (``ClickContext.segments``): voxels this many voxel edges apart are
#: neighbours, their normals from SEGMENT_NEIGHBOURS points; a pair stays joined where the
#: normals are within SEGMENT_FLAT_DEG (one surface, with a real sensor's noise) or meet
#: convexly
SEGMENT_REACH = 1.8
SEGMENT_NEIGHBOURS = 12
SEGMENT_FLAT_DEG = 20.0
#: ``sensor_origin`` of a cloud with no single viewpoint (an accumulated map): fitted without
#: the visibility terms
NO_VIEWPOINT = "none"
#: m: a scan larger than this across may not be in metres (a click error says so); a scan in
#: millimetres of a 3 cm object already reads as 30 m, while a room or a workcell is < 25 m
MM_LOOKING_EXTENT = 25.0
#: metres per unit of a scan file (``fit --units``, ``station --scene FILE --units``)
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def load_points(path: str) -> tuple[np.ndarray, tuple | None]:
    """Read a scene file: PLY or PCD (Open3D), or an organized ``.npy`` array (H, W, 3).

    Returns (points (N, 3) float64 possibly with NaN rows, organized shape or None); see
    :func:`~affordance_registration.core.pointfiles.read_points` for the checks."""
    from .pointfiles import read_points
    f = read_points(path)
    return f.points, f.organized


def voxel_downsample(points: np.ndarray, voxel: float, origin=None, frame=None) -> np.ndarray:
    """Centroid of the points in each occupied voxel of edge ``voxel`` (m). (N, 3) -> (M, 3).
    The grid is aligned with the scene's axes at its origin, or with the columns of ``frame``
    (3, 3) and centred on ``origin`` (3,) -- a grid attached to the data turns with it -- and the
    voxels come in the order of their grid coordinates."""
    if len(points) == 0:
        return points.reshape(0, 3)
    # a grid attached to the data has ``origin`` at a voxel's centre (a surface through the
    # origin, the click, would otherwise be split between two layers of voxels)
    grid = points if frame is None else _minus(points, origin) @ frame + 0.5 * voxel
    keys = np.floor(grid / voxel).astype(np.int64)
    cols = [keys[:, k] - keys[:, k].min() for k in range(3)]     # column by column: no
    dims = [int(col.max()) + 1 for col in cols]                   # (N, 3) reductions
    flat = (cols[0] * dims[1] + cols[1]) * dims[2] + cols[2]
    inverse, counts = _group(flat, dims[0] * dims[1] * dims[2])
    sums = np.stack([np.bincount(inverse, weights=points[:, k], minlength=len(counts))
                     for k in range(3)], axis=1)
    return sums / counts[:, None]


#: a voxel grid of at most this many cells per point is grouped through a table of its cells
#: (no sort); a sparser one by sorting the cells' keys
DENSE_CELLS_PER_POINT = 64


def _group(keys: np.ndarray, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Group integer ``keys`` (N,) in [0, ``cells``): the rank of each key among the distinct
    keys, ascending (N,) int, and how many times each distinct key occurs (M,) -- what
    ``np.unique(keys, return_inverse=True, return_counts=True)`` gives, without its sort when
    the keys are dense enough for a table of every cell."""
    if cells > DENSE_CELLS_PER_POINT * len(keys):
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        return inverse, counts
    occupied = np.zeros(cells, bool)
    occupied[keys] = True
    uniq = np.flatnonzero(occupied)
    rank = np.empty(cells, np.intp)
    rank[uniq] = np.arange(len(uniq))
    inverse = rank[keys]
    return inverse, np.bincount(inverse, minlength=len(uniq))


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

    The image looks along ``frame``'s third column (the ray from the sensor origin to the
    click), whatever axes the scene's frame has: a point's depth is its distance along that ray
    and its bin is square in tangent space (x/z, y/z in ``frame``) with edge ``bin_size``;
    directions more than 90 degrees off the ray (only where the sensor is inside the crop) have
    no bin. A lookup gives the observed depth along the ray through a point, or NaN where the
    sensor saw nothing in that bin.
    """

    def __init__(self, points: np.ndarray, origin: np.ndarray, bin_size: float,
                 frame: np.ndarray):
        self.origin = np.asarray(origin, dtype=float)
        self.frame = np.asarray(frame, dtype=float)
        self.bin = float(bin_size)
        rel = _minus(points, self.origin) @ self.frame
        z = rel[:, 2]
        keep = z > 1e-3
        if not keep.all():          # (only where the sensor is inside the crop)
            rel, z = rel[keep], z[keep]
        if len(z) == 0:
            raise SceneError("no scanned point near the click lies in front of the sensor origin")
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
        return self.lookup_offsets(points - self.origin)

    def lookup_offsets(self, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`lookup` of points given as their offsets (..., 3) from the sensor origin."""
        rel = offsets @ self.frame
        z = rel[..., 2]
        zs = np.maximum(z, 1e-3)
        iu = np.floor((rel[..., 0] / zs - self.u0) / self.bin).astype(np.int64)
        iv = np.floor((rel[..., 1] / zs - self.v0) / self.bin).astype(np.int64)
        # a negative bin wraps to a huge unsigned one: one comparison per axis
        inside = (iu.view(np.uint64) < self.nu) & (iv.view(np.uint64) < self.nv) & (z > 1e-3)
        flat = np.where(inside, iu * self.nv + iv, self.nu * self.nv)     # outside: the NaN
        return self._depth_or_nan[flat], z

    @cached_property
    def _depth_or_nan(self) -> np.ndarray:
        """``depth`` followed by one NaN (what a lookup outside the image reads)."""
        return np.append(self.depth, np.nan)


def local_frame(points: np.ndarray, click: np.ndarray, origin: np.ndarray | None) -> np.ndarray:
    """A rotation (3, 3) attached to the scan around a click, whatever frame it is given in:
    third column towards the sensor ``origin`` (without one: the direction in which
    ``points`` (N, 3) spread least), first column their main axis across it; the signs of the
    axes from the points' third moments along them. Rigidly moving the points, the click and the
    origin turns this frame with them."""
    rel = _minus(points, _mean_rows(points))
    cov = rel.T @ rel

    def signed(axis):       # the side the points' distribution leans to
        return axis if _leans_forward(rel @ axis) else -axis

    if origin is not None and np.linalg.norm(origin - click) > 1e-9:
        z = (origin - click) / np.linalg.norm(origin - click)
    else:
        z = signed(np.linalg.eigh(cov)[1][:, 0])
    across = np.eye(3) - np.outer(z, z)
    x = signed(np.linalg.eigh(across @ cov @ across)[1][:, 2])
    x = x - z * (x @ z)
    if np.linalg.norm(x) < 1e-9:        # no spread across z at all: any perpendicular
        x = align_z_to(z)[:, 0]
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _leans_forward(along: np.ndarray) -> bool:
    """Whether the sum of the cubes of ``along`` (N,) is at least zero, as
    ``np.sum(along ** 3) >= 0`` decides it. The cubes are products (``** 3`` is a pow() per
    value, ten times slower); they differ from pow()'s by a few ulp and their sum by far less
    than 1e-9 of the sum of their sizes, so a sum closer to zero than that is decided by
    pow()'s cubes."""
    cubes = along * along * along
    lean = cubes.sum()
    if abs(lean) <= 1e-9 * np.abs(cubes).sum():
        lean = np.sum(along ** 3)
    return bool(lean >= 0)


@dataclass
class ClickContext:
    """Everything the fitting needs around one click (built once, reused for refits).

    ``cluster`` are the voxelized points connected to the click with the dominant plane removed
    (the ICP target); ``crop`` all voxelized points of the crop (the scoring target); ``fine`` the
    full-resolution cluster points (the final refinement target). ``frame`` (3, 3) is the
    rotation attached to the scan around the click (:func:`local_frame`): random draws and
    grids are laid out in it. Without a viewpoint ``sensor_origin`` and ``range_image`` are
    None (no visibility terms).
    """

    click: np.ndarray
    radius: float
    voxel: float
    sensor_origin: np.ndarray | None
    crop: np.ndarray = field(repr=False)
    cluster: np.ndarray = field(repr=False)
    fine: np.ndarray = field(repr=False)
    plane: Plane | None
    plane_threshold: float
    range_image: RangeImage | None = field(repr=False)
    crop_tree: KDTree = field(repr=False)
    cluster_tree: KDTree = field(repr=False)
    fine_tree: KDTree = field(repr=False)
    fine_normals: np.ndarray = field(repr=False)
    #: the dominant plane of the crop even where nothing stands off it (``plane`` is then None)
    support: Plane | None = None
    frame: np.ndarray = field(repr=False, default_factory=lambda: np.eye(3))

    @property
    def has_viewpoint(self) -> bool:
        return self.sensor_origin is not None

    def cluster_mean_near(self, point: np.ndarray, radius: float,
                          min_points: int = 1) -> np.ndarray | None:
        """Mean (3,) of the cluster points within ``radius`` (m) of ``point`` (3,), or None when
        fewer than ``min_points`` are."""
        point = np.asarray(point, dtype=float)
        if np.array_equal(point, self.click):       # (asked once per template: the same
            dist = self._cluster_to_click              # distances each time)
        else:
            dist = np.linalg.norm(self.cluster - point, axis=1)
        near = dist <= radius
        if near.sum() < max(min_points, 1):
            return None
        return self.cluster[near].mean(axis=0)

    @cached_property
    def _cluster_to_click(self) -> np.ndarray:
        """Distances (N,) of the cluster points to the click."""
        return np.linalg.norm(self.cluster - self.click, axis=1)

    @cached_property
    def noise(self) -> float:
        """The scan's measured noise around the click (m): the median, over up to
        NOISE_SAMPLES full-resolution cluster points spread evenly, of the spread of each
        one's NOISE_NEIGHBOURS nearest neighbours off their own plane (the square root of the
        smallest eigenvalue of their covariance). A simulated Kinect at 1 m reads about
        1.3 mm, with the fault model about 2 mm."""
        P = self.fine
        if len(P) < NOISE_NEIGHBOURS:
            return 0.0
        idx = np.linspace(0, len(P) - 1, min(NOISE_SAMPLES, len(P))).astype(np.int64)
        nb = np.take(P, k_nearest(self.fine_tree, np.take(P, idx, axis=0), NOISE_NEIGHBOURS),
                     axis=0)
        nb = nb - nb.mean(axis=1, keepdims=True)
        lam = np.linalg.eigvalsh(np.swapaxes(nb, 1, 2) @ nb / NOISE_NEIGHBOURS)[:, 0]
        return float(np.median(np.sqrt(np.maximum(lam, 0.0))))

    @cached_property
    def segments(self) -> np.ndarray:
        """A segment label (N,) for each cluster point: the cluster cut where two touching
        surfaces meet in a concave edge (the contact of two objects, of an object and what it
        stands on) -- neighbours SEGMENT_REACH voxels apart stay joined where their normals
        are within SEGMENT_FLAT_DEG of each other or meet convexly (a box's edges). A convex
        object is one segment; the verdict asks which segments a candidate explains."""
        return segment(self.cluster, self.sensor_origin, self.voxel, self.cluster_tree)


class Scene:
    """The points of one scan, (N, 3) float64 metres, and the sensor origin in that frame.

    ``sensor_origin``: where the scan was taken from, (3,) in the points' frame; None: the
    frame's origin (a cloud in its sensor's frame); :data:`NO_VIEWPOINT` (``"none"``): no single
    viewpoint -- fitted without the visibility terms, normals estimated from the data.
    Non-finite rows (NaN holes of organized clouds) are no points: ``points`` holds the finite
    ones and ``dropped`` counts the others. Both are worked out on first use, not when the scene
    is made: a click crops the cloud first (:meth:`around`) and drops the holes inside the crop
    only, so a cloud that is replaced before anyone reads all of it never costs a pass over it.
    A scene with no finite point is an error.
    """

    #: rows looked at per step while checking that a cloud has a finite point at all (after
    #: the _FIRST_PROBE rows in the middle of the cloud, which nearly always hold one)
    _PROBE_ROWS = 65536
    _FIRST_PROBE = 1024

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
        self._squared_to: tuple | None = None
        self._whole: "Scene | None" = None       # the scene a part was cut from (units hint)
        mid = len(pts) // 2
        if not (np.isfinite(pts[mid:mid + self._FIRST_PROBE]).all(axis=1).any() or
                any(np.isfinite(pts[i:i + self._PROBE_ROWS]).all(axis=1).any()
                    for i in _middle_first(len(pts), self._PROBE_ROWS))):
            raise SceneError("the scene has no finite points" +
                             (f" ({len(pts)} NaN/inf points dropped)" if len(pts) else ""))
        self.sensor_origin = _origin(sensor_origin)
        self.frame_id = frame_id

    @property
    def points(self) -> np.ndarray:
        """The finite points (N, 3) float64, m (one pass over the cloud, on first use)."""
        if self._points is None:
            self._points = np.compress(np.isfinite(self._raw).all(axis=1), self._raw, axis=0)
        return self._points

    @property
    def dropped(self) -> int:
        """How many rows of the cloud were not finite (holes)."""
        return len(self._raw) - len(self.points)

    @classmethod
    def from_file(cls, path: str, sensor_origin=None, scale: float = 1.0) -> "Scene":
        """The scene in a PLY, PCD or .npy file. ``sensor_origin`` as for :class:`Scene` (in
        metres); None: a PCD's ``VIEWPOINT`` where it has one, else the frame's origin.
        ``scale``: metres per unit of the file (``UNITS``: 0.001 for a scan in millimetres);
        the points and the file's viewpoint are scaled by it."""
        from .pointfiles import read_points
        f = read_points(path)
        if sensor_origin is None and f.viewpoint is not None:
            sensor_origin = np.asarray(f.viewpoint, dtype=float) * scale
        return cls(f.points * scale if scale != 1.0 else f.points, sensor_origin=sensor_origin)

    @property
    def has_viewpoint(self) -> bool:
        return self.sensor_origin is not None

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
        d = _minus(np.take(pts, idx, axis=0), c)
        d2 = np.einsum("ij,ij->i", d, d)
        inside = d2 <= radius * radius
        near = np.take(pts, np.compress(inside, idx), axis=0)
        if len(near) == 0:
            return None
        part = Scene.__new__(Scene)
        part._raw = part._points = near
        # the squared distances of its points to ``point``, for a snap to it (the same numbers
        # a pass over the part would give: each is its own row's sum)
        part._squared_to = (c, np.compress(inside, d2))
        part.sensor_origin, part.frame_id = self.sensor_origin, self.frame_id
        part._whole = self._whole or self
        return part

    def units_hint(self) -> str:
        """'' -- or, for a scan (the whole one a part was cut from) more than
        ``MM_LOOKING_EXTENT`` across, a sentence saying that it may not be in metres: a
        scan in millimetres of a 30 cm object reads as 300 m across. Computed when an error
        needs it (a pass over the cloud)."""
        whole = self._whole or self
        pts = whole._raw if whole._points is None else whole._points
        finite = pts[np.all(np.isfinite(pts), axis=1)] if len(pts) else pts
        if len(finite) == 0:
            return ""
        extent = float(np.max(finite.max(axis=0) - finite.min(axis=0)))
        if extent <= MM_LOOKING_EXTENT:
            return ""
        return (f"; the scan is {extent:.0f} units across, which as metres is larger than a "
                f"room: if it is in millimetres or centimetres, give its units (--units mm or "
                f"cm) so that it is scaled to metres")

    def snap(self, click, max_distance: float = 0.03) -> np.ndarray:
        """The scene point nearest ``click`` (3,). Farther than ``max_distance`` is an error."""
        c = _point3(click, "click")
        if self._squared_to is not None and np.array_equal(self._squared_to[0], c):
            d2 = self._squared_to[1]        # a part cut around this very point
        else:
            rel = _minus(self.points, c)
            d2 = np.einsum("ij,ij->i", rel, rel)
        i = int(np.argmin(d2))
        dist = math.sqrt(d2[i])
        if dist > max_distance:
            raise SceneError(f"the click ({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) is {dist * 100:.1f} cm "
                             f"from the nearest scanned point (limit {max_distance * 100:.1f} cm): "
                             f"click on the object's surface{self.units_hint()}")
        return self.points[i].copy()

    def prepare_click(self, click, radius: float, voxel: float = 0.005,
                      plane_threshold: float = 0.006, min_plane_fraction: float = 0.15,
                      cluster_gap: float | None = None, seed: int = 0,
                      threads: int = 1, fine_points: int = 0) -> ClickContext:
        """Crop ``radius`` around the (already snapped) click and prepare the fitting targets.
        ``threads``: the fine points' normals (most of the time) in that many parts side by side
        (the same numbers). ``fine_points``: at most this many full-resolution points (an even
        subset of them in the scan's order; 0: all)."""
        c = _point3(click, "click")
        rel = _minus(self.points, c)
        d2 = np.einsum("ij,ij->i", rel, rel)
        raw = np.compress(d2 <= radius * radius, self.points, axis=0)
        if len(raw) < 10:
            raise SceneError(f"only {len(raw)} scanned points within {radius:.2f} m of the click"
                             f"{self.units_hint()}")
        origin = self.sensor_origin
        if origin is not None and np.linalg.norm(origin - c) < 1e-3:
            raise SceneError("the sensor origin is at the click: the scan cannot have been "
                             "taken from there (give where the sensor was, or 'none')")
        frame = local_frame(raw, c, origin)
        crop = voxel_downsample(raw, voxel, c, frame)
        _check_spread(crop, voxel, radius)
        crop_tree = build_tree(crop)
        plane = _ransac_plane(crop, plane_threshold, min_plane_fraction, origin, seed)
        band = plane_threshold          # taken off the support plane for the cluster
        if plane is not None:
            flat, sigma = _flatness(plane, crop, crop_tree, plane_threshold)
            if flat < FLAT_FRACTION:
                plane = None    # a slab through a curved object: no support under it
            else:
                band = min(max(SUPPORT_SIGMAS * sigma, plane_threshold),
                           SUPPORT_REACH * plane_threshold)
        support = plane
        if plane is not None and abs(plane.distance(c)) <= ON_PLANE * plane_threshold:
            plane = None    # the click is on the plane: it is the object's, not a mount's
        gap = cluster_gap if cluster_gap is not None else 0.025
        if plane is None:
            keep = np.ones(len(crop), bool)
        else:       # off the plane, but not the support's own surface lifted by the noise
            off = plane.distance(crop)
            keep = off > plane_threshold
            lifted = np.flatnonzero(keep & (off <= band))
            keep[lifted] = ~_along(plane, np.take(crop, lifted, axis=0), crop, crop_tree)
        cluster = _connected_to(crop, keep, c, gap, reach=max(0.3 * radius, 3 * voxel))
        if len(cluster) < 10:       # nothing off the plane near the click: fit to the whole crop
            cluster = crop
            plane_for_fine = None
        else:
            plane_for_fine = plane
        # full-resolution points of the cluster's voxels (final refinement target)
        # (the points on the plane first left out: most of a crop's, and none of them fine)
        cluster_tree = build_tree(cluster)
        fine = raw if plane_for_fine is None else \
            np.compress(plane_for_fine.distance(raw) > plane_threshold, raw, axis=0)
        fine = _within(fine, cluster, cluster_tree, voxel)
        if len(fine) < 10:
            fine = cluster
        if 0 < fine_points < len(fine):     # a dense sensor's: the fine stage needs no more
            fine = np.take(fine, (np.arange(fine_points) * (len(fine) / fine_points))
                           .astype(np.int64), axis=0)
        range_image = None
        if origin is not None:
            depth = max(float(np.linalg.norm(c - origin)), 0.2)
            # the image's axis runs from the sensor to the click: the frame's z turned round
            range_image = RangeImage(raw, origin, bin_size=voxel / depth,
                                     frame=frame * np.array([1.0, -1.0, -1.0]))
        fine_tree = build_tree(fine)
        ctx = ClickContext(click=c, radius=float(radius), voxel=float(voxel),
                           sensor_origin=origin, crop=crop, cluster=cluster, fine=fine,
                           plane=plane_for_fine, plane_threshold=plane_threshold,
                           range_image=range_image, crop_tree=crop_tree,
                           cluster_tree=cluster_tree, fine_tree=fine_tree,
                           fine_normals=_fine_normals(fine, fine_tree, threads), support=support,
                           frame=frame)
        return ctx


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


def _minus(points: np.ndarray, point: np.ndarray) -> np.ndarray:
    """``points - point`` for points (N, 3) and a point (3,), column by column: the same
    numbers, three times faster than broadcasting over a last axis of length three."""
    out = np.empty(points.shape, np.result_type(points, point))
    for k in range(3):
        np.subtract(points[:, k], point[k], out=out[:, k])
    return out


def _mean_rows(points: np.ndarray) -> np.ndarray:
    """``points.mean(axis=0)`` of points (N, 3), N >= 1: the same numbers -- numpy adds the
    rows one after the other there, as a running sum of each column does -- twice as fast."""
    return np.array([np.add.accumulate(points[:, k])[-1] for k in range(3)]) / len(points)


def _point3(value, what: str) -> np.ndarray:
    return finite_vector(value, what, SceneError)


def _origin(value) -> np.ndarray | None:
    """A sensor origin: (3,) finite, None for :data:`NO_VIEWPOINT`; None given: zeros."""
    if value is None:
        return np.zeros(3)
    if isinstance(value, str):
        if value.strip().lower() == NO_VIEWPOINT:
            return None
        raise SceneError(f"sensor origin must be 3 finite numbers or '{NO_VIEWPOINT}', "
                         f"got {value!r}")
    return finite_vector(value, "sensor origin", SceneError)


def _check_spread(crop: np.ndarray, voxel: float, radius: float) -> None:
    """Refuse a crop that is no surface at all: a handful of distinct places, or points on one
    line (nothing can be fitted to them)."""
    if len(crop) < 10:
        raise SceneError(f"the scan around the click holds only {len(crop)} distinct points "
                         f"(at {voxel * 1000:.0f} mm): nothing to fit")
    rel = _minus(crop, _mean_rows(crop))
    # the singular values from the eigenvalues of the (3, 3) Gram matrix (an SVD of the crop
    # costs ten times more); within rounding of the limit, from the SVD
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(rel.T @ rel)[::-1], 0.0) / len(crop))
    if abs(spread[1] - 0.5 * voxel) <= 1e-6 * spread[0]:
        spread = np.linalg.svd(rel, compute_uv=False) / math.sqrt(len(crop))
    if spread[1] < 0.5 * voxel:
        raise SceneError("the scanned points around the click lie on a line: nothing to fit")


def _ransac_plane(points: np.ndarray, threshold: float, min_fraction: float,
                  origin: np.ndarray | None, seed: int,
                  hypotheses: int = 96) -> Plane | None:
    """Dominant plane by vectorised RANSAC + least-squares refit; None if it holds fewer than
    ``min_fraction`` of the points. Its normal faces the sensor ``origin``; without one, the
    side of the plane holding more of the points off it (the objects on it)."""
    n = len(points)
    if n < 50:
        return None
    rng = np.random.default_rng(seed)
    sub = points if n <= 3000 else np.take(points, rng.choice(n, 3000, replace=False), axis=0)
    tri = np.take(sub, rng.integers(0, len(sub), size=(hypotheses, 3)), axis=0)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norm[ok, None]
    ds = -np.einsum("ij,ij->i", normals, tri[ok, 0])
    off = sub @ normals.T
    off += ds
    counts = np.count_nonzero(np.abs(off, out=off) < threshold, axis=0)
    best = int(np.argmax(counts))
    normal, d = normals[best], ds[best]
    for _ in range(2):   # least-squares refit on the inliers
        inl = np.compress(np.abs(points @ normal + d) < threshold, points, axis=0)
        if len(inl) < 3:
            return None
        centre = _mean_rows(inl)
        _, _, vt = np.linalg.svd(_minus(inl, centre), full_matrices=False)
        normal = vt[2]
        d = -normal @ centre
    frac = float(np.mean(np.abs(points @ normal + d) < threshold))
    if frac < min_fraction:
        return None
    if origin is not None:
        flip = normal @ (origin - centre) < 0
    else:
        off = points @ normal + d
        flip = np.count_nonzero(off > threshold) < np.count_nonzero(off < -threshold)
    if flip:
        normal, d = -normal, -d
    return Plane(normal=normal, d=float(d), inlier_fraction=frac)


def _along(plane: Plane, points: np.ndarray, crop: np.ndarray, tree: KDTree) -> np.ndarray:
    """Whether the surface at each of ``points`` (N, 3) -- the normal of its FLAT_NEIGHBOURS
    nearest ``crop`` points (``tree``: over them) -- runs along ``plane`` (within FLAT_DEG).
    (N,) bool."""
    if len(points) == 0:
        return np.zeros(0, bool)
    normals = pca_normals(crop, FLAT_NEIGHBOURS, tree, at=points)
    return np.abs(normals @ plane.normal) >= math.cos(math.radians(FLAT_DEG))


def _flatness(plane: Plane, crop: np.ndarray, tree: KDTree,
              threshold: float) -> tuple[float, float]:
    """How flat the surface under ``plane`` is, from up to FLAT_SAMPLES crop (N, 3) points within
    SUPPORT_REACH thresholds of it (``tree``: over ``crop``): the fraction of those inside the
    ``threshold`` whose local normal is within FLAT_DEG of the plane's, and the spread (robust
    standard deviation, m) of the distances to the plane of all those whose normal is -- the
    scan's noise on the support."""
    d = plane.distance(crop)
    near = np.flatnonzero(np.abs(d) < SUPPORT_REACH * threshold)
    if len(near) > FLAT_SAMPLES:
        near = near[np.linspace(0, len(near) - 1, FLAT_SAMPLES).astype(np.int64)]
    agree = _along(plane, np.take(crop, near, axis=0), crop, tree)
    inside = np.abs(d[near]) < threshold
    if not inside.any() or not agree.any():
        return 0.0, 0.0
    on = d[near][agree]
    return float(np.mean(agree[inside])), float(1.4826 * np.median(np.abs(on - np.median(on))))


#: the fine points' normals are split between threads in parts of at least this many points
MIN_NORMALS_PART = 256


def _fine_normals(fine: np.ndarray, tree: KDTree, threads: int) -> np.ndarray:
    """:func:`pca_normals` (12 neighbours) of the fine points (N, 3) (``tree``: over them) in
    contiguous parts on up to ``threads`` threads (KD queries and numpy's batched eigh release
    the GIL): each point's normal is its own neighbourhood's, the same numbers either way."""
    from .registration.parallel import parts, run  # (the fitter imports this module)
    pieces = parts(len(fine), threads, MIN_NORMALS_PART)
    if len(pieces) == 1:
        return pca_normals(fine, 12, tree)
    return np.concatenate(run([lambda idx=idx: pca_normals(fine, 12, tree,
                                                           at=np.take(fine, idx, axis=0))
                               for idx in pieces], threads))


def _within(points: np.ndarray, targets: np.ndarray, tree: KDTree,
            distance: float) -> np.ndarray:
    """The ``points`` (N, 3) within ``distance`` (m) of any of ``targets`` (M, 3) (``tree``:
    over them), in their order. Only those inside the targets' bounding box widened by the
    distance are looked up in the tree: the others are farther from every target."""
    reach = distance * (1 + 1e-6)
    inside = np.ones(len(points), bool)
    for k in range(3):
        col = points[:, k]
        inside &= col >= targets[:, k].min() - reach
        inside &= col <= targets[:, k].max() + reach
    idx = np.flatnonzero(inside)
    near, _ = nearest(tree, np.take(points, idx, axis=0), distance)
    return np.take(points, np.compress(np.isfinite(near), idx), axis=0)


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


def _middle_first(n: int, step: int):
    """Start rows of the ``step``-row chunks of ``n`` rows, the middle chunk first, then
    outwards (an organized cloud's holes are mostly at its borders)."""
    starts = list(range(0, n, step))
    mid = len(starts) // 2
    return sorted(starts, key=lambda i: abs(i // step - mid))
