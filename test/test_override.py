# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Accepting a candidate the verdict refuses is an operator override, and the registration says
so (core engine, saved file, reloaded); a right fit is accepted plainly."""

import numpy as np
import yaml

from affordance_registration.core.engine import AffordanceEngine


def bare_wall_point(scene) -> np.ndarray:
    """A scanned point of the panel at least 12 cm from every object, nearest the panel's
    middle."""
    pts = scene.points[np.all(np.isfinite(scene.points), axis=1)]
    centres = np.array([o.T_scene_model[:3, 3] for o in scene.objects])
    d = np.min(np.linalg.norm(pts[:, None, :] - centres[None], axis=2), axis=1)
    far = pts[d > 0.12]
    middle = np.median(pts, axis=0)
    return far[np.argmin(np.linalg.norm(far - middle, axis=1))]


def test_an_override_is_marked_in_the_registration(library, panel_scene, tmp_path):
    engine = AffordanceEngine(library)
    engine.set_scene(panel_scene.organized, frame_id="camera_depth_optical_frame")
    obj = max(panel_scene.objects, key=lambda o: o.visible_points)
    engine.click(obj.click)
    assert not engine.active_object().no_match
    plain = engine.accept()
    assert "override" not in plain
    engine.click(bare_wall_point(panel_scene))
    refused = engine.active_object()
    assert refused.no_match, [c.coverage for c in refused.candidates]
    message = engine.accept()
    assert "operator override (no template fits here)" in message
    regs = engine.status()["registered"]
    assert [r["override"] for r in regs] == [False, True]
    path = tmp_path / "r.yaml"
    engine.save(str(path))
    saved = yaml.safe_load(path.read_text())["registrations"]
    assert [r["override"] for r in saved] == [False, True]
    again = AffordanceEngine(library)
    again.load(str(path))
    assert [r["override"] for r in again.status()["registered"]] == [False, True]
