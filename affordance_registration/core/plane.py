# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The dominant plane around a click: found by RANSAC, kept as the support under the clicked object
only where the surface it cuts is flat (not a slab through a curved object), with the band of
the support's own noisy points that the cluster leaves out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .neighbours import KDTree, pca_normals
from .voxels import mean_rows, minus_point

__all__ = [
    "Plane",
    "ON_PLANE",
    "FLAT_FRACTION",
    "FLAT_DEG",
    "SUPPORT_REACH",
    "SUPPORT_SIGMAS",
    "STRADDLE_SHARE",
    "SUPPORT_TRIES",
    "reaches_behind",
]

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
FLAT_SAMPLES = 300  #: points near the plane whose normals are looked at (evenly spread)
#: the support's own points -- flat, their normals along the plane's -- are looked for this many
#: plane thresholds from it; their spread sigma (a depth camera's noise) widens the band taken
#: off the support for the cluster to SUPPORT_SIGMAS sigma, between one and SUPPORT_REACH
#: thresholds (a clean scan: the threshold)
SUPPORT_REACH = 3.0
SUPPORT_SIGMAS = 3.0
#: nothing is seen through what an object stands on: a plane with at least this share of the
#: clicked object behind it (by more than SUPPORT_REACH plane thresholds: the support's noise)
#: is not its support -- a crowded table's plane through other objects' faces, the top of a box
#: another lies across and hangs over. Set from that principle, not tuned: an object on its
#: support has nothing there; 5% is some 40 voxels of a tea box
STRADDLE_SHARE = 0.05
#: ... and the click's support is then looked for among this many further planes of the crop
#: (the click in front of each), the first the object does not reach behind
SUPPORT_TRIES = 2


@dataclass(frozen=True)
class Plane:
    """Plane n . x + d = 0 with unit normal ``n`` facing the sensor."""

    normal: np.ndarray
    d: float
    inlier_fraction: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.d


def ransac_plane(
    points: np.ndarray,
    threshold: float,
    min_fraction: float,
    origin: np.ndarray | None,
    seed: int,
    hypotheses: int = 96,
) -> Plane | None:
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
    for _ in range(2):  # least-squares refit on the inliers
        inl = np.compress(np.abs(points @ normal + d) < threshold, points, axis=0)
        if len(inl) < 3:
            return None
        centre = mean_rows(inl)
        _, _, vt = np.linalg.svd(minus_point(inl, centre), full_matrices=False)
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


def reaches_behind(plane: Plane, points: np.ndarray, threshold: float) -> bool:
    """Whether an object's ``points`` (N, 3) reach behind ``plane`` (of plane threshold
    ``threshold``): at least STRADDLE_SHARE of them (and 10) more than SUPPORT_REACH
    thresholds behind it -- the plane is then not what the object stands on."""
    behind = int(np.sum(plane.distance(points) < -SUPPORT_REACH * threshold))
    return behind >= max(10, STRADDLE_SHARE * len(points))


def runs_along(plane: Plane, points: np.ndarray, crop: np.ndarray, tree: KDTree) -> np.ndarray:
    """Whether the surface at each of ``points`` (N, 3) -- the normal of its FLAT_NEIGHBOURS
    nearest ``crop`` points (``tree``: over them) -- runs along ``plane`` (within FLAT_DEG).
    (N,) bool."""
    if len(points) == 0:
        return np.zeros(0, bool)
    normals = pca_normals(crop, FLAT_NEIGHBOURS, tree, at=points)
    return np.abs(normals @ plane.normal) >= math.cos(math.radians(FLAT_DEG))


def flatness(
    plane: Plane, crop: np.ndarray, tree: KDTree, threshold: float
) -> tuple[float, float]:
    """How flat the surface under ``plane`` is, from up to FLAT_SAMPLES crop (N, 3) points within
    SUPPORT_REACH thresholds of it (``tree``: over ``crop``): the fraction of those inside the
    ``threshold`` whose local normal is within FLAT_DEG of the plane's, and the spread (robust
    standard deviation, m) of the distances to the plane of all those whose normal is -- the
    scan's noise on the support."""
    d = plane.distance(crop)
    near = np.flatnonzero(np.abs(d) < SUPPORT_REACH * threshold)
    if len(near) > FLAT_SAMPLES:
        near = near[np.linspace(0, len(near) - 1, FLAT_SAMPLES).astype(np.int64)]
    agree = runs_along(plane, np.take(crop, near, axis=0), crop, tree)
    inside = np.abs(d[near]) < threshold
    if not inside.any() or not agree.any():
        return 0.0, 0.0
    on = d[near][agree]
    return float(np.mean(agree[inside])), float(1.4826 * np.median(np.abs(on - np.median(on))))
