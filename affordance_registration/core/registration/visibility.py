# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Which posed template samples the sensor could have seen: the one place that reasons about
the sensor's view of a hypothesis (a range image of the crop looking along the ray from the
sensor origin to the click: no axis of the scene's frame is special).

A sample counts when it faces the sensor (not beyond the grazing angle) and the sensor's return
in its direction is not in front of it (hidden behind observed surfaces); a sample the sensor saw
through (its return lies behind the sample) violates free space. A direction with no return at
all (a dropout, nothing scanned there) is no evidence either way: such samples neither pull nor
count.

Without a viewpoint (a cloud with no single sensor origin) there are no visibility terms: every
sample counts and none violates free space.
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import view_array
from ..memo import per_object
from ..scene import ClickContext
from .settings import FitSettings

__all__ = ["visible", "facing", "compiled_view"]


def facing(ctx: ClickContext, X: np.ndarray, Nw: np.ndarray, settings: FitSettings) -> np.ndarray:
    """Which posed samples X (B, S, 3) with normals Nw (B, S, 3) face the sensor, not beyond
    the grazing angle (sensors return nothing there); (B, S) bool, all True without a
    viewpoint."""
    if ctx.sensor_origin is None:
        return np.ones(X.shape[:-1], bool)
    return _facing(X - ctx.sensor_origin, Nw, settings.scoring.grazing_angle)


def _facing(D: np.ndarray, Nw: np.ndarray, grazing_angle: float) -> np.ndarray:
    """:func:`facing` of the samples' offsets D (..., 3) from the sensor origin: the cosine of
    the angle between a normal and the ray back to the sensor, -Nw . D / |D|, above
    cos(grazing_angle) -- compared squared, without a division or a square root (the sums of
    three products written out: a reduction over a last axis of length 3 costs more than the
    arithmetic)."""
    c = math.cos(grazing_angle)
    dn = D * Nw
    dot = dn[..., 0] + dn[..., 1] + dn[..., 2]  # -|D| cos(incidence)
    dd = D * D
    n2 = np.maximum(dd[..., 0] + dd[..., 1] + dd[..., 2], 1e-18)
    if c >= 0.0:
        return (dot < 0.0) & (dot * dot > (c * c) * n2)
    return (dot < 0.0) | (dot * dot < (c * c) * n2)


def visible(
    ctx: ClickContext,
    X: np.ndarray,
    Nw: np.ndarray,
    settings: FitSettings,
    exposed: bool = False,
    occluded: np.ndarray | None = None,
):
    """(seen, violated), both (B, S) bool, for posed samples X (B, S, 3) with normals Nw
    (B, S, 3) in the scene frame: seen = facing the sensor with a return that is not in front of
    them; violated = facing it while the sensor saw through where they would be. With
    ``exposed`` also the samples facing the sensor in a direction it returned something, hidden
    or not (what a fit's coverage is judged over) -- in the rows ``occluded`` (B,) bool marks,
    not those hidden ``verdict.occluder_gap`` or more behind the return either, where something
    else stands in front of them."""
    origin, image = ctx.sensor_origin, ctx.range_image
    if origin is None:
        front = np.ones(X.shape[:-1], bool)
    else:
        D = X - origin  # the offsets the facing test and the range image share
        front = _facing(D, Nw, settings.scoring.grazing_angle)
    if image is None:
        none = np.zeros_like(front)
        return (front, none, front) if exposed else (front, none)
    shared = origin is not None and (
        image.origin is origin or np.array_equal(image.origin, origin)
    )
    obs, depth = image.lookup_offsets(D) if shared else image.lookup(X)
    m = settings.scoring.free_space_margin
    # NaN (no return) compares False: an unknown direction is neither hidden nor violated
    known = front & (obs == obs) if exposed else None
    if exposed and occluded is not None and occluded.any():
        known[occluded] &= obs[occluded] >= depth[occluded] - settings.verdict.occluder_gap
    seen = front & (obs >= depth - m)
    violated = front & (obs > depth + m)
    return (seen, violated, known) if exposed else (seen, violated)


def compiled_view(ctx: ClickContext, settings: FitSettings, band: float, d0: float):
    """What :func:`visible` reads of the click, and the plane band (samples within ``band`` of
    the plane pair with it) and the weight scale ``d0`` of the correspondences, as the compiled
    ICP step takes them: (view, frame, depth) -- kept with the click for these settings."""

    def make():
        image, plane = ctx.range_image, ctx.plane
        fields = {"d0": d0}
        if ctx.sensor_origin is not None:
            fields.update(
                origin=ctx.sensor_origin, cos_grazing=math.cos(settings.scoring.grazing_angle)
            )
        if image is not None:
            fields.update(
                image_origin=image.origin,
                u0=image.u0,
                v0=image.v0,
                bin=image.bin,
                nu=image.nu,
                nv=image.nv,
                margin=settings.scoring.free_space_margin,
            )
        if plane is not None:
            fields.update(normal=plane.normal, plane_d=plane.d, band=band)
        frame = np.ascontiguousarray(image.frame if image is not None else np.eye(3), float)
        depth = image.depth_or_nan if image is not None else np.full(1, np.nan)
        return view_array(**fields), frame, np.ascontiguousarray(depth, float)

    key = (
        "compiled view",
        settings.scoring.grazing_angle,
        settings.scoring.free_space_margin,
        band,
        d0,
    )
    return per_object(ctx, key, make)
