# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The fitter's hand-rolled fast paths give the digits of the slower, general code they replace
(the golden fits depend on it): checked against that code on random input."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from affordance_registration.core.transforms import axis_angle_matrix, matrix_to_quat_xyzw

_axis = st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3).filter(
    lambda a: math.fsum(x * x for x in a) > 1e-12
)
_angle = st.one_of(st.floats(-10.0, 10.0), st.floats(-2e-3, 2e-3))


def _scipy_axis_angle(axis, angle):
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    unit = (
        axis / np.linalg.norm(axis)
        if axis.ndim == 1
        else axis / np.sqrt([a @ a for a in axis])[:, None]
    )
    return Rotation.from_rotvec(unit * angle[..., None]).as_matrix()


@settings(max_examples=300, deadline=None)
@given(axes=st.lists(_axis, min_size=1, max_size=12), angles=st.data())
def test_axis_angle_matrix_has_scipys_digits(axes, angles):
    angle = angles.draw(st.lists(_angle, min_size=len(axes), max_size=len(axes)))
    for a, q in ((axes, angle), (axes[0], angle[0]), (axes[0], angle)):
        got, want = (
            axis_angle_matrix(a, q if np.ndim(q) == 0 else np.array(q)),
            _scipy_axis_angle(a, q),
        )
        assert got.shape == want.shape
        assert np.array_equal(got, want)


@settings(max_examples=400, deadline=None)
@given(
    axis=_axis, angle=st.one_of(st.floats(-10.0, 10.0), st.sampled_from([0.0, math.pi, -math.pi]))
)
def test_matrix_to_quaternion_has_scipys_digits(axis, angle):
    R = _scipy_axis_angle(axis, angle)
    want = Rotation.from_matrix(R).as_quat()
    want = want if want[3] >= 0 else -want
    assert np.array_equal(matrix_to_quat_xyzw(R), want)


# -- visibility: one pass over the offsets from the sensor, against the formulas it replaced --

import pytest  # noqa: E402

from affordance_registration.core.registration import FitSettings, Registrar  # noqa: E402
from affordance_registration.core.registration.correspondences import stack_samples  # noqa: E402
from affordance_registration.core.registration.visibility import facing, visible  # noqa: E402
from affordance_registration.core.scene import Scene  # noqa: E402
from affordance_registration.core.templates import TemplateLibrary  # noqa: E402
from affordance_registration.core.transforms import random_rotations  # noqa: E402
from affordance_registration.evaluation.simulation import simulate_taskboard  # noqa: E402


@pytest.fixture(scope="module")
def clicked():
    """(registrar, prepared click context) on a simulated panel scene."""
    library = TemplateLibrary.load()
    sim = simulate_taskboard(library, 1000)
    registrar = Registrar(library)
    return registrar, registrar.prepare(Scene(sim.organized), sim.objects[0].click)


def _reference_visible(ctx, X, Nw, settings):
    """The visibility terms as first written: cosine by division, range image by masks."""
    ray = ctx.sensor_origin - X
    cos_in = np.einsum("bsi,bsi->bs", Nw, ray) / np.maximum(np.linalg.norm(ray, axis=-1), 1e-9)
    front = cos_in > math.cos(settings.scoring.grazing_angle)
    img = ctx.range_image
    rel = (X - img.origin) @ img.frame
    z = rel[..., 2]
    zs = np.where(z > 1e-3, z, 1e-3)
    iu = np.floor((rel[..., 0] / zs - img.u0) / img.bin).astype(np.int64)
    iv = np.floor((rel[..., 1] / zs - img.v0) / img.bin).astype(np.int64)
    inside = (iu >= 0) & (iu < img.nu) & (iv >= 0) & (iv < img.nv) & (z > 1e-3)
    obs = np.where(inside, img.depth[np.where(inside, iu * img.nv + iv, 0)], np.nan)
    known = np.isfinite(obs)
    m = settings.scoring.free_space_margin
    hidden = known & (obs < z - m)
    violated = known & (obs > z + m)
    return cos_in, front, obs, z, (front & known & ~hidden, front & violated, front & known)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), grazing=st.sampled_from([60.0, 80.0, 89.0, 95.0]))
def test_visibility_matches_the_formulas_it_replaced(clicked, seed, grazing):
    registrar, ctx = clicked
    s = FitSettings().with_(**{"scoring.grazing_angle": math.radians(grazing)})
    rng = np.random.default_rng(seed)
    models = [registrar.models.model(t) for t in registrar.library.values()]
    models = [models[i] for i in rng.integers(0, len(models), 6)]
    P, N = stack_samples(models, 128)
    R = random_rotations(len(models), rng)
    t = ctx.click + rng.normal(scale=0.05, size=(len(models), 3))
    t[-1] = ctx.click + 2.0 * ctx.frame[:, 0]  # off the range image: no returns
    X = P @ np.swapaxes(R, 1, 2) + t[:, None]
    Nw = N @ np.swapaxes(R, 1, 2)
    cos_in, front, obs, z, want = _reference_visible(ctx, X, Nw, s)
    got = visible(ctx, X, Nw, s, exposed=True)
    # the facing test compares squares instead of dividing: it may differ only on the edge
    edge = np.abs(cos_in - math.cos(s.scoring.grazing_angle)) < 1e-12
    assert np.array_equal(facing(ctx, X, Nw, s) | edge, front | edge)
    for g, w in zip(got, want):
        assert np.array_equal(g | edge, w | edge)
    # a primitive's rows: what something else hides by occluder_gap or more is not exposed
    rows = np.arange(len(models)) % 2 == 0
    exposed = visible(ctx, X, Nw, s, exposed=True, occluded=rows)[2]
    hidden = np.isfinite(obs) & (obs < z - s.verdict.occluder_gap)
    assert np.array_equal(exposed[~rows] | edge[~rows], want[2][~rows] | edge[~rows])
    assert np.array_equal(exposed[rows] | edge[rows], (want[2] & ~hidden)[rows] | edge[rows])
    got_obs, got_z = ctx.range_image.lookup(X)
    assert np.array_equal(got_z, z)
    assert np.array_equal(got_obs, obs, equal_nan=True)
    assert np.isnan(obs).any() and np.isfinite(obs).any()  # both cases exercised


def test_stacked_samples_are_each_models_own(clicked):
    registrar, _ = clicked
    models = [registrar.models.model(t) for t in registrar.library.values()]
    articulated = next(m for m in models if m.template.joint is not None)
    models.append(articulated.with_values(q=0.3, scale=1.1))
    for batch in (models[:1], models[:1] * 4, models * 3 + models[::-1]):
        P, N = stack_samples(batch, 64)
        assert P.shape == N.shape == (len(batch), 64, 3)
        for b, m in enumerate(batch):
            assert np.array_equal(P[b], m.samples(64)[0])
            assert np.array_equal(N[b], m.samples(64)[1])


def _reference_distances(models, local, upper):
    """Distances to each model's surface, one query per distinct model (the code it replaced)."""
    out = np.empty(local.shape[:2])
    keys = np.array([id(m) for m in models])
    for key in dict.fromkeys(keys.tolist()):
        sel = np.flatnonzero(keys == key)
        d, _ = models[int(sel[0])].nearest(local[sel].reshape(-1, 3), upper)
        out[sel] = d.reshape(len(sel), -1)
    return out


@settings(max_examples=60, deadline=None)
@given(
    picks=st.lists(
        st.tuples(
            st.integers(0, 4),
            st.sampled_from([0.0, -0.4, 0.3, 0.7]),
            st.sampled_from([1.0, 0.9, 1.15]),
            st.booleans(),
        ),
        min_size=1,
        max_size=12,
    ),
    k=st.integers(1, 40),
    upper=st.sampled_from([np.inf, 0.01, 0.05]),
    seed=st.integers(0, 99),
)
def test_surface_distances_of_a_batch_are_each_models_own(clicked, picks, k, upper, seed):
    """One query per template and scale gives the distances each model's own query gives --
    models repeated (shared by hypotheses) or not, joints at zero or turned, any scale."""
    from affordance_registration.core.registration.model import surface_distances

    registrar, ctx = clicked
    tpls = list(registrar.library.values())
    made = {}
    models = []
    for i, q, g, shared in picks:
        tpl = tpls[i]
        key = (i, q, g)
        m = made.get(key) if shared else None
        if m is None:
            m = registrar.models.model(
                tpl, q if tpl.joint is not None else 0.0, g, articulated=True
            )
            made[key] = m
        models.append(m)
    rng = np.random.default_rng(seed)
    local = rng.normal(scale=0.05, size=(len(models), k, 3))
    got = surface_distances(models, local, upper)
    assert np.array_equal(got, _reference_distances(models, local, upper))


# -- normals: the closed-form smallest eigenvector against LAPACK's --


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    spreads=st.lists(
        st.sampled_from([0.0, 1e-9, 1e-6, 1e-4, 1e-3, 1e-2, 1.0, 1e3]), min_size=3, max_size=3
    ),
    n=st.integers(1, 16),
    turned=st.booleans(),
)
def test_least_spread_is_lapacks_smallest_eigenvector(seed, spreads, n, turned):
    """Neighbourhoods of every shape -- a plane, a line, a blob, one point repeated, scales
    from nanometres to kilometres, along the axes or turned anyhow: the closed-form vector is
    a unit vector of the smallest eigenvalue (its Rayleigh quotient at LAPACK's smallest
    eigenvalue), along LAPACK's within 1e-9 rad wherever the two smallest eigenvalues are
    apart."""
    from affordance_registration.core.neighbours import CLOSE_EIGENVALUES, least_spread

    rng = np.random.default_rng(seed)
    turn = Rotation.random(random_state=seed).as_matrix() if turned else np.eye(3)
    pts = rng.normal(size=(8, n, 3)) * np.asarray(spreads) @ turn.T + rng.normal(size=3) * 10
    rel = pts - pts.mean(axis=1, keepdims=True)
    C = np.swapaxes(rel, 1, 2) @ rel
    got = least_spread(C)
    vals, vecs = np.linalg.eigh(C)
    assert np.allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)
    rayleigh = np.einsum("mi,mij,mj->m", got, C, got)
    assert np.all(rayleigh <= vals[:, 0] + 1e-9 * np.maximum(vals[:, 2], 1e-300))
    apart = vals[:, 1] - vals[:, 0] > 2 * CLOSE_EIGENVALUES * vals[:, 2]
    sin = np.linalg.norm(np.cross(got[apart], vecs[apart, :, 0]), axis=1)
    assert np.all(sin <= 1e-9), sin.max()
