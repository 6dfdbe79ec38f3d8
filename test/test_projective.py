# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Projective correspondences (``icp.projective``, off by default): a posed sample pairs with the
target point the sensor sees nearest in its bin of the click's range image."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from affordance_registration.core.click_context import RangeImage


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400))
def test_front_points_are_the_nearest_to_the_sensor_in_each_bin(seed, n):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * 0.05 + [0.0, 0.0, 1.0]
    image = RangeImage(pts, np.zeros(3), 0.01, np.eye(3))
    front = image.front_points(pts)
    flat, z = image.bins(pts - image.origin)
    assert front.shape == (image.nu * image.nv + 1,) and front[-1] == -1
    for b in np.unique(flat):
        mine = np.flatnonzero(flat == b)
        assert front[b] in mine and z[front[b]] == z[mine].min()
    assert (front >= 0).sum() == len(np.unique(flat[flat < image.nu * image.nv]))


def test_projective_pairs_are_what_the_sensor_sees_in_each_samples_direction():
    from affordance_registration.core.registration import FitSettings, Registrar
    from affordance_registration.core.registration.correspondences import forward_pairs
    from affordance_registration.core.registration.settings import CLUSTER, IcpSettings
    from affordance_registration.core.scene import Scene
    from affordance_registration.core.templates import TemplateLibrary
    from affordance_registration.core.transforms import pose_points, rotate
    from affordance_registration.evaluation.simulation import simulate_taskboard

    library = TemplateLibrary.load().specific()
    sim = simulate_taskboard(library, seed=1000)
    obj = [o for o in sim.objects if o.visible_points >= 200][0]
    s = FitSettings(icp=IcpSettings(projective=True))
    ctx = Registrar(library, s).prepare(Scene(sim.organized), obj.click)
    P, N = library[obj.template].samples(200)
    R, t = obj.T_scene_model[None, :3, :3], obj.T_scene_model[None, :3, 3]
    X, Nw = pose_points(R, t, P[None]), rotate(R, N[None])
    Q, _, w = forward_pairs(ctx, CLUSTER, X, Nw, np.array([0.05]), s, normals=False)
    Qk, _, wk = forward_pairs(ctx, CLUSTER, X, Nw, np.array([0.05]), FitSettings(), False)
    paired = (w[0] > 0) & (np.abs(ctx.plane.distance(X[0])) > 1.5 * ctx.plane_threshold)
    assert paired.sum() > 20
    image = ctx.range_image
    bx, _ = image.bins(X[0][paired] - image.origin)
    bq, zq = image.bins(Q[0][paired] - image.origin)
    assert np.array_equal(bx, bq)  # the point the sensor sees in the sample's direction ...
    fb, fz = image.bins(ctx.cluster - image.origin)
    for b, z in zip(bq, zq):  # ... the nearest to it there
        assert z == fz[fb == b].min()
    # never nearer than the nearest point; at the true pose within a couple of voxels
    d = np.linalg.norm(X[0] - Q[0], axis=1)[paired]
    dk = np.linalg.norm(X[0] - Qk[0], axis=1)[paired]
    assert (d >= dk - 1e-12).all() and (d > dk + 1e-9).any()
    assert np.median(d) < 2 * ctx.voxel
