# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Compiled kernels (numba) for the fitter's hot loops, each with its numpy reference, and the
switch between them.

A kernel here gives the numbers its numpy path gives, to the last bit: it does the same
floating-point operations in the same order (no fast-math, no fused multiply-add, no
reductions reordered), and a test holds the two equal (``test/test_compiled.py``). What it
saves is the work around them -- the calls, the pruning -- and it releases the GIL, so the
fitter's threads (:mod:`.registration.parallel`) run it side by side.

The kernels are compiled on first use -- a template's first dense surface, so a registrar's
warm-up pays it, not a click -- and cached on disk by numba where it can write (on this loaded
machine compiling took 9 s once; loading them again, with numba's own start, 1.3 s a process).
Where numba is missing or fails to compile, one log line says so and every caller takes the
numpy path; ``use_compiled(False)`` takes it on purpose (the bench's ``kernels`` row compares
the two in one run).

The kernel: the nearest of a point set to each query point, up to a bound
(:class:`DistanceGrid`) -- what the residual's cluster -> template pass and the verdict's
explained share ask of a template's dense surface for every hypothesis. A uniform grid of cells
at least as large as the bound answers it from the few cells the bound reaches; the distance is
the KD-tree's, sqrt((dx^2 + dy^2) + dz^2), and the point the same one (two points exactly as
near are the one case where the two may name different ones). Where the cells would hold many
points the KD-tree prunes better and answers instead (:func:`grid_cell`): ICP's correspondences
in the full-resolution cluster, and in the voxelized one, where a grid measured no faster (a
simulated click's CPU 1.009x with it; the grid code kept the tree's numbers).
"""

from __future__ import annotations

import logging
import math
import threading
from contextlib import contextmanager

import numpy as np

__all__ = [
    "DistanceGrid",
    "kernels",
    "available",
    "use_compiled",
    "compiled_enabled",
    "cell_load",
    "grid_cell",
    "MAX_CELL_LOAD",
]

_log = logging.getLogger(__name__)
_lock = threading.Lock()
_kernels = None
_tried = False
_enabled = True

#: a grid has at most this many cells along an axis (a finer bound than the set's extent over
#: this: the cells are this coarse)
MAX_CELLS_PER_AXIS = 64
#: a grid answers a query faster than the KD-tree where its cells hold about this many points
#: or fewer (:func:`cell_load`; measured on the fitter's queries, cells of 1.6 and 3.1 cm: 80-500
#: ns a query up to here against the tree's 400-460, 400-770 above)
MAX_CELL_LOAD = 64


# the kernels, as plain Python that numba compiles (module level: numba caches them on disk)
def _build(points, cell):
    """A grid over ``points`` (N, 3) with cells of edge ``cell``: the points sorted by cell
    (N, 3), their indices in ``points`` (N,), the grid's corner (3,), its cells along each axis
    (3,), and where each cell's points start in the sorted ones (cells + 1,)."""
    n = points.shape[0]
    lo = np.empty(3)
    dims = np.empty(3, np.int64)
    for d in range(3):
        mn = np.inf
        mx = -np.inf
        for i in range(n):
            v = points[i, d]
            mn = min(mn, v)
            mx = max(mx, v)
        lo[d] = mn
        dims[d] = int((mx - mn) / cell) + 1
    key = np.empty(n, np.int64)
    for i in range(n):
        a = int((points[i, 0] - lo[0]) / cell)
        b = int((points[i, 1] - lo[1]) / cell)
        c = int((points[i, 2] - lo[2]) / cell)
        key[i] = (a * dims[1] + b) * dims[2] + c
    order = np.argsort(key, kind="mergesort")
    first = np.zeros(dims[0] * dims[1] * dims[2] + 1, np.int64)
    for i in range(n):
        first[key[i] + 1] += 1
    for c in range(first.shape[0] - 1):
        first[c + 1] += first[c]
    pts = np.empty((n, 3))
    for j in range(n):
        for d in range(3):
            pts[j, d] = points[order[j], d]
    return pts, order, lo, dims, first


def _nearest(pts, order, lo, dims, first, cell, queries, upper, out, index):
    """For each of ``queries`` (M, 3): the distance to the nearest grid point within ``upper``
    into ``out`` (inf beyond) and its index in the original points into ``index`` (-1)."""
    bound = upper * upper
    for i in range(queries.shape[0]):
        q0, q1, q2 = queries[i, 0], queries[i, 1], queries[i, 2]
        a0 = max(int(math.floor((q0 - upper - lo[0]) / cell)), 0)
        a1 = min(int(math.floor((q0 + upper - lo[0]) / cell)), dims[0] - 1)
        b0 = max(int(math.floor((q1 - upper - lo[1]) / cell)), 0)
        b1 = min(int(math.floor((q1 + upper - lo[1]) / cell)), dims[1] - 1)
        c0 = max(int(math.floor((q2 - upper - lo[2]) / cell)), 0)
        c1 = min(int(math.floor((q2 + upper - lo[2]) / cell)), dims[2] - 1)
        best = np.inf
        at = -1
        if c0 > c1:  # (beyond the grid along z: no cell to read)
            a1 = a0 - 1
        for a in range(a0, a1 + 1):
            for b in range(b0, b1 + 1):
                row = (a * dims[1] + b) * dims[2]
                for j in range(first[row + c0], first[row + c1 + 1]):
                    dx = q0 - pts[j, 0]
                    dy = q1 - pts[j, 1]
                    dz = q2 - pts[j, 2]
                    d = dx * dx + dy * dy + dz * dz
                    if d < best:
                        best = d
                        at = j
        if best <= bound:
            out[i] = math.sqrt(best)
            index[i] = order[at]
        else:
            out[i] = np.inf
            index[i] = -1


def _compile():
    """The compiled kernels (a namespace of numba functions), compiled now (or loaded from
    numba's cache)."""
    import numba

    def jit(fn, signature):
        try:
            return numba.njit(signature, nogil=True, cache=True)(fn)
        except Exception:  # (no writable cache directory: compiled for this process only)
            return numba.njit(signature, nogil=True)(fn)

    class Kernels:
        pass

    k = Kernels()
    k.build = jit(
        _build, "Tuple((f8[:, ::1], i8[::1], f8[::1], i8[::1], i8[::1]))(f8[:, ::1], f8)"
    )
    k.nearest = jit(
        _nearest,
        "void(f8[:, ::1], i8[::1], f8[::1], i8[::1], i8[::1], f8, f8[:, ::1], f8, f8[::1], "
        "i8[::1])",
    )
    return k


def kernels():
    """The compiled kernels, or None where numba is missing or fails to compile (said once in
    the log) or :func:`use_compiled` turned them off."""
    global _kernels, _tried
    if not _enabled:
        return None
    if not _tried:
        with _lock:
            if not _tried:
                try:
                    _kernels = _compile()
                except Exception as exc:  # ImportError, or numba's errors
                    _log.warning(
                        "compiled kernels unavailable (%s: %s): the fitter uses numpy; "
                        "pip install numba for the compiled loops",
                        type(exc).__name__,
                        str(exc).splitlines()[0] if str(exc) else "",
                    )
                    _kernels = None
                _tried = True
    return _kernels


def available() -> bool:
    """Whether the compiled kernels are in use."""
    return kernels() is not None


def compiled_enabled() -> bool:
    """Whether the compiled path is switched on (:func:`use_compiled`)."""
    return _enabled


@contextmanager
def use_compiled(on: bool):
    """The compiled kernels switched on or off while the block runs (process-wide: for the
    bench and the tests that compare the two paths; the numbers are the same either way)."""
    global _enabled
    before = _enabled
    _enabled = bool(on)
    try:
        yield
    finally:
        _enabled = before


def cell_load(n: int, extent: float, cell: float) -> float:
    """About how many of ``n`` points sampling a surface ``extent`` (m) across lie in a cell of
    edge ``cell``: the share of the extent, squared (a query reads up to 27 cells: where they
    are full, a KD-tree prunes better)."""
    return n * (cell / max(extent, cell)) ** 2


def grid_cell(points: np.ndarray, upper: float, extent: float | None = None) -> float | None:
    """The cell of the grid worth building over ``points`` (N, 3) for queries bounded by
    ``upper`` -- the power of two at or above it -- or None where a grid does not pay (its
    cells would hold more than ``MAX_CELL_LOAD`` points, the bound is not finite and positive,
    or the kernels are not in use). ``extent``: the points' largest side, if known."""
    if not 0.0 < upper < np.inf or len(points) == 0 or kernels() is None:
        return None
    cell = 2.0 ** math.ceil(math.log2(upper))
    if extent is None:
        extent = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    return cell if cell_load(len(points), extent, cell) <= MAX_CELL_LOAD else None


class DistanceGrid:
    """Distances from query points to the nearest of ``points`` (N, 3), up to a bound: the
    points sorted into cubic cells of edge ``cell`` (a grid over their bounding box, at most
    ``MAX_CELLS_PER_AXIS`` cells along an axis). Built by the compiled kernels; use
    :func:`grid_for` rather than building one where they may be missing."""

    def __init__(self, points: np.ndarray, cell: float, k=None):
        k = k or kernels()
        points = np.array(points, dtype=float, order="C").reshape(-1, 3)  # (its own copy)
        extent = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
        self.cell = max(float(cell), extent / MAX_CELLS_PER_AXIS, 1e-9)
        self.n = len(points)
        self._k = k
        self._grid = k.build(points, self.cell)

    def nearest(self, queries: np.ndarray, upper: float):
        """Distance (M,) from each of ``queries`` (M, 3) to the nearest point and that point's
        index (M,), as :func:`..neighbours.nearest` gives them: beyond ``upper`` the distance is
        inf and the index a valid but meaningless one. ``upper`` is finite; a query reads the
        cells the bound reaches (a bound of about the cell or less is what the grid is for)."""
        # (the compiled signature takes writable C arrays: a read-only one is copied)
        q = np.require(np.reshape(queries, (-1, 3)), float, ["C", "W"])
        out, index = np.empty(len(q)), np.empty(len(q), dtype=np.int64)
        if len(q):
            self._k.nearest(*self._grid, self.cell, q, float(upper), out, index)
        index[index < 0] = max(self.n - 1, 0)
        return out, index.astype(np.intp, copy=False)

    def distances(self, queries: np.ndarray, upper: float) -> np.ndarray:
        """The distances of :meth:`nearest`."""
        return self.nearest(queries, upper)[0]
