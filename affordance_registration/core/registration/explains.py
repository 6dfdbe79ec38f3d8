# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Whether a shape explains the object at the click, and nothing else.

A primitive is measured on the clicked object's points (the region: the clicked segment of the
crop, its inside where it is a vessel, and the pieces something standing in front splits off).
It explains the object when both directions hold within the sensor's noise:

* **recall** -- of the object's points, the share within ``tolerance`` of the shape's surface
  (a shape measured on a part of the object, or too small for it, leaves the rest out);
* **precision** -- of the scan's points within ``tolerance`` of the shape's surface, the share
  that is the object's (a shape too large for it lies on the table around its base, on the box
  it stands on, on a neighbour's face).

The tolerance is ``verdict.object_distance`` or ``verdict.noise_sigmas`` times the scan's
measured noise around the click, whichever is larger. This is the measure the operator's own
question asks ("is this the object, the whole of it and only it?"), and the one the product is
scored by against hand-labelled real scans (``docs/REAL_DATA.md``): the verdict says "fits" of a
primitive only where it expects that score to pass.

Which scan points are the object's is read off the click's segmentation (the clicked segment,
:func:`.primitives.object_voxels`), grown by what the shape explains whole (see
:func:`explanation`); the support's own surface never is.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..click_context import ClickContext
from ..meshes import primitive_distance, primitive_normal, primitive_outside
from ..neighbours import build_tree, nearest
from ..plane import runs_along
from .model import Model, surface_distances
from .settings import FitSettings

__all__ = ["Explanation", "ObjectVoxels", "explanation", "object_tolerance", "SCAN_POINTS"]

#: at most this many of the scan's points around the click are asked whether they lie on the
#: shape (an even subset: the shares, not the counts, matter)
SCAN_POINTS = 20000
#: a primitive whose z lies within this (cosine, about 15 deg) of the support's normal stands
#: on its base
STANDING_COS = 0.966


@dataclass(frozen=True)
class Explanation:
    """How a posed shape explains the clicked object: ``recall`` (share of the object's points
    on its surface), ``precision`` (share of the scan points on its surface that are the
    object's; 1.0 where no scan point lies on it), ``tolerance`` (m)."""

    recall: float
    precision: float
    tolerance: float


def object_tolerance(ctx: ClickContext, settings: FitSettings) -> float:
    """The distance (m) within which a scan point lies on a shape's surface around this click:
    ``verdict.object_distance``, or ``verdict.noise_sigmas`` times the scan's noise."""
    v = settings.verdict
    return max(v.object_distance, v.noise_sigmas * ctx.noise)


@dataclass(frozen=True)
class ObjectVoxels:
    """The clicked object as voxels of a cluster (:func:`.primitives.object_voxels`):
    ``cluster`` (K, 3) and its ``tree``, each voxel's segment ``labels`` (K,) and smooth
    ``patches`` (K,; the pieces the segments were joined from), the ``clicked`` segment, the
    voxel edge (m), the surface the object stands on (``support``, a Plane or None) and its
    ``up`` direction where the support does not give it (None: from the support)."""

    cluster: np.ndarray = field(repr=False)
    tree: object = field(repr=False)
    labels: np.ndarray = field(repr=False)
    patches: np.ndarray = field(repr=False)
    clicked: int
    voxel: float
    support: object
    up: np.ndarray | None

    def member(self, points: np.ndarray, patches=(), reach: float | None = None) -> np.ndarray:
        """Whether each of ``points`` (N, 3) is the object's: its nearest cluster voxel, within
        ``reach`` (m; default a voxel), lies in the clicked segment or in one of the smooth
        ``patches``. (N,) bool."""
        d, idx = nearest(self.tree, points, self.voxel if reach is None else reach)
        out = np.isfinite(d)
        near = idx[out]
        out[out] = (self.labels[near] == self.clicked) | np.isin(self.patches[near], patches)
        return out


def explanation(
    ctx: ClickContext,
    model: Model,
    T_scene_model: np.ndarray,
    region: np.ndarray,
    scan: np.ndarray,
    voxels: ObjectVoxels,
    pieces,
    settings: FitSettings,
) -> Explanation:
    """The :class:`Explanation` of ``model`` posed at ``T_scene_model`` (4x4) for the object
    whose points are ``region`` (N, 3) -- what it was measured on -- among ``scan`` (M, 3), the
    scan's points around the click (full resolution; an even subset of at most SCAN_POINTS is
    used). Which scan points are the object's: the clicked segment's (``voxels``), and every
    smooth patch of the cluster and every piece of ``pieces`` ((K, 3) arrays: the parts an
    occluder splits off) that lies on the shape -- off the base a standing shape stands on --
    for at least ``verdict.min_precision`` of its points: the shape, measured on the clicked
    part, explains it whole, so it is the object's too (a face the segmentation joined to a
    neighbour, the far side of something standing in front). The
    support's own surface (within its plane threshold, running along it: not the object's side
    faces where they meet it) never is."""
    tol = object_tolerance(ctx, settings)
    share = settings.verdict.min_precision
    T = np.asarray(T_scene_model, float)
    R, t = T[:3, :3], T[:3, 3]

    tpl = model.template
    # a primitive standing on the support (its z along the support's normal) stands on its
    # base: scan points on the base are what it stands on (a lower box's top face), no
    # evidence of the object
    standing = (
        tpl.primitive is not None
        and voxels.support is not None
        and abs(float(np.asarray(voxels.support.normal) @ R[:, 2])) >= STANDING_COS
    )

    def on_surface(points: np.ndarray, evidence: bool = False) -> np.ndarray:
        """Which ``points`` lie on the shape's surface (with ``evidence``: not on the base it
        stands on)."""
        if len(points) == 0:
            return np.zeros(0, bool)
        local = (np.asarray(points, float) - t) @ R
        if tpl.primitive is None:
            return surface_distances([model], local[None], 2.0 * tol)[0] <= tol
        # (exact: a mesh's samples lie a millimetre off it)
        on = primitive_distance(tpl.primitive, tpl.dimensions, local) <= tol
        if evidence and standing:
            on &= primitive_normal(tpl.primitive, tpl.dimensions, local)[:, 2] > -0.5
        return on

    region = np.asarray(region, float)
    recall = float(np.mean(on_surface(region))) if len(region) else 0.0
    scan = np.asarray(scan, float)
    if len(scan) > SCAN_POINTS:
        scan = np.take(scan, np.linspace(0, len(scan) - 1, SCAN_POINTS).astype(np.int64), axis=0)
    on = np.compress(on_surface(scan), scan, axis=0)
    if len(on) == 0:
        return Explanation(recall, 1.0, tol)
    patches = voxels.patches
    counts = np.bincount(patches)
    held = np.bincount(patches, weights=on_surface(voxels.cluster, True), minlength=len(counts))
    whole = np.flatnonzero(held >= share * np.maximum(counts, 1))
    # (within a voxel of the cluster -- or, in the support's band, which the cluster leaves
    # out, of the voxels just over it: an object's side faces reach down into the band)
    mine = voxels.member(on, whole, ctx.voxel + ctx.plane_threshold)
    joined = [
        np.asarray(p, float) for p in pieces if len(p) and on_surface(p, True).mean() >= share
    ]
    if joined:
        mine |= np.isfinite(nearest(build_tree(np.concatenate(joined)), on, ctx.voxel)[0])
    support = voxels.support  # (the object's: a face the click is on is not)
    if support is not None:  # the support's own surface: in its band, and running along it
        band = np.flatnonzero(mine & (np.abs(support.distance(on)) <= ctx.plane_threshold))
        flat = runs_along(support, np.take(on, band, axis=0), ctx.crop, ctx.crop_tree)
        mine[band[flat]] = False
        if tpl.primitive is not None:  # ... or, round a primitive's base, outside its solid
            # by more than the verdict's noise (sigma: a noise_sigmas-th of the tolerance):
            # the strip of support at its foot, which the voxels' membership cannot part
            # from its side faces' lowest millimetres
            rest = band[~flat]
            local = (np.take(on, rest, axis=0) - t) @ R
            sigma = tol / settings.verdict.noise_sigmas
            mine[rest[primitive_outside(tpl.primitive, tpl.dimensions, local) > sigma]] = False
    return Explanation(recall, float(np.mean(mine)), tol)
