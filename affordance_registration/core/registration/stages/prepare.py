# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Prepare (``crop`` settings): the click snapped to the scan and the crop around it -- its
support plane, the cluster on it, the cluster's segments, the range image -- as the
:class:`~...click_context.ClickContext` every later stage reads.
"""

from __future__ import annotations

from dataclasses import replace

from ...click_context import ClickContext
from ...scene import Scene
from ..parallel import single_threaded_blas
from ..services import Services
from ..state import FitState, stage

__all__ = ["click_context", "run"]


def click_context(
    services: Services, scene: Scene, click, radius: float | None = None
) -> ClickContext:
    """Snap the click to the surface and prepare the crop around it (``radius``, m: by
    default the library's, ``crop.factor`` times its largest template). Only the part of
    the scene that can be in the crop is read (one pass over the cloud): the points within
    the crop radius plus the snap distance of the click hold the snapped point and its
    crop."""
    s = services.settings
    radius = s.crop.factor * services.library.max_diameter if radius is None else radius
    with single_threaded_blas():
        part = scene.around(click, radius + s.crop.snap_distance)
        snapped = (scene if part is None else part).snap(click, s.crop.snap_distance)  # None: why
        return part.prepare_click(
            snapped,
            radius=radius,
            voxel=s.crop.voxel,
            seed=s.seed,
            threads=s.threads,
            fine_points=s.fine.points,
        )


@stage("prepare")
def run(state: FitState) -> FitState:
    """The click's context (:func:`click_context`)."""
    return replace(state, ctx=click_context(state.services, state.scene, state.click))
