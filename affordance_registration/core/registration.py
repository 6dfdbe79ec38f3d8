"""Random-restart weighted ICP over every template, batched.

The method of record (Hagenow et al.): correspondences from template samples to the nearest scene
points; a correspondence whose distance d exceeds the template diameter is rejected; the rest are
weighted w = 1/(1+d); the weighted rigid transform is solved in closed form (SVD); iterate.
Restarts start from random orientations and offsets around the click; a template's likelihood is
the inverse of its residual. ``method="paper"`` runs that literally (the benchmark baseline).

The default method keeps the spirit and fixes what a literal implementation gets wrong on
one-sided scans (see DESIGN.md):

* the weight keeps the paper's form but scales the distance, w = 1/(1 + d/d0), d0 = 5 mm
  (``weight_scale``) -- with d in metres the paper's weight is ~1 for every useful d;
* only template samples that face the sensor and are not hidden behind observed surfaces take part
  (a range image of the crop answers "hidden?" and "did the sensor see through here?");
* the residual is two-way and capped: template -> scene (free-space violations count as the cap)
  and scene cluster -> template, so neither a thin template lying flat nor a small template hiding
  inside a big object can win;
* all restarts of all templates advance together (one KD query per iteration, a batched weighted
  SVD), coarse to fine: 64 samples for every restart -> the best 2 per template at 256 -> rank ->
  the winner at 1500;
* initial orientations come from the mounting plane under the click (template +z along its
  normal, a yaw sweep), from the template's stable resting facets on that plane (objects lying
  on a table) and from uniform random ones; the best mounted hypothesis always reaches the
  medium stage;
* the operator clicked *on* the object: candidates are centred on the cluster points near the
  click and pay for a surface that misses the click by more than ``click_tolerance``;
* directions in which the sensor returned nothing (outside the image, dropouts) are no evidence
  either way: samples there neither pull nor count;
* articulated templates (a joint with its moving part, or a scale range) among the leading
  candidates get their joint value and scale with the pose: a sweep across the joint's limits
  (the fixed part held, or moved back with the moving part left where the data put it), local
  steps, and a fine stage whose point-to-plane Gauss-Newton step has a column for the joint and
  one for the scale besides the six of the pose. A fit resting on the plane under the click keeps
  resting on it, and a joint value or scale the data cannot tell from a named state or scale 1 is
  reported there, so the extra unknowns cost no rigid accuracy.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from .errors import RegistrationError
from .scene import ClickContext, Scene
from .templates import AffordanceTemplate, TemplateLibrary
from .transforms import align_z_to, axis_angle_matrix, make_T, random_rotations, rotation_angle

__all__ = ["FitSettings", "FitResult", "FitReport", "Registrar", "PosedTemplate",
           "correspondence_weights",
           "weighted_rigid_fit"]


MOUNTED, RESTING, RANDOM = 0, 1, 2     # families of initial hypotheses
CONTACT_BAND = 0.002                   # m: samples this close to the lowest one rest on the plane
CONTACT_SLACK = 0.005                  # m: a gap to the plane within this costs nothing


@dataclass(frozen=True)
class FitSettings:
    """Fitting parameters (lengths in metres, angles in radians)."""

    method: str = "default"            #: "default" or "paper" (the literal baseline)
    mode: str = "auto"                 #: "auto" (plane prior + random), "mounted", "free"
    voxel: float = 0.005               #: voxel edge of the crop
    crop_factor: float = 1.0           #: crop radius = crop_factor * largest template diameter
    snap_distance: float = 0.03        #: a click farther than this from the scan is refused
    click_tolerance: float = 0.015     #: a candidate's surface should pass this close to the click
    weight_scale: float = 0.005        #: d0 in w = 1 / (1 + d / d0)
    score_cap: float = 0.01            #: per-point distance cap of the residual
    reject_floor: float = 0.015        #: ICP rejection radius shrinks to this within a stage
    free_space_margin: float = 0.01    #: depth tolerance of the visibility tests
    grazing_angle: float = math.radians(89.0)  #: samples seen more obliquely count as unseen
    score_samples: int = 600           #: template samples per candidate in the residual
    yaw_restarts: int = 12             #: plane-prior restarts per template (yaw sweep)
    random_restarts: int = 12          #: uniformly random restarts per template
    free_restarts: int = 40            #: random restarts per template when there is no plane
    resting_poses: int = 5             #: stable resting facets tried per template (plane found)
    resting_yaws: int = 6              #: yaw steps per resting facet
    coarse_samples: int = 64
    coarse_iterations: int = 8
    keep_per_template: int = 3
    coarse_two_way: bool = True        #: coarse selection also scores cluster -> template
    medium_samples: int = 256
    medium_iterations: int = 10
    fine_samples: int = 1500
    fine_iterations: int = 25
    fine_metric: str = "plane"         #: final stage: "plane" (point-to-plane) or "point"
    two_way: bool = True               #: final stage also pairs scene points with the template
    reverse_points: int = 600          #: at most this many scene points in those pairs
    yaw_sweep: int = 8                 #: winner re-tried at this many angles about its axis
    #: estimate joint values and scale where templates have them (see ``bench``'s articulated rows)
    articulated: bool = True
    articulated_candidates: int = 4    #: at most that many leading candidates get them estimated,
    articulated_margin: float = 1.3    #: those with a residual within this factor of the best
    joint_sweep: int = 13              #: joint values tried across a revolute joint's limits
    scale_sweep: int = 7               #: scales tried across a template's scale range
    #: an articulated candidate whose rigid fit touches the plane under the click (within this)
    #: keeps touching it: the joint must not be traded for the whole object floating off it
    contact_distance: float = 0.01
    #: a joint value the data cannot tell from the nearest named state (residual within this
    #: fraction) is reported at that state; likewise a scale and the nominal scale 1
    nominal_preference: float = 0.02
    nominal_scale_preference: float = 0.005
    articulation_rounds: int = 3
    articulation_icp: int = 5          #: ICP iterations per sweep hypothesis
    refit_restarts: int = 10
    refit_spread: float = 0.015        #: translation spread of the refit's restarts (m)
    refit_samples: int = 800
    refit_iterations: int = 12
    refit_max_move: float = 0.05       #: a refit may move at most this far from the correction
    refit_max_turn: float = math.radians(30.0)
    paper_restarts: int = 25
    paper_iterations: int = 100
    paper_samples: int = 500
    seed: int = 0

    def validate(self) -> "FitSettings":
        if self.method not in ("default", "paper"):
            raise RegistrationError(f"method must be 'default' or 'paper', got {self.method!r}")
        if self.fine_metric not in ("plane", "point"):
            raise RegistrationError(f"fine_metric must be 'plane' or 'point', got {self.fine_metric!r}")
        if self.mode not in ("auto", "mounted", "free"):
            raise RegistrationError(f"mode must be 'auto', 'mounted' or 'free', got {self.mode!r}")
        for name in ("voxel", "crop_factor", "snap_distance", "click_tolerance", "refit_spread", "weight_scale", "score_cap",
                     "free_space_margin", "grazing_angle", "reject_floor", "refit_max_move", "refit_max_turn",
                     "articulated_margin", "contact_distance", "nominal_preference",
                     "nominal_scale_preference"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise RegistrationError(f"{name} must be a positive number, got {v!r}")
        for name in ("coarse_samples", "coarse_iterations", "keep_per_template", "medium_samples",
                     "medium_iterations", "fine_samples", "score_samples", "reverse_points",
                     "refit_samples", "refit_iterations", "fine_iterations", "refit_restarts",
                     "paper_restarts", "paper_iterations", "paper_samples"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise RegistrationError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("yaw_restarts", "random_restarts", "free_restarts", "yaw_sweep",
                     "articulated_candidates", "joint_sweep", "scale_sweep", "articulation_rounds",
                     "articulation_icp",
                     "resting_poses", "resting_yaws"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 0):
                raise RegistrationError(f"{name} must be an integer >= 0, got {v!r}")
        if self.yaw_restarts + self.random_restarts == 0 or self.free_restarts == 0:
            raise RegistrationError("at least one restart per template is needed")
        return self


@dataclass(frozen=True)
class FitResult:
    """One fitted candidate. Candidates are ranked by ``likelihood`` (higher is better), which is
    the inverse of ``residual``; ``probability`` is the likelihood normalized over the click's
    candidates."""

    template: str
    T_scene_model: np.ndarray = field(repr=False)   #: 4x4, model -> scene
    residual: float                                  #: m, two-way capped mean distance
    likelihood: float                                #: 1 / residual (the ranking field)
    probability: float = 0.0
    inlier_fraction: float = 0.0                     #: visible samples within the cap
    iterations: int = 0
    time_s: float = 0.0
    rank: int = 0                                    #: 1 = best
    joints: dict = field(default_factory=dict)       #: joint name -> value (rad or m)
    scale: float = 1.0                               #: uniform scale of the template
    state: str | None = None                         #: the nearest named state

    def to_dict(self) -> dict:
        return {"rank": self.rank, "template": self.template,
                "joints": {k: round(float(v), 6) for k, v in self.joints.items()},
                "scale": round(float(self.scale), 6), "state": self.state,
                "likelihood": round(self.likelihood, 6), "probability": round(self.probability, 6),
                "residual": round(self.residual, 9), "inlier_fraction": round(self.inlier_fraction, 4),
                "iterations": self.iterations, "time_s": round(self.time_s, 6),
                "pose": [[round(float(v), 9) for v in row] for row in self.T_scene_model]}


@dataclass(frozen=True)
class FitReport:
    """The ranked candidates of one click (best first) and where the time went."""

    point: np.ndarray
    candidates: tuple
    timing_s: dict
    context: ClickContext = field(repr=False)


class PartTrees:
    """KD-trees over dense samples of a template's fixed and moving part at joint value zero and
    scale one, in the template frame: nearest-surface queries for the template at any joint value
    and scale without building a tree per hypothesis."""

    def __init__(self, template: AffordanceTemplate, n: int = 4096):
        P, _, moving = template.part_samples(n, seed=2)
        self.base_pts, self.moving_pts = P[~moving], P[moving]
        self.base = cKDTree(self.base_pts)
        self.moving = cKDTree(self.moving_pts) if len(self.moving_pts) else None


class PosedTemplate:
    """A template with its joint at ``q`` and scaled by ``scale``: the interface the fitting
    uses (samples, centroid, diameter, symmetry, name, nearest), so articulated and scaled
    candidates run through the same batched ICP and scoring as rigid ones. ``moving_only`` keeps
    just the moving part's samples (to judge a joint value by the part it moves)."""

    def __init__(self, template: AffordanceTemplate, trees: PartTrees, q: float = 0.0,
                 scale: float = 1.0, moving_only: bool = False):
        self.template, self.trees, self.q, self.scale = template, trees, float(q), float(scale)
        self.name, self.symmetry = template.name, template.symmetry
        self.moving_only = moving_only
        self._cache: dict = {}

    def with_values(self, q: float | None = None, scale: float | None = None,
                    moving_only: bool = False) -> "PosedTemplate":
        return PosedTemplate(self.template, self.trees, self.q if q is None else q,
                             self.scale if scale is None else scale, moving_only)

    @property
    def diameter(self) -> float:
        return self.template.diameter * self.scale

    @property
    def centroid(self) -> np.ndarray:
        if "centroid" not in self._cache:
            P, N, moving = self.template.part_samples(2048, seed=0)
            self._cache["centroid"] = self.template.pose_parts(P, N, moving, self.q,
                                                               self.scale)[0].mean(axis=0)
        return self._cache["centroid"]

    def samples(self, n: int, seed: int = 0):
        key = (int(n), int(seed))
        if key not in self._cache:
            if self.moving_only:
                P, N, moving = self.template.part_samples(4 * n, seed)
                P, N = self.template.pose_parts(P, N, moving, self.q, self.scale)
                idx = np.flatnonzero(moving)
                idx = idx[np.linspace(0, len(idx) - 1, n).astype(int)]
                self._cache[key] = (P[idx], N[idx])
            else:
                P, N, moving = self.template.part_samples(n, seed)
                self._cache[key] = self.template.pose_parts(P, N, moving, self.q, self.scale)
        return self._cache[key]

    def nearest(self, local: np.ndarray, upper: float = np.inf, parts: bool = False):
        """Distance (m) from points ``local`` (N, 3, this posed template's frame) to the nearest
        dense surface sample, and that sample (N, 3); distances beyond ``upper`` are inf. With
        ``parts``, also whether that sample is on the moving part (N,) bool."""
        u = np.asarray(local, dtype=float) / self.scale
        ub = upper / self.scale
        d, i = self.trees.base.query(u, k=1, distance_upper_bound=ub)
        pts = self.trees.base_pts[np.minimum(i, len(self.trees.base_pts) - 1)]
        if self.trees.moving is not None:
            T = self.template.joint_transform(self.q) if self.q else np.eye(4)
            um = (u - T[:3, 3]) @ T[:3, :3]          # into the moving part's zero pose
            dm, im = self.trees.moving.query(um, k=1, distance_upper_bound=ub)
            closer = dm < d
            d = np.where(closer, dm, d)
            pm = self.trees.moving_pts[np.minimum(im, len(self.trees.moving_pts) - 1)]
            pts = np.where(closer[:, None], pm @ T[:3, :3].T + T[:3, 3], pts)
        else:
            closer = np.zeros(len(d), bool)
        if parts:
            return d * self.scale, pts * self.scale, closer
        return d * self.scale, pts * self.scale

    def resting_rotations(self, max_poses: int = 6):
        """The template's resting orientations (those at joint zero; scale does not change
        them)."""
        return self.template.resting_rotations(max_poses)

    @property
    def joints(self) -> dict:
        j = self.template.joint
        return {j.name: self.q} if j is not None else {}


def _rank(results: list[FitResult]) -> tuple:
    results = sorted(results, key=lambda r: -r.likelihood)
    total = sum(r.likelihood for r in results) or 1.0
    return tuple(replace(r, rank=i, probability=r.likelihood / total)
                 for i, r in enumerate(results, start=1))


def correspondence_weights(dist, reject, d0: float) -> np.ndarray:
    """The paper's correspondence rule: distances beyond ``reject`` are rejected (weight 0), the
    rest weigh w = 1 / (1 + d / d0). The paper has d0 = 1 (d in metres); the default method uses
    d0 = ``weight_scale`` (5 mm), without which every useful d weighs about 1."""
    dist = np.asarray(dist, dtype=float)
    return np.where(dist <= reject, 1.0 / (1.0 + dist / d0), 0.0)


def _kabsch_weighted(X: np.ndarray, Q: np.ndarray, w: np.ndarray):
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


def _point_to_plane_weighted(X: np.ndarray, Q: np.ndarray, Nq: np.ndarray, w: np.ndarray):
    """Batched weighted point-to-plane step: minimise sum w ((R x + t - q) . n)^2, linearised
    about each batch's weighted centroid; returns (R, t) like :func:`_kabsch_weighted`."""
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
    angle = np.linalg.norm(omega, axis=1)
    R = np.stack([axis_angle_matrix(o, a) if a > 1e-12 else np.eye(3)
                  for o, a in zip(omega, angle)])
    t = c + v - np.einsum("bij,bj->bi", R, c)
    R[~ok] = np.eye(3)
    t[~ok] = 0.0
    return R, t


def weighted_rigid_fit(source: np.ndarray, target: np.ndarray, weights=None) -> np.ndarray:
    """T (4x4) minimising sum w |T source - target|^2 for paired (N, 3) point sets (closed form,
    SVD, reflection-safe)."""
    X = np.asarray(source, dtype=float)[None]
    Q = np.asarray(target, dtype=float)[None]
    w = np.ones(X.shape[1]) if weights is None else np.asarray(weights, dtype=float)
    R, t = _kabsch_weighted(X, Q, w[None])
    return make_T(R[0], t[0])


class Registrar:
    """Fits a template library to clicks in scenes. Thread-safe for concurrent ``fit`` calls
    (per-template caches are filled under the templates' own locks)."""

    def __init__(self, library: TemplateLibrary, settings: FitSettings | None = None):
        if library is None or len(library) == 0:
            raise RegistrationError("the template library is empty: nothing to fit")
        self.library = library
        self.settings = (settings or FitSettings()).validate()
        self._dense_trees: dict[str, cKDTree] = {}
        self._part_tree_cache: dict[str, PartTrees] = {}
        self._cos_grazing = math.cos(self.settings.grazing_angle)

    # ------------------------------------------------------------------ public API
    def warm_up(self) -> None:
        """Compute every template's samples, diameter and resting poses now (they are cached),
        so the first click costs what every later one does."""
        s = self.settings
        for tpl in self.library.values():
            for n in {s.coarse_samples, s.medium_samples, s.fine_samples, s.score_samples,
                      s.refit_samples, 256}:
                tpl.samples(n, seed=1)
            tpl.centroid, tpl.diameter
            tpl.resting_rotations(s.resting_poses)
            self._dense_tree(tpl)
            if tpl.articulated:
                self._part_trees(tpl)

    def prepare(self, scene: Scene, click) -> ClickContext:
        """Snap the click to the surface and prepare the crop around it."""
        s = self.settings
        snapped = scene.snap(click, s.snap_distance)
        return scene.prepare_click(snapped, radius=s.crop_factor * self.library.max_diameter,
                                   voxel=s.voxel, seed=s.seed)

    def fit(self, scene: Scene, click, templates=None) -> FitReport:
        """Fit every template (or the named ones) around ``click`` (3,) in ``scene``.

        Returns the candidates ranked best first, one per template."""
        t0 = time.perf_counter()
        ctx = self.prepare(scene, click)
        t1 = time.perf_counter()
        names = list(self.library) if templates is None else list(templates)
        if not names:
            raise RegistrationError("no templates to fit")
        if self.settings.method == "paper":
            candidates = self._fit_paper(ctx, names)
        else:
            candidates = self._fit_default(ctx, names)
        t2 = time.perf_counter()
        timing = {"prepare": t1 - t0, "fit": t2 - t1, "total": t2 - t0}
        return FitReport(point=ctx.click, candidates=candidates, timing_s=timing, context=ctx)

    def refit(self, ctx: ClickContext, template: str, T_init: np.ndarray,
              joints: dict | None = None, scale: float = 1.0,
              hold_joint: bool | None = None) -> FitResult:
        """Refine ``template`` locally from ``T_init`` (an operator's correction): a few small
        perturbations, medium then fine ICP. The result never strays farther than
        ``refit_max_move`` / ``refit_max_turn`` from ``T_init``: a refit that would jump back to a
        pose the operator moved away from keeps the closest acceptable pose instead.

        An articulated template starts from ``joints`` (name -> value) and ``scale`` (with
        ``settings.articulated``). ``hold_joint`` keeps the joint value as given and refines the
        pose and scale only; by default (None) a joint value that is given is kept -- estimated
        once with the click, then changed by the operator's joint corrections, not by refits of
        the pose -- and one that is not given is estimated."""
        s = self.settings
        t0 = time.perf_counter()
        tpl = self._model(template, joints, scale)
        if hold_joint is None:
            hold_joint = bool(joints)
        rng = np.random.default_rng(s.seed + 7919)
        Ts = [np.asarray(T_init, dtype=float)]
        centre = Ts[0][:3, :3] @ tpl.centroid + Ts[0][:3, 3]
        # one restart centred on the data around the correction (a rough drag is often off by a
        # good part of the object's size)
        near = np.linalg.norm(ctx.cluster - centre, axis=1) <= 0.5 * tpl.diameter
        if near.sum() >= 10:
            snapped = Ts[0].copy()
            snapped[:3, 3] += ctx.cluster[near].mean(axis=0) - centre
            if ctx.plane is not None:      # keep the height above the plane the operator chose
                snapped[:3, 3] -= ctx.plane.normal * (ctx.plane.normal @ (snapped[:3, 3] -
                                                                           Ts[0][:3, 3]))
            Ts.append(snapped)
        while len(Ts) < s.refit_restarts:
            axis = rng.normal(size=3)
            dR = axis_angle_matrix(axis, math.radians(4.0) * rng.uniform(0.5, 1.0))
            R = dR @ Ts[0][:3, :3]
            t = dR @ (Ts[0][:3, 3] - centre) + centre + rng.normal(scale=s.refit_spread, size=3)
            Ts.append(make_T(R, t))
        Ts = np.stack(Ts)
        # reach out as far as a refit may move, so a rough correction is pulled in
        reject = np.full(len(Ts), max(0.25 * tpl.diameter, s.refit_max_move))
        R, t = self._icp([tpl] * len(Ts), Ts[:, :3, :3], Ts[:, :3, 3], ctx, s.medium_samples,
                         6, reject, target="cluster", occlusion=True)
        fwd, _ = self._forward_score(ctx, [tpl] * len(Ts), R, t, s.medium_samples)
        move = np.linalg.norm(t - Ts[0][:3, 3], axis=1)
        turn = rotation_angle(np.swapaxes(Ts[0][None, :3, :3], 1, 2) @ R)
        allowed = (move <= s.refit_max_move) & (turn <= s.refit_max_turn)
        if not allowed.any():   # every restart wandered off: start from the correction itself
            R[0], t[0] = Ts[0][:3, :3], Ts[0][:3, 3]
            allowed[0] = True
        best = int(np.argmin(np.where(allowed, fwd, np.inf)))
        if isinstance(tpl, PosedTemplate):
            res, tpl = self._finish_articulated(ctx, tpl, R[best], t[best], s.refit_samples,
                                                s.refit_iterations, 6, hold_joint=hold_joint)
        else:
            res = self._finish(ctx, tpl, R[best], t[best], samples=s.refit_samples,
                               iterations=s.refit_iterations, iterations_before=6)
        res = self._guard_refit(res, Ts[0], R[best], t[best], ctx, tpl)
        return replace(res, time_s=time.perf_counter() - t0)

    def score(self, ctx: ClickContext, template: str, T_scene_model: np.ndarray,
              joints: dict | None = None, scale: float = 1.0) -> FitResult:
        """Residual and likelihood of a given pose, joint values and scale (no fitting)."""
        tpl = self._model(template, joints, scale)
        T = np.asarray(T_scene_model, dtype=float)
        return self._result(ctx, tpl, T[:3, :3], T[:3, 3], 0, 0.0)

    def _model(self, template: str, joints: dict | None = None, scale: float = 1.0):
        """The template to fit: with ``settings.articulated``, an articulated one posed at
        ``joints`` (clipped to its limits) and ``scale`` (clipped to its range)."""
        base = self.library[template]
        if not (self.settings.articulated and base.articulated):
            return base
        j = base.joint
        q = float(np.clip(base.joint_value(joints or {}), j.lower, j.upper)) if j else 0.0
        lo_hi = base.scale_range
        return self._posed(base, q, float(np.clip(scale, *lo_hi)) if lo_hi is not None else 1.0)

    # ------------------------------------------------------------------ default method
    def _fit_default(self, ctx: ClickContext, names: list[str]) -> tuple:
        s = self.settings
        t0 = time.perf_counter()
        rng = np.random.default_rng(s.seed)
        tpls = [self.library[n] for n in names]
        # 1. initial hypotheses for every template: plane prior (yaw sweep) + uniform random;
        #    a template that comes in sizes also at the ends of its scale range
        variants = [(i, tpl) for i, tpl in enumerate(tpls)]
        if s.articulated:
            variants += [(i, self._posed(tpl, 0.0, g)) for i, tpl in enumerate(tpls)
                         if tpl.scale_range is not None for g in tpl.scale_range if g != 1.0]
        hyp_v, hyp_R, hyp_t, family = self._initial_hypotheses(ctx, [m for _, m in variants],
                                                               rng)
        hyp_tpl = np.array([variants[v][0] for v in hyp_v])      # the template of each
        hyp_model = [variants[v][1] for v in hyp_v]               # ... and the model fitted
        # 2. coarse ICP, all restarts of all templates together
        reject = np.array([0.5 * m.diameter for m in hyp_model])
        tlist = hyp_model
        R, t = self._icp(tlist, hyp_R, hyp_t, ctx, s.coarse_samples, s.coarse_iterations, reject,
                         target="cluster", occlusion=True)
        fwd, _ = self._forward_score(ctx, tlist, R, t, s.coarse_samples)
        fwd = fwd + self._click_penalty(ctx, tlist, R, t)
        if s.coarse_two_way:     # the cluster -> template half of the residual, on a subsample
            fwd = 0.5 * fwd + 0.5 * self._coarse_backward(ctx, tlist, R, t)
        # 3. keep the best distinct few per template, refine them at medium resolution
        keep = []
        for i, tpl in enumerate(tpls):
            idx = np.flatnonzero(hyp_tpl == i)
            idx = idx[np.argsort(fwd[idx])]
            mounted = idx[family[idx] == MOUNTED]
            # the best mounting-prior hypothesis always goes on: 64 samples cannot judge a
            # tipped-over pose against it reliably
            chosen = [mounted[0]] if len(mounted) and s.keep_per_template > 1 else []
            for j in idx:
                if all(np.linalg.norm(t[j] - t[k]) > 0.01 or
                       _sym_angle(tpl, R[k].T @ R[j]) > math.radians(10) for k in chosen):
                    chosen.append(j)
                if len(chosen) == s.keep_per_template:
                    break
            keep.extend(chosen)
        keep = np.array(keep)
        tlist = [hyp_model[j] for j in keep]
        reject = np.array([0.25 * tp.diameter for tp in tlist])
        R, t = self._icp(tlist, R[keep], t[keep], ctx, s.medium_samples, s.medium_iterations,
                         reject, target="cluster", occlusion=True)
        # 4. rank: the best hypothesis per template by the two-way residual
        best: dict[int, FitResult] = {}
        elapsed = time.perf_counter() - t0
        iters = s.coarse_iterations + s.medium_iterations
        for k, j in enumerate(keep):
            i = int(hyp_tpl[j])
            res = self._result(ctx, tlist[k], R[k], t[k], iters, elapsed)
            if i not in best or res.likelihood > best[i].likelihood:
                best[i] = res
        ranked = _rank(list(best.values()))
        # 5. articulated templates among the leaders: joint value and scale with the pose
        models = {}
        if s.articulated:
            for r in ranked[:s.articulated_candidates]:
                tpl = self.library[r.template]
                # a rigid fit of a valve with its handle turned can rank behind a wrong
                # template: every close enough articulated candidate gets its joint estimated
                if not tpl.articulated or r.residual > s.articulated_margin * ranked[0].residual:
                    continue
                model, Ra, ta = self._articulate(ctx, tpl, r.T_scene_model[:3, :3],
                                                 r.T_scene_model[:3, 3], tpl.joint_value(r.joints),
                                                 r.scale)
                res = self._result(ctx, model, Ra, ta, iters, elapsed)
                models[r.template] = model
                ranked = tuple(res if x.template == r.template else x for x in ranked)
            ranked = _rank(list(ranked))
        # 6. the winner: a sweep about its mounting axis (near-symmetric handles), then alone
        #    at full resolution
        win = ranked[0]
        tpl = models.get(win.template, self.library[win.template])
        R_w, t_w = self._yaw_sweep(ctx, tpl, win.T_scene_model[:3, :3], win.T_scene_model[:3, 3])
        if isinstance(tpl, PosedTemplate):       # the joint after the sweep, once more
            tpl, R_w, t_w = self._articulate(ctx, tpl.template, R_w, t_w, tpl.q, tpl.scale,
                                             sweep=False)
            final, _ = self._finish_articulated(ctx, tpl, R_w, t_w, s.fine_samples,
                                                s.fine_iterations, iters)
        else:
            final = self._finish(ctx, tpl, R_w, t_w, s.fine_samples, s.fine_iterations, iters)
        if final.likelihood < win.likelihood:
            final = win
        if isinstance(tpl, PosedTemplate):
            final = self._prefer_nominal(ctx, self._model(final.template, final.joints,
                                                        final.scale), final, iters)
        total = time.perf_counter() - t0
        out = [replace(final, time_s=total)] + [replace(r, time_s=total) for r in ranked[1:]]
        return _rank(out)

    def _initial_hypotheses(self, ctx: ClickContext, tpls, rng):
        """Initial (template index, R, t) hypotheses.

        With a plane under the click: mounted (template +z along the plane normal, a yaw sweep;
        modes auto and mounted), resting (each stable facet of the template down on the plane,
        a yaw sweep; modes auto and free) and uniformly random orientations resting on the plane.
        Without a plane: uniformly random orientations around the cluster. The template's
        centroid starts over the cluster's centroid; random ones get an offset of up to 15% of
        the template diameter (the paper's restarts use up to the diameter)."""
        s = self.settings
        plane = ctx.plane
        hyp_tpl, Rs, ts, family = [], [], [], []
        centroid = ctx.cluster.mean(axis=0)

        def add(i, tpl, R0, offset=None, kind=MOUNTED):
            t0 = centroid - R0 @ tpl.centroid
            if offset is not None:
                t0 = t0 + offset
            if plane is not None:   # rest on the plane: the lowest point touches it
                low = tpl.samples(256, seed=1)[0]
                t0 = t0 - plane.normal * plane.distance(low @ R0.T + t0).min()
            hyp_tpl.append(i)
            Rs.append(R0)
            ts.append(t0)
            family.append(kind)

        for i, tpl in enumerate(tpls):
            # the object is under the click: centre on the cluster points within reach of it
            # (the cluster may have merged with a neighbour)
            near = np.linalg.norm(ctx.cluster - ctx.click, axis=1) <= 0.5 * tpl.diameter
            centroid = ctx.cluster[near].mean(axis=0) if near.any() else ctx.click
            if plane is not None:
                up = align_z_to(plane.normal)
                if s.mode in ("auto", "mounted"):
                    for yaw in (np.arange(s.yaw_restarts) + rng.uniform()) * 2 * math.pi / s.yaw_restarts:
                        add(i, tpl, up @ axis_angle_matrix([0, 0, 1], yaw))
                if s.mode in ("auto", "free"):
                    cluster_axis = _principal_angle(ctx.cluster @ up)
                    for R_rest, _ in tpl.resting_rotations(s.resting_poses):
                        if s.mode == "auto" and (R_rest @ [0, 0, 1.0])[2] > 0.95:
                            continue   # the mounted orientation, already swept
                        yaws = list((np.arange(s.resting_yaws) + rng.uniform()) * 2 * math.pi
                                    / s.resting_yaws)
                        # and the two yaws that line the resting template's long axis up with
                        # the cluster's (elongated parts lying on a table)
                        tpl_axis = _principal_angle(tpl.samples(256, seed=1)[0] @ R_rest.T)
                        if cluster_axis is not None and tpl_axis is not None:
                            yaws += [cluster_axis - tpl_axis, cluster_axis - tpl_axis + math.pi]
                        for yaw in yaws:
                            add(i, tpl, up @ axis_angle_matrix([0, 0, 1], yaw) @ R_rest,
                                kind=RESTING)
            n_rand = 0 if s.mode == "mounted" and plane is not None else (
                s.random_restarts if plane is not None else s.free_restarts)
            if n_rand:
                offsets = rng.normal(size=(n_rand, 3))
                offsets *= (0.15 * tpl.diameter * rng.uniform(size=(n_rand, 1)) ** (1 / 3)
                            / np.linalg.norm(offsets, axis=1, keepdims=True))
                for R0, off in zip(random_rotations(n_rand, rng), offsets):
                    add(i, tpl, R0, off, kind=RANDOM)
        return np.array(hyp_tpl), np.stack(Rs), np.stack(ts), np.array(family)

    def _yaw_sweep(self, ctx: ClickContext, tpl, R, t):
        """Rotate a pose about its template's z (mounting / symmetry) axis through the centroid
        in ``yaw_sweep`` steps over one symmetry period, refine each, keep the best. Returns
        (R, t)."""
        s = self.settings
        if s.yaw_sweep <= 1:
            return R, t
        sym = tpl.symmetry
        period = 2 * math.pi / (sym.order if sym is not None and not sym.continuous else 1)
        axis_model = np.asarray(sym.axis) if sym is not None else np.array([0.0, 0.0, 1.0])
        axis = R @ axis_model
        centre = R @ tpl.centroid + t
        Rs, ts = [], []
        for k in range(s.yaw_sweep):
            dR = axis_angle_matrix(axis, k * period / s.yaw_sweep)
            Rs.append(dR @ R)
            ts.append(dR @ (t - centre) + centre)
        tlist = [tpl] * len(Rs)
        reject = np.full(len(Rs), 0.25 * tpl.diameter)
        R2, t2 = self._icp(tlist, np.stack(Rs), np.stack(ts), ctx, s.medium_samples, 6, reject,
                           target="cluster", occlusion=True)
        scores = [self._result(ctx, tpl, R2[k], t2[k], 0, 0.0).residual
                  for k in range(len(Rs))]
        best = int(np.argmin(scores))
        return R2[best], t2[best]

    def _articulate(self, ctx: ClickContext, tpl: AffordanceTemplate, R, t, q0: float = 0.0,
                    scale0: float = 1.0, sweep: bool = True):
        """Estimate the joint value and the scale with the pose.

        The sweep tries joint values across the limits, each three ways: the fixed part stays and
        the moving part moves, or the fixed part moves back by half or all of the change (a rigid
        fit has often turned or shifted the whole object to match its moving part); then scales
        across the range. Every hypothesis gets a short batched ICP and is judged by
        the two-way residual plus the moving part's own fit. Rounds of local joint/scale steps
        (each with a short ICP) follow, halving the step. Returns (PosedTemplate, R, t)."""
        s = self.settings
        joint = tpl.joint
        lo_hi = tpl.scale_range
        n = s.medium_samples
        model = self._posed(tpl, q0, scale0)
        contact = self._in_contact(ctx, model, R, t)

        def best_of(models, Rs, ts, icp_iterations):
            Rs, ts = np.stack(Rs), np.stack(ts)
            if icp_iterations:
                reject = np.array([0.15 * m.diameter for m in models])
                Rs, ts = self._icp(models, Rs, ts, ctx, n, icp_iterations, reject,
                                   target="cluster", occlusion=True)
            scores = self._scores(ctx, models, Rs, ts, n)
            if contact:    # a gap to (or a dip into) the plane beyond its noise costs
                gap = np.abs(self._plane_gap(ctx, models, Rs, ts, n))
                scores = scores + np.clip(gap - CONTACT_SLACK, 0.0, s.score_cap)
            if joint is not None:
                parts = [m.with_values(moving_only=True) for m in models]
                scores = scores + self._forward_score(ctx, parts, Rs, ts, n // 2)[0]
            k = int(np.argmin(scores))
            return models[k], Rs[k], ts[k]

        if sweep and joint is not None:
            steps = s.joint_sweep if joint.type == "revolute" else max(3, s.joint_sweep // 2)
            T = make_T(R, t)
            models, Rs, ts = [], [], []
            for g in np.linspace(joint.lower, joint.upper, steps):
                moves = (0.0, 0.5, 1.0) if g != q0 else (0.0,)
                for f in moves:     # the fixed part turns back by none, half or all of it
                    T_h = T @ tpl.joint_transform(f * (q0 - g)) if f else T
                    models.append(model.with_values(q=g))
                    Rs.append(T_h[:3, :3])
                    ts.append(T_h[:3, 3])
            model, R, t = best_of(models, Rs, ts, s.articulation_icp)
        if sweep and lo_hi is not None:
            # each scale about the template's origin (the mounting base stays), about its
            # centroid (the fit matched the middle of a bigger or smaller object), and with its
            # centroid over the data near the click (the fit matched one end of a bigger one),
            # along the plane when there is one
            centre = R @ model.centroid + t
            near = np.linalg.norm(ctx.cluster - ctx.click, axis=1) <= 0.5 * tpl.diameter * lo_hi[1]
            data = ctx.cluster[near].mean(axis=0) if near.any() else centre
            if ctx.plane is not None:
                data = data - ctx.plane.normal * (ctx.plane.normal @ (data - centre))
            models, Rs, ts = [], [], []
            for g in np.linspace(lo_hi[0], lo_hi[1], s.scale_sweep):
                m = model.with_values(scale=g)
                models += [m, m, m]
                Rs += [R, R, R]
                ts += [t, centre - R @ m.centroid, data - R @ m.centroid]
            model, R, t = best_of(models, Rs, ts, s.articulation_icp)
        q_step = (joint.upper - joint.lower) / (2 * s.joint_sweep) if joint is not None else 0.0
        s_step = (lo_hi[1] - lo_hi[0]) / (2 * s.scale_sweep) if lo_hi is not None else 0.0
        if not sweep:
            q_step, s_step = q_step / 2, s_step / 2
        for _ in range(s.articulation_rounds):
            models = [model]
            if joint is not None:
                models += [model.with_values(q=float(np.clip(model.q + d * q_step, joint.lower,
                                                             joint.upper))) for d in (-1.0, 1.0)]
            if lo_hi is not None:
                models += [model.with_values(scale=float(np.clip(model.scale + d * s_step,
                                                                 *lo_hi))) for d in (-1.0, 1.0)]
            if len(models) == 1:
                break
            model, R, t = best_of(models, [R] * len(models), [t] * len(models), 4)
            q_step, s_step = q_step / 2, s_step / 2
        return model, R, t

    def _prefer_nominal(self, ctx: ClickContext, model: PosedTemplate, res: FitResult,
                        iterations_before: int) -> FitResult:
        """Occam's razor for the extra unknowns: refit at the nearest named state's joint value
        and/or at the nominal scale 1 (within the range) -- the fixed part held or moved so the
        moving part stays, the template scaled about its origin or its centroid -- and keep
        that when its residual is within ``nominal_preference`` (joint) plus
        ``nominal_scale_preference`` (scale) of the free fit's. Valves mostly
        sit open or closed, and most objects come in their nominal size."""
        tpl = model.template
        s = self.settings
        qs, scales = [model.q], [model.scale]
        if tpl.joint is not None and tpl.states and res.state is not None:
            q_s = float(tpl.states[res.state].get(tpl.joint.name, model.q))
            if abs(q_s - model.q) > 1e-9:
                qs.append(q_s)
        lo_hi = tpl.scale_range
        if lo_hi is not None and lo_hi[0] <= 1.0 <= lo_hi[1] and abs(model.scale - 1.0) > 1e-9:
            scales.append(1.0)
        T = res.T_scene_model
        centre = T[:3, :3] @ model.centroid + T[:3, 3]
        best = None
        for q in qs:
            for sc in scales:
                if q == model.q and sc == model.scale:
                    continue
                allowed = (1.0 + (s.nominal_preference if q != model.q else 0.0)
                           + (s.nominal_scale_preference if sc != model.scale else 0.0)) \
                    * res.residual
                m = model.with_values(q=q, scale=sc)
                starts = [T]
                if q != model.q:
                    starts.append(T @ tpl.joint_transform(model.q - q))
                if sc != model.scale:
                    starts += [make_T(T0[:3, :3], centre - T0[:3, :3] @ m.centroid)
                               for T0 in list(starts)]
                for T0 in starts:
                    # as it is, and refined (the fine stage's objective is not the residual)
                    refined, _ = self._finish_articulated(ctx, m, T0[:3, :3], T0[:3, 3],
                                                          s.refit_samples, s.refit_iterations,
                                                          iterations_before, hold_joint=True,
                                                          hold_scale=True)
                    for cand in (self._result(ctx, m, T0[:3, :3], T0[:3, 3],
                                              iterations_before, 0.0), refined):
                        if cand.residual <= allowed and (best is None or
                                                         cand.residual < best.residual):
                            best = cand
        return best if best is not None else res

    def _plane_gap(self, ctx: ClickContext, models, Rs, ts, n: int) -> np.ndarray:
        """Signed distance (m) of each hypothesis' lowest sample from the plane under the click
        (positive: floating above it), (B,)."""
        P, _ = self._stack_samples(models, n)
        X = np.einsum("bij,bsj->bsi", np.asarray(Rs), P) + np.asarray(ts)[:, None, :]
        return ctx.plane.distance(X).min(axis=1)

    def _in_contact(self, ctx: ClickContext, model, R, t) -> bool:
        """Whether a pose rests on the plane under the click (its lowest sample within
        ``contact_distance`` of it)."""
        if ctx.plane is None:
            return False
        gap = self._plane_gap(ctx, [model], R[None], t[None], 256)[0]
        return abs(gap) <= self.settings.contact_distance

    def _scores(self, ctx: ClickContext, models, Rs, ts, n: int) -> np.ndarray:
        """The two-way capped residual (plus the click penalty) of a batch of hypotheses (B,), the
        cluster -> template half on an even subsample of ``n`` cluster points."""
        fwd, _ = self._forward_score(ctx, models, Rs, ts, n)
        bwd = self._coarse_backward(ctx, models, np.asarray(Rs), np.asarray(ts), n)
        return 0.5 * (fwd + bwd) + self._click_penalty(ctx, models, Rs, ts)

    def _finish_articulated(self, ctx: ClickContext, model: PosedTemplate, R, t, samples: int,
                            iterations: int, iterations_before: int, hold_joint: bool = False,
                            hold_scale: bool = False):
        """The fine stage with the joint value and the scale as unknowns besides the pose: the
        two-way weighted point-to-plane step of :meth:`_icp` extended by a column per extra
        unknown (d x / d q: the moving part's motion about or along the joint axis; d x / d s:
        the unscaled posed point), solved in closed form each iteration (Gauss-Newton);
        ``hold_joint`` / ``hold_scale`` keep those as given. Returns (FitResult, PosedTemplate)."""
        s = self.settings
        tpl = model.template
        joint = None if hold_joint else tpl.joint
        lo_hi = None if hold_scale else tpl.scale_range
        if joint is None and lo_hi is None:     # nothing but the pose: the rigid fine stage
            return self._finish(ctx, model, R, t, samples, iterations, iterations_before), model
        d0 = s.weight_scale
        P0, N0, moving0 = tpl.part_samples(samples, seed=1)
        q, sc = model.q, model.scale
        R, t = np.array(R, dtype=float), np.array(t, dtype=float)
        reject = 0.1 * model.diameter
        floor = min(reject, s.reject_floor)
        pts, normals = self._reverse_subset(ctx)
        axis = np.asarray(joint.axis) if joint is not None else None
        origin = np.asarray(joint.origin) if joint is not None else None
        contact = self._in_contact(ctx, model, R, t)
        it = 0
        for it in range(iterations):
            radius = reject * (floor / reject) ** (it / max(iterations - 1, 1))
            U, Nu = tpl.pose_parts(P0, N0, moving0, q)       # unscaled, joint at q
            X = (sc * U) @ R.T + t
            Q, Nq, w = self._pairs(ctx, ctx.fine_tree, X[None], (Nu @ R.T)[None],
                                   np.array([radius]), True, True)
            Q, Nq, w, mov = Q[0], Nq[0], w[0], moving0
            if s.two_way:   # scene -> template pairs: each scene point with its nearest sample
                posed = model.with_values(q=q, scale=sc)
                centre = R @ posed.centroid + t
                near = np.einsum("ij,ij->i", pts - centre, pts - centre) <= \
                    (0.5 * posed.diameter) ** 2
                d_r, x_r, mov_r = posed.nearest((pts[near] - t) @ R, parts=True)
                finite = np.isfinite(d_r)
                X = np.vstack([X, x_r[finite] @ R.T + t])
                Q = np.vstack([Q, pts[near][finite]])
                Nq = np.vstack([Nq, normals[near][finite]])
                w = np.concatenate([w, correspondence_weights(d_r[finite], radius, d0)])
                U = np.vstack([U, x_r[finite] / sc])
                mov = np.concatenate([mov, mov_r[finite]])
            if contact:     # the lowest samples rest on the plane (unseen: the object hides them)
                X, Q, Nq, w, U, mov = self._contact_rows(ctx, X, Q, Nq, w, U, mov, len(P0),
                                                         radius)
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
            extra = ([(q, joint.lower, joint.upper, (joint.upper - joint.lower) / 8)]
                     if joint is not None else []) + \
                ([(sc, lo_hi[0], lo_hi[1], 0.05)] if lo_hi is not None else [])
            free = np.ones(J.shape[1], bool)
            while True:   # an unknown at its limit that the step pushes beyond stays there
                Jf = J[:, free]
                A = (Jf * w[:, None]).T @ Jf + 1e-9 * np.eye(Jf.shape[1])
                xi = np.zeros(J.shape[1])
                xi[free] = np.linalg.solve(A, (Jf * w[:, None]).T @ r)
                stuck = [6 + i for i, (val, lo, hi, _) in enumerate(extra) if free[6 + i] and
                         ((val <= lo and xi[6 + i] < 0) or (val >= hi and xi[6 + i] > 0))]
                if not stuck:
                    break
                free[stuck] = False
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
            if angle < 2e-4 and np.linalg.norm(v) < 5e-5 and dq_ds < 1e-4:
                break
        model = model.with_values(q=q, scale=sc)
        return self._result(ctx, model, R, t, iterations_before + it + 1, 0.0), model

    def _contact_rows(self, ctx: ClickContext, X, Q, Nq, w, U, mov, n_forward: int, radius):
        """Append point-to-plane rows pairing the lowest of the first ``n_forward`` posed samples
        (within ``CONTACT_BAND`` of the lowest) with the plane under the click."""
        pd = ctx.plane.distance(X[:n_forward])
        low = np.flatnonzero(pd <= pd.min() + CONTACT_BAND)
        x_low = X[low]
        return (np.vstack([X, x_low]), np.vstack([Q, x_low - pd[low][:, None] * ctx.plane.normal]),
                np.vstack([Nq, np.broadcast_to(ctx.plane.normal, x_low.shape)]),
                np.concatenate([w, correspondence_weights(np.abs(pd[low]), radius,
                                                          self.settings.weight_scale)]),
                np.vstack([U, U[low]]), np.concatenate([mov, mov[low]]))

    def _finish(self, ctx, tpl, R, t, samples, iterations, iterations_before) -> FitResult:
        reject = np.array([0.1 * tpl.diameter])
        R2, t2 = self._icp([tpl], R[None], t[None], ctx, samples, iterations, reject,
                           target="fine", occlusion=True)
        return self._result(ctx, tpl, R2[0], t2[0], iterations_before + iterations, 0.0)

    def _guard_refit(self, res, T_init, R_fallback, t_fallback, ctx, tpl) -> FitResult:
        s = self.settings
        T = res.T_scene_model
        move = np.linalg.norm(T[:3, 3] - T_init[:3, 3])
        turn = rotation_angle(T_init[:3, :3].T @ T[:3, :3])
        if move <= s.refit_max_move and turn <= s.refit_max_turn:
            return res
        return self._result(ctx, tpl, R_fallback, t_fallback, res.iterations, 0.0)

    # ------------------------------------------------------------------ building blocks
    def _stack_samples(self, tlist, n: int):
        P = np.stack([tp.samples(n, seed=1)[0] for tp in tlist])
        N = np.stack([tp.samples(n, seed=1)[1] for tp in tlist])
        return P, N

    def _visible(self, ctx: ClickContext, X, Nw, occlusion: bool):
        """Samples facing the sensor and (with ``occlusion``) seen: their direction has a return
        that is not in front of them; also the free-space violations (the sensor saw through
        where the sample would be)."""
        ray = ctx.sensor_origin - X
        cos_in = np.einsum("bsi,bsi->bs", Nw, ray) / np.maximum(np.linalg.norm(ray, axis=-1), 1e-9)
        facing = cos_in > self._cos_grazing     # depth sensors return nothing at grazing angles
        if not occlusion:
            return facing, np.zeros_like(facing)
        obs, z = ctx.range_image.lookup(X)
        m = self.settings.free_space_margin
        known = np.isfinite(obs)
        hidden = known & (obs < z - m)
        violated = known & (obs > z + m)
        # a direction with no return at all (outside the image, a dropout) is no evidence either
        # way: such samples neither pull nor count
        return facing & known & ~hidden, facing & violated

    def _icp(self, tlist, R, t, ctx: ClickContext, n_samples: int, iterations: int,
             reject: np.ndarray, target: str, occlusion: bool):
        """Weighted ICP for a batch of hypotheses. R (B, 3, 3), t (B, 3) model -> scene.

        Point-to-point with the closed-form weighted SVD; on the full-resolution target
        (``target="fine"``) with ``fine_metric="plane"``, the same weights in a point-to-plane
        step (closed-form 6x6 solve), which does not creep along flat or cylindrical surfaces."""
        point_to_plane = target == "fine" and self.settings.fine_metric == "plane"
        two_way = target == "fine" and self.settings.two_way
        tree = ctx.cluster_tree if target == "cluster" else ctx.fine_tree
        P, N = self._stack_samples(tlist, n_samples)
        R = np.array(R, dtype=float)
        t = np.array(t, dtype=float)
        reject = np.asarray(reject, dtype=float)
        floor = np.minimum(reject, self.settings.reject_floor)
        for it in range(iterations):
            # the rejection radius shrinks geometrically from ``reject`` to the floor
            frac = it / max(iterations - 1, 1)
            radius = reject * (floor / reject) ** frac
            X = np.einsum("bij,bsj->bsi", R, P) + t[:, None, :]
            Nw = np.einsum("bij,bsj->bsi", R, N)
            Q, Nq, w = self._pairs(ctx, tree, X, Nw, radius, occlusion, point_to_plane)
            if two_way:
                X, Q, Nq, w = self._add_reverse_pairs(ctx, tlist, R, t, X, Q, Nq, w, radius)
            if point_to_plane:
                dR, dt = _point_to_plane_weighted(X, Q, Nq, w)
            else:
                dR, dt = _kabsch_weighted(X, Q, w)
            R = dR @ R
            t = np.einsum("bij,bj->bi", dR, t) + dt
            if np.all(rotation_angle(dR) < 2e-4) and np.all(np.linalg.norm(dt, axis=1) < 5e-5):
                break
        return R, t

    def _pairs(self, ctx: ClickContext, tree: cKDTree, X, Nw, radius, occlusion: bool,
               normals: bool):
        """Correspondences of posed samples X (B, S, 3) with normals Nw: the nearest target point
        (Q), its normal when ``normals`` (Nq, else zeros) and the weight w (B, S) -- zero for
        unseen samples and beyond ``radius`` (B,)."""
        d0 = self.settings.weight_scale
        pts = tree.data
        B, S = X.shape[:2]
        vis, _ = self._visible(ctx, X, Nw, occlusion)
        dist = np.full((B, S), np.inf)
        Q = np.empty_like(X)
        band = np.zeros_like(vis)
        if ctx.plane is not None:
            # The plane band was removed from the targets; a sample in it corresponds to its
            # projection on the plane, which the sensor did observe (keeps tilt and height
            # constrained when the rest of the object is degenerate, e.g. a bar seen from above).
            pd = ctx.plane.distance(X)
            band = vis & (pd <= 1.5 * ctx.plane_threshold)
            dist[band] = np.abs(pd[band])
            Q[band] = X[band] - pd[band][:, None] * ctx.plane.normal
            vis = vis & ~band
        d_v, i_v = tree.query(X[vis], k=1, workers=_workers(int(vis.sum())))
        dist[vis] = d_v
        Q[vis] = pts[np.minimum(i_v, len(pts) - 1)]
        w = correspondence_weights(dist, radius[:, None], d0)
        Q = np.where(np.isfinite(dist)[..., None], Q, X)
        Nq = np.zeros_like(X)
        if normals:
            Nq[vis] = ctx.fine_normals[np.minimum(i_v, len(pts) - 1)]
            if ctx.plane is not None:
                Nq[band] = ctx.plane.normal
        return Q, Nq, w

    def _reverse_subset(self, ctx: ClickContext):
        """The full-resolution scene points (and normals) the fine stage pairs with the template:
        at most ``reverse_points``, an even, fixed subset (the same one every iteration)."""
        pts, normals = ctx.fine, ctx.fine_normals
        limit = self.settings.reverse_points
        if len(pts) > limit:
            pick = (np.arange(limit) * (len(pts) / limit)).astype(np.int64)
            pts, normals = pts[pick], normals[pick]
        return pts, normals

    def _add_reverse_pairs(self, ctx, tlist, R, t, X, Q, Nq, w, radius):
        """Append scene -> template pairs: each full-resolution scene point inside a hypothesis'
        bounding sphere paired with its nearest template sample (weights of the same form).
        Returns the extended (X, Q, Nq, w) with the model side in X, the scene side in Q."""
        d0 = self.settings.weight_scale
        pts, normals = self._reverse_subset(ctx)
        rows = []
        for b, tpl in enumerate(tlist):
            centre = R[b] @ tpl.centroid + t[b]
            near = np.einsum("ij,ij->i", pts - centre, pts - centre) <= (0.5 * tpl.diameter) ** 2
            q = pts[near]
            d, x = self._nearest(tpl, (q - t[b]) @ R[b])
            x = x @ R[b].T + t[b]
            wb = correspondence_weights(d, radius[b], d0)
            rows.append((x, q, normals[near], wb))
        S2 = max(len(r[0]) for r in rows)
        if S2 == 0:
            return X, Q, Nq, w
        B = len(tlist)
        X2, Q2, N2, w2 = (np.zeros((B, S2, 3)), np.zeros((B, S2, 3)), np.zeros((B, S2, 3)),
                          np.zeros((B, S2)))
        for b, (x, q, n, wb) in enumerate(rows):
            X2[b, :len(x)], Q2[b, :len(x)], N2[b, :len(x)], w2[b, :len(x)] = x, q, n, wb
        return (np.concatenate([X, X2], 1), np.concatenate([Q, Q2], 1),
                np.concatenate([Nq, N2], 1), np.concatenate([w, w2], 1))

    def _forward_score(self, ctx: ClickContext, tlist, R, t, n_samples: int):
        """Template -> scene capped mean distance over visible samples (free-space violations
        count as the cap), and the fraction of visible samples within the cap. (B,), (B,)."""
        cap = self.settings.score_cap
        P, N = self._stack_samples(tlist, n_samples)
        X = np.einsum("bij,bsj->bsi", R, P) + t[:, None, :]
        Nw = np.einsum("bij,bsj->bsi", R, N)
        vis, violated = self._visible(ctx, X, Nw, occlusion=True)
        dist = np.full(vis.shape, cap)
        d_v, _ = ctx.crop_tree.query(X[vis], k=1, distance_upper_bound=cap,
                                     workers=_workers(int(vis.sum())))
        dist[vis] = np.minimum(d_v, cap)
        dist[violated] = cap
        n_vis = vis.sum(axis=1)
        fwd = np.where(n_vis >= max(3, 0.03 * P.shape[1]),
                       (dist * vis).sum(axis=1) / np.maximum(n_vis, 1), cap)
        inl = ((dist < cap) & vis).sum(axis=1) / np.maximum(n_vis, 1)
        return fwd, inl

    def _dense_tree(self, tpl: AffordanceTemplate) -> cKDTree:
        tree = self._dense_trees.get(tpl.name)
        if tree is None:
            tree = cKDTree(tpl.samples(4096, seed=2)[0])
            self._dense_trees[tpl.name] = tree
        return tree

    def _part_trees(self, tpl: AffordanceTemplate) -> PartTrees:
        trees = self._part_tree_cache.get(tpl.name)
        if trees is None:
            trees = self._part_tree_cache[tpl.name] = PartTrees(tpl)
        return trees

    def _posed(self, tpl: AffordanceTemplate, q: float = 0.0, scale: float = 1.0) -> PosedTemplate:
        return PosedTemplate(tpl, self._part_trees(tpl), q, scale)

    def _nearest(self, tpl, local: np.ndarray, upper: float = np.inf):
        """Distances from ``local`` (N, 3, model frame) to the template's dense surface samples
        (inf beyond ``upper``) and those samples (N, 3)."""
        if isinstance(tpl, PosedTemplate):
            return tpl.nearest(local, upper)
        tree = self._dense_tree(tpl)
        d, i = tree.query(local, k=1, distance_upper_bound=upper)
        return d, tree.data[np.minimum(i, tree.n - 1)]

    def _backward_score(self, ctx: ClickContext, tpl, R, t) -> float:
        """Scene -> template capped mean distance over the cluster points inside the template's
        bounding sphere at this pose (points no sample explains count up to the cap)."""
        cap = self.settings.score_cap
        centre = R @ tpl.centroid + t
        radius = 0.5 * tpl.diameter + cap
        pts = ctx.cluster
        near = np.einsum("ij,ij->i", pts - centre, pts - centre) <= radius * radius
        if not near.any():
            return cap
        local = (pts[near] - t) @ R          # scene -> model frame
        d, _ = self._nearest(tpl, local, cap)
        return float(np.minimum(d, cap).mean())

    def _coarse_backward(self, ctx: ClickContext, tlist, R, t, n: int = 64) -> np.ndarray:
        """Scene -> template capped mean distance of a fixed subsample of the cluster (B,)."""
        cap = self.settings.score_cap
        pts = ctx.cluster[np.linspace(0, len(ctx.cluster) - 1, min(n, len(ctx.cluster)))
                          .astype(int)]
        local = np.einsum("bji,bnj->bni", R, pts[None] - t[:, None, :])   # (B, n, 3) model
        out = np.empty(len(tlist))
        keys = np.array([id(tp) for tp in tlist])
        for key in set(keys.tolist()):
            sel = np.flatnonzero(keys == key)
            tp = tlist[int(sel[0])]
            d, _ = self._nearest(tp, local[sel].reshape(-1, 3), cap)
            out[sel] = np.minimum(d, cap).reshape(len(sel), -1).mean(axis=1)
        return out

    def _click_penalty(self, ctx: ClickContext, tlist, R, t) -> np.ndarray:
        """The operator clicked on the object: a candidate whose surface passes farther than
        ``click_tolerance`` from the (snapped) click pays the excess, up to ``score_cap``. (B,)"""
        s = self.settings
        local = np.einsum("bji,bj->bi", R, ctx.click - t)      # click in each model frame
        d = np.empty(len(tlist))
        keys = np.array([id(tp) for tp in tlist])
        for key in set(keys.tolist()):
            sel = keys == key
            tp = tlist[int(np.flatnonzero(sel)[0])]
            d[sel] = self._nearest(tp, local[sel])[0]
        return np.clip(d - s.click_tolerance, 0.0, s.score_cap)

    def _result(self, ctx, tpl, R, t, iterations, elapsed) -> FitResult:
        fwd, inl = self._forward_score(ctx, [tpl], R[None], t[None], self.settings.score_samples)
        bwd = self._backward_score(ctx, tpl, R, t)
        click = float(self._click_penalty(ctx, [tpl], R[None], t[None])[0])
        residual = max(0.5 * (float(fwd[0]) + bwd) + click, 1e-6)
        posed = isinstance(tpl, PosedTemplate)
        joints = tpl.joints if posed else {}
        base = tpl.template if posed else tpl
        return FitResult(template=tpl.name, T_scene_model=make_T(R, t), residual=residual,
                         likelihood=1.0 / residual, inlier_fraction=float(inl[0]),
                         iterations=int(iterations), time_s=float(elapsed), joints=joints,
                         scale=tpl.scale if posed else 1.0,
                         state=base.nearest_state(joints) if joints else None)

    # ------------------------------------------------------------------ the paper, literally
    def _fit_paper(self, ctx: ClickContext, names: list[str]) -> tuple:
        """Per template, per restart: random orientation, offset within the diameter around the
        click, point-to-point ICP with w = 1/(1+d) (d in metres), rejection beyond the diameter,
        up to ``paper_iterations``; likelihood = 1 / weighted residual."""
        s = self.settings
        rng = np.random.default_rng(s.seed)
        tree, pts = ctx.crop_tree, ctx.crop
        results = []
        for name in names:
            t_start = time.perf_counter()
            tpl = self.library[name]
            P = tpl.samples(s.paper_samples, seed=1)[0]
            diam = tpl.diameter
            best = None
            total_iters = 0
            for R0 in random_rotations(s.paper_restarts, rng):
                off = rng.normal(size=3)
                off *= diam * rng.uniform() ** (1 / 3) / np.linalg.norm(off)
                R, t = R0, ctx.click + off
                prev = math.inf
                for it in range(s.paper_iterations):
                    X = P @ R.T + t
                    d, idx = tree.query(X, k=1)
                    w = correspondence_weights(d, diam, 1.0)
                    if w.sum() < 1e-9:
                        break
                    resid = float((w * d).sum() / w.sum())
                    dR, dt = _kabsch_weighted(X[None], pts[idx][None], w[None])
                    R, t = dR[0] @ R, dR[0] @ t + dt[0]
                    total_iters += 1
                    if abs(prev - resid) < 1e-7:
                        break
                    prev = resid
                X = P @ R.T + t
                d, _ = tree.query(X, k=1)
                w = correspondence_weights(d, diam, 1.0)
                resid = float((w * d).sum() / max(w.sum(), 1e-9)) if w.sum() > 0 else math.inf
                if best is None or resid < best[0]:
                    best = (resid, R, t, float(np.mean(d <= diam)))
            resid, R, t, inl = best
            resid = max(resid, 1e-9)
            results.append(FitResult(template=name, T_scene_model=make_T(R, t), residual=resid,
                                     likelihood=1.0 / resid, inlier_fraction=inl,
                                     iterations=total_iters,
                                     time_s=time.perf_counter() - t_start))
        return _rank(results)


def _principal_angle(points: np.ndarray) -> float | None:
    """Angle in the xy plane of the main axis of ``points`` (N, 3), or None when they are not
    elongated (the two in-plane spreads within 20% of each other)."""
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    vals, vecs = np.linalg.eigh(xy.T @ xy)
    if len(points) < 10 or vals[1] < 1.44 * max(vals[0], 1e-12):
        return None
    return float(math.atan2(vecs[1, 1], vecs[0, 1]))


def _sym_angle(tpl: AffordanceTemplate, R_rel: np.ndarray) -> float:
    if tpl.symmetry is None:
        return float(rotation_angle(R_rel))
    return tpl.symmetry.residual_angle(R_rel)


def _workers(n_queries: int) -> int:
    """KD-tree query threads: all cores for big batches, one for small ones (thread start-up
    costs more than it saves below a few thousand points)."""
    return -1 if n_queries >= 8000 else 1
