# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Generator of the taskboard template library (the five objects of the paper's ISS taskboard).

The meshes in ``models/meshes`` and the YAML files in ``models/`` are produced by
:func:`write_library` and committed; run ``affordance-registration generate-models --out models``
(or ``make models``) after changing a shape here.

Frame convention for every template: origin at the centre of the mounting base, +z pointing out of
the mounting surface, units metres. Shapes share their mounting flange and bonnet proportions so
the three valves are confusable from a distance (ranking matters) but differ in their handles.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import trimesh
import yaml

from ..core.files import write_atomically

__all__ = ["TemplateSpec", "taskboard_specs", "write_library"]


@dataclass
class TemplateSpec:
    """One generated template: its fixed part, optional moving part and the YAML metadata."""

    name: str
    description: str
    base: trimesh.Trimesh
    moving: trimesh.Trimesh | None = None
    symmetry: dict | None = None
    joint: dict | None = None
    states: dict = field(default_factory=dict)
    scale: tuple | None = None
    waypoints: list = field(default_factory=list)  #: the YAML's ``waypoints`` entries

    def full_mesh(self) -> trimesh.Trimesh:
        """The whole object at joint value zero (watertight union of the parts)."""
        if self.moving is None:
            return self.base
        return _union([self.base, self.moving])


def _cyl(radius: float, z0: float, z1: float, x: float = 0.0, y: float = 0.0, sections: int = 48):
    """Cylinder along z from z0 to z1 centred on (x, y)."""
    mesh = trimesh.creation.cylinder(radius=radius, height=z1 - z0, sections=sections)
    mesh.apply_translation([x, y, 0.5 * (z0 + z1)])
    return mesh


def _cyl_x(radius: float, x0: float, x1: float, z: float, y: float = 0.0, sections: int = 32):
    """Cylinder along x from x0 to x1 at height z."""
    mesh = trimesh.creation.cylinder(radius=radius, height=x1 - x0, sections=sections)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
    mesh.apply_translation([0.5 * (x0 + x1), y, z])
    return mesh


def _box(extents, center, yaw: float = 0.0):
    mesh = trimesh.creation.box(extents=extents)
    if yaw:
        mesh.apply_transform(trimesh.transformations.rotation_matrix(yaw, [0, 0, 1]))
    mesh.apply_translation(center)
    return mesh


def _union(parts) -> trimesh.Trimesh:
    mesh = trimesh.boolean.union(parts, engine="manifold")
    mesh.merge_vertices()
    if not mesh.is_watertight:
        raise RuntimeError("generated mesh is not watertight")
    return mesh


#: roll of half a turn: the gripper's z (its approach) along the template's -z, into the panel
DOWN = [round(math.pi, 6), 0, 0]


def _grasp(
    name: str,
    position,
    part: str | None = None,
    distance: float | None = 0.08,
    effector: str = "gripper",
    rpy=None,
    direction=(0, 0, -1),
    pitch: float | None = None,
) -> dict:
    """A waypoint entry: approached along ``direction`` (default: into the panel) by
    ``distance`` (None: no approach); ``pitch``: its part turns as it travels (a screw)."""
    wp: dict = {"name": name, "end_effector": effector}
    if part:
        wp["part"] = part
    wp["position"] = [round(float(v), 6) for v in position]
    wp["rpy"] = list(rpy or DOWN)
    if distance is not None:
        wp["approach"] = {"direction": list(direction), "distance": distance}
    if pitch is not None:
        wp["pitch"] = pitch
    return wp


def _flange():
    """The mounting flange shared by the three valves (r 45 mm, 12 mm thick)."""
    return _cyl(0.045, 0.0, 0.012)


def gate_valve() -> TemplateSpec:
    base = _union(
        [
            _flange(),
            _cyl(0.028, 0.010, 0.075),  # bonnet
            _cyl(0.018, 0.073, 0.090),  # packing nut
        ]
    )
    wheel_z = 0.130
    moving = _union(
        [
            _cyl(0.006, 0.085, 0.145),  # rising stem
            _cyl(0.014, wheel_z - 0.008, wheel_z + 0.008),  # hub
            trimesh.creation.torus(
                major_radius=0.075, minor_radius=0.007, major_sections=64, minor_sections=16
            ).apply_translation([0, 0, wheel_z]),
            _box([0.150, 0.010, 0.008], [0, 0, wheel_z]),
            _box([0.150, 0.010, 0.008], [0, 0, wheel_z], yaw=math.pi / 2),
        ]
    )
    return TemplateSpec(
        name="gate_valve",
        description="Rising-stem gate valve with a four-spoke handwheel (150 mm). The stem and "
        "wheel rise by up to 30 mm as the valve opens. Waypoint rim_grasp: the "
        "gripper on top of the wheel rim, approached from the front; the wheel "
        "turns once per 4 mm of rise (counter-clockwise seen from the front to "
        "open), so the path to open or closed is a helix of up to 7.5 turns.",
        base=base,
        moving=moving,
        symmetry={"axis": [0, 0, 1], "order": 4},
        joint={
            "name": "stem",
            "type": "prismatic",
            "axis": [0, 0, 1],
            "origin": [0, 0, 0.085],
            "lower": 0.0,
            "upper": 0.030,
            "torque_limit": 60.0,
        },
        states={"closed": {"stem": 0.0}, "open": {"stem": 0.030}},
        waypoints=[_grasp("rim_grasp", [0.075, 0, wheel_z + 0.007], part="stem", pitch=0.004)],
    )


def ball_valve() -> TemplateSpec:
    base = _union(
        [
            _flange(),
            _cyl(0.032, 0.010, 0.068),  # body
            _cyl_x(0.020, -0.058, 0.058, z=0.036),  # pipe ports along x
            _cyl(0.010, 0.066, 0.085),  # stem collar
        ]
    )
    moving = _union(
        [
            _cyl(0.013, 0.084, 0.094),  # lever nut
            _box([0.160, 0.022, 0.006], [0.065, 0, 0.089]),  # lever
            _box([0.050, 0.028, 0.014], [0.120, 0, 0.089]),  # grip sleeve
        ]
    )
    return TemplateSpec(
        name="ball_valve",
        description="Quarter-turn ball valve with a 145 mm lever handle; lever along the pipe "
        "means open, across it closed. Waypoint lever_grasp: the gripper on the "
        "lever's grip sleeve, approached from the front; it turns with the lever, "
        "so the path to closed or open is the quarter circle about the stem.",
        base=base,
        moving=moving,
        symmetry=None,
        joint={
            "name": "lever",
            "type": "revolute",
            "axis": [0, 0, 1],
            "origin": [0, 0, 0.085],
            "lower": 0.0,
            "upper": math.pi / 2,
            "torque_limit": 15.0,
        },
        states={"open": {"lever": 0.0}, "closed": {"lever": round(math.pi / 2, 6)}},
        waypoints=[_grasp("lever_grasp", [0.120, 0, 0.096], part="lever")],
    )


def quarter_turn_valve() -> TemplateSpec:
    base = _union(
        [
            _flange(),
            _cyl(0.030, 0.010, 0.062),  # body
            _cyl_x(0.014, -0.050, 0.050, z=0.034),  # pipe ports along x (show the handle's zero)
            _cyl(0.012, 0.060, 0.076),  # collar
        ]
    )
    moving = _union(
        [
            _cyl(0.014, 0.075, 0.100),  # hub
            _cyl_x(0.008, -0.062, 0.062, z=0.093),  # T bar
        ]
    )
    return TemplateSpec(
        name="quarter_turn_valve",
        description="Plug valve with a 124 mm T handle; handle along the pipe means open, a "
        "quarter turn across it closed. Waypoint handle_grasp: the gripper on one arm of the "
        "T, approached from the front; the path to closed or open is the quarter "
        "circle about the plug.",
        base=base,
        moving=moving,
        symmetry={"axis": [0, 0, 1], "order": 2},
        joint={
            "name": "handle",
            "type": "revolute",
            "axis": [0, 0, 1],
            "origin": [0, 0, 0.075],
            "lower": 0.0,
            "upper": math.pi / 2,
            "torque_limit": 10.0,
        },
        states={"open": {"handle": 0.0}, "closed": {"handle": round(math.pi / 2, 6)}},
        waypoints=[_grasp("handle_grasp", [0.045, 0, 0.101], part="handle")],
    )


def emergency_stop() -> TemplateSpec:
    base = _union(
        [
            _box([0.080, 0.080, 0.060], [0, 0, 0.030]),  # housing
            _cyl(0.032, 0.058, 0.068),  # guard collar
        ]
    )
    dome = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    dome.apply_scale([0.028, 0.028, 0.010])
    dome.apply_translation([0, 0, 0.090])
    moving = _union(
        [
            _cyl(0.014, 0.066, 0.082),  # plunger
            _cyl(0.028, 0.080, 0.090),  # mushroom rim
            dome,
        ]
    )
    return TemplateSpec(
        name="emergency_stop",
        description="Emergency stop: 80 mm square housing with a 56 mm mushroom button that "
        "latches 8 mm in when pressed. Waypoint push: the end effector on the "
        "button's dome, approached along the button's axis; the path to pressed "
        "is the 8 mm press.",
        base=base,
        moving=moving,
        symmetry={"axis": [0, 0, 1], "order": 4},
        joint={
            "name": "button",
            "type": "prismatic",
            "axis": [0, 0, -1],
            "origin": [0, 0, 0.068],
            "lower": 0.0,
            "upper": 0.008,
            "torque_limit": 40.0,
        },
        states={"released": {"button": 0.0}, "pressed": {"button": 0.008}},
        waypoints=[_grasp("push", [0, 0, 0.100], part="button")],
    )


def grab_handle() -> TemplateSpec:
    parts = []
    for x in (-0.100, 0.100):
        parts.append(_cyl(0.018, 0.0, 0.006, x=x))  # foot
        parts.append(_cyl(0.011, 0.004, 0.062, x=x))  # standoff
    parts.append(_cyl_x(0.012, -0.112, 0.112, z=0.060))  # bar
    return TemplateSpec(
        name="grab_handle",
        description="U-shaped grab handle: a 24 mm bar on two standoffs 200 mm apart. Waypoints "
        "bar_grasp (the gripper on the bar's middle, approached from the front) "
        "and bar_pull (the same grasp pulled 100 mm out from the panel).",
        base=_union(parts),
        symmetry={"axis": [0, 0, 1], "order": 2},
        waypoints=[
            _grasp("bar_grasp", [0, 0, 0.072]),
            _grasp("bar_pull", [0, 0, 0.172], distance=None),
        ],
    )


def taskboard_specs() -> list[TemplateSpec]:
    """The five taskboard templates, in a fixed order."""
    return [gate_valve(), ball_valve(), quarter_turn_valve(), emergency_stop(), grab_handle()]


def write_library(out_dir: str) -> list[str]:
    """Write every taskboard template (STL meshes + YAML) into ``out_dir``; returns YAML paths.
    The library's files land together (atomically): where one cannot be written (a folder or
    a FIFO in its place, a full disk), none is."""
    written, files = [], {}
    for spec in taskboard_specs():
        doc: dict = {
            "name": spec.name,
            "description": spec.description,
            "mesh": f"meshes/{spec.name}.stl",
            "mesh_scale": 1.0,
        }
        files[os.path.join(out_dir, doc["mesh"])] = spec.full_mesh().export(file_type="stl")
        if spec.scale:
            doc["scale"] = list(spec.scale)
        if spec.symmetry:
            doc["symmetry"] = spec.symmetry
        if spec.joint:
            base_name = f"meshes/{spec.name}_base.stl"
            moving_name = f"meshes/{spec.name}_{spec.joint['name']}.stl"
            files[os.path.join(out_dir, base_name)] = spec.base.export(file_type="stl")
            files[os.path.join(out_dir, moving_name)] = spec.moving.export(file_type="stl")
            doc["base_mesh"] = base_name
            joint = dict(spec.joint)
            joint["moving_mesh"] = moving_name
            doc["joints"] = [joint]
            doc["states"] = spec.states
        if spec.waypoints:
            doc["waypoints"] = spec.waypoints
        text = "# Generated by affordance_registration.evaluation.taskboard; edit the generator.\n"
        text += yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
        path = os.path.join(out_dir, f"{spec.name}.yaml")
        files[path] = text
        written.append(path)
    write_atomically(files)
    return written
