# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Refit (``refit`` settings): a candidate refitted from the operator's correction and judged
as at the click -- a specific template by a local ICP from the correction
(:func:`..refit.refit`), then, where it fits, distinguished from the primitive fitting the same
click; a primitive measured again (:func:`.primitives.refit`).
"""

from __future__ import annotations

import numpy as np

from ...click_context import ClickContext
from ...scene import Scene
from .. import refit as local
from ..parallel import single_threaded_blas
from ..results import FitResult
from ..services import Services
from . import primitives

__all__ = ["run"]


def run(
    services: Services,
    ctx: ClickContext,
    template: str,
    T_init: np.ndarray,
    joints: dict | None = None,
    scale: float = 1.0,
    hold_joint: bool | None = None,
    dimensions: dict | None = None,
    scene: Scene | None = None,
) -> FitResult:
    """``template`` refitted in ``ctx`` from ``T_init`` and judged (see
    :meth:`..registrar.Registrar.refit` for the arguments)."""
    if services.library[template].primitive is not None:
        with single_threaded_blas():
            return primitives.refit(services, ctx, template, T_init, dimensions, scene)
    model = services.model(template, joints, scale)
    with single_threaded_blas():
        res = local.refit(
            ctx,
            model,
            T_init,
            services.settings,
            hold_joint=bool(joints) if hold_joint is None else hold_joint,
        )
        res = services.judged(ctx, [res])[0]
        if res.fits:  # as at the click: it must show more than a primitive does
            res = services.distinguished(ctx, [res], primitives.seen(services, ctx, scene))[0]
    return res
