# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Medium (``medium`` settings): the best ``coarse.keep_per_template`` distinct hypotheses of
each template (:func:`..hypotheses.keep_distinct`; its best mounted one always among them),
refined together at medium resolution.
"""

from __future__ import annotations

from dataclasses import replace

from ..hypotheses import keep_distinct
from ..icp import icp
from ..state import FitState, stage

__all__ = ["run"]


@stage("medium")
def run(state: FitState) -> FitState:
    """The kept hypotheses after the medium ICP stage (no longer scored)."""
    s = state.settings
    keep = keep_distinct(state.hyps, state.scores, len(state.specific), s.coarse.keep_per_template)
    hyps = state.hyps.take(keep)
    return replace(state, hyps=hyps.after(icp(state.ctx, hyps, s.stages.medium, s)), scores=None)
