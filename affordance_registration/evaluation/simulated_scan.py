# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Node ``affordance_simulated_scan``: publishes a simulated depth-camera scan of a taskboard on
``points`` -- a sensor for trying the engine and the browser station without one
(``affordance-registration station --demo``).

The scan is the organized cloud of :func:`~affordance_registration.evaluation.simulation.
simulate_taskboard` (NaN where the sensor saw nothing) in the camera's optical frame, published
reliable and transient-local, again whenever a subscriber joins (a volatile subscription, as the
engine's and the station's, only hears what is published after it matched), and every
1/``rate`` s when ``rate`` > 0. Parameters: ``seed`` (7), ``layout`` (panel | table), ``frame_id``
(``camera_depth_optical_frame``), ``rate`` (0 Hz: once).
"""
from __future__ import annotations

from rclpy.node import Node

from ..core.errors import AffordanceError
from ..core.templates import TemplateLibrary
from ..ros.glue.cloud_publisher import LatchedCloudPublisher
from ..ros.glue.conversions import xyz_to_pointcloud2
from ..ros.standins.spin import run_node
from .simulation import simulate_taskboard

__all__ = ["SimulatedScanNode", "main"]


class SimulatedScanNode(Node):
    def __init__(self):
        super().__init__("affordance_simulated_scan")
        seed = int(self.declare_parameter("seed", 7).value)
        layout = str(self.declare_parameter("layout", "panel").value)
        frame = str(self.declare_parameter("frame_id", "camera_depth_optical_frame").value)
        rate = float(self.declare_parameter("rate", 0.0).value)
        if seed < 0:
            raise AffordanceError(f"seed must be >= 0, got {seed}")
        if layout not in ("panel", "table"):
            raise AffordanceError(f"layout must be 'panel' or 'table', got {layout!r}")
        if not 0.0 <= rate <= 30.0:
            raise AffordanceError(f"rate must be within 0-30 Hz, got {rate}")
        sim = simulate_taskboard(TemplateLibrary.load(), seed, layout=layout)
        self.cloud = LatchedCloudPublisher(self, xyz_to_pointcloud2(sim.organized, frame))
        if rate > 0:
            self.create_timer(1.0 / rate, self.cloud.publish)
        self.get_logger().info(f"simulated {layout} scan (seed {seed}): {len(sim.points)} points "
                               f"in '{frame}' on {self.cloud.topic_name}")


def main(args=None) -> int:
    """Console script ``affordance_simulated_scan`` (takes ``--ros-args``)."""
    return run_node(SimulatedScanNode, "affordance_simulated_scan", args)


if __name__ == "__main__":
    raise SystemExit(main())
