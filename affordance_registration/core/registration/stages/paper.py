# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Paper: the method of record, literally (Hagenow et al.) -- the baseline every benchmark
compares against. With ``FitSettings(method="paper")`` this one stage takes the place of the
default method's hypothesise ... judge (its knobs: ``paper_restarts``, ``paper_iterations``,
``paper_samples``).

Per template, per restart: a random orientation and the template's centroid placed within its
diameter of the click (the paper places the template's origin there: its templates' origins are
their middles, and a file's origin may lie anywhere); point-to-point ICP on the whole crop with
w = 1 / (1 + d) (d in metres), correspondences beyond the diameter rejected, until the weighted
residual stops changing or ``paper_iterations``; the template's likelihood is the inverse of its
best weighted residual.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ...click_context import ClickContext
from ...neighbours import nearest, tree_points
from ...templates import AffordanceTemplate
from ...transforms import make_T, random_rotations
from ..correspondences import correspondence_weights
from ..results import FitResult, rank
from ..settings import SAMPLE_SEED, FitSettings
from ..solve import kabsch_weighted
from ..state import FitState, stage

__all__ = ["run", "fit_template", "CONVERGED_RESIDUAL"]

CONVERGED_RESIDUAL = 1e-7  #: m: the paper's ICP stops when its residual changes less


@stage("paper")
def run(state: FitState) -> FitState:
    """The candidates, one per template to fit, ranked (best first)."""
    s, library = state.settings, state.services.library
    rng = np.random.default_rng(s.seed)
    fitted = [fit_template(state.ctx, library[name], s, rng) for name in state.specific]
    return replace(state, candidates=rank(fitted))


def fit_template(
    ctx: ClickContext, tpl: AffordanceTemplate, settings: FitSettings, rng: np.random.Generator
) -> FitResult:
    """The template's best of ``paper_restarts`` restarts around the click, each an ICP to
    its end (:func:`_icp`); its likelihood the inverse of its weighted residual."""
    s = settings
    t_start = time.perf_counter()
    P = tpl.samples(s.paper_samples, seed=SAMPLE_SEED)[0]
    diam = tpl.diameter
    best = None
    total_iters = 0
    # drawn in the frame attached to the scan and in the template's axes, the template's
    # centroid at the click: the restarts turn with the scan and with the template's file
    for R0 in ctx.frame @ random_rotations(s.paper_restarts, rng) @ tpl.axes.T:
        off = ctx.frame @ rng.normal(size=3)
        off *= diam * rng.uniform() ** (1 / 3) / np.linalg.norm(off)
        t0 = ctx.click + off - R0 @ tpl.centroid
        R, t, iters = _icp(ctx, P, diam, R0, t0, s.paper_iterations)
        total_iters += iters
        resid, d = _residual(ctx, P, diam, R, t)
        if best is None or resid < best[0]:
            best = (resid, R, t, float(np.mean(d <= diam)))
    resid, R, t, inl = best
    resid = max(resid, 1e-9)
    return FitResult(
        template=tpl.name,
        T_scene_model=make_T(R, t),
        residual=resid,
        likelihood=1.0 / resid,
        inlier_fraction=inl,
        iterations=total_iters,
        time_s=time.perf_counter() - t_start,
    )


def _icp(ctx: ClickContext, P, diam: float, R, t, iterations: int):
    """One restart's ICP from (R, t), at most ``iterations``; returns (R, t, iterations)."""
    pts = tree_points(ctx.crop_tree)
    prev = math.inf
    iters = 0
    for _ in range(iterations):
        X = P @ R.T + t
        d, idx = nearest(ctx.crop_tree, X)
        w = correspondence_weights(d, diam, 1.0)
        if w.sum() < 1e-9:
            break
        resid = float((w * d).sum() / w.sum())
        dR, dt = kabsch_weighted(X[None], pts[idx][None], w[None])
        R, t = dR[0] @ R, dR[0] @ t + dt[0]
        iters += 1
        if abs(prev - resid) < CONVERGED_RESIDUAL:
            break
        prev = resid
    return R, t, iters


def _residual(ctx: ClickContext, P, diam: float, R, t):
    """The weighted residual (m, inf when nothing corresponds) and the distances (N,)."""
    d, _ = nearest(ctx.crop_tree, P @ R.T + t)
    w = correspondence_weights(d, diam, 1.0)
    resid = float((w * d).sum() / max(w.sum(), 1e-9)) if w.sum() > 0 else math.inf
    return resid, d
