# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Real range scans: the Stanford Armadillo scans of the PyPI package or-pcd (0.0.1b7), fetched
with pip into a cache at test time (``make test`` fetches it first; never committed). If the
download fails, these tests fail and say why -- nothing is skipped.

The .conf convention is checked against the wrong reading; point-cloud templates built from the
scans; a scan used as its own template comes back within 1 mm / 0.5 deg; the merged scans as a
template in the taskboard library rank first on the Armadillo clicks they fit."""

import math
import os

import numpy as np
import pytest

from affordance_registration.core.registration import Registrar
from affordance_registration.core.scene import Scene
from affordance_registration.core.templates import TemplateLibrary, load_template
from affordance_registration.core.transforms import invert, make_T, pose_error, random_rotations
from affordance_registration.evaluation.realscans import (
    GROUND_TRUTH_VIEWS,
    armadillo_views,
    default_cache,
    fetch_or_pcd,
    read_conf,
    view_click,
    view_truth,
    write_point_template,
)


@pytest.fixture(scope="session")
def or_pcd():
    try:
        return fetch_or_pcd(default_cache())
    except Exception as exc:  # a failed download fails the tests, with the reason
        pytest.fail(f"the real-scan data could not be fetched: {exc}", pytrace=False)


@pytest.fixture(scope="session")
def views(or_pcd):
    return armadillo_views(or_pcd)


def _overlap_mm(a: np.ndarray, b: np.ndarray) -> float:
    """20th percentile of the distances from ``a``'s points to ``b``'s nearest (mm)."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(b).query(a[::7])
    return float(np.percentile(d, 20)) * 1000


def test_conf_convention_aligns_the_views_and_the_other_reading_does_not(or_pcd, views):
    """bmesh tx ty tz qx qy qz qw maps scan points p to R(q)^T p + t: overlapping views
    (0 / 60, 0 / 330) then meet within a millimetre; R(q) p + t leaves them centimetres apart."""
    poses = read_conf(os.path.join(or_pcd, "ArmadilloBack.conf"))
    assert set(GROUND_TRUTH_VIEWS) <= set(poses)
    by_name = {v.name: v for v in views}

    def common(view, transpose=True):
        T = view.T_common_scan
        R = T[:3, :3] if transpose else T[:3, :3].T
        return view.points @ R.T + T[:3, 3]

    for a, b in (
        ("ArmadilloBack_0", "ArmadilloBack_60"),
        ("ArmadilloBack_0", "ArmadilloBack_330"),
    ):
        right = _overlap_mm(common(by_name[a]), common(by_name[b]))
        wrong = _overlap_mm(common(by_name[a], False), common(by_name[b], False))
        assert right < 1.5 and wrong > 5.0, (a, b, right, wrong)


def test_point_cloud_templates_read_like_scenes(tmp_path, views):
    yml = write_point_template(views[:2], str(tmp_path), "statue")
    tpl = load_template(yml)
    assert tpl.is_point_template and 0.15 < tpl.diameter < 0.45
    P, N = tpl.samples(500, seed=1)
    assert np.allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-5)
    # normals from the file: towards the scanners, not away from the centroid
    eye = views[0].T_common_scan[:3, :3] @ views[0].sensor_origin + views[0].T_common_scan[:3, 3]
    assert np.mean(np.einsum("ij,ij->i", N, eye - P) > 0) > 0.5


@pytest.mark.parametrize("name", GROUND_TRUTH_VIEWS)
def test_a_scan_as_its_own_template_comes_back_exactly(tmp_path, views, name):
    view = next(v for v in views if v.name == name)
    yml = write_point_template(
        [view], str(tmp_path), "self", T_template_common=invert(view.T_common_scan)
    )
    registrar = Registrar(TemplateLibrary([load_template(yml)]))
    best = registrar.fit(
        Scene(view.points, sensor_origin=view.sensor_origin), view_click(view)
    ).candidates[0]
    dt, dr = pose_error(best.T_scene_model, np.eye(4))
    assert dt <= 0.001 and dr <= math.radians(0.5), (name, dt, math.degrees(dr))
    assert best.fits


def test_a_raw_range_scan_is_a_template(tmp_path, or_pcd, views):
    """A raw Cyberware scan as or-pcd ships it (binary big-endian PLY with a range_grid
    element, no faces) loads as a point-cloud template as it is, and is found in itself."""
    import shutil

    shutil.copy(os.path.join(or_pcd, "ArmadilloBack_0.ply"), tmp_path / "scan.ply")
    (tmp_path / "scan.yaml").write_text("name: raw_scan\nmesh: scan.ply\n")
    tpl = load_template(str(tmp_path / "scan.yaml"))
    view = next(v for v in views if v.name == "ArmadilloBack_0")
    assert tpl.is_point_template and len(tpl.points) == len(view.points)
    best = (
        Registrar(TemplateLibrary([tpl]))
        .fit(Scene(view.points, sensor_origin=view.sensor_origin), view_click(view))
        .candidates[0]
    )
    dt, dr = pose_error(best.T_scene_model, np.eye(4))
    assert dt <= 0.001 and dr <= math.radians(0.5), (dt, math.degrees(dr))


def _held_by_others(view, views) -> float:
    """The fraction of ``view``'s points within 2 mm of the other views' (common frame): how
    much of what it saw a template of the others holds at all."""
    from scipy.spatial import cKDTree

    def common(v):
        return v.points @ v.T_common_scan[:3, :3].T + v.T_common_scan[:3, 3]

    others = np.vstack([common(v) for v in views if v is not view])
    return float(np.mean(cKDTree(others).query(common(view)[::5])[0] <= 0.002))


@pytest.fixture(scope="module")
def others_fit(views, tmp_path_factory):
    """``get(view_name)``: (a registrar of the other views merged as the template "armadillo",
    its best candidate on that view's scan and click), made once per view for the module: the
    two tests below fit the same view with the same template (the fit is deterministic)."""
    made = {}

    def get(name):
        if name not in made:
            view = next(v for v in views if v.name == name)
            tpl = load_template(
                write_point_template(
                    [v for v in views if v is not view],
                    str(tmp_path_factory.mktemp(name)),
                    "armadillo",
                )
            )
            registrar = Registrar(TemplateLibrary([tpl]))
            best = registrar.fit(
                Scene(view.points, sensor_origin=view.sensor_origin), view_click(view)
            ).candidates[0]
            made[name] = registrar, best
        return made[name]

    return get


def test_a_template_of_the_other_views_finds_each_view_it_covers(views, others_fit):
    """The other views merged as the template: each view whose surface they hold (at least
    two fifths of its points within 2 mm of theirs -- ArmadilloBack_0 and _330 most, _60 half;
    _180 a seventh, see the bench's real-scans row) is found within 5 mm / 5 deg; where they
    hold most of it, it is judged to fit (on _60 under half of the template's seen surface is
    covered: the verdict says so)."""
    held = {v.name: _held_by_others(v, views) for v in views}
    covered = [v for v in views if held[v.name] >= 0.4]
    assert {v.name for v in covered} == {
        "ArmadilloBack_0",
        "ArmadilloBack_60",
        "ArmadilloBack_330",
    }
    for view in covered:
        _, best = others_fit(view.name)
        dt, dr = pose_error(best.T_scene_model, view_truth(view))
        assert dt <= 0.005 and dr <= math.radians(5), (view.name, dt, math.degrees(dr))
        assert best.fits == (held[view.name] >= 0.7), (view.name, best.coverage)


def test_the_statue_beats_the_taskboard_templates_and_the_verdict_holds(tmp_path, views, library):
    """The four views merged as a template, in the taskboard library: on a click on each view
    -- in the middle of the statue, and low on it (among its lowest 5% of points, its feet and
    legs, where a flat-ish slab of its back once passed for a support plane and cut it down to
    a leg) -- it ranks first with its pose within 5 mm / 5 deg: the small valve and handle
    templates, which fit parts of the statue, lose to it; a valve template alone on the statue
    never reads a probability near 1."""
    statue = load_template(write_point_template(views, str(tmp_path), "armadillo"))
    mixed = Registrar(TemplateLibrary([statue] + [library[n] for n in library]))
    valve_only = Registrar(TemplateLibrary([library["gate_valve"]]))
    for view in views:
        scene = Scene(view.points, sensor_origin=view.sensor_origin)
        for low in (False, True):
            best = mixed.fit(scene, view_click(view, low)).candidates[0]
            assert best.template == "armadillo", (view.name, low, best.template)
            dt, dr = pose_error(best.T_scene_model, view_truth(view))
            assert dt <= 0.005 and dr <= math.radians(5), (view.name, low, dt, math.degrees(dr))
        lone = valve_only.fit(scene, view_click(view)).candidates[0]
        assert lone.probability < 0.9, view.name  # never 1.00 for a poor fit


def test_a_real_scan_moved_rigidly_gives_the_moved_fit(views, others_fit):
    """Equivariance with a point-cloud template (whose hypotheses include matched shape
    features): the scan, click and scanner moved by T give T . (the original fit)."""
    view = next(v for v in views if v.name == "ArmadilloBack_330")
    registrar, original = others_fit(view.name)
    click = view_click(view)
    rng = np.random.default_rng(18)
    for _ in range(2):
        R = random_rotations(1, rng)[0]
        T = make_T(R, rng.uniform(-5, 5, 3))
        moved = Scene(
            view.points @ R.T + T[:3, 3], sensor_origin=R @ view.sensor_origin + T[:3, 3]
        )
        got = registrar.fit(moved, R @ click + T[:3, 3]).candidates[0]
        dt, dr = pose_error(got.T_scene_model, T @ original.T_scene_model)
        assert dt <= 0.001 and dr <= math.radians(1.0), (dt, math.degrees(dr))


def test_fetch_failure_is_one_clear_error(tmp_path):
    """A cache that cannot be written: one AffordanceError naming it (no traceback from pip or
    the file system)."""
    from affordance_registration.core.errors import AffordanceError

    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    with pytest.raises(AffordanceError, match="cache"):
        fetch_or_pcd(str(blocked / "cache"))
