# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The label-refined fits the bench uses to tell a fitter's miss from the label rule's own reach
(evaluation/label_ceiling.py): a refinement that finds a primitive from the points on it, and on
the shared mOSD scenes (skipped with one line without them), what it says of the two tuning
objects the fitter misses."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from affordance_registration.core.registration import Registrar
from affordance_registration.core.scene import Scene
from affordance_registration.core.transforms import axis_angle_matrix, make_T, pose_error
from affordance_registration.evaluation import realdata as rd
from affordance_registration.evaluation.label_ceiling import label_refined, refined_score


def _box_seen_around(dims, n, rng, noise):
    """Points (n, 3) on all six faces of a box (base centre at the origin, +z up): views from
    all around. (From one view the faces not seen leave the box free to grow behind them: the
    refinement keeps the start there, as a closed surface's distance cannot tell.)"""
    hx, hy, hz = dims["x"] / 2, dims["y"] / 2, dims["z"]
    k = n // 6
    faces = [
        np.column_stack([rng.uniform(-hx, hx, k), rng.uniform(-hy, hy, k), np.full(k, z)])
        for z in (0.0, hz)
    ]
    for sign in (-1, 1):
        faces.append(
            np.column_stack(
                [np.full(k, sign * hx), rng.uniform(-hy, hy, k), rng.uniform(0, hz, k)]
            )
        )
        faces.append(
            np.column_stack(
                [rng.uniform(-hx, hx, k), np.full(k, sign * hy), rng.uniform(0, hz, k)]
            )
        )
    return np.vstack(faces) + rng.normal(0.0, noise, (6 * k, 3))


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_a_box_is_refined_onto_the_points_it_explains(seed):
    """From a start 8 mm and 4 deg off, each edge 8 mm off, the box refined on points of its
    faces (1 mm noise) lands within 1.5 mm / 1 deg and its edges within 1.5 mm."""
    rng = np.random.default_rng(seed)
    dims = {"x": rng.uniform(0.08, 0.3), "y": rng.uniform(0.05, 0.2), "z": rng.uniform(0.04, 0.25)}
    truth = make_T(
        axis_angle_matrix([0, 0, 1], rng.uniform(0, 2 * math.pi)), rng.uniform(-0.5, 0.5, 3)
    )
    local = _box_seen_around(dims, 3000, rng, 0.001)
    points = local @ truth[:3, :3].T + truth[:3, 3]
    turn = axis_angle_matrix(rng.normal(size=3), math.radians(4))
    start = make_T(turn @ truth[:3, :3], truth[:3, 3] + 0.008 * rng.choice([-1, 1], 3))
    off = {k: v + 0.008 * rng.choice([-1, 1]) for k, v in dims.items()}
    T, refined = label_refined("box", points, start, off)
    dt, dr = pose_error(T, truth)
    assert dt < 0.0015 and dr < math.radians(1), (dt, math.degrees(dr))
    assert all(abs(refined[k] - dims[k]) < 0.0015 for k in dims), (refined, dims)


@pytest.mark.parametrize(
    "scene,object_id,passes", [("learn17", 2, False), ("learn41", 2, False), ("learn0", 2, True)]
)
def test_the_tuning_misses_are_the_rules_not_the_fits(data_dir, library, scene, object_id, passes):
    """learn17's box and learn41's tin miss the label score's precision with the fitter's answer
    and with that answer refined on their own labelled points alike (the table within 6 mm of
    their lower edges); learn0's box passes both ways. The refined fit stays within 1 cm of the
    fitter's: both lie on the object."""
    cloud = rd.read_labelled_pcd(f"{rd.osd_dir(data_dir)}/{scene}.pcd")
    obj = [o for o in rd.labelled_objects(cloud) if o.id == object_id][0]
    scene = Scene(cloud.points.reshape(-1, 3), sensor_origin=cloud.viewpoint)
    best = [c for c in Registrar(library).fit(scene, obj.click).candidates if c.primitive][0]
    fitted = rd.score_primitive(cloud, obj, best.primitive, best.T_scene_model, best.dimensions)
    refined = refined_score(cloud, obj, best.primitive, best.T_scene_model, best.dimensions)
    assert fitted.passes is passes and refined.passes is passes, (fitted, refined)
    assert refined.recall >= 0.95 and abs(refined.precision - fitted.precision) < 0.03
    own = cloud.points.reshape(-1, 3)[
        cloud.valid.reshape(-1) & (cloud.object_ids.reshape(-1) == object_id)
    ]
    T, _ = label_refined(best.primitive, own, best.T_scene_model, best.dimensions)
    assert np.linalg.norm(T[:3, 3] - best.T_scene_model[:3, 3]) < 0.01
