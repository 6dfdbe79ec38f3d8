# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A primitive fits only where it explains the clicked object, the whole of it and only it
(``core/registration/explains.py``): the verdict's recall and precision, read off the click's
own segmentation, against the label rule computed from the simulator's truth."""

import numpy as np
import pytest
from label_rule import assert_honest

from affordance_registration.core.meshes import primitive_distance, primitive_normal
from affordance_registration.core.registration import Registrar
from affordance_registration.core.registration.explains import explanation
from affordance_registration.core.registration.primitives import object_points, object_voxels
from affordance_registration.core.scene import Scene
from affordance_registration.core.transforms import make_T
from affordance_registration.evaluation.realdata import box_distance, score_points
from affordance_registration.evaluation.rows import label_score, simulate_primitives

#: development scenes of boxes and standing cylinders (the bench's primitive rows' development
#: seeds; held-out 6000-6009 are not looked at here)
SEEDS = [5000, 5001, 5002, 5003]


@pytest.fixture(scope="module")
def registrar(library):
    reg = Registrar(library)
    reg.warm_up()
    return reg


@pytest.fixture(scope="module")
def fitted(registrar):
    """(organized, the object, its primitive of the right kind) for every clicked object of
    the development scenes."""
    out = []
    for seed in SEEDS:
        organized, objects = simulate_primitives(seed)
        for obj in objects:
            if obj["click"] is None or obj["visible"] < 300:
                continue
            rep = registrar.fit(Scene(organized), obj["click"])
            res = next(c for c in rep.candidates if c.primitive == obj["kind"])
            out.append((organized, obj, res, rep.context))
    assert len(out) >= 8
    return out


def test_the_verdicts_recall_and_precision_track_the_label_rule(fitted):
    """On every clicked object of the development tables the estimate read off the
    segmentation is within a few points of the truth's, and the verdict agrees with the rule
    wherever the truth is clear of its bar (:func:`label_rule.assert_honest`)."""
    for organized, obj, res, _ in fitted:
        score = label_score(organized, obj, res)
        assert abs(res.recall - score.recall) <= 0.03, (res.recall, score.to_dict())
        assert abs(res.precision - score.precision) <= 0.05, (res.precision, score.to_dict())
        assert_honest(res, score)


def test_a_box_measured_on_part_of_the_object_explains_too_little(registrar, fitted):
    """The right box cut to half its length -- a box measured on a part of the object --
    leaves half of the object's points off its surface: the recall falls below the bar, as
    the label rule's does."""
    organized, obj, res, ctx = next(f for f in fitted if f[1]["kind"] == "box")
    dims = dict(obj["dimensions"])
    dims["x"] /= 2
    T = obj["T_scene_model"] @ make_T(None, [-dims["x"] / 2, 0.0, 0.0])
    model = registrar.services.models.model(registrar.library["box"].sized(dims))
    e = _explanation(registrar, ctx, organized, model, T)
    valid = np.all(np.isfinite(organized), axis=-1)
    truth = score_points(organized[valid], obj["mask"][valid], "box", T, model.template.dimensions)
    assert e.recall < 0.9 and truth.recall < 0.9, (e, truth.to_dict())
    assert abs(e.recall - truth.recall) <= 0.05


def test_a_box_grown_over_the_table_explains_more_than_the_object(registrar, fitted):
    """The right box with its footprint 4 cm larger all round lies on the table around its
    base: what lies on its surface is less than 90% the object's, as the rule says."""
    organized, obj, res, ctx = next(f for f in fitted if f[1]["kind"] == "box")
    dims = dict(obj["dimensions"])
    dims["x"] += 0.08
    dims["y"] += 0.08
    model = registrar.services.models.model(registrar.library["box"].sized(dims))
    T = obj["T_scene_model"]
    e = _explanation(registrar, ctx, organized, model, T)
    valid = np.all(np.isfinite(organized), axis=-1)
    truth = score_points(organized[valid], obj["mask"][valid], "box", T, model.template.dimensions)
    assert e.precision < 0.9 and truth.precision < 0.9, (e, truth.to_dict())


def _explanation(registrar, ctx, organized, model, T):
    ctx = ctx.with_insides()
    pts = organized.reshape(-1, 3)
    scan = pts[np.all(np.isfinite(pts), axis=1)]
    return explanation(
        ctx,
        model,
        T,
        object_points(ctx)[0],
        scan[np.linalg.norm(scan - ctx.click, axis=1) <= ctx.radius],
        object_voxels(ctx),
        [],
        registrar.settings,
    )


def test_primitive_distances_and_normals_are_those_of_the_closed_surface():
    """The analytic distance agrees with the evaluation's own box distance, is zero on every
    face and grows off it; the normal of the nearest face points out of it."""
    rng = np.random.default_rng(3)
    dims = {"x": 0.2, "y": 0.1, "z": 0.05}
    pts = rng.uniform(-0.15, 0.15, size=(500, 3))
    assert np.allclose(
        primitive_distance("box", dims, pts), box_distance(pts, np.eye(4), dims), atol=1e-12
    )
    top = np.array([[0.03, -0.02, 0.05], [0.0, 0.0, 0.07]])
    assert np.allclose(primitive_distance("box", dims, top), [0.0, 0.02])
    assert np.allclose(primitive_normal("box", dims, top), [[0, 0, 1], [0, 0, 1]])
    side = np.array([[0.1, 0.0, 0.02], [-0.13, 0.01, 0.02]])
    assert np.allclose(primitive_normal("box", dims, side), [[1, 0, 0], [-1, 0, 0]])
    cyl = {"radius": 0.05, "length": 0.1}
    q = np.array([[0.05, 0.0, 0.05], [0.0, 0.0, -0.01], [0.0, 0.08, 0.05]])
    assert np.allclose(primitive_distance("cylinder", cyl, q), [0.0, 0.01, 0.03])
    assert np.allclose(primitive_normal("cylinder", cyl, q), [[1, 0, 0], [0, 0, -1], [0, 1, 0]])
