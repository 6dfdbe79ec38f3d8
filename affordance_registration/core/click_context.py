# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What the fitting gets for one click (:class:`ClickContext`, built by
:meth:`~affordance_registration.core.scene.Scene.prepare_click` and reused for refits): the
cropped and voxelized points, the cluster around the click, its full-resolution points and
their normals, the support plane, the frame attached to the scan, and the range image the
visibility terms look up (:class:`RangeImage`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .errors import SceneError
from .neighbours import KDTree, k_nearest
from .plane import Plane
from .segmentation import joined_insides, segments_and_patches
from .voxels import minus_point

__all__ = ["ClickContext", "RangeImage", "NOISE_NEIGHBOURS", "NOISE_SAMPLES"]

#: the scan's noise around a click (``ClickContext.noise``): the spread off their plane of
#: this many nearest full-resolution neighbours, at up to NOISE_SAMPLES places
NOISE_NEIGHBOURS = 16
NOISE_SAMPLES = 300


class RangeImage:
    """Nearest observed depth per angular bin, as seen from the sensor origin.

    The image looks along ``frame``'s third column (the ray from the sensor origin to the
    click), whatever axes the scene's frame has: a point's depth is its distance along that ray
    and its bin is square in tangent space (x/z, y/z in ``frame``) with edge ``bin_size``;
    directions more than 90 degrees off the ray (only where the sensor is inside the crop) have
    no bin. A lookup gives the observed depth along the ray through a point, or NaN where the
    sensor saw nothing in that bin.
    """

    def __init__(self, points: np.ndarray, origin: np.ndarray, bin_size: float, frame: np.ndarray):
        self.origin = np.asarray(origin, dtype=float)
        self.frame = np.asarray(frame, dtype=float)
        self.bin = float(bin_size)
        rel = minus_point(points, self.origin) @ self.frame
        z = rel[:, 2]
        keep = z > 1e-3
        if not keep.all():  # (only where the sensor is inside the crop)
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
        flat, z = self.bins(offsets)
        return self.depth_or_nan[flat], z

    def bins(self, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The flat bin (...,) of each of the points given as offsets (..., 3) from the sensor
        origin -- ``nu * nv`` for a point outside the image -- and its depth (...,)."""
        rel = offsets @ self.frame
        z = rel[..., 2]
        zs = np.maximum(z, 1e-3)
        iu = np.floor((rel[..., 0] / zs - self.u0) / self.bin).astype(np.int64)
        iv = np.floor((rel[..., 1] / zs - self.v0) / self.bin).astype(np.int64)
        # a negative bin wraps to a huge unsigned one: one comparison per axis
        inside = (iu.view(np.uint64) < self.nu) & (iv.view(np.uint64) < self.nv) & (z > 1e-3)
        return np.where(inside, iu * self.nv + iv, self.nu * self.nv), z

    def front_points(self, points: np.ndarray) -> np.ndarray:
        """For each bin, the index of the one of ``points`` (N, 3) in it nearest the sensor,
        -1 where none is: (nu * nv + 1,), the last entry (outside the image) -1 -- an organized
        view of ``points`` for projective correspondences."""
        flat, z = self.bins(minus_point(points, self.origin))
        out = np.full(self.nu * self.nv + 1, -1, dtype=np.int64)
        order = np.lexsort((z, flat))  # by bin, nearest first
        first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]
        out[flat[first]] = first
        out[-1] = -1
        return out

    @cached_property
    def depth_or_nan(self) -> np.ndarray:
        """``depth`` followed by one NaN (what a lookup outside the image reads)."""
        return np.append(self.depth, np.nan)


@dataclass
class ClickContext:
    """Everything the fitting needs around one click (built once, reused for refits).

    ``cluster`` are the voxelized points connected to the click with the dominant plane removed
    (the ICP target); ``crop`` all voxelized points of the crop (the scoring target); ``fine`` the
    full-resolution cluster points (the final refinement target). ``frame`` (3, 3) is the
    rotation attached to the scan around the click
    (:func:`~affordance_registration.core.voxels.local_frame`): random draws and grids are laid
    out in it. Without a viewpoint ``sensor_origin`` and ``range_image`` are None (no visibility
    terms).
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
    #: an object's inside is joined to it in ``segments`` (:meth:`with_insides`)
    insides: bool = False

    @property
    def has_viewpoint(self) -> bool:
        return self.sensor_origin is not None

    def cluster_mean_near(
        self, point: np.ndarray, radius: float, min_points: int = 1
    ) -> np.ndarray | None:
        """Mean (3,) of the cluster points within ``radius`` (m) of ``point`` (3,), or None when
        fewer than ``min_points`` are."""
        point = np.asarray(point, dtype=float)
        if np.array_equal(point, self.click):  # (asked once per template: the same
            dist = self._cluster_to_click  # distances each time)
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
        nb = np.take(
            P, k_nearest(self.fine_tree, np.take(P, idx, axis=0), NOISE_NEIGHBOURS), axis=0
        )
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
        return self._segmentation[0]

    @cached_property
    def patches(self) -> np.ndarray:
        """The smooth patch label (N,) of each cluster point: the pieces ``segments`` joins,
        each a surface whose normals turn smoothly (a box's face, a can's side)."""
        return self._segmentation[1]

    @cached_property
    def _found_segments(self) -> tuple[np.ndarray, np.ndarray]:
        """The cluster's segments and patches as found, an inside not joined yet: shared with
        the copies :meth:`with_insides` makes (the segmentation is a click's dearest step
        after the fit; it is done once)."""
        return segments_and_patches(
            self.cluster, self.sensor_origin, self.voxel, self.cluster_tree
        )

    @cached_property
    def _segmentation(self) -> tuple[np.ndarray, np.ndarray]:
        labels, patches = self._found_segments
        if self.insides and self.plane is not None:
            clicked = labels[int(np.argmin(self._cluster_to_click))]
            labels = joined_insides(
                self.cluster,
                labels,
                clicked,
                self.plane.normal,
                self.frame[:, 0],
                self.sensor_origin,
            )
        return labels, patches

    def with_insides(self) -> "ClickContext":
        """This context with an object's inside and outside one segment
        (:func:`~.segmentation.joined_insides`: a mug clicked on its inside bottom is the mug),
        as a primitive measures the clicked object; itself where it is so already."""
        if self.insides:
            return self
        self._found_segments  # (found here, shared with the copy)
        out = self._segmented_again()
        out.__dict__.pop("_segmentation", None)
        out.insides = True
        return out

    def _segmented_again(self) -> "ClickContext":
        """A copy of this context sharing everything but what depends on the segments."""
        out = copy.copy(self)
        for name in (
            "segments",
            "patches",
            "clicked_segment",
            "clicked_patch",
            "clicked_points",
            "clicked_spread",
        ):
            out.__dict__.pop(name, None)
        return out

    def with_clicked_part(self, keep: np.ndarray) -> "ClickContext":
        """This context with its clicked segment cut in two: the segment's cluster points not in
        ``keep`` (N,) bool over the cluster become a segment of their own (a box standing on
        another with their sides flush, which the segments joined). Everything else is
        shared; what depends on the segments is computed again."""
        labels = np.array(self.segments)
        labels[(labels == self.clicked_segment) & ~np.asarray(keep, bool)] = labels.max() + 1
        out = self._segmented_again()
        out.__dict__["_segmentation"] = (labels, self.patches)
        return out

    @cached_property
    def clicked_segment(self) -> int:
        """The label (of ``segments``) of the segment the cluster point nearest the click is in."""
        return int(self.segments[int(np.argmin(self._cluster_to_click))])

    @cached_property
    def clicked_patch(self) -> int:
        """The label (of ``patches``) of the smooth patch the cluster point nearest the click is
        in."""
        return int(self.patches[int(np.argmin(self._cluster_to_click))])

    @cached_property
    def clicked_points(self) -> np.ndarray:
        """The cluster points (M, 3) of the clicked segment (``clicked_segment``)."""
        return self.cluster[self.segments == self.clicked_segment]

    @cached_property
    def clicked_spread(self) -> tuple[np.ndarray, float]:
        """The clicked segment's mean (3,) and the largest distance (m) of its points from it."""
        pts = self.clicked_points
        middle = pts.mean(axis=0)
        return middle, float(np.sqrt(((pts - middle) ** 2).sum(axis=1).max()))
