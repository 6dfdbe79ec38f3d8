# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Where the sensor should look from to settle an unsettled click (:func:`suggest_view`).

Candidate sensor poses are sampled within the ``viewpoint`` bounds: ``directions`` directions
about the best candidate's centre, at most ``max_angle`` from the current view, at least
``min_elevation`` above the support plane on its open side (the sensor's), each at
``distances`` distances in [``min_distance``, ``max_distance``]. From each, and from the current
pose, the sensor's view is predicted for every hypothesis to tell apart
(:class:`~.ambiguity.Ambiguity`'s rivals; a weakly held pose's rival is itself moved along its
weak motion, both ways): a z-buffer of the scan around the click (the occluder: the crop's points
off the support plane, and the rest of the scan within reach where it is given) and of the
hypothesis's posed samples that face the sensor within ``grazing_angle`` (:func:`predict_views`). A
sample is in sight where neither its own surface nor the scan is nearer in its bin by more than a
tolerance (``depth_difference`` plus two bins' width at its depth).

What a view would tell: the samples of each hypothesis it newly brings into sight (out of sight
from the current view: what the scan already shows has been judged) whose depth the other
hypothesis's prediction contradicts there -- for the best against each rival and each rival
against the best, the rivals weighted by how likely each is against the best (the inverse
residual ratio). A view scores that plus ``visibility_weight`` x the best candidate's newly
visible samples; the best-scoring view is suggested. Bins are square in tangent space,
``crop.voxel`` / the middle distance across, so a nearer view has more of them on the object
(as a real sensor has more pixels there).

The pose is an optical frame (z forward, x right, y down) in the cloud's frame; its roll
follows the current sensor's where that is known, else "down" is into the support plane (or
along an axis of the frame attached to the scan around the click).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import minimum_filter

from ..scene import ClickContext
from .ambiguity import WEAK_STEP, Ambiguity, Hypothesis, moved_along, pose_hessian
from .parallel import parts, run
from .settings import FitSettings

__all__ = ["SuggestedView", "suggest_view", "predict_views", "optical_pose", "WEAK_STEP"]

GOLDEN = math.pi * (3.0 - math.sqrt(5.0))
#: the predicted views of one hypothesis hold at most this many bins in all (V x n x n; at the
#: defaults 121 views of about 170 x 170)
VIEW_BINS = 8_000_000


@dataclass(frozen=True)
class SuggestedView:
    """A suggested sensor pose: ``T_scene_optical`` (4x4; z forward, x right, y down) looking at
    ``target`` (3,) from ``distance`` (m), turned ``turn`` (rad) from the current view about the
    target; ``differing``: the newly seen samples where the rivals' predictions contradict each
    other (weighted over the rivals) and ``separation`` their share of all samples in sight;
    ``visible`` / ``visible_now``: the share of the best candidate's samples the sensor would
    see from there / sees from the current view; ``views``: the poses scored."""

    T_scene_optical: np.ndarray = field(repr=False)
    target: np.ndarray = field(repr=False)
    distance: float
    turn: float
    differing: int
    separation: float
    visible: float
    visible_now: float
    score: float
    views: int
    time_s: float = 0.0

    def describe(self) -> str:
        p = self.T_scene_optical[:3, 3]
        return (
            f"look from ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}), {self.distance:.2f} m from the "
            f"object, turned {math.degrees(self.turn):.0f} deg from the current view: the "
            f"hypotheses differ on {self.separation:.0%} of what it would see, and "
            f"{self.visible:.0%} of the best candidate's surface is in sight "
            f"({self.visible_now:.0%} now)"
        )

    def to_dict(self) -> dict:
        from ..transforms import matrix_to_quat_xyzw

        R, p = self.T_scene_optical[:3, :3], self.T_scene_optical[:3, 3]
        return {
            "position": [round(float(v), 6) for v in p],
            "orientation_xyzw": [round(float(v), 6) for v in matrix_to_quat_xyzw(R)],
            "pose": [[round(float(v), 9) for v in row] for row in self.T_scene_optical],
            "target": [round(float(v), 6) for v in self.target],
            "distance": round(self.distance, 4),
            "turn_deg": round(math.degrees(self.turn), 2),
            "differing_samples": int(self.differing),
            "separation": round(self.separation, 4),
            "visible": round(self.visible, 4),
            "visible_now": round(self.visible_now, 4),
            "score": round(self.score, 3),
            "views_scored": self.views,
            "time_s": round(self.time_s, 6),
            "text": self.describe(),
        }


def optical_pose(origin: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """The optical frames (..., 4, 4; z forward, x right, y down) at ``origin`` (..., 3)
    looking at ``target`` (3,), their y as near ``down`` (3,) as the view allows."""
    origin = np.asarray(origin, float)
    z = np.asarray(target, float) - origin
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    y = down - z * (z @ down)[..., None]
    other = np.where((np.abs(z[..., :1]) < 0.9), [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    along = np.linalg.norm(y, axis=-1, keepdims=True) < 1e-6  # looking along "down"
    y = np.where(along, np.cross(z, other), y)  # (any roll will do)
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    T = np.zeros(origin.shape[:-1] + (4, 4))
    T[..., :3, 0], T[..., :3, 1], T[..., :3, 2] = np.cross(y, z), y, z
    T[..., :3, 3], T[..., 3, 3] = origin, 1.0
    return T


def _directions(d0: np.ndarray, max_angle: float, n: int, frame: np.ndarray) -> np.ndarray:
    """``n`` unit directions (n, 3) spread evenly (a Fibonacci spiral) over the cap of half-angle
    ``max_angle`` about ``d0``, ``d0`` itself first; the spiral starts from the axis of
    ``frame`` (3, 3: attached to the scan) farthest from ``d0``, so a rigidly moved scene gets
    the rigidly moved directions."""
    ref = frame[:, int(np.argmin(np.abs(frame.T @ d0)))]
    e1 = ref - d0 * (ref @ d0)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d0, e1)
    k = np.arange(n - 1)
    cos_t = 1.0 - (1.0 - math.cos(max_angle)) * (k + 0.5) / max(n - 1, 1)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t**2, 0.0))
    phi = k * GOLDEN
    dirs = cos_t[:, None] * d0 + sin_t[:, None] * (
        np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    )
    return np.concatenate([d0[None], dirs])


def _weak_rivals(
    ctx: ClickContext, best: Hypothesis, amb: Ambiguity, settings: FitSettings
) -> list:
    """The best pose moved both ways along its weak motion (samples moving ``WEAK_STEP``):
    [] when it is not weakly held."""
    if amb.weak_direction is None or best.model is None:
        return []
    held = pose_hessian(ctx, best.model, best.T_scene_model, settings)
    if held is None:
        return []
    return [
        Hypothesis(
            best.template,
            moved_along(best.T_scene_model, held, np.asarray(amb.weak_direction, float) * sign),
            best.residual,
            best.model,
        )
        for sign in (1, -1)
    ]


def _occluders(ctx: ClickContext) -> np.ndarray:
    """The crop's points that can hide something from a sensor on the open side of the support
    plane: those off it (a plane hides nothing on its own side from a sensor on that side)."""
    if ctx.support is None:
        return ctx.crop
    return ctx.crop[np.abs(ctx.support.distance(ctx.crop)) > ctx.plane_threshold]


def predict_views(
    ctx: ClickContext,
    hyps,
    poses: np.ndarray,
    settings: FitSettings,
    occluders: np.ndarray | None = None,
):
    """The predicted views of each hypothesis (:class:`~.ambiguity.Hypothesis`, best first)
    from each sensor pose (V, 4, 4, optical frames): (pred (H, V, n, n) depth, inf where
    nothing; surface (H, V, n, n) bool: the hypothesis's surface shows there; seen (H, V, S)
    bool: which of its ``viewpoint.samples`` samples (``Model.samples`` order) the sensor would
    see; bins (H, V, S): each sample's bin (n * n: none); depth (H, V, S): its depth; the
    bin's size, tangent space: :func:`bin_size`, coarser where VIEW_BINS asks).
    ``occluders``: the scan points that hide (default the crop's, less the support plane's).
    The poses are rendered in parts side by side (``threads``)."""
    s = settings.viewpoint
    occ = (_occluders(ctx) if occluders is None else occluders).astype(np.float32)
    posed = []
    for h in hyps:
        P, N = h.model.samples(s.samples)
        R, t = h.T_scene_model[:3, :3], h.T_scene_model[:3, 3]
        posed.append(((P @ R.T + t).astype(np.float32), (N @ R.T).astype(np.float32)))
    allX = np.concatenate([X for X, _ in posed])
    centre = 0.5 * (allX.min(axis=0) + allX.max(axis=0))
    reach = float(np.linalg.norm(allX - centre, axis=1).max()) * 1.1 + 2 * ctx.voxel
    dist = np.linalg.norm(poses[:, :3, 3] - centre, axis=1)
    half = float(np.arctan(reach / np.maximum(dist - reach, 0.05)).max())
    n, b = _image_size(2 * math.tan(half), bin_size(ctx, s), len(poses))

    def render(part):
        return _render(part, occ, posed, n, b, s)

    done = run(
        [lambda idx=idx: render(poses[idx]) for idx in parts(len(poses), settings.threads, 8)],
        settings.threads,
    )
    return tuple(np.concatenate([d[k] for d in done], axis=1) for k in range(5)) + (b,)


def bin_size(ctx: ClickContext, s) -> float:
    """The predicted views' bin (tangent space): the crop's voxel at the middle distance."""
    return ctx.voxel / (0.5 * (s.min_distance + s.max_distance))


def _image_size(width: float, b: float, views: int) -> tuple[int, float]:
    """(n, bin) of the predicted views' n x n images spanning ``width`` (tangent space) in bins
    ``b``: at most VIEW_BINS bins over the ``views`` -- a view close to the object (the sensor
    a few centimetres from it) or very many views make the bins coarser, not the images
    larger (they grew to gigabytes)."""
    n_max = max(16, int(math.sqrt(VIEW_BINS / max(views, 1))))
    if not width / b < n_max - 1:
        b = width / (n_max - 1)
    return min(int(math.ceil(width / b)) + 1, n_max), b


def _render(poses, occ, posed, n: int, b: float, s):
    """:func:`predict_views` of the poses (V, 4, 4): bins ``b`` (tangent space) across, n x n
    of them about the optical axis."""
    V = len(poses)
    R = poses[:, :3, :3].astype(np.float32)
    o = poses[:, :3, 3].astype(np.float32)
    shift = np.einsum("vj,vji->vi", o, R)[:, None]
    cosg = math.cos(s.grazing_angle)
    outside = V * n * n

    def project(X):
        """(V, K) flat bins (``outside`` where outside) and depths of points X (K, 3)."""
        rel = np.matmul(X[None], R) - shift
        z = rel[..., 2]
        zs = np.maximum(z, 1e-3) * b
        iu = np.floor(rel[..., 0] / zs + n / 2).astype(np.int64)
        iv = np.floor(rel[..., 1] / zs + n / 2).astype(np.int64)
        ok = (iu >= 0) & (iu < n) & (iv >= 0) & (iv < n) & (z > 1e-3)
        return np.where(ok, np.arange(V)[:, None] * n * n + iu * n + iv, outside), z

    def zbuffer(flat, z):
        """(raw, and with each bin the nearest of its 3 x 3: no holes between samples)."""
        img = np.full(outside + 1, np.inf, np.float32)
        np.minimum.at(img, flat.ravel(), z.ravel())
        return img, nearest_of_3x3(img[:-1].reshape(V, n, n))

    occ_img = zbuffer(*project(occ))[1]
    occ_flat = np.append(occ_img.ravel(), np.inf)
    preds, surfaces, seen, bins, depths = [], [], [], [], []
    for X, Nw in posed:
        flat, z = project(X)
        depths.append(z)
        # facing: -n . (x - o) > cos(grazing) |x - o|
        dot = (X * Nw).sum(axis=1)[None] - o @ Nw.T  # n . (x - o)
        D = X[None] - o[:, None]
        flat = np.where(-dot > cosg * np.sqrt(np.einsum("vki,vki->vk", D, D)), flat, outside)
        raw, img = zbuffer(flat, z)
        surface = np.isfinite(img) & ~(occ_img < img - s.depth_difference)
        preds.append(np.minimum(img, occ_img))
        surfaces.append(surface)
        # a sample is in sight where nothing of its own (the nearest of its bin) nor of the
        # scan (the nearest of its 3 x 3) is in front of it by more than the tolerance
        tol = tolerance(z, b, s)
        seen.append((flat < outside) & (z <= raw[flat] + tol) & ~(occ_flat[flat] < z - tol))
        bins.append(np.where(flat < outside, flat - np.arange(V)[:, None] * n * n, n * n))
    return np.stack(preds), np.stack(surfaces), np.stack(seen), np.stack(bins), np.stack(depths)


def nearest_of_3x3(img: np.ndarray) -> np.ndarray:
    """Each bin of the (V, n, n) depth images the nearest of its 3 x 3 (``minimum_filter``
    with ``size=(1, 3, 3)`` beyond an inf border), filtered only over each view's box around
    the bins it has (the rest of a far view's image is empty): the same numbers."""
    out = np.full(img.shape, np.inf, img.dtype)
    finite = np.isfinite(img)
    rows, cols = finite.any(axis=2), finite.any(axis=1)
    for v in np.flatnonzero(rows.any(axis=1)):
        r, c = np.flatnonzero(rows[v]), np.flatnonzero(cols[v])
        r0, r1 = max(r[0] - 1, 0), min(r[-1] + 2, img.shape[1])
        c0, c1 = max(c[0] - 1, 0), min(c[-1] + 2, img.shape[2])
        out[v, r0:r1, c0:c1] = minimum_filter(
            img[v, r0:r1, c0:c1], size=3, mode="constant", cval=np.inf
        )
    return out


def tolerance(z: np.ndarray, b: float, s) -> np.ndarray:
    """The depth two predictions may differ by at depth ``z`` and still be the same surface:
    ``depth_difference`` plus two bins' width there (a slanted surface's depth runs across a
    bin)."""
    return s.depth_difference + 2.0 * b * z


def suggest_view(
    ctx: ClickContext,
    amb: Ambiguity,
    settings: FitSettings,
    T_scene_optical: np.ndarray | None = None,
    occluders: np.ndarray | None = None,
    support=None,
) -> SuggestedView | None:
    """The sensor pose within the ``viewpoint`` bounds that best tells the rivals of ``amb``
    apart and shows most of the best candidate (see the module's description), or None
    without a viewpoint or hypotheses. ``occluders`` (N, 3): more of the scan that may hide the
    object (the crop's points always do); ``support``: the plane the views stay in front of
    (default the crop's support plane; none: no such bound)."""
    t0 = time.perf_counter()
    s = settings.viewpoint
    if ctx.sensor_origin is None or not amb.rivals or amb.rivals[0].model is None:
        return None
    hyps = list(amb.rivals)
    hyps += _weak_rivals(ctx, hyps[0], amb, settings)
    best = hyps[0]
    target = best.T_scene_model[:3, :3] @ best.model.centroid + best.T_scene_model[:3, 3]
    origin = ctx.sensor_origin
    d0 = origin - target
    r0 = float(np.linalg.norm(d0))
    d0 = d0 / max(r0, 1e-9)
    dirs = _directions(d0, s.max_angle, s.directions, ctx.frame)
    support = ctx.support if support is None else support
    if support is not None:
        normal = support.normal * (1.0 if support.normal @ d0 >= 0 else -1.0)
        dirs = dirs[dirs @ normal >= math.sin(s.min_elevation) - 1e-9]
        down = -normal
    else:  # an axis of the frame attached to the scan (none of the cloud's)
        down = ctx.frame[:, 1]
    if T_scene_optical is not None:
        down = np.asarray(T_scene_optical, float)[:3, 1]
    if not len(dirs):
        return None
    lo, hi = sorted((s.min_distance, s.max_distance))
    distances = (
        np.linspace(lo, hi, s.distances) if s.distances > 1 else np.array([0.5 * (lo + hi)])
    )
    current = optical_pose(origin, target, down)
    around = (target + distances[:, None, None] * dirs[None]).reshape(-1, 3)
    poses = np.concatenate([current[None], optical_pose(around, target, down)])
    if occluders is not None:  # the scan beyond the crop, the support plane left out
        if support is not None:
            occluders = occluders[np.abs(support.distance(occluders)) > 2 * ctx.plane_threshold]
        occluders = np.concatenate([_occluders(ctx), occluders])
    pred, surface, seen, bins, depth, b = predict_views(ctx, hyps, poses, settings, occluders)
    new = seen & ~seen[:, :1]  # samples in sight from there, out of sight now
    V = len(poses)
    flat = np.concatenate(
        [pred.reshape(len(hyps), V, -1), np.full((len(hyps), V, 1), np.inf, pred.dtype)], axis=2
    )

    def telling(a: int, c: int) -> np.ndarray:
        """(V,) how many of hypothesis a's newly seen samples hypothesis c's prediction
        contradicts (its depth there differs by more than the tolerance)."""
        other = np.take_along_axis(flat[c], bins[a], axis=1)
        with np.errstate(invalid="ignore"):
            off = ~(np.abs(other - depth[a]) <= tolerance(depth[a], b, s))
        return (new[a] & off).sum(axis=1)

    if len(hyps) > 1:  # each rival weighs as likely as it is against the best
        weight = np.array([hyps[0].residual / max(h.residual, 1e-12) for h in hyps[1:]])
        tells = np.array([telling(0, k) + telling(k, 0) for k in range(1, len(hyps))])
        differing = (weight[:, None] * tells).sum(axis=0) / weight.sum()
    else:
        differing = np.zeros(V)
    score = differing + s.visibility_weight * new[0].sum(axis=1)
    k = 1 + int(np.argmax(score[1:]))  # the current pose itself is no suggestion
    T = poses[k]
    turn = float(
        np.arccos(np.clip((T[:3, 3] - target) @ d0 / np.linalg.norm(T[:3, 3] - target), -1.0, 1.0))
    )
    return SuggestedView(
        T_scene_optical=T,
        target=target,
        distance=float(np.linalg.norm(T[:3, 3] - target)),
        turn=turn,
        differing=int(round(float(differing[k]))),
        separation=float(differing[k] / max(int(seen[:, k].sum()), 1)),
        visible=float(seen[0, k].mean()),
        visible_now=float(seen[0, 0].mean()),
        score=float(score[k]),
        views=len(poses) - 1,
        time_s=time.perf_counter() - t0,
    )
