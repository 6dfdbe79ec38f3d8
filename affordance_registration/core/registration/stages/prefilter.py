# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Prefilter (``prefilter`` settings): in a library larger than ``prefilter.keep``, the
templates whose best coarse score is more than ``prefilter.margin`` x the best template's leave
the fit, each ranked behind the others with its coarse pose (:func:`..hypotheses.prefilter`).
It looks after the coarse stage's first iterations and again after the whole stage: the medium
stage is the dearer one.
"""

from __future__ import annotations

from dataclasses import replace

from .. import hypotheses
from ..state import FitState, stage

__all__ = ["run"]


@stage("prefilter")
def run(state: FitState) -> FitState:
    """The hypotheses of the templates worth fitting on, with their scores; those set aside
    join ``state.set_aside``."""
    hyps, scores, aside = hypotheses.prefilter(
        state.hyps, state.scores, list(state.specific), state.settings
    )
    return replace(state, hyps=hyps, scores=scores, set_aside=state.set_aside + aside)
