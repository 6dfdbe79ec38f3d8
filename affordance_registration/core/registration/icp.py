"""Weighted ICP: one loop for every stage. A batch of hypotheses advances together (one KD query
per iteration); the rejection radius shrinks from the stage's reach to ``reject_floor``; the
loop stops once every hypothesis has converged (its step turns it less than
``CONVERGED_ROTATION``, moves its weighted centroid less than ``CONVERGED_TRANSLATION`` and
changes its joint value and scale less than ``CONVERGED_EXTRA``) or at the stage's iteration
limit.

On the voxelized cluster the step is point to point (closed-form weighted SVD). On the
full-resolution cluster (the fine stage) scene points are paired with the template too, and the
step is point to plane (it does not creep along flat or cylindrical surfaces), with a column per
extra unknown -- a joint value, a scale -- besides the six of the pose.
"""
from __future__ import annotations


import numpy as np

from ..scene import ClickContext
from ..transforms import pose_points, rotate
from .correspondences import (Pairs, contact_rows, forward_pairs, in_contact, reverse_rows,
                              stack_samples)
from .model import Batch, Model
from .results import IcpResult
from .settings import (CONVERGED_EXTRA, CONVERGED_ROTATION, CONVERGED_TRANSLATION, FINE,
                       JOINT_STEP_LIMIT, SAMPLE_SEED, SCALE_STEP_LIMIT, FitSettings, Stage)
from .solve import plane_step, rigid_step

__all__ = ["icp", "fine_stage", "radius_schedule", "JOINT", "SCALE"]

JOINT, SCALE = "joint", "scale"     #: the extra unknowns a stage may fit besides the pose


def radius_schedule(reject, floor, it: int, iterations: int):
    """The rejection radius of iteration ``it`` of ``iterations``: from ``reject`` down to
    ``floor``, geometrically."""
    return reject * (floor / reject) ** (it / max(iterations - 1, 1))


def icp(ctx: ClickContext, batch: Batch, stage: Stage, settings: FitSettings, reject=None,
        unknowns: tuple = (), contact: bool = False) -> IcpResult:
    """Weighted ICP of a batch of hypotheses. ``reject`` (B,) in m overrides the stage's
    reach. ``unknowns`` (fine stage only):
    JOINT and/or SCALE, fitted with the pose (every model has them); ``contact``: the lowest
    samples also pair with the plane under the click (the fit rests on it)."""
    fine = stage.target == FINE
    posing = _Posing(batch.models, stage.samples, unknowns)
    R, t = np.array(batch.R, dtype=float), np.array(batch.t, dtype=float)
    if reject is None:
        reject = stage.reject * np.array([m.diameter for m in batch.models])
    reject = np.asarray(reject, dtype=float)
    floor = np.minimum(reject, settings.reject_floor)
    converged = np.zeros(len(batch), bool)
    it = -1
    for it in range(stage.iterations):
        radius = radius_schedule(reject, floor, it, stage.iterations)
        X, Nw, U, moving = posing.posed(R, t)
        Q, Nq, w = forward_pairs(ctx, stage.target, X, Nw, radius, settings, normals=fine)
        pairs = forward = Pairs(X, Q, Nq, w, U, moving)
        if fine:
            pairs = pairs.joined(reverse_rows(ctx, Batch(tuple(posing.models), R, t), radius,
                                              settings))
        if contact:
            pairs = pairs.joined(contact_rows(ctx, forward, radius, settings))
        if fine:
            step = plane_step(pairs.X, pairs.Q, pairs.N, pairs.w, posing.columns(pairs, R),
                              posing.bounds())
        else:
            step = rigid_step(pairs.X, pairs.Q, pairs.w)
        R = step.R @ R
        t = np.einsum("bij,bj->bi", step.R, t) + step.t
        extra = posing.advance(step.extra)
        converged = (step.rotation < CONVERGED_ROTATION) & \
            (step.motion < CONVERGED_TRANSLATION) & (extra < CONVERGED_EXTRA)
        if converged.all():
            break
    return IcpResult(tuple(posing.models), R, t, it + 1, converged)


def fine_stage(ctx: ClickContext, model: Model, R, t, stage: Stage, settings: FitSettings,
               hold_joint: bool = False, hold_scale: bool = False) -> IcpResult:
    """One hypothesis alone on the full-resolution target. An articulated model's joint value
    and scale are unknowns besides the pose (``hold_joint`` / ``hold_scale`` keep them as
    given); such a fit resting on the plane under the click keeps resting on it."""
    tpl = model.template
    unknowns = () if not model.articulated else \
        ((JOINT,) if tpl.joint is not None and not hold_joint else ()) + \
        ((SCALE,) if tpl.scale_range is not None and not hold_scale else ())
    contact = bool(unknowns) and in_contact(ctx, model, R, t, settings)
    return icp(ctx, Batch.single(model, R, t), stage, settings, unknowns=unknowns,
               contact=contact)


class _Posing:
    """The samples of a batch of hypotheses, posed every iteration -- with extra unknowns at
    each model's current joint value and scale -- and those unknowns' columns, bounds and
    updates."""

    def __init__(self, models, n: int, unknowns: tuple):
        self.models, self.unknowns = list(models), tuple(unknowns)
        if not self.unknowns:
            self.P, self.N = stack_samples(models, n)
        else:
            self.parts = [m.template.part_samples(n, seed=SAMPLE_SEED) for m in models]

    def posed(self, R, t):
        """(X, Nw) the samples in the scene (B, S, 3); with extra unknowns also U, the samples
        unscaled in the model frame (B, S, 3), and which are on the moving part (B, S)."""
        if not self.unknowns:
            U, moving, P, N = None, None, self.P, self.N
        else:
            posed = [m.template.pose_parts(P0, N0, mov, m.q)
                     for m, (P0, N0, mov) in zip(self.models, self.parts)]
            U = np.stack([p[0] for p in posed])
            N = np.stack([p[1] for p in posed])
            moving = np.stack([mov for _, _, mov in self.parts])
            P = U * np.array([m.scale for m in self.models])[:, None, None]
        return pose_points(R, t, P), rotate(R, N), U, moving

    def columns(self, pairs: Pairs, R) -> np.ndarray | None:
        """d(x . n) / d(value) of every row for each extra unknown, (B, S, k) or None."""
        if not self.unknowns:
            return None
        cols = []
        for name in self.unknowns:
            if name == JOINT:
                du = np.stack([self._joint_motion(m, U) for m, U in zip(self.models, pairs.U)])
                du = du * pairs.moving[..., None] * \
                    np.array([m.scale for m in self.models])[:, None, None]
            else:
                du = pairs.U
            cols.append(np.einsum("bsi,bsi->bs", rotate(R, du), pairs.N))
        return np.stack(cols, axis=-1)

    @staticmethod
    def _joint_motion(model: Model, U: np.ndarray) -> np.ndarray:
        """d U / d q of the moving part's points U (S, 3): about or along the joint axis."""
        j = model.template.joint
        axis = np.asarray(j.axis)
        if j.type == "revolute":
            return np.cross(axis, U - np.asarray(j.origin))
        return np.broadcast_to(axis, U.shape)

    def _limits(self, model: Model):
        """(value, lower, upper, largest step) of each extra unknown of ``model``."""
        out = []
        for name in self.unknowns:
            if name == JOINT:
                j = model.template.joint
                out.append((model.q, j.lower, j.upper, (j.upper - j.lower) * JOINT_STEP_LIMIT))
            else:
                lo, hi = model.template.scale_range
                out.append((model.scale, lo, hi, SCALE_STEP_LIMIT))
        return np.array(out, dtype=float).reshape(len(self.unknowns), 4)

    def bounds(self):
        """(values, lower, upper) of the extra unknowns, each (B, k), or None."""
        if not self.unknowns:
            return None
        lim = np.stack([self._limits(m) for m in self.models])
        return lim[..., 0], lim[..., 1], lim[..., 2]

    def advance(self, increments: np.ndarray) -> np.ndarray:
        """Apply the extra unknowns' increments (B, k), each limited to its largest step and
        kept within its bounds; returns the largest step taken per hypothesis (B,)."""
        if not self.unknowns:
            return np.zeros(len(self.models))
        lim = np.stack([self._limits(m) for m in self.models])
        steps = np.clip(increments, -lim[..., 3], lim[..., 3])
        values = np.clip(lim[..., 0] + steps, lim[..., 1], lim[..., 2])
        for b, m in enumerate(self.models):
            new = dict(zip(self.unknowns, values[b]))
            self.models[b] = m.with_values(q=new.get(JOINT), scale=new.get(SCALE))
        return np.abs(steps).max(axis=1)
