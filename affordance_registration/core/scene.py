# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
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

The steps live in modules of their own: the voxel grid and the frame in
:mod:`~affordance_registration.core.voxels`, the plane in
:mod:`~affordance_registration.core.plane`, the cluster and its segments in
:mod:`~affordance_registration.core.segmentation`, what a click gets in
:mod:`~affordance_registration.core.click_context`. This module composes them and re-exports the
names the rest of the package imports from it.

Nothing here assumes an axis: the voxel grid, the range image's bins and every random draw of
the fit are laid out in a frame attached to the scan around the click (``ClickContext.frame``:
its z towards the sensor, its x along the main axis of the points), so fitting a rigidly moved
scene (its points, click and sensor origin) gives the rigidly moved answer.
"""

from __future__ import annotations

import math

import numpy as np

from .click_context import ClickContext, RangeImage
from .errors import SceneError
from .neighbours import KDTree, build_tree, nearest, pca_normals
from .plane import (
    FLAT_FRACTION,
    ON_PLANE,
    SUPPORT_REACH,
    SUPPORT_SIGMAS,
    SUPPORT_TRIES,
    Plane,
    flatness,
    ransac_plane,
    reaches_behind,
    runs_along,
)
from .segmentation import connected_to, gap_components, segment
from .transforms import finite_vector
from .voxels import local_frame, mean_rows, minus_point, voxel_downsample

__all__ = [
    "Scene",
    "ClickContext",
    "Plane",
    "RangeImage",
    "voxel_downsample",
    "load_points",
    "local_frame",
    "segment",
    "NO_VIEWPOINT",
]

#: a sensor origin or a click farther than this (m) from its frame's origin is refused: beyond any
#: map frame (UTM northings are below 1e7 m), and its squared distances would overflow
MAX_ORIGIN = 1e9
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
        self._whole: "Scene | None" = None  # the scene a part was cut from (units hint)
        mid = len(pts) // 2
        if not (
            np.isfinite(pts[mid : mid + self._FIRST_PROBE]).all(axis=1).any()
            or any(
                np.isfinite(pts[i : i + self._PROBE_ROWS]).all(axis=1).any()
                for i in _middle_first(len(pts), self._PROBE_ROWS)
            )
        ):
            raise SceneError(
                "the scene has no finite points"
                + (f" ({len(pts)} NaN/inf points dropped)" if len(pts) else "")
            )
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
        d = minus_point(np.take(pts, idx, axis=0), c)
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
        return (
            f"; the scan is {extent:.0f} units across, which as metres is larger than a "
            f"room: if it is in millimetres or centimetres, give its units (--units mm or "
            f"cm) so that it is scaled to metres"
        )

    def snap(self, click, max_distance: float = 0.03) -> np.ndarray:
        """The scene point nearest ``click`` (3,). Farther than ``max_distance`` is an error."""
        c = _point3(click, "click")
        if self._squared_to is not None and np.array_equal(self._squared_to[0], c):
            d2 = self._squared_to[1]  # a part cut around this very point
        else:
            rel = minus_point(self.points, c)
            d2 = np.einsum("ij,ij->i", rel, rel)
        i = int(np.argmin(d2))
        dist = math.sqrt(d2[i])
        if dist > max_distance:
            raise SceneError(
                f"the click ({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) is {dist * 100:.1f} cm "
                f"from the nearest scanned point (limit {max_distance * 100:.1f} cm): "
                f"click on the object's surface{self.units_hint()}"
            )
        return self.points[i].copy()

    def prepare_click(
        self,
        click,
        radius: float,
        voxel: float = 0.005,
        plane_threshold: float = 0.006,
        min_plane_fraction: float = 0.15,
        cluster_gap: float | None = None,
        seed: int = 0,
        threads: int = 1,
        fine_points: int = 0,
    ) -> ClickContext:
        """Crop ``radius`` around the (already snapped) click and prepare the fitting targets.
        ``threads``: the fine points' normals (most of the time) in that many parts side by side
        (the same numbers). ``fine_points``: at most this many full-resolution points (an even
        subset of them in the scan's order; 0: all)."""
        c = _point3(click, "click")
        rel = minus_point(self.points, c)
        d2 = np.einsum("ij,ij->i", rel, rel)
        raw = np.compress(d2 <= radius * radius, self.points, axis=0)
        if len(raw) < 10:
            raise SceneError(
                f"only {len(raw)} scanned points within {radius:.2f} m of the click"
                f"{self.units_hint()}"
            )
        origin = self.sensor_origin
        if origin is not None and np.linalg.norm(origin - c) < 1e-3:
            raise SceneError(
                "the sensor origin is at the click: the scan cannot have been "
                "taken from there (give where the sensor was, or 'none')"
            )
        frame = local_frame(raw, c, origin)
        crop = voxel_downsample(raw, voxel, c, frame)
        _check_spread(crop, voxel, radius)
        crop_tree = build_tree(crop)
        plane, band = _flat_plane(
            crop, crop, crop_tree, plane_threshold, min_plane_fraction, origin, seed
        )
        support = plane
        if (
            plane is not None
            and abs(plane.distance(c)) <= ON_PLANE * plane_threshold
            and _reaches(plane, crop, c, ON_PLANE * plane_threshold, voxel)
        ):
            plane = None  # the click is on the plane: it is the object's, not a mount's
        gap = cluster_gap if cluster_gap is not None else 0.025
        reach = max(0.3 * radius, 3 * voxel)
        keep, straddles = np.ones(len(crop), bool), False
        if plane is not None:
            keep, straddling, straddles = _off_plane(
                plane, band, crop, crop_tree, plane_threshold, c, gap, reach
            )
            if straddles:  # the clicked object reaches behind it: is another its support?
                other = _support_in_front(
                    plane,
                    crop,
                    crop_tree,
                    plane_threshold,
                    min_plane_fraction,
                    origin,
                    seed,
                    c,
                    gap,
                    reach,
                )
                if other is not None:  # (which the object does not reach behind)
                    (plane, keep), straddles = other, False
                    support = plane
                else:  # none: the first plane, the object's part behind it kept
                    keep = keep | straddling
        cluster = connected_to(crop, keep, c, gap, reach=reach)
        if len(cluster) < 10:  # nothing off the plane near the click: fit to the whole crop
            cluster = crop
            plane_for_fine = None
        else:
            plane_for_fine = plane
        # full-resolution points of the cluster's voxels (final refinement target)
        # (the points on the plane first left out: most of a crop's, and none of them fine)
        cluster_tree = build_tree(cluster)
        if plane_for_fine is None:
            fine = raw
        else:
            off_raw = plane_for_fine.distance(raw)
            ahead = off_raw > plane_threshold
            if straddles:  # (and the object's part behind the plane)
                ahead |= off_raw < -SUPPORT_REACH * plane_threshold
            fine = np.compress(ahead, raw, axis=0)
        fine = _within(fine, cluster, cluster_tree, voxel)
        if len(fine) < 10:
            fine = cluster
        if 0 < fine_points < len(fine):  # a dense sensor's: the fine stage needs no more
            fine = np.take(
                fine, (np.arange(fine_points) * (len(fine) / fine_points)).astype(np.int64), axis=0
            )
        range_image = None
        if origin is not None:
            depth = max(float(np.linalg.norm(c - origin)), 0.2)
            # the image's axis runs from the sensor to the click: the frame's z turned round
            range_image = RangeImage(
                raw, origin, bin_size=voxel / depth, frame=frame * np.array([1.0, -1.0, -1.0])
            )
        fine_tree = build_tree(fine)
        ctx = ClickContext(
            click=c,
            radius=float(radius),
            voxel=float(voxel),
            sensor_origin=origin,
            crop=crop,
            cluster=cluster,
            fine=fine,
            plane=plane_for_fine,
            plane_threshold=plane_threshold,
            range_image=range_image,
            crop_tree=crop_tree,
            cluster_tree=cluster_tree,
            fine_tree=fine_tree,
            fine_normals=_fine_normals(fine, fine_tree, threads),
            support=support,
            frame=frame,
        )
        return ctx


def _flat_plane(
    points: np.ndarray,
    crop: np.ndarray,
    tree: KDTree,
    threshold: float,
    min_fraction: float,
    origin: np.ndarray | None,
    seed: int,
) -> tuple[Plane | None, float]:
    """The largest plane of ``points`` (holding at least ``min_fraction`` of them) where the
    ``crop``'s surface under it is flat (:func:`~.plane.flatness`; ``tree`` over ``crop``),
    and the band (m) its surface's noise lifts points off it; (None, ``threshold``): none (a
    slab through a curved object is no support)."""
    plane = ransac_plane(points, threshold, min_fraction, origin, seed)
    if plane is None:
        return None, threshold
    flat, sigma = flatness(plane, crop, tree, threshold)
    if flat < FLAT_FRACTION:
        return None, threshold
    return plane, min(max(SUPPORT_SIGMAS * sigma, threshold), SUPPORT_REACH * threshold)


def _support_in_front(
    plane: Plane,
    crop: np.ndarray,
    tree: KDTree,
    threshold: float,
    min_fraction: float,
    origin: np.ndarray | None,
    seed: int,
    click: np.ndarray,
    gap: float,
    reach: float,
) -> tuple[Plane, np.ndarray] | None:
    """The support of a click whose object reaches behind ``plane`` (the crop's dominant one):
    the first of the next SUPPORT_TRIES flat planes of the ``crop`` (each holding at least
    ``min_fraction`` of it, found among the points off the planes before it) with the click
    in front of it and the object not reaching behind it, with what stands off it for the
    cluster (:func:`_off_plane`'s points in front); None: none."""
    left = crop
    for attempt in range(1, 1 + SUPPORT_TRIES):
        left = np.compress(np.abs(plane.distance(left)) > threshold, left, axis=0)
        if len(left) < 10:
            return None
        plane, band = _flat_plane(
            left,
            crop,
            tree,
            threshold,
            min(1.0, min_fraction * len(crop) / len(left)),
            origin,
            seed + attempt,
        )
        if plane is None:
            return None
        if plane.distance(click) <= threshold:
            continue  # (a support has the click in front of it)
        keep, _, straddles = _off_plane(plane, band, crop, tree, threshold, click, gap, reach)
        if not straddles:
            return plane, keep
    return None


def _off_plane(
    plane: Plane,
    band: float,
    crop: np.ndarray,
    tree: KDTree,
    threshold: float,
    click: np.ndarray,
    gap: float,
    reach: float,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """What stands off ``plane`` for the click's cluster: (the ``crop`` points in front of it --
    not the plane's own surface lifted by its noise, up to ``band`` -- (N,) bool; those behind
    it that belong with the click, (N,) bool; whether the clicked object reaches behind it).

    Nothing is seen through what an object stands on. A plane through the faces of other
    objects (a crowded table's box tops, the top of a box another lies across and hangs over)
    has the clicked object reaching behind it, and taking everything behind it away cuts the
    object. Behind it: the points more than SUPPORT_REACH ``threshold`` behind, and those
    between whose surface crosses the plane (not running along it, within ``gap`` of the
    points behind), joined by steps of at most ``gap`` to the points in front within
    ``reach`` of the click; whether all that the steps join reaches behind it is
    :func:`~.plane.reaches_behind`'s."""
    off = plane.distance(crop)
    keep = off > threshold
    lifted = np.flatnonzero(keep & (off <= band))
    keep[lifted] = ~runs_along(plane, np.take(crop, lifted, axis=0), crop, tree)
    behind = off < -SUPPORT_REACH * threshold
    if not behind.any():
        return keep, behind, False
    between = np.flatnonzero(~keep & ~behind)
    if len(between):
        d, _ = nearest(build_tree(np.compress(behind, crop, axis=0)), crop[between], gap)
        between = between[np.isfinite(d)]
    crossing = np.zeros(len(crop), bool)
    if len(between):
        crossing[between] = ~runs_along(plane, crop[between], crop, tree)
    idx = np.flatnonzero(keep | behind | crossing)
    pts = crop[idx]
    labels = gap_components(pts, gap)
    seeds = keep[idx] & (np.linalg.norm(minus_point(pts, click), axis=1) <= reach)
    joined = np.zeros(len(crop), bool)
    joined[idx[np.isin(labels, np.unique(labels[seeds]))]] = True
    straddles = reaches_behind(plane, np.compress(joined, crop, axis=0), threshold)
    return keep, joined & (behind | crossing), straddles


#: the plane's surface reaches a click near it where the plane's points joined by steps of at
#: most this many voxels link the click to at least REACH_SHARE of them; a click nearer the
#: plane than its own points that is walled off from it (the inside bottom of a mug standing on
#: the table) is on another surface, the plane still the mount
REACH_STEP = 1.5
REACH_SHARE = 0.25


def _reaches(plane: Plane, crop: np.ndarray, click: np.ndarray, band: float, voxel: float) -> bool:
    """Whether the surface of ``plane`` -- the ``crop`` points within ``band`` of it -- reaches
    ``click`` (the points of it that steps of REACH_STEP voxels join to the click hold at least
    REACH_SHARE of them)."""
    on = np.compress(np.abs(plane.distance(crop)) <= band, crop, axis=0)
    step = REACH_STEP * voxel
    d = np.linalg.norm(minus_point(on, click), axis=1)
    if len(on) == 0 or float(d.min()) > step:
        return False
    labels = gap_components(on, step)
    mine = labels == labels[int(np.argmin(d))]
    return int(mine.sum()) >= REACH_SHARE * len(on)


def _point3(value, what: str) -> np.ndarray:
    p = finite_vector(value, what, SceneError)
    if np.max(np.abs(p)) > MAX_ORIGIN:
        raise SceneError(
            f"the {what} ({p[0]:.3g}, {p[1]:.3g}, {p[2]:.3g}) lies more than "
            f"{MAX_ORIGIN:.0e} m from the scan's origin"
        )
    return p


def _origin(value) -> np.ndarray | None:
    """A sensor origin: (3,) finite, None for :data:`NO_VIEWPOINT`; None given: zeros."""
    if value is None:
        return np.zeros(3)
    if isinstance(value, str):
        if value.strip().lower() == NO_VIEWPOINT:
            return None
        raise SceneError(
            f"sensor origin must be 3 finite numbers or '{NO_VIEWPOINT}', got {value!r}"
        )
    return _point3(value, "sensor origin")


def _check_spread(crop: np.ndarray, voxel: float, radius: float) -> None:
    """Refuse a crop that is no surface at all: a handful of distinct places, or points on one
    line (nothing can be fitted to them)."""
    if len(crop) < 10:
        raise SceneError(
            f"the scan around the click holds only {len(crop)} distinct points "
            f"(at {voxel * 1000:.0f} mm): nothing to fit"
        )
    rel = minus_point(crop, mean_rows(crop))
    # the singular values from the eigenvalues of the (3, 3) Gram matrix (an SVD of the crop
    # costs ten times more); within rounding of the limit, from the SVD
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(rel.T @ rel)[::-1], 0.0) / len(crop))
    if abs(spread[1] - 0.5 * voxel) <= 1e-6 * spread[0]:
        spread = np.linalg.svd(rel, compute_uv=False) / math.sqrt(len(crop))
    if spread[1] < 0.5 * voxel:
        raise SceneError("the scanned points around the click lie on a line: nothing to fit")


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
    return np.concatenate(
        run(
            [
                lambda idx=idx: pca_normals(fine, 12, tree, at=np.take(fine, idx, axis=0))
                for idx in pieces
            ],
            threads,
        )
    )


def _within(points: np.ndarray, targets: np.ndarray, tree: KDTree, distance: float) -> np.ndarray:
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


def _middle_first(n: int, step: int):
    """Start rows of the ``step``-row chunks of ``n`` rows, the middle chunk first, then
    outwards (an organized cloud's holes are mostly at its borders)."""
    starts = list(range(0, n, step))
    mid = len(starts) // 2
    return sorted(starts, key=lambda i: abs(i // step - mid))
