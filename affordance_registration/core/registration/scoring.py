# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The residual a candidate is ranked by: two-way and capped -- template -> scene over the
samples the sensor could have seen (a free-space violation counts as the cap), scene cluster ->
template, and the click penalty (the operator clicked *on* the object). Its inverse is the
likelihood.

And the absolute verdict on a candidate, whatever the others score: its ``coverage`` (the
fraction of the template surface the sensor could have seen that has scan points within
``verdict.coverage_distance``) and ``inlier_rmse`` (the RMS distance of those covered samples);
below ``verdict.min_coverage`` no template fits here.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..neighbours import nearest_distances
from ..scene import ClickContext
from ..transforms import make_T, pose_points, rotate
from .correspondences import stack_samples
from .explains import object_tolerance
from .model import Batch, Model, surface_distances
from .parallel import over_batch, parts, run
from .results import FitResult
from .settings import FitSettings
from .visibility import visible

__all__ = [
    "forward_residual",
    "backward_residual",
    "click_penalty",
    "judge",
    "distinguished",
    "widening",
    "explained_share",
    "description_lengths",
    "parameters",
    "open_share",
    "self_hidden",
    "scores",
    "result",
    "results",
]

MIN_VISIBLE_SAMPLES = 3  #: fewer visible samples than this (or ...)
MIN_VISIBLE_FRACTION = 0.03  #: (... this fraction) and the forward residual is the cap
#: a return seen through a primitive lies inside it (an open object: a mug's inside) only
#: this far (m, or three times the scan's noise there) above its base face: the surface it
#: stands on, seen through a primitive with nothing in it, is not
BASE_CLEAR = 0.004
#: ... and only a primitive standing on the support is open (at its top): its z within about
#: 15 deg of the support's normal (the cosine)
OPEN_UPRIGHT = 0.966
#: a candidate whose covered samples lie on the dominant plane around the click for at least this
#: fraction covers the wall, not an object: those do not count towards its coverage
PLANE_COVERED = 0.8
#: the surface an object stands on (``ClickContext.plane``, the click off it) is solid: a
#: specific template with more than SOLID_SHARE of its samples more than SOLID_DEPTH object
#: tolerances behind it does not fit (on the simulated panels and tables, seeds 1000-1011 and
#: 2000-2007, no right fit has a sample that deep; the wrong ones that fitted, 2-9%; a tea
#: box read as an emergency stop, its button in the table: 17% deeper than 5 mm)
SOLID_DEPTH = 2.0
SOLID_SHARE = 0.01


def _forward_distances(
    ctx: ClickContext,
    batch: Batch,
    n: int,
    settings: FitSettings,
    occluded: np.ndarray | None = None,
):
    """The capped distances (B, n) from ``n`` posed samples of each hypothesis to the scene
    (free-space violations at the cap), which of the samples the sensor could have seen and
    which face it where it returned something (hidden or not; in the rows ``occluded`` marks,
    not where something else stands in front: :func:`.visibility.visible`)."""
    cap = settings.scoring.cap
    P, N = stack_samples(batch.models, n)
    X = pose_points(batch.R, batch.t, P)
    Nw = rotate(batch.R, N)
    vis, violated, exposed = visible(ctx, X, Nw, settings, exposed=True, occluded=occluded)
    dist = np.full(vis.shape, cap)
    dist[vis] = np.minimum(nearest_distances(ctx.crop_tree, X[vis], cap, owner=ctx), cap)
    dist[violated] = cap
    return dist, vis, exposed


def _forward(dist: np.ndarray, vis: np.ndarray, settings: FitSettings):
    """(forward residual, inlier fraction) of :func:`forward_residual` from the distances."""
    cap = settings.scoring.cap
    n_vis = vis.sum(axis=1)
    fwd = np.where(
        n_vis >= max(MIN_VISIBLE_SAMPLES, MIN_VISIBLE_FRACTION * dist.shape[1]),
        (dist * vis).sum(axis=1) / np.maximum(n_vis, 1),
        cap,
    )
    inl = ((dist < cap) & vis).sum(axis=1) / np.maximum(n_vis, 1)
    return fwd, inl


def forward_residual(ctx: ClickContext, batch: Batch, n: int, settings: FitSettings):
    """Template -> scene capped mean distance over ``n`` samples of each hypothesis, those the
    sensor could have seen (free-space violations count as the cap), and the fraction of them
    within the cap. (B,), (B,)."""
    dist, vis, _ = _forward_distances(ctx, batch, n, settings)
    return _forward(dist, vis, settings)


def judge(ctx: ClickContext, models, fits, settings: FitSettings) -> list:
    """Each of ``fits`` (a fit of the model at the same place in ``models``) with its absolute
    verdict: ``coverage`` -- of the template's ``scoring.samples`` samples that face the sensor
    where it returned something (hidden behind observed surfaces or not: a template sunk into a
    wall is not covered), not counting those its own parts hide, the fraction the sensor saw
    with scan points within ``verdict.coverage_distance`` -- not counting those on the dominant
    plane around the click when they are most of them (at least ``PLANE_COVERED``: a candidate
    covering a wall explains no object) -- ``inlier_rmse``, the RMS distance (m) of those
    covered samples, and ``fits``: coverage at least ``verdict.min_coverage``. Without a viewpoint
    every sample is exposed, and the bar is ``verdict.min_coverage_no_viewpoint``. The distances of
    all of them come from one pass (each candidate's numbers are its own)."""
    fits = list(fits)
    if not fits:
        return []
    T = np.stack([r.T_scene_model for r in fits])
    # a primitive is measured from what is seen of the object: the part something else hides
    # is not held against it; a specific template claims what it is, and is judged on all of
    # it the sensor faces
    primitive = np.array([m.template.primitive is not None for m in models])
    batch = Batch.of(models, T[:, :3, :3], T[:, :3, 3])
    dist, vis, exposed = _forward_distances(
        ctx, batch, settings.scoring.samples, settings, primitive
    )
    open_faces = _seen_into(ctx, models, batch, primitive, settings)
    vis &= ~open_faces
    exposed &= ~open_faces
    bar = (
        settings.verdict.min_coverage
        if ctx.sensor_origin is not None
        else settings.verdict.min_coverage_no_viewpoint
    )
    widen = widening(ctx, settings)
    covered_within = widen * settings.verdict.coverage_distance
    explained, object_bwd = _explained(
        ctx,
        models,
        T,
        widen * settings.verdict.explained_distance,
        settings.scoring.cap,
        settings.verdict.min_explained,
    )
    # the verdict's residual is the object's: template -> scene as ranked, object -> template
    # over the clicked object's points only (touching neighbours in the cluster are not the
    # template's to explain), plus the click penalty
    object_residual = 0.5 * (_forward(dist, vis, settings)[0] + object_bwd) + click_penalty(
        ctx, batch, settings
    )
    max_residual = widen * settings.verdict.max_residual
    solid_depth = SOLID_DEPTH * object_tolerance(ctx, settings)
    out = []
    for k, (model, res) in enumerate(zip(models, fits)):
        R, t = T[k, :3, :3], T[k, :3, 3]
        P = model.samples(settings.scoring.samples)[0]
        X = P @ R.T + t
        near = vis[k] & (dist[k] <= covered_within)
        if ctx.support is not None:
            on_plane = near & (np.abs(ctx.support.distance(X)) <= ctx.plane_threshold)
            if on_plane.sum() >= PLANE_COVERED * max(int(near.sum()), 1):
                near &= ~on_plane  # it covers the wall around the click, not an object
        seen = _seen(ctx, model, P, R, t, exposed[k], settings)
        n_exposed, n_near = int(seen.sum()), int((near & seen).sum())
        cov = n_near / n_exposed if n_exposed >= MIN_VISIBLE_SAMPLES else 0.0
        rmse = math.sqrt(float((dist[k][near & seen] ** 2).sum()) / max(n_near, 1))
        # (without a viewpoint nothing is known of what the sensor saw, the cluster's
        # segments nor the two-way residual's visibility: coverage alone judges there)
        seen_from = ctx.sensor_origin is not None
        obj_res = float(object_residual[k])
        why = [
            f"it covers {cov:.0%} of its visible surface (a fit needs {bar:.0%})"
            if cov < bar
            else "",
            f"it explains {explained[k]:.0%} of the clicked object's points (a fit needs "
            f"{settings.verdict.min_explained:.0%})"
            if seen_from and explained[k] < settings.verdict.min_explained
            else "",
            f"its surface and the object run {obj_res * 1e3:.1f} mm apart on average (a "
            f"fit is within {max_residual * 1e3:.1f} mm)"
            if seen_from and obj_res > max_residual
            else "",
        ]
        if not primitive[k] and ctx.plane is not None:
            above = ctx.plane.distance(X)
            if np.mean(above < -solid_depth) > SOLID_SHARE:
                why.append(
                    f"it would reach {-float(above.min()) * 1e3:.0f} mm into "
                    f"the surface the object stands on"
                )
        why = "; ".join(w for w in why if w)
        out.append(
            replace(
                res,
                coverage=cov,
                inlier_rmse=rmse,
                explained=float(explained[k]),
                object_residual=obj_res,
                noise=ctx.noise,
                fits=not why,
                reason=why or None,
            )
        )
    return out


def _seen_into(
    ctx: ClickContext, models, batch: Batch, primitive: np.ndarray, settings: FitSettings
) -> np.ndarray:
    """(B, S) bool: the samples of the primitives (rows ``primitive`` marks) standing upright
    on the support (their z within OPEN_UPRIGHT of its normal) through which the sensor saw
    into the primitive: on its top face, its return there, behind the sample by more than
    ``scoring.free_space_margin``, lies inside the posed primitive -- the object is open there
    (a mug's top). Those are neither held against its coverage nor its residual: the primitive is
    the object's hull. (A return beyond the primitive still is: it saw through the object.)"""
    image = ctx.range_image
    if image is None or ctx.support is None or not primitive.any():
        return np.zeros((len(primitive), settings.scoring.samples), bool)
    P, _ = stack_samples(batch.models, settings.scoring.samples)
    out = np.zeros(P.shape[:2], bool)
    for k in np.flatnonzero(primitive):
        R, t = batch.R[k], batch.t[k]
        if R[:, 2] @ ctx.support.normal < OPEN_UPRIGHT:  # (its normal faces the sensor)
            continue
        height = models[k].template.dimensions.get(
            "z", models[k].template.dimensions.get("length")
        )
        D = P[k] @ R.T + t - ctx.sensor_origin
        obs, depth = image.lookup_offsets(D)
        on_top = P[k][:, 2] >= height - 1e-6
        behind = (obs > depth + settings.scoring.free_space_margin) & on_top  # (NaN: False)
        if not behind.any():
            continue
        back = (ctx.sensor_origin + D[behind] * (obs[behind] / depth[behind])[:, None] - t) @ R
        into = np.zeros(len(D), bool)
        into[np.flatnonzero(behind)] = _inside(
            models[k].template, back, max(BASE_CLEAR, 3.0 * ctx.noise)
        )
        # an opening within a rim: the top's samples seen into lie inward of those that are
        # not (a stepped top -- a housing's shoulder round a button -- is the other way round)
        if not into.any():
            continue
        rim = _outwards(models[k].template, P[k][on_top & (obs == obs) & ~into])
        if len(rim) and np.median(_outwards(models[k].template, P[k][into])) >= np.median(rim):
            continue
        out[k] = into
    return out


def _outwards(template, q: np.ndarray) -> np.ndarray:
    """How far out on its top face each of ``q`` (N, 3, the primitive's frame) lies: 0 at the
    centre, 1 at the edge."""
    dims = template.dimensions
    if template.primitive == "box":
        return np.maximum(np.abs(q[:, 0]) / dims["x"], np.abs(q[:, 1]) / dims["y"]) * 2.0
    return np.hypot(q[:, 0], q[:, 1]) / dims["radius"]


def open_share(ctx: ClickContext, model: Model, T: np.ndarray, settings: FitSettings) -> float:
    """The share of the primitive ``model``'s samples, posed by ``T``, through which the
    sensor saw into it (:func:`_seen_into`): how open the object is (a mug seen from above)."""
    batch = Batch.of([model], T[None, :3, :3], T[None, :3, 3])
    return float(_seen_into(ctx, [model], batch, np.array([True]), settings).mean())


def _inside(template, q: np.ndarray, clear: float) -> np.ndarray:
    """Whether the points ``q`` (N, 3, in the primitive's frame) lie inside the primitive
    ``template`` at its dimensions, more than ``clear`` (m) above its base face (what it
    stands on, seen through an empty primitive, is not its inside)."""
    dims = template.dimensions
    if template.primitive == "box":
        return (
            (np.abs(q[:, 0]) <= dims["x"] / 2)
            & (np.abs(q[:, 1]) <= dims["y"] / 2)
            & (q[:, 2] > clear)
            & (q[:, 2] <= dims["z"])
        )
    return (
        (np.hypot(q[:, 0], q[:, 1]) <= dims["radius"])
        & (q[:, 2] > clear)
        & (q[:, 2] <= dims["length"])
    )


def widening(ctx: ClickContext, settings: FitSettings) -> float:
    """How much wider than the simulator's the verdict's distances are around this click: the
    scan's measured noise over ``verdict.noise_reference``, at least 1 (a noisier scan: wider)."""
    return max(1.0, ctx.noise / settings.verdict.noise_reference)


def explained_share(
    ctx: ClickContext, models, fits, settings: FitSettings, points: int | None = None
) -> np.ndarray:
    """The share (B,) of the clicked object's points each of ``fits`` (posed ``models``)
    explains, as :func:`judge` counts it (``FitResult.explained``), over an even, fixed
    subsample of at most ``points`` cluster points (None: all of them); all zero without a
    viewpoint (no segments)."""
    fits = list(fits)
    if ctx.sensor_origin is None or not fits:
        return np.zeros(len(fits))
    T = np.stack([r.T_scene_model for r in fits])
    return _explained(
        ctx,
        list(models),
        T,
        widening(ctx, settings) * settings.verdict.explained_distance,
        settings.scoring.cap,
        settings.verdict.min_explained,
        points,
    )[0]


def _seen(
    ctx: ClickContext,
    model: Model,
    P: np.ndarray,
    R,
    t,
    exposed: np.ndarray,
    settings: FitSettings,
) -> np.ndarray:
    """Which of the model's samples ``P`` (S, 3, model frame), posed at (R, t), face the
    sensor where it returned something (``exposed``, (S,) bool) and are not hidden by the
    model's own surface. (S,) bool."""
    seen = exposed.copy()
    rows = np.flatnonzero(seen)
    if ctx.sensor_origin is not None and len(rows):  # (only the exposed ones matter)
        seen[
            rows[
                self_hidden(
                    model,
                    P[rows],
                    R.T @ (ctx.sensor_origin - t),
                    settings.scoring.free_space_margin,
                )
            ]
        ] = False
    return seen


#: a specific template differs from a primitive where it shows the sensor at least this share
#: of its surface more than ``verdict.distinct_distance`` off the primitive's; less, and the scan
#: cannot tell them apart (the distinction test is not made)
DISTINCT_SHARE = 0.1


#: the description length is taken over an even subset of at most this many of the cluster's
#: points
DESCRIPTION_POINTS = 2000


def parameters(model: Model, res: FitResult) -> int:
    """How many numbers the candidate ``res`` (fitted as ``model``) sets: its pose's six, a
    primitive's dimensions, a template's joint values and its scale where it has a range."""
    tpl = model.template
    if tpl.primitive is not None:
        return 6 + len(res.dimensions or tpl.dimensions or {})
    return 6 + len(res.joints or {}) + (tpl.scale_range is not None)


def description_lengths(
    ctx: ClickContext, models, T: np.ndarray, k, settings: FitSettings
) -> tuple[np.ndarray, np.ndarray]:
    """How well and how simply each posed shape describes the clicked object -- one criterion
    for every kind of candidate: the description length (B,, nats) of the object's points given
    each of ``models`` posed by ``T`` (B, 4, 4) with ``k`` (B,) parameters (:func:`parameters`),
    and the share (B,) of those points the shape explains.

    The object's points, the same for all: of an even subset of at most DESCRIPTION_POINTS of
    the cluster's (N of them), those of the clicked segment and of every segment one of the
    shapes lies on for at least OBJECT_SEGMENT of its points (whole before part: a grab
    handle's posts, which a cylinder round its bar leaves out). The noise model is the
    verdict's: a point within the object tolerance ``tol`` of a shape's surface
    (:func:`.explains.object_tolerance`) is explained, anywhere in that band alike (within it
    the template's own deviations from the real object, not the sensor, set the distance: a
    tenth of a millimetre closer says nothing); one farther off is an outlier, anywhere in the
    crop. An outlier costs ln(radius / tol) nats more than an explained point, and each
    parameter ln(N) / 2 (BIC): a template explaining as much as a primitive wins by its fewer
    numbers, one leaving points of the object unexplained loses."""
    pts, labels = ctx.cluster, ctx.segments
    if len(pts) > DESCRIPTION_POINTS:
        pick = (np.arange(DESCRIPTION_POINTS) * (len(pts) / DESCRIPTION_POINTS)).astype(np.int64)
        pts, labels = np.take(pts, pick, axis=0), np.take(labels, pick)
    T = np.asarray(T, float)
    tol = object_tolerance(ctx, settings)
    local = (pts[None] - T[:, None, :3, 3]) @ T[:, :3, :3]
    on = surface_distances(list(models), local, 2.0 * tol) <= tol
    counts = np.maximum(np.bincount(labels, minlength=int(ctx.clicked_segment) + 1), 1)
    part = np.logical_or.reduce(
        [_object_segments(labels, row, ctx.clicked_segment, counts) for row in on]
    )
    on = on[:, part[labels]]
    n = max(on.shape[1], 1)
    outlier = math.log(max(ctx.radius / tol, 1.0))
    lengths = (~on).sum(axis=1) * outlier + 0.5 * np.asarray(k, float) * math.log(n)
    return lengths, on.mean(axis=1) if on.shape[1] else np.ones(len(T))


def distinguished(
    ctx: ClickContext,
    models,
    fits,
    primitive_model: Model,
    primitive_fit: FitResult,
    settings: FitSettings,
) -> list:
    """Each of ``fits`` (fitting specific candidates, their models in ``models``) tested against
    the primitive that fits the same click (``primitive_fit``, its model ``primitive_model``).
    It must describe the clicked object at least as well, by one criterion for both
    (:func:`description_lengths`): a template explaining as much of it as the primitive wins
    by its fewer numbers; one that leaves part of the object off its surface loses (an
    emergency stop's housing read into a lying can). And the samples of the
    candidate the sensor faces (as :func:`judge` counts them) that lie more
    than ``verdict.distinct_distance`` from the posed primitive's surface are what sets the
    template apart -- an emergency stop's button on a box's housing. When they are at least
    ``DISTINCT_SHARE`` of what it shows, at least ``verdict.min_distinct`` of them must be
    covered (within the verdict's widened ``coverage_distance``), or the candidate does not fit:
    the object is no more than the primitive. ``distinct`` is that share (None where the
    test is not made)."""
    fits = list(fits)
    if ctx.sensor_origin is None or not fits:
        return fits
    s = settings
    widen = widening(ctx, s)
    Tp = primitive_fit.T_scene_model
    T = np.stack([r.T_scene_model for r in fits])
    dist, vis, exposed = _forward_distances(
        ctx,
        Batch.of(models, T[:, :3, :3], T[:, :3, 3]),
        s.scoring.samples,
        s,
        np.zeros(len(fits), bool),
    )
    kind = primitive_fit.primitive
    lengths, explains = description_lengths(
        ctx,
        [*models, primitive_model],
        np.concatenate([T, Tp[None]]),
        [parameters(m, r) for m, r in zip(models, fits)]
        + [parameters(primitive_model, primitive_fit)],
        s,
    )
    out = []
    for k, (model, res) in enumerate(zip(models, fits)):
        why = []
        if lengths[k] > lengths[-1]:
            why.append(
                f"a {kind} describes the clicked object better: it explains "
                f"{explains[-1]:.0%} of its points, this {explains[k]:.0%}"
            )
        R, t = T[k, :3, :3], T[k, :3, 3]
        P = model.samples(s.scoring.samples)[0]
        X = P @ R.T + t
        seen = _seen(ctx, model, P, R, t, exposed[k], s)
        off = surface_distances(
            [primitive_model],
            ((X - Tp[:3, 3]) @ Tp[:3, :3])[None],
            2 * s.verdict.distinct_distance,
        )[0]
        distinct = seen & (off > s.verdict.distinct_distance)
        n = int(distinct.sum())
        share = None
        if n and n >= DISTINCT_SHARE * max(int(seen.sum()), 1):
            share = (
                float((distinct & vis[k] & (dist[k] <= widen * s.verdict.coverage_distance)).sum())
                / n
            )
            if share < s.verdict.min_distinct:
                why.append(
                    f"of its surface that a {kind} does not have, {share:.0%} is seen (a "
                    f"fit needs {s.verdict.min_distinct:.0%}): here it is no more than a "
                    f"{kind}"
                )
        if not why:
            out.append(res if share is None else replace(res, distinct=share))
            continue
        why = "; ".join(why)
        out.append(
            replace(
                res,
                distinct=share,
                fits=False,
                reason=f"{res.reason}; {why}" if res.reason else why,
            )
        )
    return out


#: nats: a shape whose description of the clicked object (:func:`description_lengths`) is this
#: much longer than another's that fits is decisively the worse description -- a difference in
#: BIC of 10 (twice the description length), "very strong" evidence on Kass and Raftery's
#: scale; not set on any data
DECISIVE_NATS = 5.0


def described(ctx: ClickContext, models, fits, settings: FitSettings) -> list:
    """``fits`` (primitives judged on one click, their models in ``models``) with each that
    fits refused where another that fits describes the clicked object decisively better: its
    description length (:func:`description_lengths`) more than ``DECISIVE_NATS`` shorter (a
    flat cylinder laid over one face of a box explains that face, not the box). Unchanged
    with fewer than two that fit, and without a viewpoint (no segments)."""
    fits, models = list(fits), list(models)
    fitting = [k for k, r in enumerate(fits) if r.fits]
    if ctx.sensor_origin is None or len(fitting) < 2:
        return fits
    lengths, explains = description_lengths(
        ctx,
        [models[k] for k in fitting],
        np.stack([fits[k].T_scene_model for k in fitting]),
        [parameters(models[k], fits[k]) for k in fitting],
        settings,
    )
    best = int(np.argmin(lengths))
    out = list(fits)
    for j, k in enumerate(fitting):
        if lengths[j] - lengths[best] > DECISIVE_NATS:
            r = fits[k]
            why = (
                f"a {fits[fitting[best]].primitive} describes the clicked object better: it "
                f"explains {explains[best]:.0%} of its points, this {explains[j]:.0%}"
            )
            out[k] = replace(r, fits=False, reason=f"{r.reason}; {why}" if r.reason else why)
    return out


#: a cluster segment of which at least this share lies on a candidate is part of the object
#: the candidate stands for (with the clicked segment); one that merely touches it (less) is a
#: neighbour
OBJECT_SEGMENT = 0.3
#: ... and within those segments, the smooth patches (``ClickContext.patches``: a box's face, a
#: can's side) of which less than this share lies on a specific template are a neighbour the
#: segment joined across their contact (a statue touching a box, one small patch of it meeting
#: the box's face convexly) where the template explains the rest to the verdict's bar -- the
#: clicked patch aside; else they count, as before. A template inside an object's points lies
#: on part of its faces (a valve in a box covers part of the face it sits in, more than this
#: share of it): that face counts. A primitive is held to all of its segments (they are what
#: it was measured from)
NEIGHBOUR_PATCH = 0.05


def _object_segments(labels: np.ndarray, on: np.ndarray, clicked: int, counts: np.ndarray):
    """Which segments (bool, one per count of ``counts``, each segment's number of points
    among ``labels``) are the object a shape stands for, the shape lying on the points ``on``
    (bool, one per label): the ``clicked`` one and those it lies on for at least
    OBJECT_SEGMENT of their points."""
    part = np.bincount(labels, weights=on, minlength=len(counts)) / counts >= OBJECT_SEGMENT
    part[clicked] = True
    return part


def _explained(
    ctx: ClickContext,
    models,
    T: np.ndarray,
    within: float,
    cap: float,
    bar: float,
    points: int | None = None,
):
    """The share (B,) of the clicked object's cluster points within ``within`` of each posed
    candidate's surface, and their capped mean distance to it (B,, m, capped at ``cap``). The
    object is the clicked segment of the cluster and every segment
    (``ClickContext.segments``) the candidate lies on for at least ``OBJECT_SEGMENT`` of its
    points: touching neighbours, and a sensor's mixed pixels bridging to them, do not count
    against a candidate; the rest of an object it is too small for does. A specific template
    that explains less than ``bar`` of that, but at least ``bar`` of it without the smooth
    patches it does not come near (``NEIGHBOUR_PATCH``), is judged on the latter: they are a
    neighbour the segment joined. ``points``: over an even, fixed subsample of at most that
    many cluster points (None: all)."""
    pts, labels, patches = ctx.cluster, ctx.segments, ctx.patches
    clicked = ctx.clicked_segment
    clicked_patch = ctx.clicked_patch
    if points is not None and len(pts) > points:
        pick = (np.arange(points) * (len(pts) / points)).astype(np.int64)
        pts, labels, patches = pts[pick], labels[pick], patches[pick]
    local = (pts[None] - T[:, None, :3, 3]) @ T[:, :3, :3]  # (B, K, 3) model frames
    dist = np.minimum(surface_distances(list(models), local, max(cap, within * 2)), cap)
    on = dist <= within
    counts = np.maximum(np.bincount(labels, minlength=int(clicked) + 1), 1)
    patch_counts = np.maximum(np.bincount(patches, minlength=clicked_patch + 1), 1)
    share_on, mean_d = np.empty(len(T)), np.empty(len(T))
    for k in range(len(T)):
        mine = _object_segments(labels, on[k], clicked, counts)[labels]
        if not mine.any():  # (a subsample without the clicked segment: unknown)
            share_on[k], mean_d[k] = 1.0, 0.0
            continue
        share_on[k], mean_d[k] = float(on[k][mine].mean()), float(dist[k][mine].mean())
        if models[k].template.primitive is None and share_on[k] < bar:
            near = (
                np.bincount(patches, weights=on[k], minlength=len(patch_counts)) / patch_counts
                >= NEIGHBOUR_PATCH
            )
            near[clicked_patch] = True
            own = mine & near[patches]
            if own.any() and on[k][own].mean() >= bar:
                share_on[k], mean_d[k] = float(on[k][own].mean()), float(dist[k][own].mean())
    return share_on, mean_d


def self_hidden(model: Model, P: np.ndarray, origin: np.ndarray, margin: float) -> np.ndarray:
    """Which of the model's samples P (S, 3, model frame) its own surface hides from a sensor
    at ``origin`` (3, model frame): the ray to the sample meets the mesh more than ``margin``
    before it. (S,) bool; none for a point-cloud template."""
    scene = model.raycaster()
    if scene is None:
        return np.zeros(len(P), bool)
    import open3d as o3d

    d = P - origin
    length = np.linalg.norm(d, axis=1)
    rays = np.concatenate([np.broadcast_to(origin, P.shape), d / length[:, None]], axis=1)
    hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    return hit < length - margin


def backward_residual(
    ctx: ClickContext, batch: Batch, settings: FitSettings, cluster_points: int | None = None
) -> np.ndarray:
    """Scene cluster -> template: the capped mean distance (B,) from the cluster points to
    each posed model's surface (points no sample explains count as the cap, so a template that
    leaves part of the object unexplained pays for it), on an even, fixed subsample of at most
    ``cluster_points`` of them (None: all)."""
    cap = settings.scoring.cap
    pts = ctx.cluster
    if cluster_points is not None and len(pts) > cluster_points:
        pts = pts[np.linspace(0, len(pts) - 1, cluster_points).astype(int)]
    local = (pts[None] - batch.t[:, None, :]) @ batch.R  # (B, K, 3), model frames
    return np.minimum(surface_distances(batch.models, local, cap), cap).mean(axis=1)


def click_penalty(ctx: ClickContext, batch: Batch, settings: FitSettings) -> np.ndarray:
    """The operator clicked on the object: a candidate whose surface passes farther than
    ``scoring.click_tolerance`` from the (snapped) click pays the excess, up to ``scoring.cap``.
    (B,)"""
    local = np.einsum("bji,bj->bi", batch.R, ctx.click - batch.t)  # click in model frames
    d = surface_distances(batch.models, local[:, None, :])[:, 0]
    return np.clip(d - settings.scoring.click_tolerance, 0.0, settings.scoring.cap)


def scores(
    ctx: ClickContext, batch: Batch, settings: FitSettings, samples: int, cluster_points: int
) -> np.ndarray:
    """The two-way capped residual plus the click penalty of a batch of hypotheses (B,):
    template -> scene on ``samples`` template samples, cluster -> template on an even
    subsample of ``cluster_points`` cluster points. A big batch is scored in parts side by
    side."""
    return np.concatenate(
        over_batch(
            lambda part: _scores(ctx, part, settings, samples, cluster_points),
            batch,
            settings.threads,
        )
    )


def _scores(
    ctx: ClickContext, batch: Batch, settings: FitSettings, samples: int, cluster_points: int
) -> np.ndarray:
    fwd, _ = forward_residual(ctx, batch, samples, settings)
    bwd = backward_residual(ctx, batch, settings, cluster_points)
    return 0.5 * (fwd + bwd) + click_penalty(ctx, batch, settings)


def result(
    ctx: ClickContext,
    model: Model,
    R,
    t,
    settings: FitSettings,
    iterations: int = 0,
    converged: bool | None = None,
) -> FitResult:
    """The candidate ``model`` at (R, t): its residual (two-way, capped, plus the click
    penalty), likelihood, inlier fraction and, for an articulated model, joints, scale and
    the nearest named state; ``iterations`` and ``converged`` as ICP reported them."""
    return results(
        ctx,
        Batch.single(model, R, t),
        settings,
        iterations,
        None if converged is None else [converged],
    )[0]


def results(
    ctx: ClickContext, batch: Batch, settings: FitSettings, iterations: int = 0, converged=None
) -> list:
    """:func:`result` of every hypothesis of a batch (scored together; a big batch in parts
    side by side), ``converged`` (B,) or None."""
    conv = None if converged is None else np.asarray(converged, dtype=bool)
    done = run(
        [
            lambda idx=idx: _results(
                ctx, batch.take(idx), settings, iterations, None if conv is None else conv[idx]
            )
            for idx in parts(len(batch), settings.threads)
        ],
        settings.threads,
    )
    return [r for part in done for r in part]


def _results(
    ctx: ClickContext, batch: Batch, settings: FitSettings, iterations: int, converged
) -> list:
    fwd, inl = forward_residual(ctx, batch, settings.scoring.samples, settings)
    bwd = backward_residual(ctx, batch, settings)
    click = click_penalty(ctx, batch, settings)
    out = []
    for k, model in enumerate(batch.models):
        residual = max(0.5 * (float(fwd[k]) + float(bwd[k])) + float(click[k]), 1e-6)
        joints = model.joints
        out.append(
            FitResult(
                template=model.name,
                T_scene_model=make_T(batch.R[k], batch.t[k]),
                residual=residual,
                likelihood=1.0 / residual,
                inlier_fraction=float(inl[k]),
                iterations=int(iterations),
                joints=joints,
                scale=model.scale if model.articulated else 1.0,
                state=model.template.nearest_state(joints) if joints else None,
                converged=None if converged is None else bool(converged[k]),
            )
        )
    return out
