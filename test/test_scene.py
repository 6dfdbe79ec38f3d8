# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The crop preparation's fast paths give the numbers of their plain formulations, bit for bit:
the voxel grid grouped through a table of cells, the cluster's components from CSR rows, the
fine points looked up inside the cluster's box only, the normals' neighbourhood sums, the
frame's lean and the spread check decided without pow() and SVD, a snap reusing the crop's
distances. Each reference below is the plain formulation the fast path must match."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from affordance_registration.core import scene as S
from affordance_registration.core import segmentation, voxels
from affordance_registration.core.errors import SceneError
from affordance_registration.core.neighbours import (
    build_tree,
    k_nearest,
    least_spread,
    nearest,
    pairs_within,
    pca_normals,
)


def _voxel_reference(points, voxel, origin=None, frame=None):
    grid = points if frame is None else (points - origin) @ frame + 0.5 * voxel
    keys = np.floor(grid / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    uniq, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.stack(
        [np.bincount(inverse, weights=points[:, k], minlength=len(uniq)) for k in range(3)], axis=1
    )
    return sums / counts[:, None]


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 3000),
    spread=st.sampled_from([0.01, 0.3, 5.0]),
    framed=st.booleans(),
)
def test_voxel_grid_is_the_sorted_grouping(seed, n, spread, framed):
    # small spreads take the cell table, large ones (more cells than 64 per point) the sort
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * spread + rng.normal(size=3) * 10
    origin, frame = (pts[0], _rotation(rng)) if framed else (None, None)
    got = S.voxel_downsample(pts, 0.005, origin, frame)
    assert np.array_equal(got, _voxel_reference(pts, 0.005, origin, frame))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), m=st.integers(0, 1500))
def test_components_are_scipys(seed, n, m):
    rng = np.random.default_rng(seed)
    pairs = np.sort(rng.integers(0, n, size=(m, 2)), axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    labels = segmentation._components(n, pairs)
    graph = coo_matrix((np.ones(len(pairs), bool), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, ref = connected_components(graph, directed=False)
    # the same partition: a one-to-one map between the two labellings
    assert (
        len(set(zip(labels.tolist(), ref.tolist())))
        == len(set(ref.tolist()))
        == len(set(labels.tolist()))
    )


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    blobs=st.integers(1, 12),
    n=st.integers(1, 600),
    gap=st.sampled_from([0.01, 0.025, 0.06]),
)
def test_gap_components_are_those_of_every_pair_within_the_gap(seed, blobs, n, gap):
    # clumps and specks at about the gap from each other: joined or not by a few steps
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-0.1, 0.1, size=(blobs, 3))
    pts = centres[rng.integers(0, blobs, n)] + rng.normal(size=(n, 3)) * 0.01
    labels = segmentation.gap_components(pts, gap)
    _, ref = connected_components(
        coo_matrix(
            (np.ones(len(p := pairs_within(pts, gap)), bool), (p[:, 0], p[:, 1])), shape=(n, n)
        ),
        directed=False,
    )
    assert (
        len(set(zip(labels.tolist(), ref.tolist())))
        == len(set(ref.tolist()))
        == len(set(labels.tolist()))
    )


def test_components_of_a_graph_too_big_for_the_radix_sort():
    n = 70000
    pairs = np.array([[0, 69999], [5, 69999], [7, 8], [69998, 8]])
    labels = segmentation._components(n, pairs)
    assert labels[0] == labels[5] == labels[69999] != labels[7]
    assert labels[7] == labels[8] == labels[69998]
    assert len(np.unique(labels)) == n - 4


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 300),
    m=st.integers(0, 2000),
    distance=st.sampled_from([0.005, 0.05, 0.5]),
)
def test_points_within_a_distance_are_the_trees_answer(seed, n, m, distance):
    rng = np.random.default_rng(seed)
    targets = rng.normal(size=(n, 3)) * 0.1
    points = rng.normal(size=(m, 3)) * 0.2
    tree = build_tree(targets)
    d, _ = nearest(tree, points, distance)
    assert np.array_equal(
        S._within(points, targets, tree, distance), points[np.isfinite(d)].reshape(-1, 3)
    )


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(3, 800),
    k=st.sampled_from([3, 12, 30]),
    scale=st.sampled_from([1e-3, 1.0, 1e3]),
)
def test_normals_are_the_neighbourhoods_plain_pca(seed, n, k, scale):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * scale
    k = min(k, n)
    idx = k_nearest(build_tree(pts), pts, k)
    nb = pts[idx]
    nb = nb - nb.mean(axis=1, keepdims=True)
    # the neighbourhood's covariance to the digit (its smallest eigenvector in closed form:
    # checked against LAPACK's in test_fast_paths)
    ref = least_spread(np.swapaxes(nb, 1, 2) @ nb)
    assert np.array_equal(pca_normals(pts, k), ref)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 60000))
def test_the_mean_of_rows_is_numpys(seed, n):
    # values over twelve orders of magnitude: any other order of the sums shows
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-6, 6, size=(n, 3))
    assert np.array_equal(S.mean_rows(pts), pts.mean(axis=0))


def _frame_reference(points, click, origin):
    rel = points - points.mean(axis=0)
    cov = rel.T @ rel

    def signed(axis):
        return axis if np.sum((rel @ axis) ** 3) >= 0 else -axis

    if origin is not None and np.linalg.norm(origin - click) > 1e-9:
        z = (origin - click) / np.linalg.norm(origin - click)
    else:
        z = signed(np.linalg.eigh(cov)[1][:, 0])
    across = np.eye(3) - np.outer(z, z)
    x = signed(np.linalg.eigh(across @ cov @ across)[1][:, 2])
    x = x - z * (x @ z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(10, 2000),
    symmetric=st.booleans(),
    viewpoint=st.booleans(),
)
def test_local_frame_leans_as_the_exact_cubes_do(seed, n, symmetric, viewpoint):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * [0.2, 0.1, 0.01]
    if symmetric:  # a distribution without lean: the products cannot call it
        pts = np.concatenate([pts, -pts])
    pts = pts @ _rotation(rng).T + rng.normal(size=3)
    origin = pts[0] + rng.normal(size=3) if viewpoint else None
    assert np.array_equal(
        S.local_frame(pts, pts[0], origin), _frame_reference(pts, pts[0], origin)
    )


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 40))
def test_the_lean_is_the_sign_of_the_exact_cubes(seed, n):
    # the last value cancels the others' cubes: sums within rounding of zero, where products
    # rounded twice and pow() often disagree on the sign
    rng = np.random.default_rng(seed)
    along = rng.normal(size=n)
    along[-1] = -np.cbrt(np.sum(along[:-1] ** 3))
    assert voxels._leans_forward(along) == (np.sum(along**3) >= 0)
    assert voxels._leans_forward(-along * 3.0) == (np.sum((-along * 3.0) ** 3) >= 0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), width=st.floats(0.0, 0.01))
def test_the_spread_check_decides_as_the_svd_does(seed, width):
    rng = np.random.default_rng(seed)
    n = 500
    crop = (
        np.stack(
            [rng.uniform(-0.2, 0.2, n), rng.uniform(-1, 1, n) * width * math.sqrt(3), np.zeros(n)],
            axis=1,
        )
        @ _rotation(rng).T
    )
    spread = np.linalg.svd(crop - crop.mean(axis=0), compute_uv=False) / math.sqrt(n)
    line = spread[1] < 0.5 * 0.005
    if line:
        with pytest.raises(SceneError, match="on a line"):
            S._check_spread(crop, 0.005, 0.24)
    else:
        S._check_spread(crop, 0.005, 0.24)


def test_a_snap_from_the_part_around_the_click_is_the_whole_scenes(panel_scene):
    scene = S.Scene(panel_scene.organized)
    for obj in panel_scene.objects[:4]:
        click = obj.click + np.array([0.004, -0.003, 0.002])
        part = scene.around(click, 0.3)
        assert np.array_equal(part.snap(click), scene.snap(click))
        # the cached distances are to that point only
        other = click + np.array([0.01, 0.0, 0.0])
        assert np.array_equal(part.snap(other), scene.snap(other))


def test_two_threads_prepare_the_same_click(panel_scene):
    """The fine points' normals in parts side by side: the same context, bit for bit."""
    from affordance_registration.core.registration.parallel import single_threaded_blas

    scene = S.Scene(panel_scene.organized)
    for obj in panel_scene.objects[:3]:
        part = scene.around(obj.click, 0.27)
        c = part.snap(obj.click)
        with single_threaded_blas():
            one = part.prepare_click(c, radius=0.24)
            two = part.prepare_click(c, radius=0.24, threads=2)
        assert len(one.fine) > 2 * S.MIN_NORMALS_PART
        for name in ("crop", "cluster", "fine", "fine_normals", "frame"):
            assert np.array_equal(getattr(one, name), getattr(two, name)), name


def test_the_fine_points_are_capped_by_an_even_subset(panel_scene):
    """``fine_points`` keeps at most that many full-resolution points: an even subset of the
    uncapped ones in their order, spread over the whole cluster (a click on a large flat
    surface holds tens of thousands); everything else about the click is the same."""
    scene = S.Scene(panel_scene.organized)
    obj = max(panel_scene.objects, key=lambda o: o.visible_points)
    part = scene.around(obj.click, 0.27)
    c = part.snap(obj.click)
    full = part.prepare_click(c, radius=0.24)
    cap = len(full.fine) // 3
    capped = part.prepare_click(c, radius=0.24, fine_points=cap)
    assert len(capped.fine) == cap < len(full.fine)
    rows = {tuple(p) for p in full.fine.tolist()}
    assert all(tuple(p) in rows for p in capped.fine.tolist())
    # even: nearly every full-resolution point has a kept one within two voxels (the first
    # third of them, say, would leave the rest of the cluster 2 to 11 cm from any)
    d, _ = nearest(build_tree(capped.fine), full.fine)
    assert np.percentile(d, 99) < 2 * full.voxel, np.percentile(d, [50, 99])
    for name in ("crop", "cluster", "frame"):
        assert np.array_equal(getattr(full, name), getattr(capped, name)), name
    assert len(part.prepare_click(c, radius=0.24, fine_points=0).fine) == len(full.fine)
