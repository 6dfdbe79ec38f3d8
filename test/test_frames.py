# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Scenes in any frame: fitting a rigidly moved scene gives the rigidly moved fit (a property,
over random frames and the bench's four), clouds without a viewpoint, the sensor origin from
``--sensor-origin`` and a PCD's VIEWPOINT, the absolute verdict ("no template fits here") and
degenerate input as one clear line."""

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from affordance_registration.cli import main as cli_main
from affordance_registration.core.engine import AffordanceEngine
from affordance_registration.core.errors import SceneError
from affordance_registration.core.registration import NO_MATCH, Registrar
from affordance_registration.core.scene import Scene
from affordance_registration.core.templates import TemplateLibrary
from affordance_registration.core.transforms import axis_angle_matrix, make_T, pose_error
from affordance_registration.evaluation.simulation import ply_bytes, simulate_taskboard

#: the frames of the bench's frames row: (rotation vector (rad), translation (m))
Z_UP = (np.array([-math.pi / 2, 0.0, 0.0]) * 1.0, [0.0, 0.0, 1.1])  # optical -> z-up base
MAP = ([0.3, -0.2, 1.9], [12.5, -7.25, 1.3])  # metres from the origin
ARBITRARY = ([1.1, 2.0, -0.7], [1.2, -1.1, 1.2])  # sensor 2 m away
UPSIDE_DOWN = ([math.pi, 0.0, 0.0], [0.0, 0.0, 0.0])  # z (and y) negated


def _T(rotvec, t) -> np.ndarray:
    rotvec = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(rotvec))
    R = axis_angle_matrix(rotvec, angle) if angle > 0 else np.eye(3)
    return make_T(R, t)


@pytest.fixture(scope="module")
def setup(library):
    sim = simulate_taskboard(library, 1001)
    registrar = Registrar(library)
    registrar.warm_up()
    obj = max(sim.objects, key=lambda o: o.visible_points)
    original = registrar.fit(Scene(sim.points), obj.click).candidates
    return sim, registrar, obj, original


@settings(
    max_examples=8,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@example(rotvec=Z_UP[0], t=Z_UP[1])
@example(rotvec=MAP[0], t=MAP[1])
@example(rotvec=ARBITRARY[0], t=ARBITRARY[1])
@example(rotvec=UPSIDE_DOWN[0], t=UPSIDE_DOWN[1])
@given(
    rotvec=st.lists(st.floats(-math.pi, math.pi), min_size=3, max_size=3),
    t=st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3),
)
def test_fitting_a_moved_scene_gives_the_moved_fit(setup, rotvec, t):
    """T . scene, T . click, T . sensor origin -> T . (the original fit), the same ranking."""
    sim, registrar, obj, original = setup
    T = _T(rotvec, t)
    moved = Scene(sim.points @ T[:3, :3].T + T[:3, 3], sensor_origin=T[:3, 3])
    got = registrar.fit(moved, T[:3, :3] @ obj.click + T[:3, 3]).candidates
    assert [c.template for c in got] == [c.template for c in original]
    for a, b in zip(original, got):
        dt, dr = pose_error(b.T_scene_model, T @ a.T_scene_model)
        assert dt <= 0.001 and dr <= math.radians(1.0), (a.template, dt, math.degrees(dr))
        assert b.coverage == pytest.approx(a.coverage, abs=0.02)


def test_a_scanner_looking_along_minus_z_is_fitted(library, setup):
    """The optical scene turned upside down about x: every point has z < 0 (the range image of
    old refused it); the fit is the turned original's."""
    sim, registrar, obj, original = setup
    T = _T([math.pi, 0, 0], [0, 0, 0])
    pts = sim.points @ T[:3, :3].T
    assert np.all(pts[:, 2] < 0)
    best = registrar.fit(Scene(pts), T[:3, :3] @ obj.click).candidates[0]
    assert best.template == obj.template
    dt, dr = pose_error(best.T_scene_model, T @ obj.T_scene_model, library[obj.template].symmetry)
    assert dt <= 0.005 and dr <= math.radians(5)


def test_without_a_viewpoint_the_right_template_still_wins(library, setup):
    sim, registrar, obj, _ = setup
    rep = registrar.fit(Scene(sim.points, sensor_origin="none"), obj.click)
    assert rep.context.sensor_origin is None and rep.context.range_image is None
    best = rep.candidates[0]
    assert best.template == obj.template and best.fits
    dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, library[obj.template].symmetry)
    assert dt <= 0.005 and dr <= math.radians(5)


# ------------------------------------------------------------------------ the verdict
def _bare_panel_point(sim):
    flat = sim.organized.reshape(-1, 3)
    finite = np.all(np.isfinite(flat), axis=1)
    labels = sim.labels.reshape(-1)[finite]
    pts = flat[finite].astype(float)
    panel, objects = pts[labels == 0], pts[labels > 0]
    from scipy.spatial import cKDTree

    d, _ = cKDTree(objects).query(panel)
    return panel[np.argmax(d)]


def test_a_click_on_bare_wall_says_no_template_fits(library, setup):
    sim, registrar, obj, original = setup
    assert original[0].fits and original[0].coverage >= registrar.settings.verdict.min_coverage
    engine = AffordanceEngine(library)
    engine.set_scene(sim.organized)
    message = engine.click(_bare_panel_point(sim))
    assert NO_MATCH in message
    status = engine.status()["objects"][0]
    assert status["no_match"] and status["verdict"] == NO_MATCH
    assert len(status["candidates"]) == len(library)  # still listed
    assert all(
        0 <= c["coverage"] < registrar.settings.verdict.min_coverage
        and c["fits"] is False
        and "inlier_rmse" in c
        for c in status["candidates"][:1]
    )


def test_a_one_template_library_that_does_not_match(library, setup):
    sim, _, obj, _ = setup
    other = next(n for n in library if n != obj.template and n != "grab_handle")
    lonely = Registrar(TemplateLibrary([library[other]]))
    best = lonely.fit(Scene(sim.points), obj.click).candidates[0]
    assert best.fits is False and best.coverage < lonely.settings.verdict.min_coverage
    assert best.probability < 0.9  # never 1.00 for a poor fit
    right = Registrar(TemplateLibrary([library[obj.template]]))
    good = right.fit(Scene(sim.points), obj.click).candidates[0]
    assert good.fits and good.probability > best.probability


# ------------------------------------------------------------------------ the CLI
@pytest.fixture(scope="module")
def scene_files(tmp_path_factory, setup):
    sim, _, obj, _ = setup
    out = tmp_path_factory.mktemp("frames")
    T = _T(ARBITRARY[0], ARBITRARY[1])
    moved = sim.points @ T[:3, :3].T + T[:3, 3]
    ply = out / "moved.ply"
    ply.write_bytes(ply_bytes(moved))
    pcd = out / "moved.pcd"
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(moved)}\nHEIGHT 1\nVIEWPOINT {T[0, 3]} {T[1, 3]} {T[2, 3]} 1 0 0 0\n"
        f"POINTS {len(moved)}\nDATA binary\n"
    )
    pcd.write_bytes(header.encode() + moved.astype("<f4").tobytes())
    return T, obj, ply, pcd


def _fit_json(capsys, *args):
    assert cli_main(["fit", "--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


def test_cli_sensor_origin_and_pcd_viewpoint(scene_files, capsys, library):
    T, obj, ply, pcd = scene_files
    click = [str(v) for v in T[:3, :3] @ obj.click + T[:3, 3]]
    origin = [str(v) for v in T[:3, 3]]
    given_origin = _fit_json(
        capsys, "--scene", str(ply), "--point", *click, "--sensor-origin", *origin
    )
    from_viewpoint = _fit_json(capsys, "--scene", str(pcd), "--point", *click)
    for doc in (given_origin, from_viewpoint):
        assert doc["sensor_origin"] == pytest.approx(list(T[:3, 3]), abs=1e-5)
        best = doc["candidates"][0]
        assert best["template"] == obj.template and doc["verdict"] == "fits"
        assert {"coverage", "inlier_rmse", "fits"} <= set(best)
        dt, dr = pose_error(
            np.asarray(best["pose"]), T @ obj.T_scene_model, library[obj.template].symmetry
        )
        assert dt <= 0.005 and dr <= math.radians(5)
    none = _fit_json(capsys, "--scene", str(ply), "--point", *click, "--sensor-origin", "none")
    assert none["sensor_origin"] is None and none["candidates"][0]["template"] == obj.template


def test_scene_reads_the_pcd_viewpoint(scene_files):
    T, _, _, pcd = scene_files
    assert Scene.from_file(str(pcd)).sensor_origin == pytest.approx(T[:3, 3], abs=1e-6)
    assert Scene.from_file(str(pcd), sensor_origin="none").sensor_origin is None


@pytest.mark.parametrize(
    "case", ["identical", "line", "behind_far", "origin_at_click", "bad_origin"]
)
def test_degenerate_input_is_one_line_exit_2(case, tmp_path, capsys):
    rng = np.random.default_rng(0)
    args = []
    if case == "identical":
        pts = np.tile([0.1, 0.2, 1.0], (500, 1))
    elif case == "line":
        pts = np.stack([np.linspace(0, 0.3, 500), np.zeros(500), np.ones(500)], axis=1)
    elif case == "behind_far":  # every point behind the sensor, none near the click
        pts = rng.normal(size=(500, 3)) * 0.01 + [0, 0, -1.0]
        args = ["--point", "0", "0", "1"]
    else:
        pts = rng.uniform(-0.2, 0.2, size=(2000, 3)) * [1, 1, 0.01] + [0, 0, 1.0]
        args = ["--sensor-origin", *(["0", "0", "1"] if case == "origin_at_click" else ["1", "2"])]
    path = tmp_path / "scene.ply"
    path.write_bytes(ply_bytes(pts))
    point = args[1:4] if args[:1] == ["--point"] else [str(v) for v in pts[0]]
    if case == "origin_at_click":
        point = ["0", "0", "1"]
        pts[0] = [0, 0, 1.0]
        path.write_bytes(ply_bytes(pts))
    extra = [] if args[:1] == ["--point"] else args
    code = cli_main(["fit", "--scene", str(path), "--point", *point, *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "internal error" not in err, err


def test_scene_origin_values():
    pts = np.random.default_rng(1).normal(size=(100, 3))
    assert Scene(pts).sensor_origin == pytest.approx([0, 0, 0])
    assert Scene(pts, sensor_origin="None").sensor_origin is None
    for bad in ("far", [1, 2], [0, np.nan, 0]):
        with pytest.raises(SceneError):
            Scene(pts, sensor_origin=bad)


def test_default_view_convention_by_frame_name():
    """The node's default view for twists: REP-103 body / world frames look along x (z up);
    optical frames and other camera frame names keep the optical convention."""
    from affordance_registration.ros.glue.frames import R_BODY_OPTICAL, T_frame_optical

    for body in ("base_link", "/map", "odom", "camera_link", "base_footprint", "velodyne"):
        assert np.allclose(T_frame_optical(body)[:3, :3], R_BODY_OPTICAL), body
    for optical in ("camera_depth_optical_frame", "cam", "camera_depth", "kinect_rgb_optical"):
        assert np.allclose(T_frame_optical(optical), np.eye(4)), optical
    # the optical z (forward) of a body frame is its x; optical y (down) is its -z
    assert np.allclose(R_BODY_OPTICAL @ [0, 0, 1], [1, 0, 0])
    assert np.allclose(R_BODY_OPTICAL @ [0, 1, 0], [0, 0, -1])
