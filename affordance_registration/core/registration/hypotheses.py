# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Where ICP starts: initial hypotheses around the click for every template, the library
prefilter after the coarse stage, the distinct best few kept per template, and the winner's
sweep about its mounting axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..scene import ClickContext
from ..templates import AffordanceTemplate
from ..transforms import align_z_to, axis_angle_matrix, make_T, rotation_angle, unit_quaternions
from .features import global_alignments
from .model import Batch
from .results import FitResult, IcpResult
from .settings import REST_SAMPLES, SAMPLE_SEED, FitSettings

__all__ = [
    "Hypotheses",
    "MOUNTED",
    "RESTING",
    "RANDOM",
    "initial_hypotheses",
    "prefilter",
    "keep_distinct",
    "best_per_template",
    "yaw_sweep_starts",
    "principal_angle",
    "symmetric_angle",
]

RANDOM_OFFSET = 0.15  #: random restarts start up to this fraction of the diameter off
DISTINCT_DISTANCE = 0.01  #: hypotheses of one template closer than this ...
DISTINCT_ANGLE = math.radians(10.0)  #: ... and turned less than this count as one
ELONGATED = 1.44  #: main axis: in-plane spreads at least this far apart (20% in std)

MOUNTED, RESTING, RANDOM = 0, 1, 2  #: families of initial hypotheses
#: a click off an object's middle: where the clicked segment of the cluster (no larger than
#: SEGMENT_REACH x a template's radius) has its mean more than CENTRE_SHIFT x the template's
#: diameter from the centre the click gives, the yaw sweeps start over that mean too
SEGMENT_REACH = 1.1
CENTRE_SHIFT = 0.1
FEATURE_SEED = 4099  #: the feature matching draws from ``[settings.seed, FEATURE_SEED]``


@dataclass(frozen=True)
class Hypotheses(Batch):
    """A batch of B poses: ``models`` (B, what each fits), ``R`` (B, 3, 3) and ``t`` (B, 3)
    model -> scene, ``index`` (B,) which of the given templates each is of, ``family`` (B,)
    MOUNTED, RESTING or RANDOM; the ICP iterations run on them so far and which converged in
    the last stage ((B,) bool, or None before any)."""

    index: np.ndarray
    family: np.ndarray
    iterations: int = 0
    converged: np.ndarray | None = None

    def take(self, idx) -> "Hypotheses":
        """The hypotheses at ``idx`` (an index array), in that order."""
        idx = np.asarray(idx, dtype=int)
        return Hypotheses(
            tuple(self.models[i] for i in idx),
            self.R[idx],
            self.t[idx],
            self.index[idx],
            self.family[idx],
            self.iterations,
            None if self.converged is None else self.converged[idx],
        )

    def after(self, stage: IcpResult) -> "Hypotheses":
        """The same hypotheses as an ICP stage left them."""
        return Hypotheses(
            stage.models,
            stage.R,
            stage.t,
            self.index,
            self.family,
            self.iterations + stage.iterations,
            stage.converged,
        )

    def relabelled(self, index_of: np.ndarray) -> "Hypotheses":
        """The same hypotheses with ``index`` mapped through ``index_of`` (e.g. from the
        models they started from to the templates those are of)."""
        return Hypotheses(
            self.models,
            self.R,
            self.t,
            np.asarray(index_of)[self.index],
            self.family,
            self.iterations,
            self.converged,
        )


def initial_hypotheses(
    ctx: ClickContext, models, settings: FitSettings, rng: np.random.Generator
) -> Hypotheses:
    """Initial hypotheses for each of ``models`` (anything with ``samples``, ``centroid``,
    ``diameter`` and ``resting_rotations``: a registration model or a template).

    With a plane under the click: mounted (the template's mount's +z along the plane normal, a
    yaw sweep; modes auto and mounted), resting (each stable facet of the template down on the
    plane, a yaw sweep; modes auto and free) and uniformly random orientations resting on the
    plane. Every orientation is drawn in the template's ``axes`` (its mount's, or without one
    its surface's own: a template with no mount is "mounted" with its least-spread axis along
    the normal), so the hypotheses turn with the frame its file is written in.
    Without a plane: uniformly random orientations around the cluster (drawn in the frame
    attached to the scan, ``ctx.frame``, so they do not depend on the scene's frame). The
    template's centroid starts over the cluster points within reach of the click (the cluster may
    have merged with a neighbour) -- and the yaw sweeps also over the clicked segment's middle
    where the click is off it (:func:`_segment_middle`); random ones get an offset of up to
    ``RANDOM_OFFSET`` of the diameter (the paper's restarts use up to the diameter). A
    point-cloud template (a scanned object) also starts from the poses its shape features
    match in the cluster (:mod:`.features`)."""
    up = cluster_axis = None
    if ctx.plane is not None:  # the plane's frame (turns with the scan) and the cluster's
        up = align_z_to(ctx.plane.normal, hint=ctx.frame[:, 0])  # main axis in it
        cluster_axis = principal_angle(ctx.cluster @ up)
    # every template's draws in turn, then the rotations of all of them composed at once
    draws = [_draws(ctx, model, settings, rng, cluster_axis) for model in models]
    yawed = random = None
    if any(len(d.yaws) for d in draws):
        yawed = (
            up
            @ _about_z(np.concatenate([d.yaws for d in draws]))
            @ np.concatenate([d.bases for d in draws])
        )
    if any(len(d.quats) for d in draws):  # drawn in the frame attached to the scan
        random = (
            ctx.frame @ Rotation.from_quat(np.concatenate([d.quats for d in draws])).as_matrix()
        )
        shifted = np.concatenate([d.offsets for d in draws]) @ ctx.frame.T
    index, Rs, ts, family = [], [], [], []
    n_yawed = n_random = 0
    for i, (model, d) in enumerate(zip(models, draws)):
        centre = ctx.cluster_mean_near(ctx.click, 0.5 * model.diameter)
        if centre is None:
            centre = ctx.click
        k, n = len(d.yaws), len(d.quats)
        R0 = [yawed[n_yawed : n_yawed + k]] if k else []
        offsets = [np.zeros((k, 3))]
        if n:
            R0.append(random[n_random : n_random + n])
            offsets.append(shifted[n_random : n_random + n])
        n_yawed, n_random = n_yawed + k, n_random + n
        if d.aligned:
            R0.append(np.stack(d.aligned))
            offsets.append(np.zeros((len(d.aligned), 3)))
        R0 = np.concatenate(R0) if R0 else np.empty((0, 3, 3))
        A = model.axes  # drawn in the template's axes: its mount's, or its surface's own
        if not np.array_equal(A, np.eye(3)):
            R0[: k + n] = R0[: k + n] @ A.T
        index.append(np.full(len(R0), i))
        Rs.append(R0)
        ts.append(_starts(ctx, model, R0, centre, np.concatenate(offsets)))
        family.append(np.concatenate([d.families, np.full(len(R0) - k, RANDOM)]))
        middle = _segment_middle(ctx, model, centre) if k else None
        if middle is not None:  # the sweeps again, over the clicked object's middle
            index.append(np.full(k, i))
            Rs.append(R0[:k])
            ts.append(_starts(ctx, model, R0[:k], middle, np.zeros((k, 3))))
            family.append(d.families)
        if getattr(getattr(model, "template", model), "is_point_template", False):
            # a scanned object: poses from matched shape features too (their own generator,
            # so the other templates' draws stay as they are)
            features = np.random.default_rng([settings.seed, FEATURE_SEED])
            matched = global_alignments(ctx, model, features)
            if matched:
                index.append(np.full(len(matched), i))
                Rs.append(np.stack([R for R, _ in matched]))
                ts.append(np.stack([t for _, t in matched]))
                family.append(np.full(len(matched), RANDOM))
    index = np.concatenate(index)
    return Hypotheses(
        tuple(models[i] for i in index),
        np.concatenate(Rs),
        np.concatenate(ts),
        index,
        np.concatenate(family),
    )


def _segment_middle(ctx: ClickContext, model, centre: np.ndarray) -> np.ndarray | None:
    """The mean (3,) of the clicked segment of the cluster (``ClickContext.segments``) where
    the template's centroid could lie there and the click's ``centre`` does not: the segment
    lies within ``SEGMENT_REACH`` x the template's radius of its mean, which is more than
    ``CENTRE_SHIFT`` x its diameter from ``centre`` (a handle clicked near one end: the cluster
    points within reach of the click are mostly that end's). None otherwise."""
    middle, reach = ctx.clicked_spread
    if np.linalg.norm(middle - centre) <= CENTRE_SHIFT * model.diameter:
        return None
    return middle if reach <= SEGMENT_REACH * 0.5 * model.diameter else None


@dataclass(frozen=True)
class _Draws:
    """One template's draws: yaws (K,) about the plane's normal with the orientations they
    turn (K, 3, 3) and their families (K,); random rotations as unit quaternions (n, 4) with
    their offsets (n, 3, in the frame attached to the scan); the principal-axes alignments
    (rotations, without a plane)."""

    yaws: np.ndarray
    bases: np.ndarray
    families: np.ndarray
    quats: np.ndarray
    offsets: np.ndarray
    aligned: list


def _draws(
    ctx: ClickContext,
    model,
    settings: FitSettings,
    rng: np.random.Generator,
    cluster_axis: float | None,
) -> _Draws:
    """One template's initial orientations, drawn from ``rng`` in their order: mounted and
    resting yaw sweeps (with a plane), random rotations and offsets, principal axes (without
    one). ``cluster_axis``: the cluster's main axis in the plane's frame
    (:func:`principal_angle`)."""
    s, plane = settings, ctx.plane
    yaws, bases, families = [], [], []
    if plane is not None:
        # yaws about the plane's normal, each with the template's orientation it turns:
        # identity (mounted) or a resting facet
        if s.mode in ("auto", "mounted"):
            yaws.append(_yaws(s.hypotheses.yaw_restarts, rng))
            bases.append(np.broadcast_to(np.eye(3), (s.hypotheses.yaw_restarts, 3, 3)))
            families.append(np.full(s.hypotheses.yaw_restarts, MOUNTED))
        if s.mode in ("auto", "free"):
            for R_rest, tpl_axis in _resting_axes(model, s.hypotheses.resting_poses):
                if s.mode == "auto" and R_rest[2, 2] > 0.95:
                    continue  # the mounted orientation (of the axes), already swept
                facet = list(_yaws(s.hypotheses.resting_yaws, rng))
                # and the two yaws that line the resting template's long axis up with the
                # cluster's (elongated parts lying on a table)
                if cluster_axis is not None and tpl_axis is not None:
                    facet += [cluster_axis - tpl_axis, cluster_axis - tpl_axis + math.pi]
                if facet:
                    yaws.append(np.array(facet))
                    bases.append(np.broadcast_to(R_rest, (len(facet), 3, 3)))
                    families.append(np.full(len(facet), RESTING))
    n_rand = (
        0
        if s.mode == "mounted" and plane is not None
        else (s.hypotheses.random_restarts if plane is not None else s.hypotheses.free_restarts)
    )
    quats, off = np.empty((0, 4)), np.empty((0, 3))
    if n_rand:
        off = rng.normal(size=(n_rand, 3))
        off *= (
            RANDOM_OFFSET
            * model.diameter
            * rng.uniform(size=(n_rand, 1)) ** (1 / 3)
            / np.linalg.norm(off, axis=1, keepdims=True)
        )
        quats = unit_quaternions(n_rand, rng)
    aligned = _principal_alignments(ctx.cluster, model) if plane is None else []
    return _Draws(
        np.concatenate(yaws) if yaws else np.empty(0),
        np.concatenate(bases) if bases else np.empty((0, 3, 3)),
        np.concatenate(families) if families else np.empty(0, dtype=int),
        quats,
        off,
        aligned,
    )


def _resting_axes(model, max_poses: int) -> list:
    """The model's resting rotations R_rest (3, 3), of its ``axes`` (what turns them so the
    facet faces down: the template frame's R_rest is R_rest @ axes.T), with the main-axis angle
    of its samples turned by each (:func:`principal_angle`, rad or None): [(R_rest, angle)];
    computed once per registration model (a template is asked each time)."""

    def compute():
        low = model.samples(REST_SAMPLES, seed=SAMPLE_SEED)[0]
        rests = [R for R, _ in model.resting_rotations(max_poses)]
        angles = [principal_angle(low @ R.T) for R in rests]
        A = model.axes
        if not np.array_equal(A, np.eye(3)):
            rests = [R @ A for R in rests]
        return (
            np.array(rests).reshape(-1, 3, 3),
            np.array([np.nan if a is None else a for a in angles], dtype=float),
        )

    cache = getattr(model, "cache", None)
    rests, angles = (
        compute()
        if cache is None
        else cache.posed(
            (
                "resting axes",
                model.template,
                model.q,
                model.scale,
                model.moving_only,
                int(max_poses),
            ),
            compute,
        )
    )
    return [(R, None if math.isnan(a) else float(a)) for R, a in zip(rests, angles)]


def _principal_axes(points: np.ndarray) -> np.ndarray:
    """The principal axes of ``points`` (N, 3) as the columns of a rotation, largest spread
    first."""
    rel = points - points.mean(axis=0)
    axes = np.linalg.eigh(rel.T @ rel)[1][:, ::-1]
    axes[:, 2] = np.cross(axes[:, 0], axes[:, 1])
    return axes


def _principal_alignments(cluster: np.ndarray, model) -> list:
    """The four rotations (proper: two axes flipped at a time) that put the model's principal
    axes on the cluster's -- a big free object seen whole is often found from one of them."""
    if len(cluster) < 10:
        return []
    A = _principal_axes(cluster)
    B = _principal_axes(model.samples(REST_SAMPLES, seed=SAMPLE_SEED)[0])
    return [A @ np.diag(f) @ B.T for f in ((1, 1, 1), (-1, -1, 1), (-1, 1, -1), (1, -1, -1))]


def _about_z(angles: np.ndarray) -> np.ndarray:
    """Rotations (K, 3, 3) about z by ``angles`` (K,) rad."""
    c, s = np.cos(angles), np.sin(angles)
    R = np.zeros((len(angles), 3, 3))
    R[:, 0, 0] = R[:, 1, 1] = c
    R[:, 1, 0] = s
    R[:, 0, 1] = -s
    R[:, 2, 2] = 1.0
    return R


def _yaws(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` yaw angles evenly around the circle from a random start (rad)."""
    return (np.arange(n) + rng.uniform()) * 2 * math.pi / n


def _starts(
    ctx: ClickContext, model, R0: np.ndarray, centre: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """The translations (K, 3) putting the model's centroid over ``centre`` (plus ``offsets``,
    (K, 3)) for rotations R0 (K, 3, 3); with a plane, resting on it (the lowest sample touches
    it)."""
    t0 = centre - R0 @ model.centroid + offsets
    if ctx.plane is not None:
        low = model.samples(REST_SAMPLES, seed=SAMPLE_SEED)[0]
        # a posed sample's height over the plane is n . (R p + t) + d = (R^T n) . p + n . t + d
        n = ctx.plane.normal
        lowest = (low @ (n @ R0).T).min(axis=0) + t0 @ n + ctx.plane.d
        t0 = t0 - n * lowest[:, None]
    return t0


def keep_distinct(hyps: Hypotheses, scores: np.ndarray, n_templates: int, keep: int) -> np.ndarray:
    """Indices of the best ``keep`` distinct hypotheses per template by ``scores`` (lower is
    better; distinct: their centroids more than ``DISTINCT_DISTANCE`` apart or turned more than
    ``DISTINCT_ANGLE``, symmetry-aware). The best mounting-prior hypothesis always goes on: few
    samples cannot judge a tipped-over pose against it reliably."""
    out = []
    for i in range(n_templates):
        idx = np.flatnonzero(hyps.index == i)
        if not len(idx):
            continue
        idx = idx[np.argsort(scores[idx])]
        tpl = hyps.models[int(idx[0])].template
        mounted = idx[hyps.family[idx] == MOUNTED]
        chosen = [mounted[0]] if len(mounted) and keep > 1 else []
        # where each pose puts the object: its centroid (the file's origin may lie anywhere)
        centroids = {}
        for j in idx:
            m = hyps.models[j]
            if id(m) not in centroids:
                centroids[id(m)] = m.centroid
        c = np.stack([centroids[id(hyps.models[j])] for j in idx])
        at = dict(zip(idx.tolist(), np.einsum("bij,bj->bi", hyps.R[idx], c) + hyps.t[idx]))
        for j in idx:
            if all(
                np.linalg.norm(at[j] - at[k]) > DISTINCT_DISTANCE
                or symmetric_angle(tpl, hyps.R[k].T @ hyps.R[j]) > DISTINCT_ANGLE
                for k in chosen
            ):
                chosen.append(j)
            if len(chosen) == keep:
                break
        out.extend(chosen)
    return np.array(out)


def best_per_template(hyps: Hypotheses, scores: np.ndarray, keep: int) -> np.ndarray:
    """Indices (in their order) of each template's best ``keep`` hypotheses by ``scores``
    (lower is better) and its best mounting-prior one (:func:`keep_distinct` always takes it
    on); all of them with ``keep`` 0."""
    if keep <= 0:
        return np.arange(len(hyps))
    chosen = np.zeros(len(hyps), bool)
    for i in np.unique(hyps.index):
        idx = np.flatnonzero(hyps.index == i)
        idx = idx[np.argsort(scores[idx], kind="stable")]
        chosen[idx[:keep]] = True
        mounted = idx[hyps.family[idx] == MOUNTED]
        if len(mounted):
            chosen[mounted[0]] = True
    return np.flatnonzero(chosen)


def prefilter(hyps: Hypotheses, scores: np.ndarray, names: list, settings: FitSettings):
    """The library prefilter: the hypotheses of the templates worth fitting on, their scores,
    and a candidate for each template set aside (its best coarse hypothesis, residual = its
    coarse score, ``prefiltered``). A template is set aside when its best score is more than
    ``prefilter.margin`` x the best template's and ``prefilter.keep`` templates score better
    (``prefilter.keep`` 0: none is). ``scores`` (B,), lower is better."""
    keep_n = settings.prefilter.keep
    if keep_n <= 0 or len(names) <= keep_n:
        return hyps, scores, ()
    best = np.full(len(names), np.inf)
    np.minimum.at(best, hyps.index, scores)
    order = np.argsort(best, kind="stable")
    out = np.zeros(len(names), bool)
    out[order[keep_n:]] = True
    out &= best > settings.prefilter.margin * best[order[0]]
    if not out.any():
        return hyps, scores, ()
    aside = []
    for i in np.flatnonzero(out & np.isfinite(best)):
        j = int(np.flatnonzero(hyps.index == i)[np.argmin(scores[hyps.index == i])])
        residual = max(float(scores[j]), 1e-6)
        aside.append(
            FitResult(
                template=names[i],
                T_scene_model=make_T(hyps.R[j], hyps.t[j]),
                residual=residual,
                likelihood=1.0 / residual,
                iterations=hyps.iterations,
                prefiltered=True,
            )
        )
    stay = np.flatnonzero(~out[hyps.index])
    return hyps.take(stay), scores[stay], tuple(aside)


def yaw_sweep_starts(model, R: np.ndarray, t: np.ndarray, steps: int):
    """A pose turned about its template's symmetry axis (else the z of its ``axes``: its mount's
    normal) through the centroid in ``steps`` steps over one symmetry period: (R (steps, 3, 3),
    t (steps, 3))."""
    sym = model.symmetry
    period = 2 * math.pi / (sym.order if sym is not None and not sym.continuous else 1)
    axis_model = np.asarray(sym.axis) if sym is not None else model.axes[:, 2]
    axis = R @ axis_model
    centre = R @ model.centroid + t
    Rs, ts = [], []
    for k in range(steps):
        dR = axis_angle_matrix(axis, k * period / steps)
        Rs.append(dR @ R)
        ts.append(dR @ (t - centre) + centre)
    return np.stack(Rs), np.stack(ts)


def principal_angle(points: np.ndarray) -> float | None:
    """Angle in the xy plane of the main axis of ``points`` (N, 3), or None when they are not
    elongated (the two in-plane spreads within 20% of each other)."""
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    vals, vecs = np.linalg.eigh(xy.T @ xy)
    if len(points) < 10 or vals[1] < ELONGATED * max(vals[0], 1e-12):
        return None
    return float(math.atan2(vecs[1, 1], vecs[0, 1]))


def symmetric_angle(tpl: AffordanceTemplate, R_rel: np.ndarray) -> float:
    """Rotation angle (rad) of ``R_rel`` up to the template's symmetry."""
    if tpl.symmetry is None:
        return float(rotation_angle(R_rel))
    return tpl.symmetry.residual_angle(R_rel)
