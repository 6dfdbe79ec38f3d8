# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Primitives: the library's boxes and cylinders measured on the clicked object
(:mod:`..primitives`), judged like any candidate, and ranked with the fitted templates -- a
specific template that fits ranks above them, and must show the sensor what sets it apart from
the primitive that fits the same click (:meth:`..services.Services.distinguished`). Where no
specific template fits, the primitives that may lead are refined, and boxes stacked that the
segments took for one object are measured on the clicked one.

An object that runs past the crop is measured again in a crop ``WIDER`` times as large: a box
longer than the library's templates is still a box; a wall runs past that one too, and is
refused.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ...click_context import ClickContext
from ...scene import Scene
from ..explains import explanation
from ..hidden_parts import hidden_parts, with_hidden_parts
from ..model import surface_distances
from ..primitives import (
    REFINE_SHARE,
    fit_primitive,
    object_points,
    object_voxels,
    past_crop,
    refine_primitive,
    stacked,
    truncated,
)
from ..results import FitResult, rank
from ..scoring import described, widening
from ..services import Services
from ..state import FitState, stage
from .prepare import click_context

__all__ = ["WIDER", "run", "measure", "measured_on", "measured", "seen", "refit"]

#: a primitive's object running past the crop (:func:`..primitives.truncated`) is measured again
#: in a crop this many times as large
WIDER = 2.0


@stage("primitives")
def run(state: FitState) -> FitState:
    """The candidates with the primitives ``state.primitives`` measured, ranked together
    (refined where no specific template fits; else the fitting templates distinguished from
    them, and refined after all where none fits then); the primitives are kept for the
    click's refits (:class:`..services.PrimitivesSeen`)."""
    if not state.primitives:
        return state
    services, ctx, names = state.services, state.ctx, state.primitives
    candidates = state.candidates
    # (a specific template that fits ranks above them: they are not refined ...)
    refine = not any(r.fits for r in candidates)
    fitted = measure(services, ctx, names, state.scene, refine)
    if not refine:
        # ... when the scan shows what sets it apart from the primitive
        candidates = services.distinguished(ctx, candidates, fitted)
        if not any(r.fits for r in candidates):
            fitted = measure(services, ctx, names, state.scene, True)
    services.seen.remember(ctx, fitted)
    return replace(state, candidates=rank(list(candidates) + fitted))


def measure(
    services: Services, ctx: ClickContext, names, scene: Scene | None = None, refine: bool = True
) -> list:
    """The primitive templates ``names``, measured and refined (:mod:`..primitives`), judged;
    with ``refine``, those that may lead refined (:func:`..primitives.refine_primitive`). An
    object that runs past the crop is measured again in a crop WIDER times as large (from
    ``scene``). With ``refine`` (no specific template fits), where none fits or a box does,
    boxes stacked that the segments took for one object (:func:`..primitives.stacked`) are
    measured and judged on the clicked one."""
    t0 = time.perf_counter()
    ctx, points, past = measured(services, ctx.with_insides(), scene)  # once for them all
    judged = measured_on(services, ctx, scene, names, points, refine)
    lead = max(judged, key=lambda r: (bool(r.fits), r.likelihood))  # (a box has one top)
    cut = stacked(ctx, points) if refine and (not lead.fits or lead.primitive == "box") else None
    if cut is not None:
        on_part = measured_on(services, cut[0], scene, names, cut[1], refine)
        judged = on_part if any(r.fits for r in on_part) else judged
    total = time.perf_counter() - t0
    return past_crop(ctx, past, [replace(r, time_s=total) for r in judged])


def measured_on(services: Services, ctx: ClickContext, scene, names, points, refine: bool) -> list:
    """The primitives ``names`` measured on ``points`` (:func:`..primitives.object_points`'
    tuple) and on it with the pieces something in front splits off
    (:func:`..hidden_parts.with_hidden_parts`), those that may lead refined with ``refine``,
    judged in ``ctx`` -- also against each other: one that fits but describes the object
    decisively worse than another that fits is refused (:func:`..scoring.described`)."""
    library, s = services.library, services.settings

    def fit_on(on, k):
        return fit_primitive(ctx, library[names[k]], services.models, s, measured=on, refine=False)

    fitted, pieces = with_hidden_parts(
        ctx,
        scene,
        points,
        [fit_on(points, k) for k in range(len(names))],
        fit_on,
        services.model_of,
        s,
    )
    # (refining costs an ICP: only the primitives that may lead are refined)
    lead = max(r.likelihood for r in fitted)
    judged = services.judged(
        ctx,
        [
            refine_primitive(ctx, library[n], services.models, s, r)
            if refine and r.likelihood >= REFINE_SHARE * lead
            else r
            for n, r in zip(names, fitted)
        ],
    )
    judged = explained(services, ctx, scene, judged, points[0], pieces)
    # (of two that explain it, the one that describes it decisively worse is refused)
    return described(ctx, [services.model_of(r) for r in judged], judged, s)


def explained(
    services: Services, ctx: ClickContext, scene, judged: list, region: np.ndarray, pieces
) -> list:
    """The ``judged`` primitives, each refused where it does not explain the clicked object
    -- the whole of it and only it (:func:`..explains.explanation`: ``verdict.min_recall``
    of the object's points on its surface, ``verdict.min_precision`` of the scan's points on
    its surface the object's) -- with its ``recall`` and ``precision``. ``region``: the points
    it was measured on; ``pieces``: per primitive, the points of the pieces an occluder split
    off that it was measured with (N, 3) -- they are the object's. Without a viewpoint (no
    segments to tell the object from its neighbours) they stand as judged."""
    if ctx.sensor_origin is None or not judged:
        return list(judged)
    v = services.settings.verdict
    near = scene.around(ctx.click, ctx.radius) if scene is not None else None
    scan = ctx.crop if near is None else near.points
    voxels = object_voxels(ctx)
    parts = [q for q, _ in hidden_parts(ctx, scene, services.settings)]
    out = []
    for r, extra in zip(judged, pieces):
        e = explanation(
            ctx,
            services.model_of(r),
            r.T_scene_model,
            np.concatenate([region, extra]),
            scan,
            voxels,
            parts,
            services.settings,
        )
        why = [
            f"it explains {e.recall:.0%} of the clicked object (a fit needs {v.min_recall:.0%})"
            if e.recall < v.min_recall
            else "",
            f"{1 - e.precision:.0%} of what lies on its surface is not the clicked object (a "
            f"fit allows {1 - v.min_precision:.0%})"
            if e.precision < v.min_precision
            else "",
        ]
        why = "; ".join(w for w in why if w)
        r = replace(r, recall=e.recall, precision=e.precision)
        if why:
            r = replace(r, fits=False, reason=f"{r.reason}; {why}" if r.reason else why)
        out.append(r)
    return out


def measured(services: Services, ctx: ClickContext, scene: Scene | None) -> tuple:
    """(the context, the clicked object's points in it, whether they run past its crop).
    Where they run past ``ctx``'s, they are measured again in a crop WIDER times as large
    from ``scene``, kept where they run past ``ctx``'s crop there too; else ``ctx`` held
    all of it (the wider crop's coarser segments split it: a box another stands on)."""
    points = object_points(ctx)
    past = truncated(ctx, points)
    if not past or scene is None:
        return ctx, points, past
    wide = click_context(services, scene, ctx.click, WIDER * ctx.radius).with_insides()
    again = object_points(wide)
    return (wide, again, truncated(wide, again)) if truncated(ctx, again) else (ctx, points, False)


def pieces_on(services: Services, ctx: ClickContext, scene, res: FitResult) -> np.ndarray:
    """The points (N, 3) of the pieces an occluder splits off the clicked object
    (:func:`..hidden_parts.hidden_parts`) that the primitive ``res`` lies on -- at least
    ``verdict.min_explained`` of each within the verdict's ``explained_distance``, as at the
    click (:func:`..hidden_parts.with_hidden_parts`)."""
    s = services.settings
    parts = hidden_parts(ctx, scene, s)
    if not parts:
        return np.zeros((0, 3))
    model, T = services.model_of(res), res.T_scene_model
    within = widening(ctx, s) * s.verdict.explained_distance
    on = [
        q
        for q, _ in parts
        if np.mean(
            surface_distances([model], ((q - T[:3, 3]) @ T[:3, :3])[None], 2 * within)[0] <= within
        )
        >= s.verdict.min_explained
    ]
    return np.concatenate(on) if on else np.zeros((0, 3))


def seen(services: Services, ctx: ClickContext, scene: Scene | None = None) -> list:
    """The library's primitives fitted to ``ctx``'s click: those its fit found (kept for
    the last ``PRIMITIVES_KEPT`` click contexts), else measured now (and kept); none
    without a viewpoint."""
    library = services.library
    names = [n for n in library if library[n].primitive is not None]
    if not names or ctx.sensor_origin is None:
        return []
    hit = services.seen.get(ctx)
    if hit is not None:
        return hit
    fitted = measure(services, ctx, names, scene, refine=False)
    services.seen.remember(ctx, fitted)
    return fitted


def refit(
    services: Services,
    ctx: ClickContext,
    template: str,
    T_init: np.ndarray,
    dimensions: dict | None = None,
    scene: Scene | None = None,
) -> FitResult:
    """The primitive ``template`` measured again from ``T_init`` (an operator's correction),
    keeping ``dimensions`` as given (without them they are measured again), judged; on a
    stack, as at the click, on the clicked box where that fits (:func:`measure`)."""
    tpl, s = services.library[template], services.settings
    ctx = ctx.with_insides()
    wide, points, past = measured(services, ctx, scene)
    res = services.judged(
        ctx,
        [
            fit_primitive(
                ctx,
                tpl,
                services.models,
                s,
                dimensions,
                T_init,
                points if wide is ctx else None,
            )
        ],
    )[0]
    res = explained(
        services, ctx, scene, [res], points[0], [pieces_on(services, ctx, scene, res)]
    )[0]
    cut = stacked(ctx, points) if wide is ctx and not res.fits else None
    if cut is not None:
        alt = services.judged(
            cut[0], [fit_primitive(cut[0], tpl, services.models, s, dimensions, T_init, cut[1])]
        )[0]
        alt = explained(services, cut[0], scene, [alt], cut[1][0], [np.zeros((0, 3))])[0]
        res = alt if alt.fits else res
    return past_crop(wide, past, [res])[0]
