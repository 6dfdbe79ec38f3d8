# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Template files: reading a template's YAML and checking every key before any work is
done, so that a broken file is refused with one line naming the file and the key.

A template is a YAML file (``models/<name>.yaml``)::

    name: ball_valve                 # required, unique in a library
    mesh: meshes/ball_valve.stl      # required, relative to the YAML; STL/OBJ/PLY mesh, or a
                                     # PLY/PCD point cloud (a scan of the object: its normals
                                     # from the file, or estimated when it has none)
    mesh_scale: 1.0                  # factor from mesh units to metres
    scale: [0.8, 1.25]               # optional: the design comes in sizes; scale is estimated
    symmetry: {axis: [0, 0, 1], order: 4}      # or {axis: [...], continuous: true}; the axis
                                     # passes through point: [x, y, z] (default the origin)
    mount: {position: [0, 0, 0], rpy: [0, 0, 0]}   # the mounting frame (default: the file's
                                     # own); ``mount: none`` for an object with no mounting side
    base_mesh: meshes/ball_valve_base.stl      # the part that does not move (with joints)
    joints:
      - {name: lever, type: revolute, axis: [0, 0, 1], origin: [0, 0, 0.085],
         lower: 0.0, upper: 1.5708, torque_limit: 15.0, moving_mesh: meshes/ball_valve_lever.stl}
    states: {open: {lever: 0.0}, closed: {lever: 1.5708}}
    waypoints:                       # end-effector poses (core.waypoints has the format)
      - {name: lever_grasp, end_effector: gripper, part: lever, position: [0.12, 0, 0.096],
         rpy: [3.141593, 0, 0], approach: {direction: [0, 0, -1], distance: 0.08}}
    description: free text

Lengths in the file -- a joint's origin, a prismatic joint's limits and its named states, the
symmetry's point, the mount's position -- are in the mesh's units (``mesh_scale`` turns them into
metres); angles are radians.

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

The frames these lengths are given in are
:mod:`~affordance_registration.core.affordance_template`'s.
"""

from __future__ import annotations

import math
import os

import numpy as np
import trimesh

from .affordance_template import MAX_SCALE, AffordanceTemplate, Joint, Symmetry, parse_scale_range
from .errors import TemplateError
from .files import read_yaml, unreadable
from .meshes import PRIMITIVES, primitive_mesh
from .neighbours import pca_normals
from .pointfiles import MAX_FILE_BYTES, check_header, read_points
from .transforms import make_T, template_vector
from .waypoints import parse_waypoints, template_orientation

__all__ = ["load_template", "MAX_TEMPLATE_SIZE"]

_KNOWN_KEYS = {
    "name",
    "mesh",
    "mesh_scale",
    "symmetry",
    "joints",
    "states",
    "description",
    "base_mesh",
    "scale",
    "allow_external_files",
    "primitive",
    "size",
    "radius",
    "length",
    "waypoints",
    "mount",
}
MIN_DIMENSION = 0.002  #: m, the smallest dimension a primitive may be given
#: bounds on what a template file may ask for, checked before any work is done
MAX_YAML_BYTES = 1_000_000
MAX_TEMPLATE_SIZE = 100.0  #: m, largest extent of a (scaled) template
MAX_SYMMETRY_ORDER = 360  #: beyond this, say ``continuous: true``
MAX_REVOLUTE = 64 * math.pi  #: rad, joint limits of a revolute joint (32 turns)
MAX_JOINTS = 16
_JOINT_KEYS = {"name", "type", "axis", "origin", "lower", "upper", "torque_limit", "moving_mesh"}


def load_template(path: str) -> AffordanceTemplate:
    """Load one template YAML file. Raises :class:`TemplateError` naming the file and key."""
    path = str(path)
    try:
        return _load_template(path)
    except OverflowError:  # an integer of hundreds of digits, wherever it is
        raise TemplateError(f"{path}: a number too large for a float (beyond 1.8e308)") from None


def _load_template(path: str) -> AffordanceTemplate:
    doc = read_yaml(path, TemplateError, max_bytes=MAX_YAML_BYTES, kind="template file")
    if not isinstance(doc, dict):
        raise TemplateError(f"{path}: expected a mapping with at least 'name' and 'mesh'")
    unknown = set(doc) - _KNOWN_KEYS
    if unknown:
        raise _fail(
            path, sorted(unknown)[0], f"unknown key (known: {', '.join(sorted(_KNOWN_KEYS))})"
        )
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
    if (
        isinstance(scale, bool)
        or not isinstance(scale, (int, float))
        or not math.isfinite(scale)
        or not 1 / MAX_SCALE <= scale <= MAX_SCALE
    ):
        raise _fail(
            path,
            "mesh_scale",
            f"expected a number in [{1 / MAX_SCALE:g}, {MAX_SCALE:g}], got {scale!r}",
        )
    external = doc.get("allow_external_files", False)
    if external not in (True, False):
        raise _fail(path, "allow_external_files", f"expected true or false, got {external!r}")
    mesh, points, normals = _load_geometry(path, "mesh", doc["mesh"], float(scale), external)
    symmetry = _parse_symmetry(path, doc.get("symmetry"), float(scale))
    mount = _parse_mount(path, doc, mesh is not None, float(scale))
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
            scale_range = parse_scale_range(doc["scale"])
        except ValueError as exc:
            raise _fail(path, "scale", str(exc)) from None
    if joints and base is None:
        raise _fail(path, "base_mesh", "a template with joints needs the fixed part's mesh")
    waypoints = parse_waypoints(path, doc.get("waypoints"), joints, float(scale))
    tpl = AffordanceTemplate(
        name=name.strip(),
        path=path,
        mesh=mesh,
        points=points,
        point_normals=normals,
        mesh_scale=float(scale),
        symmetry=symmetry,
        joints=joints,
        states=states,
        description=description,
        base_mesh=base,
        scale_range=scale_range,
        waypoints=waypoints,
        mount=mount,
    )
    if mesh is not None and len(joints) <= 1:
        files = {"mesh": doc["mesh"]}
        if joints:
            files.update(base_mesh=doc["base_mesh"], moving_mesh=doc["joints"][0]["moving_mesh"])
        tpl.mesh_files = {
            key: os.path.abspath(_geometry_path(path, key, rel, external))
            for key, rel in files.items()
        }
    return tpl


def _primitive_template(path: str, doc: dict, name: str, description: str) -> AffordanceTemplate:
    """A ``primitive:`` template: the kind and its dimension ranges checked, its mesh at the
    middle of the ranges."""
    kind = doc.get("primitive")
    if kind not in PRIMITIVES:
        raise _fail(path, "primitive", f"expected one of {', '.join(PRIMITIVES)}, got {kind!r}")
    other = sorted(
        set(doc)
        & {"mesh", "mesh_scale", "base_mesh", "joints", "states", "scale", "symmetry", "mount"}
    )
    if other:
        raise _fail(
            path,
            other[0],
            "a primitive template has dimensions and its own frame, not a mesh, joints, a "
            "symmetry, a mount or a scale range",
        )
    given = {"box": ("size",), "cylinder": ("radius", "length")}[kind]
    stray = sorted(set(doc) & {"size", "radius", "length"} - set(given))
    if stray:
        raise _fail(path, stray[0], f"not a dimension of a {kind} (it has {', '.join(given)})")
    if kind == "box":
        size = doc.get("size")
        if not isinstance(size, dict) or set(size) != {"x", "y", "z"}:
            raise _fail(
                path,
                "size",
                f"expected {{x: [min, max], y: [min, max], z: [min, max]}} "
                f"in metres, got {size!r}",
            )
        specs = {f"size.{k}": size[k] for k in "xyz"}
    else:
        specs = {k: doc.get(k) for k in ("radius", "length")}
    ranges = {}
    for key, value in specs.items():
        try:
            if isinstance(value, (str, bytes)):  # ("12" is not [1, 2])
                raise TypeError
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError, OverflowError):
            raise _fail(path, key, f"expected [min, max] in metres, got {value!r}") from None
        if not (
            math.isfinite(lo)
            and math.isfinite(hi)
            and MIN_DIMENSION <= lo <= hi
            and hi <= MAX_TEMPLATE_SIZE
        ):
            raise _fail(
                path,
                key,
                f"expected {MIN_DIMENSION} <= min <= max <= "
                f"{MAX_TEMPLATE_SIZE:.0f} (metres), got {value!r}",
            )
        ranges[key.split(".")[-1]] = (lo, hi)
    middle = {k: 0.5 * (lo + hi) for k, (lo, hi) in ranges.items()}
    symmetry = Symmetry(order=2) if kind == "box" else Symmetry(continuous=True)
    waypoints = parse_waypoints(path, doc.get("waypoints"), (), 1.0, primitive=kind)
    return AffordanceTemplate(
        name,
        path,
        primitive_mesh(kind, middle),
        symmetry=symmetry,
        description=description,
        primitive=kind,
        dimension_ranges=ranges,
        dimensions=middle,
        waypoints=waypoints,
    )


def _fail(path: str, key: str, msg: str) -> TemplateError:
    return TemplateError(f"{path}: key '{key}': {msg}")


def _vector(path: str, key: str, value, length: int = 3) -> tuple:
    return tuple(
        float(v) for v in template_vector(value, key, lambda k, m: _fail(path, k, m), length)
    )


def _geometry_path(yaml_path: str, key: str, rel, allow_external: bool) -> str:
    """The file a template key names: relative to the YAML, and inside the YAML's folder unless
    the template says ``allow_external_files: true``.

    The check follows symlinks: the file's real path must lie in the real path of the YAML's
    folder, or -- for a YAML that is itself a symlink, as in a ``colcon build --symlink-install``
    share folder, where every file is linked on its own -- in the folder of the YAML's real file.
    A path that resolves anywhere else is refused."""
    if not isinstance(rel, str) or not rel:
        raise _fail(yaml_path, key, "expected a file path relative to the YAML file")
    if "\x00" in rel:  # (no file system takes one: os.path raises ValueError)
        raise _fail(yaml_path, key, f"{rel!r} holds a NUL character: no file has such a name")
    folder = os.path.dirname(os.path.abspath(yaml_path))
    path = os.path.join(folder, rel)
    if not allow_external:
        real = os.path.realpath(path)
        roots = {os.path.realpath(folder), os.path.dirname(os.path.realpath(yaml_path))}
        if not any(os.path.commonpath([real, root]) == root for root in roots):
            raise _fail(
                yaml_path,
                key,
                f"{rel} is outside the template's folder {folder} "
                f"(set 'allow_external_files: true' to allow that)",
            )
    why = unreadable(path)
    if why is not None:
        raise _fail(yaml_path, key, f"{path}: {why}")
    if os.path.getsize(path) > MAX_FILE_BYTES:
        raise _fail(yaml_path, key, f"{path} is larger than {MAX_FILE_BYTES / 1e9:.0f} GB")
    return path


def _load_geometry(yaml_path: str, key: str, rel: str, scale: float, allow_external: bool = False):
    """Load a mesh, or a point cloud (a PCD, or a PLY without faces: a scan of the object, read
    like a scene); returns (mesh or None, points or None, normals or None)."""
    path = _geometry_path(yaml_path, key, rel, allow_external)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".stl", ".obj", ".ply", ".pcd", ".off", ".glb", ".gltf"):
        raise _fail(yaml_path, key, f"unsupported file type '{ext}' (STL, OBJ, PLY, PCD)")
    fail = lambda msg: _fail(yaml_path, key, msg)
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
        raise _fail(
            yaml_path,
            key,
            f"the geometry is {size:.3g} m across, more than the "
            f"{MAX_TEMPLATE_SIZE:.0f} m a template may be (mesh_scale "
            f"converts its units to metres)",
        )


def _estimate_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals of a scanned object by local PCA, oriented away from the centroid."""
    normals = pca_normals(points, 16)
    inward = np.einsum("ni,ni->n", normals, points - points.mean(axis=0)) < 0
    normals[inward] *= -1
    return normals


def _parse_symmetry(path: str, value, scale: float = 1.0) -> Symmetry | None:
    """The ``symmetry`` key: an axis (through ``point``, file units, default the origin) with an
    order or ``continuous: true``."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise _fail(
            path, "symmetry", f"expected a mapping like {{axis: [0,0,1], order: 4}}, got {value!r}"
        )
    unknown = set(value) - {"axis", "order", "continuous", "point"}
    if unknown:
        raise _fail(
            path,
            "symmetry",
            f"unknown symmetry form: keys {sorted(unknown)} "
            f"(use axis with order N or continuous: true, and optionally point)",
        )
    axis = _vector(path, "symmetry.axis", value.get("axis", [0, 0, 1]))
    if np.linalg.norm(axis) < 1e-9:
        raise _fail(path, "symmetry.axis", "axis must not be zero")
    axis = tuple(float(v) for v in np.asarray(axis) / np.linalg.norm(axis))
    point = tuple(
        v * scale for v in _vector(path, "symmetry.point", value.get("point", [0, 0, 0]))
    )
    continuous = value.get("continuous", False)
    if continuous not in (True, False):
        raise _fail(path, "symmetry.continuous", f"expected true or false, got {continuous!r}")
    if continuous:
        if "order" in value:
            raise _fail(path, "symmetry", "give either order or continuous, not both")
        return Symmetry(axis=axis, continuous=True, point=point)
    order = value.get("order")
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise _fail(path, "symmetry.order", f"expected an integer >= 1, got {order!r}")
    if order > MAX_SYMMETRY_ORDER:
        raise _fail(
            path,
            "symmetry.order",
            f"{order} is more than {MAX_SYMMETRY_ORDER}: for a "
            f"shape that looks the same at every angle use "
            f"'continuous: true'",
        )
    return Symmetry(axis=axis, order=order, point=point)


_MOUNT_KEYS = {"position", "rpy", "quaternion"}


def _parse_mount(path: str, doc: dict, is_mesh: bool, scale: float):
    """The ``mount`` key: the mounting frame (4, 4; ``position`` in file units, ``rpy`` or
    ``quaternion``), None for ``mount: none``; left out, the file's frame for a mesh and none
    for a point cloud."""
    if "mount" not in doc:
        return np.eye(4) if is_mesh else None
    value = doc["mount"]
    if value == "none":
        return None
    if not isinstance(value, dict) or not value:
        raise _fail(
            path,
            "mount",
            f"expected {{position: [x, y, z], rpy: [r, p, y]}} or none, got {value!r}",
        )
    unknown = set(value) - _MOUNT_KEYS
    if unknown:
        raise _fail(
            path,
            "mount",
            f"unknown keys {sorted(unknown)} (known: {', '.join(sorted(_MOUNT_KEYS))})",
        )
    R = template_orientation(value, "mount", lambda k, m: _fail(path, k, m))
    position = _vector(path, "mount.position", value.get("position", [0, 0, 0]))
    return make_T(R, np.asarray(position) * scale)


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
            raise _fail(
                path,
                f"{key}.lower/upper",
                f"limits inverted or empty: lower={lower} must be below upper={upper}",
            )
        reach = MAX_REVOLUTE if jtype == "revolute" else MAX_TEMPLATE_SIZE / scale
        if max(abs(lower), abs(upper)) > reach:
            raise _fail(
                path,
                f"{key}.lower/upper",
                f"limits beyond ±{reach:.4g} ({'rad' if jtype == 'revolute' else 'mesh units'}):"
                f" lower={lower}, upper={upper}",
            )
        torque = spec.get("torque_limit")
        if torque is not None:
            try:
                torque = float(torque)
            except (TypeError, ValueError):
                raise _fail(
                    path, f"{key}.torque_limit", f"expected a number, got {torque!r}"
                ) from None
            if not torque > 0:
                raise _fail(path, f"{key}.torque_limit", "must be positive")
        if "moving_mesh" not in spec:
            raise _fail(path, f"{key}.moving_mesh", "missing: the moving part's mesh is required")
        moving, _, _ = _load_geometry(
            path, f"{key}.moving_mesh", spec["moving_mesh"], scale, external
        )
        if moving is None:
            raise _fail(path, f"{key}.moving_mesh", "the moving part must be a mesh")
        if jtype == "prismatic":
            lower_o, upper_o = lower * scale, upper * scale
        else:
            lower_o, upper_o = lower, upper
        joints.append(
            Joint(
                name=name,
                type=jtype,
                axis=tuple(float(v) for v in axis / np.linalg.norm(axis)),
                origin=tuple(float(v) * scale for v in origin),
                lower=lower_o,
                upper=upper_o,
                torque_limit=torque,
                moving_mesh=moving,
            )
        )
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
        if not values:
            raise _fail(
                path,
                f"states.{state}",
                "names no joint value: a state is joint values such as {lever: 1.5708}",
            )
        states[str(state)] = checked = {}
        for jname, v in values.items():
            if jname not in by_name:
                raise _fail(path, f"states.{state}.{jname}", "no joint of that name")
            joint = by_name[jname]
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise _fail(
                    path, f"states.{state}.{jname}", f"expected a number, got {v!r}"
                ) from None
            unit = scale if joint.type == "prismatic" else 1.0
            tol = 1e-6 * max(1.0, abs(joint.upper - joint.lower))
            if not joint.lower - tol <= v * unit <= joint.upper + tol:
                raise _fail(
                    path,
                    f"states.{state}.{jname}",
                    f"{v} is outside the joint limits [{joint.lower / unit:.6g}, "
                    f"{joint.upper / unit:.6g}]",
                )
            checked[jname] = v * unit
    return states
