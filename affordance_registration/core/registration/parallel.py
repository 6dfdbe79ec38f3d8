# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Both cores for one click: independent pieces of a stage -- the hypotheses of a batch, split
into contiguous parts, or the leading candidates' joint estimates -- run on a small shared pool
of threads while the calling thread runs the first piece itself.

numpy's array operations and the KD queries (:mod:`..neighbours`) release the GIL, so the
pieces really run side by side; the Python between them does not. Every piece's result depends
on its own hypotheses only, so a fit gives the same numbers with any number of threads
(``FitSettings.threads``). A piece that is itself running on the pool runs its own pieces one
after the other (no pool task ever waits for another, so the pool cannot deadlock, and
concurrent fits share it safely).

numpy's and scipy's BLAS (OpenBLAS) would spread even the fitter's small matrix products over
every core, and on a loaded machine those threads wait for each other far longer than the
products take (a click's crop preparation took 3x as long). While any fit runs, BLAS runs on
one thread (:func:`single_threaded_blas`; the fitter's parallelism is its own threads), and
the count the user set is put back when the last one ends. The numbers are the same either
way. So are the KD queries' OpenMP threads: one per fitting thread, set once for the fit on the
calling thread and once for each piece on the pool (:func:`..neighbours.one_openmp_thread`).
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np
from threadpoolctl import ThreadpoolController

from ..neighbours import one_openmp_thread

__all__ = ["run", "parts", "over_batch", "single_threaded_blas", "MIN_PART"]

#: a batch is split only into parts of at least this many hypotheses (a smaller part's
#: array operations are too short to pay for the hand-over)
MIN_PART = 24

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_inside = threading.local()
_blas_lock = threading.Lock()
_blas_users = 0  #: fits running (BLAS is on one thread while any is)
_blas_before: list = []  #: (library, its thread count) as the user had it
_blas_libs: list | None = None  #: the BLAS libraries loaded (looked up on the first fit)


def _mark_worker() -> None:
    _inside.worker = True


def _executor(workers: int) -> ThreadPoolExecutor:
    """The shared pool, grown to at least ``workers`` threads."""
    global _pool, _pool_size
    with _lock:
        if _pool is None or _pool_size < workers:
            old = _pool
            _pool = ThreadPoolExecutor(
                max_workers=workers, thread_name_prefix="affordance-fit", initializer=_mark_worker
            )
            _pool_size = workers
            if old is not None:
                old.shutdown(wait=False)
        return _pool


def run(tasks, threads: int) -> list:
    """The results of calling each of ``tasks`` (callables without arguments), in order: with
    ``threads`` > 1, all but the first on the pool and the first on the calling thread. An
    exception of any task is raised once every task has finished."""
    tasks = list(tasks)
    if threads <= 1 or len(tasks) <= 1 or getattr(_inside, "worker", False):
        return [task() for task in tasks]
    pool = _executor(threads - 1)
    futures = [pool.submit(_on_one_openmp_thread, task) for task in tasks[1:]]
    try:
        first = tasks[0]()
    finally:
        rest = [f.exception() for f in futures]  # wait for every piece either way
    for f, exc in zip(futures, rest):
        if exc is not None:
            raise exc
    return [first] + [f.result() for f in futures]


def _on_one_openmp_thread(task):
    with one_openmp_thread():
        return task()


def over_batch(fn, batch, threads: int, min_part: int = MIN_PART) -> list:
    """``fn`` of each contiguous part of ``batch`` (anything with ``len`` and ``take(idx)``),
    the parts side by side: the list of their results, in order."""
    return run(
        [lambda idx=idx: fn(batch.take(idx)) for idx in parts(len(batch), threads, min_part)],
        threads,
    )


def parts(n: int, threads: int, min_part: int = MIN_PART) -> list:
    """``range(n)`` split into at most ``threads`` contiguous index arrays of at least
    ``min_part`` each (one array when it is not worth splitting)."""
    k = max(1, min(int(threads), n // max(min_part, 1)))
    return np.array_split(np.arange(n), k)


@contextmanager
def single_threaded_blas():
    """BLAS on one thread while the block runs (numbers unchanged): the first of concurrent
    blocks to enter sets it, the last to leave puts back the user's thread counts. The calling
    thread's KD queries run on one OpenMP thread meanwhile
    (:func:`..neighbours.one_openmp_thread`)."""
    global _blas_users, _blas_before, _blas_libs
    with _blas_lock:
        if _blas_users == 0:
            if _blas_libs is None:
                _blas_libs = ThreadpoolController().select(user_api="blas").lib_controllers
            _blas_before = [(lib, lib.num_threads) for lib in _blas_libs if lib.num_threads != 1]
            for lib, _ in _blas_before:
                lib.set_num_threads(1)
        _blas_users += 1
    try:
        with one_openmp_thread():
            yield
    finally:
        with _blas_lock:
            _blas_users -= 1
            if _blas_users == 0:
                for lib, n in _blas_before:
                    lib.set_num_threads(n)
                _blas_before = []
