# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The closed-form solves of one ICP iteration: the weighted rigid transform (SVD, point to
point) and the weighted point-to-plane Gauss-Newton step -- 6 unknowns for a rigid motion, plus
bounded extra unknowns (a joint value, a scale).

Arrays are batched: ``B`` hypotheses of ``S`` pairs each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..transforms import axis_angle_matrix, make_T, rotation_angle

__all__ = [
    "Step",
    "rigid_step",
    "plane_step",
    "gauss_newton",
    "kabsch_weighted",
    "point_to_plane_weighted",
    "rotations_from_vectors",
    "weighted_rigid_fit",
]


@dataclass(frozen=True)
class Step:
    """One ICP step of a batch of B hypotheses: the rigid motion (R (B, 3, 3), t (B, 3)) to
    apply to each pose (x -> R x + t), the weighted centroid of the model side it was solved
    about (B, 3), and the increments of the extra unknowns (B, k)."""

    R: np.ndarray
    t: np.ndarray
    centre: np.ndarray
    extra: np.ndarray

    @property
    def rotation(self) -> np.ndarray:
        """How far each hypothesis turns (rad), (B,)."""
        return rotation_angle(self.R)

    @property
    def motion(self) -> np.ndarray:
        """How far each hypothesis' weighted centroid moves (m), (B,) -- unlike the translation
        of the frame's origin, the same in every scene frame."""
        moved = np.einsum("bij,bj->bi", self.R, self.centre) + self.t
        return np.linalg.norm(moved - self.centre, axis=1)


def rigid_step(X: np.ndarray, Q: np.ndarray, w: np.ndarray) -> Step:
    """Batched weighted rigid fit (point to point, closed form): the R, t minimising
    sum w |R x + t - q|^2 per hypothesis. X, Q (B, S, 3); w (B, S). Reflection-safe;
    hypotheses with no weight get the identity."""
    W = w.sum(axis=1)
    ok = W > 1e-9
    Ws = np.where(ok, W, 1.0)[:, None]
    mx = _weighted_sum(w, X) / Ws
    mq = _weighted_sum(w, Q) / Ws
    H = np.swapaxes((X - mx[:, None]) * w[..., None], 1, 2) @ (Q - mq[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    det = np.linalg.det(V @ np.swapaxes(U, 1, 2))
    D = np.ones((len(X), 3))
    D[:, 2] = np.sign(det) + (det == 0)
    R = (V * D[:, None, :]) @ np.swapaxes(U, 1, 2)
    t = mq - np.einsum("bij,bj->bi", R, mx)
    if not ok.all():
        R[~ok] = np.eye(3)
        t[~ok] = 0.0
    return Step(R, t, mx, np.zeros((len(X), 0)))


def plane_step(
    X: np.ndarray,
    Q: np.ndarray,
    Nq: np.ndarray,
    w: np.ndarray,
    extra: np.ndarray | None = None,
    bounds=None,
) -> Step:
    """Batched weighted point-to-plane Gauss-Newton step: minimise
    sum w ((R x + t - q) . n + extra . dv)^2, linearised about each hypothesis' weighted
    centroid -- 6 unknowns (the rigid case) plus a column per extra unknown in ``extra``
    (B, S, k: d(x . n) / d value). ``bounds``: (values, lower, upper), each (B, k), see
    :func:`gauss_newton`. X, Q, Nq (B, S, 3); w (B, S)."""
    W = w.sum(axis=1)
    ok = W > 1e-9
    c = _weighted_sum(w, X) / np.where(ok, W, 1.0)[:, None]
    # the Jacobian's columns written in place: (x - c) x n, n, then the extra unknowns'
    # (the cross and dot products of three components spelled out, as np.cross computes them)
    A = X - c[:, None]
    J = np.empty(X.shape[:2] + (6 + (0 if extra is None else extra.shape[-1]),))
    J[..., 0] = A[..., 1] * Nq[..., 2] - A[..., 2] * Nq[..., 1]
    J[..., 1] = A[..., 2] * Nq[..., 0] - A[..., 0] * Nq[..., 2]
    J[..., 2] = A[..., 0] * Nq[..., 1] - A[..., 1] * Nq[..., 0]
    J[..., 3:6] = Nq
    if extra is not None:
        J[..., 6:] = extra
    r = np.einsum("bsi,bsi->bs", Q - X, Nq)
    xi = gauss_newton(J, r, w, *(bounds if bounds is not None else (None, None, None)))
    R = rotations_from_vectors(xi[:, :3])
    t = c + xi[:, 3:6] - np.einsum("bij,bj->bi", R, c)
    if not ok.all():
        R[~ok] = np.eye(3)
        t[~ok] = 0.0
        xi[~ok] = 0.0
    return Step(R, t, c, xi[:, 6:])


def gauss_newton(
    J: np.ndarray, r: np.ndarray, w: np.ndarray, values=None, lower=None, upper=None
) -> np.ndarray:
    """The weighted least-squares step xi (B, n) minimising sum w (J xi - r)^2 per hypothesis,
    J (B, S, n), r and w (B, S). With ``values`` / ``lower`` / ``upper`` ((B, n - 6): where the
    unknowns after the first six are now and their bounds), an unknown at a bound that the step
    would push beyond stays there -- its column drops out and the rest is solved again --
    instead of being clipped behind the other unknowns' backs."""
    B, _, n = J.shape
    free = np.ones((B, n), bool)
    while True:
        Jf = J if free.all() else J * free[:, None, :]
        JfT = np.swapaxes(Jf, 1, 2)
        A = (JfT * w[:, None, :]) @ Jf + 1e-9 * np.eye(n)
        xi = np.linalg.solve(A, JfT @ (w * r)[..., None])[..., 0]
        if values is None or n == 6:
            return xi
        push = xi[:, 6:]
        stuck = free[:, 6:] & (((values <= lower) & (push < 0)) | ((values >= upper) & (push > 0)))
        if not stuck.any():
            return xi
        free[:, 6:] &= ~stuck


def _weighted_sum(w: np.ndarray, X: np.ndarray) -> np.ndarray:
    """sum_s w[b, s] X[b, s] (B, 3) of weights w (B, S) and points X (B, S, 3)."""
    return (w[:, None, :] @ X)[:, 0]


def kabsch_weighted(X: np.ndarray, Q: np.ndarray, w: np.ndarray):
    """Batched weighted rigid fit: (R (B, 3, 3), t (B, 3)) of :func:`rigid_step`."""
    step = rigid_step(X, Q, w)
    return step.R, step.t


def point_to_plane_weighted(X: np.ndarray, Q: np.ndarray, Nq: np.ndarray, w: np.ndarray):
    """Batched weighted point-to-plane step: (R, t) of :func:`plane_step` with the six
    unknowns of a rigid motion."""
    step = plane_step(X, Q, Nq, w)
    return step.R, step.t


def rotations_from_vectors(omega: np.ndarray) -> np.ndarray:
    """The rotations (B, 3, 3) about each of ``omega`` (B, 3) by its norm (rad)."""
    angle = np.linalg.norm(omega, axis=1)
    R = np.tile(np.eye(3), (len(omega), 1, 1))
    turning = angle > 1e-12
    if turning.any():
        R[turning] = axis_angle_matrix(omega[turning], angle[turning])
    return R


def weighted_rigid_fit(source: np.ndarray, target: np.ndarray, weights=None) -> np.ndarray:
    """T (4x4) minimising sum w |T source - target|^2 for paired (N, 3) point sets (closed form,
    SVD, reflection-safe)."""
    X = np.asarray(source, dtype=float)[None]
    Q = np.asarray(target, dtype=float)[None]
    w = np.ones(X.shape[1]) if weights is None else np.asarray(weights, dtype=float)
    R, t = kabsch_weighted(X, Q, w[None])
    return make_T(R[0], t[0])
