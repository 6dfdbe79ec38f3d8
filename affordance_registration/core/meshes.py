# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Mesh geometry a template needs: the closed mesh of a parametric primitive, distances from
points to a mesh's surface, and the facets an object can rest on.

Pure functions of trimesh meshes (the distances by open3d's raycasting scene); the template
object and the template file loader call them.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
import trimesh

from .transforms import axis_angle_matrix

__all__ = ["PRIMITIVES", "CYLINDER_SECTIONS", "primitive_mesh", "mesh_distance", "resting_facets"]

#: the primitive kinds and the dimensions each is fitted with (metres)
PRIMITIVES = {"box": ("x", "y", "z"), "cylinder": ("radius", "length")}
CYLINDER_SECTIONS = 48  #: facets around a primitive cylinder's mesh


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


def primitive_distance(kind: str, dimensions: Mapping, local: np.ndarray) -> np.ndarray:
    """Distance (N,) from each of ``local`` (N, 3, in the primitive's frame) to the closed
    surface of the primitive ``kind`` ("box", "cylinder") of ``dimensions`` (m): zero on a
    face, positive inside and outside. A box spans [-x/2, x/2] x [-y/2, y/2] x [0, z]; a
    cylinder radius r about z, z in [0, length]."""
    d = _face_offsets(kind, dimensions, local)[0]
    outside = np.linalg.norm(np.maximum(d, 0.0), axis=1)
    inside = np.minimum(d.max(axis=1), 0.0)
    return np.abs(outside + inside)


def primitive_outside(kind: str, dimensions: Mapping, local: np.ndarray) -> np.ndarray:
    """How far (N,) each of ``local`` (N, 3, in the primitive's frame) lies outside the solid
    primitive (as :func:`primitive_distance`): zero inside it or on it."""
    return np.linalg.norm(np.maximum(_face_offsets(kind, dimensions, local)[0], 0.0), axis=1)


def primitive_normal(kind: str, dimensions: Mapping, local: np.ndarray) -> np.ndarray:
    """The outward unit normal (N, 3) of the face of the primitive (as
    :func:`primitive_distance`) nearest each of ``local`` (N, 3): a box's side, top or base,
    a cylinder's mantle or end."""
    d, q = _face_offsets(kind, dimensions, local)
    face = np.argmax(d, axis=1)
    n = np.zeros((len(q), 3))
    rows = np.arange(len(q))
    if kind == "box":
        n[rows, face] = np.where(q[rows, face] >= 0.0, 1.0, -1.0)
        return n
    radial = q[:, :2] / np.maximum(np.linalg.norm(q[:, :2], axis=1), 1e-12)[:, None]
    mantle = face == 0
    n[mantle, :2] = radial[mantle]
    n[~mantle, 2] = np.where(q[~mantle, 2] >= 0.0, 1.0, -1.0)
    return n


def _face_offsets(kind: str, dimensions: Mapping, local: np.ndarray):
    """(how far outside each of a primitive's face pairs each point lies (N, 2 or 3; negative
    inside), the points relative to the primitive's centre line (N, 3))."""
    q = np.asarray(local, dtype=float)
    if kind == "box":
        half = 0.5 * np.array([float(dimensions[k]) for k in ("x", "y", "z")])
        c = q - np.array([0.0, 0.0, half[2]])
        return np.abs(c) - half, c
    if kind == "cylinder":
        r, length = float(dimensions["radius"]), float(dimensions["length"])
        c = q - np.array([0.0, 0.0, 0.5 * length])
        d = np.stack([np.hypot(c[:, 0], c[:, 1]) - r, np.abs(c[:, 2]) - 0.5 * length], axis=1)
        return d, c
    raise ValueError(f"unknown primitive kind {kind!r} (one of: {', '.join(PRIMITIVES)})")


def mesh_distance(mesh: trimesh.Trimesh, points: np.ndarray, signed: bool = False) -> np.ndarray:
    """Distance (N,) from each of ``points`` (N, 3) to the surface of ``mesh``; with ``signed``,
    negative inside a watertight mesh."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
    )
    query = o3d.core.Tensor(np.asarray(points, dtype=np.float32))
    if signed:
        return scene.compute_signed_distance(query).numpy().astype(float)
    return scene.compute_distance(query).numpy().astype(float)


def _cross3(a, b) -> np.ndarray:
    """``np.cross`` of two 3-vectors, the same float operations without its per-call overhead
    (resting_facets calls it for each of a few thousand hull faces at every start)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]],
        dtype=float,
    )


def resting_facets(mesh: trimesh.Trimesh) -> list[tuple[np.ndarray, float]]:
    """(R_rest, area) of every convex-hull facet the object can rest on, largest first."""
    from scipy.spatial import ConvexHull

    hull = mesh.convex_hull
    com = np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, dtype=float)
    # trimesh re-hashes a mesh on every cached-property access: read its arrays once
    hull_vertices, hull_faces, area_faces, face_normals = (
        np.asarray(a) for a in (hull.vertices, hull.faces, hull.area_faces, hull.face_normals)
    )
    in_facet = np.zeros(len(hull_faces), bool)
    groups = []
    for facet, normal in zip(hull.facets, hull.facets_normal):
        in_facet[facet] = True
        groups.append((facet, np.asarray(normal)))
    for f in np.flatnonzero(~in_facet):
        groups.append((np.array([f]), face_normals[f]))
    out = []
    for faces, normal in groups:
        verts = hull_vertices[np.unique(hull_faces[faces])]
        area = float(area_faces[faces].sum())
        if area < 1e-6:
            continue
        # centre of mass projected onto the facet plane, inside the facet polygon?
        u = _cross3(normal, (1.0, 0.0, 0.0) if abs(normal[0]) < 0.9 else (0.0, 1.0, 0.0))
        u /= np.linalg.norm(u)
        v = _cross3(normal, u)
        poly = np.stack([verts @ u, verts @ v], axis=1)
        p = np.array([com @ u, com @ v])
        if (p < poly.min(axis=0)).any() or (p > poly.max(axis=0)).any():
            continue  # outside the facet's bounding box, so outside the facet: no hull needed
        try:
            eq = ConvexHull(poly).equations
        except Exception:  # degenerate (collinear) facet
            continue
        if np.any(eq[:, :2] @ p + eq[:, 2] > -1e-4):  # not strictly inside (1e-4 m margin)
            continue
        # rotation taking the facet normal to -z
        target = np.array([0.0, 0.0, -1.0])
        axis = _cross3(normal, target)
        s_, c_ = np.linalg.norm(axis), float(normal @ target)
        if s_ < 1e-9:
            R = np.eye(3) if c_ > 0 else axis_angle_matrix([1.0, 0, 0], math.pi)
        else:
            R = axis_angle_matrix(axis, math.atan2(s_, c_))
        out.append((R, area, normal))
    out.sort(key=lambda x: -x[1])
    total = sum(a for _, a, _ in out) or 1.0
    kept = []
    for R, area, normal in out:  # one pose per resting direction (they differ by a yaw only)
        if area / total < 0.02:
            continue
        if any(normal @ n > math.cos(math.radians(15)) for _, _, n in kept):
            continue
        kept.append((R, area, normal))
    return [(R, a) for R, a, _ in kept]
