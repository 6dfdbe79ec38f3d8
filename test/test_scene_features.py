# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The scene's side of the scanned templates' feature matching (the cluster's descriptors) is
the click's: computed once a click context, shared by every scanned template, and gone with the
context."""

import gc

import numpy as np


def test_scene_descriptors_are_computed_once_a_click_and_go_with_it():
    from affordance_registration.core import memo
    from affordance_registration.core.registration import Registrar, features
    from affordance_registration.core.scene import Scene
    from affordance_registration.core.templates import TemplateLibrary
    from affordance_registration.evaluation.simulation import simulate_taskboard

    library = TemplateLibrary.load().specific()
    sim = simulate_taskboard(library, seed=1000)
    registrar = Registrar(library)
    ctx = registrar.prepare(Scene(sim.organized), sim.objects[0].click)
    cluster = features._cluster_features(ctx)
    assert cluster.shape == (len(ctx.cluster), 33)
    assert features._cluster_features(ctx) is cluster
    assert not cluster.flags.writeable  # shared: nobody may change it
    # what the memo gives is what computing them afresh gives
    fresh = features._fpfh(
        ctx.cluster,
        features._normals(ctx, ctx.cluster, ctx.cluster_tree),
        features.GLOBAL_RADIUS * ctx.voxel,
    )
    np.testing.assert_array_equal(cluster, fresh)
    # another context of the same click has its own; the memo goes with each context
    other = registrar.prepare(Scene(sim.organized), sim.objects[0].click)
    assert features._cluster_features(other) is not cluster
    key = id(ctx)
    assert key in memo._per_object
    del ctx, other
    gc.collect()
    assert key not in memo._per_object
