# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Your own template library: a folder of template YAML files, each naming its mesh.

    python examples/own_library.py [FOLDER]

Makes a library of one template -- a rotary switch: a box with a knob, as an STL mesh made with
trimesh, and ``rotary_switch.yaml`` naming it -- in FOLDER (default: a temporary folder), loads it
as the fitter does (``--templates FOLDER`` on the command line, the node's ``templates_dir``),
renders a simulated scan of it mounted on a panel and fits a click on it. docs/TEMPLATES.md has
every key a template file may hold (joints, states, symmetry, waypoints, primitives).
"""

import os
import sys
import tempfile

import numpy as np
import trimesh

from affordance_registration import FitSettings, Registrar, Scene, TemplateLibrary
from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import simulate_taskboard

TEMPLATE = """\
name: rotary_switch
mesh: rotary_switch.stl
mesh_scale: 0.001      # the mesh is in millimetres
description: a switch box 90 x 60 x 40 mm with its knob off centre
"""


def write_library(folder: str) -> None:
    """The template's mesh, in its frame: origin at the centre of the mounting base, +z out of
    the wall."""
    body = trimesh.creation.box(extents=[90, 60, 40])
    body.apply_translation([0, 0, 20])  # its back face on the wall (z = 0)
    knob = trimesh.creation.cylinder(radius=12, height=25)
    knob.apply_translation([25, 0, 40 + 12.5])  # out of the front face, off centre
    switch = trimesh.boolean.union([body, knob])
    switch.export(os.path.join(folder, "rotary_switch.stl"))
    with open(os.path.join(folder, "rotary_switch.yaml"), "w") as handle:
        handle.write(TEMPLATE)


def main(folder: str) -> None:
    write_library(folder)
    print(f"library: {sorted(os.listdir(folder))} in {folder}")
    library = TemplateLibrary.load(folder)  # every *.yaml of the folder; errors name file and key
    switch = library["rotary_switch"]
    print(f"loaded {list(library)}: {switch.description}")

    scan = simulate_taskboard(library, 3)  # a simulated depth camera looking at a panel with it
    truth = scan.objects[0]
    report = Registrar(library, FitSettings()).fit(Scene(scan.points), truth.click)
    best = report.candidates[0]
    dt, dr = pose_error(best.T_scene_model, truth.T_scene_model, switch.symmetry)
    print(f"clicked at {np.round(truth.click, 3).tolist()}: {best.template}, fits: {best.fits}")
    print(f"pose error {dt * 1000:.1f} mm, {np.degrees(dr):.1f} deg")


if __name__ == "__main__":
    if len(sys.argv) > 1:
        os.makedirs(sys.argv[1], exist_ok=True)
        main(sys.argv[1])
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(tmp)
