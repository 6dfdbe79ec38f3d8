# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Primitive templates (a box, a cylinder) and the verdict that says whether a template
explains the clicked object: loading, fitting on simulated scans with true dimensions, ranking
against specific templates, the engine's dimension corrections, save and reload, ``fit --json``.
The real-data cases (mOSD, PCL's milk carton) are in test_real_verdict.py."""

import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from affordance_registration.core.engine import AffordanceEngine, load_registrations
from affordance_registration.core.errors import AffordanceError, EngineStateError, TemplateError
from affordance_registration.core.registration import Registrar, no_match, verdict
from affordance_registration.core.scene import Scene
from affordance_registration.core.templates import TemplateLibrary, load_template
from affordance_registration.evaluation.rows import (
    DIM_TOL,
    primitive_pose_error,
    simulate_primitives,
)
from affordance_registration.evaluation.simulation import simulate_taskboard


@pytest.fixture(scope="module")
def registrar(library):
    reg = Registrar(library)
    reg.warm_up()
    return reg


@pytest.fixture(scope="module")
def primitive_clicks():
    """Objects of seeded simulated tables of boxes and cylinders (true dimensions), each with
    its scene: [(scene, object dict)]."""
    out = []
    for seed in range(5000, 5004):
        organized, objects = simulate_primitives(seed)
        scene = Scene(organized)
        out += [(scene, o) for o in objects if o["visible"] >= 500]
    return out


def test_the_default_library_ships_a_box_and_a_cylinder(library):
    assert library["box"].primitive == "box" and library["cylinder"].primitive == "cylinder"
    assert set(library["box"].dimension_ranges) == {"x", "y", "z"}
    assert set(library["cylinder"].dimension_ranges) == {"radius", "length"}
    # the crop around a click is set by the specific templates, as before
    assert library.max_diameter == library.specific().max_diameter
    assert "box" not in library.specific() and len(library.specific()) == len(library) - 2


def test_a_sized_primitive_has_that_size_in_its_frame(library):
    box = library["box"].sized({"x": 0.2, "y": 0.1, "z": 0.05})
    lo, hi = box.mesh.bounds
    assert np.allclose(lo, [-0.1, -0.05, 0.0]) and np.allclose(hi, [0.1, 0.05, 0.05])
    can = library["cylinder"].sized({"radius": 0.04, "length": 0.12})
    lo, hi = can.mesh.bounds
    assert np.isclose(lo[2], 0.0) and np.isclose(hi[2], 0.12)
    assert np.isclose(np.abs(can.mesh.vertices[:, :2]).max(), 0.04, atol=1e-3)
    # clipped to the ranges
    assert (
        library["cylinder"].sized({"radius": 5.0, "length": 0.1}).dimensions["radius"]
        == library["cylinder"].dimension_ranges["radius"][1]
    )


@pytest.mark.parametrize(
    "doc, key",
    [
        ({"primitive": "sphere", "radius": [0.1, 0.2]}, "primitive"),
        ({"primitive": "box"}, "size"),
        ({"primitive": "box", "size": {"x": [0.1, 0.2], "y": [0.1, 0.2]}}, "size"),
        (
            {"primitive": "box", "size": {"x": [0.3, 0.2], "y": [0.1, 0.2], "z": [0.1, 0.2]}},
            "size.x",
        ),
        ({"primitive": "cylinder", "radius": [0.01, 0.1]}, "length"),
        ({"primitive": "cylinder", "radius": "wide", "length": [0.1, 0.2]}, "radius"),
        (
            {"primitive": "cylinder", "radius": [0.01, 0.1], "length": [0.1, float("nan")]},
            "length",
        ),
        (
            {
                "primitive": "box",
                "size": {"x": [0.1, 0.2], "y": [0.1, 0.2], "z": [0.1, 0.2]},
                "mesh": "a.stl",
            },
            "mesh",
        ),
        (
            {"primitive": "cylinder", "radius": [0.01, 0.1], "length": [0.1, 0.2], "size": {}},
            "size",
        ),
    ],
)
def test_a_broken_primitive_file_is_one_line_naming_the_key(tmp_path, doc, key):
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({"name": "p", **doc}))
    with pytest.raises(TemplateError) as err:
        load_template(str(path))
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and f"key '{key}'" in msg


def test_boxes_and_cylinders_are_measured_with_their_true_dimensions(
    registrar, primitive_clicks, library
):
    """Every simulated box and cylinder (the default library: five specific templates, a box
    and a cylinder) is shown as its primitive, its dimensions within 5 mm and its pose within
    5 mm / 5 deg on most clicks, and 'no template fits here; fitted as ...' is the verdict."""
    right = dims_ok = pose_ok = 0
    for scene, obj in primitive_clicks:
        rep = registrar.fit(scene, obj["click"])
        best = rep.candidates[0]
        if best.primitive != obj["kind"]:
            continue
        right += 1
        assert no_match(rep.candidates)
        if best.fits:
            assert verdict(rep.candidates).startswith(
                f"no template fits here; fitted as a {obj['kind']}"
            )
        dims_ok += all(
            abs(best.dimensions[k] - v) <= DIM_TOL for k, v in obj["dimensions"].items()
        )
        dt, dr = primitive_pose_error(
            obj["kind"], best.T_scene_model, obj["T_scene_model"], obj["dimensions"]
        )
        pose_ok += dt <= 0.005 and math.degrees(dr) <= 5.0
    n = len(primitive_clicks)
    assert n >= 8
    assert right >= 0.8 * n and dims_ok >= 0.6 * n and pose_ok >= 0.8 * n, (
        n,
        right,
        dims_ok,
        pose_ok,
    )


def test_a_specific_template_that_fits_outranks_the_primitives(registrar, panel_scene):
    """On the taskboard, a fitting specific template is shown; the primitives come after the
    specific templates and the verdict says the template fits."""
    for obj in panel_scene.objects[:3]:
        rep = registrar.fit(Scene(panel_scene.organized), obj.click)
        best = rep.candidates[0]
        assert best.template == obj.template and best.fits and best.primitive is None
        kinds = [c.primitive is not None for c in rep.candidates if not c.prefiltered]
        assert kinds == sorted(kinds)  # every specific template before a primitive
        assert verdict(rep.candidates) == "fits" and not no_match(rep.candidates)


def test_a_box_measured_from_part_of_its_segment_is_refused(registrar):
    """``simulate_primitives`` seed 5009's large box (0.228 x 0.155 x 0.100 m): its top face's
    noisy smooth patches join into two segments, and the box measured from the clicked one is
    0.095 m deep. The patch of the top face it leaves out does not count as a neighbour for a
    primitive (it is held to all of what it was measured from, while a specific template
    is not held to patches it does not come near): the box explains too little and is refused,
    not shown as a fit at the wrong size."""
    organized, objects = simulate_primitives(5009)
    obj = objects[0]
    assert obj["kind"] == "box" and abs(obj["dimensions"]["y"] - 0.155) < 0.001
    box = next(
        c for c in registrar.fit(Scene(organized), obj["click"]).candidates if c.primitive == "box"
    )
    assert box.dimensions["y"] < obj["dimensions"]["y"] - 0.03  # (the premise)
    assert box.fits is False and box.explained < 0.8 and "explains" in box.reason


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.booleans(), st.booleans(), st.floats(1.0, 1000.0)), min_size=1, max_size=8
    )
)
def test_who_leads_when_nothing_specific_fits(rows):
    """The ranking's rule (docs/TEMPLATES.md, "Primitives"): a specific template that
    fits leads; else a primitive that fits; where nothing fits, the specific templates stay
    first as the best guess (the right object refused at its right pose, its segment joined
    to a neighbour, is shown rather than a box around both); within a group, by likelihood."""
    from affordance_registration.core.registration.results import FitResult, rank

    results = [
        FitResult(
            template=f"{'box' if prim else 't'}{i}",
            T_scene_model=np.eye(4),
            residual=1.0 / lik,
            likelihood=lik,
            fits=fits,
            primitive="box" if prim else None,
        )
        for i, (prim, fits, lik) in enumerate(rows)
    ]
    ranked = rank(results)
    assert sorted(r.template for r in ranked) == sorted(r.template for r in results)
    assert [r.rank for r in ranked] == list(range(1, len(rows) + 1))
    specific_fits = any(f and not p for p, f, _ in rows)
    primitive_fits = any(f and p for p, f, _ in rows)
    leaders_are_primitives = primitive_fits and not specific_fits
    group = [(r.primitive is not None) != leaders_are_primitives for r in ranked]
    assert group == sorted(group)
    for a, b in zip(ranked, ranked[1:]):
        if (a.primitive is None) == (b.primitive is None):
            assert a.likelihood >= b.likelihood
    if any(not p for p, _, _ in rows) and not primitive_fits:
        assert ranked[0].primitive is None
        assert no_match(ranked) == (ranked[0].fits is not True)
    if leaders_are_primitives:
        assert ranked[0].primitive == "box" and no_match(ranked)


@pytest.mark.parametrize("seed", [2000, 2001])
def test_an_emergency_stop_shows_what_sets_it_apart_from_a_box(registrar, seed):
    """An emergency stop lying on a table: it is shown and fits; a box measured on it leaves
    its button out -- it explains less than ``verdict.min_recall`` of the object, and is
    refused -- or, where a box does explain it, the e-stop shows what sets it apart from the
    box (the distinction test was made, the share seen above the bar)."""
    sim = simulate_taskboard(TemplateLibrary.load().specific(), seed, layout="table")
    stops = [o for o in sim.objects if o.template == "emergency_stop" and o.visible_points >= 200]
    assert stops
    v = registrar.settings.verdict
    for obj in stops:
        candidates = registrar.fit(Scene(sim.organized), obj.click).candidates
        best = candidates[0]
        assert best.template == "emergency_stop" and best.fits is True, best.reason
        box = next(c for c in candidates if c.primitive == "box")
        if box.recall >= v.min_recall:
            assert best.distinct is not None and best.distinct >= v.min_distinct
        else:
            assert box.fits is False and "explains" in box.reason, box.reason


def test_a_template_that_describes_the_object_worse_than_a_box_is_no_fit(registrar):
    """The upper box of a stacked pair (``simulate_stack`` seed 4, 95 x 74 x 81 mm) is covered
    by an emergency stop's housing lying on its side, button away from the sensor: nothing
    that sets the e-stop apart is seen (no distinction test), but the housing leaves the box's
    longer edges off its surface where the box primitive lies on all of it -- the box
    describes the object's points better for all its three more numbers (description
    length), the e-stop does not fit, says so, and the box is shown, fitting, within 5 mm of
    the box's dimensions."""
    from affordance_registration.evaluation.rows import simulate_stack

    organized, objects = simulate_stack(4)
    obj = objects[1]
    rep = registrar.fit(Scene(organized), obj["click"])
    stop = [c for c in rep.candidates if c.template == "emergency_stop"][0]
    box = [c for c in rep.candidates if c.template == "box"][0]
    assert stop.fits is False and box.fits is True
    assert "a box describes the clicked object better" in stop.reason, stop.reason
    box_share, stop_share = (int(v) for v in re.findall(r"([0-9]+)%", stop.reason)[:2])
    assert box_share > stop_share
    best = rep.candidates[0]
    assert best.primitive == "box" and best.fits is True
    assert all(abs(best.dimensions[a] - v) <= DIM_TOL for a, v in obj["dimensions"].items()), (
        best.dimensions
    )


def test_a_refit_keeps_the_clicks_verdict_against_the_primitives(library, panel_scene):
    """The operator shows the refused emergency stop on the stacked box and refits it: the
    refit's verdict still weighs it against the box (it stays refused, saying why) -- it
    read "fits" before, the refit judged it alone. A right taskboard fit refitted stays
    accepted."""
    from affordance_registration.evaluation.rows import simulate_stack

    organized, objects = simulate_stack(4)
    engine = AffordanceEngine(library)
    engine.set_scene(organized, frame_id="cam")
    engine.click(objects[1]["click"])
    engine.select_model("emergency_stop")
    for _ in range(2):
        shown = engine.active_object().shown
        assert shown.template == "emergency_stop" and shown.fits is False
        assert "a box describes the clicked object better" in shown.reason
        engine.refit()
    engine = AffordanceEngine(library)
    engine.set_scene(panel_scene.organized, frame_id="cam")
    for obj in panel_scene.objects[:2]:
        engine.click(obj.click)
        engine.refit()
        shown = engine.active_object().shown
        assert shown.template == obj.template and shown.fits is True, shown.reason


def _table_scene(boxes, poles, seed=0, meshes=(), elevation=30.0):
    """A simulated table (the mOSD camera 1 m away, ``elevation`` deg above it, looking along
    +y) with ``boxes`` [((x, y, z) extents, (px, py))], standing ``poles`` [(radius, height,
    (px, py))] and ``meshes`` [(trimesh, T_table_mesh)]: (organized, labels), label 1 the
    first of them."""
    import trimesh

    from affordance_registration.core.transforms import invert, make_T
    from affordance_registration.evaluation.rows import TABLE, _look_at, _mosd_camera
    from affordance_registration.evaluation.simulation import DepthCamera

    extra = list(meshes)
    meshes = [(trimesh.creation.box(extents=TABLE), make_T(None, [0, 0, -TABLE[2] / 2]))]
    meshes += [
        (trimesh.creation.box(extents=ext), make_T(None, [px, py, ext[2] / 2]))
        for ext, (px, py) in boxes
    ]
    meshes += [
        (trimesh.creation.cylinder(radius=r, height=h, sections=48), make_T(None, [px, py, h / 2]))
        for r, h, (px, py) in poles
    ]
    meshes += extra
    e = math.radians(elevation)
    T_cam_table = invert(_look_at(np.array([0.0, -math.cos(e), math.sin(e)]), np.zeros(3)))
    return DepthCamera(_mosd_camera()).render(
        [(m, T_cam_table @ T) for m, T in meshes], np.random.default_rng(seed)
    )


def _gable_carton(x: float, y: float, body: float, ridge: float):
    """A milk carton's shape: an x by y by ``body`` box under a gable roof whose ridge (along
    x, ``ridge`` m above the base) runs over the middle of the top."""
    import trimesh

    corners = [
        (sx * x / 2, sy * y / 2, z) for z in (0.0, body) for sx in (-1, 1) for sy in (-1, 1)
    ]
    return trimesh.convex.convex_hull(
        np.array(corners + [(-x / 2, 0.0, ridge), (x / 2, 0.0, ridge)])
    )


@pytest.mark.parametrize("yaw", [45.0, 70.0])
def test_a_gable_top_carton_is_measured_to_its_body(registrar, yaw):
    """A carton 0.095 m square, its body 0.20 m tall under a ridge 0.245 m up, turned so both
    roof slopes are seen: the box's top face is only the strip along the ridge, and the box
    is measured to where the carton's points end across it, not to the strip's edge (which
    made it half as deep), its height between the eaves and the ridge. A box leaves the
    roof's slopes out: it is refused for the share of the carton it explains, as the label
    rule refuses it."""
    from label_rule import assert_honest

    from affordance_registration.core.transforms import axis_angle_matrix, make_T
    from affordance_registration.evaluation.realdata import click_in_middle, score_points

    carton = (
        _gable_carton(0.095, 0.095, 0.20, 0.245),
        make_T(axis_angle_matrix([0, 0, 1], math.radians(yaw)), [0.0, 0.0, 0.0]),
    )
    organized, labels = _table_scene([], [], meshes=[carton], elevation=50.0)
    click = np.asarray(click_in_middle(organized, labels == 1)[0], float)
    rep = registrar.fit(Scene(organized), click)
    box = next(c for c in rep.candidates if c.primitive == "box")
    assert abs(box.dimensions["x"] - 0.095) <= DIM_TOL, box.dimensions
    assert abs(box.dimensions["y"] - 0.095) <= DIM_TOL, box.dimensions
    assert 0.20 - DIM_TOL <= box.dimensions["z"] <= 0.245, box.dimensions
    valid = np.all(np.isfinite(organized), axis=-1)
    score = score_points(
        organized[valid], labels[valid] == 1, "box", box.T_scene_model, box.dimensions
    )
    assert score.recall < 0.9 and box.fits is False and "explains" in box.reason, box.reason
    assert_honest(box, score)


def _split_box(side: str):
    """A 0.26 m box behind a pole that splits it in two, clicked in the middle of its ``side``
    ("left" or "right") piece: (organized, click (3,))."""
    from affordance_registration.evaluation.realdata import click_in_middle

    organized, labels = _table_scene(
        [((0.26, 0.06, 0.08), (0.0, 0.0))], [(0.03, 0.30, (0.0, -0.14))]
    )
    box = labels == 1
    cols = np.nonzero(box.any(axis=0))[0]
    column = np.arange(box.shape[1])[None, :]
    piece = box & ((column < cols.mean()) if side == "left" else (column > cols.mean()))
    return organized, np.asarray(click_in_middle(organized, piece)[0], float)


@pytest.mark.parametrize("side", ["left", "right"])
def test_a_box_split_by_a_pole_in_front_is_measured_whole(registrar, side):
    """A 0.26 m box seen left and right of a pole standing in front of it: a click on either
    piece measures the whole box (the line between the pieces is hidden behind the pole)."""
    organized, click = _split_box(side)
    best = registrar.fit(Scene(organized), click, templates=["box"]).candidates[0]
    assert abs(best.dimensions["x"] - 0.26) <= DIM_TOL, best.dimensions
    assert best.fits is True


@settings(max_examples=4, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1))
def test_the_split_box_measures_the_same_in_any_frame(registrar, split_box, seed):
    """The split box's scan, click and sensor origin moved by a random rigid transform: the
    same dimensions (the pieces, the line between them and what hides it do not depend on the
    scan's axes)."""
    from affordance_registration.core.transforms import make_T, random_rotations

    organized, click, dims = split_box
    rng = np.random.default_rng(seed)
    T = make_T(random_rotations(1, rng)[0], rng.uniform(-3.0, 3.0, 3))
    pts = organized.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    moved = registrar.fit(
        Scene(pts, sensor_origin=T[:3, 3]), T[:3, :3] @ click + T[:3, 3], templates=["box"]
    ).candidates[0]
    for key, value in dims.items():
        assert abs(moved.dimensions[key] - value) <= 1e-4, (key, moved.dimensions, dims)


@pytest.fixture(scope="module")
def split_box(registrar):
    """The split box (:func:`_split_box`), clicked on its left piece: (organized, click, the
    fitted dimensions in the camera frame)."""
    organized, click = _split_box("left")
    best = registrar.fit(Scene(organized), click, templates=["box"]).candidates[0]
    return organized, click, dict(best.dimensions)


def test_two_boxes_with_the_table_seen_between_them_stay_two(registrar):
    """Two 0.10 m boxes 4 cm apart with nothing in front: the table shows between them, so a
    click on one measures that one alone."""
    from affordance_registration.evaluation.realdata import click_in_middle

    organized, labels = _table_scene(
        [((0.10, 0.06, 0.08), (-0.07, 0.0)), ((0.10, 0.06, 0.08), (0.07, 0.0))], []
    )
    for label in (1, 2):
        best = registrar.fit(
            Scene(organized), click_in_middle(organized, labels == label)[0], templates=["box"]
        ).candidates[0]
        assert abs(best.dimensions["x"] - 0.10) <= DIM_TOL, best.dimensions


def test_the_verdict_refuses_what_does_not_explain_the_object(registrar, panel_scene, library):
    """A small template inside a big object's points covers itself but explains little of
    the object: refused with the reason; the same fit of the right template is accepted."""
    obj = next(o for o in panel_scene.objects if o.template == "gate_valve")
    rep = Registrar(TemplateLibrary([library["emergency_stop"]])).fit(
        Scene(panel_scene.organized), obj.click
    )
    wrong = rep.candidates[0]
    assert wrong.fits is False and wrong.reason and "explains" in wrong.reason
    assert wrong.explained < 0.8
    right = (
        Registrar(TemplateLibrary([library["gate_valve"]]))
        .fit(Scene(panel_scene.organized), obj.click)
        .candidates[0]
    )
    assert right.fits and right.reason is None and right.explained >= 0.8


def test_the_noise_estimate_follows_the_scan(library):
    """The scan's noise around a click (which widens the verdict's distances) reads the
    simulated Kinect's millimetre and grows with the noise of the scan."""
    sim = simulate_taskboard(library, 7)
    obj = sim.objects[0]
    reg = Registrar(library.specific())
    clean = reg.prepare(Scene(sim.organized), obj.click).noise
    rng = np.random.default_rng(0)
    rays = sim.organized / np.maximum(np.linalg.norm(sim.organized, axis=-1, keepdims=True), 1e-9)
    noisy_pts = sim.organized + rays * rng.normal(
        scale=0.004, size=sim.organized.shape[:-1] + (1,)
    )
    noisy = reg.prepare(Scene(noisy_pts), obj.click).noise
    assert 0.0003 < clean < 0.003
    assert noisy > 1.5 * clean


@pytest.mark.parametrize("gap", [0.01, 0.0])
def test_segments_keep_a_convex_object_whole_and_cut_touching_ones(library, gap):
    """A box and a cylinder standing on a table a centimetre apart or touching -- one cluster
    (its gap is 2.5 cm) -- fall into two segments, each mostly one object."""
    a = library["box"].sized({"x": 0.12, "y": 0.08, "z": 0.10})
    b = library["cylinder"].sized({"radius": 0.04, "length": 0.16})
    import trimesh

    from affordance_registration.core.transforms import invert, make_T
    from affordance_registration.evaluation.rows import _look_at
    from affordance_registration.evaluation.simulation import DepthCamera

    table = trimesh.creation.box(extents=(1.0, 1.0, 0.02))
    # a camera 0.9 m from the pair, 50 deg above the table, looking at them
    T_cam_table = invert(_look_at(np.array([0.05, -0.58, 0.69]), np.array([0.05, 0.0, 0.05])))
    meshes = [
        (table, T_cam_table @ make_T(None, [0, 0, -0.01])),
        (a.mesh, T_cam_table @ make_T(None, [0.0, 0.0, 0.0])),
        (b.mesh, T_cam_table @ make_T(None, [0.06 + 0.04 + gap, 0.0, 0.0])),
    ]
    organized, labels = DepthCamera().render(meshes, np.random.default_rng(1))
    scene = Scene(organized)
    click = organized[labels == 1][len(organized[labels == 1]) // 2]
    ctx = Registrar(library.specific()).prepare(scene, click)
    from scipy.spatial import cKDTree

    pts = organized[labels > 0]
    _, idx = cKDTree(pts).query(ctx.cluster)
    owner = labels[labels > 0][idx]
    assert set(np.unique(owner)) == {1, 2}  # both objects are in the cluster
    seg = ctx.segments
    for k in (1, 2):
        mine = owner == k
        # most of each object lies in one segment, and that segment is mostly that object
        main = np.bincount(seg[mine]).argmax()
        assert (seg[mine] == main).mean() > 0.8
        assert (owner[seg == main] == k).mean() > 0.9


#: (seed, box: 0 the lower, 1 the upper) of ``simulate_stack`` scenes the concave-step rule
#: and the floor search were developed on, and whether the fit measures that box within 5 mm:
#: the lower box of seed 6 is measured from its part on one side of the upper one (the upper
#: boxes of seeds 2 and 11 are those whose crop's dominant plane is the lower box's side face
#: in front of them; seed 11's was measured 15 mm too long from the lower box's top face
#: points next to it, which face up too)
STACKED = [
    (2, 0, True),
    (2, 1, True),
    (3, 1, True),
    (6, 0, True),
    (6, 1, True),
    (8, 0, True),
    (8, 1, True),
    (11, 1, True),
]


@pytest.mark.parametrize("seed,k,measured", STACKED)
def test_segments_cut_a_box_standing_on_another(library, seed, k, measured):
    """Two stacked boxes (``simulate_stack``): where the upper one's sides meet the lower
    one's top face -- a concave step whose two sides' means nearly cancel in the convexity
    test -- the segments cut: the clicked segment is that box, and it is fitted as a box
    standing as it does (its z within 5 deg of the box's: an upper box does not stand on the
    face of the lower one in front of it), its dimensions within 5 mm where ``measured``
    (seed 6's lower box reaches the crop's edge; the wider crop's coarser segments split it
    where the upper box stands: it is measured in the first crop, which holds all of it). The
    bench's stacked rows report the seeds not looked at."""
    from affordance_registration.evaluation.realdata import box_distance
    from affordance_registration.evaluation.rows import simulate_stack

    organized, objects = simulate_stack(seed)
    scene = Scene(organized)
    reg = Registrar(library)
    obj = objects[k]
    ctx = reg.prepare(scene, obj["click"])
    d = np.stack(
        [box_distance(ctx.cluster, o["T_scene_model"], o["dimensions"]) for o in objects], axis=1
    )
    on = d.min(axis=1) <= 0.006
    owner = np.where(on, d.argmin(axis=1), -1)
    assert set(np.unique(owner[on])) == {0, 1}  # both boxes are in the cluster
    clicked = ctx.segments == ctx.clicked_segment
    assert (owner[clicked] == k).mean() > 0.9
    assert (clicked[owner == k]).mean() > 0.8
    best = next(c for c in reg.fit(scene, obj["click"]).candidates if c.primitive == "box")
    tilt = math.degrees(math.acos(abs(best.T_scene_model[:3, 2] @ obj["T_scene_model"][:3, 2])))
    assert tilt <= 5.0, tilt
    if measured:
        assert all(abs(best.dimensions[a] - v) <= DIM_TOL for a, v in obj["dimensions"].items()), (
            best.dimensions
        )


def test_engine_dimension_corrections_undo_save_and_reload(library, primitive_clicks, tmp_path):
    scene, obj = next((s, o) for s, o in primitive_clicks if o["kind"] == "cylinder")
    engine = AffordanceEngine(library)
    engine.set_scene(scene.points, frame_id="cam")
    engine.click(obj["click"])
    shown = engine.active_object().shown
    assert shown.primitive == "cylinder"
    before = dict(shown.dimensions)
    msg = engine.correct_dimension("radius", value=before["radius"] + 0.01)
    assert "radius" in msg
    after = engine.active_object().shown.dimensions
    assert after["radius"] == pytest.approx(before["radius"] + 0.01, abs=1e-4)
    assert after["length"] == pytest.approx(before["length"], abs=1e-4)
    # a refit keeps the operator's dimensions
    engine.refit()
    assert engine.active_object().shown.dimensions == after
    engine.correct_dimension("length", steps=2)
    assert engine.active_object().shown.dimensions["length"] == pytest.approx(
        after["length"] + 2 * engine.dimension_step_m, abs=1e-4
    )
    engine.undo()
    assert engine.active_object().shown.dimensions == after
    with pytest.raises(AffordanceError, match="radius, length"):
        engine.correct_dimension("x", value=0.1)
    with pytest.raises(AffordanceError, match="finite"):
        engine.correct_dimension("radius", value=float("nan"))
    status = engine.status()["objects"][0]
    assert status["verdict"].startswith("no template fits here")
    assert status["candidates"][0]["dimensions"]["radius"] == pytest.approx(
        after["radius"], abs=1e-5
    )
    engine.accept()
    path = engine.save(str(tmp_path / "regs.yaml")).split(" to ")[-1]
    reg = load_registrations(path, library)[0]
    assert reg.primitive == "cylinder" and reg.dimensions == pytest.approx(after, abs=1e-5)
    doc = yaml.safe_load(open(path))
    assert doc["registrations"][0]["dimensions"]["radius"] == pytest.approx(
        after["radius"], abs=1e-5
    )
    # a file whose primitive lacks its dimensions is refused in one line
    doc["registrations"][0].pop("dimensions")
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc))
    with pytest.raises(AffordanceError, match="needs its 'dimensions'"):
        load_registrations(str(bad), library)


def test_a_specific_template_has_no_dimensions_to_correct(library, panel_scene):
    engine = AffordanceEngine(library)
    engine.set_scene(panel_scene.organized.reshape(-1, 3), frame_id="cam")
    engine.click(panel_scene.objects[0].click)
    with pytest.raises(EngineStateError, match="not a primitive"):
        engine.correct_dimension("x", value=0.1)


def test_fit_json_carries_the_primitive_its_dimensions_and_the_verdict(tmp_path, primitive_clicks):
    scene, obj = next((s, o) for s, o in primitive_clicks if o["kind"] == "box")
    from affordance_registration.evaluation.simulation import ply_bytes

    path = tmp_path / "boxes.ply"
    path.write_bytes(ply_bytes(scene.points))
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "affordance_registration.cli",
            "fit",
            "--scene",
            str(path),
            "--point",
            *map(str, obj["click"]),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    best = doc["candidates"][0]
    assert best["primitive"] == "box" and set(best["dimensions"]) == {"x", "y", "z"}
    assert doc["no_match"] is True and doc["verdict"].startswith("no template fits here")
    for c in doc["candidates"]:
        assert {"explained", "noise", "reason", "primitive", "dimensions", "fits"} <= set(c)
        if c["primitive"] is None:
            assert c["dimensions"] is None
    table = subprocess.run(
        [
            sys.executable,
            "-m",
            "affordance_registration.cli",
            "fit",
            "--scene",
            str(path),
            "--point",
            *map(str, obj["click"]),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert table.returncode == 0 and "fitted as a box" in table.stdout


def _long_box_on_table(library, dims):
    """A box of ``dims`` on a table 2.5 x 1.5 m, rendered from 0.7 m before and 0.8 m above
    it: (the organized cloud, a click in the middle of the box)."""
    import trimesh

    from affordance_registration.core.transforms import invert, make_T
    from affordance_registration.evaluation.rows import _look_at
    from affordance_registration.evaluation.simulation import DepthCamera

    box = trimesh.creation.box(extents=(dims["x"], dims["y"], dims["z"]))
    box.apply_translation([0, 0, dims["z"] / 2])  # the primitive's frame: base centre
    table = trimesh.creation.box(extents=(2.5, 1.5, 0.02))
    T_cam_table = invert(_look_at(np.array([0.0, -0.7, 0.8]), np.array([0.0, 0.0, 0.04])))
    organized, labels = DepthCamera().render(
        [(table, T_cam_table @ make_T(None, [0, 0, -0.01])), (box, T_cam_table)],
        np.random.default_rng(1),
    )
    pts = organized[labels == 1]
    return organized, pts[np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1))]


def test_a_box_longer_than_the_crop_is_measured_in_a_wider_one(library):
    """A 0.55 m box on a table -- past the crop around the click (the taskboard templates set it
    at 0.24 m) -- is measured again in a crop twice as large: fitted as a box, accepted, every
    dimension within 5 mm."""
    dims = {"x": 0.55, "y": 0.10, "z": 0.08}
    organized, click = _long_box_on_table(library, dims)
    rep = Registrar(library).fit(Scene(organized), click)
    assert rep.context.radius < dims["x"] / 2  # the box runs past the first crop
    best = rep.candidates[0]
    assert best.primitive == "box" and best.fits is True, best.reason
    assert all(abs(best.dimensions[k] - v) <= 0.005 for k, v in dims.items()), best.dimensions


def test_an_object_past_the_wider_crop_stays_refused_after_a_refit(library):
    """A 1.2 m box runs past the wider crop too: its box is refused at the click ("runs past
    ... it cannot be measured"), and a refit of it -- the engine's, from the object's own
    cloud, and the registrar's without a cloud to widen the crop from -- keeps that verdict
    (a refit judged the crop's part alone: a 0.6 m box explains it all, and read "fits").
    The 0.55 m box, measured in the wider crop, stays accepted after the engine's refit."""
    from affordance_registration.core.engine import AffordanceEngine

    for length, accepted in ((1.2, False), (0.55, True)):
        organized, click = _long_box_on_table(library, {"x": length, "y": 0.10, "z": 0.08})
        engine = AffordanceEngine(library)
        engine.set_scene(organized)
        engine.click(click)
        engine.select_model("box")
        for step in ("click", "refit"):
            if step == "refit":
                engine.refit()
            obj = engine.status()["objects"][0]
            box = obj["candidates"][obj["shown"]]
            assert box["template"] == "box" and box["fits"] is accepted, (length, step, box)
            assert accepted or "runs past" in box["reason"], box["reason"]
        if not accepted:
            registrar = Registrar(library)
            rep = registrar.fit(Scene(organized), click)
            fitted = next(c for c in rep.candidates if c.template == "box")
            again = registrar.refit(
                rep.context, "box", fitted.T_scene_model, dimensions=fitted.dimensions
            )
            assert again.fits is False and "runs past" in again.reason, again.reason
