# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Mixed and complex real scenes that mOSD's learn split has no counterpart of, built from it,
and the measure of a fitter on them and on the learn scenes (issue 59).

**Composite scenes** (:func:`composite_scene`). A *base* learn scene keeps its table and objects;
*units* cut by their labels from other learn scenes are pasted onto its table, and simulated
objects rendered among them:

* *Units.* An object of a source scene is pasted with the objects it stands on or that stand
  on it (a stack goes as a whole) and with the objects that hide :data:`HIDDEN` or more of it
  (its hidden part then stays explained by what hides it) -- read from the annotation
  (:func:`.realdata.object_note`: ``on``, ``under``, ``hidden``, ``hidden_by``); an object
  pasted alone is seen (nearly) whole.
* *The move.* The scans are one-sided, so a unit keeps the side the sensor saw: it is turned
  about the camera's origin from its table's normal onto the base table's (both
  :func:`.realdata.fit_plane` on the table labels), lifted along the normal onto the base
  plane, turned about the vertical through the camera (which keeps its distance from the camera
  and the side it shows) and slid along the table straight away from or towards the camera by
  at most what turns its line of sight by :data:`MAX_VIEW_CHANGE_DEG`.
* *Where.* A unit or a simulated object slides along the table towards an object already there
  until its footprint (the convex hull of its points seen along the normal) comes within
  :data:`GAP` of another's, then backs off by a seeded gap (mixed: up to 10 cm; complex: up to
  1.5 cm, and half the time along the line of sight, so that one stands in front of the
  other); its footprint must lie on the table (the hull of the base's table points) and its
  points in the image.
* *Rendering.* A unit's labelled points are a surface: the organized pixels joined into
  triangles where neighbours are one object within :data:`JUMP` in depth. Posed, it is ray cast
  (:class:`.simulation.DepthCamera`, no noise added: the points are real) into the base
  scene's camera (:func:`.realdata.fit_intrinsics`); each pixel takes the colour and part label
  of the nearest source point. Simulated objects (:data:`SHAPES`: boxes, standing and lying
  cylinders, books lying, and shapes that are neither -- a bowl, a sphere, a cone, a torus, a
  pyramid, an L-shaped block, a mug with a handle) are rendered by the same camera with the
  simulator's Kinect noise (``NoiseModel``; ``faults`` adds ``FaultModel``'s), one flat colour
  each, shaded by incidence.
* *Merging.* Per pixel the nearest depth wins (a z-buffer over the base and the two rendered
  layers): base points behind a pasted object are gone, and so are its points behind base
  objects. A rendered object's holes (a source pixel without depth) hide what lies behind them
  too (:data:`HOLE_CLOSING`). Then the projector's shadows: a Kinect's pattern comes from
  :data:`PROJECTOR` (m, beside the camera; the mOSD scans have their invalid bands on the left
  of objects), so a point the projector cannot see past an added object (or an added object's
  point past a base object) has no depth.

The result is an organized (480, 640) :class:`.realdata.LabelledCloud` named
``<kind><seed>`` with labels (base objects keep theirs; each pasted or simulated object a new
id, 10 id + part) and colours, and one :class:`PlacedObject` per object: its kind ("box",
"cylinder" or "other" -- what :func:`.realdata.object_kind` says of a learn object; a simulated
mug is a "cylinder" when its outer cylinder explains at least :data:`.realdata.PASS_RECALL` of
its visible points within the label rule's tolerance, else "other", the rule every learn mug is
scored by), where it came from, and for a simulated box or cylinder its true pose and size.

**Kinds.** "mixed": boxes, cans, bowls together -- a base of at most three objects and units
of other scenes (each scene once, preferring kinds the scene lacks) to 3-5 objects, one in two
scenes with one simulated object among them. "complex": crowded -- 5-8 objects, stacks and
occlusion pairs preferred, 1-3 simulated objects (lying cylinders and books lying twice as
likely as each other shape), placed touching and hiding each other.

**Seeds and the held-out part.** Development seeds :data:`DEVELOPMENT_SEEDS` (0-19), held-out
:data:`HELD_OUT_SEEDS` (100-119, not looked at while tuning). Seeds below
:data:`HELD_OUT_FROM` take their base and units from the learn scenes kept for tuning
(``osd_scene_paths(held_out=False)``); seeds from it on from every learn scene, so held-out
composites also hold objects that tuning never saw. Which learn scenes there are, their
objects' kinds and which are held out are :mod:`.realdata`'s (``osd_scene_paths``,
``object_kind``, ``is_held_out``): an annotation of more scenes there changes the scenes a seed
gives.

**The measure** (:func:`measure`, :func:`summarize`). Every labelled object with at least
:data:`.realdata.MIN_OBJECT_POINTS` points is clicked in its middle
(:func:`.realdata.evaluate_scene`), and the shown (best) candidate is judged (:func:`judge`):
*right* -- a box or cylinder shown as that primitive passing the label rule, an "other" with
nothing fitting; *wrong and accepted* -- the shown candidate fits and is not right; *specific
claim* -- a specific (non-primitive) template fits (every object here is outside the library).
Groups: the learn scenes by mOSD group, tuning and held-out scenes apart; the mixed and
complex composites, development and held-out seeds apart.

Run ``affordance-registration trust --kind mixed --seeds 0-19 --out FILE.json`` (``--kind
learn`` for the learn scenes; ``--save DIR`` writes the composites as mOSD-like PCDs): every
click's record goes to the JSON, a summary to stdout (:func:`run`).
"""

from __future__ import annotations

import colorsys
import functools
import json
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError, cKDTree

from ..core.errors import AffordanceError
from ..core.segmentation import share_within
from ..core.transforms import axis_angle_matrix, make_T
from .realdata import (
    MIN_TOLERANCE,
    NOISE_SIGMAS,
    PASS_RECALL,
    LabelledCloud,
    cylinder_distance,
    evaluate_scene,
    fit_intrinsics,
    fit_plane,
    is_held_out,
    labelled_objects,
    local_noise,
    object_kind,
    object_note,
    osd_scene_paths,
    read_labelled_pcd,
    scene_kind,
    scene_name,
    table_points,
)

__all__ = [
    "KINDS",
    "DEVELOPMENT_SEEDS",
    "HELD_OUT_SEEDS",
    "HELD_OUT_FROM",
    "SHAPES",
    "PROJECTOR",
    "JUMP",
    "GAP",
    "MAX_VIEW_CHANGE_DEG",
    "HIDDEN",
    "HOLE_CLOSING",
    "SourceObject",
    "Unit",
    "PlacedObject",
    "CompositeScene",
    "source_units",
    "composite_scene",
    "BaseTable",
    "unit_pose",
    "paste",
    "simulated_shape",
    "judge",
    "measure",
    "measure_learn",
    "classify_learn",
    "summarize",
    "composite_rows",
    "format_lines",
    "parse_seeds",
    "write_labelled_pcd",
    "run",
]

KINDS = ("mixed", "complex")
DEVELOPMENT_SEEDS = range(0, 20)
HELD_OUT_SEEDS = range(100, 120)
#: seeds from this one on are held out (and draw on every learn scene, held-out ones too)
HELD_OUT_FROM = 100

#: m: neighbouring pixels of one object further apart in depth are not joined into a triangle
#: (a surface seen 80 deg off its normal at 0.9 m steps 10 mm from pixel to pixel)
JUMP = 0.012
#: m: the closest two footprints may come
GAP = 0.003
#: deg: the most a pasted unit's line of sight to the camera may turn
MAX_VIEW_CHANGE_DEG = 8.0
#: an object the annotation says others hide this share of (or more) is pasted with them
HIDDEN = 0.1
#: pixels: the closing of a rendered object's silhouette whose holes hide what is behind them
HOLE_CLOSING = 2
#: m, optical frame: where a Kinect's pattern projector is (7.5 cm right of the camera)
PROJECTOR = (0.075, 0.0, 0.0)
#: a projector ray met by a surface before this share of its length from the point shadows it
#: (1.5%: 9-15 mm at the scans' 0.6-1 m)
SHADOW_MARGIN = 0.015
#: the simulated shapes, with their kinds ("other": no primitive is right)
SHAPES = {
    "box": "box",
    "book": "box",
    "cylinder": "cylinder",
    "lying cylinder": "cylinder",
    "bowl": "other",
    "sphere": "other",
    "cone": "other",
    "torus": "other",
    "pyramid": "other",
    "L-block": "other",
    "mug": "cylinder or other",
}
#: the shapes each kind of composite draws (complex: lying cylinders and books twice as likely)
_SHAPE_WEIGHTS = {
    "mixed": {s: 1.0 for s in SHAPES if s not in ("book", "lying cylinder")},
    "complex": {s: 2.0 if s in ("book", "lying cylinder") else 1.0 for s in SHAPES},
}
_ATTEMPTS = 12  #: bases tried before a seed gives up
_STEP = 0.01  #: m, the slide's step (the contact is then found to within 1.25 mm)
#: the least share of its own pixels an added object keeps in view (mixed, complex), and the
#: least share of theirs every object already there keeps
_SHOWN = {"mixed": 0.6, "complex": 0.35}
_KEPT = {"mixed": 0.6, "complex": 0.4}


# ---------------------------------------------------------------------------- source units
@dataclass(frozen=True)
class SourceObject:
    """One object of a unit: its ``id`` and ``kind`` in its source scene, and its labelled
    points as a surface -- ``mesh`` (a trimesh in the source's optical frame), with each
    vertex's ``colors`` (V, 3) uint8 and ``parts`` (V,) (label % 10)."""

    id: int
    kind: str
    mesh: object = field(repr=False)
    colors: np.ndarray = field(repr=False)
    parts: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class Unit:
    """What is pasted together from one learn scene: its ``objects``, all their ``points`` (N,
    3, the source's optical frame), the source table's plane (``normal`` towards the sensor,
    ``offset``: n . p + d = 0) and whether it is a stack."""

    scene: str
    objects: tuple
    points: np.ndarray = field(repr=False)
    normal: np.ndarray = field(repr=False)
    offset: float
    stacked: bool

    @property
    def ids(self) -> tuple:
        return tuple(o.id for o in self.objects)

    @property
    def kinds(self) -> tuple:
        return tuple(o.kind for o in self.objects)


def _organized_mesh(points: np.ndarray, mask: np.ndarray, colors, labels):
    """The pixels of ``mask`` (H, W) of an organized cloud as a surface: each 2 x 2 block
    split into two triangles, a triangle kept where its three pixels are in the mask and
    within :data:`JUMP` of each other in depth. Returns (trimesh, vertex colours, parts)."""
    import trimesh

    H, W = mask.shape
    index = np.full(H * W, -1)
    flat = np.flatnonzero(mask.reshape(-1))
    index[flat] = np.arange(len(flat))
    index = index.reshape(H, W)
    z = np.where(mask, points[..., 2], np.nan)
    a, b = index[:-1, :-1], index[:-1, 1:]
    c, d = index[1:, :-1], index[1:, 1:]
    za, zb, zc, zd = z[:-1, :-1], z[:-1, 1:], z[1:, :-1], z[1:, 1:]
    faces = []
    for tri, zs in (((a, c, b), (za, zc, zb)), ((b, c, d), (zb, zc, zd))):
        ok = (tri[0] >= 0) & (tri[1] >= 0) & (tri[2] >= 0)
        with np.errstate(invalid="ignore"):
            spread = np.fmax(np.fmax(zs[0], zs[1]), zs[2]) - np.fmin(np.fmin(zs[0], zs[1]), zs[2])
        ok &= spread <= JUMP
        faces.append(np.stack([t[ok] for t in tri], axis=1))
    faces = np.concatenate(faces)
    verts = points.reshape(-1, 3)[flat]
    mesh = trimesh.Trimesh(verts, faces, process=False)
    cols = (
        colors.reshape(-1, 3)[flat]
        if colors is not None
        else np.full((len(flat), 3), 128, np.uint8)
    )
    return mesh, cols.astype(np.uint8), (labels.reshape(-1)[flat] % 10).astype(np.int64)


@functools.lru_cache(maxsize=None)
def source_units(path: str) -> tuple:
    """The :class:`Unit` s of the learn scene at ``path`` (cached): its objects joined where
    the annotation (:func:`.realdata.object_note`) says one stands on another or others hide
    :data:`HIDDEN` of it or more."""
    cloud = read_labelled_pcd(path)
    normal, offset = fit_plane(table_points(cloud), towards=cloud.viewpoint)
    ids = np.where(cloud.valid, cloud.object_ids, 0)
    objs = [o.id for o in labelled_objects(cloud, min_points=1)]
    parent = {k: k for k in objs}

    def root(k):
        while parent[k] != k:
            k = parent[k]
        return k

    notes = {k: object_note(cloud.name, k) for k in objs}
    stacked = set()
    for a, note in notes.items():
        joined = list(note.on) + list(note.under)
        stacked |= set(joined) | ({a} if joined else set())
        if note.hidden >= HIDDEN:
            joined += list(note.hidden_by)
        for b in joined:
            if b in parent:
                parent[root(a)] = root(b)
    groups: dict = {}
    for k in objs:
        groups.setdefault(root(k), []).append(k)
    flat = cloud.points.reshape(-1, 3)
    units = []
    for members in sorted(groups.values()):
        objects = []
        for k in members:
            mesh, cols, parts = _organized_mesh(cloud.points, ids == k, cloud.colors, cloud.labels)
            objects.append(SourceObject(k, notes[k].kind, mesh, cols, parts))
        units.append(
            Unit(
                cloud.name,
                tuple(objects),
                np.concatenate([flat[(ids == k).reshape(-1)] for k in members]),
                normal,
                float(offset),
                bool(stacked & set(members)),
            )
        )
    return tuple(units)


# ---------------------------------------------------------------------------- the base table
class BaseTable:
    """The base scene's table: its plane (``normal`` towards the sensor, ``offset``), a frame
    on it (``a``, ``b`` in the plane, ``foot`` the camera's foot on it), the hull of its table
    points in that frame (``table_hull`` (K, 2)) and the camera (``intrinsics``)."""

    def __init__(self, cloud: LabelledCloud):
        self.cloud = cloud
        self.intrinsics = fit_intrinsics(cloud.points)
        table = table_points(cloud)
        self.normal, self.offset = fit_plane(table, towards=cloud.viewpoint)
        a = np.array([1.0, 0.0, 0.0]) - self.normal * self.normal[0]
        self.a = a / np.linalg.norm(a)
        self.b = np.cross(self.normal, self.a)
        self.foot = -self.offset * self.normal
        flat = self.flat(table)
        self.table_hull = flat[ConvexHull(flat).vertices]

    def flat(self, points: np.ndarray) -> np.ndarray:
        """``points`` (N, 3) seen along the normal: (N, 2) in the table's frame."""
        rel = np.asarray(points, float) - self.foot
        return np.stack([rel @ self.a, rel @ self.b], axis=1)

    def T_cam_table(self) -> np.ndarray:
        """The table's frame (x = a, y = b, z = normal, origin the camera's foot) in the
        camera's."""
        return make_T(np.stack([self.a, self.b, self.normal], axis=1), self.foot)

    def in_image(self, points: np.ndarray, margin: float = 5.0) -> bool:
        """Whether ``points`` (N, 3) all project into the image, ``margin`` pixels in."""
        p = np.asarray(points, float)
        if np.any(p[:, 2] <= 0.05):
            return False
        u, v = self.intrinsics.project(p)
        i = self.intrinsics
        return bool(
            np.all((u >= margin) & (u <= i.width - 1 - margin))
            and np.all((v >= margin) & (v <= i.height - 1 - margin))
        )

    def on_table(self, footprint) -> bool:
        """Whether a footprint (its hull's corners) lies within the table points' hull."""
        return share_within(footprint.corners, self.table_hull) >= 1.0


@dataclass(frozen=True)
class _Footprint:
    """A footprint on the table: its convex hull's ``corners`` (K, 2), its ``outline`` (the
    hull's boundary as points 2 mm apart), ``centre`` and ``reach`` (the farthest outline
    point from the centre)."""

    corners: np.ndarray
    outline: np.ndarray
    centre: np.ndarray
    reach: float


def _footprint(flat: np.ndarray, spacing: float = 0.002) -> _Footprint:
    """The :class:`_Footprint` of 2-D points ``flat`` (N, 2)."""
    flat = np.asarray(flat, float)
    try:
        corners = flat[ConvexHull(flat).vertices]
    except (QhullError, ValueError):  # (a degenerate footprint: its points themselves)
        corners = flat
    out = []
    for p, q in zip(corners, np.roll(corners, -1, axis=0)):
        n = max(1, int(np.ceil(np.linalg.norm(q - p) / spacing)))
        out.append(p + (q - p) * (np.arange(n) / n)[:, None])
    outline = np.concatenate(out)
    centre = corners.mean(axis=0)
    return _Footprint(
        corners, outline, centre, float(np.linalg.norm(outline - centre, axis=1).max())
    )


def _collides(mine: _Footprint, others: list) -> bool:
    """Whether a footprint comes within :data:`GAP` of one of the ``others`` or overlaps it
    (a corner inside the other, or outlines within GAP: crossing ones are, their points
    being 2 mm apart)."""
    for other in others:
        if np.linalg.norm(mine.centre - other.centre) > mine.reach + other.reach + GAP:
            continue
        if cKDTree(other.outline).query(mine.outline, distance_upper_bound=GAP)[0].min() < GAP:
            return True
        if share_within(mine.corners, other.corners) > 0:
            return True
        if share_within(other.corners, mine.corners) > 0:
            return True
    return False


# ---------------------------------------------------------------------------- the move
def unit_pose(unit: Unit, table: BaseTable, target=None) -> tuple[np.ndarray, float]:
    """The move (T_base_source, 4 x 4) that brings ``unit`` onto ``table`` with the centre of
    its points at the 2-D ``target`` (the table's frame, :meth:`BaseTable.flat`; None: where
    it comes down, its bearing and distance from the camera as in its own scene): turned
    about the camera from its table's normal onto the base's, lifted onto the base plane,
    turned about the vertical through the camera to the target's bearing and slid along the
    line of sight to its distance. Returns it and how far (deg) the unit's line of sight
    turned (the last slide's doing: the turns keep it)."""
    n_s, n_b = unit.normal, table.normal
    axis = np.cross(n_s, n_b)
    s, c = np.linalg.norm(axis), float(n_s @ n_b)
    R = axis_angle_matrix(axis / s, math.atan2(s, c)) if s > 1e-12 else np.eye(3)
    lift = (unit.offset - table.offset) * n_b
    centre = R @ unit.points.mean(axis=0) + lift
    q0 = table.flat(centre[None])[0]
    target = q0 if target is None else np.asarray(target, float)
    phi = math.atan2(target[1], target[0]) - math.atan2(q0[1], q0[0])
    Rz = axis_angle_matrix(n_b, phi)
    bearing = target / max(np.linalg.norm(target), 1e-9)
    slide = (np.linalg.norm(target) - np.linalg.norm(q0)) * (
        bearing[0] * table.a + bearing[1] * table.b
    )
    T = make_T(Rz @ R, Rz @ lift + slide)
    before = Rz @ centre
    after = before + slide
    cos = float(before @ after / (np.linalg.norm(before) * np.linalg.norm(after)))
    return T, math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def _moved(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


# ---------------------------------------------------------------------------- simulated shapes
def simulated_shape(name: str, rng: np.random.Generator) -> dict:
    """A seeded simulated object of :data:`SHAPES`: {"shape", "kind", "mesh" (a trimesh
    standing on its base: z = 0 the table, +z up), "T_model_primitive" and "dimensions" (a box
    or cylinder: its frame in the mesh's and its size, the convention of :mod:`.realdata`;
    None for the others), "color" (RGB 0-255)}."""
    import trimesh

    from .rows import mug_handle, mug_mesh

    def box(x, y, z):
        mesh = trimesh.creation.box(extents=(x, y, z))
        mesh.apply_translation([0.0, 0.0, z / 2])
        return mesh

    T_prim, dims = None, None
    kind = SHAPES[name]
    if name in ("box", "book"):
        if name == "box":
            x = rng.uniform(0.08, 0.25)
            y, z = rng.uniform(0.05, x - 0.01), rng.uniform(0.05, 0.22)
        else:
            x = rng.uniform(0.15, 0.28)
            y, z = rng.uniform(0.10, min(0.21, x - 0.02)), rng.uniform(0.015, 0.05)
        mesh, T_prim, dims = box(x, y, z), np.eye(4), {"x": x, "y": y, "z": z}
    elif name == "cylinder":
        r, length = rng.uniform(0.03, 0.06), rng.uniform(0.06, 0.22)
        mesh = trimesh.creation.cylinder(radius=r, height=length, sections=64)
        mesh.apply_translation([0.0, 0.0, length / 2])
        T_prim, dims = np.eye(4), {"radius": r, "length": length}
    elif name == "lying cylinder":
        r, length = rng.uniform(0.03, 0.06), rng.uniform(0.10, 0.25)
        mesh = trimesh.creation.cylinder(radius=r, height=length, sections=64)
        turn = axis_angle_matrix([0.0, 1.0, 0.0], math.pi / 2)  # its axis along x
        mesh.apply_transform(make_T(turn, [0.0, 0.0, r]))
        T_prim, dims = make_T(turn, [-length / 2, 0.0, r]), {"radius": r, "length": length}
    elif name == "bowl":
        R, wall = rng.uniform(0.06, 0.10), rng.uniform(0.003, 0.006)
        depth, foot = R * rng.uniform(0.45, 0.65), R * rng.uniform(0.35, 0.5)
        t = np.linspace(0.0, 1.0, 12)
        outer = np.stack(
            [foot + (R - foot) * np.sin(t * math.pi / 2), depth * (1 - np.cos(t * math.pi / 2))],
            axis=1,
        )
        inner = (outer - [wall, -wall])[::-1]
        inner = inner[inner[:, 1] < depth]
        profile = np.vstack([[0.0, 0.0], outer, [R - wall, depth], inner, [0.0, wall]])
        profile[:, 0] = np.maximum(profile[:, 0], 0.0)
        mesh = trimesh.creation.revolve(profile, sections=64)
        if rng.random() < 0.4:  # upside down
            mesh.apply_transform(
                make_T(axis_angle_matrix([1.0, 0.0, 0.0], math.pi), [0, 0, depth])
            )
    elif name == "sphere":
        r = rng.uniform(0.035, 0.07)
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=r)
        mesh.apply_translation([0.0, 0.0, r])
    elif name == "cone":
        mesh = trimesh.creation.cone(
            radius=rng.uniform(0.04, 0.07), height=rng.uniform(0.08, 0.18), sections=48
        )
    elif name == "torus":
        minor = rng.uniform(0.015, 0.025)
        mesh = trimesh.creation.torus(
            major_radius=rng.uniform(0.05, 0.08), minor_radius=minor, major_sections=48
        )
        mesh.apply_translation([0.0, 0.0, minor])
    elif name == "pyramid":
        s, h = rng.uniform(0.08, 0.15) / 2, rng.uniform(0.06, 0.15)
        corners = [[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0], [0, 0, h]]
        mesh = trimesh.convex.convex_hull(np.array(corners, float))
    elif name == "L-block":
        w, height = rng.uniform(0.04, 0.07), rng.uniform(0.04, 0.12)
        long_, short = rng.uniform(0.14, 0.22), rng.uniform(0.08, 0.14)
        first = box(long_, w, height)
        if rng.random() < 0.5:  # an L in plan
            second = box(w, short, height)
            second.apply_translation([(long_ - w) / 2, (short + w) / 2, 0.0])
        else:  # an L standing: a block on one end
            second = box(w, w, short)
            second.apply_translation([(long_ - w) / 2, 0.0, height])
        mesh = trimesh.util.concatenate([first, second])
    elif name == "mug":
        radius, length = rng.uniform(0.03, 0.05), rng.uniform(0.08, 0.12)
        handle = mug_handle(rng, length)
        wall, bottom = rng.uniform(0.003, 0.006), rng.uniform(0.005, 0.012)
        mesh = mug_mesh(radius, length, wall, bottom, handle)
        T_prim, dims = np.eye(4), {"radius": radius, "length": length}
    else:
        raise AffordanceError(f"unknown simulated shape {name!r} ({', '.join(SHAPES)})")
    rgb = colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0.5, 0.9), rng.uniform(0.5, 0.95))
    return {
        "shape": name,
        "kind": kind,
        "mesh": mesh,
        "T_model_primitive": T_prim,
        "dimensions": None if dims is None else {k: float(v) for k, v in dims.items()},
        "color": np.array(rgb) * 255.0,
    }


# ---------------------------------------------------------------------------- the scene
@dataclass(frozen=True)
class PlacedObject:
    """An object of a composite: its ``id`` there, ``kind`` ("box" | "cylinder" | "other"),
    ``origin`` ("base", "pasted", "simulated"), ``source`` (e.g. "learn33 object 4",
    "simulated torus"), ``unit`` (objects pasted together share it; -1 for base and simulated
    objects), ``stacked``; a pasted object's ``T_scene_source`` (its source scene's frame ->
    the composite's); a simulated one's ``shape`` and, for a box or cylinder (a mug's outer
    cylinder too), ``T_scene_model`` and ``dimensions`` (the convention of :mod:`.realdata`)."""

    id: int
    kind: str
    origin: str
    source: str
    unit: int = -1
    stacked: bool = False
    shape: str | None = None
    T_scene_source: np.ndarray | None = field(default=None, repr=False)
    T_scene_model: np.ndarray | None = field(default=None, repr=False)
    dimensions: dict | None = None

    def to_dict(self) -> dict:
        def rows(T):
            return None if T is None else [[round(float(v), 6) for v in r] for r in T]

        return {
            "id": self.id,
            "kind": self.kind,
            "origin": self.origin,
            "source": self.source,
            "unit": self.unit,
            "stacked": self.stacked,
            "shape": self.shape,
            "T_scene_source": rows(self.T_scene_source),
            "T_scene_model": rows(self.T_scene_model),
            "dimensions": self.dimensions,
        }


@dataclass(frozen=True)
class CompositeScene:
    """A composite scene: ``seed``, ``kind``, ``base`` (the learn scene whose table it is),
    ``cloud`` (the organized :class:`.realdata.LabelledCloud`, named ``<kind><seed>``) and its
    ``objects`` (:class:`PlacedObject`, by id)."""

    seed: int
    kind: str
    base: str
    cloud: LabelledCloud = field(repr=False)
    objects: tuple = ()

    @property
    def kinds(self) -> dict:
        """{object id: kind}."""
        return {o.id: o.kind for o in self.objects}

    def object(self, object_id: int) -> PlacedObject:
        return next(o for o in self.objects if o.id == int(object_id))


@dataclass
class _Placed:
    """What is on the table while a scene is built: the :class:`_Footprint` of each object
    or unit, and what to render."""

    footprints: list = field(default_factory=list)
    units: list = field(default_factory=list)  # (unit, T)
    shapes: list = field(default_factory=list)  # (shape dict, T_cam_model)


def _slides(table: BaseTable, placed: _Placed, pose, rng, close: bool, tries: int = 30):
    """The spots a thing posed by ``pose(target 2-D) -> (T, footprint, points 3-D) | None``
    may go to, one per slide (at most ``tries``): from an object already there (or a random
    table point) along a seeded direction -- half the time along the line of sight when
    ``close`` -- inwards in :data:`_STEP` steps until its footprint comes within :data:`GAP` of
    another's (the contact then halved down to 1.25 mm), then back by a seeded gap (``close``:
    up to 1.5 cm, else up to 10 cm), on the table and in the image. Yields (T, footprint)."""

    def spot(s):
        got = pose(centre + s * direction)
        if got is None:
            return None, False
        T, foot, pts = got
        if _collides(foot, placed.footprints):
            return None, True
        return ((T, foot) if table.on_table(foot) and table.in_image(pts) else None), False

    for _ in range(tries):
        if placed.footprints and rng.random() < 0.9:
            centre = placed.footprints[int(rng.integers(len(placed.footprints)))].centre
        else:
            hull = table.table_hull
            centre = hull[rng.choice(len(hull), 3, replace=False)].mean(axis=0)
        if close and rng.random() < 0.5:
            direction = centre / max(np.linalg.norm(centre), 1e-9) * rng.choice([-1.0, 1.0])
        else:
            angle = rng.uniform(0, 2 * math.pi)
            direction = np.array([math.cos(angle), math.sin(angle)])
        back = rng.uniform(0.0, 0.015 if close else 0.10)
        free, contact = None, None
        for s in np.arange(0.4, -_STEP / 2, -_STEP):
            got, hit = spot(s)
            if hit:
                contact = s
                break
            if got is not None:
                free = s
        if free is None:
            continue
        if contact is not None and free - contact <= _STEP + 1e-9:
            lo, hi = contact, free  # hi free, lo touching: halve three times
            for _ in range(3):
                mid = 0.5 * (lo + hi)
                got, hit = spot(mid)
                if hit:
                    lo = mid
                elif got is not None:
                    hi = mid
                else:
                    break
            free = hi
        got, _ = spot(free + back)
        if got is None:
            got, _ = spot(free)
        if got is not None:
            yield got


def _unit_pose_fn(unit: Unit, table: BaseTable):
    sample = unit.points[:: max(1, len(unit.points) // 3000)]

    def pose(target):
        T, turned = unit_pose(unit, table, target)
        if turned > MAX_VIEW_CHANGE_DEG:
            return None
        pts = _moved(T, sample)
        return T, _footprint(table.flat(pts)), pts

    return pose


def _shape_pose_fn(shape: dict, table: BaseTable, yaw: float):
    verts = np.asarray(shape["mesh"].vertices, float)
    R = axis_angle_matrix([0.0, 0.0, 1.0], yaw)
    T_ct = table.T_cam_table()

    def pose(target):
        T = T_ct @ make_T(R, [target[0], target[1], 0.0])
        pts = _moved(T, verts)
        return T, _footprint(table.flat(pts)), pts

    return pose


def _render_layer(table: BaseTable, meshes: list, colors: list, rng=None, faults=None) -> dict:
    """Ray cast ``meshes`` ((trimesh, T_cam_mesh) each) with the base camera: ``rng`` None
    renders as they are, else with the simulator's noise (and ``faults``). ``colors``: per
    mesh, (V, 3) vertex colours taken from the nearest vertex, or (3,) a flat colour shaded by
    incidence. Returns the layer: ``points`` (H, W, 3), ``index`` (H, W) the mesh hit (-1
    none), ``colors`` (H, W, 3) uint8, ``vertex`` (H, W) the nearest vertex (-1 none)."""
    from .simulation import DepthCamera

    camera = DepthCamera(table.intrinsics, faults=faults)
    points, index, normals = camera.render(meshes, rng, return_normals=True)
    points = points.astype(float)
    H, W = index.shape
    out_colors = np.zeros((H, W, 3), np.uint8)
    vertex = np.full((H, W), -1)
    ok = np.all(np.isfinite(points), axis=-1)
    for k, ((mesh, T), col) in enumerate(zip(meshes, colors)):
        hit = ok & (index == k)
        if not hit.any():
            continue
        col = np.asarray(col)
        if col.ndim == 2:
            verts = _moved(T, np.asarray(mesh.vertices))
            _, nearest = cKDTree(verts).query(points[hit])
            vertex[hit] = nearest
            out_colors[hit] = col[nearest]
        else:
            ray = points[hit] / np.linalg.norm(points[hit], axis=1, keepdims=True)
            shade = 0.45 + 0.55 * np.abs(np.einsum("ij,ij->i", normals[hit], ray))
            out_colors[hit] = np.clip(col[None] * shade[:, None], 0, 255).astype(np.uint8)
    index = np.where(ok, index, -1)
    return {"points": points, "index": index, "colors": out_colors, "vertex": vertex}


def _cover(layer_points: np.ndarray) -> np.ndarray:
    """The depth (H, W) by which a rendered layer hides what is behind it: its own depth,
    and in the holes of its silhouette (closed by :data:`HOLE_CLOSING` pixels) its nearest
    neighbour's; inf elsewhere."""
    z = layer_points[..., 2]
    valid = np.isfinite(z)
    closed = ndimage.binary_closing(valid, iterations=HOLE_CLOSING) | valid
    near = ndimage.minimum_filter(
        np.where(valid, z, np.inf), size=2 * HOLE_CLOSING + 1, mode="constant", cval=np.inf
    )
    return np.where(valid, z, np.where(closed, near, np.inf))


def _shadowed(points: np.ndarray, meshes: list) -> np.ndarray:
    """(N,) bool: ``points`` (N, 3) the projector (:data:`PROJECTOR`) cannot see past
    ``meshes`` ((trimesh, T) each): its ray to the point meets one before the last
    :data:`SHADOW_MARGIN` of its length."""
    import open3d as o3d
    import trimesh

    from ..core.registration.model import raycaster

    if not len(points) or not meshes:
        return np.zeros(len(points), bool)
    posed = []
    for mesh, T in meshes:
        copy = mesh.copy()
        copy.apply_transform(T)
        posed.append(copy)
    scene = raycaster(trimesh.util.concatenate(posed))
    origin = np.asarray(PROJECTOR, float)
    rays = np.concatenate([np.broadcast_to(origin, points.shape), points - origin], axis=1)
    blocked = scene.test_occlusions(
        o3d.core.Tensor(rays.astype(np.float32)), 0.0, 1.0 - SHADOW_MARGIN
    )
    return blocked.numpy().astype(bool)


def paste(
    base: LabelledCloud,
    table: BaseTable,
    units: list,
    shapes: list,
    rng: np.random.Generator | None = None,
    faults=None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Merge onto ``base`` the ``units`` ((Unit, T_base_source) each) and simulated ``shapes``
    ((shape dict, T_cam_model) each) by a z-buffer (see the module docstring); the shapes are
    rendered with noise drawn from ``rng`` (None: without). Returns (points (H, W, 3), labels
    (H, W), colours (H, W, 3) uint8, {"ids": (H, W) the composite's object id of each pixel
    -- pasted ids numbered from the base's largest + 1, units' objects first, then shapes --,
    "layers": the two rendered layers})."""
    H, W = base.labels.shape
    base_ids = np.where(base.valid, base.object_ids, 0)
    next_id = int(max(base.object_ids.max(), 1)) + 1
    unit_meshes, unit_colors, unit_parts, unit_ids = [], [], [], []
    for unit, T in units:
        for obj in unit.objects:
            unit_meshes.append((obj.mesh, T))
            unit_colors.append(obj.colors)
            unit_parts.append(obj.parts)
            unit_ids.append(next_id)
            next_id += 1
    shape_ids = list(range(next_id, next_id + len(shapes)))
    layers = []
    if unit_meshes:
        layer = _render_layer(table, unit_meshes, unit_colors, None)
        hit = layer["index"] >= 0
        layer["ids"] = np.where(hit, np.array(unit_ids + [0])[layer["index"]], 0)
        parts = np.zeros((H, W), np.int64)
        for k, p in enumerate(unit_parts):
            m = hit & (layer["index"] == k)
            parts[m] = p[layer["vertex"][m]]
        layer["parts"] = parts
        layers.append(layer)
    if shapes:
        layer = _render_layer(
            table,
            [(s["mesh"], T) for s, T in shapes],
            [s["color"] for s, _ in shapes],
            rng,
            faults,
        )
        hit = layer["index"] >= 0
        layer["ids"] = np.where(hit, np.array(shape_ids + [0])[np.maximum(layer["index"], 0)], 0)
        layer["parts"] = np.zeros((H, W), np.int64)
        layers.append(layer)
    base_z = np.where(base.valid, base.points[..., 2], np.inf)
    depth = np.stack([base_z] + [_cover(layer["points"]) for layer in layers])
    winner = np.argmin(depth, axis=0)
    points = np.where(base.valid[..., None], base.points, np.nan)
    labels = np.where(base.valid, base.labels, 0).astype(np.int64)
    ids = base_ids.copy()
    colors = base.colors.copy() if base.colors is not None else np.full((H, W, 3), 128, np.uint8)
    for k, layer in enumerate(layers, start=1):
        won = (winner == k) & np.isfinite(depth[k])
        seen = won & (layer["ids"] > 0)
        points[won] = np.nan
        labels[won] = 0
        ids[won] = 0
        points[seen] = layer["points"][seen]
        labels[seen] = 10 * layer["ids"][seen] + layer["parts"][seen]
        ids[seen] = layer["ids"][seen]
        colors[seen] = layer["colors"][seen]
    # the projector's shadows: everything past an added object, an added object past a base one
    added = unit_meshes + [(s["mesh"], T) for s, T in shapes]
    valid = np.all(np.isfinite(points), axis=-1)
    dark = np.zeros((H, W), bool)
    dark[valid] = _shadowed(points[valid], added)
    new = valid & (ids >= int(max(base.object_ids.max(), 1)) + 1)
    if new.any():
        base_meshes = [
            (
                _organized_mesh(base.points, (base_ids == k) & base.valid, None, base.labels)[0],
                np.eye(4),
            )
            for k in np.unique(base_ids[base_ids > 0])
        ]
        dark[new] |= _shadowed(points[new], base_meshes)
    points[dark] = np.nan
    labels[dark] = 0
    ids[dark] = 0
    return points, labels, colors, {"ids": ids, "layers": layers}


def _mug_kind(cloud: LabelledCloud, object_id: int, T_scene_model, dims) -> str:
    """A simulated mug is a "cylinder" when its outer cylinder explains at least
    :data:`.realdata.PASS_RECALL` of its visible points within the label rule's tolerance,
    else "other"."""
    own = cloud.points[cloud.valid & (cloud.object_ids == object_id)]
    if len(own) < 50:
        return "other"
    tol = max(MIN_TOLERANCE, NOISE_SIGMAS * local_noise(own))
    recall = float(np.mean(cylinder_distance(own, T_scene_model, dims) <= tol))
    return "cylinder" if recall >= PASS_RECALL else "other"


def _pool(seed: int) -> list:
    paths = osd_scene_paths(held_out=None if seed >= HELD_OUT_FROM else False)
    if not paths:
        raise AffordanceError("no shared mOSD learn scenes (set AFFORDANCE_SHARED_DATA)")
    return paths


def _plan(kind: str, base_units: tuple, pool_units: dict, base_name: str, rng) -> tuple:
    """What to add to a base: (units, shapes) -- lists of Unit and shape names -- and the
    number of objects aimed at."""
    n_base = sum(len(u.objects) for u in base_units)
    lo, hi = (3, 5) if kind == "mixed" else (5, 8)
    target = int(rng.integers(max(lo, n_base + 1), max(hi, n_base + 1) + 1))
    if kind == "mixed":
        n_shapes = int(rng.random() < 0.5)
    else:
        n_shapes = int(rng.integers(1, 4))
    n_shapes = min(n_shapes, target - n_base - 1) if target - n_base > 1 else 0
    have = {k for u in base_units for k in u.kinds}
    units, used = [], {base_name}
    count = n_base + n_shapes
    while count < target:
        room = target - count
        options = [
            u
            for name, us in pool_units.items()
            if name not in used
            for u in us
            if len(u.objects) <= (min(room, 2) if kind == "mixed" else room)
        ]
        if not options:
            break
        weight = np.array(
            [
                (4.0 if set(u.kinds) - have else 1.0)
                * (3.0 if kind == "complex" and (u.stacked or len(u.objects) > 1) else 1.0)
                for u in options
            ]
        )
        pick = options[int(rng.choice(len(options), p=weight / weight.sum()))]
        units.append(pick)
        used.add(pick.scene)
        have |= set(pick.kinds)
        count += len(pick.objects)
    weights = _SHAPE_WEIGHTS[kind]
    names = list(weights)
    p = np.array([weights[n] for n in names])
    shapes = [names[int(rng.choice(len(names), p=p / p.sum()))] for _ in range(n_shapes)]
    return units, shapes, target


def composite_scene(seed: int, kind: str, faults=None) -> CompositeScene:
    """The seeded composite scene of ``kind`` ("mixed" | "complex"; see the module
    docstring); ``faults`` (a :class:`.simulation.FaultModel`) adds the sensor faults to the
    simulated objects. Deterministic by (seed, kind). Raises :class:`AffordanceError` when
    the data is absent, the kind unknown or no base of :data:`_ATTEMPTS` takes the plan."""
    if kind not in KINDS:
        raise AffordanceError(f"unknown composite kind {kind!r} ({', '.join(KINDS)})")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise AffordanceError(f"seed must be a non-negative integer, got {seed!r}")
    from ..core.registration.parallel import single_threaded_blas

    with single_threaded_blas():  # (tiny LAPACK calls: many times slower on two threads)
        return _composite(int(seed), kind, faults)


def _composite(seed: int, kind: str, faults) -> CompositeScene:
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    paths = _pool(seed)
    units_of = {scene_name(p): source_units(p) for p in paths}
    most = 3 if kind == "mixed" else 4
    bases = [p for p in paths if sum(len(u.objects) for u in units_of[scene_name(p)]) <= most]
    for _ in range(_ATTEMPTS):
        base_path = bases[int(rng.integers(len(bases)))]
        name = scene_name(base_path)
        add_units, add_shapes, target = _plan(kind, units_of[name], units_of, name, rng)
        got = _build(seed, kind, base_path, add_units, add_shapes, rng, faults)
        if got is not None and len(got.objects) >= (3 if kind == "mixed" else 5):
            return got
    raise AffordanceError(f"{kind} seed {seed}: no base took its objects in {_ATTEMPTS} tries")


class _View:
    """What the camera sees while a scene is built: the nearest depth and the thing (an id)
    of each pixel, and how many pixels each thing had when it came."""

    def __init__(self, base: LabelledCloud):
        self.z = np.where(base.valid, base.points[..., 2], np.inf)
        self.owner = np.where(base.valid, base.object_ids, 0)
        ids, counts = np.unique(self.owner[self.owner > 0], return_counts=True)
        self.had = dict(zip(ids.tolist(), counts.tolist()))
        self.next = int(max(base.object_ids.max(), 1)) + 1

    def admit(self, layer: dict, shown: float, kept: float) -> bool:
        """Add the things of a rendered ``layer`` (``points``, ``index``: one thing per
        index) when each keeps ``shown`` of its pixels in view and every thing already there
        ``kept`` of those it had; False (nothing changes) else."""
        z = np.where(layer["index"] >= 0, layer["points"][..., 2], np.inf)
        wins = z < self.z
        for k in np.unique(layer["index"][layer["index"] >= 0]):
            mine = layer["index"] == k
            if (mine & wins).sum() < shown * mine.sum():
                return False
        for k, had in self.had.items():
            if ((self.owner == k) & ~wins).sum() < kept * had:
                return False
        for k in np.unique(layer["index"][layer["index"] >= 0]):
            mine = (layer["index"] == k) & wins
            self.owner[mine] = self.next
            self.had[self.next] = int((layer["index"] == k).sum())
            self.next += 1
        self.z = np.where(wins, z, self.z)
        return True


def _build(seed, kind, base_path, add_units, add_shapes, rng, faults) -> CompositeScene | None:
    base = read_labelled_pcd(base_path)
    table = BaseTable(base)
    close = kind == "complex"
    placed = _Placed()
    view = _View(base)
    ids = np.where(base.valid, base.object_ids, 0)
    for obj in labelled_objects(base, min_points=1):
        placed.footprints.append(_footprint(table.flat(base.points[ids == obj.id])))
    order = [("unit", u) for u in add_units] + [("shape", s) for s in add_shapes]
    order = [order[i] for i in rng.permutation(len(order))]
    for what, item in order:
        if what == "unit":
            pose = _unit_pose_fn(item, table)
            meshes = [o.mesh for o in item.objects]
        else:
            item = simulated_shape(item, rng)
            pose = _shape_pose_fn(item, table, rng.uniform(0, 2 * math.pi))
            meshes = [item["mesh"]]
        for T, foot in _slides(table, placed, pose, rng, close):
            alone = _render_layer(table, [(m, T) for m in meshes], [(0, 0, 0)] * len(meshes))
            if view.admit(alone, _SHOWN[kind], _KEPT[kind]):
                (placed.units if what == "unit" else placed.shapes).append((item, T))
                placed.footprints.append(foot)
                break
    if not placed.units:
        return None
    points, labels, colors, info = paste(base, table, placed.units, placed.shapes, rng, faults)
    cloud = LabelledCloud(
        f"{kind}{seed}", points, labels, np.asarray(base.viewpoint, float), colors
    )
    objects = []
    stacked = {k for u in source_units(base_path) if u.stacked for k in u.ids}
    for obj in labelled_objects(base, min_points=1):
        objects.append(
            PlacedObject(
                obj.id,
                object_kind(base.name, obj.id),
                "base",
                f"{base.name} object {obj.id}",
                stacked=obj.id in stacked,
            )
        )
    next_id = int(max(base.object_ids.max(), 1)) + 1
    for u, (unit, T) in enumerate(placed.units):
        for obj in unit.objects:
            objects.append(
                PlacedObject(
                    next_id,
                    obj.kind,
                    "pasted",
                    f"{unit.scene} object {obj.id}",
                    unit=u,
                    stacked=unit.stacked,
                    T_scene_source=T,
                )
            )
            next_id += 1
    for shape, T in placed.shapes:
        T_model = None if shape["T_model_primitive"] is None else T @ shape["T_model_primitive"]
        what = shape["kind"]
        if shape["shape"] == "mug":
            what = _mug_kind(cloud, next_id, T_model, shape["dimensions"])
        objects.append(
            PlacedObject(
                next_id,
                what,
                "simulated",
                f"simulated {shape['shape']}",
                shape=shape["shape"],
                T_scene_model=T_model,
                dimensions=shape["dimensions"],
            )
        )
        next_id += 1
    return CompositeScene(int(seed), kind, base.name, cloud, tuple(objects))


# ---------------------------------------------------------------------------- writing one
def write_labelled_pcd(cloud: LabelledCloud, path: str) -> str:
    """Write ``cloud`` as an organized binary PCD with mOSD's fields (``label x y z rgba``:
    :func:`.realdata.read_labelled_pcd` and ``Scene.from_file`` read it), atomically."""
    from ..core.files import write_atomically

    H, W = cloud.labels.shape
    record = np.dtype(
        [("label", "<u4"), ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgba", "<u4")]
    )
    data = np.zeros(H * W, record)
    data["label"] = np.maximum(cloud.labels.reshape(-1), 0).astype(np.uint32)
    for i, axis in enumerate("xyz"):
        data[axis] = cloud.points.reshape(-1, 3)[:, i].astype(np.float32)
    if cloud.colors is not None:
        c = cloud.colors.reshape(-1, 3).astype(np.uint32)
        data["rgba"] = (255 << 24) | (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS label x y z rgba\n"
        "SIZE 4 4 4 4 4\nTYPE U F F F U\nCOUNT 1 1 1 1 1\n"
        f"WIDTH {W}\nHEIGHT {H}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {H * W}\nDATA binary\n"
    )
    return write_atomically({path: header.encode("ascii") + data.tobytes()})[0]


# ---------------------------------------------------------------------------- the measure
def judge(record: dict) -> dict:
    """The verdict on one click's record (:func:`.realdata.evaluate_scene`'s, its
    ``object_kind`` set): ``right`` (a box or cylinder shown as that primitive passing the
    label rule; an "other" with nothing fitting), ``accepted`` (the shown candidate fits),
    ``wrong_accepted`` (accepted and not right), ``specific_claim`` (a specific template
    fits) and ``verdict`` (one word: "right", "wrong and accepted", "refused" -- a box or
    cylinder whose shown candidate does not fit and is not right --, "error")."""
    kind = record.get("object_kind")
    if record.get("template") is None:
        return {
            "right": False,
            "accepted": False,
            "wrong_accepted": False,
            "specific_claim": False,
            "verdict": "error",
        }
    accepted = record.get("fits") is True
    primitive = record.get("primitive")
    if kind in ("box", "cylinder"):
        score = record.get("score") or {}
        right = primitive == kind and bool(score.get("passes"))
    elif kind == "other":
        right = not accepted
    else:
        raise AffordanceError(f"unknown object kind {kind!r} (box, cylinder, other)")
    wrong = accepted and not right
    return {
        "right": bool(right),
        "accepted": bool(accepted),
        "wrong_accepted": bool(wrong),
        "specific_claim": bool(accepted and primitive is None),
        "verdict": "right" if right else "wrong and accepted" if wrong else "refused",
    }


def _split(seed: int) -> str:
    return "held-out" if seed >= HELD_OUT_FROM else "development"


def measure(registrar, kind: str, seeds, refined: bool = False, log=None, save=None) -> list:
    """Click every labelled object (>= MIN_OBJECT_POINTS) of the ``kind`` composites of
    ``seeds`` with ``registrar`` and judge the shown candidate: one record per click
    (:func:`.realdata.evaluate_scene`'s, with :func:`judge`'s verdict and ``group``
    (the kind), ``split``, ``seed``, ``base``, ``origin``, ``source``, ``shape``, ``unit``,
    ``stacked``, ``truth`` (a simulated box's or cylinder's pose and size)). A seed whose
    scene cannot be built gives one record with its ``error``. ``save``: a folder to write
    each scene into (:func:`write_labelled_pcd`, ``<kind><seed>.pcd``)."""
    records = []
    for seed in seeds:
        t0 = time.perf_counter()
        try:
            scene = composite_scene(int(seed), kind)
        except AffordanceError as exc:
            records.append(
                {"group": kind, "split": _split(int(seed)), "seed": int(seed), "error": str(exc)}
            )
            continue
        built = time.perf_counter() - t0
        if save:
            os.makedirs(save, exist_ok=True)
            write_labelled_pcd(scene.cloud, os.path.join(save, f"{scene.cloud.name}.pcd"))
        recs = evaluate_scene(registrar, scene.cloud, refined=refined, object_kinds=scene.kinds)
        for rec in recs:
            obj = scene.object(rec["object"])
            rec.update(
                group=kind,
                split=_split(int(seed)),
                seed=int(seed),
                base=scene.base,
                origin=obj.origin,
                source=obj.source,
                shape=obj.shape,
                unit=obj.unit,
                stacked=obj.stacked,
                truth=None
                if obj.T_scene_model is None
                else {
                    "T_scene_model": obj.to_dict()["T_scene_model"],
                    "dimensions": obj.dimensions,
                },
                build_s=round(built, 3),
            )
            rec.update(judge(rec))
        records += recs
        if log:
            right = sum(r["right"] for r in recs)
            wrong = sum(r["wrong_accepted"] for r in recs)
            log(
                f"{kind} {seed} (base {scene.base}, {len(scene.objects)} objects): "
                f"{len(recs)} clicks, {right} right, {wrong} wrong and accepted"
            )
    return records


def _learn_group(name: str) -> tuple[str, str]:
    return f"learn {scene_kind(name)}", "held-out" if is_held_out(name) else "tuning"


def classify_learn(records: list) -> list:
    """:func:`.realdata.evaluate_scene` records of learn scenes with their ``group`` ("learn
    <mOSD group>"), ``split`` ("tuning" | "held-out") and :func:`judge`'s verdict."""
    out = []
    for rec in records:
        rec = dict(rec)
        rec["group"], rec["split"] = _learn_group(rec["scene"])
        rec.update(origin="learn", source=f"{rec['scene']} object {rec['object']}")
        rec.update(judge(rec))
        out.append(rec)
    return out


def measure_learn(registrar, paths=None, refined: bool = False, log=None) -> list:
    """Every labelled object of the learn scenes ``paths`` (default all shared ones,
    ``osd_scene_paths()``) clicked and judged (:func:`classify_learn`)."""
    records = []
    for path in osd_scene_paths() if paths is None else paths:
        if log:
            log(f"learn {scene_name(path)} ...")
        records += evaluate_scene(registrar, path, refined=refined)
    return classify_learn(records)


def _rates(recs: list) -> dict:
    clicks = [r for r in recs if "verdict" in r]
    n = len(clicks)
    primitive = [r for r in clicks if r["object_kind"] in ("box", "cylinder")]

    def share(flags):
        flags = list(flags)
        return None if not flags else round(float(np.mean(flags)), 4)

    return {
        "clicks": n,
        "right": share(r["right"] for r in clicks),
        "right_and_accepted": share(r["right"] and r["accepted"] for r in primitive),
        "wrong_accepted": share(r["wrong_accepted"] for r in clicks),
        "specific_claims": share(r["specific_claim"] for r in clicks),
        "errors": sum(r["verdict"] == "error" for r in clicks),
        # (with --refined: the clicks whose fit, refined on the object's labelled points, still
        # fails the rule -- the rule's reach on that object, not the fitter's miss)
        "refined_fails": sum(
            bool(r.get("refined_score")) and not r["refined_score"]["passes"] for r in clicks
        ),
        "scenes_not_built": sum("verdict" not in r for r in recs),
    }


def summarize(records: list) -> dict:
    """{group: {split: rates}} with rates: ``clicks``, ``right``, ``right_and_accepted`` (of
    the boxes and cylinders), ``wrong_accepted``, ``specific_claims`` (shares), ``errors``,
    ``scenes_not_built``, ``refined_fails`` (clicks measured with ``refined`` whose fit
    refined on the object's labels fails the rule too), and the same ``by_kind`` (box,
    cylinder, other) and ``by_origin`` (base, pasted, simulated)."""
    out: dict = {}
    for group in dict.fromkeys(r["group"] for r in records):
        out[group] = {}
        for split in dict.fromkeys(r["split"] for r in records if r["group"] == group):
            recs = [r for r in records if r["group"] == group and r["split"] == split]
            rates = _rates(recs)
            rates["by_kind"] = {
                k: _rates([r for r in recs if r.get("object_kind") == k])
                for k in ("box", "cylinder", "other")
                if any(r.get("object_kind") == k for r in recs)
            }
            origins = dict.fromkeys(r.get("origin") for r in recs if r.get("origin"))
            if len(origins) > 1:
                rates["by_origin"] = {
                    o: _rates([r for r in recs if r.get("origin") == o]) for o in origins
                }
            out[group][split] = rates
    return out


def _pct(v) -> str:
    return "-" if v is None else f"{v:.0%}"


def format_lines(summary: dict) -> list:
    """One line per group and split of :func:`summarize`'s result."""
    lines = []
    for group, splits in summary.items():
        for split, r in splits.items():
            kinds = ", ".join(
                f"{k} {_pct(v['right'])} right / {_pct(v['wrong_accepted'])} wrong acc. "
                f"of {v['clicks']}"
                for k, v in r.get("by_kind", {}).items()
            )
            lines.append(
                f"trust, {group} ({split}, {r['clicks']} clicks): right {_pct(r['right'])}, "
                f"wrong and accepted {_pct(r['wrong_accepted'])}, specific claims "
                f"{_pct(r['specific_claims'])}, primitive right and accepted "
                f"{_pct(r['right_and_accepted'])}"
                + (f" ({kinds})" if kinds else "")
                + (
                    f"; on {r['refined_fails']} the fit refined on the labels fails the rule too"
                    if r.get("refined_fails")
                    else ""
                )
            )
    return lines


def composite_rows(
    library=None,
    samples: int | None = 5,
    learn_records=None,
    registrar_factory=None,
    log=None,
) -> dict:
    """The bench's trust rows (issue 59): the mixed and complex composites, ``samples``
    seeds of each of the development and held-out seeds (None: all of
    :data:`DEVELOPMENT_SEEDS` and :data:`HELD_OUT_SEEDS`), and the learn scenes -- from
    ``learn_records`` (:func:`.realdata.evaluate_scene`'s records of a run that has them),
    else measured. Returns {"summary": :func:`summarize`, "seeds": {kind: [...]}, "records"}
    ({"left_out": why} without the shared data)."""
    from ..core.registration import Registrar
    from ..core.templates import TemplateLibrary

    if not osd_scene_paths():
        return {"left_out": "no shared mOSD scenes (set AFFORDANCE_SHARED_DATA)"}
    registrar = (registrar_factory or Registrar)(
        library if library is not None else TemplateLibrary.load()
    )
    seeds = list(DEVELOPMENT_SEEDS)[:samples] + list(HELD_OUT_SEEDS)[:samples]
    records = []
    for kind in KINDS:
        if log:
            log(f"trust: {kind} composites, seeds {', '.join(map(str, seeds))} ...")
        records += measure(registrar, kind, seeds)
    if learn_records is None:
        records += measure_learn(registrar)
    else:
        records += classify_learn(learn_records)
    return {"summary": summarize(records), "seeds": {k: seeds for k in KINDS}, "records": records}


# ---------------------------------------------------------------------------- the command
def parse_seeds(text: str) -> list:
    """``"0-19,100-119"`` -> [0, ..., 19, 100, ..., 119]; :class:`AffordanceError` for
    anything else."""
    seeds = []
    for part in str(text).split(","):
        part = part.strip()
        lo, sep, hi = part.partition("-")
        if not lo.isdigit() or (sep and not hi.isdigit()):
            raise AffordanceError(f"seeds: {text!r} is not a list of N or N-M (e.g. 0-19,100)")
        a, b = int(lo), int(hi) if sep else int(lo)
        if b < a:
            raise AffordanceError(f"seeds: {part!r} runs backwards")
        seeds += range(a, b + 1)
    return seeds


def run(
    kind: str,
    seeds: str,
    out: str,
    refined: bool = False,
    save: str | None = None,
    log=None,
) -> tuple[dict, list]:
    """``affordance-registration trust``: measure the default library
    (``TemplateLibrary.load()``) on the composites of ``kind`` and ``seeds`` (N, N-M,
    comma-separated), or on the learn scenes (``kind`` "learn"); every click's record and the
    summary written to the JSON file ``out`` (atomically). Returns (summary, records). A bad
    argument or absent data raises :class:`AffordanceError` before anything is measured."""
    out = os.path.abspath(out)
    if os.path.exists(out) and not os.path.isfile(out):
        raise AffordanceError(f"{out} exists and is not a regular file")
    if not os.path.isdir(os.path.dirname(out)):
        raise AffordanceError(f"{os.path.dirname(out)}: no such folder")
    if kind not in KINDS + ("learn",):
        raise AffordanceError(f"no composite kind {kind!r} (have: {', '.join(KINDS)}, learn)")
    seeds = parse_seeds(seeds) if kind != "learn" else []
    if not osd_scene_paths():
        raise AffordanceError("no shared mOSD scenes (set AFFORDANCE_SHARED_DATA)")
    from ..core.files import write_atomically
    from ..core.registration import Registrar
    from ..core.templates import TemplateLibrary

    registrar = Registrar(TemplateLibrary.load())
    if kind == "learn":
        records = measure_learn(registrar, refined=refined, log=log)
    else:
        records = measure(registrar, kind, seeds, refined=refined, log=log, save=save)
    summary = summarize(records)
    write_atomically({out: json.dumps({"summary": summary, "records": records}, indent=1) + "\n"})
    return summary, records
