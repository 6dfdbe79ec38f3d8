# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The depth-camera simulator: determinism, geometry, visibility and the noise model."""

import math

import numpy as np
import pytest
import trimesh

from affordance_registration.core.transforms import invert, make_T, transform_points
from affordance_registration.evaluation.simulation import (
    DepthCamera,
    NoiseModel,
    load_truth,
    mesh_distance,
    simulate_taskboard,
    write_scene,
)


def test_same_seed_same_scene(library, panel_scene):
    again = simulate_taskboard(library, 7)
    assert np.array_equal(again.organized, panel_scene.organized, equal_nan=True)
    for a, b in zip(again.objects, panel_scene.objects):
        assert np.array_equal(a.T_scene_model, b.T_scene_model)
    other = simulate_taskboard(library, 8)
    assert not np.array_equal(other.organized, panel_scene.organized, equal_nan=True)


def test_scene_layout(panel_scene):
    s = panel_scene
    assert s.organized.shape == (576, 640, 3)
    cam_in_board = invert(s.T_scene_board)[:3, 3]
    dist = np.linalg.norm(cam_in_board)
    assert 0.5 < dist < 1.45
    off_normal = math.degrees(math.acos(cam_in_board[2] / dist))
    assert off_normal < 45
    assert len(s.objects) == 5
    for o in s.objects:
        # mounted on the panel: template z along the panel normal, base on the panel
        z_board = (invert(s.T_scene_board) @ o.T_scene_model)[:3, 2]
        assert z_board[2] == pytest.approx(1.0, abs=1e-9)
        assert o.visible_points > 100 and o.click is not None


def test_points_lie_on_the_true_surfaces_within_noise(library, panel_scene):
    s = panel_scene
    noise = NoiseModel()
    for k, o in enumerate(s.objects, start=1):
        pts = s.organized[s.labels == k].astype(float)
        local = transform_points(invert(o.T_scene_model), pts)
        d = mesh_distance(library[o.template].mesh, local)
        sigma = noise.sigma(pts[:, 2], math.radians(80))
        assert np.all(d <= 5 * sigma), o.template
        assert np.median(d) < noise.sigma(np.median(pts[:, 2])) * 1.5
        # the click is one of the object's visible points
        assert np.min(np.linalg.norm(pts - o.click, axis=1)) < 1e-9
    panel = s.organized[s.labels == 0].astype(float)
    z_board = transform_points(invert(s.T_scene_board), panel)[:, 2]
    assert np.all(np.abs(z_board) <= 5 * noise.sigma(panel[:, 2], math.radians(80)))


def test_back_faces_and_hidden_surfaces_give_no_points():
    camera = DepthCamera()
    target = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    T_target = make_T(t=[0.0, 0.0, 1.0])
    # alone: the face towards the camera is seen, the back face is not
    pts, labels = camera.render([(target, T_target)], rng=None)
    seen = pts[labels == 0]
    assert len(seen) > 100
    assert np.allclose(seen[:, 2], 0.95, atol=1e-6)  # only the front face (z = 0.95)
    # a larger box in front hides it completely
    blocker = trimesh.creation.box(extents=[0.3, 0.3, 0.02])
    pts, labels = camera.render([(target, T_target), (blocker, make_T(t=[0, 0, 0.6]))], rng=None)
    assert (labels == 0).sum() == 0 and (labels == 1).sum() > 100


def test_noise_statistics_match_the_model():
    """A wall 1 m away, head-on: depth spread equals sigma(1 m); tilted 82 degrees: most returns
    drop out."""
    rng = np.random.default_rng(0)
    camera = DepthCamera()
    wall = trimesh.creation.box(extents=[3.0, 3.0, 0.01])
    pts, labels = camera.render([(wall, make_T(t=[0, 0, 1.005]))], rng=rng)
    z = pts[labels == 0][:, 2]
    expected = NoiseModel().sigma(1.0, 0.0)
    assert z.std() == pytest.approx(expected, rel=0.05)
    assert z.mean() == pytest.approx(1.0, abs=2e-4)
    from affordance_registration.core.transforms import axis_angle_matrix

    tilted = make_T(axis_angle_matrix([0, 1, 0], math.radians(75)), [0, 0, 1.2])
    _, lab_noisy = camera.render([(wall, tilted)], rng=np.random.default_rng(1))
    _, lab_clean = camera.render([(wall, tilted)], rng=None)
    hit = lab_clean == 0
    # expected survival per pixel from the incidence angle, computed independently here
    model = NoiseModel()
    dirs = camera.ray_directions[hit]
    rays = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    theta = np.arccos(np.abs(rays @ tilted[:3, 2]))
    lo, hi = math.radians(model.drop_start_deg), math.radians(model.drop_full_deg)
    survive = 1 - np.clip((theta - lo) / (hi - lo), 0, 1)
    assert survive.mean() < 0.9  # the case exercises dropouts
    kept = (lab_noisy[hit] == 0).mean()
    assert kept == pytest.approx(survive.mean(), abs=0.01)


def test_write_scene_and_truth_round_trip(tmp_path, panel_scene):
    paths = write_scene(panel_scene, str(tmp_path / "out"))
    truth = load_truth(paths["truth.yaml"])
    assert [o["template"] for o in truth["objects"]] == [o.template for o in panel_scene.objects]
    for o, t in zip(panel_scene.objects, truth["objects"]):
        assert np.allclose(o.T_scene_model, t["T_scene_model"], atol=1e-8)
    from affordance_registration.core.scene import load_points

    pts, _ = load_points(paths["scene.ply"])
    assert len(pts) == len(panel_scene.points)
    org, shape = load_points(paths["scene_organized.npy"])
    assert shape == (576, 640)
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]


def test_table_layout_rests_objects_on_the_table(library):
    s = simulate_taskboard(library, 3, layout="table")
    T_board_scene = invert(s.T_scene_board)
    for o in s.objects:
        v = transform_points(T_board_scene @ o.T_scene_model, library[o.template].mesh.vertices)
        assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9)


def test_bad_arguments(library):
    from affordance_registration.core.errors import AffordanceError

    with pytest.raises(AffordanceError, match="seed"):
        simulate_taskboard(library, -1)
    with pytest.raises(AffordanceError, match="layout"):
        simulate_taskboard(library, 1, layout="floor")


def test_articulated_scenes_record_joint_values_and_scales(library):
    s = simulate_taskboard(library, 4, articulated=True)
    by = {o.template: o for o in s.objects}
    lever = by["ball_valve"].joints["lever"]
    assert 0.0 <= lever <= math.pi / 2
    assert by["emergency_stop"].joints["button"] in (0.0, 0.008)
    assert by["emergency_stop"].state in ("pressed", "released")
    assert all(o.scale == 1.0 for o in s.objects)  # no bundled template has sizes
    from affordance_registration.evaluation.simulation import sized_library

    sized = simulate_taskboard(sized_library(library), 4, articulated=True)
    handle = next(o for o in sized.objects if o.template == "grab_handle")
    assert 0.8 <= handle.scale <= 1.25 and handle.scale != 1.0
    assert by["grab_handle"].joints == {} and by["grab_handle"].state is None
    # the rendered surface is the template with that joint value and scale
    k = [o.template for o in s.objects].index("ball_valve") + 1
    o = by["ball_valve"]
    pts = s.organized[s.labels == k].astype(float)
    local = transform_points(invert(o.T_scene_model), pts)
    posed = library["ball_valve"].mesh_at(lever, o.scale)
    assert np.median(mesh_distance(posed, local)) < 0.003
    truth = s.truth()["objects"][[x["template"] for x in s.truth()["objects"]].index("ball_valve")]
    assert truth["joints"]["lever"] == pytest.approx(lever) and truth["state"] == o.state
    # without articulated=True nothing moves: the seed gives the same scene as before
    plain = simulate_taskboard(library, 4)
    assert all(x.joints == {} and x.scale == 1.0 for x in plain.objects)


def test_depth_camera_fault_model_does_what_its_options_say(library):
    """Each documented fault alone, against the clean rendering of the same scene: off values
    change nothing; the distortion is smooth with the RMS asked for; flying pixels are returns
    between a depth edge's two sides (label -2); dark patches and grazing angles drop returns."""
    import math

    from affordance_registration.evaluation.simulation import (
        DepthCamera,
        FaultModel,
        simulate_taskboard,
    )

    off = dict(
        flying_pixels=0.0, distortion=0.0, dark_patches=0, grazing_start_deg=90.0, noise_scale=1.0
    )

    def render(**kw):
        faults = None if kw.pop("clean", False) else FaultModel(**{**off, **kw})
        return simulate_taskboard(library, 1001, camera=DepthCamera(faults=faults))

    clean = render(clean=True)
    z0 = clean.organized[..., 2]
    same = render()
    assert np.array_equal(np.isfinite(z0), np.isfinite(same.organized[..., 2]))
    assert np.allclose(z0[np.isfinite(z0)], same.organized[..., 2][np.isfinite(z0)])
    warped = render(distortion=0.002).organized[..., 2]
    both = np.isfinite(z0) & np.isfinite(warped)
    dz = (warped - z0)[both]
    assert 0.0012 < math.sqrt(np.mean(dz**2)) < 0.0035
    rows = np.where(both[:-1] & both[1:])
    step = np.abs((warped - z0)[1:][rows] - (warped - z0)[:-1][rows])
    assert np.median(step) < 1e-4  # smooth: neighbours move alike
    flying = render(flying_pixels=1.0)
    mixed = flying.labels == -2
    assert mixed.sum() > 100 and np.all(np.isfinite(flying.organized[mixed]))
    assert np.count_nonzero(
        np.isfinite(render(dark_patches=8, dark_dropout=1.0).organized[..., 2])
    ) < np.count_nonzero(np.isfinite(z0))
    assert np.count_nonzero(
        np.isfinite(render(grazing_start_deg=30.0).organized[..., 2])
    ) < np.count_nonzero(np.isfinite(z0))
