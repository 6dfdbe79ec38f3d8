"""Weighted ICP: a batch of hypotheses advanced together, one KD query per iteration; the
rejection radius shrinks from the stage's reach to ``reject_floor``; iterations stop early once
every hypothesis has converged.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import ClickContext
from ..transforms import axis_angle_matrix, rotation_angle
from .correspondences import (add_reverse_pairs, contact_rows,
                              forward_pairs, in_contact, reverse_pairs, reverse_subset,
                              stack_samples)
from .model import Model
from .settings import (CONVERGED_EXTRA, CONVERGED_ROTATION, CONVERGED_TRANSLATION, FINE,
                       JOINT_STEP_LIMIT, SCALE_STEP_LIMIT, FitSettings, Stage)
from .solve import bounded_least_squares, kabsch_weighted, point_to_plane_weighted

__all__ = ["icp", "fine_stage", "Refined", "radius_schedule"]


@dataclass(frozen=True)
class Refined:
    """One hypothesis after a fine stage: the model (its joint value and scale as fitted), the
    pose and the iterations it took (counting those before it)."""

    model: Model
    R: np.ndarray
    t: np.ndarray
    iterations: int


def radius_schedule(reject, floor, it: int, iterations: int):
    """The rejection radius of iteration ``it`` of ``iterations``: from ``reject`` down to
    ``floor``, geometrically."""
    return reject * (floor / reject) ** (it / max(iterations - 1, 1))


def icp(ctx: ClickContext, models, R, t, stage: Stage, settings: FitSettings, reject=None):
    """Weighted ICP for a batch of hypotheses. R (B, 3, 3), t (B, 3) model -> scene; ``reject``
    (B,) overrides the stage's reach (m). Returns the refined (R, t).

    Point-to-point with the closed-form weighted SVD; on the full-resolution target (the fine
    stage) two-way (scene points paired with the template too) and with the same weights in a
    point-to-plane step (closed-form 6x6 solve), which does not creep along flat or
    cylindrical surfaces."""
    point_to_plane = two_way = stage.target == FINE
    P, N = stack_samples(models, stage.samples)
    R = np.array(R, dtype=float)
    t = np.array(t, dtype=float)
    if reject is None:
        reject = stage.reject * np.array([m.diameter for m in models])
    reject = np.asarray(reject, dtype=float)
    floor = np.minimum(reject, settings.reject_floor)
    for it in range(stage.iterations):
        radius = radius_schedule(reject, floor, it, stage.iterations)
        X = np.einsum("bij,bsj->bsi", R, P) + t[:, None, :]
        Nw = np.einsum("bij,bsj->bsi", R, N)
        Q, Nq, w = forward_pairs(ctx, stage.target, X, Nw, radius, settings, point_to_plane)
        if two_way:
            X, Q, Nq, w = add_reverse_pairs(ctx, models, R, t, X, Q, Nq, w, radius, settings)
        if point_to_plane:
            dR, dt = point_to_plane_weighted(X, Q, Nq, w)
        else:
            dR, dt = kabsch_weighted(X, Q, w)
        R = dR @ R
        t = np.einsum("bij,bj->bi", dR, t) + dt
        if np.all(rotation_angle(dR) < CONVERGED_ROTATION) and \
                np.all(np.linalg.norm(dt, axis=1) < CONVERGED_TRANSLATION):
            break
    return R, t


def fine_stage(ctx: ClickContext, model: Model, R, t, stage: Stage, settings: FitSettings,
               hold_joint: bool = False, hold_scale: bool = False) -> Refined:
    """One hypothesis alone on the full-resolution target. An articulated model's joint value
    and scale are unknowns besides the pose (``hold_joint`` / ``hold_scale`` keep them as
    given): the two-way weighted point-to-plane step of :func:`icp` extended by a column per
    extra unknown (d x / d q: the moving part's motion about or along the joint axis; d x / d s:
    the unscaled posed point), solved in closed form each iteration (Gauss-Newton)."""
    tpl = model.template
    joint = None if hold_joint or not model.articulated else tpl.joint
    lo_hi = None if hold_scale or not model.articulated else tpl.scale_range
    if joint is None and lo_hi is None:     # nothing but the pose
        R2, t2 = icp(ctx, [model], R[None], t[None], stage, settings)
        return Refined(model, R2[0], t2[0], stage.iterations)
    s = settings
    iterations = stage.iterations
    d0 = s.weight_scale
    P0, N0, moving0 = tpl.part_samples(stage.samples, seed=1)
    q, sc = model.q, model.scale
    R, t = np.array(R, dtype=float), np.array(t, dtype=float)
    reject = stage.reject * model.diameter
    floor = min(reject, s.reject_floor)
    pts, normals = reverse_subset(ctx, s.reverse_points)
    axis = np.asarray(joint.axis) if joint is not None else None
    origin = np.asarray(joint.origin) if joint is not None else None
    contact = in_contact(ctx, model, R, t, s)
    it = 0
    for it in range(iterations):
        radius = radius_schedule(reject, floor, it, iterations)
        U, Nu = tpl.pose_parts(P0, N0, moving0, q)       # unscaled, joint at q
        X = (sc * U) @ R.T + t
        Q, Nq, w = forward_pairs(ctx, FINE, X[None], (Nu @ R.T)[None], np.array([radius]), s,
                                 True)
        Q, Nq, w, mov = Q[0], Nq[0], w[0], moving0
        # scene -> template pairs: each scene point with its nearest sample
        x_r, q_r, n_r, w_r, local_r, mov_r = reverse_pairs(
            model.with_values(q=q, scale=sc), R, t, pts, normals, radius, d0)
        X = np.vstack([X, x_r])
        Q = np.vstack([Q, q_r])
        Nq = np.vstack([Nq, n_r])
        w = np.concatenate([w, w_r])
        U = np.vstack([U, local_r / sc])
        mov = np.concatenate([mov, mov_r])
        if contact:     # the lowest samples rest on the plane (unseen: the object hides them)
            X, Q, Nq, w, U, mov = contact_rows(ctx, X, Q, Nq, w, U, mov, len(P0), radius, s)
        W = w.sum()
        if W < 1e-9:
            break
        c = (w[:, None] * X).sum(axis=0) / W
        cols = [np.cross(X - c, Nq), Nq]
        if joint is not None:
            du = (np.cross(axis, U - origin) if joint.type == "revolute"
                  else np.broadcast_to(axis, U.shape)) * mov[:, None]
            cols.append(np.einsum("si,si->s", (sc * du) @ R.T, Nq)[:, None])
        if lo_hi is not None:
            cols.append(np.einsum("si,si->s", U @ R.T, Nq)[:, None])
        J = np.concatenate(cols, axis=1)
        r = np.einsum("si,si->s", Q - X, Nq)
        # (value, lower, upper, largest step) of the extra unknowns, in column order
        extra = ([(q, joint.lower, joint.upper, (joint.upper - joint.lower) * JOINT_STEP_LIMIT)]
                 if joint is not None else []) + \
            ([(sc, lo_hi[0], lo_hi[1], SCALE_STEP_LIMIT)] if lo_hi is not None else [])
        xi = bounded_least_squares(J, r, w, [e[0] for e in extra], [e[1] for e in extra],
                                   [e[2] for e in extra])
        omega, v = xi[:3], xi[3:6]
        angle = float(np.linalg.norm(omega))
        dR = axis_angle_matrix(omega, angle) if angle > 1e-12 else np.eye(3)
        R = dR @ R
        t = dR @ (t - c) + c + v
        steps = [float(np.clip(xi[6 + i], -big, big)) for i, (_, _, _, big) in enumerate(extra)]
        values = [float(np.clip(val + d, lo, hi))
                  for (val, lo, hi, _), d in zip(extra, steps)]
        if joint is not None:
            q = values.pop(0)
        if lo_hi is not None:
            sc = values.pop(0)
        dq_ds = max((abs(d) for d in steps), default=0.0)
        if angle < CONVERGED_ROTATION and np.linalg.norm(v) < CONVERGED_TRANSLATION and \
                dq_ds < CONVERGED_EXTRA:
            break
    return Refined(model.with_values(q=q, scale=sc), R, t, it + 1)
