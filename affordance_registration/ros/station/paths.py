# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station's path display: "Show path" asks the engine for the path of the selected
object's waypoint to the state typed in "Path to state" (``<engine>/path_request``, with the
object's id from the engine's status), and the engine's answer (``<engine>/path``, a PoseArray
in the cloud frame) is drawn as a polyline. A refusal (no such state...) is the engine's: the
panel shows its last error. The engine's waypoint grippers come with its markers; the page's
"Waypoints" toggle shows or hides them."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseArray
from std_msgs.msg import String

from ..glue.qos import INPUT, LATCHED
from .state import active_object

__all__ = ["StationPaths"]


class StationPaths:
    """Path requests and answers of a station node (its ``engine`` name, ``page``, the engine
    status it last took and its panel note)."""

    def __init__(self, node):
        self._node = node
        self._asked = False
        self._pub = node.create_publisher(String, f"{node.engine}/path_request", INPUT)
        node.create_subscription(PoseArray, f"{node.engine}/path", self._on_path, LATCHED)

    def request(self, state: str) -> None:
        """The "Show path" button (viser's thread)."""
        node = self._node
        obj = active_object(node._status)
        if obj is None:
            node._note("path: select an object first (click it)", failed=True)
            return
        if not state or len(state.split()) != 1 or len(state) > 64:
            node._note(
                "path: type the name of one of the object's states (e.g. closed)", failed=True
            )
            return
        self._pub.publish(String(data=f"{obj['id']} {state}"))
        self._asked = True
        node._note(f"path of object {obj['id']} to {state}: asked")

    def _on_path(self, msg: PoseArray) -> None:
        if not self._asked:  # a path another client asked for before this station ran
            return
        points = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
        self._node.page.show_path(points)
        text = f"path drawn: {len(points)} poses in '{msg.header.frame_id}'"
        self._node.get_logger().info(text)
        self._node._note(text)

    def toggled(self, shown: bool, drawn: int) -> None:
        """The "Waypoints" toggle (viser's thread)."""
        text = f"waypoints {'shown' if shown else 'hidden'} ({drawn} drawn)"
        self._node.get_logger().info(text)
        self._node._note(text)
