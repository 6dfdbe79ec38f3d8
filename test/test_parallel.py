# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Both cores for one click: the pieces of a batch side by side give the same fits as one
thread, and the pool passes errors on and never waits on itself."""

import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from affordance_registration.core.errors import RegistrationError
from affordance_registration.core.registration import FitSettings, Registrar, parallel
from affordance_registration.core.scene import Scene
from affordance_registration.evaluation.simulation import simulate_taskboard, sized_library


def _same(a, b) -> bool:
    return [c.template for c in a] == [c.template for c in b] and all(
        np.array_equal(x.T_scene_model, y.T_scene_model)
        and x.residual == y.residual
        and x.joints == y.joints
        and x.scale == y.scale
        and x.iterations == y.iterations
        and x.converged == y.converged
        for x, y in zip(a, b)
    )


@pytest.mark.parametrize(
    "seed, kw", [(11, {}), (3007, {"articulated": True}), (2003, {"layout": "table"})]
)
def test_fits_do_not_depend_on_the_thread_count(library, seed, kw):
    lib = sized_library(library)
    sim = simulate_taskboard(lib, seed, **kw)
    scene = Scene(sim.organized)
    fits = {n: Registrar(lib, FitSettings(threads=n)) for n in (1, 2, 3)}
    objs = [o for o in sim.objects if o.visible_points >= 200][:2]
    assert objs
    for obj in objs:
        got = {n: reg.fit(scene, obj.click).candidates for n, reg in fits.items()}
        assert _same(got[1], got[2]) and _same(got[1], got[3]), obj.template
        assert got[1][0].template == obj.template


def test_pool_runs_every_task_and_raises_a_failed_ones_error():
    ran = []

    def ok(i):
        ran.append(i)
        return i

    def bad():
        raise ValueError("piece failed")

    assert parallel.run([lambda i=i: ok(i) for i in range(5)], threads=3) == list(range(5))
    with pytest.raises(ValueError, match="piece failed"):
        parallel.run([lambda: ok(10), bad, lambda: ok(11)], threads=3)
    assert {10, 11} <= set(ran)


def test_a_task_on_the_pool_runs_its_own_pieces_itself():
    """Nested pieces never wait for the pool (which could be busy with their parents)."""

    def parent(i):
        inner = parallel.run(
            [lambda j=j: (threading.current_thread().name, i, j) for j in range(3)], threads=2
        )
        return inner

    out = parallel.run([lambda i=i: parent(i) for i in range(4)], threads=2)
    assert [[(i, j) for _, i, j in part] for part in out] == [
        [(i, j) for j in range(3)] for i in range(4)
    ]
    for part in out[1:]:  # ran on the pool: each nested piece on the same thread
        assert len({name for name, _, _ in part}) == 1


def test_parts_and_thread_setting():
    assert [len(p) for p in parallel.parts(100, 2, 24)] == [50, 50]
    assert len(parallel.parts(40, 2, 24)) == 1
    assert np.array_equal(np.concatenate(parallel.parts(77, 3, 10)), np.arange(77))
    with pytest.raises(RegistrationError, match="threads"):
        FitSettings(threads=0).validate()


_BLAS = """
import threading
from threadpoolctl import threadpool_info
from affordance_registration.core.errors import RegistrationError
from affordance_registration.core.registration import Registrar, parallel
from affordance_registration.core.scene import Scene
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.core.templates import TemplateLibrary

def blas():
    return sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})

seen = [blas()]
a_in, b_out = threading.Event(), threading.Event()
def a():
    with parallel.single_threaded_blas():
        a_in.set()
        b_out.wait(60)
        seen.append(blas())          # B has left, A is still inside
worker = threading.Thread(target=a)
worker.start()
a_in.wait(60)
with parallel.single_threaded_blas():
    seen.append(blas())
b_out.set()
worker.join(60)
seen.append(blas())
library = TemplateLibrary.load()
sim = simulate_taskboard(library, 11)
obj = next(o for o in sim.objects if o.visible_points >= 200)
Registrar(library).fit(Scene(sim.organized), obj.click)
seen.append(blas())
try:
    Registrar(library).fit(Scene(sim.organized), obj.click, templates=[])
except RegistrationError:
    seen.append(blas())
print(seen)
"""


def test_blas_runs_on_one_thread_while_any_fit_runs_and_is_put_back_after():
    """With OPENBLAS_NUM_THREADS=2 (OpenBLAS allows at most the core count): BLAS stays on one
    thread until the last of concurrent blocks leaves, then has the user's count again -- also
    after a real fit and after a fit that failed."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    out = subprocess.run(
        [sys.executable, "-c", _BLAS], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[[2], [1], [1], [2], [2], [2]]"
