# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Initial poses from local shape features, for scanned (point-cloud) templates.

A scanned template is usually a large, free-standing object with no mounting base, and a click
may land anywhere on it (a leg of a statue): random restarts about the click rarely start ICP in
its basin. Here FPFH descriptors (Open3D) of the template's thinned surface are matched to those
of the *cluster* -- the points connected to the click off the support, where an object touching
others in clutter still has most of its own points and a crop full of neighbours would outvote
it: mutual nearest descriptors (all nearest ones where too few are mutual), then
``GLOBAL_RUNS`` runs of a RANSAC over three matches (:func:`global_ransac`: Open3D's
feature-matching RANSAC's checks and stopping rule, drawn from the fit's generator for it),
whose best poses join the other initial hypotheses and compete in the same coarse stage. The
descriptors -- normals towards the sensor -- do not depend on the scene's frame. (Mesh
templates are not matched: the taskboard parts are found by the mounting prior, and their
results stay as they were.)

This matching was Open3D's RANSAC, run three times at 100000 draws. It poses every draw before
it checks the draw's edges, and on a cluster the template is not in no pose ends the draws
early: the three runs took 1.2-1.8 s of CPU on a real mOSD click with PCL's milk carton as the
scanned template, where about 0.1% of the draws keep their edges. Checking the edges first, in
batches, answers 50000 draws in 10-20 ms. A second matching, of the template's descriptors to
the crop's (1500 crop points, its own RANSAC), went with it: it found no pose the cluster's
runs did not (the Armadillo in clutter, the Armadillo's views, the milk carton: the same found,
ranked and accepted without it), and it cost 180-240 ms a click.

What a scanned template costs a click here: the cluster's descriptors 50-90 ms (the click's,
not the template's: computed once a click context, :func:`_per_click`, and shared by every
scanned template of the library), the matching 50-60 ms, the RANSAC runs 30-60 ms.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..memo import per_object
from ..neighbours import pca_normals
from ..scene import ClickContext
from .solve import rigid_step

__all__ = ["global_alignments", "global_ransac"]

FEATURE_SAMPLES = 20000  #: a mesh template's samples its descriptors are computed on
NORMAL_NEIGHBOURS = 12  #: the normals of the cluster and of the thinned template
CHUNK = 250  #: poses whose inliers are counted at once

GLOBAL_RADIUS = 5.0  #: FPFH radius, in voxels
#: independent RANSAC runs, each one pose. Set on the Armadillo in clutter, 22 tuning clicks x
#: 8 generator seeds: a pose in the true one's basin (3 cm, 30 deg) on 176/176 from 3 runs,
#: on 170 from the 3 distinct best poses of one run (Open3D's 3 runs: 176)
GLOBAL_RUNS = 3
#: draws a run at the most (the same 22 x 8, 3 runs: 10000 174/176, 20000 175, 34000 176,
#: 50000 176, 100000 176)
GLOBAL_ITERATIONS = 50000
GLOBAL_DISTANCE = 1.5  #: a match within this many voxels is an inlier
GLOBAL_EDGE = 0.9  #: a draw's edges must agree to this ratio (Open3D's edge check)
GLOBAL_CONFIDENCE = 0.999  #: the draws stop when a better pose is this unlikely
#: fewer mutual matches than this share of the template's descriptors: all their matches are used
MUTUAL_SHARE = 0.1
FIRST_BATCH = 2000  #: the first batch of draws (then four times as many each)


def _per_click(ctx: ClickContext, what: str, compute):
    """``compute()`` (an array, made read-only: it is shared) once per click context: the
    scene's side of the matching, shared by the library's scanned templates."""

    def shared():
        value = compute()
        value.setflags(write=False)
        return value

    return per_object(ctx, ("features", what), shared)


def _fpfh(points: np.ndarray, normals: np.ndarray, radius: float) -> np.ndarray:
    """FPFH descriptors (N, 33) of points (N, 3) with unit normals (N, 3)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=100)
    feat = o3d.pipelines.registration.compute_fpfh_feature(cloud, param)
    return np.asarray(feat.data).T.copy()


def _template_features(model, voxel: float):
    """The model's surface described as the scene's cluster is: thinned to the mean of each
    occupied voxel (model frame), normals by PCA of ``NORMAL_NEIGHBOURS`` of those means
    (turned to the side of the file's normals), FPFH descriptors (``GLOBAL_RADIUS``); cached
    with the model. A scanned template gives every point of its file (it is a scan: its points
    are the surface), a mesh ``FEATURE_SAMPLES`` samples. The voxel grid is laid out in the
    template's axes about its centroid (``AffordanceTemplate.axes``), so the voxels do not
    depend on the frame its file is in, and their means do not depend on which sample came
    first in each. A voxel whose file normals cancel (two sides of a thin part; their mean
    shorter than 1/2) is left out."""

    def build():
        pts = model.template.points
        P, N = model.samples(FEATURE_SAMPLES if pts is None else len(pts))
        own = (P - model.centroid) @ model.axes
        keys = np.floor(own / voxel + 0.5).astype(np.int64)
        _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        inv = inv.ravel()

        def means(values):
            sums = [np.bincount(inv, values[:, k], len(counts)) for k in range(3)]
            return np.stack(sums, axis=1) / counts[:, None]

        P, N = means(P), means(N)
        length = np.linalg.norm(N, axis=1)
        keep = length > 0.5
        P, N = P[keep], N[keep] / length[keep, None]
        # the normals found as the scene's are (on the thinned points), on the file's side
        normals = pca_normals(P, NORMAL_NEIGHBOURS)
        normals[np.einsum("ij,ij->i", normals, N) < 0] *= -1
        return P, normals, _fpfh(P, normals, GLOBAL_RADIUS * voxel)

    key = ("fpfh", model.template, model.q, model.scale, float(voxel), GLOBAL_RADIUS)
    return model.cache.posed(key, build)


def _normals(ctx: ClickContext, points: np.ndarray, tree) -> np.ndarray:
    """Unit normals of ``points`` towards the sensor (away from their centre without one)."""
    normals = pca_normals(points, NORMAL_NEIGHBOURS, tree)
    if ctx.sensor_origin is not None:
        flip = np.einsum("ij,ij->i", normals, ctx.sensor_origin - points) < 0
    else:
        flip = np.einsum("ij,ij->i", normals, points - points.mean(axis=0)) < 0
    normals[flip] *= -1
    return normals


def _cluster_features(ctx: ClickContext):
    """The cluster's descriptors (normals towards the sensor, or away from the cluster's
    centre without one), once a click."""
    return _per_click(
        ctx,
        "cluster",
        lambda: _fpfh(
            ctx.cluster, _normals(ctx, ctx.cluster, ctx.cluster_tree), GLOBAL_RADIUS * ctx.voxel
        ),
    )


def _matched(F: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The descriptor matches (template indices, cluster indices): each template descriptor's
    nearest of the cluster's, kept where it is mutual -- or all of them where fewer than
    ``MUTUAL_SHARE`` of them are (Open3D's feature matching does the same)."""
    _, s2t = cKDTree(G).query(F)
    _, t2s = cKDTree(F).query(G)
    mutual = np.flatnonzero(t2s[s2t] == np.arange(len(F)))
    keep = mutual if len(mutual) >= MUTUAL_SHARE * len(F) else np.arange(len(F))
    return keep, s2t[keep]


def _kept_edges(src: np.ndarray, dst: np.ndarray, picks: np.ndarray) -> np.ndarray:
    """The draws (indices into ``picks`` (B, 3), pairs of ``src`` -> ``dst``) whose triangles
    have every edge of one within ``GLOBAL_EDGE`` of the other's both ways, none of zero
    length; an edge at a time, each on the draws the last one kept (most fail the first)."""
    kept = np.arange(len(picks))
    limit = GLOBAL_EDGE * GLOBAL_EDGE
    for a, b in ((0, 1), (1, 2), (2, 0)):
        i, j = picks[kept, a], picks[kept, b]
        dx, dq = src[i] - src[j], dst[i] - dst[j]
        ex, eq = np.einsum("ij,ij->i", dx, dx), np.einsum("ij,ij->i", dq, dq)
        kept = kept[(ex >= limit * eq) & (eq >= limit * ex) & (eq > 0)]
    return kept


def global_ransac(
    src: np.ndarray, dst: np.ndarray, rng: np.random.Generator, distance: float
) -> tuple | None:
    """The pose (R (3, 3), t (3,)) that brings the most matched pairs ``src`` -> ``dst`` (M, 3
    each) within ``distance`` (fewer squared errors on a tie), by RANSAC over three pairs: a
    draw is posed only where its edges agree to ``GLOBAL_EDGE`` both ways (a rigid motion keeps
    them) and every pair lands within ``distance``; the best pose's inliers are then fitted by
    least squares. The draws stop at ``GLOBAL_ITERATIONS`` or, as soon as the best pose's
    inlier share w makes it ``GLOBAL_CONFIDENCE`` sure that a better one would have been
    drawn, at log(1 - confidence) / log(1 - w^3) -- Open3D's criterion. Drawn in growing
    batches (``FIRST_BATCH``, four times larger each) and judged in draw order, so the answer
    is the one draw by draw would give; None when no draw holds. On a cluster the template is
    not in, few draws keep their edges (about 0.1%, measured on mOSD clicks with the milk
    carton's template), and the cost is the draws' edges."""
    M = len(src)
    best_count, best_rmse, best = 0, math.inf, None
    stop, done, batch = GLOBAL_ITERATIONS, 0, FIRST_BATCH
    while done < stop:
        n = min(batch, stop - done)
        picks = rng.integers(0, M, size=(n, 3))
        kept = _kept_edges(src, dst, picks)
        if len(kept):
            X, Q = src[picks[kept]], dst[picks[kept]]
            step = rigid_step(X, Q, np.ones((len(kept), 3)))
            posed = np.einsum("bij,bnj->bni", step.R, X) + step.t[:, None, :]
            near = np.all(np.linalg.norm(posed - Q, axis=2) <= distance, axis=1)
            kept, R, t = kept[near], step.R[near], step.t[near]
            for k in range(0, len(kept), CHUNK):
                d = np.linalg.norm(
                    np.einsum("bij,nj->bni", R[k : k + CHUNK], src)
                    + t[k : k + CHUNK, None, :]
                    - dst,
                    axis=2,
                )
                inl = d < distance
                counts = inl.sum(axis=1)
                sse = np.where(inl, d * d, 0.0).sum(axis=1)
                for j in range(len(counts)):
                    if done + kept[k + j] >= stop:
                        break
                    c = int(counts[j])
                    rmse = math.sqrt(sse[j] / c) if c else math.inf
                    if c > best_count or (c == best_count and c and rmse < best_rmse):
                        best_count, best_rmse, best = c, rmse, inl[j].copy()
                        w3 = (c / M) ** 3
                        need = (
                            0
                            if w3 >= 1.0
                            else math.ceil(math.log(1.0 - GLOBAL_CONFIDENCE) / math.log1p(-w3))
                        )
                        stop = min(stop, max(done + int(kept[k + j]) + 1, need))
        done += n
        batch *= 4
    if best is None:
        return None
    fit = rigid_step(src[best][None], dst[best][None], np.ones((1, best_count)))
    return fit.R[0], fit.t[0]


def global_alignments(ctx: ClickContext, model, rng: np.random.Generator) -> list:
    """Poses (R (3, 3), t (3,)), model -> scene, from matching the model's descriptors to the
    cluster's (:func:`_matched`): the best of each of ``GLOBAL_RUNS`` runs of
    :func:`global_ransac` over the matches, drawn from ``rng`` in turn; [] for a cluster too
    small to match."""
    if len(ctx.cluster) < 30:
        return []
    P, _, F = _template_features(model, ctx.voxel)
    mine, theirs = _matched(F, _cluster_features(ctx))
    runs = (
        global_ransac(P[mine], ctx.cluster[theirs], rng, GLOBAL_DISTANCE * ctx.voxel)
        for _ in range(GLOBAL_RUNS)
    )
    return [pose for pose in runs if pose is not None]
