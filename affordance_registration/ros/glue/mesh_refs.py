# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Templates drawn by reference: a template read from mesh files is a ``MESH_RESOURCE`` marker
naming its file (RViz loads each file once), a primitive is a ``CUBE`` or ``CYLINDER`` at its
size, so a ``~/markers`` update carries poses, not triangles. A jointed template is two
markers: its fixed part, and its moving part at the joint's pose. Templates without files (a
scanned point cloud, a derived copy) keep their triangles (``TRIANGLE_LIST``).

The URI is ``package://affordance_registration/...`` when the file lies in the package's
share folder of a ROS install (the ament index knows it: a colcon install), else
``file://`` and the absolute path (a pip install, a checkout, a template folder of your own).
:func:`referenced_mesh` turns such a marker back into triangles, for the station."""

from __future__ import annotations

import functools
import os
from urllib.parse import unquote, urlparse

import numpy as np
import trimesh
from visualization_msgs.msg import Marker

from .conversions import ConversionError, matrix_to_pose, mesh_marker, new_marker

__all__ = ["template_markers", "mesh_uri", "referenced_mesh", "PACKAGE"]

PACKAGE = "affordance_registration"
#: the mesh files a referenced marker may name (what the template loader reads)
MESH_EXTENSIONS = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")


@functools.lru_cache(maxsize=1)
def _ament_share() -> str | None:
    """The package's share folder in the ament index (a ROS install), or None."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return os.path.abspath(get_package_share_directory(PACKAGE))
    except Exception:  # not installed with colcon (PackageNotFoundError), no ament index
        return None


def mesh_uri(path: str) -> str:
    """The URI a viewer loads ``path`` (absolute) from."""
    share = _ament_share()
    if share is not None and os.path.commonpath([share, path]) == share:
        return f"package://{PACKAGE}/{os.path.relpath(path, share)}"
    return "file://" + path


def _resource(
    uri: str, T: np.ndarray, size: float, frame: str, ns: str, marker_id: int, colour, stamp
) -> Marker:
    m = new_marker(Marker.MESH_RESOURCE, frame, ns, marker_id, stamp)
    m.pose = matrix_to_pose(T)
    m.scale.x = m.scale.y = m.scale.z = float(size)
    m.color = colour
    m.mesh_resource = uri
    return m


def _primitive(
    tpl, T: np.ndarray, scale: float, frame: str, ns: str, marker_id: int, colour, stamp
) -> Marker:
    """A box or cylinder as RViz's own shape: centred on its marker pose, so the pose is the
    template's frame (centre of the base / end face) moved half its height along +z."""
    d = {k: float(v) * scale for k, v in tpl.dimensions.items()}
    box = tpl.primitive == "box"
    m = new_marker(Marker.CUBE if box else Marker.CYLINDER, frame, ns, marker_id, stamp)
    height = d["z"] if box else d["length"]
    centre = np.eye(4)
    centre[2, 3] = height / 2
    m.pose = matrix_to_pose(T @ centre)
    m.scale.x, m.scale.y, m.scale.z = (
        (d["x"], d["y"], height) if box else (2 * d["radius"], 2 * d["radius"], height)
    )
    m.color = colour
    return m


def template_markers(
    tpl,
    T: np.ndarray,
    q: float,
    scale: float,
    frame: str,
    ns: str,
    marker_id: int,
    colour,
    moving_colour,
    stamp,
) -> list:
    """The markers that draw ``tpl`` posed at ``T`` with its joint at ``q`` and scaled by
    ``scale``: namespace ``ns`` the template (its fixed part, for a jointed one), ``ns +
    "_moving_part"`` its moving part (in ``moving_colour``)."""
    files = tpl.mesh_files
    if tpl.primitive is not None and tpl.dimensions:
        return [_primitive(tpl, T, scale, frame, ns, marker_id, colour, stamp)]
    size = tpl.mesh_scale * scale
    if files and tpl.joint is None:
        return [_resource(mesh_uri(files["mesh"]), T, size, frame, ns, marker_id, colour, stamp)]
    if files and "moving_mesh" in files:
        J = tpl.joint_transform(q).copy()
        J[:3, 3] *= scale  # the joint's motion, in the scaled template
        return [
            _resource(mesh_uri(files["base_mesh"]), T, size, frame, ns, marker_id, colour, stamp),
            _resource(
                mesh_uri(files["moving_mesh"]),
                T @ J,
                size,
                frame,
                f"{ns}_moving_part",
                marker_id,
                moving_colour,
                stamp,
            ),
        ]
    out = [mesh_marker(tpl.mesh_at(q, scale), T, frame, ns, marker_id, colour, stamp)]
    moving = tpl.moving_mesh_at(q, scale)
    if moving is not None:  # the moving part where the fit put it
        out.append(
            mesh_marker(moving, T, frame, f"{ns}_moving_part", marker_id, moving_colour, stamp)
        )
    return out


def _uri_path(uri: str) -> str:
    """The local file of a ``file://`` or ``package://`` URI (ConversionError otherwise)."""
    parsed = urlparse(uri)
    if parsed.scheme == "file":
        path = unquote(parsed.path)
    elif parsed.scheme == "package" and parsed.netloc:
        from ..standins.launcher import package_share

        try:
            share = package_share(parsed.netloc)
        except Exception as exc:
            raise ConversionError(f"mesh {uri}: package '{parsed.netloc}' not found") from exc
        path = os.path.join(share, unquote(parsed.path).lstrip("/"))
    else:
        raise ConversionError(f"mesh {uri!r}: expected a file:// or package:// URI")
    if os.path.splitext(path)[1].lower() not in MESH_EXTENSIONS:
        raise ConversionError(f"mesh {uri}: not a mesh file")
    return path


@functools.lru_cache(maxsize=64)
def _load(path: str, mtime: float) -> np.ndarray:
    try:
        geom = trimesh.load(path, process=True)
        if isinstance(geom, trimesh.Scene):
            geom = geom.dump(concatenate=True)
    except Exception as exc:
        raise ConversionError(f"mesh {path} does not load: {exc}") from None
    if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
        raise ConversionError(f"mesh {path} has no faces")
    soup = np.asarray(geom.vertices, np.float32)[np.asarray(geom.faces)].reshape(-1, 3)
    soup.setflags(write=False)
    return soup


@functools.lru_cache(maxsize=2)
def _unit_shape(kind: int) -> np.ndarray:
    shape = (
        trimesh.creation.box(extents=(1, 1, 1))
        if kind == Marker.CUBE
        else trimesh.creation.cylinder(radius=0.5, height=1.0, sections=32)
    )
    return np.asarray(shape.vertices, np.float32)[np.asarray(shape.faces)].reshape(-1, 3)


def referenced_mesh(m: Marker) -> np.ndarray:
    """The triangle corners (3F, 3) float32 of a ``MESH_RESOURCE``, ``CUBE`` or ``CYLINDER``
    marker in its own frame, its scale applied (a file is read once, again when it changes).
    ConversionError when the file cannot be found or read."""
    if m.type == Marker.MESH_RESOURCE:
        path = _uri_path(m.mesh_resource)
        try:
            soup = _load(path, os.stat(path).st_mtime)
        except OSError as exc:
            raise ConversionError(f"mesh {m.mesh_resource}: {exc.strerror}") from None
    else:
        soup = _unit_shape(m.type)
    scale = np.array([m.scale.x or 1.0, m.scale.y or 1.0, m.scale.z or 1.0], np.float32)
    return soup * scale
