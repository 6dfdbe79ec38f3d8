# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The parts of a clicked object that something standing in front of it splits off.

A box behind a can is seen left and right of the can: two pieces of the scan, not connected,
and the click lands on one of them. A primitive measured on that piece alone is half the box.
Another piece is taken for part of the same object when

* it lies off the support -- a segment of what lies outside the click's cluster, or a
  segment of the cluster other than the clicked one (what stands in front may join both to
  the cluster) -- and is not much smaller than the clicked part (``MIN_PART`` of its points);
* the straight line from the clicked part to it (between their nearest points, at most
  ``BRIDGE_REACH`` long) is hidden all along: wherever the sensor returned something in its
  direction, that return lies at least ``verdict.occluder_gap`` in front of the line (all but
  ``SEEN_PAST`` of its points) -- what splits them stands in front (two boxes side by side
  show the table between them instead);

and the primitive measured on both pieces explains each of them (the registrar's test). The
pieces come at the scan's full resolution, with normals towards the sensor, as
:func:`.primitives.object_points` gives the clicked part.
"""

from __future__ import annotations

import numpy as np

from ..click_context import RangeImage
from ..memo import per_object
from ..neighbours import build_tree, nearest, pca_normals
from ..scene import ClickContext
from ..segmentation import gap_components, segments_and_patches
from .model import surface_distances
from .primitives import MEASURE_POINTS
from .scoring import widening
from .settings import FitSettings

__all__ = ["hidden_parts", "joined", "with_hidden_parts"]

#: a piece at most this far (m) from the clicked part may be split off it
BRIDGE_REACH = 0.12
#: points along the line between them, their ends left out
BRIDGE_SAMPLES = 9
#: at least this share of those points has a return (the rest: no evidence either way)
BRIDGE_KNOWN = 0.5
#: ... and all but at most this many of them lie behind something in front (the one at an
#: end may see the occluder's mixed pixels or the gap at its silhouette)
SEEN_PAST = 1
#: a piece holds at least this share of the clicked part's voxels (and 10)
MIN_PART = 0.2
#: steps between the voxels of one piece (m; the cluster's own gap)
PIECE_GAP = 0.025


def hidden_parts(ctx: ClickContext, scene, settings: FitSettings) -> list:
    """The pieces of the crop split off the clicked part (``ctx.clicked_points``) by
    something in front of it (see the module), each as (points (N, 3), normals (N, 3)) at
    the scan's full resolution from ``scene``; [] without a viewpoint, a support, a range
    image or a scene. Found once per click context, scene and settings (the primitives'
    measure and their verdict both ask)."""
    key = (
        "hidden parts",
        id(scene),
        settings.verdict.occluder_gap,
        settings.scoring.free_space_margin,
    )
    return per_object(ctx, key, lambda: _hidden_parts(ctx, scene, ctx.clicked_points, settings))


def _hidden_parts(ctx: ClickContext, scene, clicked: np.ndarray, settings: FitSettings) -> list:
    """:func:`hidden_parts` of the clicked part ``clicked`` (its voxels, (K, 3))."""
    if (
        scene is None
        or ctx.sensor_origin is None
        or ctx.support is None
        or ctx.range_image is None
        or len(clicked) < 10
    ):
        return []
    crop = ctx.crop
    off = ctx.support.distance(crop) > ctx.plane_threshold
    d, _ = nearest(ctx.cluster_tree, crop, 1e-9)
    rest = crop[off & ~np.isfinite(d)]
    # the candidates: the crop's pieces outside the cluster, and the cluster's other segments
    # (what stands in front may join them to the cluster)
    candidates = []
    if len(rest) >= 10:
        labels = gap_components(rest, PIECE_GAP)
        candidates += [(rest[labels == k], True) for k in range(int(labels.max()) + 1)]
    segments = ctx.segments
    clicked_label = ctx.clicked_segment
    candidates += [
        (ctx.cluster[segments == k], False) for k in np.unique(segments) if k != clicked_label
    ]
    tree_a = build_tree(clicked)
    image, pieces = None, []
    for piece, joined_by_steps in candidates:
        if len(piece) < max(10, MIN_PART * len(clicked)):
            continue
        dist, idx = nearest(tree_a, piece, BRIDGE_REACH)
        if not np.isfinite(dist).any():
            continue
        j = int(np.argmin(dist))
        a, b = clicked[idx[j]], piece[j]
        line = a + np.linspace(0.0, 1.0, BRIDGE_SAMPLES + 2)[1:-1, None] * (b - a)
        obs, depth = ctx.range_image.lookup(line)
        if np.sum(obs > depth + settings.scoring.free_space_margin) > SEEN_PAST:
            continue  # the sensor saw past the line: nothing stands in front there
        # (what stands in front may lie outside the crop: the whole scan in its cone)
        image = _cone_image(ctx, scene) if image is None else image
        obs, depth = image.lookup(line)
        known = obs == obs
        hidden = obs[known] < depth[known] - settings.verdict.occluder_gap
        if known.sum() < BRIDGE_KNOWN * BRIDGE_SAMPLES or hidden.sum() < known.sum() - SEEN_PAST:
            continue
        if joined_by_steps:
            piece = _segment_at(ctx, piece, j)
            if len(piece) < max(10, MIN_PART * len(clicked)):
                continue
        pieces.append(_full_resolution(ctx, scene, piece))
    return [p for p in pieces if len(p[0]) >= 10]


def _segment_at(ctx: ClickContext, piece: np.ndarray, end: int) -> np.ndarray:
    """The segment of ``piece`` (voxels, (N, 3)) that its point ``end`` (where the line from
    the clicked part arrives) lies in: a piece outside the cluster is what the cluster's steps
    join, and another object touching the hidden part is joined to it -- cut where two
    touching surfaces meet, as the cluster is (:func:`~..segmentation.segments_and_patches`)."""
    labels, _ = segments_and_patches(piece, ctx.sensor_origin, ctx.voxel)
    return piece[labels == labels[end]]


def _cone_image(ctx: ClickContext, scene) -> RangeImage:
    """The range image of the crop (as the click's context has it), of every scan point in
    the cone from the sensor that the crop's sphere fills (at most 60 degrees round the ray):
    what stands in front of the crop too."""
    origin = ctx.sensor_origin
    axis = ctx.click - origin
    reach = float(np.linalg.norm(axis))
    axis = axis / reach
    rel = scene.points - origin
    along = rel @ axis
    # (at most 60 degrees off the ray: a sensor inside the crop would see half a sphere)
    cos_cone = max(0.5, float(np.sqrt(max(0.0, 1.0 - min(1.0, ctx.radius / reach) ** 2))))
    inside = (along > 1e-3) & (along >= cos_cone * np.linalg.norm(rel, axis=1))
    return RangeImage(
        scene.points[inside], origin, bin_size=ctx.range_image.bin, frame=ctx.range_image.frame
    )


def _full_resolution(ctx: ClickContext, scene, voxels: np.ndarray):
    """The scan's points within a voxel of ``voxels`` (and of the click's crop), with PCA
    normals turned towards the sensor."""
    pts = scene.points
    near = np.einsum("ij,ij->i", pts - ctx.click, pts - ctx.click) <= ctx.radius**2
    pts = pts[near]
    d, _ = nearest(build_tree(voxels), pts, ctx.voxel)
    pts = pts[np.isfinite(d)]
    if len(pts) < 10:
        return pts, np.zeros_like(pts)
    normals = pca_normals(pts, 12, build_tree(pts))
    normals[np.einsum("ij,ij->i", normals, ctx.sensor_origin - pts) < 0] *= -1
    return pts, normals


def joined(measured, parts, limit: int):
    """``measured`` (:func:`.primitives.object_points`' tuple) with the points and normals of
    ``parts`` added, an even subset of at most ``limit`` of them."""
    points, normals, support, up = measured
    points = np.concatenate([points] + [p for p, _ in parts])
    normals = np.concatenate([normals] + [n for _, n in parts])
    if len(points) > limit:
        keep = np.linspace(0, len(points) - 1, limit).astype(np.int64)
        points, normals = points[keep], normals[keep]
    return points, normals, support, up


def with_hidden_parts(
    ctx: ClickContext, scene, measured, fitted: list, fit_on, model_of, settings: FitSettings
) -> tuple[list, list]:
    """``fitted`` (one primitive each, measured on the clicked part: ``measured``), each
    measured again with the pieces of the object something in front splits off
    (:func:`hidden_parts`) where there are any, and kept so when that one explains the clicked
    part and every piece: the share of each within the verdict's (widened)
    ``explained_distance`` of its surface is at least ``verdict.min_explained``.
    ``fit_on(measured, k)``: the k-th primitive measured on such a tuple; ``model_of(result)``:
    a result's model. Returns (the fits, the points (N, 3) of the pieces each was measured with
    -- (0, 3) where none)."""
    none = np.zeros((0, 3))
    parts = hidden_parts(ctx, scene, settings)
    if not parts:
        return fitted, [none] * len(fitted)
    v = settings.verdict
    within = widening(ctx, settings) * v.explained_distance
    both = joined(measured, parts, MEASURE_POINTS)
    pieces = np.concatenate([p for p, _ in parts])
    out, used = [], []
    for k, alone in enumerate(fitted):
        res = fit_on(both, k)
        model, T = model_of(res), res.T_scene_model
        shares = [
            float(
                np.mean(
                    surface_distances([model], ((p - T[:3, 3]) @ T[:3, :3])[None], 2 * within)[0]
                    <= within
                )
            )
            for p in [measured[0]] + [q for q, _ in parts]
        ]
        keep = min(shares) >= v.min_explained
        out.append(res if keep else alone)
        used.append(pieces if keep else none)
    return out, used
