# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Hypothesise (``hypotheses`` settings): where ICP starts for every template -- the mounting
plane's yaw sweep, the template's resting facets on that plane, uniform random orientations
(:func:`..hypotheses.initial_hypotheses`) -- and, for a template that comes in sizes, the same
at both ends of its scale range; for one whose sliding part travels farther than the verdict's
``explained_distance``, the same with the part at the far end of its travel.

Fitted closed, a gate valve whose stem is out 30 mm leaves its wheel unexplained, and the rigid
fit tilts the body to reach it (55 deg off on an articulated board, ranked below a cylinder that
does not fit either); the joint's estimate, started there, cannot come back. A turning part
stays where the fixed part puts it and is found by the joint's sweep
(:mod:`.articulate`); a part that slides by less than the verdict's explained distance is the
same shape to the coarse stage.
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
    ``settings.articulated`` a template that comes in sizes also at both ends of its range,
    one with a sliding part (a prismatic joint) also with the part at each end of its travel
    farther than ``verdict.explained_distance`` from zero -- and the index into ``names`` of
    each: (models, indices (M,))."""
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
        far = services.settings.verdict.explained_distance
        out += [
            (i, services.models.model(tpl, q, 1.0, articulated=True))
            for i, tpl in enumerate(tpls)
            if tpl.joint is not None and tpl.joint.type == "prismatic"
            for q in (tpl.joint.lower, tpl.joint.upper)
            if abs(q) > far
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
