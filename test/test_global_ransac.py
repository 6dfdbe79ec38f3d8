# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The cluster matching's RANSAC (:func:`affordance_registration.core.registration.features.
global_ransac`) on matched pairs with a known pose: it finds the pose from any share of
inliers down to a fifth (within 1 mm / 0.5 deg, every true pair held), in any frame (the same
draws, the pose moved with the frame), and stops early when every pair agrees."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from affordance_registration.core.registration.features import (
    FIRST_BATCH,
    GLOBAL_ITERATIONS,
    global_ransac,
)
from affordance_registration.core.transforms import make_T, pose_error, random_rotations

DISTANCE = 0.0075  #: 1.5 voxels of 5 mm, as on an mOSD click


def _pairs(seed: int, n: int, share: float):
    """``n`` template points (a 20 cm object) matched to scene points: the first ``share`` of
    them by a random pose (returned), the rest to random points of the same region."""
    rng = np.random.default_rng(seed)
    src = rng.uniform(-0.1, 0.1, size=(n, 3))
    R = random_rotations(1, rng)[0]
    t = rng.uniform(-3.0, 3.0, size=3)
    dst = src @ R.T + t
    k = int(round(share * n))
    dst[k:] = t + rng.uniform(-0.15, 0.15, size=(n - k, 3))
    return src, dst, make_T(R, t)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    share=st.floats(0.2, 1.0),
    frame_seed=st.integers(0, 10**6),
)
def test_the_pose_is_found_and_moves_with_the_frame(seed, share, frame_seed):
    src, dst, T = _pairs(seed, 300, share)
    R, t = global_ransac(src, dst, np.random.default_rng(1), DISTANCE)
    # every true pair held; an outlier that lands near its partner by chance may join the
    # least squares, so the pose is right within a tenth of the inlier distance
    k = int(round(share * 300))
    assert np.all(np.linalg.norm(src[:k] @ R.T + t - dst[:k], axis=1) < DISTANCE)
    e, a = pose_error(make_T(R, t), T)
    assert e < 1e-3 and math.degrees(a) < 0.5, (e, a)
    # the scene seen in another frame (metres away, turned): the same draws, the pose moved
    rng = np.random.default_rng(frame_seed)
    M = make_T(random_rotations(1, rng)[0], rng.uniform(-5.0, 5.0, size=3))
    moved = global_ransac(src, dst @ M[:3, :3].T + M[:3, 3], np.random.default_rng(1), DISTANCE)
    e, a = pose_error(make_T(*moved), M @ make_T(R, t))
    assert e < 1e-9 and a < 1e-6  # (an angle from acos: 1e-8 of rounding)


def test_every_pair_agreeing_ends_the_draws_at_once():
    """All inliers: the first pose that keeps its edges holds every pair, and the stopping
    rule ends the draws there -- the generator has drawn the first batch and no more."""
    src, dst, T = _pairs(3, 200, 1.0)
    rng = np.random.default_rng(1)
    found = global_ransac(src, dst, rng, DISTANCE)
    e, a = pose_error(make_T(*found), T)
    assert e < 1e-9 and a < 1e-6  # (an angle from acos: 1e-8 of rounding)
    fresh = np.random.default_rng(1)
    fresh.integers(0, 200, size=(FIRST_BATCH, 3))
    assert rng.bit_generator.state == fresh.bit_generator.state
    assert FIRST_BATCH < GLOBAL_ITERATIONS


def test_pairs_with_no_common_pose_find_none_or_few():
    """Random pairs: no pose holds more than a handful of them."""
    rng = np.random.default_rng(5)
    src, dst = rng.uniform(-0.1, 0.1, (300, 3)), rng.uniform(-0.1, 0.1, (300, 3))
    found = global_ransac(src, dst, np.random.default_rng(1), DISTANCE)
    if found is not None:
        R, t = found
        assert (np.linalg.norm(src @ R.T + t - dst, axis=1) < DISTANCE).sum() < 30
