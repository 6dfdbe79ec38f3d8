# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Rank: each template's best hypothesis by the two-way residual (:func:`..scoring.results`),
ranked, those the prefilter set aside behind; every hypothesis's result is kept as the fit's
alternatives (the second poses the ambiguity reads).
"""

from __future__ import annotations

from dataclasses import replace

from ..results import FitResult, rank
from ..scoring import results
from ..state import FitState, stage

__all__ = ["run"]


@stage("rank")
def run(state: FitState) -> FitState:
    """The candidates, one per template, ranked; the alternatives."""
    hyps = state.hyps
    best: dict[int, FitResult] = {}
    every = results(state.ctx, hyps, state.settings, hyps.iterations, hyps.converged)
    for i, res in zip(hyps.index.tolist(), every):
        if i not in best or res.likelihood > best[i].likelihood:
            best[i] = res
    ranked = rank(rank(best.values()) + state.set_aside)
    return replace(state, candidates=ranked, alternatives=tuple(every))
