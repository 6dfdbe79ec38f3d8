"""Frame graphs for clicks and view poses: the latest transforms heard on /tf and /tf_static
(``ros/tf.py`` fills one) and the static transforms given as a parameter (the fallback).

A static transform parameter entry is a string ``"parent child x y z qx qy qz qw"`` (metres,
unit quaternion): the pose of ``child`` in ``parent``, as ``ros2 run tf2_ros
static_transform_publisher`` takes it. Chains are followed in either direction.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from ..core.errors import AffordanceError
from ..core.transforms import invert, make_T, quat_xyzw_to_matrix

__all__ = ["FrameGraph", "StaticFrames", "parse_static_transform", "FrameError",
           "T_frame_optical", "R_BODY_OPTICAL", "is_body_frame"]

#: a REP-103 body frame (x forward, y left, z up) -> the optical frame at the same place
#: (x right, y down, z forward): R_body_optical
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


#: frames REP-103 / REP-105 name for robots and the world (x forward, z up); a frame named
#: ``*_link`` or ``*_footprint``, or a lidar's, is one too
BODY_FRAMES = ("map", "odom", "earth", "world", "base_link", "base_footprint", "base_stabilized")
BODY_HINTS = ("lidar", "laser", "velodyne", "ouster", "livox", "scan")


def is_body_frame(frame: str) -> bool:
    """Whether ``frame`` names a REP-103 body or world frame (x forward, y left, z up) rather
    than a camera's optical frame: not ``*optical*``, and a REP-105 name, ``*_link``,
    ``*_footprint`` or a lidar's. Any other name keeps the optical convention the node has
    always assumed of a cloud's frame (a camera driver's ``cam``, ``camera_depth``)."""
    name = frame.strip().lstrip("/").lower()
    if "optical" in name:
        return False
    return name in BODY_FRAMES or name.endswith(("_link", "_footprint")) or \
        any(hint in name for hint in BODY_HINTS)


def T_frame_optical(frame: str) -> np.ndarray:
    """The optical frame (x right, y down, z forward) of a sensor whose frame is named
    ``frame``, in that frame: for a REP-103 body frame (:func:`is_body_frame`: ``base_link``,
    ``map``, ``lidar``) one looking along its x axis, else the frame itself (REP-105's
    ``camera_depth_optical_frame``, and any camera frame not named as a body frame)."""
    return make_T(R_BODY_OPTICAL) if is_body_frame(frame) else make_T()


class FrameError(AffordanceError):
    """No transform is known between two frames."""


def parse_static_transform(text: str) -> tuple[str, str, np.ndarray]:
    parts = str(text).split()
    if len(parts) != 9:
        raise AffordanceError(f"static transform {text!r}: expected 'parent child x y z qx qy qz qw'")
    try:
        values = np.array([float(v) for v in parts[2:]])
    except ValueError:
        raise AffordanceError(f"static transform {text!r}: x y z qx qy qz qw must be numbers") \
            from None
    if not np.all(np.isfinite(values)):
        raise AffordanceError(f"static transform {text!r}: values must be finite")
    q = values[3:]
    if abs(np.linalg.norm(q) - 1.0) > 0.01:
        raise AffordanceError(f"static transform {text!r}: the quaternion is not unit length")
    return parts[0].lstrip("/"), parts[1].lstrip("/"), make_T(quat_xyzw_to_matrix(q), values[:3])


class FrameGraph:
    """Transforms between frames as tf2 keeps them: each child frame has one parent (a new
    transform for a child replaces its old one). ``lookup(target, source)`` gives
    T_target_source, following chains in either direction."""

    def __init__(self):
        self._parents: dict[str, tuple[str, np.ndarray]] = {}   # child -> (parent, T_parent_child)

    def set(self, parent: str, child: str, T_parent_child: np.ndarray) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if parent and child and parent != child:
            self._parents[child] = (parent, np.asarray(T_parent_child, dtype=float))

    def __len__(self) -> int:
        return len(self._parents)

    def merged(self, other: "FrameGraph") -> "FrameGraph":
        """This graph with ``other``'s transforms added; ``other`` wins for a child both have."""
        out = FrameGraph()
        out._parents = {**self._parents, **other._parents}
        return out

    def lookup(self, target: str, source: str) -> np.ndarray:
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return np.eye(4)
        edges: dict[str, list[tuple[str, np.ndarray]]] = {}
        for child, (parent, T) in self._parents.items():
            edges.setdefault(parent, []).append((child, T))          # T_parent_child
            edges.setdefault(child, []).append((parent, invert(T)))  # T_child_parent
        # breadth-first from the target: T_target_node accumulates along the path
        seen = {target: np.eye(4)}
        queue = deque([target])
        while queue:
            node = queue.popleft()
            for nxt, T_node_next in edges.get(node, []):
                if nxt in seen:
                    continue
                seen[nxt] = seen[node] @ T_node_next
                if nxt == source:
                    return seen[nxt]
                queue.append(nxt)
        raise FrameError(f"no transform from frame '{source}' to frame '{target}' "
                         f"(publish it on /tf or /tf_static, or give it as a static_transforms "
                         f"parameter)")


class StaticFrames(FrameGraph):
    """The ``static_transforms`` parameter's entries as a frame graph."""

    def __init__(self, entries=()):
        super().__init__()
        for entry in entries:
            if not str(entry).strip():      # [""] is how an empty string list is often written
                continue
            self.set(*parse_static_transform(entry))
