# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Path requests of the engine node: ``~/path_request`` (std_msgs/String ``"ID STATE"`` or
``"ID STATE WAYPOINT"``) is answered on ``~/path`` (geometry_msgs/PoseArray, latched, in the cloud
frame; a registration's own frame, where it was registered in another): the path of the waypoint
of object ID (a registration, or an open object's shown candidate) from its joint value to the
named state -- the approach pose, the waypoint along the joint, the retreat
(``core.waypoints``). A request that cannot be answered (an unknown object, state or waypoint, a
malformed line) is refused in one line: logged, and the status's ``node.last_error``; an answer
is the status's ``node.last_message``.

A topic pair rather than a service: the pip-only install has no service type taking a request
line and answering poses (no nav_msgs, and std_srvs' types carry no arguments); the request is
answered from the engine's state as it is, in the executor thread (it is a few hundred poses at
most, no fitting)."""

from __future__ import annotations

from geometry_msgs.msg import PoseArray
from std_msgs.msg import String

from ...core.errors import AffordanceError, bounded
from .conversions import matrix_to_pose
from .qos import INPUT, LATCHED

__all__ = ["PathRequests", "parse_path_request", "path_message"]

MAX_REQUEST = 256


def parse_path_request(text: str) -> tuple:
    """(object id, state, waypoint or None) of a request line; AffordanceError saying what
    the line should be."""
    if len(text) > MAX_REQUEST:
        raise AffordanceError(f"the request has {len(text):,} characters (at most {MAX_REQUEST})")
    words = text.split()
    if len(words) not in (2, 3) or not (words[0].isascii() and words[0].isdigit()):
        raise AffordanceError(
            f"expected 'OBJECT_ID STATE [WAYPOINT]' (e.g. '1 closed'), got {bounded(text, 80)!r}"
        )
    return int(words[0]), words[1], (words[2] if len(words) == 3 else None)


def path_message(trajectory, frame: str, stamp) -> PoseArray:
    """The poses of a :class:`~affordance_registration.core.waypoints.Trajectory` as a
    PoseArray in ``frame``."""
    msg = PoseArray()
    msg.header.frame_id, msg.header.stamp = frame, stamp
    msg.poses = [matrix_to_pose(T) for T in trajectory.poses]
    return msg


class PathRequests:
    """The request subscription and the answer publisher of an engine node: requests answered
    from ``engine``, in ``frame()`` (the frame the node reports in), what came of each put into
    ``outbox``."""

    def __init__(self, node, engine, outbox, frame):
        self._node, self._engine, self._outbox, self._frame = node, engine, outbox, frame
        self._pub = node.create_publisher(PoseArray, "~/path", LATCHED)
        self._sub = node.create_subscription(String, "~/path_request", self._on_request, INPUT)

    def _on_request(self, msg: String) -> None:
        engine = self._engine
        try:
            object_id, state, waypoint = parse_path_request(msg.data)
            path = engine.trajectory(object_id, state, waypoint)
        except AffordanceError as exc:
            self._outbox.outcome("path", False, f"path request refused: {exc}")
            return
        # a registration keeps the frame it was registered in (the cloud's may have changed)
        frame = getattr(engine.state.fit_of(object_id), "frame_id", "") or self._frame()
        self._pub.publish(path_message(path, frame, self._node.get_clock().now().to_msg()))
        self._outbox.outcome(
            "path",
            True,
            f"path of object {object_id}'s {path.waypoint} to "
            f"{path.state}: {len(path.poses)} poses on ~/path",
        )
