# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Weighted ICP: one loop for every stage. A batch of hypotheses advances together (one KD query
per iteration); the rejection radius shrinks from the stage's reach to ``icp.reject_floor``; the
loop stops once every hypothesis has converged (its step turns it less than
``CONVERGED_ROTATION``, moves its weighted centroid less than ``CONVERGED_TRANSLATION`` and
changes its joint value and scale less than ``CONVERGED_EXTRA``; ``FINE_CONVERGED`` times those
on the full-resolution cluster) or at the stage's iteration limit.

On the voxelized cluster the step is point to point (closed-form weighted SVD). On the
full-resolution cluster (the fine stage) scene points are paired with the template too, and the
step is point to plane (it does not creep along flat or cylindrical surfaces), with a column per
extra unknown -- a joint value, a scale -- besides the six of the pose.
"""

from __future__ import annotations

import numpy as np

from ..compiled import kernels
from ..neighbours import compiled_tree_of
from ..scene import ClickContext
from ..transforms import pose_points, rotate
from .correspondences import (
    PLANE_BAND,
    Pairs,
    compiled_tree,
    contact_rows,
    forward_pairs,
    in_contact,
    reverse_rows,
    reverse_subset,
    stack_samples,
)
from .model import Batch, Model
from .parallel import parts, run
from .results import IcpResult
from .settings import FINE, FINE_CONVERGED, SAMPLE_SEED, FitSettings, Stage
from .solve import Step, plane_step, rigid_step
from .visibility import compiled_view

__all__ = ["icp", "fine_stage", "radius_schedule", "JOINT", "SCALE"]

CONVERGED_ROTATION = 2e-4  #: rad: an ICP step turning less than this ...
CONVERGED_TRANSLATION = 5e-5  #: m: ... and moving less than this has converged
CONVERGED_EXTRA = 1e-4  #: rad, m or scale: ... and so have joint and scale steps this small
JOINT_STEP_LIMIT = 1 / 8  #: a Gauss-Newton joint step moves at most this part of the range
SCALE_STEP_LIMIT = 0.05  #: ... and a scale step at most this much

JOINT, SCALE = "joint", "scale"  #: the extra unknowns a stage may fit besides the pose


def radius_schedule(reject, floor, it: int, iterations: int):
    """The rejection radius of iteration ``it`` of ``iterations``: from ``reject`` down to
    ``floor``, geometrically."""
    return reject * (floor / reject) ** (it / max(iterations - 1, 1))


def icp(
    ctx: ClickContext,
    batch: Batch,
    stage: Stage,
    settings: FitSettings,
    reject=None,
    unknowns: tuple = (),
    contact: bool = False,
    span: tuple | None = None,
    converge: float | None = None,
) -> IcpResult:
    """Weighted ICP of a batch of hypotheses. ``reject`` (B,) in m overrides the stage's
    reach. ``span`` (first, stop) runs only those of the stage's iterations (its rejection
    radii as in the whole stage), so a stage can be run in two parts. ``unknowns`` (fine stage
    only):
    JOINT and/or SCALE, fitted with the pose (every model has them); ``contact``: the lowest
    samples also pair with the plane under the click (the fit rests on it). ``converge``: the
    step thresholds' factor (None: ``FINE_CONVERGED`` on the full-resolution target, else 1).
    A big batch runs in parts side by side (``settings.threads``); each hypothesis' result is
    its own."""
    if reject is not None:
        reject = np.broadcast_to(np.asarray(reject, dtype=float), (len(batch),))
    pieces = parts(len(batch), settings.threads)
    if len(pieces) == 1:
        return _icp(ctx, batch, stage, settings, reject, unknowns, contact, span, converge)
    done = run(
        [
            lambda idx=idx: _icp(
                ctx,
                batch.take(idx),
                stage,
                settings,
                None if reject is None else reject[idx],
                unknowns,
                contact,
                span,
                converge,
            )
            for idx in pieces
        ],
        settings.threads,
    )
    return IcpResult(
        sum((r.models for r in done), ()),
        np.concatenate([r.R for r in done]),
        np.concatenate([r.t for r in done]),
        max(r.iterations for r in done),
        np.concatenate([r.converged for r in done]),
    )


def _icp(
    ctx: ClickContext,
    batch: Batch,
    stage: Stage,
    settings: FitSettings,
    reject,
    unknowns: tuple,
    contact: bool,
    span: tuple | None = None,
    converge: float | None = None,
) -> IcpResult:
    """:func:`icp` of one batch on the calling thread."""
    fine = stage.target == FINE
    posing = _Posing(batch.models, stage.samples, unknowns)
    R, t = np.array(batch.R, dtype=float), np.array(batch.t, dtype=float)
    if reject is None:
        reject = stage.reject * np.array([m.diameter for m in batch.models])
    reject = np.broadcast_to(np.asarray(reject, dtype=float), (len(batch),))
    floor = np.minimum(reject, settings.icp.reject_floor)
    small = converge if converge is not None else FINE_CONVERGED if fine else 1.0
    converged = np.zeros(len(batch), bool)
    active = np.arange(len(batch))  # the hypotheses still moving
    first, stop = span if span is not None else (0, stage.iterations)
    fused = None if fine or contact or unknowns else _Fused.of(ctx, stage.target, settings)
    rows = _FineRows.of(ctx, settings) if fine else None
    it = first - 1
    for it in range(first, stop):
        radius = radius_schedule(reject[active], floor[active], it, stage.iterations)
        Ra, ta = R[active], t[active]
        if fused is not None:
            step = fused.step(posing, active, Ra, ta, radius)
            R[active] = step.R @ Ra
            t[active] = (step.R @ ta[:, :, None])[:, :, 0] + step.t
            done = (step.rotation < small * CONVERGED_ROTATION) & (
                step.motion < small * CONVERGED_TRANSLATION
            )
            converged[active[done]] = True
            active = active[~done]
            if not len(active):
                break
            continue
        X, Nw, U, moving = posing.posed(Ra, ta, active)
        if rows is not None and len(active) == 1:
            forward, pairs = rows.pairs(X, Nw, U, moving, radius, posing.models[active[0]], Ra, ta)
        else:
            Q, Nq, w = forward_pairs(ctx, stage.target, X, Nw, radius, settings, normals=fine)
            pairs = forward = Pairs(X, Q, Nq, w, U, moving)
            if fine:
                pairs = pairs.joined(
                    reverse_rows(ctx, Batch(posing.models_at(active), Ra, ta), radius, settings)
                )
        if contact:
            pairs = pairs.joined(contact_rows(ctx, forward, radius, settings))
        if fine:
            step = plane_step(
                pairs.X,
                pairs.Q,
                pairs.N,
                pairs.w,
                posing.columns(pairs, Ra, active),
                posing.bounds(active),
            )
        else:
            step = rigid_step(pairs.X, pairs.Q, pairs.w)
        R[active] = step.R @ Ra
        t[active] = (step.R @ ta[:, :, None])[:, :, 0] + step.t
        extra = posing.advance(step.extra, active)
        done = (
            (step.rotation < small * CONVERGED_ROTATION)
            & (step.motion < small * CONVERGED_TRANSLATION)
            & (extra < small * CONVERGED_EXTRA)
        )
        # a converged hypothesis stays where it is (its result does not depend on the others
        # in the batch, so a batch may be split across threads)
        converged[active[done]] = True
        active = active[~done]
        if not len(active):
            break
    return IcpResult(tuple(posing.models), R, t, it + 1 - first, converged)


def fine_stage(
    ctx: ClickContext,
    model: Model,
    R,
    t,
    stage: Stage,
    settings: FitSettings,
    hold_joint: bool = False,
    hold_scale: bool = False,
    converge: float | None = None,
) -> IcpResult:
    """One hypothesis alone on the full-resolution target. An articulated model's joint value
    and scale are unknowns besides the pose (``hold_joint`` / ``hold_scale`` keep them as
    given); such a fit resting on the plane under the click keeps resting on it.
    ``converge``: as :func:`icp`'s (None: ``FINE_CONVERGED``)."""
    tpl = model.template
    unknowns = (
        ()
        if not model.articulated
        else ((JOINT,) if tpl.joint is not None and not hold_joint else ())
        + ((SCALE,) if tpl.scale_range is not None and not hold_scale else ())
    )
    contact = bool(unknowns) and in_contact(ctx, model, R, t, settings)
    return icp(
        ctx,
        Batch.single(model, R, t),
        stage,
        settings,
        unknowns=unknowns,
        contact=contact,
        converge=converge,
    )


class _Fused:
    """The point-to-point step of the voxelized stages as one compiled kernel
    (:func:`..compiled._rigid_step`): posing, visibility, the plane band, the nearest target
    point (a compiled KD-tree: the same neighbours), the weights and the weighted SVD in one
    call per iteration, the GIL released. The same numbers as the numpy path but for the
    rounding of its sums (the golden fits' tolerance holds them, ``test/test_compiled.py``)."""

    def __init__(self, k, tree, view):
        self.k, self.tree, (self.view, self.frame, self.depth) = k, tree, view
        self.guess = None  # each sample's last partner (where its next search starts)

    @staticmethod
    def of(ctx: ClickContext, target: str, settings: FitSettings) -> "_Fused | None":
        """The fused step for ``target``, or None where the compiled kernels are not in use
        (or correspondences are projective)."""
        k = kernels()
        if k is None or settings.icp.projective:
            return None
        view = compiled_view(
            ctx, settings, PLANE_BAND * ctx.plane_threshold, settings.icp.weight_scale
        )
        return _Fused(k, compiled_tree(ctx, target), view)

    def step(self, posing: "_Posing", active, R, t, radius) -> Step:
        b = len(active)
        if self.guess is None:
            self.guess = np.full(posing.P.shape[:2], -1, dtype=np.int64)
        out_R, out_t, out_c = np.empty((b, 3, 3)), np.empty((b, 3)), np.empty((b, 3))
        self.k.rigid_step(
            posing.P,
            posing.N,
            np.ascontiguousarray(active, dtype=np.int64),
            np.ascontiguousarray(R, dtype=float),
            np.ascontiguousarray(t, dtype=float),
            np.ascontiguousarray(radius, dtype=float),
            self.view,
            self.frame,
            self.depth,
            self.tree.arrays,
            self.guess,
            out_R,
            out_t,
            out_c,
        )
        return Step(out_R, out_t, out_c, np.zeros((b, 0)))


class _FineRows:
    """The correspondences of one hypothesis on the full-resolution cluster -- forward pairs
    and the scene's reverse ones, as :func:`.correspondences.forward_pairs` and
    :func:`.correspondences.reverse_rows` make them -- in one compiled call
    (:func:`..compiled._fine_rows`; compiled KD-trees, the same neighbours), the step solved
    from them as before."""

    def __init__(self, k, ctx: ClickContext, settings: FitSettings, view):
        self.k, (self.view, self.frame, self.depth) = k, view
        self.fine = compiled_tree(ctx, FINE)
        self.normals = np.require(ctx.fine_normals, float, ["C", "W"])
        rev, rev_n = reverse_subset(ctx, settings.fine.reverse_points)
        self.rev = np.require(rev, float, ["C", "W"])
        self.rev_n = np.require(rev_n, float, ["C", "W"])
        self.guess = None

    @staticmethod
    def of(ctx: ClickContext, settings: FitSettings) -> "_FineRows | None":
        k = kernels()
        if k is None or settings.icp.projective:
            return None
        view = compiled_view(
            ctx, settings, PLANE_BAND * ctx.plane_threshold, settings.icp.weight_scale
        )
        return _FineRows(k, ctx, settings, view)

    def pairs(self, X, Nw, U, moving, radius, model: Model, R, t) -> tuple:
        """(forward, all) :class:`.correspondences.Pairs` of the one hypothesis at R (1, 3, 3),
        t (1, 3): the posed samples X, Nw (1, S, 3) (with U, moving: their unscaled model-frame
        places and parts, or None), ``radius`` (1,)."""
        S = X.shape[1]
        if self.guess is None:
            self.guess = np.full(S, -1, dtype=np.int64)
        surface = model.cache.surface(model.template)
        jointed = not (model.q == 0.0 or surface.moving_part is None)
        whole = compiled_tree_of(surface, surface.whole)
        base = compiled_tree_of(surface, surface.base) if jointed else whole
        part = compiled_tree_of(surface, surface.moving_part) if jointed else whole
        T = model.template.joint_transform(model.q) if jointed else np.eye(4)
        Rh, th = np.ascontiguousarray(R[0], dtype=float), np.ascontiguousarray(t[0], dtype=float)
        size = S + len(self.rev)
        out_X, out_Q, out_N, out_U = (np.zeros((size, 3)) for _ in range(4))
        out_w, out_moving = np.zeros(size), np.zeros(size, bool)
        n = self.k.fine_rows(
            np.ascontiguousarray(X[0], dtype=float),
            np.ascontiguousarray(Nw[0], dtype=float),
            float(radius[0]),
            self.view,
            self.frame,
            self.depth,
            self.fine.arrays,
            self.normals,
            self.guess,
            self.rev,
            self.rev_n,
            np.ascontiguousarray(Rh @ model.centroid + th),
            0.5 * model.diameter,
            Rh,
            th,
            float(model.scale),
            whole.arrays,
            np.array(surface.moving, dtype=bool),  # (the kernel takes a writable one)
            jointed,
            base.arrays,
            part.arrays,
            np.ascontiguousarray(T, dtype=float),
            out_X,
            out_Q,
            out_N,
            out_w,
            out_U,
            out_moving,
        )
        if U is not None:
            out_U[:S], out_moving[:S] = U[0], moving[0]
        rows = [a[None, :n] for a in (out_X, out_Q, out_N, out_w, out_U, out_moving)]
        if U is None:
            rows[4] = rows[5] = None
        forward = Pairs(X, rows[1][:, :S], rows[2][:, :S], rows[3][:, :S], U, moving)
        return forward, Pairs(*rows)


class _Posing:
    """The samples of a batch of hypotheses, posed every iteration -- with extra unknowns at
    each model's current joint value and scale -- and those unknowns' columns, bounds and
    updates. Every method works on the hypotheses at ``idx`` (an index array)."""

    def __init__(self, models, n: int, unknowns: tuple):
        self.models, self.unknowns = list(models), tuple(unknowns)
        if not self.unknowns:
            self.P, self.N = stack_samples(models, n)
        else:
            self.parts = [m.template.part_samples(n, seed=SAMPLE_SEED) for m in models]

    def models_at(self, idx) -> tuple:
        return tuple(self.models[i] for i in idx)

    def posed(self, R, t, idx):
        """(X, Nw) the samples in the scene (b, S, 3) at poses R (b, 3, 3), t (b, 3); with
        extra unknowns also U, the samples unscaled in the model frame (b, S, 3), and which are
        on the moving part (b, S)."""
        if not self.unknowns:
            U, moving = None, None
            # every hypothesis still moving: the samples as they are, no copy
            P, N = (self.P, self.N) if len(idx) == len(self.P) else (self.P[idx], self.N[idx])
        else:
            models, parts = self.models_at(idx), [self.parts[i] for i in idx]
            posed = [
                m.template.pose_parts(P0, N0, mov, m.q) for m, (P0, N0, mov) in zip(models, parts)
            ]
            U = np.stack([p[0] for p in posed])
            N = np.stack([p[1] for p in posed])
            moving = np.stack([mov for _, _, mov in parts])
            P = U * np.array([m.scale for m in models])[:, None, None]
        return pose_points(R, t, P), rotate(R, N), U, moving

    def columns(self, pairs: Pairs, R, idx) -> np.ndarray | None:
        """d(x . n) / d(value) of every row for each extra unknown, (b, S, k) or None."""
        if not self.unknowns:
            return None
        models = self.models_at(idx)
        cols = []
        for name in self.unknowns:
            if name == JOINT:
                du = np.stack([self._joint_motion(m, U) for m, U in zip(models, pairs.U)])
                du = (
                    du
                    * pairs.moving[..., None]
                    * np.array([m.scale for m in models])[:, None, None]
                )
            else:
                du = pairs.U
            cols.append(np.einsum("bsi,bsi->bs", rotate(R, du), pairs.N))
        return np.stack(cols, axis=-1)

    @staticmethod
    def _joint_motion(model: Model, U: np.ndarray) -> np.ndarray:
        """d U / d q of the moving part's points U (S, 3): about or along the joint axis."""
        j = model.template.joint
        axis = np.asarray(j.axis)
        if j.type == "revolute":
            return np.cross(axis, U - np.asarray(j.origin))
        return np.broadcast_to(axis, U.shape)

    def _limits(self, model: Model):
        """(value, lower, upper, largest step) of each extra unknown of ``model``."""
        out = []
        for name in self.unknowns:
            if name == JOINT:
                j = model.template.joint
                out.append((model.q, j.lower, j.upper, (j.upper - j.lower) * JOINT_STEP_LIMIT))
            else:
                lo, hi = model.template.scale_range
                out.append((model.scale, lo, hi, SCALE_STEP_LIMIT))
        return np.array(out, dtype=float).reshape(len(self.unknowns), 4)

    def bounds(self, idx):
        """(values, lower, upper) of the extra unknowns, each (b, k), or None."""
        if not self.unknowns:
            return None
        lim = np.stack([self._limits(m) for m in self.models_at(idx)])
        return lim[..., 0], lim[..., 1], lim[..., 2]

    def advance(self, increments: np.ndarray, idx) -> np.ndarray:
        """Apply the extra unknowns' increments (b, k), each limited to its largest step and
        kept within its bounds; returns the largest step taken per hypothesis (b,)."""
        if not self.unknowns:
            return np.zeros(len(idx))
        lim = np.stack([self._limits(m) for m in self.models_at(idx)])
        steps = np.clip(increments, -lim[..., 3], lim[..., 3])
        values = np.clip(lim[..., 0] + steps, lim[..., 1], lim[..., 2])
        for b, i in enumerate(idx):
            new = dict(zip(self.unknowns, values[b]))
            self.models[i] = self.models[i].with_values(q=new.get(JOINT), scale=new.get(SCALE))
        return np.abs(steps).max(axis=1)
