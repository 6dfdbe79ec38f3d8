# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Judge (``verdict`` settings): the absolute verdict on every fitted candidate, whatever the
others score (:func:`..scoring.judge`: coverage of what the sensor could see, the share of the
clicked object explained, the object residual; ``fits`` or not). Those the prefilter set aside
have coarse poses: they are not judged (``fits`` None) until a refit fits them -- the engine's,
when one is first shown.
"""

from __future__ import annotations

import time
from dataclasses import replace

from ..results import rank
from ..state import FitState, stage

__all__ = ["run"]


@stage("judge")
def run(state: FitState) -> FitState:
    """The candidates judged and ranked again, each with the method's time (``time_s``: its
    stages' so far, this one's included)."""
    t0 = time.perf_counter()
    ranked = state.candidates
    fitted = [r for r in ranked if not r.prefiltered]
    judged = state.services.judged(state.ctx, fitted) + [r for r in ranked if r.prefiltered]
    total = state.fit_seconds() + time.perf_counter() - t0
    return replace(state, candidates=rank([replace(r, time_s=total) for r in judged]))
