# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine's open objects as ranked detections: for each, its candidates best first (template,
probability, pose with a covariance) and a box around the shown one -- what a perception
consumer reads (the node publishes them as vision_msgs/Detection3DArray). Pure Python (no ROS).

A candidate's covariance comes from its fit: the inverse of the point-to-plane normal matrix
J^T J over the template's samples the scan holds (:func:`~.registration.ambiguity.pose_hessian`,
the matrix the settledness check reads), scaled by the candidate's squared residual, and carried
from the Hessian's parameters (a rotation about the samples' centroid, scaled by their RMS
radius, and a translation) to the pose's: (x, y, z, rotation about x, y, z) of the model's
origin in the scene frame. A motion the scan does not hold (a continuous symmetry's rotation, a
flat face's slide) gets :data:`UNHELD_VARIANCE`; a candidate without a single viewpoint or too
few held samples gets it along every axis.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from .registration.ambiguity import pose_hessian

__all__ = ["Hypothesis", "Detection", "Detections", "pose_covariance", "UNHELD_VARIANCE"]

#: the variance (m^2 or rad^2) of a motion the scan does not hold: nothing is known along it
UNHELD_VARIANCE = 1.0e6
#: eigenvalues of J^T J below this fraction of the largest hold nothing
HELD_FRACTION = 1e-9


@dataclass(frozen=True)
class Hypothesis:
    """One candidate: its ``template``, ``score`` (the probability it is ranked with), pose
    ``T_scene_model`` and its ``covariance`` (6, 6: x, y, z, rotation about x, y, z)."""

    template: str
    score: float
    T_scene_model: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class Detection:
    """An open object: its ``object_id``, its ``hypotheses`` best first, and the box around the
    shown candidate: its centre pose ``T_scene_box`` and ``size`` (3,) (m)."""

    object_id: int
    hypotheses: tuple
    T_scene_box: np.ndarray = field(repr=False)
    size: np.ndarray = field(repr=False)


def pose_covariance(hessian, T: np.ndarray, residual: float) -> np.ndarray:
    """The covariance (6, 6) of the pose ``T`` (x, y, z of its origin, then rotation about x,
    y, z) from :func:`pose_hessian`'s ``(H, c, L)`` (None: nothing held), scaled by
    ``residual`` squared (m). See the module docstring."""
    if hessian is None:
        return np.eye(6) * UNHELD_VARIANCE
    H, c, L = hessian
    w, V = np.linalg.eigh(H)
    held = w > HELD_FRACTION * max(float(w[-1]), 0.0)
    variance = np.where(held, residual**2 / np.where(held, w, 1.0), np.inf)
    # from the Hessian's parameters xi = (rotation * L about c, translation) to the pose's
    # p = (the origin's motion, rotation): the origin t moves by omega x (t - c) + v
    r = np.asarray(T, float)[:3, 3] - np.asarray(c, float)
    skew = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    A = np.zeros((6, 6))
    A[:3, :3], A[:3, 3:] = -skew / L, np.eye(3)
    A[3:, :3] = np.eye(3) / L
    B = A @ V  # each column: the pose motion of one eigen-direction
    finite = np.isfinite(variance)
    cov = (B[:, finite] * variance[finite]) @ B[:, finite].T
    unheld = B[:, ~finite]
    if unheld.size:  # the pose components an unheld direction moves are unknown
        touched = np.abs(unheld).max(axis=1) > 1e-9
        cov[touched, :] = 0.0
        cov[:, touched] = 0.0
        cov[touched, touched] = UNHELD_VARIANCE
    return np.minimum(cov, UNHELD_VARIANCE)


class Detections:
    """The open objects of an engine as :class:`Detection` records (:meth:`of`); each
    candidate's covariance and each shown candidate's box are computed once. Thread-safe."""

    def __init__(self):
        self._lock = threading.Lock()
        self._held: dict[int, tuple] = {}  # id(candidate) -> (candidate, context, covariance)

    def of(self, engine) -> list[Detection]:
        state, registrar = engine.state, engine.registrar
        held, out = {}, []
        with self._lock:
            for obj in state.objects:
                hypotheses = []
                for c in obj.candidates:
                    entry = self._held.get(id(c))
                    if entry is None or entry[0] is not c or entry[1] is not obj.context:
                        entry = (c, obj.context, self._covariance(registrar, obj.context, c))
                    held[id(c)] = entry
                    hypotheses.append(
                        Hypothesis(c.template, float(c.probability), c.T_scene_model, entry[2])
                    )
                T_box, size = _box(engine.geometry(obj.shown), obj.shown)
                out.append(Detection(obj.id, tuple(hypotheses), T_box, size))
            self._held = held
        return out

    @staticmethod
    def _covariance(registrar, ctx, candidate) -> np.ndarray:
        if ctx is None or ctx.sensor_origin is None or candidate.template not in registrar.library:
            return pose_covariance(None, candidate.T_scene_model, candidate.residual)
        model = registrar.services.model_of(candidate)
        hessian = pose_hessian(ctx, model, candidate.T_scene_model, registrar.settings)
        return pose_covariance(hessian, candidate.T_scene_model, candidate.residual)


def _box(tpl, candidate) -> tuple[np.ndarray, np.ndarray]:
    """(the pose of the box's centre in the scene frame, its size) around ``tpl`` (the template
    the candidate is drawn with) at the candidate's joint values, scale and pose."""
    mesh = tpl.mesh_at(tpl.joint_value(candidate.joints), candidate.scale)
    lo, hi = np.asarray(mesh.bounds, float)
    T = np.asarray(candidate.T_scene_model, float).copy()
    T[:3, 3] = T[:3, :3] @ ((lo + hi) / 2) + T[:3, 3]
    return T, hi - lo
