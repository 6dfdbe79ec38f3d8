# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""One affordance template: its geometry (a mesh, or a scan's points), symmetry, joints and named
states, with the seeded, cached surface samples the fitting draws on.

Template frame: the frame the file is written in, metres. By default it is also the mounting
frame (origin at the centre of the mounting base, +z out of the mounting surface); a file may
declare another (``mount``) or none. A box primitive's frame: origin at the centre of its base
face, +z out of the surface it stands on, x along its longer horizontal edge (dimensions x >= y,
full edge lengths). A cylinder's: origin at the centre of one end face, +z along its axis.

Templates are made by :func:`~affordance_registration.core.template_files.load_template` from
their YAML files; :class:`~affordance_registration.core.templates.TemplateLibrary` holds them.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import trimesh

from .errors import TemplateError
from .meshes import PRIMITIVES, mesh_distance, primitive_mesh, resting_facets
from .transforms import align_x_to, axis_angle_matrix, make_T, rotation_angle

__all__ = ["Symmetry", "Joint", "AffordanceTemplate", "AXES_SAMPLES", "AXES_SEED"]

#: the surface samples (and their seed) whose principal axes are a template's own axes
#: (:attr:`AffordanceTemplate.own_axes`)
AXES_SAMPLES, AXES_SEED = 2048, 1
#: ``mount`` left out: the file's frame for a mesh, none for a point cloud
_DEFAULT_MOUNT = object()


@dataclass(frozen=True)
class Symmetry:
    """Rotational symmetry of a template about an axis through ``point`` (template frame, m;
    the origin unless the file says otherwise).

    ``order`` n >= 1 means the shape maps onto itself under rotations by 2*pi*k/n; ``continuous``
    means under every rotation about ``axis``.
    """

    axis: tuple = (0.0, 0.0, 1.0)
    order: int = 1
    continuous: bool = False
    point: tuple = (0.0, 0.0, 0.0)

    @property
    def rotations(self) -> np.ndarray:
        """The symmetry rotations (k, 3, 3), identity first. A continuous symmetry is sampled at
        1 degree steps (use :meth:`residual_angle` for exact errors)."""
        n = 360 if self.continuous else self.order
        return np.stack([axis_angle_matrix(self.axis, 2.0 * math.pi * k / n) for k in range(n)])

    @property
    def transforms(self) -> np.ndarray:
        """The symmetry motions (k, 4, 4) of the template frame, identity first: the
        :attr:`rotations` about the axis through :attr:`point` (``T @ S`` is a pose the shape
        cannot be told from ``T``)."""
        p = np.asarray(self.point, dtype=float)
        return np.stack([make_T(R, p - R @ p) for R in self.rotations])

    def residual_angle(self, R_rel: np.ndarray) -> float:
        """Smallest rotation angle (rad) between ``R_rel`` and any symmetry rotation."""
        if self.continuous:
            a = np.asarray(self.axis, dtype=float)
            a = a / np.linalg.norm(a)
            return float(np.arccos(np.clip(a @ (R_rel @ a), -1.0, 1.0)))
        S = self.rotations
        return float(np.min(rotation_angle(np.swapaxes(S, 1, 2) @ R_rel)))


@dataclass(frozen=True)
class Joint:
    """A joint of an articulated template. ``axis`` is a unit vector and ``origin`` a point, both
    in the template frame; values are radians (revolute) or metres (prismatic)."""

    name: str
    type: str
    axis: tuple
    origin: tuple
    lower: float
    upper: float
    torque_limit: float | None
    moving_mesh: trimesh.Trimesh = field(repr=False, compare=False)


class AffordanceTemplate:
    """One template: geometry (mesh or scanned points), symmetry, joints and named states.

    Surface samples are area-weighted, seeded and cached: ``samples(n, seed)`` always returns the
    same arrays for the same arguments.
    """

    def __init__(
        self,
        name: str,
        path: str,
        mesh: trimesh.Trimesh | None,
        points: np.ndarray | None = None,
        point_normals: np.ndarray | None = None,
        mesh_scale: float = 1.0,
        symmetry: Symmetry | None = None,
        joints: tuple = (),
        states: Mapping | None = None,
        description: str = "",
        base_mesh: trimesh.Trimesh | None = None,
        scale_range: tuple | None = None,
        primitive: str | None = None,
        dimension_ranges: Mapping | None = None,
        dimensions: Mapping | None = None,
        waypoints: tuple = (),
        mount=_DEFAULT_MOUNT,
    ):
        if mesh is None and points is None:
            raise TemplateError(f"{path}: template '{name}' has neither a mesh nor points")
        self.name = name
        self.path = path
        self.mesh = mesh
        self.points = points
        self.point_normals = point_normals
        self.mesh_scale = float(mesh_scale)
        self.symmetry = symmetry
        self.joints = tuple(joints)
        self.states = dict(states or {})
        self.description = description
        self.base_mesh = base_mesh
        self.scale_range = scale_range
        #: a parametric primitive ("box", "cylinder") or None; its dimensions' [min, max]
        #: ranges (m) and the dimensions its mesh has (the middle of the ranges, or those of
        #: a fit: :meth:`sized`)
        self.primitive = primitive
        self.dimension_ranges = dict(dimension_ranges or {})
        self.dimensions = dict(dimensions or {})
        #: the mesh files the geometry was read from, as they are on disk ("mesh", and with a
        #: joint "base_mesh" and "moving_mesh"; absolute paths, file units times
        #: ``mesh_scale``): a viewer can load them itself. Empty where the geometry is not a
        #: file's (a point cloud, a primitive, a derived copy)
        self.mesh_files: dict[str, str] = {}
        #: end-effector waypoints (:class:`~affordance_registration.core.waypoints.Waypoint`)
        self.waypoints = tuple(waypoints)
        #: the mounting frame (4, 4) in the template frame -- origin at the centre of the
        #: mounting base, +z out of the surface it is mounted on -- or None for an object with
        #: no mounting side; left out, the template frame itself for a mesh (the documented
        #: convention) and None for a point cloud (a scan)
        if mount is _DEFAULT_MOUNT:
            mount = None if mesh is None else np.eye(4)
        self.mount = None if mount is None else np.array(mount, dtype=float)
        if self.mount is not None:
            self.mount.setflags(write=False)
        self._cache: dict = {}
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"AffordanceTemplate({self.name!r}, diameter={self.diameter:.3f} m)"

    @property
    def is_point_template(self) -> bool:
        return self.mesh is None

    def clip_dimensions(self, dimensions: Mapping) -> dict:
        """A primitive's ``dimensions`` (name -> m) within its ranges (a box's x >= y kept)."""
        out = {
            k: float(np.clip(float(dimensions[k]), *self.dimension_ranges[k]))
            for k in PRIMITIVES[self.primitive]
        }
        return out

    def sized(self, dimensions: Mapping) -> "AffordanceTemplate":
        """This primitive with the given dimensions (clipped to its ranges, rounded to 0.1
        mm): a template of the same name whose mesh has that size. Sized templates are cached
        (:meth:`_cached_mesh`), so a refit at the same size reuses its samples and surface."""
        dims = {k: round(v, 4) for k, v in self.clip_dimensions(dimensions).items()}
        key = ("sized",) + tuple(dims.values())

        def build():
            return AffordanceTemplate(
                self.name,
                self.path,
                primitive_mesh(self.primitive, dims),
                symmetry=self.symmetry,
                description=self.description,
                primitive=self.primitive,
                dimension_ranges=self.dimension_ranges,
                dimensions=dims,
                waypoints=self.waypoints,
                mount=self.mount,
            )

        return self._cached_mesh(key, build)

    @property
    def vertices(self) -> np.ndarray:
        """Mesh vertices, or the template points (N, 3) float64, metres."""
        return np.asarray(self.mesh.vertices if self.mesh is not None else self.points, float)

    @property
    def diameter(self) -> float:
        """Largest distance between two points of the template (m)."""
        with self._lock:
            if "diameter" not in self._cache:
                verts = self.vertices
                try:
                    hull = trimesh.convex.convex_hull(verts).vertices
                except Exception:  # degenerate (flat) point sets
                    hull = verts
                if len(hull) > 4000:
                    hull = hull[np.random.default_rng(0).choice(len(hull), 4000, replace=False)]
                d = np.sqrt(((hull[:, None, :] - hull[None, :, :]) ** 2).sum(-1)).max()
                self._cache["diameter"] = float(d)
            return self._cache["diameter"]

    @property
    def centroid(self) -> np.ndarray:
        """Area-weighted surface centroid (3,), template frame."""
        return self.samples(2048, seed=0)[0].mean(axis=0)

    @property
    def own_axes(self) -> np.ndarray:
        """The surface's own axes (3, 3 rotation, columns in the template frame): the principal
        axes of its samples, largest spread first, each pointing where the samples' third moment
        along it is positive (right-handed). They turn with the surface, whatever frame its
        file is written in."""
        with self._lock:
            hit = self._cache.get("own axes")
        if hit is not None:
            return hit
        rel = self.samples(AXES_SAMPLES, seed=AXES_SEED)[0]
        rel = rel - rel.mean(axis=0)
        axes = np.linalg.eigh(rel.T @ rel)[1][:, ::-1].copy()
        for k in range(2):
            if np.sum((rel @ axes[:, k]) ** 3) < 0:
                axes[:, k] *= -1
        axes[:, 2] = np.cross(axes[:, 0], axes[:, 1])
        axes.setflags(write=False)
        with self._lock:
            self._cache["own axes"] = axes
        return axes

    @property
    def axes(self) -> np.ndarray:
        """The axes (3, 3 rotation, columns in the template frame) the fitter lays out what it
        draws for this template in -- orientations, resting facets, a voxel grid: its mount's
        (+z out of the mounting surface), or its :attr:`own_axes` without a mount. Both move
        with the file's declarations, so a fit does not depend on the frame the file is in."""
        return self.own_axes if self.mount is None else self.mount[:3, :3]

    def samples(self, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``n`` area-weighted surface samples and their outward unit normals, both (n, 3)
        float64 in the template frame. Cached per (n, seed); do not modify the arrays."""
        key = ("samples", int(n), int(seed))
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                return hit
        if self.mesh is not None:
            pts, faces = trimesh.sample.sample_surface(self.mesh, int(n), seed=int(seed))
            nrm = np.asarray(self.mesh.face_normals[faces], dtype=float)
            pts = np.asarray(pts, dtype=float)
        else:
            rng = np.random.default_rng(seed)
            idx = rng.choice(len(self.points), size=int(n), replace=len(self.points) < n)
            pts = self.points[idx].astype(float)
            nrm = self.point_normals[idx].astype(float)
        pts.setflags(write=False)
        nrm.setflags(write=False)
        with self._lock:
            self._cache[key] = (pts, nrm)
        return pts, nrm

    def resting_rotations(self, max_poses: int = 6) -> list[tuple[np.ndarray, float]]:
        """Orientations in which the template can rest on a horizontal surface.

        A convex-hull facet is a resting facet when the centre of mass projects inside it. Returns
        up to ``max_poses`` (R_rest, weight) pairs, largest facet first: R_rest (3x3) turns the
        template so that facet faces down (-z); weight is the facet's share of the resting area.
        The facets are found in the template's :attr:`axes` (so each R_rest turns with the
        file's frame). Point templates have none."""
        key = ("resting", int(max_poses))
        with self._lock:
            if key in self._cache:
                return self._cache[key]
        A = self.axes
        if self.mesh is None:
            poses = []
        elif np.array_equal(A, np.eye(3)):
            poses = resting_facets(self.mesh)[:max_poses]
        else:
            turned = self.mesh.copy()
            turned.apply_transform(make_T(A.T))
            poses = [(R @ A.T, w) for R, w in resting_facets(turned)[:max_poses]]
        total = sum(w for _, w in poses) or 1.0
        poses = [(R, w / total) for R, w in poses]
        with self._lock:
            self._cache[key] = poses
        return poses

    def with_scale_range(self, scale_range: tuple | None) -> "AffordanceTemplate":
        """A copy of this template allowing uniform scale within ``scale_range`` (min, max)
        -- what a ``scale: [min, max]`` key in its YAML gives -- or rigid (None)."""
        if scale_range is not None:
            try:
                scale_range = parse_scale_range(scale_range)
            except ValueError as exc:
                raise TemplateError(f"{self.path}: scale range {exc}") from None
        copy = AffordanceTemplate(
            self.name,
            self.path,
            self.mesh,
            self.points,
            self.point_normals,
            self.mesh_scale,
            self.symmetry,
            self.joints,
            self.states,
            self.description,
            self.base_mesh,
            scale_range,
            waypoints=self.waypoints,
            mount=self.mount,
        )
        copy.mesh_files = dict(self.mesh_files)  # the same geometry, the same files
        return copy

    @property
    def joint(self) -> Joint | None:
        """The joint fitted with the pose (the first, with its moving part), or None."""
        return self.joints[0] if self.joints and self.base_mesh is not None else None

    def joint_value(self, joints: Mapping[str, float]) -> float:
        """This template's joint value in ``joints`` (name -> value; 0 when absent)."""
        return float(joints.get(self.joint.name, 0.0)) if self.joint is not None else 0.0

    @property
    def articulated(self) -> bool:
        """Has a joint (with its moving part) or allows scaling: fitted with extra unknowns."""
        return self.joint is not None or self.scale_range is not None

    def part_samples(self, n: int, seed: int = 0):
        """Area-weighted samples of the object's surface at joint value zero, each labelled with
        its part: (points (n, 3), normals (n, 3), moving (n,) bool) -- the points and normals
        of :meth:`samples`. Without a joint, all samples are fixed."""
        key = ("parts", int(n), int(seed))
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        if self.joint is None:
            P, N = self.samples(n, seed)
            out = (P, N, np.zeros(len(P), bool))
        elif self.mesh is not None:
            # the object's outer surface (the YAML mesh, the union at joint value zero), each
            # sample labelled with the part it lies on: no faces hidden inside the union
            P, N = self.samples(n, seed)
            moving = mesh_distance(self.joint.moving_mesh, P) < mesh_distance(self.base_mesh, P)
            out = (P, N, moving)
        else:
            moving = self.joints[0].moving_mesh
            n_mov = int(round(n * moving.area / (moving.area + self.base_mesh.area)))
            n_mov = min(max(n_mov, 1), n - 1)
            pb, fb = trimesh.sample.sample_surface(self.base_mesh, n - n_mov, seed=int(seed))
            pm, fm = trimesh.sample.sample_surface(moving, n_mov, seed=int(seed) + 1)
            P = np.vstack([pb, pm]).astype(float)
            N = np.vstack([self.base_mesh.face_normals[fb], moving.face_normals[fm]]).astype(float)
            out = (P, N, np.r_[np.zeros(len(pb), bool), np.ones(len(pm), bool)])
        for a in out:
            a.setflags(write=False)
        with self._lock:
            self._cache[key] = out
        return out

    def joint_transform(self, q: float) -> np.ndarray:
        """4x4 motion of the moving part at joint value ``q`` (rad or m) from its zero pose."""
        j = self.joints[0]
        axis, origin = np.asarray(j.axis), np.asarray(j.origin)
        if j.type == "prismatic":
            return make_T(t=axis * q)
        R = axis_angle_matrix(axis, q)
        return make_T(R, origin - R @ origin)

    def pose_parts(self, P, N, moving, q: float = 0.0, scale: float = 1.0):
        """Samples with the moving part at joint value ``q`` and the whole template scaled
        about its origin (the mounting base centre). ``N`` None: only the points are posed
        (None returned for the normals)."""
        P = np.array(P, dtype=float)
        N = None if N is None else np.array(N, dtype=float)
        if q and self.joints and moving.any():
            T = self.joint_transform(q)
            P[moving] = P[moving] @ T[:3, :3].T + T[:3, 3]
            if N is not None:
                N[moving] = N[moving] @ T[:3, :3].T
        return P * scale, N

    def _cached_mesh(self, key: tuple, build):
        """A mesh from the cache (``key[0]`` names its kind: at most 256 kept), else built."""
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        mesh = build()
        with self._lock:
            if len(self._cache) > 256:
                for k in [k for k in self._cache if k[0] == key[0]][:128]:
                    del self._cache[k]
            self._cache[key] = mesh
        return mesh

    def mesh_at(self, q: float = 0.0, scale: float = 1.0) -> trimesh.Trimesh:
        """The template's mesh with the moving part at ``q``, scaled by ``scale`` (cached)."""

        def build():
            if self.joint is not None and q:
                mesh = trimesh.util.concatenate([self.base_mesh, self.moving_mesh_at(q)])
            else:
                mesh = self.mesh.copy()
            if scale != 1.0:
                mesh.apply_scale(scale)
            return mesh

        return self._cached_mesh(("mesh", round(float(q), 5), round(float(scale), 5)), build)

    def moving_mesh_at(self, q: float = 0.0, scale: float = 1.0) -> trimesh.Trimesh | None:
        """The moving part alone at joint value ``q``, scaled (None without a joint; cached)."""
        if self.joint is None:
            return None

        def build():
            moving = self.joint.moving_mesh.copy()
            moving.apply_transform(self.joint_transform(q))
            if scale != 1.0:
                moving.apply_scale(scale)
            return moving

        return self._cached_mesh(("moving", round(float(q), 5), round(float(scale), 5)), build)

    def joint_frame(self, q: float = 0.0, scale: float = 1.0) -> np.ndarray:
        """4x4 pose in the template frame of the joint at value ``q``: origin on the joint
        origin (moved along the axis for a prismatic joint), x along the joint axis, turned
        about it by ``q`` for a revolute joint."""
        j = self.joints[0]
        axis, origin = np.asarray(j.axis), np.asarray(j.origin)
        R0 = align_x_to(axis)
        if j.type == "revolute":
            return make_T(axis_angle_matrix(axis, q) @ R0, scale * origin)
        return make_T(R0, scale * (origin + q * axis))

    def joint_value_from_frame(self, T_model_frame: np.ndarray, scale: float = 1.0) -> float:
        """Inverse of :meth:`joint_frame`: the joint value a (dragged) joint frame shows,
        clamped to the limits."""
        j = self.joints[0]
        rel = np.linalg.inv(self.joint_frame(0.0, scale)) @ np.asarray(T_model_frame, float)
        q = math.atan2(rel[2, 1], rel[1, 1]) if j.type == "revolute" else rel[0, 3] / scale
        return float(np.clip(q, j.lower, j.upper))

    def nearest_state(self, joint_values: Mapping[str, float]) -> str | None:
        """Name of the named state closest to ``joint_values`` (None without states)."""
        best, best_d = None, math.inf
        for state, values in self.states.items():
            d = sum((float(values.get(k, 0.0)) - float(v)) ** 2 for k, v in joint_values.items())
            if d < best_d:
                best, best_d = state, d
        return best


#: a template's scale range and its mesh_scale lie within [1 / MAX_SCALE, MAX_SCALE]: a mesh
#: in micrometres is the smallest unit a file is written in; 1e300 overflows
MAX_SCALE = 1e6


def parse_scale_range(value) -> tuple:
    """(min, max) from a ``scale`` value; ValueError saying what is wrong."""
    try:
        if isinstance(value, (str, bytes)):  # ("19" is not [1, 9])
            raise TypeError
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"expected [min, max], got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 1 / MAX_SCALE <= lo < hi <= MAX_SCALE):
        raise ValueError(
            f"expected {1 / MAX_SCALE:g} <= min < max <= {MAX_SCALE:g}, got {value!r}"
        )
    return lo, hi
