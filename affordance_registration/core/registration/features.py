# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Initial poses from local shape features, for scanned (point-cloud) templates.

A scanned template is usually a large, free-standing object with no mounting base, and a click
may land anywhere on it (a leg of a statue): random restarts about the click rarely start ICP in
its basin. Here FPFH descriptors (Open3D) of the template's samples are matched to those of the
crop, and a RANSAC over three-point correspondences (drawn from a generator of their own, and
the descriptors -- normals towards the sensor -- do not depend on the scene's frame) proposes a
few distinct poses; they join the other initial hypotheses and compete in the same coarse
stage.

A second source matches the template's descriptors to the *cluster's* -- the points connected to
the click off the support, where an object touching others in clutter still has most of its own
points and a crop full of neighbours would outvote it: mutual nearest descriptors (all nearest
ones where too few are mutual), then a RANSAC of its own (:func:`global_ransac`: Open3D's
feature-matching RANSAC's checks and stopping rule, its draws from a seeded generator of its
own) whose ``GLOBAL_KEEP`` distinct best poses join the hypotheses. (Mesh templates use
neither source: the taskboard parts are found by the mounting prior, and their results stay as
they were.)

The cluster matching was Open3D's RANSAC, run three times (seeds 1-3, one pose each). It poses
every draw before it checks the draw's edges, and on a cluster the template is not in no pose
ends the draws early: the three runs took 1.2-1.8 s of CPU on a real mOSD click with PCL's
milk carton as the scanned template, where about 0.1% of the draws keep their edges. Checking
the edges first, in batches, answers the same draws in 20-30 ms each 100000; the distinct best
poses of one run replace the best of three runs, which found the same pose more often than
not. Found within 5 mm / 5 deg, the Armadillo in clutter, before -> after: 16/16 -> 16/16 on
8 tuning tables not tuned on (learn1, 5, 9, 15, 19, 25, 29, 35, seeds 0-1), 6/6 -> 6/6 on
learn0 and learn20, 12/12 -> 12/12 held out; their clicks' CPU 33.4 -> 21.8 s, 12.5 -> 7.7 s,
24.0 -> 15.9 s. What the carton's scanned template adds to 20 mOSD clicks: 1533 -> 301 ms.

What a scanned template costs a click besides: the crop's descriptors 140-190 ms (at the
MAX_PAIRS crop points that get a partner only, their neighbourhoods in the whole crop: the same
descriptors as the whole crop's there, which cost 200-280 ms), the cluster's 50-90 ms, the crop
matching's own RANSAC 30-50 ms. The scene's descriptors are the click's, not the template's:
they are computed once a click context (:func:`_per_click`) and shared by every scanned
template of the library.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..memo import per_object
from ..neighbours import pca_normals
from ..scene import ClickContext
from ..transforms import rotation_angle
from .solve import rigid_step

__all__ = ["feature_alignments", "global_alignments"]

FEATURE_RADIUS = 10.0  #: FPFH radius, in voxels
FEATURE_SAMPLES = 20000  #: a mesh template's samples its descriptors are computed on
NORMAL_NEIGHBOURS = 12  #: the normals of the crop, the cluster and the thinned template
RANSAC_TRIALS = 60000  #: three-point draws
EDGE_TOLERANCE = 0.1  #: a draw's edges must agree to this fraction (rigid)
INLIER_VOXELS = 2.0  #: a correspondence within this many voxels is an inlier
MAX_EVALUATED = 4000  #: rigid draws whose inliers are counted
MAX_PAIRS = 1500  #: at most this many crop points (evenly spread) get a partner
CHUNK = 250  #: hypotheses whose inliers are counted at once
#: distinct poses returned per template: a template of the Armadillo's other views holds only
#: half of view 60, and its true pose was among the best 4 on 1 of 6 seeds, the best 16 on 5
KEEP = 16
DISTINCT_TURN = math.radians(20.0)

GLOBAL_RADIUS = 5.0  #: FPFH radius of the cluster matching, in voxels
GLOBAL_SEED = 1  #: the cluster matching's RANSAC draws from a generator of this seed
#: the distinct best poses the cluster matching returns (it once took the best of three runs:
#: they found the same pose more often than not)
GLOBAL_KEEP = 3
GLOBAL_ITERATIONS = 100000  #: RANSAC draws per run
GLOBAL_DISTANCE = 1.5  #: a correspondence within this many voxels is an inlier
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


def _fpfh(points: np.ndarray, normals: np.ndarray, radius: float, at=None) -> np.ndarray:
    """FPFH descriptors (N, 33) of points (N, 3) with unit normals (N, 3); ``at``: of those
    points only (indices, (M, 33) -- the same descriptors, their neighbourhoods still in all
    the points)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=100)
    compute = o3d.pipelines.registration.compute_fpfh_feature
    feat = compute(cloud, param) if at is None else compute(cloud, param, np.asarray(at).tolist())
    return np.asarray(feat.data).T.copy()


def _template_features(model, voxel: float, radius: float = FEATURE_RADIUS):
    """The model's surface described as the scene's crop is: thinned to the mean of each
    occupied voxel (model frame), normals by PCA of ``NORMAL_NEIGHBOURS`` of those means
    (turned to the side of the file's normals), FPFH descriptors (``radius`` in voxels); cached
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
        return P, normals, _fpfh(P, normals, radius * voxel)

    key = ("fpfh", model.template, model.q, model.scale, float(voxel))
    return model.cache.posed(key if radius == FEATURE_RADIUS else key + (float(radius),), build)


def _normals(ctx: ClickContext, points: np.ndarray, tree) -> np.ndarray:
    """Unit normals of ``points`` towards the sensor (away from their centre without one)."""
    normals = pca_normals(points, NORMAL_NEIGHBOURS, tree)
    if ctx.sensor_origin is not None:
        flip = np.einsum("ij,ij->i", normals, ctx.sensor_origin - points) < 0
    else:
        flip = np.einsum("ij,ij->i", normals, points - points.mean(axis=0)) < 0
    normals[flip] *= -1
    return normals


def _scene_features(ctx: ClickContext):
    """The descriptors of the crop points :func:`_paired` names (normals towards the sensor,
    or away from the crop's centre without one; their neighbourhoods in the whole crop), once
    a click."""
    return _per_click(
        ctx,
        "crop",
        lambda: _fpfh(
            ctx.crop,
            _normals(ctx, ctx.crop, ctx.crop_tree),
            FEATURE_RADIUS * ctx.voxel,
            _paired(ctx),
        ),
    )


def _paired(ctx: ClickContext) -> np.ndarray:
    """The crop points (indices) that get a template partner: at most ``MAX_PAIRS``, evenly
    spread."""
    n = len(ctx.crop)
    return np.unique(np.linspace(0, n - 1, min(n, MAX_PAIRS)).astype(int))


def _cluster_features(ctx: ClickContext):
    """The cluster's descriptors for :func:`global_alignments`, once a click."""
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


def _distinct(R, t, R2, t2, centre: np.ndarray, reach: float) -> bool:
    """Two poses are distinct where they turn more than ``DISTINCT_TURN`` apart or move
    ``centre`` more than ``reach`` apart."""
    return (
        rotation_angle(R.T @ R2) > DISTINCT_TURN
        or np.linalg.norm(R @ centre + t - R2 @ centre - t2) > reach
    )


def global_ransac(
    src: np.ndarray,
    dst: np.ndarray,
    rng: np.random.Generator,
    distance: float,
    keep: int = 1,
    centre: np.ndarray | None = None,
    reach: float = 0.0,
) -> list:
    """Up to ``keep`` distinct poses (R (3, 3), t (3,)), best first, that bring the most
    matched pairs ``src`` -> ``dst`` (M, 3 each) within ``distance`` (fewer squared errors on a
    tie), by RANSAC over three pairs: a draw is posed only where its edges agree to
    ``GLOBAL_EDGE`` both ways (a rigid motion keeps them) and every pair lands within
    ``distance``; each kept pose's inliers are then fitted by least squares. Poses are
    :func:`_distinct` about ``centre`` (the model's) within ``reach``: of two that are not, the
    better stays (drawn, and again refined). The draws stop at ``GLOBAL_ITERATIONS`` or, as
    soon as the best pose's inlier share w makes it ``GLOBAL_CONFIDENCE`` sure that a better
    one would have been drawn, at log(1 - confidence) / log(1 - w^3) -- Open3D's criterion.
    Drawn in growing batches (``FIRST_BATCH``, four times larger each) and judged in draw
    order, so the answer is the one draw by draw would give; [] when no draw holds. On a
    cluster the template is not in, few draws keep their edges (about 0.1%, measured on mOSD
    clicks with the milk carton's template), and the cost is the draws' edges."""
    M = len(src)
    centre = np.zeros(3) if centre is None else centre
    tops: list = []  # [count, sse, inliers, R, t], best first

    def rank(entry):
        count, sse = entry[0], entry[1]
        return (-count, math.sqrt(sse / count))

    def offer(count, sse, inl, R, t) -> bool:
        """Keep the pose among ``tops`` where it belongs; True when it is the best now."""
        entry = [count, sse, inl, R, t]
        for i, other in enumerate(tops):
            if not _distinct(R, t, other[3], other[4], centre, reach):
                if rank(entry) >= rank(other):
                    return False
                tops[i] = entry
                break
        else:
            if len(tops) == keep and rank(entry) >= rank(tops[-1]):
                return False
            tops.append(entry)
        tops.sort(key=rank)
        del tops[keep:]
        return tops[0] is entry

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
                    if c and offer(c, float(sse[j]), inl[j], R[k + j], t[k + j]):
                        w3 = (c / M) ** 3
                        need = (
                            0
                            if w3 >= 1.0
                            else math.ceil(math.log(1.0 - GLOBAL_CONFIDENCE) / math.log1p(-w3))
                        )
                        stop = min(stop, max(done + int(kept[k + j]) + 1, need))
        done += n
        batch *= 4
    out = []
    for count, _, inl, _, _ in tops:  # refined, the poses are still distinct
        fit = rigid_step(src[inl][None], dst[inl][None], np.ones((1, count)))
        R, t = fit.R[0], fit.t[0]
        if all(_distinct(R, t, R2, t2, centre, reach) for R2, t2 in out):
            out.append((R, t))
    return out


def global_alignments(ctx: ClickContext, model) -> list:
    """Poses (R (3, 3), t (3,)), model -> scene, from matching the model's descriptors to the
    cluster's (:func:`_matched`): the ``GLOBAL_KEEP`` distinct best of :func:`global_ransac`
    over the matches; [] for a cluster too small to match."""
    if len(ctx.cluster) < 30:
        return []
    P, _, F = _template_features(model, ctx.voxel, GLOBAL_RADIUS)
    mine, theirs = _matched(F, _cluster_features(ctx))
    return global_ransac(
        P[mine],
        ctx.cluster[theirs],
        np.random.default_rng(GLOBAL_SEED),
        GLOBAL_DISTANCE * ctx.voxel,
        GLOBAL_KEEP,
        model.centroid,
        0.1 * model.diameter,
    )


def feature_alignments(ctx: ClickContext, model, rng: np.random.Generator) -> list:
    """Up to ``KEEP`` distinct poses (R (3, 3), t (3,)), model -> scene, that bring the model's
    descriptors onto the crop's with the most inliers, best first; [] when too few match."""
    if len(ctx.crop) < 10:
        return []
    P, _, F = _template_features(model, ctx.voxel)
    s_idx = _paired(ctx)
    if len(s_idx) < 6:
        return []
    # each paired crop point's nearest template descriptor (33-D: scipy's tree, not the
    # spatial one)
    _, i_sm = cKDTree(F).query(_scene_features(ctx))
    src, dst = P[i_sm], ctx.crop[s_idx]
    picks = rng.integers(0, len(src), size=(RANSAC_TRIALS, 3))
    X, Q = src[picks], dst[picks]
    ex = np.linalg.norm(X - np.roll(X, 1, axis=1), axis=2)
    eq = np.linalg.norm(Q - np.roll(Q, 1, axis=1), axis=2)
    rigid = np.all(np.abs(ex - eq) <= EDGE_TOLERANCE * np.maximum(eq, 1e-9), axis=1) & np.all(
        eq > 2 * ctx.voxel, axis=1
    )
    if not rigid.any():
        return []
    keep = np.flatnonzero(rigid)[:MAX_EVALUATED]
    step = rigid_step(X[keep], Q[keep], np.ones((len(keep), 3)))
    inliers = np.concatenate(
        [
            np.linalg.norm(
                np.einsum("bij,nj->bni", step.R[k : k + CHUNK], src)
                + step.t[k : k + CHUNK, None, :]
                - dst,
                axis=2,
            )
            <= INLIER_VOXELS * ctx.voxel
            for k in range(0, len(keep), CHUNK)
        ]
    )
    counts = inliers.sum(axis=1)
    out = []
    for k in np.argsort(-counts, kind="stable"):
        if counts[k] < 6 or len(out) >= KEEP:
            break
        inl = inliers[k]
        refined = rigid_step(src[inl][None], dst[inl][None], np.ones((1, int(inl.sum()))))
        R, t = refined.R[0], refined.t[0]
        if all(_distinct(R, t, R2, t2, model.centroid, 0.1 * model.diameter) for R2, t2 in out):
            out.append((R, t))
    return out
