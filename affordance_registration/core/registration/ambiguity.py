# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Whether a click's answer is settled (:class:`Ambiguity`), and if not, why -- what the fit
already knows about its own doubt, read off its candidates without changing any of them.

The answer is the candidate shown first: the best specific template, or, where none fits, the
primitive (box, cylinder) that fits. It is settled when it fits and nothing rivals it:

* **refused**: the verdict refuses it (``FitResult.fits`` False);
* **rival template**: another candidate -- a specific template, or a primitive where the answer
  is one -- scores within ``viewpoint.margin`` of it (a fitting box and a fitting cylinder
  alike: the scan cannot tell them apart -- where one describes the clicked object decisively
  better, the verdict refuses the other, :func:`.scoring.described`: a flat cylinder laid over
  a box's face explains that face, not the box);
* **rival pose**: its template in a second pose -- more than ``viewpoint.pose_distance`` /
  ``viewpoint.pose_angle`` away, symmetry-aware -- scores within that margin (the fit's
  medium-stage hypotheses, ``FitReport.alternatives``, are those second poses);
* **weakly held**: the residual barely changes along some motion of its pose -- the smallest
  eigenvalue of the point-to-plane Hessian J^T J over the samples the scan covers is below
  ``viewpoint.weak_ratio`` x the largest (a flat face seen edge-on slides along itself; a
  primitive's model as measured, too). Rotations are scaled by the samples' RMS radius so they
  weigh like translations, and a continuous symmetry's own rotation is left out (it moves
  nothing). The Hessian does not see where a surface ends: a box seen on its top and front
  faces slides along their common edge as far as the point-to-plane residual goes, and yet the
  scan shows both ends of the box. So the pose moved ``WEAK_STEP`` along that motion, each way,
  is put to the scan (:func:`contradicted`): where it puts samples where the sensor saw through,
  or leaves points of the clicked object (off the surface it stands on) off its surface, at
  ``MIN_HOLDING`` places or more both ways, the outline holds it. Else it is weakly held (a
  face whose ends are hidden, a wheel seen edge-on, a plate nearly flush with its panel).

What the verdict refuses rivals no answer that fits: a valve that does not fit a box's points
may score near the box, and the box is still the answer (a second pose or an alternative of a
template stands as its template's candidate does). Nor does a primitive rival a specific template
that fits: the verdict has already made that template show what sets it apart from the primitive
fitting the same points (:func:`.scoring.distinguished`), or refused it. Where the answer is
refused, every candidate within the margin is a hypothesis a new view may settle.

The rivals (best first) are the hypotheses a suggested view must tell apart (:mod:`.viewpoint`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..neighbours import nearest
from ..scene import ClickContext
from ..transforms import axis_angle_matrix, make_T, pose_error
from .model import Model, surface_distances
from .results import FitResult
from .settings import FitSettings
from .visibility import visible

__all__ = [
    "Ambiguity",
    "Hypothesis",
    "assess",
    "pose_hessian",
    "moved_along",
    "contradicted",
    "WEAK_STEP",
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
#: fewer holding samples than this: the Hessian says nothing (the verdict speaks instead); and
#: a move the scan contradicts at fewer places than this is not told apart by it
MIN_HOLDING = 12
#: a weakly held pose is moved along its weak motion until its samples move this far (m): what
#: the scan says of the moved pose decides whether it is held after all, and the moved poses are
#: the rivals a suggested view tells apart (:mod:`.viewpoint`)
WEAK_STEP = 0.02


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
    """The :class:`Ambiguity` of a click's ranked ``candidates`` (FitResult, best first: the
    specific templates and the primitives); ``alternatives`` (FitResult) are further
    hypotheses of the fit (other poses of each template, less refined than the candidates),
    ``model_of(result)`` the model a result was fitted as, ``refine(result)`` (optional) an
    alternative of the answer's template within the margin finished as a candidate is (it may
    then join the answer's pose, or fall behind the margin). The candidates the library
    prefilter set aside take no part (they are not fitted answers)."""
    s = settings.viewpoint
    fitted = [c for c in candidates if not c.prefiltered]
    if not fitted:
        return Ambiguity(settled=False, kinds=(REFUSED,), reasons=("nothing was fitted",))
    best = fitted[0]
    kinds, reasons = [], []
    if best.fits is False:
        kinds.append(REFUSED)
        reasons.append(f"the verdict refuses {best.template} ({best.reason})")
    standing = {c.template: c for c in fitted}  # each template's candidate

    def rivals_best(r: FitResult) -> bool:
        """Whether ``r`` (a candidate or an alternative) can rival the answer: not when the
        answer fits and the verdict refuses ``r``'s template, nor when a primitive meets a
        specific template that fits (the verdict set those apart)."""
        if not best.fits:
            return True
        if standing.get(r.template, r).fits is False:
            return False
        return best.primitive is not None or r.primitive is None

    bar = s.margin * best.residual
    rivals = [Hypothesis(best.template, best.T_scene_model, best.residual, model_of(best))]
    for r in sorted(list(fitted[1:]) + list(alternatives), key=lambda r: r.residual):
        if r.residual > bar or len(rivals) >= 1 + s.rivals or not rivals_best(r):
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
        model, T = rivals[0].model, best.T_scene_model
        H = pose_hessian(ctx, model, T, settings)
        if H is not None:
            weakest, direction = _weakest(H, model, T)
            if weakest < s.weak_ratio and (
                direction is None
                or not all(
                    contradicted(ctx, model, T, moved_along(T, H, sign * direction), settings)
                    >= MIN_HOLDING
                    for sign in (1.0, -1.0)
                )
            ):
                kinds.append(WEAKLY_HELD)
                reasons.append(
                    f"the scan barely holds {best.template} along one motion (its "
                    f"weakest direction is {weakest:.1%} of its strongest, and nothing in the "
                    f"scan tells a move of {WEAK_STEP * 100:.0f} cm along it apart)"
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


def moved_along(T: np.ndarray, held, motion: np.ndarray) -> np.ndarray:
    """The pose ``T`` (4x4) moved by ``motion`` (6,: rotation (rad) and translation (m) per
    unit, about the centroid of the samples :func:`pose_hessian` held -- ``held`` is its
    answer) scaled so that its samples move ``WEAK_STEP``."""
    _, c, L = held
    w, v = motion[:3], motion[3:]
    step = WEAK_STEP / max(float(np.linalg.norm(v) + np.linalg.norm(w) * L), 1e-9)
    angle = step * float(np.linalg.norm(w))
    R = axis_angle_matrix(w / max(np.linalg.norm(w), 1e-12), angle) if angle > 0 else np.eye(3)
    return make_T(R @ T[:3, :3], R @ (T[:3, 3] - c) + c + step * v)


def contradicted(
    ctx: ClickContext, model: Model, T: np.ndarray, moved: np.ndarray, settings: FitSettings
) -> int:
    """At how many places the scan contradicts ``model`` at pose ``moved`` where it did not at
    ``T``: its samples (``viewpoint.samples`` of them) where the sensor saw through (free
    space), and the clicked object's points (an even subsample of at most as many of the
    clicked segment's, those off the support plane) within ``HOLDING`` x
    ``verdict.coverage_distance`` of its surface at ``T`` and not at ``moved``. Without a
    viewpoint, 0."""
    if ctx.sensor_origin is None:
        return 0
    n = settings.viewpoint.samples
    P, N = model.samples(n)
    pts = ctx.clicked_points
    if len(pts) > n:
        pts = pts[(np.arange(n) * (len(pts) / n)).astype(np.int64)]
    if ctx.support is not None and len(pts):  # (the surface it stands on is no part of it)
        pts = pts[np.abs(ctx.support.distance(pts)) > ctx.plane_threshold]
    near = HOLDING * settings.verdict.coverage_distance

    def against(pose: np.ndarray):
        """(samples seen through, points on the surface) at ``pose``."""
        R, t = pose[:3, :3], pose[:3, 3]
        _, through = visible(ctx, (P @ R.T + t)[None], (N @ R.T)[None], settings)
        on = surface_distances([model], ((pts - t) @ R)[None], 2.0 * near)[0] <= near
        return through[0], on

    through, on = against(T)
    through_moved, on_moved = against(moved)
    return int((through_moved & ~through).sum()) + int((on & ~on_moved).sum())


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
