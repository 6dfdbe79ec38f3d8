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

from ..scene import ClickContext
from .settings import FitSettings

__all__ = ["visible", "facing"]


def facing(ctx: ClickContext, X: np.ndarray, Nw: np.ndarray, settings: FitSettings) -> np.ndarray:
    """Which posed samples X (B, S, 3) with normals Nw (B, S, 3) face the sensor, not beyond
    the grazing angle (sensors return nothing there); (B, S) bool, all True without a
    viewpoint."""
    if ctx.sensor_origin is None:
        return np.ones(X.shape[:-1], bool)
    ray = ctx.sensor_origin - X
    cos_in = np.einsum("bsi,bsi->bs", Nw, ray) / np.maximum(np.linalg.norm(ray, axis=-1), 1e-9)
    return cos_in > math.cos(settings.grazing_angle)


def visible(ctx: ClickContext, X: np.ndarray, Nw: np.ndarray, settings: FitSettings,
            exposed: bool = False):
    """(seen, violated), both (B, S) bool, for posed samples X (B, S, 3) with normals Nw
    (B, S, 3) in the scene frame: seen = facing the sensor with a return that is not in front of
    them; violated = facing it while the sensor saw through where they would be. With
    ``exposed`` also the samples facing the sensor in a direction it returned something, hidden
    or not (what a fit's coverage is judged over)."""
    front = facing(ctx, X, Nw, settings)
    if ctx.range_image is None:
        none = np.zeros_like(front)
        return (front, none, front) if exposed else (front, none)
    obs, depth = ctx.range_image.lookup(X)
    m = settings.free_space_margin
    known = np.isfinite(obs)
    hidden = known & (obs < depth - m)
    violated = known & (obs > depth + m)
    seen = front & known & ~hidden
    return (seen, front & violated, front & known) if exposed else (seen, front & violated)
