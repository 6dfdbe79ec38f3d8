# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Correspondences of one ICP iteration: posed template samples paired with the nearest scene
points (forward), scene points paired with the nearest template surface (reverse), and a resting
template's lowest samples paired with the plane under the click (contact) -- each pair weighted
by the paper's rule with a scaled distance, :func:`correspondence_weights`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..compiled import NearestTree, kernels
from ..memo import per_object
from ..neighbours import nearest, tree_points
from ..scene import ClickContext
from ..transforms import pose_points
from .model import Batch, Model
from .settings import CLUSTER, REST_SAMPLES, FitSettings
from .visibility import visible

__all__ = [
    "Pairs",
    "correspondence_weights",
    "forward_pairs",
    "reverse_subset",
    "reverse_pairs",
    "reverse_rows",
    "contact_rows",
    "plane_gap",
    "in_contact",
    "stack_samples",
    "in_sphere",
    "compiled_tree",
    "PLANE_BAND",
]

PLANE_BAND = 1.5  #: samples within this many plane thresholds pair with the plane
CONTACT_BAND = 0.002  #: samples this close to the lowest one rest on the plane


def correspondence_weights(dist, reject, d0: float) -> np.ndarray:
    """The paper's correspondence rule: distances beyond ``reject`` are rejected (weight 0), the
    rest weigh w = 1 / (1 + d / d0). The paper has d0 = 1 (d in metres); the default method uses
    d0 = ``icp.weight_scale`` (5 mm), without which every useful d weighs about 1."""
    dist = np.asarray(dist, dtype=float)
    return np.where(dist <= reject, 1.0 / (1.0 + dist / d0), 0.0)


def stack_samples(models, n: int):
    """The ``n`` samples and normals of each model, (B, n, 3) each, model frames."""
    index: dict = {}  # a batch repeats few distinct models: each sampled once
    which = np.array([index.setdefault(id(m), (len(index), m))[0] for m in models])
    distinct = [m for _, m in index.values()]
    if len(distinct) == 1:
        P, N = distinct[0].samples(n)
        return np.broadcast_to(P, (len(models),) + P.shape).copy(), np.broadcast_to(
            N, (len(models),) + N.shape
        ).copy()
    samples = [m.samples(n) for m in distinct]
    return np.stack([s[0] for s in samples])[which], np.stack([s[1] for s in samples])[which]


def in_sphere(points: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Which of ``points`` (N, 3) lie within ``radius`` of ``centre`` (3,), (N,) bool."""
    rel = points - centre
    return np.einsum("ij,ij->i", rel, rel) <= radius * radius


def forward_pairs(
    ctx: ClickContext,
    target: str,
    X: np.ndarray,
    Nw: np.ndarray,
    radius: np.ndarray,
    settings: FitSettings,
    normals: bool,
):
    """Correspondences of posed samples X (B, S, 3) with normals Nw: the nearest ``target``
    point (Q), its normal when ``normals`` (Nq, else zeros) and the weight w (B, S) -- zero for
    unseen samples and beyond ``radius`` (B,)."""
    tree = ctx.cluster_tree if target == CLUSTER else ctx.fine_tree
    pts = tree_points(tree)
    shape = X.shape[:2]
    vis, _ = visible(ctx, X, Nw, settings)
    # flat rows, addressed by index: the samples nothing pairs with keep Q = X, d = inf
    Xf = X.reshape(-1, 3)
    dist = np.full(Xf.shape[0], np.inf)
    Q = Xf.copy()
    Nq = np.zeros_like(Xf)
    if ctx.plane is not None:
        # The plane band was removed from the targets; a sample in it corresponds to its
        # projection on the plane, which the sensor did observe (keeps tilt and height
        # constrained when the rest of the object is degenerate, e.g. a bar seen from above).
        pd = ctx.plane.distance(Xf)
        in_band = vis.reshape(-1) & (pd <= PLANE_BAND * ctx.plane_threshold)
        band = np.flatnonzero(in_band)
        pb = pd[band]
        dist[band] = np.abs(pb)
        Q[band] = Xf[band] - pb[:, None] * ctx.plane.normal
        if normals:
            Nq[band] = ctx.plane.normal
        rows = np.flatnonzero(vis.reshape(-1) & ~in_band)
    else:
        rows = np.flatnonzero(vis)
    # (only pairs within a hypothesis' radius weigh anything: the search stops at the largest
    # radius, and a sample with nothing there keeps a finite partner and a zero weight)
    if settings.icp.projective and ctx.range_image is not None:
        d_v, i_v = _projective(ctx, target, pts, Xf[rows])
    else:
        fast = compiled_tree(ctx, target)  # (the same neighbours, fewer calls' overhead)
        if fast is not None:
            d_v, i_v = fast.nearest(Xf[rows], float(radius.max()))
        else:
            d_v, i_v = nearest(tree, Xf[rows], float(radius.max()), parallel=True)
    dist[rows] = d_v
    Q[rows] = pts[i_v]
    if normals:
        Nq[rows] = ctx.fine_normals[i_v]
    dist = dist.reshape(shape)
    w = correspondence_weights(dist, radius[:, None], settings.icp.weight_scale)
    return Q.reshape(X.shape), Nq.reshape(X.shape), w


def compiled_tree(ctx: ClickContext, target: str) -> NearestTree | None:
    """The compiled KD-tree over the ``target`` points (:class:`..compiled.NearestTree`: the
    same neighbours as the click's own tree), kept with the click; None where the compiled
    kernels are not in use."""
    if kernels() is None:
        return None
    tree = ctx.cluster_tree if target == CLUSTER else ctx.fine_tree
    return per_object(ctx, ("compiled tree", target), lambda: NearestTree(tree_points(tree)))


def _projective(ctx: ClickContext, target: str, pts: np.ndarray, X: np.ndarray):
    """Projective correspondences (``icp.projective``): each of ``X`` (M, 3) paired with the
    ``target`` point (of ``pts``) the sensor sees nearest in its bin of the click's range image
    -- distance (M,), inf where the bin holds none, and that point's index (M,), as
    :func:`..neighbours.nearest` gives them."""
    image = ctx.range_image
    front = per_object(ctx, ("front points", target), lambda: image.front_points(pts))
    j = front[image.bins(X - image.origin)[0]]
    seen = j >= 0
    j = np.where(seen, j, 0)
    gap = X - pts[j]
    d = np.sqrt(np.einsum("ij,ij->i", gap, gap))
    return np.where(seen, d, np.inf), j


def reverse_subset(ctx: ClickContext, limit: int):
    """The full-resolution scene points (and normals) the fine stage pairs with the template:
    at most ``limit``, an even, fixed subset (the same one every iteration)."""
    pts, normals = ctx.fine, ctx.fine_normals
    if len(pts) > limit:
        pick = (np.arange(limit) * (len(pts) / limit)).astype(np.int64)
        pts, normals = pts[pick], normals[pick]
    return pts, normals


def reverse_pairs(
    model: Model,
    R: np.ndarray,
    t: np.ndarray,
    pts: np.ndarray,
    normals: np.ndarray,
    radius: float,
    d0: float,
):
    """Scene -> template pairs of one hypothesis (R (3, 3), t (3,)): each of the scene points
    ``pts`` (N, 3, with ``normals``) inside the posed model's bounding sphere paired with its
    nearest template surface sample. Returns (x: that sample in the scene (M, 3), q: the scene
    point (M, 3), n: its normal, w (M,), local: the sample in the model frame (M, 3), moving:
    whether it is on the moving part (M,))."""
    near = in_sphere(pts, R @ model.centroid + t, 0.5 * model.diameter)
    q = pts[near]
    d, local, moving = model.nearest((q - t) @ R, radius, parts=True)  # (beyond: weight 0)
    return (
        local @ R.T + t,
        q,
        normals[near],
        correspondence_weights(d, radius, d0),
        local,
        moving,
    )


@dataclass(frozen=True)
class Pairs:
    """The correspondences of a batch of B hypotheses, S rows each: the model side X and the
    scene side Q (B, S, 3), the scene normals N (zeros where a stage does not use them), the
    weights w (B, S; zero on padding). For the extra unknowns of the fine stage also the model
    side in the unscaled model frame U (B, S, 3) and whether it lies on the moving part
    (B, S) -- or None."""

    X: np.ndarray
    Q: np.ndarray
    N: np.ndarray
    w: np.ndarray
    U: np.ndarray | None = None
    moving: np.ndarray | None = None

    def joined(self, other: "Pairs") -> "Pairs":
        """These rows followed by ``other``'s (hypothesis by hypothesis)."""

        def cat(a, b):
            return None if a is None or b is None else np.concatenate([a, b], axis=1)

        return Pairs(
            cat(self.X, other.X),
            cat(self.Q, other.Q),
            cat(self.N, other.N),
            cat(self.w, other.w),
            cat(self.U, other.U),
            cat(self.moving, other.moving),
        )


def _padded(rows: list, fill=0.0) -> np.ndarray:
    """Ragged per-hypothesis rows (n_b, ...) stacked into (B, max n_b, ...), padded."""
    if len(rows) == 1:
        return np.asarray(rows[0])[None]  # one hypothesis: nothing to pad
    width = max(len(r) for r in rows)
    out = np.full((len(rows), width) + rows[0].shape[1:], fill, dtype=rows[0].dtype)
    for b, r in enumerate(rows):
        out[b, : len(r)] = r
    return out


def _pairs_of(rows: list) -> Pairs:
    """Pairs from per-hypothesis (X, Q, N, w, U, moving) rows of different lengths, padded
    with zero weights."""
    fills = (0.0, 0.0, 0.0, 0.0, 0.0, False)
    return Pairs(*(_padded([r[k] for r in rows], fill) for k, fill in enumerate(fills)))


def reverse_rows(ctx: ClickContext, batch: Batch, radius, settings: FitSettings) -> Pairs:
    """Scene -> template pairs (:func:`reverse_pairs`) of a batch of hypotheses against an even
    subset of at most ``fine.reverse_points`` full-resolution scene points, padded with zero
    weights."""
    pts, normals = reverse_subset(ctx, settings.fine.reverse_points)
    rows = []
    for b, m in enumerate(batch.models):
        x, q, n, w, local, moving = reverse_pairs(
            m, batch.R[b], batch.t[b], pts, normals, radius[b], settings.icp.weight_scale
        )
        rows.append((x, q, n, w, local / m.scale, moving))
    return _pairs_of(rows)


def contact_rows(ctx: ClickContext, forward: Pairs, radius, settings: FitSettings) -> Pairs:
    """Point-to-plane rows pairing each hypothesis' lowest forward samples (within
    ``CONTACT_BAND`` of the lowest, seen or not: the object hides them) with the plane under
    the click, padded with zero weights."""
    normal = ctx.plane.normal
    rows = []
    for b in range(len(forward.X)):
        pd = ctx.plane.distance(forward.X[b])
        low = np.flatnonzero(pd <= pd.min() + CONTACT_BAND)
        x = forward.X[b][low]
        rows.append(
            (
                x,
                x - pd[low][:, None] * normal,
                np.broadcast_to(normal, x.shape),
                correspondence_weights(np.abs(pd[low]), radius[b], settings.icp.weight_scale),
                forward.U[b][low],
                forward.moving[b][low],
            )
        )
    return _pairs_of(rows)


def plane_gap(ctx: ClickContext, batch: Batch, n: int) -> np.ndarray:
    """Signed distance (m) of each hypothesis' lowest of ``n`` samples from the plane under the
    click (positive: floating above it), (B,)."""
    P, _ = stack_samples(batch.models, n)
    X = pose_points(batch.R, batch.t, P)
    return ctx.plane.distance(X).min(axis=1)


def in_contact(ctx: ClickContext, model: Model, R, t, settings: FitSettings) -> bool:
    """Whether a pose rests on the plane under the click (its lowest sample within
    ``articulation.contact_distance`` of it)."""
    if ctx.plane is None:
        return False
    gap = plane_gap(ctx, Batch.single(model, R, t), REST_SAMPLES)[0]
    return abs(gap) <= settings.articulation.contact_distance
