# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Frame graphs for clicks and view poses: the latest transforms heard on /tf and /tf_static
(``ros/glue/tf.py`` fills one) and the static transforms given as a parameter (the fallback).

A static transform parameter entry is a string ``"parent child x y z qx qy qz qw"`` (metres,
unit quaternion): the pose of ``child`` in ``parent``, as ``ros2 run tf2_ros
static_transform_publisher`` takes it. Chains are followed in either direction.
"""

from __future__ import annotations

import bisect
from collections import deque

import numpy as np

from ...core.errors import AffordanceError, FrameError, FrameNotYet
from ...core.scene_feed import R_BODY_OPTICAL, T_frame_optical, is_body_frame
from ...core.transforms import invert, make_T, quat_xyzw_to_matrix

__all__ = [
    "FrameGraph",
    "StaticFrames",
    "TransformBuffer",
    "TF_CACHE_S",
    "parse_static_transform",
    "FrameError",
    "FrameNotYet",
    "T_frame_optical",
    "R_BODY_OPTICAL",
    "is_body_frame",
]


def parse_static_transform(text: str) -> tuple[str, str, np.ndarray]:
    parts = str(text).split()
    if len(parts) != 9:
        raise AffordanceError(
            f"static transform {text!r}: expected 'parent child x y z qx qy qz qw'"
        )
    try:
        values = np.array([float(v) for v in parts[2:]])
    except ValueError:
        raise AffordanceError(
            f"static transform {text!r}: x y z qx qy qz qw must be numbers"
        ) from None
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
        self._parents: dict[str, tuple[str, np.ndarray]] = {}  # child -> (parent, T_parent_child)

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
            edges.setdefault(parent, []).append((child, T))  # T_parent_child
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
        raise FrameError(
            f"no transform from frame '{source}' to frame '{target}' "
            f"(publish it on /tf or /tf_static, or give it as a static_transforms "
            f"parameter)"
        )


class StaticFrames(FrameGraph):
    """The ``static_transforms`` parameter's entries as a frame graph."""

    def __init__(self, entries=()):
        super().__init__()
        for entry in entries:
            if not str(entry).strip():  # [""] is how an empty string list is often written
                continue
            self.set(*parse_static_transform(entry))


#: how long a TF buffer keeps each dynamic transform (s), as tf2's default cache time
TF_CACHE_S = 10.0


class TransformBuffer:
    """Transforms per child frame in time order, as tf2's buffer keeps them: each dynamic
    transform is stored at its header stamp (s) for ``cache_s`` after the newest one of its
    frame; static ones hold at every time. :meth:`graph` gives the frames at one stamp:

    * ``None`` (or 0: a message without a stamp): the newest transform of every frame -- an
      out-of-order old transform, arriving after a newer one, never replaces it;
    * a stamp between two transforms of a frame: interpolated (translation linearly, rotation
      along the shortest arc), as tf2 does;
    * a stamp after the newest: the newest (a click made between two TF messages of a slowly
      published frame is normal) -- or, with ``exact`` (a cloud brought into the fixed frame),
      none: the frame is left out, as tf2 refuses to extrapolate;
    * a stamp before the oldest kept: refused (:class:`FrameError`), the frame's history there
      is gone.

    A child that changes parent starts a new history. Not thread-safe: guard it."""

    def __init__(self, cache_s: float = TF_CACHE_S):
        self.cache_s = float(cache_s)
        self._static: dict[str, tuple[str, np.ndarray]] = {}
        self._dynamic: dict[str, tuple[str, list]] = {}  # child -> (parent, [(stamp, T)])

    def set(
        self,
        parent: str,
        child: str,
        T_parent_child: np.ndarray,
        stamp: float = 0.0,
        static: bool = False,
    ) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if not parent or not child or parent == child:
            return
        T = np.asarray(T_parent_child, dtype=float)
        if static:
            self._static[child] = (parent, T)
            return
        stamp = float(stamp)
        old_parent, history = self._dynamic.get(child, (parent, []))
        if old_parent != parent:
            history = []
        stamps = [s for s, _ in history]
        i = bisect.bisect_left(stamps, stamp)
        if i < len(history) and history[i][0] == stamp:
            history[i] = (stamp, T)  # the same stamp again: the newer message
        else:
            history.insert(i, (stamp, T))
        newest = history[-1][0]
        while len(history) > 1 and history[0][0] < newest - self.cache_s:
            history.pop(0)
        self._dynamic[child] = (parent, history)

    def graph(
        self, stamp: float | None = None, exact: bool = False, behind: dict | None = None
    ) -> FrameGraph:
        """The frames at ``stamp`` (s; None or 0: the newest) as a :class:`FrameGraph`; with
        ``exact``, a frame whose newest transform is older than ``stamp`` is left out (and, given
        a ``behind`` dict, how far behind it is is put there: child -> s)."""
        out = FrameGraph()
        for child, (parent, T) in self._static.items():
            out.set(parent, child, T)
        for child, (parent, history) in self._dynamic.items():
            try:
                out.set(parent, child, self._at(child, history, stamp, exact))
            except FrameNotYet as exc:
                if behind is not None:
                    behind[child] = exc.behind
            except FrameError:  # its history does not reach back to ``stamp``
                continue
        return out

    def _at(
        self, child: str, history: list, stamp: float | None, exact: bool = False
    ) -> np.ndarray:
        if stamp and exact and stamp > history[-1][0]:
            raise FrameNotYet(
                f"frame '{child}' is known up to {history[-1][0]:.3f} s, not yet at {stamp:.3f} s",
                behind=stamp - history[-1][0],
            )
        if not stamp or stamp >= history[-1][0]:
            return history[-1][1]
        stamps = [s for s, _ in history]
        i = bisect.bisect_left(stamps, stamp)
        if i == 0:
            if stamp == stamps[0]:
                return history[0][1]
            raise FrameError(
                f"frame '{child}' at {stamp:.3f} s is older than what TF keeps "
                f"(transforms from {stamps[0]:.3f} s on; the cache is "
                f"{self.cache_s:g} s)"
            )
        (s0, T0), (s1, T1) = history[i - 1], history[i]
        return _interpolate(T0, T1, (stamp - s0) / (s1 - s0))


def _interpolate(T0: np.ndarray, T1: np.ndarray, f: float) -> np.ndarray:
    """The pose a fraction ``f`` of the way from ``T0`` to ``T1``."""
    from scipy.spatial.transform import Rotation, Slerp

    rot = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]])))
    T = np.eye(4)
    T[:3, :3] = rot([f]).as_matrix()[0]
    T[:3, 3] = (1 - f) * T0[:3, 3] + f * T1[:3, 3]
    return T
