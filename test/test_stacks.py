# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Boxes standing on each other with a side of one flush with the other's (``simulate_stack``
seeds 1, 3 and 9, development seeds): the segments cannot part them (flush faces are one plane
to them), so the clicked segment holds both. Where no primitive explains it, the primitives are
measured and judged on the clicked box alone, cut at the top of the lower one's top face
(``primitives.stacked``). The bench's stacked rows report the held-out seeds."""

import math

import numpy as np
import pytest

from affordance_registration.core.engine import AffordanceEngine
from affordance_registration.core.registration import Registrar
from affordance_registration.core.registration.primitives import object_points, stacked
from affordance_registration.core.scene import Scene
from affordance_registration.evaluation.realdata import box_distance
from affordance_registration.evaluation.rows import DIM_TOL, primitive_pose_error, simulate_stack

#: (seed, box: 0 the lower, 1 the upper) whose clicked segment holds both boxes
FLUSH = [(1, 0), (1, 1), (3, 0), (9, 0), (9, 1)]
#: ... and of the second development set (seeds 200-239), clicks where one box measured on both
#: fitted and was accepted, its size wrong: the two boxes of 222 as one 171 mm tall (the upper
#: within 18 mm of the lower's edges), 215's lower box with the upper's height, 212's and 233's
#: upper box reaching over the lower one's top face
ONE_BOX = [(222, 0), (222, 1), (215, 0), (212, 1), (233, 1)]


@pytest.fixture(scope="module")
def registrar(library):
    reg = Registrar(library)
    reg.warm_up()
    return reg


def _owner(points, objects, within=0.006):
    d = np.stack(
        [box_distance(points, o["T_scene_model"], o["dimensions"]) for o in objects], axis=1
    )
    return np.where(d.min(axis=1) <= within, d.argmin(axis=1), -1)


@pytest.mark.parametrize("seed,k", FLUSH + ONE_BOX)
def test_a_box_of_a_flush_stack_is_measured_alone_and_accepted(registrar, seed, k):
    """The clicked box is shown as a box that fits, its dimensions within 5 mm and its pose
    within 5 mm / 5 deg (FLUSH: the segment held both boxes, the box measured on it explained
    66-72% of it and was refused, and a taskboard template led, refused too; ONE_BOX: the box
    measured on both fitted -- a box that fits has one top, and their up-facing points lie at
    two levels)."""
    organized, objects = simulate_stack(seed)
    obj = objects[k]
    best = registrar.fit(Scene(organized), obj["click"]).candidates[0]
    assert best.primitive == "box" and best.fits is True, (best.template, best.reason)
    assert all(abs(best.dimensions[a] - v) <= DIM_TOL for a, v in obj["dimensions"].items()), (
        best.dimensions
    )
    dt, dr = primitive_pose_error(
        "box", best.T_scene_model, obj["T_scene_model"], obj["dimensions"]
    )
    assert dt <= 0.005 and dr <= math.radians(5), (dt, math.degrees(dr))


@pytest.mark.parametrize("seed,k", [(1, 0), (1, 1)])
def test_the_cut_splits_the_clicked_segment_at_the_lower_top(registrar, seed, k):
    """The stack's segment is cut in two: the clicked part is the clicked box (over 95% of its
    cluster points, with over 90% of that box's), the rest a segment of its own; the other
    segments are as they were."""
    organized, objects = simulate_stack(seed)
    ctx = registrar.prepare(Scene(organized), objects[k]["click"])
    owner = _owner(ctx.cluster, objects)
    was = ctx.segments == ctx.clicked_segment
    assert (owner[was] == 1 - k).mean() > 0.3  # the segment held both boxes
    cut, (points, _, support, _) = stacked(ctx, object_points(ctx))
    part = cut.segments == cut.clicked_segment
    assert (owner[part] == k).mean() > 0.95 and part[owner == k].mean() > 0.9
    assert np.array_equal(cut.segments[~was], ctx.segments[~was])
    assert len(np.unique(cut.segments)) == len(np.unique(ctx.segments)) + 1
    # the upper box stands on the lower one's top face: its support is that face
    if k == 1:
        top = objects[0]["T_scene_model"] @ np.array([0, 0, objects[0]["dimensions"]["z"], 1])
        assert abs(support.distance(top[None, :3])[0]) < 0.003


def test_one_box_or_a_parted_stack_is_not_cut(registrar):
    """A box whose up-facing points lie at one height (a stack the segments parted: seed 0) is
    never cut."""
    organized, objects = simulate_stack(0)
    for obj in objects:
        ctx = registrar.prepare(Scene(organized), obj["click"])
        assert stacked(ctx, object_points(ctx)) is None


def test_a_dimension_correction_on_a_stack_keeps_the_fit(library):
    """The operator widens the lower box of a flush stack by 2 mm: the refit keeps its verdict
    (it is judged on that box, as at the click) and the dimension."""
    organized, objects = simulate_stack(1)
    engine = AffordanceEngine(library)
    engine.set_scene(organized, frame_id="cam")
    engine.click(objects[0]["click"])
    shown = engine.active_object().shown
    assert shown.primitive == "box" and shown.fits is True
    engine.correct_dimension("x", value=shown.dimensions["x"] + 0.002)
    again = engine.active_object().shown
    assert again.fits is True, again.reason
    assert again.dimensions["x"] == pytest.approx(shown.dimensions["x"] + 0.002)
