# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Fit a click on a scan file: every template of the library is fitted around the clicked point,
ranked, and judged ("does it fit?").

    python examples/fit_scan_file.py                      # a simulated scan, its first object
    python examples/fit_scan_file.py SCAN.ply X Y Z [--units mm]

Without a scan it first writes one with ``affordance-registration simulate`` (a taskboard with
ground truth) and clicks the first object of its ``truth.yaml``, then says how far the fit is from
the truth. ``affordance-registration fit --scene SCAN --point X Y Z`` does the same on the
command line.
"""

import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np
import yaml

from affordance_registration import FitSettings, Registrar, Scene, TemplateLibrary
from affordance_registration.core.transforms import pose_error

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def simulated_scan(folder: str) -> tuple[str, list, dict]:
    """A scan written by ``affordance-registration simulate``: its path, the click on its first
    object and that object's truth."""
    command = os.path.join(os.path.dirname(sys.executable), "affordance-registration")
    subprocess.run(
        [command, "simulate", "--out", folder, "--seed", "7"],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    print(f"wrote a simulated scan with ground truth into {folder}")
    with open(os.path.join(folder, "truth.yaml")) as handle:
        first = yaml.safe_load(handle)["objects"][0]
    return os.path.join(folder, "scene.ply"), first["click"], first


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scan", nargs="?", help="a PLY, PCD or organized .npy scan")
    parser.add_argument("point", nargs="*", type=float, help="the click X Y Z, in --units")
    parser.add_argument("--units", choices=UNITS, default="m", help="the scan's length unit")
    args = parser.parse_args()
    if args.scan and len(args.point) != 3:
        parser.error("give the click as X Y Z after the scan")

    with tempfile.TemporaryDirectory() as folder:
        truth = None
        if args.scan:
            path, click = args.scan, [v * UNITS[args.units] for v in args.point]
        else:
            path, click, truth = simulated_scan(folder)
        scene = Scene.from_file(path, scale=UNITS[args.units])  # metres from here on
        library = TemplateLibrary.load()  # the bundled models/; TemplateLibrary.load("DIR")
        report = Registrar(library, FitSettings()).fit(scene, click)

    print(f"{len(scene.points)} points; click at {np.round(report.point, 3).tolist()} (m)")
    for c in report.candidates[:3]:
        verdict = "fits" if c.fits else f"does not fit: {c.reason}"
        print(f"  {c.rank}. {c.template:<20} p={c.probability:.2f}  {verdict}")
    best = report.candidates[0]
    print(f"best: {best.template} at {np.round(best.T_scene_model[:3, 3], 3).tolist()} (m)")
    if truth is not None:
        T_true = np.asarray(truth["T_scene_model"], dtype=float).reshape(4, 4)
        dt, dr = pose_error(best.T_scene_model, T_true, library[truth["template"]].symmetry)
        print(
            f"truth: {truth['template']}; the best is {dt * 1000:.1f} mm and "
            f"{np.degrees(dr):.1f} deg from it"
        )


if __name__ == "__main__":
    main()
