"""Affordance templates and the template library.

A template is a YAML file (``models/<name>.yaml``)::

    name: ball_valve                 # required, unique in a library
    mesh: meshes/ball_valve.stl      # required, relative to the YAML; STL/OBJ/PLY mesh, or a
                                     # PLY/PCD point cloud (a scan of the object: its normals
                                     # from the file, or estimated when it has none)
    mesh_scale: 1.0                  # factor from mesh units to metres
    scale: [0.8, 1.25]               # optional: the design comes in sizes; scale is estimated
    symmetry: {axis: [0, 0, 1], order: 4}      # or {axis: [...], continuous: true}
    base_mesh: meshes/ball_valve_base.stl      # the part that does not move (with joints)
    joints:
      - {name: lever, type: revolute, axis: [0, 0, 1], origin: [0, 0, 0.085],
         lower: 0.0, upper: 1.5708, torque_limit: 15.0, moving_mesh: meshes/ball_valve_lever.stl}
    states: {open: {lever: 0.0}, closed: {lever: 1.5708}}
    description: free text

Lengths in the file -- a joint's origin, a prismatic joint's limits and its named states -- are
in the mesh's units (``mesh_scale`` turns them into metres); angles are radians.

Template frame: origin at the centre of the mounting base, +z out of the mounting surface, metres.

A template may instead be a parametric *primitive* (an object outside the library: a box, a
pipe, a can), its dimensions fitted with its pose from the click::

    name: box
    primitive: box
    size: {x: [0.02, 0.6], y: [0.02, 0.6], z: [0.01, 0.6]}   # metres, [min, max] each
    ---
    name: cylinder
    primitive: cylinder
    radius: [0.01, 0.25]
    length: [0.02, 0.6]

A box's frame: origin at the centre of its base face, +z out of the surface it stands on, x
along its longer horizontal edge (dimensions x >= y, full edge lengths). A cylinder's: origin
at the centre of one end face, +z along its axis.
"""
from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass, field
from typing import Iterator, Mapping

import numpy as np
import trimesh
import yaml

from .errors import TemplateError
from .neighbours import pca_normals
from .pointfiles import MAX_FILE_BYTES, check_header, read_points
from .transforms import align_x_to, axis_angle_matrix, make_T, rotation_angle

__all__ = ["Symmetry", "Joint", "AffordanceTemplate", "TemplateLibrary", "default_models_dir",
           "PRIMITIVES", "primitive_mesh"]

_KNOWN_KEYS = {"name", "mesh", "mesh_scale", "symmetry", "joints", "states", "description",
               "base_mesh", "scale", "allow_external_files", "primitive", "size", "radius",
               "length"}
#: the primitive kinds and the dimensions each is fitted with (metres)
PRIMITIVES = {"box": ("x", "y", "z"), "cylinder": ("radius", "length")}
MIN_DIMENSION = 0.002            #: m, the smallest dimension a primitive may be given
CYLINDER_SECTIONS = 48           #: facets around a primitive cylinder's mesh
#: bounds on what a template file may ask for, checked before any work is done
MAX_YAML_BYTES = 1_000_000
MAX_TEMPLATE_SIZE = 100.0        #: m, largest extent of a (scaled) template
MAX_SYMMETRY_ORDER = 360         #: beyond this, say ``continuous: true``
MAX_REVOLUTE = 64 * math.pi      #: rad, joint limits of a revolute joint (32 turns)
MAX_JOINTS = 16
_JOINT_KEYS = {"name", "type", "axis", "origin", "lower", "upper", "torque_limit", "moving_mesh"}


@dataclass(frozen=True)
class Symmetry:
    """Rotational symmetry of a template about an axis through its origin.

    ``order`` n >= 1 means the shape maps onto itself under rotations by 2*pi*k/n; ``continuous``
    means under every rotation about ``axis``.
    """

    axis: tuple = (0.0, 0.0, 1.0)
    order: int = 1
    continuous: bool = False

    @property
    def rotations(self) -> np.ndarray:
        """The symmetry rotations (k, 3, 3), identity first. A continuous symmetry is sampled at
        1 degree steps (use :meth:`residual_angle` for exact errors)."""
        n = 360 if self.continuous else self.order
        return np.stack([axis_angle_matrix(self.axis, 2.0 * math.pi * k / n) for k in range(n)])

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

    def __init__(self, name: str, path: str, mesh: trimesh.Trimesh | None,
                 points: np.ndarray | None = None, point_normals: np.ndarray | None = None,
                 mesh_scale: float = 1.0, symmetry: Symmetry | None = None,
                 joints: tuple = (), states: Mapping | None = None, description: str = "",
                 base_mesh: trimesh.Trimesh | None = None, scale_range: tuple | None = None,
                 primitive: str | None = None, dimension_ranges: Mapping | None = None,
                 dimensions: Mapping | None = None):
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
        self._cache: dict = {}
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"AffordanceTemplate({self.name!r}, diameter={self.diameter:.3f} m)"

    @property
    def is_point_template(self) -> bool:
        return self.mesh is None

    def clip_dimensions(self, dimensions: Mapping) -> dict:
        """A primitive's ``dimensions`` (name -> m) within its ranges (a box's x >= y kept)."""
        out = {k: float(np.clip(float(dimensions[k]), *self.dimension_ranges[k]))
               for k in PRIMITIVES[self.primitive]}
        return out

    def sized(self, dimensions: Mapping) -> "AffordanceTemplate":
        """This primitive with the given dimensions (clipped to its ranges, rounded to 0.1
        mm): a template of the same name whose mesh has that size. The last SIZED_KEPT are
        cached, so a refit at the same size reuses its samples and surface."""
        dims = {k: round(v, 4) for k, v in self.clip_dimensions(dimensions).items()}
        key = ("sized",) + tuple(dims.values())

        def build():
            return AffordanceTemplate(self.name, self.path, primitive_mesh(self.primitive, dims),
                                      symmetry=self.symmetry, description=self.description,
                                      primitive=self.primitive,
                                      dimension_ranges=self.dimension_ranges, dimensions=dims)
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
        Point templates have none."""
        key = ("resting", int(max_poses))
        with self._lock:
            if key in self._cache:
                return self._cache[key]
        poses = [] if self.mesh is None else _resting_facets(self.mesh)[:max_poses]
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
                scale_range = _scale_range(scale_range)
            except ValueError as exc:
                raise TemplateError(f"{self.path}: scale range {exc}") from None
        return AffordanceTemplate(self.name, self.path, self.mesh, self.points,
                                  self.point_normals, self.mesh_scale, self.symmetry,
                                  self.joints, self.states, self.description, self.base_mesh,
                                  scale_range)

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


def primitive_mesh(kind: str, dimensions: Mapping) -> trimesh.Trimesh:
    """The closed mesh of a primitive of ``dimensions`` (m) in its frame: a box's origin at
    the centre of its base face, a cylinder's at the centre of one end face, +z up / along
    the axis."""
    if kind == "box":
        ext = [float(dimensions["x"]), float(dimensions["y"]), float(dimensions["z"])]
        mesh = trimesh.creation.box(extents=ext)
        mesh.apply_translation([0.0, 0.0, ext[2] / 2])
    else:
        r, h = float(dimensions["radius"]), float(dimensions["length"])
        mesh = trimesh.creation.cylinder(radius=r, height=h, sections=CYLINDER_SECTIONS)
        mesh.apply_translation([0.0, 0.0, h / 2])
    return mesh


def _primitive_template(path: str, doc: dict, name: str, description: str) -> AffordanceTemplate:
    """A ``primitive:`` template: the kind and its dimension ranges checked, its mesh at the
    middle of the ranges."""
    kind = doc.get("primitive")
    if kind not in PRIMITIVES:
        raise _fail(path, "primitive", f"expected one of {', '.join(PRIMITIVES)}, got {kind!r}")
    other = sorted(set(doc) & {"mesh", "mesh_scale", "base_mesh", "joints", "states", "scale",
                               "symmetry"})
    if other:
        raise _fail(path, other[0], "a primitive template has dimensions, not a mesh, joints "
                                    "or a scale range")
    given = {"box": ("size",), "cylinder": ("radius", "length")}[kind]
    stray = sorted(set(doc) & {"size", "radius", "length"} - set(given))
    if stray:
        raise _fail(path, stray[0], f"not a dimension of a {kind} (it has "
                                    f"{', '.join(given)})")
    if kind == "box":
        size = doc.get("size")
        if not isinstance(size, dict) or set(size) != {"x", "y", "z"}:
            raise _fail(path, "size", f"expected {{x: [min, max], y: [min, max], z: [min, max]}} "
                                      f"in metres, got {size!r}")
        specs = {f"size.{k}": size[k] for k in "xyz"}
    else:
        specs = {k: doc.get(k) for k in ("radius", "length")}
    ranges = {}
    for key, value in specs.items():
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise _fail(path, key, f"expected [min, max] in metres, got {value!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and MIN_DIMENSION <= lo <= hi
                and hi <= MAX_TEMPLATE_SIZE):
            raise _fail(path, key, f"expected {MIN_DIMENSION} <= min <= max <= "
                                   f"{MAX_TEMPLATE_SIZE:.0f} (metres), got {value!r}")
        ranges[key.split(".")[-1]] = (lo, hi)
    middle = {k: 0.5 * (lo + hi) for k, (lo, hi) in ranges.items()}
    symmetry = Symmetry(order=2) if kind == "box" else Symmetry(continuous=True)
    return AffordanceTemplate(name, path, primitive_mesh(kind, middle), symmetry=symmetry,
                              description=description, primitive=kind,
                              dimension_ranges=ranges, dimensions=middle)


def mesh_distance(mesh: trimesh.Trimesh, points: np.ndarray, signed: bool = False) -> np.ndarray:
    """Distance (N,) from each of ``points`` (N, 3) to the surface of ``mesh``; with ``signed``,
    negative inside a watertight mesh."""
    import open3d as o3d
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))
    query = o3d.core.Tensor(np.asarray(points, dtype=np.float32))
    if signed:
        return scene.compute_signed_distance(query).numpy().astype(float)
    return scene.compute_distance(query).numpy().astype(float)


def _resting_facets(mesh: trimesh.Trimesh) -> list[tuple[np.ndarray, float]]:
    """(R_rest, area) of every convex-hull facet the object can rest on, largest first."""
    from scipy.spatial import ConvexHull
    hull = mesh.convex_hull
    com = np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, dtype=float)
    in_facet = np.zeros(len(hull.faces), bool)
    groups = []
    for facet, normal in zip(hull.facets, hull.facets_normal):
        in_facet[facet] = True
        groups.append((facet, np.asarray(normal)))
    for f in np.flatnonzero(~in_facet):
        groups.append((np.array([f]), np.asarray(hull.face_normals[f])))
    out = []
    for faces, normal in groups:
        verts = hull.vertices[np.unique(hull.faces[faces])]
        area = float(hull.area_faces[faces].sum())
        if area < 1e-6:
            continue
        # centre of mass projected onto the facet plane, inside the facet polygon?
        u = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        poly = np.stack([verts @ u, verts @ v], axis=1)
        p = np.array([com @ u, com @ v])
        try:
            eq = ConvexHull(poly).equations
        except Exception:   # degenerate (collinear) facet
            continue
        if np.any(eq[:, :2] @ p + eq[:, 2] > -1e-4):   # not strictly inside (1e-4 m margin)
            continue
        # rotation taking the facet normal to -z
        target = np.array([0.0, 0.0, -1.0])
        axis = np.cross(normal, target)
        s_, c_ = np.linalg.norm(axis), float(normal @ target)
        if s_ < 1e-9:
            R = np.eye(3) if c_ > 0 else axis_angle_matrix([1.0, 0, 0], math.pi)
        else:
            R = axis_angle_matrix(axis, math.atan2(s_, c_))
        out.append((R, area, normal))
    out.sort(key=lambda x: -x[1])
    total = sum(a for _, a, _ in out) or 1.0
    kept = []
    for R, area, normal in out:   # one pose per resting direction (they differ by a yaw only)
        if area / total < 0.02:
            continue
        if any(normal @ n > math.cos(math.radians(15)) for _, _, n in kept):
            continue
        kept.append((R, area, normal))
    return [(R, a) for R, a, _ in kept]


def _fail(path: str, key: str, msg: str) -> TemplateError:
    return TemplateError(f"{path}: key '{key}': {msg}")


def _vector(path: str, key: str, value, length: int = 3) -> tuple:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise _fail(path, key, f"expected {length} numbers, got {value!r}") from None
    if arr.shape != (length,) or not np.all(np.isfinite(arr)):
        raise _fail(path, key, f"expected {length} finite numbers, got {value!r}")
    return tuple(float(v) for v in arr)


def _scale_range(value) -> tuple:
    """(min, max) from a ``scale`` value; ValueError saying what is wrong."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"expected [min, max], got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"expected 0 < min < max, got {value!r}")
    return lo, hi


def _geometry_path(yaml_path: str, key: str, rel, allow_external: bool) -> str:
    """The file a template key names: relative to the YAML, and inside the YAML's folder unless
    the template says ``allow_external_files: true``.

    The check follows symlinks: the file's real path must lie in the real path of the YAML's
    folder, or -- for a YAML that is itself a symlink, as in a ``colcon build --symlink-install``
    share folder, where every file is linked on its own -- in the folder of the YAML's real file.
    A path that resolves anywhere else is refused."""
    if not isinstance(rel, str) or not rel:
        raise _fail(yaml_path, key, "expected a file path relative to the YAML file")
    folder = os.path.dirname(os.path.abspath(yaml_path))
    path = os.path.join(folder, rel)
    if not allow_external:
        real = os.path.realpath(path)
        roots = {os.path.realpath(folder), os.path.dirname(os.path.realpath(yaml_path))}
        if not any(os.path.commonpath([real, root]) == root for root in roots):
            raise _fail(yaml_path, key, f"{rel} is outside the template's folder {folder} "
                                        f"(set 'allow_external_files: true' to allow that)")
    if not os.path.isfile(path):
        raise _fail(yaml_path, key, f"file not found: {path}")
    if os.path.getsize(path) > MAX_FILE_BYTES:
        raise _fail(yaml_path, key, f"{path} is larger than {MAX_FILE_BYTES / 1e9:.0f} GB")
    return path


def _load_geometry(yaml_path: str, key: str, rel: str, scale: float,
                   allow_external: bool = False):
    """Load a mesh, or a point cloud (a PCD, or a PLY without faces: a scan of the object, read
    like a scene); returns (mesh or None, points or None, normals or None)."""
    path = _geometry_path(yaml_path, key, rel, allow_external)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".stl", ".obj", ".ply", ".pcd", ".off", ".glb", ".gltf"):
        raise _fail(yaml_path, key, f"unsupported file type '{ext}' (STL, OBJ, PLY, PCD)")
    fail = (lambda msg: _fail(yaml_path, key, msg))
    if ext in (".ply", ".pcd") and not check_header(path, fail)["faces"]:
        f = read_points(path, fail)
        finite = np.all(np.isfinite(f.points), axis=1)
        pts = f.points[finite] * scale
        if len(pts) < 10:
            raise _fail(yaml_path, key, f"{path}: fewer than 10 finite points")
        _check_extent(yaml_path, key, pts)
        # the file's normals (a scan's, oriented towards its scanner) or estimated ones
        normals = f.normals[finite] if f.normals is not None else _estimate_normals(pts)
        return None, pts, normals
    try:
        geom = trimesh.load(path, process=True)
        if isinstance(geom, trimesh.Scene):
            geom = geom.dump(concatenate=True) if geom.geometry else None
    except Exception as exc:  # trimesh raises many types for broken files
        raise _fail(yaml_path, key, f"{path} does not load: {exc}") from None
    if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
        raise _fail(yaml_path, key, f"{path} does not load as a mesh (no faces)")
    mesh = geom.copy()
    mesh.apply_scale(scale)
    _check_extent(yaml_path, key, np.asarray(mesh.vertices))
    if mesh.area <= 0:
        raise _fail(yaml_path, key, f"{path} has no surface area")
    return mesh, None, None


def _check_extent(yaml_path: str, key: str, points: np.ndarray) -> None:
    """Scaled geometry must be finite and at most MAX_TEMPLATE_SIZE across."""
    if not np.all(np.isfinite(points)):
        raise _fail(yaml_path, key, "the geometry is not finite (mesh_scale too large?)")
    size = float(np.max(points.max(axis=0) - points.min(axis=0)))
    if size > MAX_TEMPLATE_SIZE:
        raise _fail(yaml_path, key, f"the geometry is {size:.3g} m across, more than the "
                                    f"{MAX_TEMPLATE_SIZE:.0f} m a template may be (mesh_scale "
                                    f"converts its units to metres)")


def _estimate_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals of a scanned object by local PCA, oriented away from the centroid."""
    normals = pca_normals(points, 16)
    inward = np.einsum("ni,ni->n", normals, points - points.mean(axis=0)) < 0
    normals[inward] *= -1
    return normals


def _parse_symmetry(path: str, value) -> Symmetry | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise _fail(path, "symmetry", f"expected a mapping like {{axis: [0,0,1], order: 4}}, "
                                      f"got {value!r}")
    unknown = set(value) - {"axis", "order", "continuous"}
    if unknown:
        raise _fail(path, "symmetry", f"unknown symmetry form: keys {sorted(unknown)} "
                                      f"(use axis with order N or continuous: true)")
    axis = _vector(path, "symmetry.axis", value.get("axis", [0, 0, 1]))
    if np.linalg.norm(axis) < 1e-9:
        raise _fail(path, "symmetry.axis", "axis must not be zero")
    axis = tuple(float(v) for v in np.asarray(axis) / np.linalg.norm(axis))
    continuous = value.get("continuous", False)
    if continuous not in (True, False):
        raise _fail(path, "symmetry.continuous", f"expected true or false, got {continuous!r}")
    if continuous:
        if "order" in value:
            raise _fail(path, "symmetry", "give either order or continuous, not both")
        return Symmetry(axis=axis, continuous=True)
    order = value.get("order")
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise _fail(path, "symmetry.order", f"expected an integer >= 1, got {order!r}")
    if order > MAX_SYMMETRY_ORDER:
        raise _fail(path, "symmetry.order", f"{order} is more than {MAX_SYMMETRY_ORDER}: for a "
                                            f"shape that looks the same at every angle use "
                                            f"'continuous: true'")
    return Symmetry(axis=axis, order=order)


def _parse_joints(path: str, value, scale: float, external: bool = False) -> tuple:
    if value is None:
        return ()
    if not isinstance(value, list):
        raise _fail(path, "joints", "expected a list of joints")
    if len(value) > MAX_JOINTS:
        raise _fail(path, "joints", f"{len(value)} joints; at most {MAX_JOINTS}")
    joints, names = [], set()
    for i, spec in enumerate(value):
        key = f"joints[{i}]"
        if not isinstance(spec, dict):
            raise _fail(path, key, "expected a mapping")
        unknown = set(spec) - _JOINT_KEYS
        if unknown:
            raise _fail(path, key, f"unknown keys {sorted(unknown)}")
        name = spec.get("name")
        if not isinstance(name, str) or not name:
            raise _fail(path, f"{key}.name", "missing or empty")
        if name in names:
            raise _fail(path, f"{key}.name", f"duplicate joint name '{name}'")
        names.add(name)
        jtype = spec.get("type")
        if jtype not in ("revolute", "prismatic"):
            raise _fail(path, f"{key}.type", f"expected revolute or prismatic, got {jtype!r}")
        axis = np.asarray(_vector(path, f"{key}.axis", spec.get("axis")))
        if np.linalg.norm(axis) < 1e-9:
            raise _fail(path, f"{key}.axis", "axis must not be zero")
        origin = _vector(path, f"{key}.origin", spec.get("origin", [0, 0, 0]))
        try:
            lower, upper = float(spec["lower"]), float(spec["upper"])
        except KeyError as exc:
            raise _fail(path, f"{key}.{exc.args[0]}", "missing joint limit") from None
        except (TypeError, ValueError):
            raise _fail(path, f"{key}.lower/upper", "limits must be numbers") from None
        if not (math.isfinite(lower) and math.isfinite(upper)) or lower >= upper:
            raise _fail(path, f"{key}.lower/upper",
                        f"limits inverted or empty: lower={lower} must be below upper={upper}")
        reach = MAX_REVOLUTE if jtype == "revolute" else MAX_TEMPLATE_SIZE / scale
        if max(abs(lower), abs(upper)) > reach:
            raise _fail(path, f"{key}.lower/upper",
                        f"limits beyond ±{reach:.4g} ({'rad' if jtype == 'revolute' else 'mesh units'}):"
                        f" lower={lower}, upper={upper}")
        torque = spec.get("torque_limit")
        if torque is not None:
            try:
                torque = float(torque)
            except (TypeError, ValueError):
                raise _fail(path, f"{key}.torque_limit", f"expected a number, got {torque!r}") \
                    from None
            if not torque > 0:
                raise _fail(path, f"{key}.torque_limit", "must be positive")
        if "moving_mesh" not in spec:
            raise _fail(path, f"{key}.moving_mesh", "missing: the moving part's mesh is required")
        moving, _, _ = _load_geometry(path, f"{key}.moving_mesh", spec["moving_mesh"], scale,
                                      external)
        if moving is None:
            raise _fail(path, f"{key}.moving_mesh", "the moving part must be a mesh")
        if jtype == "prismatic":
            lower_o, upper_o = lower * scale, upper * scale
        else:
            lower_o, upper_o = lower, upper
        joints.append(Joint(name=name, type=jtype,
                            axis=tuple(float(v) for v in axis / np.linalg.norm(axis)),
                            origin=tuple(float(v) * scale for v in origin), lower=lower_o,
                            upper=upper_o, torque_limit=torque, moving_mesh=moving))
    return tuple(joints)


def _parse_states(path: str, value, joints: tuple, scale: float) -> dict:
    """Named joint values: radians, or for a prismatic joint the mesh's units as its limits are
    (times ``scale``, metres like them)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _fail(path, "states", "expected a mapping of state name to joint values")
    by_name = {j.name: j for j in joints}
    states = {}
    for state, values in value.items():
        if not isinstance(values, dict):
            raise _fail(path, f"states.{state}", "expected a mapping of joint name to value")
        states[str(state)] = checked = {}
        for jname, v in values.items():
            if jname not in by_name:
                raise _fail(path, f"states.{state}.{jname}", "no joint of that name")
            joint = by_name[jname]
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise _fail(path, f"states.{state}.{jname}", f"expected a number, got {v!r}") \
                    from None
            unit = scale if joint.type == "prismatic" else 1.0
            tol = 1e-6 * max(1.0, abs(joint.upper - joint.lower))
            if not joint.lower - tol <= v * unit <= joint.upper + tol:
                raise _fail(path, f"states.{state}.{jname}",
                            f"{v} is outside the joint limits [{joint.lower / unit:.6g}, "
                            f"{joint.upper / unit:.6g}]")
            checked[jname] = v * unit
    return states


def load_template(path: str) -> AffordanceTemplate:
    """Load one template YAML file. Raises :class:`TemplateError` naming the file and key."""
    path = str(path)
    try:
        if os.path.getsize(path) > MAX_YAML_BYTES:
            raise TemplateError(f"{path}: larger than {MAX_YAML_BYTES // 1000} kB: not a "
                                f"template file")
        with open(path, encoding="utf-8") as handle:
            doc = yaml.safe_load(handle)
    except OSError as exc:
        raise TemplateError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise TemplateError(f"{path}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        raise TemplateError(f"{path}: not valid YAML: {exc}".splitlines()[0]) from None
    except RecursionError:
        raise TemplateError(f"{path}: YAML nested too deeply") from None
    if not isinstance(doc, dict):
        raise TemplateError(f"{path}: expected a mapping with at least 'name' and 'mesh'")
    unknown = set(doc) - _KNOWN_KEYS
    if unknown:
        raise _fail(path, sorted(unknown)[0], f"unknown key (known: {', '.join(sorted(_KNOWN_KEYS))})")
    name = doc.get("name")
    if not isinstance(name, str) or not name.strip():
        raise _fail(path, "name", "missing or empty")
    if "primitive" in doc:
        description = doc.get("description", "")
        if not isinstance(description, str):
            raise _fail(path, "description", "expected text")
        return _primitive_template(path, doc, name.strip(), description)
    if "mesh" not in doc:
        raise _fail(path, "mesh", "missing")
    scale = doc.get("mesh_scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) \
            or scale <= 0:
        raise _fail(path, "mesh_scale", f"expected a positive number, got {scale!r}")
    external = doc.get("allow_external_files", False)
    if external not in (True, False):
        raise _fail(path, "allow_external_files", f"expected true or false, got {external!r}")
    mesh, points, normals = _load_geometry(path, "mesh", doc["mesh"], float(scale), external)
    symmetry = _parse_symmetry(path, doc.get("symmetry"))
    joints = _parse_joints(path, doc.get("joints"), float(scale), external)
    states = _parse_states(path, doc.get("states"), joints, float(scale))
    base = None
    if "base_mesh" in doc:
        base, _, _ = _load_geometry(path, "base_mesh", doc["base_mesh"], float(scale), external)
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise _fail(path, "description", "expected text")
    scale_range = None
    if "scale" in doc:
        try:
            scale_range = _scale_range(doc["scale"])
        except ValueError as exc:
            raise _fail(path, "scale", str(exc)) from None
    if joints and base is None:
        raise _fail(path, "base_mesh", "a template with joints needs the fixed part's mesh")
    return AffordanceTemplate(name=name.strip(), path=path, mesh=mesh, points=points,
                              point_normals=normals, mesh_scale=float(scale), symmetry=symmetry,
                              joints=joints, states=states, description=description,
                              base_mesh=base, scale_range=scale_range)


def default_models_dir() -> str:
    """The package's own template library: the source tree's models/ (editable install or
    checkout), else ``share/affordance_registration/models`` of the install prefix."""
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    candidates = [os.path.join(here, "models")]
    try:  # colcon / ament install
        from ament_index_python.packages import get_package_share_directory
        candidates.append(os.path.join(get_package_share_directory("affordance_registration"),
                                       "models"))
    except Exception:
        pass
    import sys
    candidates.append(os.path.join(sys.prefix, "share", "affordance_registration", "models"))
    for c in candidates:
        if os.path.isdir(c) and any(f.endswith(".yaml") for f in os.listdir(c)):
            return c
    raise TemplateError("the package's models/ directory was not found; pass a templates "
                        "directory explicitly")


class TemplateLibrary(Mapping):
    """An ordered, read-only name -> :class:`AffordanceTemplate` mapping."""

    def __init__(self, templates=()):
        self._templates: dict[str, AffordanceTemplate] = {}
        for t in templates:
            if t.name in self._templates:
                raise TemplateError(f"{t.path}: key 'name': duplicate template name '{t.name}' "
                                    f"(also in {self._templates[t.name].path})")
            self._templates[t.name] = t

    @classmethod
    def load(cls, source: str | None = None) -> "TemplateLibrary":
        """Load a directory of ``*.yaml`` templates, or one YAML file. ``None`` loads the
        package's own models. An empty directory is an error."""
        source = default_models_dir() if source is None else str(source)
        if os.path.isdir(source):
            files = sorted(os.path.join(source, f) for f in os.listdir(source)
                           if f.endswith((".yaml", ".yml")) and not f.startswith("."))
            if not files:
                raise TemplateError(f"{source}: no template files (*.yaml) in this directory")
        elif os.path.isfile(source):
            files = [source]
        else:
            raise TemplateError(f"{source}: no such template file or directory")
        return cls(load_template(f) for f in files)

    def __getitem__(self, name: str) -> AffordanceTemplate:
        try:
            return self._templates[name]
        except KeyError:
            raise KeyError(f"no template named '{name}' (have: {', '.join(self._templates)})") \
                from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._templates)

    def __len__(self) -> int:
        return len(self._templates)

    @property
    def max_diameter(self) -> float:
        """The largest template's diameter (m): it sets the crop around a click. Primitives
        count only in a library of primitives alone (their size is what a fit finds)."""
        specific = [t for t in self._templates.values() if t.primitive is None]
        return max(t.diameter for t in (specific or self._templates.values()))

    def specific(self) -> "TemplateLibrary":
        """The library less its primitives."""
        return TemplateLibrary(t for t in self._templates.values() if t.primitive is None)
