# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Coarse (``coarse`` settings): every restart of every template advanced together on few
samples (one KD query per iteration, a batched weighted SVD: :func:`..icp.icp`), then scored
on the two-way residual for the prefilter and the medium stage.

The stage may pause after ``prefilter.iterations`` iterations for the prefilter's first look
(:func:`first_look`, :func:`rest`): the templates clearly worse than the leaders leave there,
and each template's restarts beyond its best ``coarse.keep``; a library of more than twice
what the prefilter keeps takes that first look on ``prefilter.samples`` samples.
"""

from __future__ import annotations

from dataclasses import replace

from ..hypotheses import best_per_template
from ..icp import icp
from ..scoring import scores
from ..state import FitState, stage

__all__ = ["BACKWARD_SUBSAMPLE", "pause", "first_look", "rest", "run"]

BACKWARD_SUBSAMPLE = 64  #: cluster points in the coarse stage's cluster -> template half


def pause(state: FitState) -> int:
    """The iteration after which the stage pauses for the prefilter's first look, or 0: it
    runs through (a library the prefilter keeps whole and ``coarse.keep`` 0, or
    ``prefilter.iterations`` outside the stage)."""
    s = state.settings
    split = (
        s.prefilter.iterations
        if 0 < s.prefilter.keep < len(state.specific) or s.coarse.keep
        else 0
    )
    return split if 0 < split < s.coarse.iterations else 0


@stage("coarse")
def first_look(state: FitState) -> FitState:
    """The stage's first :func:`pause` iterations, scored (a library of more than twice
    ``prefilter.keep`` templates on ``prefilter.samples`` template samples and as many
    cluster points)."""
    s, ctx = state.settings, state.ctx
    screen = s.prefilter.samples if 0 < 2 * s.prefilter.keep < len(state.specific) else 0
    look = replace(s.stages.coarse, samples=screen) if screen else s.stages.coarse
    hyps = state.hyps.after(icp(ctx, state.hyps, look, s, span=(0, pause(state))))
    score = scores(
        ctx,
        hyps,
        s,
        look.samples,
        min(screen, BACKWARD_SUBSAMPLE) if screen else BACKWARD_SUBSAMPLE,
    )
    return replace(state, hyps=hyps, scores=score)


@stage("coarse")
def rest(state: FitState) -> FitState:
    """After the first look: each template's best ``coarse.keep`` hypotheses (and its best
    mounted one) through the stage's remaining iterations, scored."""
    s, ctx = state.settings, state.ctx
    hyps = state.hyps.take(best_per_template(state.hyps, state.scores, s.coarse.keep))
    hyps = hyps.after(icp(ctx, hyps, s.stages.coarse, s, span=(pause(state), s.coarse.iterations)))
    return replace(
        state, hyps=hyps, scores=scores(ctx, hyps, s, s.coarse.samples, BACKWARD_SUBSAMPLE)
    )


@stage("coarse")
def run(state: FitState) -> FitState:
    """The whole stage, scored."""
    s, ctx = state.settings, state.ctx
    hyps = state.hyps.after(icp(ctx, state.hyps, s.stages.coarse, s))
    return replace(
        state, hyps=hyps, scores=scores(ctx, hyps, s, s.coarse.samples, BACKWARD_SUBSAMPLE)
    )
