# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Assess (``viewpoint`` settings): whether the ranked candidates settle the click -- refused,
a rival template or a second pose within ``viewpoint.margin``, a weakly held pose
(:func:`..ambiguity.assess`) -- read off the candidates and the fit's alternatives, changing
none of them.
"""

from __future__ import annotations

from dataclasses import replace

from ...click_context import ClickContext
from .. import ambiguity
from ..icp import fine_stage
from ..parallel import single_threaded_blas
from ..results import FitResult
from ..scoring import result
from ..services import Services
from ..state import FitState, stage

__all__ = ["ambiguity_of", "run"]


def ambiguity_of(
    services: Services, ctx: ClickContext, candidates, alternatives=()
) -> ambiguity.Ambiguity:
    """The :class:`..ambiguity.Ambiguity` of a click's ranked ``candidates``; an alternative
    of the best template within the margin is finished as a leader is (its fine stage) before
    it counts as a second pose."""
    s, model_of = services.settings, services.model_of

    def refine(r: FitResult) -> FitResult:  # a second pose, finished as a leader is
        fit = fine_stage(
            ctx, model_of(r), r.T_scene_model[:3, :3], r.T_scene_model[:3, 3], s.stages.fine, s
        )
        return result(ctx, fit.models[0], fit.R[0], fit.t[0], s)

    with single_threaded_blas():
        return ambiguity.assess(ctx, candidates, alternatives, model_of, s, refine)


@stage("assess")
def run(state: FitState) -> FitState:
    """The state with its :class:`..ambiguity.Ambiguity`."""
    return replace(
        state,
        ambiguity=ambiguity_of(state.services, state.ctx, state.candidates, state.alternatives),
    )
