# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Operator corrections: a 6-DoF twist in the operator's view frame -> an SE(3) step.

The *view frame* is the screen as the operator sees it: x to the right, y up, z towards the
viewer. A SpaceMouse push to the right therefore moves the object to the right on the screen,
whatever the camera's pose in the scene. Rotations turn the object about its own centre (not about
the scene origin or the template's base), so a twist never flings a distant object around.
"""

from __future__ import annotations

import numpy as np

from .errors import AffordanceError
from .transforms import axis_angle_matrix, finite_vector, make_T

__all__ = ["view_from_optical", "twist_step", "apply_twist", "OPTICAL_TO_VIEW", "R_VIEW_SPACENAV"]

#: Rotation from the screen view frame (x right, y up, z to the viewer) to a camera optical frame
#: (x right, y down, z forward): R_optical_view.
OPTICAL_TO_VIEW = np.diag([1.0, -1.0, -1.0])

#: Rotation from the spacenav device axes of ``spacenav/twist`` (x away from the user, y left, z
#: up) to the view axes: push right -> right on the screen, push away -> into the screen, lift ->
#: up.
R_VIEW_SPACENAV = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


def view_from_optical(T_scene_optical: np.ndarray) -> np.ndarray:
    """T_scene_view of an operator looking through a camera whose optical frame is given."""
    T = np.array(T_scene_optical, dtype=float)
    T[:3, :3] = T[:3, :3] @ OPTICAL_TO_VIEW
    return T


def _vec3(value, what: str) -> np.ndarray:
    return finite_vector(value, what, AffordanceError)


def twist_step(linear, angular, dt: float, T_scene_view: np.ndarray, centre) -> np.ndarray:
    """The scene-frame step ``T_step`` (4x4) of a twist held for ``dt`` seconds.

    ``linear`` (m/s) and ``angular`` (rad/s, axis-angle rate) are in the view frame; the rotation
    is about ``centre`` (3,), a scene point (the object's centre). Apply as ``T_step @ T``.
    """
    v = _vec3(linear, "linear velocity")
    w = _vec3(angular, "angular velocity")
    if not (np.isfinite(dt) and dt >= 0):
        raise AffordanceError(f"dt must be a finite non-negative number, got {dt!r}")
    c = _vec3(centre, "rotation centre")
    R_sv = np.asarray(T_scene_view, dtype=float)[:3, :3]
    v_s, w_s = R_sv @ v, R_sv @ w
    angle = float(np.linalg.norm(w_s)) * dt
    R = axis_angle_matrix(w_s, angle) if angle > 1e-12 else np.eye(3)
    return make_T(R, c - R @ c + v_s * dt)


def apply_twist(
    T_scene_model: np.ndarray, linear, angular, dt: float, T_scene_view: np.ndarray, centre_model
) -> np.ndarray:
    """``T_scene_model`` moved by a view-frame twist about the model point ``centre_model``."""
    T = np.asarray(T_scene_model, dtype=float)
    centre = T[:3, :3] @ np.asarray(centre_model, dtype=float) + T[:3, 3]
    return twist_step(linear, angular, dt, T_scene_view, centre) @ T
