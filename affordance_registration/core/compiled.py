# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Compiled kernels (numba) for the fitter's hot loops, each with its numpy reference, and the
switch between them.

A kernel here gives the numbers its numpy path gives, to the last bit: it does the same
floating-point operations in the same order (no fast-math, no fused multiply-add, no
reductions reordered), and a test holds the two equal (``test/test_compiled.py``) -- but for the
fused ICP step (below), whose sums are added in another order than numpy's BLAS adds them: its
fits stay within the golden fits' tolerance of the numpy path's (the same test). What a kernel
saves is the work around the arithmetic -- the calls, the pruning -- and it releases the GIL,
so the fitter's threads (:mod:`.registration.parallel`) run it side by side.

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

The KD-tree (:class:`NearestTree`): the same neighbours as pykdtree's tree (the same distances
to the last bit; of points exactly as near, the lowest index), 25-30% less time a query on the
fitter's sets (240-300 ns against 300-400), no call's overhead, and readable from inside a
kernel -- where a search may start from a guess (the last iteration's partner), a tighter
bound with the same answer.

The pairs of a point set within a radius (:func:`pairs_within`): what the clicked object's
segmentation joins (``segmentation``), the same set as scipy's ``query_pairs`` from a grid of
cells of the radius, each pair looked at once -- 4.8 against 7.6 ms of a real click.

The fused ICP step (:func:`_rigid_step`): one point-to-point iteration of a batch of hypotheses
on the voxelized cluster -- posing, the visibility test, the plane band, the nearest point, the
weights, the weighted sums and the 3 x 3 SVD -- in one call instead of some fifty array
operations (``registration.icp``). On the full-resolution cluster, :func:`_fine_rows` makes one
hypothesis' correspondences (forward and reverse) in one call; the Gauss-Newton step stays
numpy's. (A fused residual -- forward, backward and click terms in one call -- measured 20%
slower than numpy's with the grids: the grids answer the capped queries faster than a tree.)
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
    "pairs_within",
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


def _select(keys, idx, lo, stop, k):
    """Reorder ``keys`` and ``idx`` alike over [lo, stop) so that ``keys[k]`` is the value a
    sort would put there, none before it larger and none after it smaller (Hoare's selection,
    the pivot the median of three): a median in linear time, where a sort takes n log n."""
    hi = stop - 1
    while hi > lo:
        mid = (lo + hi) // 2
        x, y, z = keys[lo], keys[mid], keys[hi]
        pivot = max(min(x, y), min(max(x, y), z))
        i, j = lo, hi
        while i <= j:
            while keys[i] < pivot:
                i += 1
            while keys[j] > pivot:
                j -= 1
            if i <= j:
                keys[i], keys[j] = keys[j], keys[i]
                idx[i], idx[j] = idx[j], idx[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:  # (between them every key is the pivot)
            return


def _tree_build(points, leaf):
    """A KD-tree over ``points`` (N, 3): the points in leaf order (N, 3), their indices in
    ``points`` (N,), and per node its first and end point, its split axis and value (-1 and 0
    for a leaf) and its two children (-1 for a leaf). A node is split at its median along its
    widest axis until it holds at most ``leaf`` points."""
    n = points.shape[0]
    idx = np.arange(n)
    most = 4 * (n // max(leaf, 1) + 1) + 1  # (a split leaf holds leaf // 2 points or more)
    start = np.empty(most, np.int64)
    stop = np.empty(most, np.int64)
    axis = np.full(most, -1, np.int64)
    split = np.zeros(most)
    left = np.full(most, -1, np.int64)
    right = np.full(most, -1, np.int64)
    todo = np.empty(most, np.int64)
    keys = np.empty(n)
    start[0], stop[0], todo[0] = 0, n, 0
    nodes, pending = 1, 1
    while pending > 0:
        pending -= 1
        node = todo[pending]
        a, b = start[node], stop[node]
        if b - a <= leaf:
            continue
        widest, ax = -1.0, 0
        for d in range(3):
            mn = np.inf
            mx = -np.inf
            for i in range(a, b):
                v = points[idx[i], d]
                mn = min(mn, v)
                mx = max(mx, v)
            if mx - mn > widest:
                widest, ax = mx - mn, d
        for i in range(a, b):
            keys[i] = points[idx[i], ax]
        m = (a + b) // 2
        _select(keys, idx, a, b, m)
        axis[node], split[node] = ax, points[idx[m], ax]
        left[node], right[node] = nodes, nodes + 1
        start[nodes], stop[nodes] = a, m
        start[nodes + 1], stop[nodes + 1] = m, b
        todo[pending], todo[pending + 1] = nodes, nodes + 1
        nodes += 2
        pending += 2
    pts = np.empty((n, 3))
    for j in range(n):
        for d in range(3):
            pts[j, d] = points[idx[j], d]
    return (
        pts,
        idx,
        start[:nodes].copy(),
        stop[:nodes].copy(),
        axis[:nodes].copy(),
        split[:nodes].copy(),
        left[:nodes].copy(),
        right[:nodes].copy(),
    )


def _tree_query(
    pts, idx, start, stop, axis, split, left, right, q0, q1, q2, bound, todo, lower, guess
):
    """The squared distance (at most ``bound``, else ``bound``) from (q0, q1, q2) to the
    nearest tree point and that point's place in the tree's ``pts`` (-1 beyond the bound);
    ``todo`` and ``lower`` are scratch (at least the tree's depth + 2). Of points exactly as
    near, the one of lowest index. ``guess``: a place whose point is likely near (the last
    iteration's partner), or -1 -- a tighter bound to start from, the same answer."""
    best = bound
    at = -1
    if guess >= 0:
        dx = q0 - pts[guess, 0]
        dy = q1 - pts[guess, 1]
        dz = q2 - pts[guess, 2]
        d = dx * dx + dy * dy + dz * dz
        if d <= best:
            best = d
            at = guess
    todo[0], lower[0] = 0, 0.0
    pending = 1
    while pending > 0:
        pending -= 1
        if lower[pending] > best:
            continue
        node = todo[pending]
        while left[node] >= 0:
            ax = axis[node]
            gap = (q0 if ax == 0 else q1 if ax == 1 else q2) - split[node]
            near, far = (left[node], right[node]) if gap < 0 else (right[node], left[node])
            if gap * gap <= best:
                todo[pending], lower[pending] = far, gap * gap
                pending += 1
            node = near
        for j in range(start[node], stop[node]):
            dx = q0 - pts[j, 0]
            dy = q1 - pts[j, 1]
            dz = q2 - pts[j, 2]
            d = dx * dx + dy * dy + dz * dz
            if d < best or d == best and (at < 0 or idx[j] < idx[at]):
                best = d
                at = j
    return best, at


def _tree_nearest(pts, idx, start, stop, axis, split, left, right, queries, upper, out, index):
    """For each of ``queries`` (M, 3): the distance to the nearest tree point within ``upper``
    into ``out`` (inf beyond) and its index into ``index`` (-1)."""
    todo = np.empty(128, np.int64)
    lower = np.empty(128)
    bound = upper * upper
    for i in range(queries.shape[0]):
        best, at = _tree_query(
            pts,
            idx,
            start,
            stop,
            axis,
            split,
            left,
            right,
            queries[i, 0],
            queries[i, 1],
            queries[i, 2],
            bound,
            todo,
            lower,
            -1,
        )
        out[i] = math.sqrt(best) if at >= 0 else np.inf
        index[i] = idx[at] if at >= 0 else -1


#: the layout of the ``view`` array of :func:`_rigid_step` (what the sensor saw around a click
#: and how the correspondences are weighed; :func:`view_array` fills it)
V_ORIGIN, V_HAS_ORIGIN, V_COS = 0, 3, 4  # sensor origin, whether there is one, cos(grazing)
V_IMAGE, V_HAS_IMAGE, V_U0, V_V0, V_BIN, V_NU, V_NV, V_MARGIN = 5, 8, 9, 10, 11, 12, 13, 14
V_NORMAL, V_PLANE_D, V_HAS_PLANE, V_BAND, V_D0 = 15, 18, 19, 20, 21
V_SIZE = 22


def _rigid_step(P, N, active, R, t, radius, view, frame, depth, tree, guess, out_R, out_t, out_c):
    """One point-to-point ICP step of each hypothesis ``active[b]`` (samples P, normals N
    (B, S, 3), model frame) at pose R[b] (b, 3, 3), t[b] (b, 3) with rejection radius
    ``radius[b]``: the samples posed, those the sensor could see (facing it, not behind the
    range image ``depth`` looked up through ``frame``) paired with the plane band's projection
    or the nearest ``tree`` point, weighed 1 / (1 + d / d0) within the radius, and the
    weighted rigid transform solved (SVD, reflection-safe) into out_R, out_t, about the
    weighted centroid out_c (identity where nothing weighs). ``guess`` (B, S): each sample's
    last partner's place in the tree (-1: none), where the search starts; updated."""
    pts, idx, start, stop, axis, split, left, right = tree
    S = P.shape[1]
    x = np.empty((S, 3))
    q = np.empty((S, 3))
    w = np.empty(S)
    todo = np.empty(128, np.int64)
    lower = np.empty(128)
    H = np.empty((3, 3))
    xs = np.empty(3)
    ns = np.empty(3)
    has_plane = view[V_HAS_PLANE] > 0
    nu, nv = int(view[V_NU]), int(view[V_NV])
    d0 = view[V_D0]
    for b in range(active.shape[0]):
        h = active[b]
        rad = radius[b]
        for s in range(S):
            p0, p1, p2 = P[h, s, 0], P[h, s, 1], P[h, s, 2]
            m0, m1, m2 = N[h, s, 0], N[h, s, 1], N[h, s, 2]
            for i in range(3):
                xs[i] = p0 * R[b, i, 0] + p1 * R[b, i, 1] + p2 * R[b, i, 2] + t[b, i]
                ns[i] = m0 * R[b, i, 0] + m1 * R[b, i, 1] + m2 * R[b, i, 2]
            seen = _seen(xs, ns, view, frame, depth, nu, nv)
            dist = np.inf
            for i in range(3):
                x[s, i] = xs[i]
                q[s, i] = xs[i]
            if seen:
                pd = 0.0
                if has_plane:
                    pd = (
                        xs[0] * view[V_NORMAL]
                        + xs[1] * view[V_NORMAL + 1]
                        + xs[2] * view[V_NORMAL + 2]
                        + view[V_PLANE_D]
                    )
                if has_plane and pd <= view[V_BAND]:
                    dist = abs(pd)
                    for i in range(3):
                        q[s, i] = xs[i] - pd * view[V_NORMAL + i]
                else:
                    best, at = _tree_query(
                        pts,
                        idx,
                        start,
                        stop,
                        axis,
                        split,
                        left,
                        right,
                        xs[0],
                        xs[1],
                        xs[2],
                        rad * rad,
                        todo,
                        lower,
                        guess[h, s],
                    )
                    if at >= 0:
                        guess[h, s] = at
                        dist = math.sqrt(best)
                        for i in range(3):
                            q[s, i] = pts[at, i]
            w[s] = 1.0 / (1.0 + dist / d0) if dist <= rad else 0.0
        W = 0.0
        for s in range(S):
            W += w[s]
        ok = W > 1e-9
        Ws = W if ok else 1.0
        mx = np.zeros(3)
        mq = np.zeros(3)
        for s in range(S):
            for i in range(3):
                mx[i] += w[s] * x[s, i]
                mq[i] += w[s] * q[s, i]
        for i in range(3):
            mx[i] /= Ws
            mq[i] /= Ws
            out_c[b, i] = mx[i]
        if not ok:
            for i in range(3):
                for j in range(3):
                    out_R[b, i, j] = 1.0 if i == j else 0.0
                out_t[b, i] = 0.0
            continue
        for i in range(3):
            for j in range(3):
                H[i, j] = 0.0
        for s in range(S):
            if w[s] == 0.0:
                continue
            for i in range(3):
                a = (x[s, i] - mx[i]) * w[s]
                for j in range(3):
                    H[i, j] += a * (q[s, j] - mq[j])
        U, _, Vt = np.linalg.svd(H)
        V = Vt.T.copy()
        det = np.linalg.det(V @ U.T)
        sign = (1.0 if det > 0 else -1.0 if det < 0 else 0.0) + (1.0 if det == 0 else 0.0)
        for j in range(3):
            V[j, 2] *= sign
        Rs = V @ U.T
        for i in range(3):
            for j in range(3):
                out_R[b, i, j] = Rs[i, j]
            out_t[b, i] = mq[i] - (Rs[i, 0] * mx[0] + Rs[i, 1] * mx[1] + Rs[i, 2] * mx[2])


def _seen(x, n, view, frame, depth, nu, nv):
    """Whether the sensor could see a sample at ``x`` (3,) with normal ``n`` (3,): facing it,
    not beyond the grazing angle, and not behind the range image (``visibility.visible``)."""
    seen = True
    if view[V_HAS_ORIGIN] > 0:
        D0 = x[0] - view[V_ORIGIN]
        D1 = x[1] - view[V_ORIGIN + 1]
        D2 = x[2] - view[V_ORIGIN + 2]
        dot = D0 * n[0] + D1 * n[1] + D2 * n[2]
        n2 = max(D0 * D0 + D1 * D1 + D2 * D2, 1e-18)
        c = view[V_COS]
        if c >= 0.0:
            seen = dot < 0.0 and dot * dot > (c * c) * n2
        else:
            seen = dot < 0.0 or dot * dot < (c * c) * n2
    if seen and view[V_HAS_IMAGE] > 0:
        E0 = x[0] - view[V_IMAGE]
        E1 = x[1] - view[V_IMAGE + 1]
        E2 = x[2] - view[V_IMAGE + 2]
        r0 = E0 * frame[0, 0] + E1 * frame[1, 0] + E2 * frame[2, 0]
        r1 = E0 * frame[0, 1] + E1 * frame[1, 1] + E2 * frame[2, 1]
        z = E0 * frame[0, 2] + E1 * frame[1, 2] + E2 * frame[2, 2]
        zs = max(z, 1e-3)
        fu = math.floor((r0 / zs - view[V_U0]) / view[V_BIN])
        fv = math.floor((r1 / zs - view[V_V0]) / view[V_BIN])
        flat = nu * nv
        if 0 <= fu < nu and 0 <= fv < nv and z > 1e-3:
            flat = int(fu) * nv + int(fv)
        seen = depth[flat] >= z - view[V_MARGIN]  # (NaN: unknown, not seen)
    return seen


def _pairs(pts, order, lo, dims, first, cell, radius, out):
    """The index pairs (i < j, into the original points) of the grid points (``_build``'s
    arrays, cells of edge ``cell`` at least ``radius``) at most ``radius`` apart -- squared
    distance ((dx^2 + dy^2) + dz^2) against radius^2, as the KD-tree's ``query_pairs``
    compares them -- written into ``out`` (M, 2) up to its length; returns how many there are
    (a count larger than ``out`` holds: call again with room for them). Each pair is looked at
    once: a cell's own points after each point, and the 13 neighbouring cells that come after
    it in the grid's order."""
    bound = radius * radius
    m = 0
    room = out.shape[0]
    n1, n2 = dims[1], dims[2]
    for a0 in range(dims[0]):
        for b0 in range(n1):
            for c0 in range(n2):
                here = (a0 * n1 + b0) * n2 + c0
                hi_c = min(c0 + 1, n2 - 1)  # (the cells along z up to the next one)
                for i in range(first[here], first[here + 1]):
                    p0, p1, p2 = pts[i, 0], pts[i, 1], pts[i, 2]
                    oi = order[i]
                    for da in range(0, 2):
                        a = a0 + da
                        if a >= dims[0]:
                            continue
                        for db in range(-1, 2):
                            b = b0 + db
                            if b < 0 or b >= n1 or (da == 0 and db < 0):
                                continue
                            row = (a * n1 + b) * n2
                            # (in this column: this cell's later points and the next cell)
                            lo_j = i + 1 if da == 0 and db == 0 else first[row + max(c0 - 1, 0)]
                            for j in range(lo_j, first[row + hi_c + 1]):
                                dx = p0 - pts[j, 0]
                                dy = p1 - pts[j, 1]
                                dz = p2 - pts[j, 2]
                                if dx * dx + dy * dy + dz * dz <= bound:
                                    if m < room:
                                        oj = order[j]
                                        out[m, 0] = min(oi, oj)
                                        out[m, 1] = max(oi, oj)
                                    m += 1
    return m


def _fine_rows(
    X,
    Nw,
    radius,
    view,
    frame,
    depth,
    fine,
    fine_normals,
    guess,
    rev_pts,
    rev_normals,
    centre,
    half,
    R,
    t,
    scale,
    whole,
    whole_moving,
    jointed,
    base,
    moving,
    T,
    out_X,
    out_Q,
    out_N,
    out_w,
    out_U,
    out_moving,
):
    """The correspondences of one iteration of the full-resolution stage for one hypothesis
    (R (3, 3), t (3,), rejection ``radius``), as ``correspondences.forward_pairs`` and
    ``reverse_pairs`` make them, into the ``out_`` rows; returns how many. Forward: each posed
    sample of X, Nw (S, 3) the sensor could see paired with the plane band's projection or the
    nearest ``fine`` point (its normal from ``fine_normals``; ``guess`` (S,): where each
    search starts, updated); the others keep Q = X, N = 0, w = 0. Reverse: each of ``rev_pts``
    within ``half`` of ``centre`` paired with the nearest dense surface sample of the model
    (scaled by ``scale``; with ``jointed``, of its fixed part ``base`` or its moving part
    ``moving`` moved by ``T``, else of ``whole``, whose samples ``whole_moving`` labels),
    U the sample unscaled in the model frame and ``out_moving`` its part."""
    todo = np.empty(128, np.int64)
    lower = np.empty(128)
    nu, nv = int(view[V_NU]), int(view[V_NV])
    d0 = view[V_D0]
    fp = fine[0]
    S = X.shape[0]
    for s in range(S):
        x = X[s]
        seen = _seen(x, Nw[s], view, frame, depth, nu, nv)
        dist = np.inf
        for i in range(3):
            out_X[s, i] = x[i]
            out_Q[s, i] = x[i]
            out_N[s, i] = 0.0
        if seen:
            pd = 0.0
            if view[V_HAS_PLANE] > 0:
                pd = (
                    x[0] * view[V_NORMAL]
                    + x[1] * view[V_NORMAL + 1]
                    + x[2] * view[V_NORMAL + 2]
                    + view[V_PLANE_D]
                )
            if view[V_HAS_PLANE] > 0 and pd <= view[V_BAND]:
                dist = abs(pd)
                for i in range(3):
                    out_Q[s, i] = x[i] - pd * view[V_NORMAL + i]
                    out_N[s, i] = view[V_NORMAL + i]
            else:
                best, at = _tree_query(
                    fp,
                    fine[1],
                    fine[2],
                    fine[3],
                    fine[4],
                    fine[5],
                    fine[6],
                    fine[7],
                    x[0],
                    x[1],
                    x[2],
                    radius * radius,
                    todo,
                    lower,
                    guess[s],
                )
                if at >= 0:
                    guess[s] = at
                    dist = math.sqrt(best)
                    for i in range(3):
                        out_Q[s, i] = fp[at, i]
                        out_N[s, i] = fine_normals[fine[1][at], i]
        out_w[s] = 1.0 / (1.0 + dist / d0) if dist <= radius else 0.0
    n = S
    ub = radius / scale
    bound = ub * ub
    u = np.empty(3)
    um = np.empty(3)
    p = np.empty(3)
    for m in range(rev_pts.shape[0]):
        e0 = rev_pts[m, 0] - centre[0]
        e1 = rev_pts[m, 1] - centre[1]
        e2 = rev_pts[m, 2] - centre[2]
        if not e0 * e0 + e1 * e1 + e2 * e2 <= half * half:
            continue
        g0 = rev_pts[m, 0] - t[0]
        g1 = rev_pts[m, 1] - t[1]
        g2 = rev_pts[m, 2] - t[2]
        for j in range(3):
            u[j] = (g0 * R[0, j] + g1 * R[1, j] + g2 * R[2, j]) / scale
        closer = False
        if not jointed:
            best, at = _tree_query(
                whole[0],
                whole[1],
                whole[2],
                whole[3],
                whole[4],
                whole[5],
                whole[6],
                whole[7],
                u[0],
                u[1],
                u[2],
                bound,
                todo,
                lower,
                -1,
            )
            d = math.sqrt(best) if at >= 0 else np.inf
            at = max(at, 0)
            for i in range(3):
                p[i] = whole[0][at, i]
            closer = whole_moving[whole[1][at]]
        else:
            best, at = _tree_query(
                base[0],
                base[1],
                base[2],
                base[3],
                base[4],
                base[5],
                base[6],
                base[7],
                u[0],
                u[1],
                u[2],
                bound,
                todo,
                lower,
                -1,
            )
            d = math.sqrt(best) if at >= 0 else np.inf
            at = max(at, 0)
            for i in range(3):
                p[i] = base[0][at, i]
            for j in range(3):
                um[j] = (
                    (u[0] - T[0, 3]) * T[0, j]
                    + (u[1] - T[1, 3]) * T[1, j]
                    + (u[2] - T[2, 3]) * T[2, j]
                )
            bm, am = _tree_query(
                moving[0],
                moving[1],
                moving[2],
                moving[3],
                moving[4],
                moving[5],
                moving[6],
                moving[7],
                um[0],
                um[1],
                um[2],
                bound,
                todo,
                lower,
                -1,
            )
            dm = math.sqrt(bm) if am >= 0 else np.inf
            if dm < d:
                closer = True
                d = dm
                q0, q1, q2 = moving[0][am, 0], moving[0][am, 1], moving[0][am, 2]
                for i in range(3):
                    p[i] = q0 * T[i, 0] + q1 * T[i, 1] + q2 * T[i, 2] + T[i, 3]
        dist = d * scale
        for i in range(3):
            lp = p[i] * scale
            p[i] = lp
            out_U[n, i] = lp / scale
            out_Q[n, i] = rev_pts[m, i]
            out_N[n, i] = rev_normals[m, i]
        for i in range(3):
            out_X[n, i] = p[0] * R[i, 0] + p[1] * R[i, 1] + p[2] * R[i, 2] + t[i]
        out_w[n] = 1.0 / (1.0 + dist / d0) if dist <= radius else 0.0
        out_moving[n] = closer
        n += 1
    return n


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
    k.pairs = jit(_pairs, "i8(f8[:, ::1], i8[::1], f8[::1], i8[::1], i8[::1], f8, f8, i8[:, ::1])")
    # a kernel that others call is bound in this module's namespace as compiled, where the
    # callers (compiled after it) find it
    globals()["_select"] = jit(_select, "void(f8[::1], i8[::1], i8, i8, i8)")
    tree = "Tuple((f8[:, ::1], i8[::1], i8[::1], i8[::1], i8[::1], f8[::1], i8[::1], i8[::1]))"
    k.tree_build = jit(_tree_build, f"{tree}(f8[:, ::1], i8)")
    globals()["_tree_query"] = jit(
        _tree_query,
        "Tuple((f8, i8))(f8[:, ::1], i8[::1], i8[::1], i8[::1], i8[::1], f8[::1], i8[::1], "
        "i8[::1], f8, f8, f8, f8, i8[::1], f8[::1], i8)",
    )
    k.tree_nearest = jit(
        _tree_nearest,
        "void(f8[:, ::1], i8[::1], i8[::1], i8[::1], i8[::1], f8[::1], i8[::1], i8[::1], "
        "f8[:, ::1], f8, f8[::1], i8[::1])",
    )
    # (compiled first: the step kernels call it)
    globals()["_seen"] = jit(_seen, "b1(f8[::1], f8[::1], f8[::1], f8[:, ::1], f8[::1], i8, i8)")
    k.rigid_step = jit(
        _rigid_step,
        f"void(f8[:, :, ::1], f8[:, :, ::1], i8[::1], f8[:, :, ::1], f8[:, ::1], f8[::1], "
        f"f8[::1], f8[:, ::1], f8[::1], {tree}, i8[:, ::1], f8[:, :, ::1], f8[:, ::1], "
        "f8[:, ::1])",
    )
    k.fine_rows = jit(
        _fine_rows,
        f"i8(f8[:, ::1], f8[:, ::1], f8, f8[::1], f8[:, ::1], f8[::1], {tree}, f8[:, ::1], "
        f"i8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8, f8[:, ::1], f8[::1], f8, {tree}, "
        f"b1[::1], b1, {tree}, {tree}, f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], "
        "f8[::1], f8[:, ::1], b1[::1])",
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


def pairs_within(points: np.ndarray, radius: float, k=None) -> np.ndarray:
    """Index pairs (M, 2), i < j, of ``points`` (N, 3) at most ``radius`` apart: the pairs
    the KD-tree's ``query_pairs`` finds (the same set; in another order), from a grid of cells
    of edge ``radius`` (at most ``MAX_CELLS_PER_AXIS`` along an axis). Use only where
    :func:`kernels` is not None."""
    k = k or kernels()
    points = np.array(points, dtype=float, order="C").reshape(-1, 3)
    if len(points) < 2:
        return np.empty((0, 2), np.int64)
    extent = float(np.ptp(points, axis=0).max())
    cell = max(float(radius), extent / MAX_CELLS_PER_AXIS, 1e-9)
    grid = k.build(points, cell)
    out = np.empty((8 * len(points), 2), np.int64)
    m = k.pairs(*grid, cell, float(radius), out)
    if m > len(out):  # (denser than a surface: again, with room for them all)
        out = np.empty((m, 2), np.int64)
        k.pairs(*grid, cell, float(radius), out)
    return out[:m]


#: points a leaf of :class:`NearestTree` holds at most
TREE_LEAF = 8


class NearestTree:
    """The nearest of ``points`` (N, 3) to query points, up to a bound: a KD-tree built and
    queried by the compiled kernels -- the same distances as :func:`..neighbours.nearest`'s
    tree, to the last bit, and the same points (of two exactly as near, the lower index),
    without a call's overhead and with the GIL released; ICP's fused step
    (:func:`_rigid_step`) reads it too. Use only where :func:`kernels` is not None."""

    def __init__(self, points: np.ndarray, k=None):
        k = k or kernels()
        points = np.array(points, dtype=float, order="C").reshape(-1, 3)
        self.n = len(points)
        self.points = points
        self._k = k
        self.arrays = k.tree_build(points, TREE_LEAF)

    def nearest(self, queries: np.ndarray, upper: float = np.inf):
        """Distance (M,) from each of ``queries`` (M, 3) to the nearest point and that point's
        index (M,), as :func:`..neighbours.nearest` gives them: beyond ``upper`` the distance
        is inf and the index a valid but meaningless one."""
        q = np.require(np.reshape(queries, (-1, 3)), float, ["C", "W"])
        out, index = np.empty(len(q)), np.empty(len(q), dtype=np.int64)
        if len(q) and self.n:
            bound = float(upper) if upper < np.inf else np.finfo(float).max ** 0.5
            self._k.tree_nearest(*self.arrays, q, bound, out, index)
        else:
            out[:], index[:] = np.inf, -1
        index[index < 0] = max(self.n - 1, 0)
        return out, index.astype(np.intp, copy=False)


def view_array(**fields) -> np.ndarray:
    """The ``view`` array of :func:`_rigid_step` (V_SIZE,) from its named fields: ``origin``,
    ``cos_grazing``, ``image_origin``, ``u0``, ``v0``, ``bin``, ``nu``, ``nv``, ``margin``,
    ``normal``, ``plane_d``, ``band``, ``d0`` (an absent origin, image or plane: None)."""
    v = np.zeros(V_SIZE)
    if fields.get("origin") is not None:
        v[V_ORIGIN : V_ORIGIN + 3], v[V_HAS_ORIGIN] = fields["origin"], 1.0
        v[V_COS] = fields["cos_grazing"]
    if fields.get("image_origin") is not None:
        v[V_IMAGE : V_IMAGE + 3], v[V_HAS_IMAGE] = fields["image_origin"], 1.0
        v[V_U0], v[V_V0], v[V_BIN] = fields["u0"], fields["v0"], fields["bin"]
        v[V_NU], v[V_NV], v[V_MARGIN] = fields["nu"], fields["nv"], fields["margin"]
    if fields.get("normal") is not None:
        v[V_NORMAL : V_NORMAL + 3], v[V_HAS_PLANE] = fields["normal"], 1.0
        v[V_PLANE_D], v[V_BAND] = fields["plane_d"], fields["band"]
    v[V_D0] = fields["d0"]
    return v
