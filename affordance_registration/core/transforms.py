# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""SE(3) helpers. Transforms are 4x4 float64 arrays named by their frames: ``T_a_b`` maps points
expressed in frame b into frame a, so ``T_a_c = T_a_b @ T_b_c`` reads right."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import AffordanceError

__all__ = [
    "finite_vector",
    "template_vector",
    "finite_transform",
    "make_T",
    "is_rigid",
    "RIGID_ATOL",
    "invert",
    "transform_points",
    "rotate",
    "pose_points",
    "rotation_angle",
    "pose_error",
    "axis_angle_matrix",
    "random_rotations",
    "unit_quaternions",
    "align_z_to",
    "align_x_to",
    "quat_xyzw_to_matrix",
    "matrix_to_quat_xyzw",
]


#: a template's vectors (axes, origins, waypoint positions and directions) lie within this of
#: zero: a template is an object, and 1e200 overflows when an axis is normalised
MAX_TEMPLATE_VALUE = 1e6


def finite_vector(value, what: str, error=ValueError, length: int = 3) -> np.ndarray:
    """``value`` as a float64 vector of ``length`` finite numbers, else ``error`` naming it."""
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise error(f"{what} must be {length} numbers, got {value!r}") from None
    if v.shape != (length,) or not np.all(np.isfinite(v)):
        raise error(f"{what} must be {length} finite numbers, got {value!r}")
    return v


def template_vector(value, key: str, fail, length: int = 3) -> np.ndarray:
    """A template file's entry ``key`` as ``length`` finite numbers within
    +-``MAX_TEMPLATE_VALUE``; anything else raises ``fail(key, message)``."""
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise fail(key, f"expected {length} numbers, got {value!r}") from None
    if (
        v.shape != (length,)
        or not np.all(np.isfinite(v))
        or np.max(np.abs(v)) > MAX_TEMPLATE_VALUE
    ):
        raise fail(
            key,
            f"expected {length} finite numbers within +-{MAX_TEMPLATE_VALUE:.0e}, got {value!r}",
        )
    return v


def finite_transform(T, what: str, error=AffordanceError) -> np.ndarray:
    """``T`` as a finite 4x4 float array; anything else is ``error`` naming ``what``."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise error(f"{what} must be a finite 4x4 transform")
    return T


#: how far the rotation block's R^T R may be from the identity, per element, in a pose taken
#: from outside (a saved registration, an operator's correction): the poses the package makes
#: are within 1e-13 and its files hold 9 decimals (1e-9); this still accepts a rotation written
#: with 6 decimals and refuses a scaled or sheared matrix
RIGID_ATOL = 1e-5


def is_rigid(T, atol: float = RIGID_ATOL) -> bool:
    """Whether ``T`` is a finite 4x4 rigid transform (orthonormal rotation block)."""
    T = np.asarray(T, dtype=float)
    return (
        T.shape == (4, 4)
        and bool(np.all(np.isfinite(T)))
        and bool(np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=atol))
    )


def make_T(R=None, t=None) -> np.ndarray:
    """4x4 transform from a 3x3 rotation (default identity) and a translation (default zero)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (or a stack ``(..., 4, 4)`` of them)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``T`` (4x4) to ``points`` (N, 3)."""
    return points @ T[:3, :3].T + T[:3, 3]


def rotate(R: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Each of B rotations R (B, 3, 3) applied to its points P (B, S, 3) -- or all to the same
    points (S, 3): (B, S, 3). (A batched matrix product: many times faster than ``einsum``.)"""
    return P @ np.swapaxes(R, -1, -2)


def pose_points(R: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """B poses (R (B, 3, 3), t (B, 3)) applied to their points P (B, S, 3) or to the same points
    (S, 3): (B, S, 3)."""
    return rotate(R, P) + t[:, None, :]


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians of a rotation matrix or a stack of them."""
    trace = np.trace(R, axis1=-2, axis2=-1)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def axis_angle_matrix(axis, angle) -> np.ndarray:
    """Rotation about a (not necessarily unit) axis by ``angle`` radians: axis (3,) and a
    number give (3, 3); axis (3,) or (K, 3) with angles (K,) give (K, 3, 3)."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    if axis.ndim == 1:
        unit = axis / np.linalg.norm(axis)
    else:  # each row's norm as np.linalg.norm gives it for one vector (the same digits)
        unit = axis / np.sqrt([a @ a for a in axis])[:, None]
    rotvec = unit * angle[..., None]
    if rotvec.ndim == 1:
        return np.array(_rotvec_matrix(*rotvec.tolist()))
    if len(rotvec) > _FEW_ROTATIONS:
        return Rotation.from_rotvec(rotvec).as_matrix()
    matrices = np.array([_rotvec_matrix(*r) for r in rotvec.tolist()])
    return matrices.reshape(rotvec.shape[:-1] + (3, 3))


#: up to this many rotations at once, :func:`axis_angle_matrix` composes them in plain Python
#: (a few microseconds each) rather than through scipy's ``Rotation`` (about 15 us a call)
_FEW_ROTATIONS = 8


def _rotvec_matrix(x: float, y: float, z: float) -> list:
    """The rotation matrix (3 lists of 3) of the rotation vector (x, y, z) (rad), by scipy's
    own steps (``Rotation.from_rotvec(...).as_matrix()``: through the unit quaternion, a
    Taylor series below 1e-3 rad), so the digits are scipy's."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-3:
        a2 = angle * angle
        s = 0.5 - a2 / 48 + a2 * a2 / 3840
    else:
        s = math.sin(angle / 2) / angle
    qx, qy, qz, qw = x * s, y * s, z * s, math.cos(angle / 2)
    x2, y2, z2, w2 = qx * qx, qy * qy, qz * qz, qw * qw
    xy, zw, xz, yw, yz, xw = qx * qy, qz * qw, qx * qz, qy * qw, qy * qz, qx * qw
    return [
        [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
        [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
        [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
    ]


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` rotations drawn uniformly from SO(3), shape (n, 3, 3)."""
    return Rotation.from_quat(unit_quaternions(n, rng)).as_matrix()


def unit_quaternions(n: int, rng: np.random.Generator) -> np.ndarray:
    """The unit quaternions (n, 4) of :func:`random_rotations` (the same draws)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q


def align_z_to(normal, hint=None) -> np.ndarray:
    """A rotation whose third column is the unit vector ``normal``; the first column is ``hint``
    (3,) made perpendicular to it -- pass a direction attached to the data, so the result turns
    with the data -- or, without a hint (or one along ``normal``), a coordinate axis."""
    z = np.asarray(normal, dtype=float)
    z = z / np.linalg.norm(z)
    x = None
    if hint is not None:
        x = np.asarray(hint, dtype=float) - z * (np.asarray(hint, dtype=float) @ z)
        x = x if np.linalg.norm(x) > 1e-6 else None
    if x is None:
        helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = helper - z * (helper @ z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def align_x_to(axis) -> np.ndarray:
    """A rotation whose first column is the unit vector ``axis`` (a cyclic permutation of
    :func:`align_z_to`'s columns, so still right-handed)."""
    return align_z_to(axis)[:, [2, 0, 1]]


def quat_xyzw_to_matrix(q) -> np.ndarray:
    """3x3 rotation of a quaternion (x, y, z, w); normalizes it."""
    return Rotation.from_quat(np.asarray(q, dtype=float)).as_matrix()


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) with w >= 0 of a 3x3 rotation.

    In closed form on Python floats, by the largest of the diagonal and the trace (as scipy's
    ``Rotation.from_matrix`` decides; bit for bit the same quaternion on 24,000 random and
    half-turn rotations, within about its error on a matrix a little off a rotation): about 30
    times faster on one matrix, and the node converts every shown pose on every publish
    (status, TF, poses, markers)."""
    m = np.asarray(R, dtype=float).reshape(3, 3).tolist()
    trace = m[0][0] + m[1][1] + m[2][2]
    decision = (m[0][0], m[1][1], m[2][2], trace)
    c = 0
    for k in (1, 2, 3):
        if decision[k] > decision[c]:
            c = k
    if c == 3:
        q = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1], 1 + trace]
    else:
        q = [0.0, 0.0, 0.0, 0.0]
        i, j, k = c, (c + 1) % 3, (c + 2) % 3
        q[i] = 1 - trace + 2 * m[i][i]
        q[j] = m[j][i] + m[i][j]
        q[k] = m[k][i] + m[i][k]
        q[3] = m[k][j] - m[j][k]
    q = np.array(q) / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q if q[3] >= 0 else -q


def pose_error(
    T_est: np.ndarray, T_true: np.ndarray, symmetry=None, at=None
) -> tuple[float, float]:
    """Translation error (m) and rotation error (rad) between two model->scene poses.

    ``symmetry`` is a template's :class:`~affordance_registration.core.templates.Symmetry`
    (or None): the error is the smallest over the poses the symmetry makes indistinguishable.
    The translation error is the distance between where the two poses put the model point
    ``at`` (3,): by default the symmetry's point (on its axis, which every indistinguishable
    pose puts in the same place) or, without a symmetry, the origin. Give ``at`` a point on
    the object (its centroid) for an error that does not depend on where the file's origin
    lies; with a symmetry, a point on its axis.
    """
    if at is None:
        at = (0.0, 0.0, 0.0) if symmetry is None else symmetry.point
    at = np.asarray(at, dtype=float)
    dt = float(
        np.linalg.norm(T_est[:3, :3] @ at + T_est[:3, 3] - T_true[:3, :3] @ at - T_true[:3, 3])
    )
    R_rel = T_true[:3, :3].T @ T_est[:3, :3]  # rotation of est relative to truth, model frame
    if symmetry is None:
        return dt, float(rotation_angle(R_rel))
    return dt, float(symmetry.residual_angle(R_rel))
