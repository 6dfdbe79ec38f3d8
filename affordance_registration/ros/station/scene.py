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
matched). The frame's origin is where the engine takes the scan to have been taken from (as
``fit`` without ``--sensor-origin``). A scan more than ``MM_LOOKING_EXTENT`` across given as
metres gets a warning naming ``--units``.

Parameters: ``file`` (required), ``units`` (m | cm | mm; m), ``frame_id`` (``scan``).
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node

from ...core.errors import AffordanceError
from ...core.pointfiles import read_points
from ...core.scene import MM_LOOKING_EXTENT, UNITS
from ..glue.cloud_publisher import LatchedCloudPublisher
from ..glue.conversions import xyz_to_pointcloud2
from ..standins.spin import run_node

__all__ = ["FileScanNode", "read_scan", "main"]


def read_scan(path: str, units: str) -> tuple[np.ndarray, str]:
    """(points in metres -- organized (H, W, 3) when the file is, else (N, 3) -- and a warning or
    ''). Raises AffordanceError for a file that cannot be read or unknown units."""
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
    return pts, warning


class FileScanNode(Node):
    def __init__(self):
        super().__init__("affordance_file_scan")
        path = str(self.declare_parameter("file", "").value)
        units = str(self.declare_parameter("units", "m").value)
        frame = str(self.declare_parameter("frame_id", "scan").value)
        if not frame:
            raise AffordanceError("frame_id must not be empty")
        pts, warning = read_scan(path, units)
        if warning:
            self.get_logger().warning(warning)
        self.cloud = LatchedCloudPublisher(self, xyz_to_pointcloud2(pts, frame))
        n = int(np.all(np.isfinite(pts.reshape(-1, 3)), axis=1).sum())
        self.get_logger().info(
            f"scan {path} ({units}): {n} points in '{frame}' on {self.cloud.topic_name}"
        )


def main(args=None) -> int:
    """Console script ``affordance_file_scan`` (takes ``--ros-args``)."""
    return run_node(FileScanNode, "affordance_file_scan", args)


if __name__ == "__main__":
    raise SystemExit(main())
