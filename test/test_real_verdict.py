# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The verdict and the primitives on real captures: mOSD's Kinect tabletop scans and
PCL's milk carton scene from ../shared/data (or $AFFORDANCE_SHARED_DATA; skipped with one line
when absent), and the frame a scanned template's file is in (the Armadillo scans of or-pcd).

The figures asserted are what this code reaches (see the bench's rows for them, tuning and
held-out scenes apart), set so that a regression fails."""

import math
import tempfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from affordance_registration.core.registration import Registrar, no_match
from affordance_registration.core.scene import Scene
from affordance_registration.core.templates import (
    AffordanceTemplate,
    TemplateLibrary,
    load_template,
)
from affordance_registration.core.transforms import make_T, pose_error, random_rotations
from affordance_registration.evaluation import realdata as rd
from affordance_registration.evaluation.clutter import milk_body_on_box, milk_carton_case


@pytest.fixture(scope="module")
def kinect_records(data_dir, library):
    """Every labelled object (>= 1500 points) of the 15 mOSD learn scenes the figures below were
    measured on (``ORIGINAL_SCENES``), clicked in its middle, fitted with the default library
    (the taskboard templates, a box, a cylinder)."""
    registrar = Registrar(library)
    registrar.warm_up()
    records = []
    for path in rd.osd_scene_paths(data_dir, scenes=rd.ORIGINAL_SCENES):
        records += rd.evaluate_scene(registrar, path)
    return records


def test_the_library_refuses_every_real_kinect_object(kinect_records):
    """No box, can or bowl of mOSD is called a valve, an e-stop or a handle: at least 95% of
    the labelled objects get 'no template fits here' (this code: 37 of 37), each with a
    reason."""
    assert len(kinect_records) >= 30
    assert not [r for r in kinect_records if r["error"]]
    refused = [r["primitive"] is not None or r["fits"] is not True for r in kinect_records]
    assert np.mean(refused) >= 0.95, [
        (r["scene"], r["object"], r["template"])
        for r, ok in zip(kinect_records, refused)
        if not ok
    ]
    for held in (True, False):
        part = [ok for r, ok in zip(kinect_records, refused) if r["held_out"] == held]
        assert part and np.mean(part) >= 0.9


def test_an_emergency_stop_is_refused_on_a_real_box_that_shows_no_button(data_dir, library):
    """learn8's small box, half hidden behind a large one, is covered by an emergency stop's
    housing (coverage at the bar), but the button is not there: of the e-stop's surface that
    a box does not have, less than the bar is seen, so it does not fit, says why, and the box
    primitive is shown and fits."""
    path = [p for p in rd.osd_scene_paths(data_dir) if rd.scene_name(p) == "learn8"]
    if not path:
        pytest.skip("learn8 is not among the shared mOSD scenes")
    cloud = rd.read_labelled_pcd(path[0])
    obj = [o for o in rd.labelled_objects(cloud) if o.id == 3][0]
    registrar = Registrar(library)
    rep = registrar.fit(
        Scene(cloud.points.reshape(-1, 3), sensor_origin=cloud.viewpoint), obj.click
    )
    stop = [c for c in rep.candidates if c.template == "emergency_stop"][0]
    assert stop.fits is False and stop.reason
    if stop.distinct is None:
        # on some CPUs (seen on an AMD EPYC host: other SIMD paths in the fine stages) the
        # housing settles 6 mm off the box and the residual rule refuses it before the
        # distinction is asked -- still refused, with that reason
        assert "apart on average" in stop.reason and "a fit is within" in stop.reason
    else:
        assert stop.distinct < registrar.settings.verdict.min_distinct
        assert "no more than a box" in stop.reason
    best = rep.candidates[0]
    assert best.primitive == "box" and best.fits is True


def test_the_verdicts_precision_is_the_label_rules(kinect_records):
    """What the verdict measures of a primitive's precision (the share of the scan on its
    surface that is the object) is what the hand labels say, without a bias: over the fits of
    the right kind that cover the object (label recall at least 90%), the mean difference is
    within 0.007 (this code: +0.002; +0.013 when the strip of table at a box's foot counted
    as the box) and none is off by more than 0.035."""
    diffs = np.array(
        [
            r["precision"] - r["score"]["precision"]
            for r in kinect_records
            if r["score"]
            and r["precision"] is not None
            and r["primitive"] == r["object_kind"]
            and r["score"]["recall"] >= 0.9
        ]
    )
    assert len(diffs) >= 20
    assert abs(float(diffs.mean())) <= 0.007, diffs.mean()
    assert float(np.abs(diffs).max()) <= 0.035, np.abs(diffs).max()


def _learn_click(data_dir, library, scene: str, object_id: int):
    """The report of a click in the middle of ``object_id`` of the mOSD scene ``scene`` (the
    default library); skips with one line where the scene is not shared."""
    path = [p for p in rd.osd_scene_paths(data_dir) if rd.scene_name(p) == scene]
    if not path:
        pytest.skip(f"{scene} is not among the shared mOSD scenes")
    cloud = rd.read_labelled_pcd(path[0])
    obj = [o for o in rd.labelled_objects(cloud) if o.id == object_id][0]
    scan = Scene(cloud.points.reshape(-1, 3), sensor_origin=cloud.viewpoint)
    return cloud, obj, Registrar(library).fit(scan, obj.click)


def test_two_templates_tested_against_a_primitive_each_get_their_verdict(data_dir, library):
    """learn40's tins: on the middle one two specific templates pass the first bars, one is
    tested for the surface that sets it apart from the cylinder, the other for its
    description; each gets a verdict with its reason (the second raised a TypeError once), and
    the cylinder is shown."""
    cloud, obj, rep = _learn_click(data_dir, library, "learn40", 3)
    specific = [c for c in rep.candidates if c.primitive is None]
    assert all(c.fits or c.reason for c in specific)
    assert rep.candidates[0].primitive == "cylinder"


def test_a_template_reaching_into_the_table_is_no_fit(data_dir, library):
    """learn11's tea box, lying flat: an emergency stop's housing covers it as closely as a
    box, its button hidden -- in the table, more than 3 cm deep. The table is solid: the e-stop
    does not fit, says so, and the box is shown, fitting, and passes the label rule."""
    cloud, obj, rep = _learn_click(data_dir, library, "learn11", 3)
    stop = [c for c in rep.candidates if c.template == "emergency_stop"][0]
    assert stop.fits is False and "into the surface the object stands on" in stop.reason
    best = rep.candidates[0]
    assert best.primitive == "box" and best.fits is True
    assert rd.score_primitive(cloud, obj, "box", best.T_scene_model, best.dimensions).recall >= 0.9


def test_a_template_that_describes_a_real_can_worse_than_a_cylinder_is_no_fit(data_dir, library):
    """learn30's crisps can, lying behind another and split by it: an emergency stop explains
    96% of its points (it was shown, "fits"), the cylinder all of them, closer: by the
    description length of the clicked object's points the cylinder wins, the e-stop does not
    fit, and the cylinder is shown and passes the label rule."""
    cloud, obj, rep = _learn_click(data_dir, library, "learn30", 3)
    stop = [c for c in rep.candidates if c.template == "emergency_stop"][0]
    assert stop.fits is False and "a cylinder describes the clicked object better" in stop.reason
    best = rep.candidates[0]
    assert best.primitive == "cylinder" and best.fits is True
    assert rd.score_primitive(cloud, obj, "cylinder", best.T_scene_model, best.dimensions).passes


@pytest.mark.parametrize("scene,object_id", [("learn28", 3), ("learn32", 3)])
def test_a_real_object_split_by_one_in_front_is_measured_whole(kinect_records, scene, object_id):
    """learn28's box and learn32's tube are each seen on both sides of an object standing in
    front of them: the primitive measured from the clicked piece covers both pieces (the label
    score passes: recall and precision at least 90%)."""
    rec = [r for r in kinect_records if r["scene"] == scene and r["object"] == object_id]
    if not rec:
        pytest.skip(f"{scene} is not among the shared mOSD scenes")
    assert rec[0]["score"] is not None and rec[0]["score"]["passes"], rec[0]


def test_a_real_box_reaching_behind_the_crops_plane_is_measured_whole(data_dir, library):
    """learn23's muesli box lies across the cereal box under it and hangs over its edge; the
    crop's dominant plane is the cereal box's top, with a third of the muesli box behind it.
    Everything behind that plane was taken away, the muesli box cut at its level (the cluster
    held 61% of it), and a box of 62% of it was accepted. A plane the clicked object reaches
    behind is not its support: the cluster holds the whole box, and the box measured on it fits
    and passes the label rule."""
    paths = rd.osd_scene_paths(data_dir, scenes=[23])
    if not paths:
        pytest.skip("learn23 is not among the shared mOSD scenes")
    cloud = rd.read_labelled_pcd(paths[0])
    obj = next(o for o in rd.labelled_objects(cloud) if o.id == 4)
    scene = Scene(cloud.points.reshape(-1, 3), sensor_origin=cloud.viewpoint)
    registrar = Registrar(library)
    ctx = registrar.prepare(scene, obj.click)
    own = cloud.points[cloud.valid & (cloud.object_ids == 4)]
    gap, _ = cKDTree(ctx.cluster).query(own)
    assert np.mean(gap <= ctx.voxel) > 0.95
    best = registrar.fit(scene, obj.click).candidates[0]
    assert best.primitive == "box" and best.fits, (best.template, best.reason)
    score = rd.score_primitive(cloud, obj, "box", best.T_scene_model, best.dimensions)
    assert score.passes, score


def test_primitives_on_the_boxes_of_real_scans(kinect_records):
    """The single boxes of learn0-16 (no box touching another): the box primitive is the best
    candidate and explains the labels -- of the object's points at least 90% on its surface,
    of the scan's points on its surface at least 90% the object's -- on most of them."""
    boxes = [r for r in kinect_records if r["kind"] == "boxes"]
    assert len(boxes) >= 10
    as_box = [r["primitive"] == "box" for r in boxes]
    passes = [bool(r["score"] and r["score"]["passes"]) for r in boxes]
    assert np.mean(as_box) >= 0.8 and np.mean(passes) >= 0.7, (np.mean(as_box), np.mean(passes))


def test_primitive_kind_on_scenes_of_one_kind(kinect_records):
    """On the scenes whose objects are all boxes or all cylinders, the primitive shown is of
    that kind for at least 85% of the objects (this code: 27 of 27 -- 23 of 23 on the scenes
    counted before the annotation covered learn25 and learn28, all boxes; stacked boxes and
    touching cans included)."""
    of_kind = [r for r in kinect_records if r["uniform_kind"] is not None]
    assert len(of_kind) >= 15
    right = [r["primitive"] == r["uniform_kind"] for r in of_kind]
    assert np.mean(right) >= 0.85, np.mean(right)


def test_primitives_explain_the_real_boxes_and_cylinders(kinect_records):
    """Every labelled box and closed cylinder of the learn scenes (``OBJECT_KINDS``: not the
    bowl nor the open tub), touching, stacked and half hidden ones included: the label score
    -- of the object's points at least 90% within max(6 mm, 3 sigma) of the fitted surface,
    of the scan's points on it at least 90% the object's -- passes on at least 85% of them
    (this code: 30 of 34, 22 of 24 tuning and 8 of 10 held-out; the issue's target is 90% of
    each), and the fitted primitive is accepted on at least 85%."""
    objects = [r for r in kinect_records if r["object_kind"] in ("box", "cylinder")]
    assert len(objects) >= 30
    passes = [bool(r["score"] and r["score"]["passes"]) for r in objects]
    assert np.mean(passes) >= 0.85, [
        (r["scene"], r["object"]) for r, ok in zip(objects, passes) if not ok
    ]
    accepted = [r["primitive"] is not None and r["fits"] is True for r in objects]
    assert np.mean(accepted) >= 0.85, np.mean(accepted)


@pytest.fixture(scope="module")
def touching(data_dir, library):
    """The clicked segment of each object of the learn scenes whose objects touch (stacked
    boxes, a box lying on another, a tub on a tin): (scene, object, purity, completeness) --
    the share of the segment's cluster voxels that are the object's, and of the object's
    cluster voxels in the segment."""
    from scipy.spatial import cKDTree

    registrar = Registrar(library)
    out = []
    for n in (17, 20, 25, 41):
        path = f"{rd.osd_dir(data_dir)}/learn{n}.pcd"
        cloud = rd.read_labelled_pcd(path)
        pts, ids = cloud.points.reshape(-1, 3), cloud.object_ids.reshape(-1)
        valid = np.all(np.isfinite(pts), axis=1)
        tree = cKDTree(pts[valid])
        scene = Scene(pts, sensor_origin=cloud.viewpoint)
        for obj in rd.labelled_objects(cloud):
            ctx = registrar.prepare(scene, obj.click)
            owner = ids[valid][tree.query(ctx.cluster)[1]]
            seg = ctx.segments
            mine = seg == seg[int(np.argmin(ctx._cluster_to_click))]
            both = (mine & (owner == obj.id)).sum()
            out.append((cloud.name, obj.id, both / mine.sum(), both / (owner == obj.id).sum()))
    return out


def test_touching_real_objects_are_segments_of_their_own(touching):
    """Where two real objects touch -- a Kinect blurs their seam into a band of normals turning
    a few degrees a voxel, which joined them pair by pair -- each clicked object's segment is
    at least 90% that object and holds at least 90% of it (this code: all 9)."""
    assert len(touching) >= 8
    bad = [t for t in touching if t[2] < 0.9 or t[3] < 0.9]
    assert not bad, bad


def test_the_milk_carton_is_found_in_its_real_scene(data_dir, library, tmp_path):
    """PCL's milk carton (a point-cloud template segmented from the scene: its true pose is the
    identity) in the default library: ranked first, accepted, within 2 mm where the carton is
    and 2 deg of the identity -- its file's origin lies 0.8 m from its points, where the
    error is measured at the centroid (a 0.1 deg turn moves that far origin 1.4 mm)."""
    case = milk_carton_case(str(tmp_path), data_dir)
    tpl = load_template(case.template)
    registrar = Registrar(TemplateLibrary([tpl] + list(library.values())))
    rep = registrar.fit(Scene.from_file(case.scene), case.click)
    best = rep.candidates[0]
    assert best.template == tpl.name and best.fits is True and not no_match(rep.candidates)
    c = tpl.centroid
    moved = best.T_scene_model[:3, :3] @ c + best.T_scene_model[:3, 3]
    assert np.linalg.norm(moved - c) <= 0.002
    assert math.degrees(pose_error(best.T_scene_model, np.eye(4))[1]) <= 2.0


def test_the_milk_carton_is_measured_as_a_box_without_its_template(data_dir, library, tmp_path):
    """The same click with the default library (no carton template): the box primitive is
    measured to the carton's body -- its square footprint, by the carton's own points 0.10 m a
    side, and of the points below its gable roof (0.19 m over the box's base) at least 95%
    within 6 mm of the box. Its top face is only a strip along the ridge; measured to that
    strip's edge, the box was half as deep. A box leaves the gable roof out: its verdict is
    the label rule's on the carton (its points are the scene's: milk.pcd was cut from it)."""
    from label_rule import assert_honest
    from scipy.spatial import cKDTree

    from affordance_registration.evaluation.realdata import score_points

    case = milk_carton_case(str(tmp_path), data_dir)
    scene = Scene.from_file(case.scene)
    rep = Registrar(library).fit(scene, case.click)
    box = next(c for c in rep.candidates if c.primitive == "box")
    assert all(0.09 <= box.dimensions[k] <= 0.11 for k in ("x", "y")), box.dimensions
    body, on = milk_body_on_box(case.carton, box.T_scene_model, box.dimensions)
    assert body > 0.6 and on >= 0.95, (body, on)
    own = np.isfinite(cKDTree(case.carton).query(scene.points, distance_upper_bound=1e-6)[0])
    score = score_points(scene.points, own, "box", box.T_scene_model, box.dimensions)
    assert_honest(box, score)


@pytest.fixture(scope="module")
def armadillo():
    from affordance_registration.evaluation.realscans import (
        armadillo_views,
        default_cache,
        fetch_or_pcd,
        view_click,
        write_point_template,
    )

    try:
        views = armadillo_views(fetch_or_pcd(default_cache()))
    except Exception as exc:  # a failed download fails the tests, with the reason
        pytest.fail(f"the real-scan data could not be fetched: {exc}", pytrace=False)
    view = views[0]
    tpl = load_template(write_point_template(views[1:], tempfile.mkdtemp(), "armadillo"))
    scene = Scene(view.points, sensor_origin=view.sensor_origin)
    click = view_click(view)
    T = Registrar(TemplateLibrary([tpl])).fit(scene, click).candidates[0].T_scene_model
    return tpl, scene, click, T


@settings(
    max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(seed=st.integers(0, 2**31 - 1), far=st.floats(0.0, 2.0))
def test_a_scanned_templates_file_frame_does_not_matter(armadillo, seed, far):
    """The same scanned points in any rigid frame (turned anyhow, their origin up to 2 m
    away): the fit composed back into the first frame is the same pose."""
    tpl, scene, click, T0 = armadillo
    rng = np.random.default_rng(seed)
    B = make_T(random_rotations(1, rng)[0], far * rng.normal(size=3) / math.sqrt(3))
    moved = AffordanceTemplate(
        tpl.name,
        tpl.path,
        None,
        points=tpl.points @ B[:3, :3].T + B[:3, 3],
        point_normals=tpl.point_normals @ B[:3, :3].T,
    )
    T = Registrar(TemplateLibrary([moved])).fit(scene, click).candidates[0].T_scene_model
    dt, dr = pose_error(T @ B, T0)
    assert dt <= 1e-4 and math.degrees(dr) <= 0.01, (dt, math.degrees(dr))


def test_the_real_capture_cost_row_fits_real_and_simulated_clicks_alternately(data_dir, library):
    """The bench's row "real Kinect click against a simulated panel click": two pairs, each a
    real mOSD click and a simulated one on the same engine (CPU time), their medians and the
    median ratio; the suggested views of unsettled real clicks timed apart."""
    from affordance_registration.evaluation.bench_rows import simulated_jobs
    from affordance_registration.evaluation.rows import real_capture_cost

    jobs = simulated_jobs(library.specific(), [3])
    out = real_capture_cost(
        Registrar(library), jobs, clicks=2, scenes=rd.osd_scene_paths(data_dir, scenes=[0])
    )
    assert out["pairs"] == 2
    assert out["real_median_s"] > 0 and out["simulated_median_s"] > 0
    assert 0.05 < out["ratio"] < 50 and out["clock"] == "cpu"
    assert 0 <= out["views"] <= 2 and (out["view_median_s"] is None) == (out["views"] == 0)


def test_leaders_that_cannot_fit_are_left_unfinished_with_the_same_verdicts(data_dir, library):
    """On real objects the library does not hold, the leaders explaining far too little of the
    clicked object are neither articulated nor finished (``*.explained_margin``) -- and that
    changes no verdict and no primitive: against a registrar that works on every leader, each
    template's ``fits`` is the same and the primitives' poses and dimensions are equal; some
    refused candidate does keep its medium-resolution result (its residual differs)."""
    from affordance_registration.core.registration import FitSettings

    every = Registrar(
        library,
        FitSettings().with_(
            **{"finish.explained_margin": 1.0, "articulation.explained_margin": 1.0}
        ),
    )
    default = Registrar(library)
    left = 0
    for path in rd.osd_scene_paths(data_dir, scenes=rd.ORIGINAL_SCENES)[:6]:
        cloud = rd.read_labelled_pcd(path)
        scene = Scene(cloud.points.reshape(-1, 3), sensor_origin=cloud.viewpoint)
        obj = rd.labelled_objects(cloud)[0]
        a = {c.template: c for c in default.fit(scene, obj.click).candidates}
        b = {c.template: c for c in every.fit(scene, obj.click).candidates}
        assert a.keys() == b.keys()
        for name, c in a.items():
            assert c.fits == b[name].fits, (rd.scene_name(path), name)
            if c.primitive is not None:
                assert np.array_equal(c.T_scene_model, b[name].T_scene_model)
                assert c.dimensions == b[name].dimensions
            elif c.residual != b[name].residual:
                left += 1
                assert c.fits is False
    assert left > 0
