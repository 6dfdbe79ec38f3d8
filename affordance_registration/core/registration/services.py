# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What every stage of a fit uses and none owns (:class:`Services`, one per registrar): the
template library, the settings, the model cache -- the model a candidate was fitted as -- and
the verdict on candidates (:func:`.scoring.judge`, :func:`.scoring.distinguished`), plus the
primitives fitted to the last few clicks, which a refit's verdict asks again
(:class:`PrimitivesSeen`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ..click_context import ClickContext
from ..templates import TemplateLibrary
from .model import Model, ModelCache
from .results import FitResult
from .scoring import distinguished, explained_share, judge
from .settings import FitSettings

__all__ = ["Services", "PrimitivesSeen", "PRIMITIVES_KEPT", "WORTH_POINTS"]

#: the click contexts whose primitive fits are kept for their refits' verdicts
PRIMITIVES_KEPT = 8
#: :meth:`Services.worth` judges a leader's explained share on an even subsample of this many
#: cluster points (its margins are wide: a few points' noise does not matter)
WORTH_POINTS = 400


class PrimitivesSeen:
    """The primitives fitted to the last ``kept`` clicks, by their click context (a refit's
    verdict asks what the click's asked). Thread-safe."""

    def __init__(self, kept: int = PRIMITIVES_KEPT):
        self._kept = int(kept)
        self._lock = threading.Lock()
        self._seen: OrderedDict = OrderedDict()  # id(context) -> (context, fitted)

    def get(self, ctx: ClickContext) -> list | None:
        """The primitives fitted to ``ctx``'s click, or None when they are not kept."""
        with self._lock:
            hit = self._seen.get(id(ctx))
        return hit[1] if hit is not None and hit[0] is ctx else None

    def remember(self, ctx: ClickContext, fitted) -> None:
        """Keep ``fitted`` for ``ctx`` (the oldest click dropped beyond ``kept``)."""
        with self._lock:
            self._seen[id(ctx)] = (ctx, list(fitted))
            self._seen.move_to_end(id(ctx))
            while len(self._seen) > self._kept:
                self._seen.popitem(last=False)


@dataclass(frozen=True, eq=False)
class Services:
    """The library, the settings, the model cache and the primitives seen, shared by every
    stage of every fit of one registrar; and what the stages ask of them."""

    library: TemplateLibrary
    settings: FitSettings
    models: ModelCache = field(default_factory=ModelCache)
    seen: PrimitivesSeen = field(default_factory=PrimitivesSeen)

    def model(
        self,
        template: str,
        joints: dict | None = None,
        scale: float = 1.0,
        dimensions: dict | None = None,
    ) -> Model:
        """The model to fit: with ``settings.articulated``, an articulated template posed at
        ``joints`` (clipped to its limits) and ``scale`` (clipped to its range); else rigid.
        A primitive at ``dimensions`` (clipped to its ranges)."""
        base = self.library[template]
        if base.primitive is not None:
            return self.models.model(base.sized(dimensions or base.dimensions))
        if not (self.settings.articulated and base.articulated):
            return self.models.model(base)
        j = base.joint
        q = float(np.clip(base.joint_value(joints or {}), j.lower, j.upper)) if j else 0.0
        lo_hi = base.scale_range
        scale = float(np.clip(scale, *lo_hi)) if lo_hi is not None else 1.0
        return self.models.model(base, q, scale, articulated=True)

    def model_of(self, r: FitResult) -> Model:
        """The model the candidate ``r`` was fitted as."""
        return self.model(r.template, r.joints, r.scale, r.dimensions)

    def judged(self, ctx: ClickContext, results) -> list:
        """Each result with its verdict (:func:`.scoring.judge`)."""
        results = list(results)
        return judge(ctx, [self.model_of(r) for r in results], results, self.settings)

    def distinguished(self, ctx: ClickContext, candidates, primitives) -> list:
        """``candidates`` with the fitting specific ones tested against the primitive that
        stands for the clicked object (:func:`.scoring.distinguished`): the best fitting of
        ``primitives``, else the one that explains the most of the object where that is at
        least ``verdict.min_recall`` (it may be refused for what else lies on its surface: it
        is still what the object's points are, as far as a primitive can say); unchanged
        without one."""
        fitting = [r for r in primitives if r.fits]
        if not fitting:
            bar = self.settings.verdict.min_recall
            fitting = [r for r in primitives if r.recall is not None and r.recall >= bar]
            if not fitting:
                return list(candidates)
            fitting = [max(fitting, key=lambda r: r.recall)]
        best = max(fitting, key=lambda r: r.likelihood)
        tested = [r for r in candidates if r.fits and r.primitive is None]
        done = dict(
            zip(
                map(id, tested),
                distinguished(
                    ctx,
                    [self.model_of(r) for r in tested],
                    tested,
                    self.model_of(best),
                    best,
                    self.settings,
                ),
            )
        )
        return [done.get(id(r), r) for r in candidates]

    def worth(self, ctx: ClickContext, leaders, models: dict, margin: float) -> tuple:
        """(the ``leaders`` to work on, those left as they are): a leader that explains less
        than ``verdict.min_explained - margin`` of the clicked object's points
        (:func:`.scoring.explained_share`) cannot come to fit -- a valve in a box's points --
        and is not worked on. ``models``: template -> the model a leader is fitted as, where
        it is not its result's (articulated). Without a viewpoint (no such share) every
        leader is."""
        s = self.settings
        leaders = list(leaders)
        floor = s.verdict.min_explained - margin
        if ctx.sensor_origin is None or floor <= 0.0:
            return leaders, []
        share = explained_share(
            ctx,
            [models.get(r.template) or self.model(r.template, r.joints, r.scale) for r in leaders],
            leaders,
            s,
            WORTH_POINTS,
        )
        return (
            [r for r, e in zip(leaders, share) if e >= floor],
            [r for r, e in zip(leaders, share) if e < floor],
        )
