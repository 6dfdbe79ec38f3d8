# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The KD-tree every nearest-neighbour query goes through (pykdtree): the same neighbours and
distances as scipy's cKDTree (an independent reference), and queries that stay on one OpenMP
thread without changing the user's OpenMP settings."""

import os
import subprocess
import sys

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from affordance_registration.core.neighbours import (
    build_tree,
    k_nearest,
    nearest,
    pairs_within,
    tree_points,
)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    m=st.integers(0, 300),
    upper=st.sampled_from([np.inf, 0.05, 0.2, 1e-9]),
)
def test_nearest_matches_scipy(seed, n, m, upper):
    rng = np.random.default_rng(seed)
    data = rng.normal(size=(n, 3))
    queries = rng.normal(size=(m, 3)) * rng.uniform(0.5, 2.0)
    tree = build_tree(data)
    assert np.array_equal(tree_points(tree), data)
    d, i = nearest(tree, queries, upper)
    d_ref, i_ref = cKDTree(data).query(queries, k=1, distance_upper_bound=upper)
    found = np.isfinite(d_ref)
    assert np.array_equal(np.isfinite(d), found)
    assert np.allclose(d[found], d_ref[found], rtol=0, atol=1e-12)
    # the same point, or one exactly as near (a tie)
    assert np.allclose(
        np.linalg.norm(data[i[found]] - queries[found], axis=1), d_ref[found], rtol=0, atol=1e-12
    )
    assert i.shape == (m,) and (i >= 0).all() and (i < n).all()


def test_k_nearest_and_pairs_match_scipy():
    rng = np.random.default_rng(3)
    data = rng.uniform(size=(2000, 3))
    idx = k_nearest(build_tree(data), data[:500], 12)
    _, ref = cKDTree(data).query(data[:500], k=12)
    assert idx.shape == (500, 12)
    assert np.array_equal(np.sort(idx, axis=1), np.sort(ref, axis=1))
    pairs = pairs_within(data, 0.05)
    ref_pairs = cKDTree(data).query_pairs(0.05, output_type="ndarray")
    assert {tuple(p) for p in pairs} == {tuple(p) for p in ref_pairs}


_THREADS = """
import os, threading, time
import numpy as np
from affordance_registration.core import neighbours
from pykdtree.kdtree import KDTree
def threads():
    return len(os.listdir("/proc/self/task"))
rng = np.random.default_rng(0)
data, queries = rng.normal(size=(20000, 3)), rng.normal(size=(200000, 3))
tree = neighbours.build_tree(data)
before, settings = threads(), neighbours.openmp_threads()
neighbours.nearest(tree, queries)
neighbours.k_nearest(tree, queries[:20000], 8)
worker = threading.Thread(target=neighbours.nearest, args=(tree, queries))
worker.start(); worker.join()
with neighbours.one_openmp_thread():       # a block (as a fit holds): set once, nested too
    with neighbours.one_openmp_thread():
        inside = neighbours.openmp_threads()
        neighbours.nearest(tree, queries)
    inside_outer = neighbours.openmp_threads()
deadline = time.monotonic() + 20     # a joined thread may take a moment to leave /proc;
while threads() > before and time.monotonic() < deadline:   # OpenMP's workers never do
    time.sleep(0.01)
after, settings_after = threads(), neighbours.openmp_threads()
KDTree(data).query(queries)       # pykdtree left to itself starts its OpenMP team
print(before, after, threads(), settings, settings_after, inside, inside_outer, sep="|")
"""


def test_queries_run_on_one_openmp_thread_and_leave_the_setting_alone():
    """With OMP_NUM_THREADS=4 a plain pykdtree query starts OpenMP worker threads; the
    module's queries (from the main thread, from another one and in a ``one_openmp_thread``
    block, which holds the count at one until its outermost level ends) start none, and the
    calling thread's OpenMP setting is what it was."""
    env = dict(os.environ, OMP_NUM_THREADS="4")
    out = subprocess.run(
        [sys.executable, "-c", _THREADS], capture_output=True, text=True, env=env, timeout=120
    )
    assert out.returncode == 0, out.stderr
    fields = out.stdout.strip().split("|")
    before, after, unpinned, settings_before, settings_after, inside, inside_outer = fields
    assert settings_before == settings_after and "4" in settings_before
    assert inside == inside_outer == "(1,)"  # within a block (and after a nested one): one
    assert int(after) == int(before)
    assert int(unpinned) > int(before)  # the control: the check can fail
