# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Finish (``finish`` and ``fine`` settings): the leading candidates -- the winner and the
runners-up close to it -- each swept about its mounting axis (near-symmetric handles), then
alone on the full-resolution cluster (point to plane, two-way; an articulated one with its joint
value and scale, then towards a named state and scale 1), and ranked again on those residuals.

Two near shapes (a template and a squeezed copy of it) can swap places at medium resolution; the
fine stage tells them apart, and where they finish within ``near_tie`` of each other, fine
stages run to the plain step thresholds do (:data:`..settings.NEAR_TIE`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...click_context import ClickContext
from ..articulation import articulate, prefer_nominal
from ..hypotheses import yaw_sweep_starts
from ..icp import fine_stage, icp
from ..model import Batch, Model
from ..parallel import run as side_by_side
from ..results import FitResult, rank
from ..scoring import result, results, scores
from ..services import Services
from ..settings import NEAR_TIE
from ..state import FitState, stage

__all__ = ["run", "before_fine", "finished", "yaw_sweep"]


@stage("finish")
def run(state: FitState, near_tie: float = NEAR_TIE) -> FitState:
    """The candidates with the leaders finished side by side, ranked again: the best and
    those of the next ``finish.candidates - 1`` fitted on (not set aside by the prefilter)
    whose residual is within ``finish.margin`` of the best's. A finished residual is never
    above the one it started from, and every candidate left out ranked behind those
    finished, so the ranking stays consistent. A leader that cannot come to fit
    (:meth:`..services.Services.worth`) keeps its medium-resolution result. Leaders that
    finish within ``near_tie`` x the best's residual are finished again to the plain step
    thresholds (not ``FINE_CONVERGED`` x them)."""
    s, ctx, services = state.settings, state.ctx, state.services
    ranked, models, iterations = state.candidates, state.articulated, state.hyps.iterations
    n = 1
    while (
        n < min(s.finish.candidates, len(ranked))
        and not ranked[n].prefiltered
        and ranked[n].residual <= s.finish.margin * ranked[0].residual
    ):
        n += 1
    leaders, hopeless = services.worth(ctx, ranked[:n], models, s.finish.explained_margin)
    if not leaders:
        return replace(state, candidates=rank(hopeless + list(ranked[n:])))

    def lead(win):
        swept = before_fine(services, ctx, win, models)
        return swept, finished(services, ctx, win, swept, iterations)

    swept, done = map(list, zip(*side_by_side([lambda r=r: lead(r) for r in leaders], s.threads)))
    # a near tie -- a template and a squeezed copy of it can finish within 0.1% of each
    # other -- is decided on fine stages run to the plain step thresholds
    best = min(r.residual for r in done)
    tied = [k for k in range(len(done)) if done[k].residual <= near_tie * best]
    if len(tied) > 1:
        again = side_by_side(
            [
                lambda k=k: finished(services, ctx, leaders[k], swept[k], iterations, 1.0)
                for k in tied
            ],
            s.threads,
        )
        for k, r in zip(tied, again):
            done[k] = r
    return replace(state, candidates=rank(list(done) + hopeless + list(ranked[n:])))


def before_fine(services: Services, ctx: ClickContext, win: FitResult, models) -> tuple:
    """A leader's yaw sweep (and, articulated, its joint once more after it): (model, R, t)
    for its fine stage. ``models``: template -> its articulated model (else the rigid one)."""
    s = services.settings
    model = models.get(win.template)
    if model is None:
        model = services.models.model(services.library[win.template])
    model, R, t = yaw_sweep(ctx, model, win.T_scene_model[:3, :3], win.T_scene_model[:3, 3], s)
    if model.articulated:  # the joint after the sweep, once more
        model, R, t, _ = articulate(
            ctx, model, R, t, s, sweep=False, rounds=s.articulation.finish_rounds
        )
    return model, R, t


def finished(
    services: Services,
    ctx: ClickContext,
    win: FitResult,
    swept: tuple,
    iterations: int,
    converge: float | None = None,
) -> FitResult:
    """A leader's fine stage from ``swept`` (:func:`before_fine`; joint and scale once more,
    articulated) and Occam's razor for its joint value and scale (``converge``: as
    :func:`..icp.icp`'s); never worse than ``win``."""
    s = services.settings
    model, R, t = swept
    fit = fine_stage(ctx, model, R, t, s.stages.fine, s, converge=converge)
    final = result(
        ctx,
        fit.models[0],
        fit.R[0],
        fit.t[0],
        s,
        iterations + fit.iterations,
        fit.converged[0],
    )
    if final.likelihood < win.likelihood:
        final = win
    if model.articulated:
        final = prefer_nominal(
            ctx,
            services.model(final.template, final.joints, final.scale),
            final,
            s,
            iterations,
            converge,
        )
    return final


def yaw_sweep(ctx: ClickContext, model: Model, R, t, settings) -> tuple:
    """The pose turned about its template's mounting / symmetry axis in ``finish.yaw_sweep``
    steps over one symmetry period, each refined; the best by the residual. An articulated
    model is also swept at its template's named states (a valve body turned a quarter with
    its handle turned back matches the handle alone, and the joint is held in the sweep).
    (model, R, t)"""
    s = settings
    if s.finish.yaw_sweep <= 1:
        return model, R, t
    variants = [model]
    if model.articulated:
        tpl = model.template
        variants += [
            model.with_values(q=q)
            for q in sorted({float(tpl.joint_value(v)) for v in tpl.states.values()})
            if q != model.q
        ]
    starts = [yaw_sweep_starts(m, R, t, s.finish.yaw_sweep) for m in variants]
    models = [m for m in variants for _ in range(s.finish.yaw_sweep)]
    swept = icp(
        ctx,
        Batch.of(
            models,
            np.concatenate([a for a, _ in starts]),
            np.concatenate([b for _, b in starts]),
        ),
        s.stages.short,
        s,
    )
    swept = Batch(swept.models, swept.R, swept.t)
    # ranked on the medium residual; the best few again on the full one
    keep = np.arange(len(swept))
    if 0 < s.finish.yaw_sweep_keep < len(swept):
        cheap = scores(ctx, swept, s, s.medium.samples, s.medium.samples)
        keep = np.sort(np.argsort(cheap, kind="stable")[: s.finish.yaw_sweep_keep])
    residuals = [r.residual for r in results(ctx, swept.take(keep), s)]
    best = int(keep[int(np.argmin(residuals))])
    return models[best], swept.R[best], swept.t[best]
