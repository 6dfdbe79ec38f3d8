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
points and a crop full of neighbours would outvote it: Open3D's feature-matching RANSAC
(mutual nearest descriptors, edge-length and distance checks), run ``GLOBAL_RUNS`` times with
fixed seeds, each run's pose joining the hypotheses. Open3D's RANSAC draws from its global
generator, seeded before each run under a lock, so the poses depend on the input only.
Cost: about 0.7 s per run on the 4500-6000-point clusters of the Armadillo in clutter
(``GLOBAL_ITERATIONS`` draws, 2 shared cores; 0.45 s at 10000 draws, which found the pose in
too few runs). (Mesh templates use neither source: the taskboard parts are found by the
mounting prior, and their results stay as they were.)

What a scanned template costs a click (a real mOSD click with PCL's milk carton as the one
scanned template, CPU): the three RANSAC runs about 0.9-1.0 s, the crop's descriptors 145-175
ms (at the MAX_PAIRS crop points that get a partner only, their neighbourhoods in the whole
crop: the same descriptors as the whole crop's there, which cost 200-280 ms) and the
cluster's 68-159 ms, the crop matching's own RANSAC 30-50 ms. The scene's descriptors are the
click's, not the template's: they are computed once a click context (:func:`_per_click`) and
shared by every scanned template of the library.
"""

from __future__ import annotations

import math
import threading

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
GLOBAL_RUNS = (1, 2, 3)  #: the seeds of the cluster matching's RANSAC runs (one pose each)
GLOBAL_ITERATIONS = 100000  #: RANSAC draws per run
GLOBAL_DISTANCE = 1.5  #: a correspondence within this many voxels is an inlier
GLOBAL_EDGE = 0.9  #: a draw's edges must agree to this ratio (Open3D's edge check)
_o3d_lock = threading.Lock()


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


def global_alignments(ctx: ClickContext, model) -> list:
    """Poses (R (3, 3), t (3,)), model -> scene, from Open3D's feature-matching RANSAC of the
    model's descriptors to the cluster's, one per seed of ``GLOBAL_RUNS``; [] for a cluster
    too small to match."""
    if len(ctx.cluster) < 30:
        return []
    import open3d as o3d

    reg = o3d.pipelines.registration
    P, N, F = _template_features(model, ctx.voxel, GLOBAL_RADIUS)
    Q = ctx.cluster
    G = _cluster_features(ctx)

    def cloud(points, normals):
        out = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(points, float)))
        out.normals = o3d.utility.Vector3dVector(np.array(normals, float))
        return out

    def feature(desc):
        out = reg.Feature()
        out.data = np.ascontiguousarray(desc.T)
        return out

    src, dst = cloud(P, N), cloud(Q, np.zeros_like(Q))
    fs, fd = feature(F), feature(G)
    dist = GLOBAL_DISTANCE * ctx.voxel
    checks = [
        reg.CorrespondenceCheckerBasedOnEdgeLength(GLOBAL_EDGE),
        reg.CorrespondenceCheckerBasedOnDistance(dist),
    ]
    out = []
    for seed in GLOBAL_RUNS:
        # the generator is Open3D's global one; its "too few mutual matches, all matches
        # used" warning is no news to the user
        with _o3d_lock, o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            o3d.utility.random.seed(int(seed))
            found = reg.registration_ransac_based_on_feature_matching(
                src,
                dst,
                fs,
                fd,
                True,
                dist,
                reg.TransformationEstimationPointToPoint(False),
                3,
                checks,
                reg.RANSACConvergenceCriteria(GLOBAL_ITERATIONS, 0.999),
            )
        T = np.asarray(found.transformation, dtype=float)
        if found.fitness > 0 and np.all(np.isfinite(T)):
            out.append((T[:3, :3].copy(), T[:3, 3].copy()))
    return out


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
        if all(
            rotation_angle(R.T @ R2) > DISTINCT_TURN
            or np.linalg.norm(R @ model.centroid + t - R2 @ model.centroid - t2)
            > 0.1 * model.diameter
            for R2, t2 in out
        ):
            out.append((R, t))
    return out
