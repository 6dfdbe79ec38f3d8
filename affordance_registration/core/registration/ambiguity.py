# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Whether a click's answer is settled (:class:`Ambiguity`), and if not, why -- what the fit
already knows about its own doubt, read off its candidates without changing any of them:

* **refused**: the verdict refuses the best candidate (``FitResult.fits`` False);
* **rival template**: another template scores within ``viewpoint.margin`` of the best;
* **rival pose**: the best template in a second pose -- more than ``viewpoint.pose_distance`` /
  ``viewpoint.pose_angle`` away, symmetry-aware -- scores within that margin (the fit's
  medium-stage hypotheses, ``FitReport.alternatives``, are those second poses);
* **weakly held**: the residual barely changes along some motion of the best pose -- the
  smallest eigenvalue of the point-to-plane Hessian J^T J over the samples the scan covers is
  below ``viewpoint.weak_ratio`` x the largest (a flat face seen edge-on slides along itself).
  Rotations are scaled by the samples' RMS radius so they weigh like translations, and a
  continuous symmetry's own rotation is left out (it moves nothing).

The rivals (best first) are the hypotheses a suggested view must tell apart (:mod:`.viewpoint`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..neighbours import nearest
from ..scene import ClickContext
from ..transforms import pose_error
from .model import Model
from .results import FitResult
from .settings import FitSettings
from .visibility import visible

__all__ = [
    "Ambiguity",
    "Hypothesis",
    "assess",
    "pose_hessian",
    "REFUSED",
    "RIVAL_TEMPLATE",
    "RIVAL_POSE",
    "WEAKLY_HELD",
]

REFUSED, RIVAL_TEMPLATE, RIVAL_POSE, WEAKLY_HELD = (
    "refused",
    "rival_template",
    "rival_pose",
    "weakly_held",
)
#: a sample within this many ``verdict.coverage_distance`` of the scan holds the pose
HOLDING = 2.0
#: fewer holding samples than this: the Hessian says nothing (the verdict speaks instead)
MIN_HOLDING = 12


@dataclass(frozen=True)
class Hypothesis:
    """One answer a click could have: a template at a pose (model -> scene), its residual (m)
    and the model it was fitted as (joint value, scale)."""

    template: str
    T_scene_model: np.ndarray = field(repr=False)
    residual: float
    model: Model = field(repr=False, compare=False, default=None)

    def to_dict(self) -> dict:
        return {
            "template": self.template,
            "residual": round(float(self.residual), 9),
            "pose": [[round(float(v), 9) for v in row] for row in self.T_scene_model],
        }


@dataclass(frozen=True)
class Ambiguity:
    """Whether a click's answer is settled. ``kinds`` names each doubt (:data:`REFUSED`,
    :data:`RIVAL_TEMPLATE`, :data:`RIVAL_POSE`, :data:`WEAKLY_HELD`) and ``reasons`` says it
    in a line each; ``rivals`` are the hypotheses to tell apart, the best first; ``weakest``
    the Hessian's smallest / largest eigenvalue (1: as firmly held along every motion; None: too
    few samples held) and ``weak_direction`` the motion it belongs to (rotation (rad) and
    translation (m) per unit, 6 numbers, scene frame; None when held)."""

    settled: bool
    kinds: tuple = ()
    reasons: tuple = ()
    rivals: tuple = field(default=(), repr=False)
    weakest: float | None = None
    weak_direction: tuple | None = None

    def describe(self) -> str:
        """'settled' or 'unsettled: <reason>; <reason>'."""
        return "settled" if self.settled else "unsettled: " + "; ".join(self.reasons)

    def to_dict(self) -> dict:
        return {
            "settled": self.settled,
            "kinds": list(self.kinds),
            "reasons": list(self.reasons),
            "weakest": None if self.weakest is None else round(float(self.weakest), 6),
            "weak_direction": None
            if self.weak_direction is None
            else [round(float(v), 6) for v in self.weak_direction],
            "rivals": [h.to_dict() for h in self.rivals],
        }


def assess(
    ctx: ClickContext, candidates, alternatives, model_of, settings: FitSettings, refine=None
) -> Ambiguity:
    """The :class:`Ambiguity` of a click's ranked ``candidates`` (FitResult, best first);
    ``alternatives`` (FitResult) are further hypotheses of the fit (other poses of each
    template, less refined than the candidates), ``model_of(result)`` the model a result was
    fitted as, ``refine(result)`` (optional) an alternative within the margin finished as a
    candidate is (it may then join the best's pose, or fall behind the margin). Primitives and
    the candidates the library prefilter set aside take no part (they are not fitted
    answers)."""
    s = settings.viewpoint
    fitted = [c for c in candidates if c.primitive is None and not c.prefiltered]
    if not fitted:
        return Ambiguity(settled=False, kinds=(REFUSED,), reasons=("no template was fitted",))
    best = fitted[0]
    kinds, reasons = [], []
    if best.fits is False:
        kinds.append(REFUSED)
        reasons.append(f"the verdict refuses {best.template} ({best.reason})")
    bar = s.margin * best.residual
    rivals = [Hypothesis(best.template, best.T_scene_model, best.residual, model_of(best))]
    for r in sorted(list(fitted[1:]) + list(alternatives), key=lambda r: r.residual):
        if r.residual > bar or len(rivals) >= 1 + s.rivals or r.primitive is not None:
            continue
        if any(_same(settings, h, r) for h in rivals):
            continue
        if refine is not None and r.template == best.template:
            r = refine(r)
            if r.residual > bar or any(_same(settings, h, r) for h in rivals):
                continue
        same_template = r.template == best.template
        kind = RIVAL_POSE if same_template else RIVAL_TEMPLATE
        if kind not in kinds:
            kinds.append(kind)
        ratio = r.residual / max(best.residual, 1e-12)
        how = f"within {ratio - 1:.0%} of" if ratio >= 1 else f"{1 - ratio:.0%} better than"
        who = (
            f"{best.template} in a second pose"
            if same_template
            else r.template
            + (" in another pose" if any(h.template == r.template for h in rivals) else "")
        )
        reasons.append(f"{who} scores {how} the best")
        rivals.append(Hypothesis(r.template, r.T_scene_model, r.residual, model_of(r)))
    weakest, direction = None, None
    if ctx.sensor_origin is not None:
        H = pose_hessian(ctx, rivals[0].model, best.T_scene_model, settings)
        if H is not None:
            weakest, direction = _weakest(H, rivals[0].model, best.T_scene_model)
            if weakest < s.weak_ratio:
                kinds.append(WEAKLY_HELD)
                reasons.append(
                    f"the scan barely holds {best.template} along one motion (its "
                    f"weakest direction is {weakest:.1%} of its strongest)"
                )
            else:
                direction = None
    return Ambiguity(
        settled=not kinds,
        kinds=tuple(kinds),
        reasons=tuple(reasons),
        rivals=tuple(rivals),
        weakest=weakest,
        weak_direction=None if direction is None else tuple(direction),
    )


def _same(settings: FitSettings, h: Hypothesis, r: FitResult) -> bool:
    """Whether ``r`` is the hypothesis ``h`` again: the same template within the pose
    tolerance (symmetry-aware; the distance where the two put the object's centroid, wherever
    its file's origin lies)."""
    if h.template != r.template:
        return False
    sym = h.model.symmetry if h.model is not None else None
    at = h.model.centroid if h.model is not None else None
    dt, da = pose_error(r.T_scene_model, h.T_scene_model, sym, at)
    return dt <= settings.viewpoint.pose_distance and da <= settings.viewpoint.pose_angle


def pose_hessian(ctx: ClickContext, model: Model, T: np.ndarray, settings: FitSettings):
    """The point-to-plane Hessian (6, 6) of ``model`` at pose ``T`` over its samples that the
    sensor could see and the scan holds (within ``HOLDING`` x ``verdict.coverage_distance``):
    rows [(x - c) x n / L, n] with c the samples' centroid and L their RMS radius -- a rotation
    of 1/L rad moves them as far as a translation of 1 m. Also the centroid and L:
    (H, c, L), or None with fewer than ``MIN_HOLDING`` samples."""
    P, N = model.samples(settings.scoring.samples)
    R, t = T[:3, :3], T[:3, 3]
    X, Nw = P @ R.T + t, N @ R.T
    seen, _ = visible(ctx, X[None], Nw[None], settings)
    seen = seen[0]
    d, _ = nearest(ctx.crop_tree, X[seen], HOLDING * settings.verdict.coverage_distance)
    held = np.flatnonzero(seen)[np.isfinite(d)]
    if len(held) < MIN_HOLDING:
        return None
    X, Nw = X[held], Nw[held]
    c = X.mean(axis=0)
    L = max(math.sqrt(float(((X - c) ** 2).sum(axis=1).mean())), 1e-6)
    J = np.concatenate([np.cross(X - c, Nw) / L, Nw], axis=1)
    return J.T @ J, c, L


def _weakest(hessian, model: Model, T: np.ndarray):
    """(smallest / largest eigenvalue, the motion (6,) of the smallest: rotation rad, translation
    m per unit) of :func:`pose_hessian`'s answer, a continuous symmetry's rotation left out."""
    H, c, L = hessian
    basis = np.eye(6)
    sym = model.symmetry
    if sym is not None and sym.continuous:
        a = T[:3, :3] @ np.asarray(sym.axis, float)
        a /= np.linalg.norm(a)
        on_axis = T[:3, :3] @ np.asarray(sym.point, float) + T[:3, 3]
        s = np.concatenate([a * L, np.cross(a, c - on_axis)])  # rotation about the axis
        s /= np.linalg.norm(s)
        basis = np.linalg.svd(np.eye(6) - np.outer(s, s))[0][:, :5]
    w, V = np.linalg.eigh(basis.T @ H @ basis)
    if w[-1] <= 0:
        return 0.0, None
    xi = basis @ V[:, 0]
    motion = np.concatenate([xi[:3] / L, xi[3:]])
    return float(max(w[0], 0.0) / w[-1]), motion / max(np.linalg.norm(motion), 1e-12)
