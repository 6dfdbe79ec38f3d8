# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""How far the label score of a primitive fit can go at all: the fit refined on the object's own
labelled points.

The scoring rule (:func:`.realdata.score_primitive`) asks two things of a box or cylinder fit:
that the object's labelled points lie on its surface (recall) and that the scan points on its
surface are the object's (precision). The second counts every scan point within the tolerance
of the surface -- the table around an object's base is within 6 mm of its lower edge wherever it
stands on the table, and a neighbour touching it is within 6 mm of its side -- so some objects
cannot pass it with any fit that lies on them. :func:`label_refined` gives the fit that lies on
them best: the primitive's pose (6 degrees of freedom) and dimensions least-squares fitted to the
object's labelled points (a robust loss, so mixed pixels labelled as the object do not pull it),
from the fitter's answer. Scored by the same rule, it says whether a miss is the fitter's (the
refined fit passes) or the rule's on that object (it does not).

This is a measurement with the labels, for the bench and the note: nothing in the product uses
it, and it tunes nothing."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..core.transforms import axis_angle_matrix, make_T
from .realdata import (
    LabelledCloud,
    LabelledObject,
    PrimitiveScore,
    primitive_distance,
    score_primitive,
)

__all__ = ["label_refined", "refined_score", "MAX_POINTS", "LOSS_SCALE"]

#: the object's labelled points used in the fit, at most (seeded subsample)
MAX_POINTS = 5000
#: the robust loss's scale (m): residuals beyond a few of these count less than squared
LOSS_SCALE = 0.003
#: no dimension is refined below this (m)
MIN_DIMENSION = 0.001


def _posed(T0: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``T0`` moved by ``p`` (6,): a translation, then an axis-angle turn of its axes."""
    angle = float(np.linalg.norm(p[3:6]))
    R = axis_angle_matrix(p[3:6], angle) if angle > 1e-12 else np.eye(3)
    return make_T(R @ T0[:3, :3], T0[:3, 3] + p[:3])


def label_refined(
    kind: str, points: np.ndarray, T_scene_model: np.ndarray, dims: dict, seed: int = 0
) -> tuple[np.ndarray, dict]:
    """The primitive ``kind`` ("box" | "cylinder") posed by ``T_scene_model`` at ``dims``,
    its pose and dimensions least-squares fitted to ``points`` (N, 3: the object's labelled
    points; at most :data:`MAX_POINTS` of them, seeded) by their distance to its closed
    surface (a soft-L1 loss of scale :data:`LOSS_SCALE`). Returns (T_scene_model, dims)."""
    pts = np.asarray(points, float)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) > MAX_POINTS:
        pts = pts[np.random.default_rng(seed).choice(len(pts), MAX_POINTS, replace=False)]
    T0 = np.asarray(T_scene_model, float)
    keys = list(dims)

    def residuals(p):
        return primitive_distance(kind, pts, _posed(T0, p[:6]), dict(zip(keys, p[6:])))

    start = np.r_[np.zeros(6), [float(dims[k]) for k in keys]]
    lower = np.r_[np.full(6, -np.inf), np.full(len(keys), MIN_DIMENSION)]
    start[6:] = np.maximum(start[6:], MIN_DIMENSION)
    sol = least_squares(
        residuals,
        start,
        loss="soft_l1",
        f_scale=LOSS_SCALE,
        bounds=(lower, np.full(len(start), np.inf)),
    )
    return _posed(T0, sol.x[:6]), {k: float(v) for k, v in zip(keys, sol.x[6:])}


def refined_score(
    cloud: LabelledCloud, obj: LabelledObject, kind: str, T_scene_model: np.ndarray, dims: dict
) -> PrimitiveScore:
    """The label score (:func:`.realdata.score_primitive`) of the fit ``kind`` /
    ``T_scene_model`` / ``dims`` of ``obj`` refined on its labelled points
    (:func:`label_refined`)."""
    own = cloud.points.reshape(-1, 3)[
        cloud.valid.reshape(-1) & (cloud.object_ids.reshape(-1) == obj.id)
    ]
    T, refined = label_refined(kind, own, T_scene_model, dims)
    return score_primitive(cloud, obj, kind, T, refined)
