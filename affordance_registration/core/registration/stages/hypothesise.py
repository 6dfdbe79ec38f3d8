# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Hypothesise (``hypotheses`` settings): where ICP starts for every template -- the mounting
plane's yaw sweep, the template's resting facets on that plane, uniform random orientations
(:func:`..hypotheses.initial_hypotheses`) -- and, for a template that comes in sizes, the same
at both ends of its scale range.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..hypotheses import initial_hypotheses
from ..services import Services
from ..state import FitState, stage

__all__ = ["variants", "run"]


def variants(services: Services, names) -> tuple:
    """The models the hypotheses start from -- every template rigid, and with
    ``settings.articulated`` a template that comes in sizes also at both ends of its range
    -- and the index into ``names`` of each: (models, indices (M,))."""
    tpls = [services.library[n] for n in names]
    out = [(i, services.models.model(tpl)) for i, tpl in enumerate(tpls)]
    if services.settings.articulated:
        out += [
            (i, services.models.model(tpl, 0.0, g, articulated=True))
            for i, tpl in enumerate(tpls)
            if tpl.scale_range is not None
            for g in tpl.scale_range
            if g != 1.0
        ]
    return [m for _, m in out], np.array([i for i, _ in out])


@stage("hypothesise")
def run(state: FitState) -> FitState:
    """The initial hypotheses of every template to fit, each labelled with its template's
    index in ``state.specific`` (drawn from the seed: a fit is deterministic)."""
    models, template_of = variants(state.services, state.specific)
    rng = np.random.default_rng(state.settings.seed)
    hyps = initial_hypotheses(state.ctx, models, state.settings, rng).relabelled(template_of)
    return replace(state, hyps=hyps)
