# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The demo without ROS (``affordance-registration demo --core``): the simulated operator
registers every visible object of a simulated taskboard on the core engine directly."""

from __future__ import annotations

import os

import numpy as np

from ..core.corrections import view_from_optical
from ..core.engine import AffordanceEngine
from .simulation import SimulatedOperator, simulate_taskboard


class EngineActions:
    """The simulated operator's controls, wired straight to the core engine."""

    def __init__(self, engine):
        self.engine = engine

    def click(self, point):
        self.engine.click(point)

    def shown(self):
        obj = self.engine.active_object()
        return (obj.shown.template, obj.shown.T_scene_model) if obj else (None, None)

    def next_model(self):
        self.engine.next_model()

    def push(self, linear, angular, duration, T_scene_view):
        steps = max(1, int(round(duration / 0.05)))
        for _ in range(steps):
            self.engine.correct_twist(linear, angular, duration / steps, T_scene_view)

    def refit(self):
        self.engine.refit()

    def accept(self):
        self.engine.accept()


def run_core_demo(library, seed: int, out_dir: str) -> tuple[list, str]:
    """Register the objects of simulated scene ``seed`` (those with a click and 200 visible
    points); saves the registrations in ``out_dir``. Returns (the operator's rows, the save's
    sentence)."""
    sim = simulate_taskboard(library, seed)
    engine = AffordanceEngine(library)
    engine.set_scene(sim.organized, frame_id="camera_depth_optical_frame")
    operator = SimulatedOperator(library, seed=seed)
    view = view_from_optical(np.eye(4))
    rows = [
        operator.register(obj, EngineActions(engine), view)
        for obj in sim.objects
        if obj.click is not None and obj.visible_points >= 200
    ]
    os.makedirs(out_dir, exist_ok=True)
    return rows, engine.save(os.path.join(out_dir, "registrations.yaml"))
