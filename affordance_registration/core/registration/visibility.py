"""Which posed template samples the sensor could have seen: the one place that reasons about
the sensor's view of a hypothesis (a range image of the crop, binned about the sensor origin).

A sample counts when it faces the sensor (not beyond the grazing angle) and the sensor's return
in its direction is not in front of it (hidden behind observed surfaces); a sample the sensor saw
through (its return lies behind the sample) violates free space. A direction with no return at
all (outside the image, a dropout) is no evidence either way: such samples neither pull nor count.
"""
from __future__ import annotations

import math

import numpy as np

from ..scene import ClickContext
from .settings import FitSettings

__all__ = ["visible"]


def visible(ctx: ClickContext, X: np.ndarray, Nw: np.ndarray, settings: FitSettings):
    """(seen, violated), both (B, S) bool, for posed samples X (B, S, 3) with normals Nw
    (B, S, 3) in the scene frame: seen = facing the sensor with a return that is not in front of
    them; violated = facing it while the sensor saw through where they would be."""
    ray = ctx.sensor_origin - X
    cos_in = np.einsum("bsi,bsi->bs", Nw, ray) / np.maximum(np.linalg.norm(ray, axis=-1), 1e-9)
    facing = cos_in > math.cos(settings.grazing_angle)  # sensors return nothing at grazing angles
    obs, z = ctx.range_image.lookup(X)
    m = settings.free_space_margin
    known = np.isfinite(obs)
    hidden = known & (obs < z - m)
    violated = known & (obs > z + m)
    return facing & known & ~hidden, facing & violated
