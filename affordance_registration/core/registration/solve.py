"""The closed-form solves of one ICP iteration: the weighted rigid transform (SVD, point to
point), the weighted point-to-plane step (6 unknowns, linearised) and the same step with bounded
extra unknowns (a joint value, a scale).

Arrays are batched where it says so: ``B`` hypotheses of ``S`` pairs each.
"""
from __future__ import annotations

import numpy as np

from ..transforms import axis_angle_matrix, make_T

__all__ = ["kabsch_weighted", "point_to_plane_weighted", "bounded_least_squares",
           "rotations_from_vectors", "weighted_rigid_fit"]


def kabsch_weighted(X: np.ndarray, Q: np.ndarray, w: np.ndarray):
    """Batched weighted rigid fit: R, t minimising sum w |R x + t - q|^2 per batch.

    X, Q (B, S, 3); w (B, S). Reflection-safe. Batches with no weight get the identity."""
    W = w.sum(axis=1)
    ok = W > 1e-9
    Ws = np.where(ok, W, 1.0)[:, None]
    mx = np.einsum("bs,bsi->bi", w, X) / Ws
    mq = np.einsum("bs,bsi->bi", w, Q) / Ws
    H = np.einsum("bs,bsi,bsj->bij", w, X - mx[:, None], Q - mq[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    det = np.linalg.det(V @ np.swapaxes(U, 1, 2))
    D = np.ones((len(X), 3))
    D[:, 2] = np.sign(det) + (det == 0)
    R = (V * D[:, None, :]) @ np.swapaxes(U, 1, 2)
    t = mq - np.einsum("bij,bj->bi", R, mx)
    R[~ok] = np.eye(3)
    t[~ok] = 0.0
    return R, t


def point_to_plane_weighted(X: np.ndarray, Q: np.ndarray, Nq: np.ndarray, w: np.ndarray):
    """Batched weighted point-to-plane step: minimise sum w ((R x + t - q) . n)^2, linearised
    about each batch's weighted centroid; returns (R, t) like :func:`kabsch_weighted`."""
    W = w.sum(axis=1)
    ok = W > 1e-9
    c = np.einsum("bs,bsi->bi", w, X) / np.where(ok, W, 1.0)[:, None]
    Xc = X - c[:, None]
    J = np.concatenate([np.cross(Xc, Nq), Nq], axis=-1)           # (B, S, 6)
    r = np.einsum("bsi,bsi->bs", Q - X, Nq)
    A = np.einsum("bs,bsi,bsj->bij", w, J, J) + 1e-9 * np.eye(6)
    b = np.einsum("bs,bsi,bs->bi", w, J, r)
    xi = np.linalg.solve(A, b[..., None])[..., 0]
    omega, v = xi[:, :3], xi[:, 3:]
    R = rotations_from_vectors(omega)
    t = c + v - np.einsum("bij,bj->bi", R, c)
    R[~ok] = np.eye(3)
    t[~ok] = 0.0
    return R, t


def bounded_least_squares(J: np.ndarray, r: np.ndarray, w: np.ndarray, values, lower,
                          upper) -> np.ndarray:
    """The weighted least-squares step xi minimising sum w (J xi - r)^2, J (S, 6 + k), whose last
    k unknowns are bounded: one at its ``lower`` / ``upper`` bound (``values`` (k,) are where they
    are now) that the step would push beyond stays there -- its column drops out and the rest is
    solved again -- instead of being clipped behind the other unknowns' backs. (6 + k,)."""
    free = np.ones(J.shape[1], bool)
    while True:
        Jf = J[:, free]
        A = (Jf * w[:, None]).T @ Jf + 1e-9 * np.eye(Jf.shape[1])
        xi = np.zeros(J.shape[1])
        xi[free] = np.linalg.solve(A, (Jf * w[:, None]).T @ r)
        stuck = [6 + i for i, (val, lo, hi) in enumerate(zip(values, lower, upper))
                 if free[6 + i] and ((val <= lo and xi[6 + i] < 0) or (val >= hi and xi[6 + i] > 0))]
        if not stuck:
            return xi
        free[stuck] = False


def rotations_from_vectors(omega: np.ndarray) -> np.ndarray:
    """The rotations (B, 3, 3) about each of ``omega`` (B, 3) by its norm (rad)."""
    angle = np.linalg.norm(omega, axis=1)
    return np.stack([axis_angle_matrix(o, a) if a > 1e-12 else np.eye(3)
                     for o, a in zip(omega, angle)])


def weighted_rigid_fit(source: np.ndarray, target: np.ndarray, weights=None) -> np.ndarray:
    """T (4x4) minimising sum w |T source - target|^2 for paired (N, 3) point sets (closed form,
    SVD, reflection-safe)."""
    X = np.asarray(source, dtype=float)[None]
    Q = np.asarray(target, dtype=float)[None]
    w = np.ones(X.shape[1]) if weights is None else np.asarray(weights, dtype=float)
    R, t = kabsch_weighted(X, Q, w[None])
    return make_T(R[0], t[0])
