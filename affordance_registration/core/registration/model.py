# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The model a fit poses: one type for every template (:class:`Model`) -- a rigid one is a model
with its joint at zero and scale one -- and the one cache (:class:`ModelCache`, locked) that owns
the posed samples and the dense surfaces' KD-trees.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np

from ..compiled import kernels
from ..neighbours import build_tree, nearest_distances, nearest_in
from ..templates import AffordanceTemplate
from .settings import SAMPLE_SEED

__all__ = ["Model", "ModelCache", "Surface", "Batch", "surface_distances"]

DENSE_SAMPLES = 4096  #: dense surface samples answering "nearest template surface"
DENSE_SEED = 2
CENTROID_SAMPLES = 2048  #: samples whose mean is a posed template's centroid
CENTROID_SEED = 0  #: (those of ``AffordanceTemplate.centroid``)
MOVING_OVERSAMPLING = 4  #: a moving part alone is picked from this many times the samples

#: surfaces of sized primitives a cache keeps (each fit and correction of one makes a size)
MAX_SIZED = 64


class Surface:
    """Dense surface samples of a template (joint at zero, scale one, template frame), each
    labelled with its part, and KD-trees over them: the whole surface, and the fixed and the
    moving part apart (to answer for any joint value without a tree per hypothesis)."""

    def __init__(self, template: AffordanceTemplate):
        P, _, moving = template.part_samples(DENSE_SAMPLES, seed=DENSE_SEED)
        self.points, self.moving = P, moving
        self.whole = build_tree(P)
        self.base_points, self.moving_points = P[~moving], P[moving]
        jointed = template.joint is not None and len(self.moving_points) > 0
        self.base = build_tree(self.base_points) if jointed else None
        self.moving_part = build_tree(self.moving_points) if jointed else None
        #: the mesh as it is, ready for ray casting (a point-cloud template has none)
        self.raycaster = raycaster(template.mesh) if template.mesh is not None else None
        kernels()  # (loaded, or compiled, with the first surface: a warm-up's cost, not a click's)

    def distances(self, part: str, points: np.ndarray, upper: float) -> np.ndarray:
        """Distance (N,) from ``points`` (N, 3, the template's frame, unscaled) to the nearest
        dense sample of ``part`` ("whole", "base" or "moving"), inf beyond ``upper``
        (:func:`..neighbours.nearest_distances`: a compiled grid kept with the surface where
        one pays, the same numbers as the part's tree)."""
        tree = {"whole": self.whole, "base": self.base, "moving": self.moving_part}[part]
        return nearest_distances(tree, points, upper, owner=self)


def raycaster(mesh):
    """An Open3D ray-casting scene of a trimesh mesh (its own frame)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
    )
    return scene


class ModelCache:
    """Per registrar: each template's :class:`Surface` and recently used posed samples and
    centroids. Thread-safe (concurrent fits share it); values are computed outside the lock,
    so two threads may compute one twice, never see a half-built one."""

    def __init__(self, max_posed: int = 512):
        self._lock = threading.Lock()
        self._surfaces: OrderedDict[AffordanceTemplate, Surface] = OrderedDict()
        self._posed: OrderedDict = OrderedDict()
        self._max_posed = int(max_posed)

    def model(
        self,
        template: AffordanceTemplate,
        q: float = 0.0,
        scale: float = 1.0,
        articulated: bool = False,
    ) -> "Model":
        """``template`` posed at joint value ``q`` and ``scale``; ``articulated``: the joint
        value and scale are part of the fit (reported with its result)."""
        return Model(template, self, float(q), float(scale), articulated=articulated)

    def surface(self, template: AffordanceTemplate) -> Surface:
        """The template's :class:`Surface` (built once; templates are keys by identity). A
        primitive's sizes come and go with its fits: the last MAX_SIZED are kept."""
        with self._lock:
            hit = self._surfaces.get(template)
            if hit is not None and template.primitive is not None:
                self._surfaces.move_to_end(template)
        if hit is not None:
            return hit
        surface = Surface(template)
        with self._lock:
            surface = self._surfaces.setdefault(template, surface)
            if template.primitive is not None:
                sized = [t for t in self._surfaces if t.primitive is not None]
                for old in sized[: max(0, len(sized) - MAX_SIZED)]:
                    del self._surfaces[old]
            return surface

    def posed(self, key: tuple, compute):
        """The value cached under ``key``, or ``compute()`` (then cached, the oldest dropped
        beyond ``max_posed``)."""
        with self._lock:
            hit = self._posed.get(key)
            if hit is not None:
                self._posed.move_to_end(key)
                return hit
        value = compute()
        for array in value if isinstance(value, tuple) else (value,):
            array.setflags(write=False)  # shared between threads and callers
        with self._lock:
            self._posed[key] = value
            while len(self._posed) > self._max_posed:
                self._posed.popitem(last=False)
        return value


@dataclass(frozen=True)
class Model:
    """A template with its joint at ``q`` (rad or m) and scaled by ``scale`` about its origin:
    what every stage fits, scores and queries. ``moving_only`` keeps just the moving part's
    samples (to judge a joint value by the part it moves); ``articulated``: the joint value and
    scale are unknowns of the fit, reported with its result (a rigid fit reports none)."""

    template: AffordanceTemplate = field(repr=False)
    cache: ModelCache = field(repr=False, compare=False)
    q: float = 0.0
    scale: float = 1.0
    moving_only: bool = False
    articulated: bool = False

    def with_values(
        self, q: float | None = None, scale: float | None = None, moving_only: bool = False
    ) -> "Model":
        return replace(
            self,
            q=self.q if q is None else float(q),
            scale=self.scale if scale is None else float(scale),
            moving_only=moving_only,
        )

    @property
    def name(self) -> str:
        return self.template.name

    @property
    def symmetry(self):
        return self.template.symmetry

    @property
    def axes(self) -> np.ndarray:
        """The template's :attr:`~..affordance_template.AffordanceTemplate.axes` (a joint value
        or a scale does not turn them)."""
        return self.template.axes

    @property
    def _as_is(self) -> bool:
        """The template's own geometry (joint at zero, scale one, every part)."""
        return self.q == 0.0 and self.scale == 1.0 and not self.moving_only

    @property
    def joints(self) -> dict:
        """Joint name -> value of an articulated model ({} for a rigid one)."""
        j = self.template.joint
        return {j.name: self.q} if self.articulated and j is not None else {}

    @property
    def diameter(self) -> float:
        return self.template.diameter * self.scale

    @property
    def centroid(self) -> np.ndarray:
        """Area-weighted surface centroid (3,), model frame."""
        if self._as_is:
            return self.template.centroid

        def compute():
            P, _, moving = self.template.part_samples(CENTROID_SAMPLES, seed=CENTROID_SEED)
            return self.template.pose_parts(P, None, moving, self.q, self.scale)[0].mean(axis=0)

        return self.cache.posed(("centroid", self.template, self.q, self.scale), compute)

    def samples(self, n: int, seed: int = SAMPLE_SEED) -> tuple[np.ndarray, np.ndarray]:
        """``n`` surface samples and their normals, both (n, 3) in the model frame (do not
        modify them)."""
        if self._as_is:
            return self.template.samples(n, seed)
        key = ("samples", self.template, self.q, self.scale, self.moving_only, int(n), int(seed))
        return self.cache.posed(key, lambda: self._posed_samples(int(n), int(seed)))

    def _posed_samples(self, n: int, seed: int):
        tpl = self.template
        if not self.moving_only:
            P, N, moving = tpl.part_samples(n, seed)
            return tpl.pose_parts(P, N, moving, self.q, self.scale)
        P, N, moving = tpl.part_samples(MOVING_OVERSAMPLING * n, seed)
        P, N = tpl.pose_parts(P, N, moving, self.q, self.scale)
        idx = np.flatnonzero(moving)
        idx = idx[np.linspace(0, len(idx) - 1, n).astype(int)]
        return P[idx], N[idx]

    def nearest(self, local: np.ndarray, upper: float = np.inf, parts: bool = False):
        """Distance (m) from points ``local`` (N, 3, this model's frame) to the nearest dense
        surface sample, and that sample (N, 3); distances beyond ``upper`` are inf. With
        ``parts``, also whether that sample is on the moving part (N,) bool."""
        surface = self.cache.surface(self.template)
        u = np.asarray(local, dtype=float) / self.scale
        ub = upper / self.scale
        if self.q == 0.0 or surface.moving_part is None:
            d, i = nearest_in(surface, surface.whole, u, ub)
            pts, closer = surface.points[i], surface.moving[i]
        else:
            d, i = nearest_in(surface, surface.base, u, ub)
            pts = surface.base_points[i]
            um, T = self._to_moving_part(u)
            dm, im = nearest_in(surface, surface.moving_part, um, ub)
            closer = dm < d
            d = np.where(closer, dm, d)
            pm = surface.moving_points[im]
            pts = np.where(closer[:, None], pm @ T[:3, :3].T + T[:3, 3], pts)
        if parts:
            return d * self.scale, pts * self.scale, closer
        return d * self.scale, pts * self.scale

    def _to_moving_part(self, u: np.ndarray):
        """Points ``u`` (N, 3, unscaled model frame) in the moving part's zero pose, and the
        joint transform (4, 4) at this model's joint value."""
        T = self.template.joint_transform(self.q)
        return (u - T[:3, 3]) @ T[:3, :3], T

    def _distance_key(self) -> tuple:
        """Models with equal keys answer :func:`surface_distances` from one query per tree."""
        return (id(self.cache), id(self.template), self.scale, self.q == 0.0)

    def raycaster(self):
        """An Open3D ray-casting scene of this model's mesh (at its joint value and scale,
        model frame), or None for a point-cloud template. The template's own is cached."""
        if self.template.mesh is None:
            return None
        if self._as_is:
            return self.cache.surface(self.template).raycaster
        return raycaster(self.template.mesh_at(self.q, self.scale))

    def resting_rotations(self, max_poses: int = 6):
        """The template's resting orientations (those at joint zero; scale does not change
        them)."""
        return self.template.resting_rotations(max_poses)


def surface_distances(models, local: np.ndarray, upper: float = np.inf) -> np.ndarray:
    """Distances (B, K) from points ``local`` (B, K, 3, each in its model's frame) to each of
    ``models``' dense surface, as :meth:`Model.nearest` gives them one model at a time (the
    same numbers): the models of one template at one scale share one query per tree (the
    joint values of a sweep, the hypotheses of a stage)."""
    out = np.empty(local.shape[:2])
    same: dict = {}  # the hypotheses of each model, then the models of each key
    for b, m in enumerate(models):
        same.setdefault(id(m), []).append(b)
    groups: dict = {}
    for sel in same.values():
        groups.setdefault(models[sel[0]]._distance_key(), []).extend(sel)
    for sel in groups.values():
        first = models[sel[0]]
        surface, scale = first.cache.surface(first.template), first.scale
        u = np.asarray(local[sel], dtype=float) / scale
        ub, flat = upper / scale, u.reshape(-1, 3)
        if first.q == 0.0 or surface.moving_part is None:
            d = surface.distances("whole", flat, ub)
        else:
            d = surface.distances("base", flat, ub)
            # into the moving part's zero pose, model by model (hypotheses of one model
            # together, as the model's own query turns them)
            rows = np.arange(len(sel) * u.shape[1]).reshape(len(sel), -1)
            ids = np.array([id(models[b]) for b in sel])
            order, um = [], []
            for key in dict.fromkeys(ids.tolist()):
                mine = np.flatnonzero(ids == key)
                order.append(rows[mine].ravel())
                um.append(models[sel[int(mine[0])]]._to_moving_part(u[mine].reshape(-1, 3))[0])
            order = np.concatenate(order)
            dm = np.empty(len(flat))
            dm[order] = surface.distances("moving", np.concatenate(um), ub)
            d = np.where(dm < d, dm, d)
        out[sel] = (d * scale).reshape(len(sel), -1)
    return out


@dataclass(frozen=True)
class Batch:
    """B hypotheses: the ``models`` (B,) posed by R (B, 3, 3) and t (B, 3), model -> scene --
    what the stages advance and score together."""

    models: tuple
    R: np.ndarray
    t: np.ndarray

    @staticmethod
    def of(models, R, t) -> "Batch":
        """A batch from sequences of models and of poses (stacked)."""
        return Batch(tuple(models), np.asarray(R, dtype=float), np.asarray(t, dtype=float))

    @staticmethod
    def single(model: Model, R: np.ndarray, t: np.ndarray) -> "Batch":
        """One hypothesis, R (3, 3), t (3,)."""
        return Batch((model,), np.asarray(R, dtype=float)[None], np.asarray(t, dtype=float)[None])

    def __len__(self) -> int:
        return len(self.models)

    def take(self, idx) -> "Batch":
        """The hypotheses at ``idx`` (an index array), in that order."""
        idx = np.asarray(idx, dtype=int)
        return Batch(tuple(self.models[i] for i in idx), self.R[idx], self.t[idx])
