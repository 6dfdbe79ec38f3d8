# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine's scene made from the latest cloud, and points brought into its frame.

A :class:`SceneFeed` is given what it needs -- the :class:`~.inputs.LatestCloud` slot the node
fills, a transform lookup (``lookup(target, source, stamp)`` -> T_target_source, raising
:class:`~.errors.FrameError`: TF in a node, :func:`no_transforms` without one), where the sensor
is (:class:`Sensor`) and an :class:`~.inputs.Outbox` for what it has to say -- and the operator
stream asks it for a scene before anything that fits (:meth:`SceneFeed.refresh`) and for a
click in the scene's frame (:meth:`SceneFeed.express`). It never calls back into the node.

**The fixed frame.** Without one (``fixed_frame`` ''), the scene is in the cloud's own frame.
With one (``odom``, ``map``: a camera on a moving robot), each cloud is brought into it through
the transform at the cloud's stamp -- exactly then (``lookup(..., exact=True)``: interpolated
between two transforms, never the latest in its place), so the scene, the objects and the
registrations stay where they are while the camera moves; the sensor's origin and optical pose
come through the same transform. A cloud whose transform has not arrived yet is left for the
next refresh (the previous scene is kept; said when TF is more than :data:`TF_BEHIND_S`
behind); one TF cannot place (unknown, or older than TF
keeps) is refused in one line and the previous scene kept.

When the scene's frame changes (the cloud's, without a fixed frame; or the fixed frame),
everything the engine holds is re-expressed in the new frame through the transform between the
two at the cloud's stamp (the open objects are closed when no transform is known). Pure Python
(no ROS).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import AffordanceError, EngineStateError, FrameError, FrameNotYet, bounded
from .inputs import LatestCloud, Outbox
from .scene import NO_VIEWPOINT
from .transforms import make_T

__all__ = [
    "SceneFeed",
    "Sensor",
    "Lookup",
    "no_transforms",
    "T_frame_optical",
    "R_BODY_OPTICAL",
    "BODY_FRAMES",
    "is_body_frame",
]

#: ``lookup(target, source, stamp, exact=False)``: T_target_source (4x4) at ``stamp`` (s; None:
#: the latest); ``exact``: at that stamp or not at all (:class:`~.errors.FrameNotYet` when it is
#: newer than the newest transform), else the newest transform for a later stamp
Lookup = Callable[..., np.ndarray]

#: a REP-103 body frame (x forward, y left, z up) -> the optical frame at the same place
#: (x right, y down, z forward): R_body_optical
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

#: frames REP-103 / REP-105 name for robots and the world (x forward, z up); a frame named
#: ``*_link`` or ``*_footprint``, or a lidar's, is one too
BODY_FRAMES = ("map", "odom", "earth", "world", "base_link", "base_footprint", "base_stabilized")
BODY_HINTS = ("lidar", "laser", "velodyne", "ouster", "livox", "scan")
#: a transform into the fixed frame that has not arrived is waited for (as tf2's lookups with a
#: timeout do) while TF's newest is at most this much older than the stamp asked for (s): TF is
#: live and a little behind; past it, TF has stopped or lags, and the cloud or click says so
TF_BEHIND_S = 1.0
#: how often a transform waited for is looked for again (s)
TF_POLL_S = 0.02


def is_body_frame(frame: str) -> bool:
    """Whether ``frame`` names a REP-103 body or world frame (x forward, y left, z up) rather
    than a camera's optical frame: not ``*optical*``, and a REP-105 name, ``*_link``,
    ``*_footprint`` or a lidar's. Any other name keeps the optical convention the node has
    always assumed of a cloud's frame (a camera driver's ``cam``, ``camera_depth``)."""
    name = frame.strip().lstrip("/").lower()
    if "optical" in name:
        return False
    return (
        name in BODY_FRAMES
        or name.endswith(("_link", "_footprint"))
        or any(hint in name for hint in BODY_HINTS)
    )


def T_frame_optical(frame: str) -> np.ndarray:
    """The optical frame (x right, y down, z forward) of a sensor whose frame is named
    ``frame``, in that frame: for a REP-103 body frame (:func:`is_body_frame`: ``base_link``,
    ``map``, ``lidar``) one looking along its x axis, else the frame itself (REP-105's
    ``camera_depth_optical_frame``, and any camera frame not named as a body frame)."""
    return make_T(R_BODY_OPTICAL) if is_body_frame(frame) else make_T()


def no_transforms(
    target: str, source: str, stamp: float | None = None, exact: bool = False
) -> np.ndarray:
    """The lookup of a feed without TF: a frame to itself only."""
    if not source or target.lstrip("/") == source.lstrip("/"):
        return np.eye(4)
    raise FrameError(f"no transform from frame '{source}' to frame '{target}' is known")


@dataclass(frozen=True)
class Sensor:
    """Where the scans are taken from: ``frame`` '' -- at ``origin`` (3,) in the cloud's frame;
    ``"none"`` -- no single viewpoint (an accumulated map); another name -- that frame's origin,
    looked up at the cloud's stamp."""

    frame: str = ""
    origin: tuple = (0.0, 0.0, 0.0)


class SceneFeed:
    """Makes the engine's scene the latest cloud, and clicks points of that scene's frame (see
    the module docstring). Used by the stream's worker thread; :meth:`configure` from any."""

    def __init__(
        self,
        clouds: LatestCloud | None = None,
        lookup: Lookup = no_transforms,
        sensor: Sensor = Sensor(),
        outbox: Outbox | None = None,
        fixed_frame: str = "",
        clock=time.monotonic,
        sleep=time.sleep,
    ):
        self.clouds = clouds
        self.clock, self.sleep = clock, sleep
        self.lookup = lookup
        self.sensor = sensor
        self.outbox = outbox if outbox is not None else Outbox()
        #: the frame the scene is made in ('': each cloud's own)
        self.fixed_frame = fixed_frame.strip().lstrip("/")
        self._converted = 0  # the count of the cloud the scene was made from

    def configure(
        self, sensor: Sensor | None = None, fixed_frame: str | None = None, again: bool = False
    ) -> None:
        """Use ``sensor`` and ``fixed_frame`` from the next cloud on; ``again``: make the next
        scene from the latest cloud even when it was used (the transforms changed)."""
        if sensor is not None:
            self.sensor = sensor
        if fixed_frame is not None:
            self.fixed_frame = fixed_frame.strip().lstrip("/")
        if again or sensor is not None or fixed_frame is not None:
            self._converted = -1

    # ------------------------------------------------------------------ the scene
    def refresh(self, engine) -> None:
        """Make ``engine``'s scene the latest cloud (without a cloud slot: the scene it has). An
        unusable newer cloud is reported and the previous scene kept; with no previous scene it
        is an error."""
        if self.clouds is None:
            return
        cloud, count = self.clouds.latest()
        if cloud is None:
            dropped = self.clouds.dropped
            raise EngineStateError(
                f"no usable point cloud yet on '{self.clouds.source}'"
                + (f": {dropped}" if dropped else "")
            )
        if count == self._converted and engine.has_scene:
            return  # (a cloud that was unusable with no scene is tried again: its
        try:  # sensor frame may have reached TF since)
            T_fixed_cloud = self._to_fixed(cloud)
        except FrameNotYet as exc:  # its transform is on its way: the next refresh uses it
            if not engine.has_scene:
                raise AffordanceError(f"the cloud in '{cloud.frame}' is unusable: {exc}") from None
            if exc.behind > TF_BEHIND_S:  # not on its way: TF has fallen behind the clouds
                self.outbox.outcome(
                    "cloud",
                    False,
                    f"the latest cloud waits for TF ({exc}); still using the previous one",
                )
            return
        except FrameError as exc:
            T_fixed_cloud = exc  # refused below, as any cloud that cannot be used
        self._converted = count
        try:
            if isinstance(T_fixed_cloud, FrameError):
                raise T_fixed_cloud
            points = cloud.read()
            origin, T_optical = self._sensor(cloud.frame, cloud.stamp)
            frame = cloud.frame
            if T_fixed_cloud is not None:  # the cloud, the sensor and its view in the fixed frame
                R, t = T_fixed_cloud[:3, :3], T_fixed_cloud[:3, 3]
                points = np.asarray(points, dtype=float) @ R.T + t
                if origin != NO_VIEWPOINT:
                    origin = R @ np.asarray(origin, dtype=float) + t
                T_optical = T_fixed_cloud @ T_optical
                frame = self.fixed_frame
            old, new = engine.frame_id.lstrip("/"), frame.lstrip("/")
            if old and new and old != new:  # only for a cloud that is used
                self._change_frame(engine, old, new, cloud.stamp)
            engine.set_scene(
                points, frame_id=frame, sensor_origin=origin, T_scene_optical=T_optical
            )
        except AffordanceError as exc:
            if not engine.has_scene:
                raise AffordanceError(f"the cloud in '{cloud.frame}' is unusable: {exc}") from None
            self.outbox.outcome(
                "cloud",
                False,
                f"the latest cloud is unusable ({exc}); still using the previous one",
            )

    def _to_fixed(self, cloud) -> np.ndarray | None:
        """T_fixed_cloud at the cloud's stamp, exactly (None without a fixed frame or for a
        cloud already in it)."""
        fixed = self.fixed_frame
        if not fixed or cloud.frame.lstrip("/") == fixed:
            return None
        try:
            return self._exact(fixed, cloud.frame, cloud.stamp)
        except FrameNotYet:
            raise
        except FrameError as exc:
            raise FrameError(
                f"TF cannot place it in the fixed frame '{bounded(fixed)}' at its stamp ({exc})"
            ) from None

    def _change_frame(self, engine, old: str, new: str, stamp: float | None) -> None:
        """The cloud's frame changed: what the engine holds is re-expressed in the new frame
        through TF, or the open objects are closed when no transform is known -- never left in
        the old frame's numbers under the new frame's name."""
        try:
            T_new_old = self.lookup(new, old, stamp)
        except FrameError:
            self.outbox.outcome(
                "frame",
                False,
                engine.close_open_objects(
                    f"the cloud's frame changed from '{bounded(old)}' to '{bounded(new)}' and no "
                    f"transform between them is known"
                ),
            )
            return
        self.outbox.outcome("frame", True, engine.reexpress(T_new_old, new))

    def _sensor(self, cloud_frame: str, stamp: float | None = None):
        """(sensor origin or "none", the sensor's optical pose 4x4) in ``cloud_frame``; the pose
        is the default view for twists."""
        name = self.sensor.frame.strip()
        if name.lower() == NO_VIEWPOINT:
            return NO_VIEWPOINT, T_frame_optical(cloud_frame)
        if not name:
            T = T_frame_optical(cloud_frame)
            T[:3, 3] = self.sensor.origin
            return list(self.sensor.origin), T
        try:
            T_cloud_sensor = self.lookup(cloud_frame, name, stamp)
        except FrameError:
            raise AffordanceError(
                f"the sensor frame '{name}' has no known transform to the "
                f"cloud frame '{cloud_frame}' (publish it on TF, or give it "
                f"in static_transforms)"
            ) from None
        return T_cloud_sensor[:3, 3].copy(), T_cloud_sensor @ T_frame_optical(name)

    def _exact(self, target: str, source: str, stamp: float | None) -> np.ndarray:
        """T_target_source at ``stamp`` exactly, waited for while TF is a little behind (see
        :data:`TF_BEHIND_S`)."""
        deadline = self.clock() + TF_BEHIND_S
        while True:
            try:
                return self.lookup(target, source, stamp, exact=True)
            except FrameNotYet as exc:
                if exc.behind > TF_BEHIND_S or self.clock() >= deadline:
                    raise
            self.sleep(TF_POLL_S)

    # ------------------------------------------------------------------ points
    def express(self, point: np.ndarray, frame: str, stamp: float | None, scene_frame: str):
        """A click given in ``frame`` at ``stamp`` expressed in ``scene_frame`` (through TF at
        its stamp: with a fixed frame, where the camera was when it was clicked)."""
        if not frame or frame.lstrip("/") == scene_frame.lstrip("/"):
            return point
        try:
            if self.fixed_frame and stamp:  # a moving frame: where it was then, not now
                T = self._exact(scene_frame, frame, stamp)
            else:
                T = self.lookup(scene_frame, frame, stamp)
        except FrameNotYet as exc:
            raise AffordanceError(
                f"click refused: it is in frame '{frame}' and TF has no transform to "
                f"'{scene_frame}' at its stamp yet ({exc})"
            ) from None
        except FrameError:
            raise AffordanceError(
                f"click refused: it is in frame '{frame}' and no transform to "
                f"the cloud frame '{scene_frame}' is known"
            ) from None
        return T[:3, :3] @ point + T[:3, 3]
