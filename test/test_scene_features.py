# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The scene's side of the scanned templates' feature matching (the crop's and the cluster's
descriptors) is the click's: computed once a click context, shared by every scanned template,
and gone with the context."""

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
    crop, cluster = features._scene_features(ctx), features._cluster_features(ctx)
    paired = features._paired(ctx)
    assert len(ctx.crop) > len(paired) == features.MAX_PAIRS  # (a subset: can differ)
    assert crop.shape == (len(paired), 33) and cluster.shape == (len(ctx.cluster), 33)
    assert features._scene_features(ctx) is crop and features._cluster_features(ctx) is cluster
    assert not crop.flags.writeable  # shared: nobody may change it
    # what the memo gives is what computing every crop point's afresh gives at those points
    fresh = features._fpfh(
        ctx.crop,
        features._normals(ctx, ctx.crop, ctx.crop_tree),
        features.FEATURE_RADIUS * ctx.voxel,
    )
    np.testing.assert_array_equal(crop, fresh[paired])
    # another context of the same click has its own; the memo goes with each context
    other = registrar.prepare(Scene(sim.organized), sim.objects[0].click)
    assert features._scene_features(other) is not crop
    key = id(ctx)
    assert key in memo._per_object
    del ctx, other
    gc.collect()
    assert key not in memo._per_object
