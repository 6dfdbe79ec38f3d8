# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Open-topped vessels -- mugs with and without a handle (``simulate_mugs``, development seeds
7000-7039; the bench's mug rows report held-out seeds too) -- fitted as the cylinder of their outer
radius and length, as the label rule scores a real mug. Clicked in the middle of what the
sensor sees of one, the click lands on its inside bottom, a few millimetres above the table."""

import math

import numpy as np
import pytest
from label_rule import assert_honest

from affordance_registration.core.registration import Registrar
from affordance_registration.core.registration.primitives import object_points, stacked
from affordance_registration.core.registration.scoring import judge, open_share, result
from affordance_registration.core.scene import Scene
from affordance_registration.core.transforms import invert
from affordance_registration.evaluation.rows import (
    DIM_TOL,
    _mosd_camera,
    label_score,
    primitive_pose_error,
    simulate_mugs,
    simulate_primitives,
)
from affordance_registration.evaluation.simulation import DepthCamera, FaultModel

#: (seed, mug) development clicks that came back as a refused taskboard template (7000:1,
#: 7009:0: the click was taken for one on the table, the table for the object), as a box 10 mm
#: tall (7007:1) or as a cylinder posed 7 mm off (7000:1 again, later); of the second
#: development set (7012-7039), clicks on the far inside wall, up to the rim (7027:0, 7038:0:
#: a taskboard template, a box 20 mm wide) and on an inside bottom among walls in pieces (7016:1)
HARD = [(7000, 1), (7009, 0), (7007, 1), (7003, 1), (7027, 0), (7038, 0), (7016, 1)]


@pytest.fixture(scope="module")
def registrar(library):
    reg = Registrar(library)
    reg.warm_up()
    return reg


@pytest.mark.parametrize("seed,k", HARD)
def test_a_mug_clicked_inside_is_a_cylinder_of_its_size(registrar, seed, k):
    """The cylinder measured on it has the mug's outside radius and length within 5 mm and its
    pose within 5 mm / 5 deg, and leads where it fits; it fits where the label rule passes (a
    mug seen from above shows its inside bottom a wall's thickness over the cylinder's base:
    where that is more than a tenth of what is seen, the closed cylinder does not explain the
    mug, and the verdict says so)."""
    organized, objects = simulate_mugs(seed)
    mug = objects[k]
    candidates = registrar.fit(Scene(organized), mug["click"]).candidates
    best = next(c for c in candidates if c.primitive == "cylinder")
    assert candidates[0] is best or not best.fits, (candidates[0].template, best.reason)
    assert all(abs(best.dimensions[a] - v) <= DIM_TOL for a, v in mug["dimensions"].items()), (
        best.dimensions,
        mug["dimensions"],
    )
    dt, dr = primitive_pose_error(
        "cylinder", best.T_scene_model, mug["T_scene_model"], mug["dimensions"]
    )
    assert dt <= 0.005 and dr <= math.radians(5), (dt, math.degrees(dr))
    assert_honest(best, label_score(organized, mug, best))


def test_the_click_inside_a_mug_is_not_on_the_table(registrar):
    """The click lies within the on-plane band of the table (its inside bottom is 6-12 mm up)
    but the table's surface does not reach it: the table stays the mount, taken off the
    cluster, and the clicked segment a primitive measures is the whole mug -- its inside
    joined to its outside (up to its rim, around its axis)."""
    organized, objects = simulate_mugs(7004)
    mug = objects[0]
    plain = registrar.prepare(Scene(organized), mug["click"])
    assert plain.plane is not None
    ctx = plain.with_insides()
    T_model = invert(mug["T_scene_model"])
    q = ctx.cluster[ctx.segments == ctx.clicked_segment] @ T_model[:3, :3].T + T_model[:3, 3]
    # (the segments the specific templates are judged on keep the inside apart: 72 points)
    assert (plain.segments == plain.clicked_segment).sum() < 0.2 * len(q)
    click = T_model[:3, :3] @ mug["click"] + T_model[:3, 3]
    assert click[2] < 0.015 and math.hypot(click[0], click[1]) < mug["dimensions"]["radius"]
    assert q[:, 2].max() > mug["dimensions"]["length"] - 0.01
    outside = np.hypot(q[:, 0], q[:, 1]) > mug["dimensions"]["radius"] - 0.002
    assert outside.mean() > 0.2 and q[:, 2].min() > -0.004  # its outside, not the table


def test_a_mug_seen_into_is_open_and_its_cylinder_fits_where_a_wider_one_does_not(registrar):
    """The mug's own cylinder (true pose and size) is seen into through its top (its open
    share at least 3%) and fits; the same cylinder 25 mm wider on the same base is refused
    (the table is seen through it beside the mug)."""
    organized, objects = simulate_mugs(7000)
    mug = objects[1]
    ctx = registrar.prepare(Scene(organized), mug["click"]).with_insides()
    cyl, dims, T = registrar.library["cylinder"], mug["dimensions"], mug["T_scene_model"]
    models = [
        registrar.models.model(
            cyl.sized({"radius": dims["radius"] + extra, "length": dims["length"]})
        )
        for extra in (0.0, 0.025)
    ]
    assert open_share(ctx, models[0], T, registrar.settings) >= 0.03
    judged = judge(
        ctx,
        models,
        [result(ctx, m, T[:3, :3], T[:3, 3], registrar.settings) for m in models],
        registrar.settings,
    )
    assert judged[0].fits is True, judged[0].reason
    assert judged[1].fits is False


def test_a_closed_can_is_not_open(registrar):
    """A closed cylinder (``simulate_primitives`` seed 5003's can) posed at its truth is not
    seen into (open share below 1%)."""
    organized, objects = simulate_primitives(5003)
    can = next(o for o in objects if o["kind"] == "cylinder" and o["visible"] >= 500)
    ctx = registrar.prepare(Scene(organized), can["click"])
    model = registrar.models.model(registrar.library["cylinder"].sized(can["dimensions"]))
    assert open_share(ctx, model, can["T_scene_model"], registrar.settings) < 0.01


def test_a_stepped_top_is_not_an_opening(registrar, library):
    """An emergency stop lying on a table (simulated table seed 2004, its second object): the
    cylinder around it is seen into through the ring of its top face round the button (the
    housing's shoulder lies inside it), which is no opening -- the seen-into part lies outward
    of the covered one. The e-stop is accepted (were the ring an opening, the cylinder would
    fit, and the e-stop, its button the only part a cylinder lacks, be refused as no more than
    one)."""
    from affordance_registration.evaluation.bench_rows import simulated_jobs

    scene, obj = simulated_jobs(library.specific(), [2004], layout="table")[1]
    assert obj.template == "emergency_stop"
    best = registrar.fit(scene, obj.click).candidates[0]
    assert best.template == "emergency_stop" and best.fits is True, best.reason


#: development mugs seen by a faulty sensor (:class:`FaultModel`): "fly" its flying pixels on
#: depth edges alone, "all" every fault at its defaults. Their inside bottom and rim were two
#: levels to the stack cut, which measured the inside as a box 10 mm tall (7018:1) or the mug
#: as a cylinder 20 mm long (7018:0), and accepted it
FLAKY = {
    "fly": FaultModel(distortion=0.0, dark_patches=0, noise_scale=1.0, grazing_start_deg=90),
    "all": FaultModel(),
}


@pytest.mark.parametrize("faults,seed,k", [("fly", 7018, 1), ("all", 7018, 0)])
def test_a_mug_is_not_cut_as_a_stack_and_nothing_wrong_is_accepted(registrar, faults, seed, k):
    """Its inside bottom lies within its rim seen from above (a stack's lower top shows round
    the upper box): no cut; and whatever leads, nothing but the mug's own cylinder fits."""
    organized, objects = simulate_mugs(
        seed, camera=DepthCamera(_mosd_camera(), faults=FLAKY[faults])
    )
    mug = objects[k]
    ctx = registrar.prepare(Scene(organized), mug["click"]).with_insides()
    assert stacked(ctx, object_points(ctx)) is None
    best = registrar.fit(Scene(organized), mug["click"]).candidates[0]
    right = best.primitive == "cylinder" and all(
        abs(best.dimensions[a] - v) <= DIM_TOL for a, v in mug["dimensions"].items()
    )
    assert best.fits is False or right, (best.template, best.dimensions)
