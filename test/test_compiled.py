# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The compiled kernels (numba, ``core/compiled.py``) give their numpy paths' numbers to the last
bit -- on random point sets (a property) and on the golden clicks' scoring passes -- but for the
fused ICP step, whose sums round differently: its fits stay within the golden fits' tolerance of
the numpy path's. Where numba is missing the fitter says so in one log line and takes the numpy
path."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from affordance_registration.core import compiled, neighbours
from affordance_registration.core.neighbours import build_tree, nearest

needs_numba = pytest.mark.skipif(not compiled.available(), reason="numba is not installed")


@needs_numba
@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 500),
    m=st.integers(0, 400),
    upper=st.sampled_from([0.003, 0.01, 0.05, 0.3, 2.0]),
    cell=st.sampled_from([0.004, 0.0156, 0.0625, 1.0]),
)
def test_grid_distances_are_the_kd_trees(seed, n, m, upper, cell):
    """Bit for bit what ``neighbours.nearest`` gives, inf beyond the bound alike, whatever the
    cell (larger or smaller than the bound) and for queries far outside the grid."""
    rng = np.random.default_rng(seed)
    data = rng.normal(size=(n, 3)) * rng.uniform(0.01, 0.2)
    queries = rng.normal(size=(m, 3)) * rng.uniform(0.01, 0.5)
    want, want_i = nearest(build_tree(data), queries, upper)
    got, got_i = compiled.DistanceGrid(data, cell).nearest(queries, upper)
    assert np.array_equal(np.isfinite(got), np.isfinite(want))
    assert np.array_equal(got, want)  # not close: equal
    found = np.isfinite(want)
    assert np.array_equal(got_i[found], want_i[found])  # (random points: no ties)
    assert got_i.shape == (m,) and (got_i >= 0).all() and (got_i < n).all()


@needs_numba
@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 2000),
    radius=st.sampled_from([0.0009, 0.009, 0.015, 0.05, 0.6]),
    grid=st.booleans(),
)
def test_pairs_within_are_the_kd_trees_pairs(seed, n, radius, grid):
    """The same pairs (i < j) as the KD-tree's ``query_pairs``, at most ``radius`` apart,
    whether the points are scattered or on a grid of the radius' own step (pairs exactly the
    radius apart, the comparison's edge), and where the cloud is so dense that the pairs
    outnumber the room first made for them."""
    rng = np.random.default_rng(seed)
    if grid:
        side = max(int(round(n ** (1 / 3))), 1)
        axis = np.arange(side) * radius
        data = np.stack(np.meshgrid(axis, axis, axis), axis=-1).reshape(-1, 3) + 0.1
    else:
        data = rng.normal(size=(n, 3)) * rng.uniform(0.005, 0.3)
    want = cKDTree(data).query_pairs(radius, output_type="ndarray").reshape(-1, 2)
    got = compiled.pairs_within(data, radius)
    assert got.shape[1] == 2 and (got[:, 0] < got[:, 1]).all()
    key = lambda p: np.sort(p[:, 0].astype(np.int64) * max(len(data), 1) + p[:, 1])  # noqa: E731
    assert np.array_equal(key(got), key(want))
    assert np.array_equal(key(neighbours.pairs_within(data, radius)), key(want))  # (its caller's)


@needs_numba
@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 700),
    m=st.integers(0, 300),
    upper=st.sampled_from([0.003, 0.01, 0.05, 0.3, np.inf]),
    duplicates=st.booleans(),
)
def test_the_compiled_tree_is_the_kd_trees(seed, n, m, upper, duplicates):
    """Bit for bit the distances of ``neighbours.nearest`` and the same points (of points
    exactly as near, the lowest index), inf beyond the bound alike, for queries anywhere."""
    rng = np.random.default_rng(seed)
    data = rng.normal(size=(n, 3)) * rng.uniform(0.01, 0.2)
    if duplicates:  # (repeated points: ties)
        data = data[rng.integers(0, n, n)]
    queries = rng.normal(size=(m, 3)) * rng.uniform(0.01, 0.5)
    want, want_i = nearest(build_tree(data), queries, upper)
    got, got_i = compiled.NearestTree(data).nearest(queries, upper)
    assert np.array_equal(got, want)  # not close: equal
    found = np.isfinite(want)
    assert np.array_equal(data[got_i[found]], data[want_i[found]])
    if not duplicates:
        assert np.array_equal(got_i[found], want_i[found])
    assert got_i.shape == (m,) and (got_i >= 0).all() and (got_i < n).all()


@needs_numba
def test_the_fused_icp_step_stays_within_the_golden_tolerance():
    """Golden clicks (panel, table, articulated; the default registrar) fitted with the
    compiled ICP step and with the numpy path: the same templates in the same order, the
    winner's pose within the golden fits' loose tolerance (0.1 mm, 0.01 deg), every residual
    within 1% (and the fused step read the click's view only when switched on)."""
    from test_golden_fits import LOOSE_M, LOOSE_RAD, LOOSE_RES, MIN_VISIBLE

    from affordance_registration.core import memo
    from affordance_registration.core.registration import Registrar
    from affordance_registration.core.scene import Scene
    from affordance_registration.core.templates import TemplateLibrary
    from affordance_registration.core.transforms import pose_error
    from affordance_registration.evaluation.simulation import simulate_taskboard

    library = TemplateLibrary.load().specific()
    registrar = Registrar(library)
    fits = 0
    for kw, clicks in ((dict(seed=1000), 2), (dict(seed=2000, layout="table"), 1)) + (
        (dict(seed=3000, articulated=True), 2),
    ):
        sim = simulate_taskboard(library, **kw)
        scene = Scene(sim.organized)
        for obj in [o for o in sim.objects if o.visible_points >= MIN_VISIBLE][:clicks]:
            got = {}
            for on in (False, True):
                with compiled.use_compiled(on):
                    report = registrar.fit(scene, obj.click)
                got[on] = report.candidates
                held = memo._per_object.get(id(report.context), {})
                assert any(k[0] == "compiled view" for k in held) is on
            numpy_path, fused = got[False], got[True]
            assert [c.template for c in fused] == [c.template for c in numpy_path]
            dt, dr = pose_error(fused[0].T_scene_model, numpy_path[0].T_scene_model)
            assert dt <= LOOSE_M and dr <= LOOSE_RAD, (dt, dr)
            for a, b in zip(fused, numpy_path):
                assert abs(a.residual - b.residual) <= LOOSE_RES * b.residual
            fits += 1
    assert fits == 5


@needs_numba
def test_a_grid_is_built_only_where_its_cells_stay_light():
    """The cell is the power of two at or above the bound; a grid whose cells would hold more
    than MAX_CELL_LOAD surface points, an unbounded query or an empty set gets none."""
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(4096, 3))
    sphere *= 0.1 / np.linalg.norm(sphere, axis=1, keepdims=True)  # 20 cm across
    assert compiled.grid_cell(sphere, 0.01) == 2.0**-6  # 1.56 cm: about 25 points a cell
    assert compiled.grid_cell(sphere, 0.03) is None  # 6.25 cm: about 400
    assert compiled.grid_cell(sphere, np.inf) is None
    assert compiled.grid_cell(sphere[:0], 0.01) is None
    load = compiled.cell_load(4096, 0.2, 2.0**-6)
    assert 20 < load <= compiled.MAX_CELL_LOAD
    with compiled.use_compiled(False):
        assert compiled.grid_cell(sphere, 0.01) is None


@pytest.fixture(scope="module")
def golden_click():
    """A golden click (panel 1000, the default registrar) and its medium-stage hypotheses'
    poses, as the test of the golden fits makes them."""
    from affordance_registration.core.registration import Registrar
    from affordance_registration.core.registration.hypotheses import initial_hypotheses
    from affordance_registration.core.scene import Scene
    from affordance_registration.core.templates import TemplateLibrary
    from affordance_registration.evaluation.simulation import simulate_taskboard, sized_library

    library = sized_library(TemplateLibrary.load().specific())  # jointed and scaled too
    sim = simulate_taskboard(library, seed=3001, articulated=True)
    registrar = Registrar(library)
    obj = [o for o in sim.objects if o.visible_points >= 200][0]
    ctx = registrar.prepare(Scene(sim.organized), obj.click)
    variants, _ = registrar._variants(list(library))
    hyps = initial_hypotheses(ctx, variants, registrar.settings, np.random.default_rng(0))
    return registrar, ctx, hyps


@needs_numba
def test_scoring_passes_are_the_same_either_way(golden_click):
    """The residual's cluster -> template pass, the verdict's explained share and the judge's
    verdict on a golden click: equal with the compiled kernels and without (models at joint
    values and scales other than the template's own included)."""
    from affordance_registration.core.registration.model import Batch
    from affordance_registration.core.registration.scoring import (
        backward_residual,
        explained_share,
        results,
    )

    registrar, ctx, hyps = golden_click
    s = registrar.settings
    models = [
        m.with_values(q=0.3, scale=1.1) if m.template.joint is not None else m for m in hyps.models
    ]
    batch = Batch(tuple(models), hyps.R, hyps.t)
    out = {}
    for on in (False, True):
        with compiled.use_compiled(on):
            assert compiled.available() is on
            fits = results(ctx, batch, s)
            out[on] = (
                backward_residual(ctx, batch, s),
                explained_share(ctx, models, fits, s),
                [(r.residual, r.inlier_fraction) for r in fits],
            )
    from affordance_registration.core import memo

    grids = [k for k in memo._per_object.get(id(ctx), {}) if k[0] == "grid"]
    assert grids, "the compiled path read no grid of the click's crop: nothing was compared"
    np.testing.assert_array_equal(out[True][0], out[False][0])
    np.testing.assert_array_equal(out[True][1], out[False][1])
    assert out[True][2] == out[False][2]
    assert len(out[True][0]) == len(batch) > 10
    assert np.ptp(out[True][0]) > 0  # the hypotheses differ: the comparison can fail


def test_without_numba_one_log_line_and_the_numpy_path():
    """numba missing: one warning line (however often the kernels are asked for), the grid
    never built, and the same distances as the KD-tree's."""
    script = textwrap.dedent(
        """
        import logging, sys
        sys.modules["numba"] = None  # as if it were not installed
        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s %(message)s")
        import numpy as np
        from affordance_registration.core import compiled
        from affordance_registration.core.registration.model import ModelCache
        from affordance_registration.core.registration.model import surface_distances
        from affordance_registration.core.neighbours import nearest
        from affordance_registration.core.templates import TemplateLibrary
        tpl = next(iter(TemplateLibrary.load().specific().values()))
        model = ModelCache().model(tpl)
        pts = np.random.default_rng(1).normal(size=(1, 300, 3)) * 0.05
        d = surface_distances([model], pts, 0.01)[0]
        surface = model.cache.surface(tpl)
        ref = nearest(surface.whole, pts[0], 0.01)[0]
        print("AVAILABLE", compiled.available(), compiled.kernels() is None)
        print("EQUAL", bool(np.array_equal(d, ref)), int(np.isfinite(d).sum()))
        from affordance_registration.core import memo
        grids = [k for v in memo._per_object.values() for k in v if k[0] == "grid"]
        print("GRIDS", len(grids))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        env=dict(os.environ),
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert "AVAILABLE False True" in lines
    assert "GRIDS 0" in lines
    equal = [x for x in lines if x.startswith("EQUAL")][0].split()
    assert equal[1] == "True" and int(equal[2]) > 0  # (some within the bound: can fail)
    warnings = [x for x in out.stderr.splitlines() if "compiled kernels unavailable" in x]
    assert len(warnings) == 1, out.stderr
    assert warnings[0].startswith("WARNING") and "numba" in warnings[0]


@needs_numba
def test_the_bench_compares_the_two_paths_click_by_click():
    """The bench's kernels row: each click fitted with the kernels off and on, both timed, the
    ratios to the numpy path's, and the table's line for it."""
    from affordance_registration.core.templates import TemplateLibrary
    from affordance_registration.evaluation.bench import format_table
    from affordance_registration.evaluation.bench_rows import kernel_rows, simulated_jobs

    library = TemplateLibrary.load().specific()
    jobs = simulated_jobs(library, range(1000, 1001))[:2]
    rows = kernel_rows(library, jobs)
    assert [r["kernels"] for r in rows] == ["numpy", "compiled"]
    assert all(r["clicks"] == 2 and r["median_cpu_s"] > 0 and r["median_s"] > 0 for r in rows)
    assert rows[0]["cpu_ratio_to_numpy"] == rows[0]["ratio_to_numpy"] == 1.0
    assert compiled.compiled_enabled()  # the row switched the kernels back on
    base = {"rows": [], "refit": {"median_s": 0.01, "success": 1.0}, "scenes": 1}
    base |= {"pose_tolerance": {"m": 0.005, "deg": 5.0}, "machine": {"cpus": 2}}
    table = format_table({**base, "kernels": rows})
    line = next(x for x in table.splitlines() if "compiled kernels" in x)
    assert f"{rows[1]['cpu_ratio_to_numpy']:.2f}x the numpy path's" in line, line
