# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Articulate (``articulation`` settings): the joint value and scale of the articulated
templates among the leading candidates (:func:`..articulation.articulate`), with
``settings.articulated``. A rigid fit of a valve with its handle turned can rank behind a wrong
template; estimated, it can lead.
"""

from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

from ..articulation import articulate
from ..parallel import run as side_by_side
from ..results import FitResult, rank
from ..scoring import result
from ..state import FitState, stage

__all__ = ["run"]


@stage("articulate")
def run(state: FitState) -> FitState:
    """The candidates with the articulated leaders' joint values and scales (at most
    ``articulation.candidates``, residual within ``articulation.margin`` of the best; not one
    that cannot come to fit, :meth:`..services.Services.worth`), ranked again; each one's
    articulated model in ``state.articulated``. The best first (the others' margin is to its
    estimate), then the others side by side."""
    s, ctx, services = state.settings, state.ctx, state.services
    if not s.articulated:
        return state
    library, iterations = services.library, state.hyps.iterations
    ranked, models = state.candidates, {}

    def estimate(r: FitResult):
        tpl = library[r.template]
        start = services.models.model(tpl, tpl.joint_value(r.joints), r.scale, articulated=True)
        model, R, t, converged = articulate(
            ctx, start, r.T_scene_model[:3, :3], r.T_scene_model[:3, 3], s
        )
        return model, result(ctx, model, R, t, s, iterations, converged)

    leaders = [r for r in ranked[: s.articulation.candidates] if library[r.template].articulated]
    for first in (True, False):
        todo = services.worth(
            ctx,
            [
                r
                for r in leaders
                if (r.template == ranked[0].template) == first
                and r.residual <= s.articulation.margin * ranked[0].residual
            ],
            {},
            s.articulation.explained_margin,
        )[0]
        for r, (model, res) in zip(
            todo, side_by_side([lambda r=r: estimate(r) for r in todo], s.threads)
        ):
            models[r.template] = model
            ranked = tuple(res if x.template == r.template else x for x in ranked)
    return replace(state, candidates=rank(ranked), articulated=MappingProxyType(models))
