# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The voxel grid a scan is thinned on and the frame it is laid out in, with the column-wise
array helpers the per-click preparation is built from.

The frame (:func:`local_frame`) is attached to the scan around a click, so a grid laid out in it
turns with the data: fitting a rigidly moved scene gives the rigidly moved answer. The helpers
give numpy's own numbers (a difference, a mean, a grouping) by a faster route, so that the
fitting's figures do not depend on which route was taken.
"""

from __future__ import annotations

import numpy as np

from .transforms import align_z_to

__all__ = ["voxel_downsample", "local_frame", "DENSE_CELLS_PER_POINT"]


def voxel_downsample(points: np.ndarray, voxel: float, origin=None, frame=None) -> np.ndarray:
    """Centroid of the points in each occupied voxel of edge ``voxel`` (m). (N, 3) -> (M, 3).
    The grid is aligned with the scene's axes at its origin, or with the columns of ``frame``
    (3, 3) and centred on ``origin`` (3,) -- a grid attached to the data turns with it -- and the
    voxels come in the order of their grid coordinates."""
    if len(points) == 0:
        return points.reshape(0, 3)
    # a grid attached to the data has ``origin`` at a voxel's centre (a surface through the
    # origin, the click, would otherwise be split between two layers of voxels)
    grid = points if frame is None else minus_point(points, origin) @ frame + 0.5 * voxel
    keys = np.floor(grid / voxel).astype(np.int64)
    cols = [keys[:, k] - keys[:, k].min() for k in range(3)]  # column by column: no
    dims = [int(col.max()) + 1 for col in cols]  # (N, 3) reductions
    flat = (cols[0] * dims[1] + cols[1]) * dims[2] + cols[2]
    inverse, counts = _group(flat, dims[0] * dims[1] * dims[2])
    sums = np.stack(
        [np.bincount(inverse, weights=points[:, k], minlength=len(counts)) for k in range(3)],
        axis=1,
    )
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


def local_frame(points: np.ndarray, click: np.ndarray, origin: np.ndarray | None) -> np.ndarray:
    """A rotation (3, 3) attached to the scan around a click, whatever frame it is given in:
    third column towards the sensor ``origin`` (without one: the direction in which
    ``points`` (N, 3) spread least), first column their main axis across it; the signs of the
    axes from the points' third moments along them. Rigidly moving the points, the click and the
    origin turns this frame with them."""
    rel = minus_point(points, mean_rows(points))
    cov = rel.T @ rel

    def signed(axis):  # the side the points' distribution leans to
        return axis if _leans_forward(rel @ axis) else -axis

    if origin is not None and np.linalg.norm(origin - click) > 1e-9:
        z = (origin - click) / np.linalg.norm(origin - click)
    else:
        z = signed(np.linalg.eigh(cov)[1][:, 0])
    across = np.eye(3) - np.outer(z, z)
    x = signed(np.linalg.eigh(across @ cov @ across)[1][:, 2])
    x = x - z * (x @ z)
    if np.linalg.norm(x) < 1e-9:  # no spread across z at all: any perpendicular
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
        lean = np.sum(along**3)
    return bool(lean >= 0)


def minus_point(points: np.ndarray, point: np.ndarray) -> np.ndarray:
    """``points - point`` for points (N, 3) and a point (3,), column by column: the same
    numbers, three times faster than broadcasting over a last axis of length three."""
    out = np.empty(points.shape, np.result_type(points, point))
    for k in range(3):
        np.subtract(points[:, k], point[k], out=out[:, k])
    return out


def mean_rows(points: np.ndarray) -> np.ndarray:
    """``points.mean(axis=0)`` of points (N, 3), N >= 1: the same numbers -- numpy adds the
    rows one after the other there, as a running sum of each column does -- twice as fast."""
    return np.array([np.add.accumulate(points[:, k])[-1] for k in range(3)]) / len(points)
