# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Node ``affordance_file_scan``: publishes a scan file (PLY, PCD or organized .npy) on
``points``, scaled to metres -- the sensor of ``affordance-registration station --scene FILE``,
which starts it with an engine node and the browser station
(``launch_configs/station_scene.launch.yaml``), so a user with a file can look at it, click an
object, correct, accept and save without a sensor or any other node.

The cloud is read once with the package's point-file reader (the same checks as ``fit``: a
header that does not match the file's size, more than 10 million points or values that are not
numbers are refused with one line), multiplied by the metres per unit of ``units``, and
published reliable and transient-local in ``frame_id``, again whenever a subscriber joins (a
volatile subscription, as the engine's and the station's, only hears what is published after it
matched). The scan's own colours (a PCD's ``rgb`` / ``rgba``, a PLY's ``red green blue``) go
with it in an ``rgb`` field, so the station draws the scan as the sensor saw it. Where the scan
was taken from is the file's (a PCD's VIEWPOINT, else the frame's origin, as ``fit`` without
``--sensor-origin``): ``station --scene`` hands it to the engine and the station. A scan more
than ``MM_LOOKING_EXTENT`` across given as metres gets a warning naming ``--units``.

Parameters: ``file`` (required), ``units`` (m | cm | mm; m), ``frame_id`` (``scan``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from rclpy.node import Node

from ...core.errors import AffordanceError
from ...core.pointfiles import read_points
from ...core.scene import MM_LOOKING_EXTENT, UNITS
from ..glue.cloud_publisher import LatchedCloudPublisher
from ..glue.conversions import xyz_to_pointcloud2
from ..standins.spin import run_node

__all__ = ["FileScanNode", "ScanFile", "read_scan", "main"]


class ScanFile(NamedTuple):
    """A scan file as the station shows it."""

    #: points in metres: organized (H, W, 3) when the file is, else (N, 3)
    points: np.ndarray
    warning: str  #: a warning for the user, or ''
    colors: np.ndarray | None  #: (N, 3) uint8 RGB of the points (flattened), or None
    sensor_origin: np.ndarray  #: (3,) where it was taken from, in metres (the frame's origin)


def read_scan(path: str, units: str) -> ScanFile:
    """The scan ``path`` in ``units``. Raises AffordanceError for a file that cannot be read or
    unknown units."""
    if units not in UNITS:
        raise AffordanceError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    if not path:
        raise AffordanceError("no scan file given (parameter 'file')")
    f = read_points(path)
    pts = np.asarray(f.points, dtype=float) * UNITS[units]
    if f.organized is not None:  # an organized cloud stays one (the engine's crops)
        pts = pts.reshape(*f.organized, 3)
    flat = pts.reshape(-1, 3)
    finite = flat[np.all(np.isfinite(flat), axis=1)]
    if len(finite) == 0:
        raise AffordanceError(f"{path}: no finite points")
    extent = float(np.max(finite.max(axis=0) - finite.min(axis=0)))
    warning = ""
    if extent > MM_LOOKING_EXTENT:
        warning = (
            f"{path}: the scan is {extent:.0f} m across in '{units}', larger than a room: "
            f"if it is in millimetres or centimetres, give its units (--units mm or cm)"
        )
    origin = np.zeros(3) if f.viewpoint is None else np.asarray(f.viewpoint) * UNITS[units]
    return ScanFile(pts, warning, f.colors, origin)


class FileScanNode(Node):
    def __init__(self):
        super().__init__("affordance_file_scan")
        path = str(self.declare_parameter("file", "").value)
        units = str(self.declare_parameter("units", "m").value)
        frame = str(self.declare_parameter("frame_id", "scan").value)
        if not frame:
            raise AffordanceError("frame_id must not be empty")
        scan = read_scan(path, units)
        if scan.warning:
            self.get_logger().warning(scan.warning)
        self.cloud = LatchedCloudPublisher(
            self, xyz_to_pointcloud2(scan.points, frame, colors=scan.colors)
        )
        n = int(np.all(np.isfinite(scan.points.reshape(-1, 3)), axis=1).sum())
        self.get_logger().info(
            f"scan {path} ({units}): {n} points in '{frame}'"
            f"{'' if scan.colors is None else ' with their colours'} on {self.cloud.topic_name}"
        )


def main(args=None) -> int:
    """Console script ``affordance_file_scan`` (takes ``--ros-args``)."""
    return run_node(FileScanNode, "affordance_file_scan", args)


if __name__ == "__main__":
    raise SystemExit(main())
