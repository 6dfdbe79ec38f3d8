# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Cluttered real scenes with ground truth, built from the shared real scans: the Stanford
Armadillo (or-pcd's range scans, as a point-cloud template) standing on an mOSD table among
mOSD's real objects and touching one of them, seen by a depth camera at the origin; and PCL's
milk carton in its own real Kinect scene (its true pose is the identity).

The Armadillo scene: the template's own points (``realscans.write_point_template`` of the
views), turned upright (the statue's up, ``realscans.STATUE_UP``, along the table's normal --
fitted to mOSD's table labels 1-9), a seeded turn about the normal, its lowest point on the
table plane, slid along a seeded direction towards a seeded mOSD object until it first comes
within ``CONTACT`` of an object's points. The posed points are projected with the pinhole model
the organized cloud's own pixels obey (:func:`.realdata.fit_intrinsics`) and merged per pixel
with a z-buffer: a pixel takes the Armadillo's nearest point where that is in front of the
mOSD point (or the mOSD pixel is empty); mOSD points behind the Armadillo's silhouette (its
points splatted over ``SPLAT`` pixels) are hidden, as are the Armadillo's own points behind its
front surface. Every Armadillo point in the scene is a template point moved by the true pose.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field

import numpy as np
import yaml
from scipy.ndimage import minimum_filter
from scipy.spatial import cKDTree

from ..core.errors import AffordanceError
from ..core.files import read_yaml, write_atomically
from ..core.pointfiles import read_points
from ..core.transforms import axis_angle_matrix, make_T
from .realdata import (
    SENSOR_ORIGIN,
    click_in_middle,
    fit_intrinsics,
    fit_plane,
    labelled_objects,
    read_labelled_pcd,
    shared_data_dir,
    table_points,
)

__all__ = [
    "CONTACT",
    "BODY_GAP",
    "SPLAT",
    "SELF_OCCLUSION",
    "MIN_VISIBLE",
    "ClutterScene",
    "armadillo_template",
    "armadillo_clutter",
    "MilkCase",
    "milk_carton_case",
    "milk_paths",
]

#: the Armadillo stops sliding when a point of it is this close to an object's point (m)
CONTACT = 0.004
#: the half width (pixels) of the square an Armadillo point hides behind it
SPLAT = 1
#: an Armadillo point this far (m) behind the nearest of its splats is hidden (self-occlusion)
SELF_OCCLUSION = 0.005
#: a template point is on the statue's body when its 8th nearest neighbour is this close (m)
BODY_GAP = 0.008
#: a placement is kept when at least this many Armadillo points are visible
MIN_VISIBLE = 1500


@dataclass(frozen=True)
class ClutterScene:
    """A cluttered real scene with ground truth: ``points`` (H, W, 3) organized, NaN holes
    (optical frame, metres), ``sensor_origin`` (3,), ``click`` (3,) on the Armadillo,
    ``T_scene_model`` the template's true pose, ``is_object`` (H, W) bool -- the pixels that
    hold Armadillo points -- ``labels`` (H, W) mOSD's labels with -1 at those pixels,
    ``touches`` the ids of the mOSD objects some Armadillo body point lies
    within 1 cm of, ``base`` the mOSD scene's name and ``seed``."""

    base: str
    seed: int
    points: np.ndarray = field(repr=False)
    sensor_origin: np.ndarray = field(repr=False)
    click: np.ndarray = field(repr=False)
    T_scene_model: np.ndarray = field(repr=False)
    is_object: np.ndarray = field(repr=False)
    labels: np.ndarray = field(repr=False)
    touches: tuple = ()

    @property
    def object_points(self) -> np.ndarray:
        """The Armadillo's points in the scene (M, 3)."""
        return self.points[self.is_object]


def armadillo_template(
    out_dir: str, name: str = "armadillo", views=None, voxel: float = 0.002
) -> str:
    """Write the Armadillo point-cloud template (all ground-truth views merged, the common
    frame, one point per ``voxel`` m) into ``out_dir``; returns its YAML path. ``views``:
    or-pcd's views (fetched with pip by default; :class:`AffordanceError` when pip cannot get
    them). The clutter scene is made of the template's own points: a finer ``voxel`` gives a
    denser Armadillo in it (at 2 mm it has fewer points than the camera's pixels there)."""
    from .realscans import armadillo_views, fetch_or_pcd, write_point_template

    views = armadillo_views(fetch_or_pcd()) if views is None else views
    return write_point_template(views, out_dir, name, voxel=voxel)


def _template_points(yaml_path: str) -> np.ndarray:
    doc = read_yaml(yaml_path, AffordanceError, kind="template file")
    return read_points(os.path.join(os.path.dirname(yaml_path), doc["mesh"])).points


def _upright(normal: np.ndarray, yaw: float) -> np.ndarray:
    """R_scene_model: the model's up axis (realscans.STATUE_UP) along ``normal``, turned by
    ``yaw`` about it."""
    from .realscans import STATUE_UP

    up = np.zeros(3)
    up[STATUE_UP] = 1.0
    n = normal / np.linalg.norm(normal)
    axis = np.cross(up, n)
    s, c = np.linalg.norm(axis), float(up @ n)
    R = np.eye(3) if s < 1e-9 else axis_angle_matrix(axis / s, np.arctan2(s, c))
    if s < 1e-9 and c < 0:
        R = axis_angle_matrix([1.0, 0.0, 0.0] if STATUE_UP != 0 else [0.0, 1.0, 0.0], np.pi)
    return axis_angle_matrix(n, yaw) @ R


def _render(base_pts, model_pts, intr):
    """Merge posed model points into the organized ``base_pts`` (H, W, 3) by z-buffer. Returns
    (points (H, W, 3), is_model (H, W), number of visible model points)."""
    H, W = base_pts.shape[:2]
    z = model_pts[:, 2]
    ok = z > 0.05
    u, v = intr.project(np.where(ok[:, None], model_pts, 1.0))
    col, row = np.rint(u).astype(int), np.rint(v).astype(int)
    ok &= (col >= 0) & (col < W) & (row >= 0) & (row < H)
    idx = np.flatnonzero(ok)
    pix = row[idx] * W + col[idx]
    # nearest model point per pixel, and its depth
    order = np.lexsort((z[idx], pix))
    pix_sorted, idx_sorted = pix[order], idx[order]
    first = np.r_[True, pix_sorted[1:] != pix_sorted[:-1]]
    win_pix, win_idx = pix_sorted[first], idx_sorted[first]
    zbuf = np.full(H * W, np.inf)
    zbuf[win_pix] = z[win_idx]
    # the model's silhouette hides what lies behind it over a small splat
    splat = minimum_filter(
        zbuf.reshape(H, W), size=2 * SPLAT + 1, mode="constant", cval=np.inf
    ).reshape(-1)
    visible = z[win_idx] <= splat[win_pix] + SELF_OCCLUSION
    base = base_pts.reshape(-1, 3).copy()
    base_z = np.where(np.isfinite(base[:, 2]), base[:, 2], np.inf)
    wins = visible & (z[win_idx] < base_z[win_pix])
    out = base.copy()
    hidden = np.isfinite(splat) & (splat < base_z) & np.isfinite(base_z)
    out[hidden] = np.nan
    is_model = np.zeros(H * W, bool)
    out[win_pix[wins]] = model_pts[win_idx[wins]]
    is_model[win_pix[wins]] = True
    return out.reshape(H, W, 3), is_model.reshape(H, W), int(wins.sum())


def armadillo_clutter(
    template_yaml: str, base_scene: str | None = None, seed: int = 0, tries: int = 24
) -> ClutterScene:
    """The Armadillo template (``template_yaml``, e.g. from :func:`armadillo_template`) placed
    in the mOSD scene ``base_scene`` (a path; default the shared ``learn0``) touching a real
    object (see the module docstring). Deterministic by ``seed``; raises
    :class:`AffordanceError` when no placement of ``tries`` leaves it touching an object with
    at least ``MIN_VISIBLE`` points in view."""
    if base_scene is None:
        data = shared_data_dir()
        if data is None:
            raise AffordanceError("no shared real data for the base scene")
        base_scene = os.path.join(data, "osd", "learn0.pcd")
    cloud = read_labelled_pcd(base_scene)
    intr = fit_intrinsics(cloud.points)
    normal, d = fit_plane(table_points(cloud), towards=SENSOR_ORIGIN)
    objs = labelled_objects(cloud, min_points=1)
    if not objs:
        raise AffordanceError(f"{cloud.name}: no labelled object to touch")
    flat = cloud.points.reshape(-1, 3)
    obj_ids = cloud.object_ids.reshape(-1)
    valid = cloud.valid.reshape(-1)
    others = flat[valid & (obj_ids > 0)]
    other_ids = obj_ids[valid & (obj_ids > 0)]
    tree = cKDTree(others)
    a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    table = table_points(cloud)
    table_tree = cKDTree(np.stack([table @ a, table @ b], axis=1))
    model = _template_points(template_yaml)
    # the statue's body: the range scans hold a few stray returns centimetres off it, which
    # must not decide where it rests or what it touches
    gap8, _ = cKDTree(model).query(model, k=9)
    body = gap8[:, -1] <= BODY_GAP
    rng = np.random.default_rng(seed)
    for _ in range(tries):
        R = _upright(normal, rng.uniform(0, 2 * np.pi))
        posed = model[body] @ R.T
        target = objs[int(rng.integers(len(objs)))]
        centre = flat[target.indices].mean(axis=0)
        centre = centre - normal * (normal @ centre + d)  # onto the plane
        angle = rng.uniform(0, 2 * np.pi)
        direction = np.cos(angle) * a + np.sin(angle) * b
        # on the plane: the lowest point 1 mm above it, the centroid over the sliding point
        height = 0.001 - d - float((posed @ normal).min())
        mean = posed.mean(axis=0)
        # (a step whose centroid lies farther than the body's reach plus CONTACT from every
        # object point cannot touch: only the others are queried point by point)
        reach = float(np.sqrt(((posed - mean) ** 2).sum(axis=1).max())) + CONTACT + 1e-6
        T = None
        for i, step in enumerate(np.arange(0.6, -0.003, -0.003)):  # slide in until contact
            t = centre + direction * step - mean
            t = t - normal * (t @ normal) + normal * height
            if tree.query(mean + t, distance_upper_bound=reach)[0] == np.inf:
                continue
            dist, _ = tree.query(posed + t, distance_upper_bound=CONTACT)
            if np.isfinite(dist).any():
                T = make_T(R, t) if i > 0 else None  # in contact from the start: inside
                break
        if T is None:
            continue
        pts = model @ T[:3, :3].T + T[:3, 3]
        # it stands on the table: the table was scanned under its feet (its lowest points)
        h = pts[body] @ normal + d
        feet = pts[body][h <= np.quantile(h, 0.05)]
        gap, _ = table_tree.query(np.stack([feet @ a, feet @ b], axis=1))
        if gap.max() > 0.02:
            continue
        merged, is_model, n_visible = _render(cloud.points, pts, intr)
        if n_visible < MIN_VISIBLE:
            continue
        near, which = tree.query(pts[body], distance_upper_bound=0.01)
        touches = tuple(sorted({int(other_ids[i]) for i in which[np.isfinite(near)]}))
        if not touches:
            continue
        labels = np.where(is_model, -1, cloud.labels)
        click, _ = click_in_middle(merged, is_model)
        return ClutterScene(
            cloud.name,
            seed,
            merged,
            np.asarray(cloud.viewpoint, float),
            click,
            T,
            is_model,
            labels,
            touches,
        )
    raise AffordanceError(
        f"{cloud.name}: no placement of the Armadillo touching an object "
        f"with {MIN_VISIBLE} points in view in {tries} tries (seed {seed})"
    )


# ---------------------------------------------------------------------------- the milk carton
@dataclass(frozen=True)
class MilkCase:
    """PCL's milk carton case: ``scene`` path, ``template`` (the YAML written), ``click`` (3,)
    on the carton, ``T_scene_model`` (the identity: the template is a segment of the scene),
    ``carton`` (N, 3) the template's points."""

    scene: str
    template: str
    click: np.ndarray = field(repr=False)
    T_scene_model: np.ndarray = field(repr=False)
    carton: np.ndarray = field(repr=False)


def milk_paths(data_dir: str | None = None) -> tuple[str, str] | None:
    """(scene, carton) PCD paths under ``<data>/pcl``, or None when absent."""
    data_dir = data_dir or shared_data_dir()
    if not data_dir:
        return None
    scene = os.path.join(data_dir, "pcl", "milk_cartoon_all_small_clorox.pcd")
    carton = os.path.join(data_dir, "pcl", "milk.pcd")
    return (scene, carton) if os.path.isfile(scene) and os.path.isfile(carton) else None


def milk_carton_case(
    out_dir: str, data_dir: str | None = None, name: str = "milk_carton"
) -> MilkCase:
    """Copy ``milk.pcd`` into ``out_dir`` (a temporary folder: never the project) with a
    point-cloud template YAML ``<name>.yaml`` for it; the click is the carton point nearest
    its centroid (the carton file is unorganized). Raises :class:`AffordanceError` when the
    data is absent."""
    paths = milk_paths(data_dir)
    if paths is None:
        raise AffordanceError("no shared real data (pcl/milk.pcd and its scene)")
    scene, carton = paths
    os.makedirs(out_dir, exist_ok=True)
    pcd = os.path.join(out_dir, f"{name}.pcd")
    shutil.copyfile(carton, pcd)
    doc = {
        "name": name,
        "mesh": f"{name}.pcd",
        "description": "point-cloud template: PCL's milk carton, segmented from its scene",
    }
    yml = os.path.join(out_dir, f"{name}.yaml")
    write_atomically({yml: yaml.safe_dump(doc, sort_keys=False).encode()})
    pts = read_points(pcd).points
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    click, _ = click_in_middle(pts)
    return MilkCase(scene, yml, click, np.eye(4), pts)


#: PCL's milk carton is a box under a gable roof: its body reaches this high over its base (m;
#: the eaves are at 0.20 m, the ridge at 0.245 m, by the carton's own points)
MILK_BODY = 0.19


def milk_body_on_box(
    carton: np.ndarray, T_scene_model: np.ndarray, dims, tolerance: float = 0.006
) -> tuple[float, float]:
    """How well a box (``T_scene_model``, ``dims`` {"x", "y", "z"}: the frame convention of
    :mod:`.realdata`) explains the milk ``carton`` (N, 3): (the share of its points lying
    under ``MILK_BODY`` over the box's base, the share of those within ``tolerance`` m of the
    box's surface)."""
    from .realdata import box_distance

    T = np.asarray(T_scene_model, float)
    body = (np.asarray(carton, float) - T[:3, 3]) @ T[:3, 2] < MILK_BODY
    if not body.any():
        return 0.0, 0.0
    on = box_distance(carton[body], T, dims) <= tolerance
    return float(body.mean()), float(on.mean())
