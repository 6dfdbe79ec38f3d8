# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Joint values and scale, estimated with the pose for articulated templates (a joint with its
moving part, or a scale range): a sweep across the joint's limits and the scale range, local
steps, and -- after the fine stage -- Occam's razor towards a named state and the nominal scale.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..scene import ClickContext
from ..transforms import make_T
from .correspondences import in_contact, plane_gap
from .icp import fine_stage, icp
from .model import Batch, Model
from .results import FitResult
from .scoring import forward_residual, result, scores
from .settings import FitSettings, Stage

__all__ = ["articulate", "prefer_nominal"]

CONTACT_SLACK = 0.005  #: a gap to the plane within this costs nothing


def articulate(
    ctx: ClickContext,
    model: Model,
    R,
    t,
    settings: FitSettings,
    sweep: bool = True,
    rounds: int | None = None,
):
    """Estimate the joint value and the scale of articulated ``model`` (starting at its own
    values) with the pose (R (3, 3), t (3,)).

    The sweep tries joint values across the limits, each three ways: the fixed part stays and
    the moving part moves, or the fixed part moves back by half or all of the change (a rigid
    fit has often turned or shifted the whole object to match its moving part); then scales
    across the range. Every hypothesis gets a short batched ICP and is judged by the two-way
    residual plus the moving part's own fit (and, resting on the plane under the click, by its
    gap to the plane). Rounds of local joint/scale steps (each with a short ICP) follow,
    halving the step (``rounds``, default ``settings.articulation.rounds``). Returns (Model, R,
    t, whether its last ICP converged)."""
    s = settings
    tpl = model.template
    joint, lo_hi = tpl.joint, tpl.scale_range
    judge = _Judge(ctx, s, joint is not None, in_contact(ctx, model, R, t, s))
    converged = None
    if sweep and joint is not None:
        model, R, t, converged = judge.best_of(*_joint_sweep(model, R, t, s), s.stages.sweep)
    if sweep and lo_hi is not None:
        model, R, t, converged = judge.best_of(*_scale_sweep(ctx, model, R, t, s), s.stages.sweep)
    q_step = (
        (joint.upper - joint.lower) / (2 * s.articulation.joint_sweep)
        if joint is not None
        else 0.0
    )
    s_step = (lo_hi[1] - lo_hi[0]) / (2 * s.articulation.scale_sweep) if lo_hi is not None else 0.0
    if not sweep:
        q_step, s_step = q_step / 2, s_step / 2
    for _ in range(s.articulation.rounds if rounds is None else rounds):
        models = [model]
        if joint is not None:
            models += [
                model.with_values(q=float(np.clip(model.q + d * q_step, joint.lower, joint.upper)))
                for d in (-1.0, 1.0)
            ]
        if lo_hi is not None:
            models += [
                model.with_values(scale=float(np.clip(model.scale + d * s_step, *lo_hi)))
                for d in (-1.0, 1.0)
            ]
        if len(models) == 1:
            break
        model, R, t, converged = judge.best_of(
            models, [R] * len(models), [t] * len(models), s.stages.local
        )
        q_step, s_step = q_step / 2, s_step / 2
    return model, R, t, converged


class _Judge:
    """Picks the best of a batch of joint / scale hypotheses after a short ICP."""

    def __init__(self, ctx: ClickContext, settings: FitSettings, jointed: bool, contact: bool):
        self.ctx, self.settings, self.jointed, self.contact = ctx, settings, jointed, contact

    def best_of(self, models, Rs, ts, stage: Stage):
        """(model, R, t, whether its ICP converged) of the best hypothesis."""
        ctx, s = self.ctx, self.settings
        n = s.medium.samples
        batch = Batch.of(models, np.stack(Rs), np.stack(ts))
        converged = np.zeros(len(models), bool)
        if stage.iterations:
            run = icp(ctx, batch, stage, s)
            batch, converged = Batch(run.models, run.R, run.t), run.converged
        score = scores(ctx, batch, s, n, n)
        if self.contact:  # a gap to (or a dip into) the plane beyond its noise costs
            gap = np.abs(plane_gap(ctx, batch, n))
            score = score + np.clip(gap - CONTACT_SLACK, 0.0, s.scoring.cap)
        if self.jointed:
            parts = Batch(tuple(m.with_values(moving_only=True) for m in models), batch.R, batch.t)
            score = score + forward_residual(ctx, parts, n // 2, s)[0]
        k = int(np.argmin(score))
        return models[k], batch.R[k], batch.t[k], bool(converged[k])


def _joint_sweep(model: Model, R, t, settings: FitSettings):
    """Joint values across the limits, the fixed part held or turned back by half or all of
    the change: (models, Rs, ts)."""
    tpl, joint, q0 = model.template, model.template.joint, model.q
    steps = (
        settings.articulation.joint_sweep
        if joint.type == "revolute"
        else max(3, settings.articulation.joint_sweep // 2)
    )
    T = make_T(R, t)
    models, Rs, ts = [], [], []
    for g in np.linspace(joint.lower, joint.upper, steps):
        moves = (0.0, 0.5, 1.0) if g != q0 else (0.0,)
        for f in moves:  # the fixed part turns back by none, half or all of it
            T_h = T @ tpl.joint_transform(f * (q0 - g)) if f else T
            models.append(model.with_values(q=g))
            Rs.append(T_h[:3, :3])
            ts.append(T_h[:3, 3])
    return models, Rs, ts


def _scale_sweep(ctx: ClickContext, model: Model, R, t, settings: FitSettings):
    """Scales across the range, each about the template's origin (the mounting base stays),
    about its centroid (the fit matched the middle of a bigger or smaller object), and with its
    centroid over the data near the click (the fit matched one end of a bigger one), along the
    plane when there is one: (models, Rs, ts)."""
    lo, hi = model.template.scale_range
    centre = R @ model.centroid + t
    data = ctx.cluster_mean_near(ctx.click, 0.5 * model.template.diameter * hi)
    if data is None:
        data = centre
    if ctx.plane is not None:
        data = data - ctx.plane.normal * (ctx.plane.normal @ (data - centre))
    models, Rs, ts = [], [], []
    for g in np.linspace(lo, hi, settings.articulation.scale_sweep):
        m = model.with_values(scale=g)
        models += [m, m, m]
        Rs += [R, R, R]
        ts += [t, centre - R @ m.centroid, data - R @ m.centroid]
    return models, Rs, ts


def prefer_nominal(
    ctx: ClickContext,
    model: Model,
    res: FitResult,
    settings: FitSettings,
    iterations_before: int,
    converge: float | None = None,
) -> FitResult:
    """Occam's razor for the extra unknowns: refit at the nearest named state's joint value
    and/or at the nominal scale 1 (within the range) -- the fixed part held or moved so the
    moving part stays, the template scaled about its origin or its centroid -- and keep
    that when its residual is within ``articulation.nominal_preference`` (joint) plus
    ``articulation.nominal_scale_preference`` (scale) of the free fit's. Valves mostly
    sit open or closed, and most objects come in their nominal size. Where scale 1 is tried,
    both sides are compared with samples beyond ``articulation.scale_grazing_angle`` unseen (a
    sensor returns little there, and such samples count against the larger size); the result keeps
    the residual every candidate is ranked by. ``converge``: the refits' step thresholds'
    factor (:func:`.icp.icp`)."""
    tpl = model.template
    s = settings
    qs, scales = [model.q], [model.scale]
    if tpl.joint is not None and tpl.states and res.state is not None:
        q_s = float(tpl.states[res.state].get(tpl.joint.name, model.q))
        if abs(q_s - model.q) > 1e-9:
            qs.append(q_s)
    lo_hi = tpl.scale_range
    if lo_hi is not None and lo_hi[0] <= 1.0 <= lo_hi[1] and abs(model.scale - 1.0) > 1e-9:
        scales.append(1.0)
    T = res.T_scene_model
    centre = T[:3, :3] @ model.centroid + T[:3, 3]
    # the scale is judged with samples at grazing angles unseen (both sides alike)
    judge_s = (
        replace(s, scoring=replace(s.scoring, grazing_angle=s.articulation.scale_grazing_angle))
        if len(scales) > 1 and s.articulation.scale_grazing_angle < s.scoring.grazing_angle
        else s
    )
    free = (
        res
        if judge_s is s
        else result(ctx, model, T[:3, :3], T[:3, 3], judge_s, res.iterations, res.converged)
    )
    best = None
    for q in qs:
        for sc in scales:
            if q == model.q and sc == model.scale:
                continue
            allowed = (
                1.0
                + (s.articulation.nominal_preference if q != model.q else 0.0)
                + (s.articulation.nominal_scale_preference if sc != model.scale else 0.0)
            ) * free.residual
            m = model.with_values(q=q, scale=sc)
            starts = [T]
            if q != model.q:
                starts.append(T @ tpl.joint_transform(model.q - q))
            if sc != model.scale:
                starts += [
                    make_T(T0[:3, :3], centre - T0[:3, :3] @ m.centroid) for T0 in list(starts)
                ]
            for T0 in starts:
                # as it is, and refined (the fine stage's objective is not the residual)
                fit = fine_stage(
                    ctx,
                    m,
                    T0[:3, :3],
                    T0[:3, 3],
                    s.stages.refit,
                    s,
                    hold_joint=True,
                    hold_scale=True,
                    converge=converge,
                )
                refined = result(
                    ctx,
                    m,
                    fit.R[0],
                    fit.t[0],
                    judge_s,
                    iterations_before + fit.iterations,
                    fit.converged[0],
                )
                as_is = result(
                    ctx, m, T0[:3, :3], T0[:3, 3], judge_s, res.iterations, res.converged
                )
                for cand in (as_is, refined):
                    if cand.residual <= allowed and (
                        best is None or cand.residual < best.residual
                    ):
                        best, best_model = cand, m
    if best is None:
        return res
    if judge_s is s:
        return best
    T_b = best.T_scene_model  # reported with the residual every candidate is ranked by
    return result(ctx, best_model, T_b[:3, :3], T_b[:3, 3], s, best.iterations, best.converged)
