# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A local refit after the operator's correction: a few restarts around the corrected pose, a
short ICP, the best one that stays near the correction refined at full resolution -- and never
a result farther from the correction than the operator would accept.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene import ClickContext
from ..transforms import axis_angle_matrix, make_T, rotation_angle
from .icp import fine_stage, icp
from .model import Batch, Model
from .results import FitResult
from .scoring import forward_residual, result
from .settings import FitSettings

__all__ = ["refit", "refit_starts"]

REFIT_SEED_OFFSET = 7919  #: the refit's restarts draw from ``seed + REFIT_SEED_OFFSET``
REFIT_TURN = math.radians(4.0)  #: a refit's restarts turn up to this (at least half of it)


def refit(
    ctx: ClickContext, model: Model, T_init: np.ndarray, settings: FitSettings, hold_joint: bool
) -> FitResult:
    """Refine ``model`` locally from ``T_init`` (4x4): medium then fine ICP from
    :func:`refit_starts`. The result never strays farther than ``refit.max_move`` /
    ``refit.max_turn`` from ``T_init``: a refit that would jump back to a pose the operator
    moved away from keeps the closest acceptable pose instead. ``hold_joint`` keeps an
    articulated model's joint value as given."""
    s = settings
    Ts = refit_starts(ctx, model, T_init, s)
    T0 = Ts[0]
    n = len(Ts)
    # reach out as far as a refit may move, so a rough correction is pulled in
    reject = np.full(n, max(s.stages.short.reject * model.diameter, s.refit.max_move))
    starts = icp(
        ctx, Batch.of([model] * n, Ts[:, :3, :3], Ts[:, :3, 3]), s.stages.short, s, reject=reject
    )
    R, t = starts.R, starts.t
    fwd, _ = forward_residual(ctx, starts, s.medium.samples, s)
    allowed = _within_reach(T0, R, t, s, model.centroid)
    if not allowed.any():  # every restart wandered off: start from the correction itself
        R[0], t[0] = T0[:3, :3], T0[:3, 3]
        allowed[0] = True
    best = int(np.argmin(np.where(allowed, fwd, np.inf)))
    fit = fine_stage(ctx, model, R[best], t[best], s.stages.refit, s, hold_joint=hold_joint)
    iterations = starts.iterations + fit.iterations
    if _within_reach(T0, fit.R, fit.t, s, model.centroid)[0]:
        return result(ctx, fit.models[0], fit.R[0], fit.t[0], s, iterations, fit.converged[0])
    return result(ctx, fit.models[0], R[best], t[best], s, iterations, starts.converged[best])


def refit_starts(
    ctx: ClickContext, model: Model, T_init: np.ndarray, settings: FitSettings
) -> np.ndarray:
    """The refit's restarts (K, 4, 4): the correction itself; the correction moved onto the
    cluster points around it (a rough drag is often off by a good part of the object's size;
    along the plane, keeping the height the operator chose); small random turns and shifts
    of it (seeded)."""
    s = settings
    rng = np.random.default_rng(s.seed + REFIT_SEED_OFFSET)
    T0 = np.asarray(T_init, dtype=float)
    Ts = [T0]
    centre = T0[:3, :3] @ model.centroid + T0[:3, 3]
    data = ctx.cluster_mean_near(centre, 0.5 * model.diameter, min_points=10)
    if data is not None:
        snapped = T0.copy()
        snapped[:3, 3] += data - centre
        if ctx.plane is not None:  # keep the height above the plane the operator chose
            snapped[:3, 3] -= ctx.plane.normal * (ctx.plane.normal @ (snapped[:3, 3] - T0[:3, 3]))
        Ts.append(snapped)
    while len(Ts) < s.refit.restarts:
        axis = ctx.frame @ rng.normal(size=3)  # drawn in the frame attached to the scan
        dR = axis_angle_matrix(axis, REFIT_TURN * rng.uniform(0.5, 1.0))
        R = dR @ T0[:3, :3]
        t = (
            dR @ (T0[:3, 3] - centre)
            + centre
            + ctx.frame @ rng.normal(scale=s.refit.spread, size=3)
        )
        Ts.append(make_T(R, t))
    return np.stack(Ts)


def _within_reach(
    T0: np.ndarray, R: np.ndarray, t: np.ndarray, settings: FitSettings, centroid: np.ndarray
):
    """Which poses (R (B, 3, 3), t (B, 3)) lie within ``refit.max_move`` (of where they put the
    model's ``centroid``, model frame: wherever its file's origin lies) and ``refit.max_turn``
    of ``T0``, (B,) bool."""
    move = np.linalg.norm(R @ centroid + t - (T0[:3, :3] @ centroid + T0[:3, 3]), axis=1)
    turn = rotation_angle(np.swapaxes(T0[None, :3, :3], 1, 2) @ R)
    return (move <= settings.refit.max_move) & (turn <= settings.refit.max_turn)
