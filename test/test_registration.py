# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Registration: the closed-form solves, the weighting rule, and fits on simulated scans."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from affordance_registration.core.errors import RegistrationError, SceneError
from affordance_registration.core.registration import (
    NO_MATCH_RESIDUAL,
    FitSettings,
    Registrar,
    correspondence_weights,
    weighted_rigid_fit,
)
from affordance_registration.core.registration.solve import point_to_plane_weighted
from affordance_registration.core.scene import NO_VIEWPOINT, Scene
from affordance_registration.core.templates import TemplateLibrary
from affordance_registration.core.transforms import make_T, pose_error, random_rotations
from affordance_registration.evaluation.simulation import simulate_taskboard

TOL_M, TOL_RAD = 0.005, math.radians(5)


@pytest.mark.parametrize("seed", range(6))
def test_weighted_rigid_fit_recovers_known_transforms(seed, library):
    rng = np.random.default_rng(seed)
    P = library["ball_valve"].samples(300, seed=seed)[0]
    R = random_rotations(1, rng)[0]
    t = rng.uniform(-0.5, 0.5, 3)
    Q = P @ R.T + t
    T = weighted_rigid_fit(P, Q)
    assert np.allclose(T[:3, :3], R, atol=1e-9) and np.allclose(T[:3, 3], t, atol=1e-9)
    # noisy and weighted: compare against an independent solver (scipy's Kabsch)
    Qn = Q + rng.normal(scale=0.002, size=Q.shape)
    w = rng.uniform(0.2, 1.0, len(P))
    T = weighted_rigid_fit(P, Qn, w)
    pc = (w[:, None] * P).sum(0) / w.sum()
    qc = (w[:, None] * Qn).sum(0) / w.sum()
    ref, _ = Rotation.align_vectors(Qn - qc, P - pc, weights=w)
    assert np.allclose(T[:3, :3], ref.as_matrix(), atol=1e-8)
    dt, dr = pose_error(T, make_T(R, t))
    assert dt < 0.001 and dr < math.radians(0.5)


def test_rigid_fit_never_returns_a_reflection():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(50, 3))
    Q = P * np.array([1, 1, -1])  # a mirror image: the best rotation, not a reflection
    T = weighted_rigid_fit(P, Q)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_point_to_plane_step_recovers_a_small_motion(library):
    P, N = library["emergency_stop"].samples(600, seed=1)
    R = Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix()
    t = np.array([0.003, -0.002, 0.004])
    X = P @ R.T + t  # moved copy; pair each with its original + normal
    T = np.eye(4)
    for _ in range(5):
        Xi = X @ T[:3, :3].T + T[:3, 3]
        dR, dt = point_to_plane_weighted(Xi[None], P[None], N[None], np.ones((1, len(P))))
        T = make_T(dR[0], dt[0]) @ T
    dt_, dr_ = pose_error(T @ make_T(R, t), np.eye(4))
    assert dt_ < 1e-6 and dr_ < 1e-6


def test_correspondence_rule():
    d = np.array([0.0, 0.005, 0.05, 0.3])
    assert np.allclose(correspondence_weights(d, 0.2, 1.0), [1, 1 / 1.005, 1 / 1.05, 0])
    assert np.allclose(correspondence_weights(d, 0.2, 0.005), [1, 0.5, 1 / 11, 0])


def test_weighting_and_rejection_change_the_answer(library):
    """A crafted case: 70% of the correspondences are right, 25% land on clutter 1.5 cm away and
    5% on a far outlier 0.3 m away. One weighted solve from the true pose, weights by the rule:
    the paper's weight (d in metres: all ~1) lets the clutter drag the pose; the scaled weight
    (d0 = 5 mm) does not; without the rejection beyond the diameter the far outliers drag it
    much further."""
    tpl = library["gate_valve"]
    P = tpl.samples(400, seed=1)[0]
    truth = make_T(Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), [0.1, -0.05, 0.9])
    Q = P @ truth[:3, :3].T + truth[:3, 3]
    Q[280:380] += [0.0, 0.015, 0.0]  # clutter
    Q[380:] += [0.0, 0.0, 0.3]  # far outliers
    X = P @ truth[:3, :3].T + truth[:3, 3]
    d = np.linalg.norm(X - Q, axis=1)

    def solve(d0, reject):
        step = weighted_rigid_fit(X, Q, correspondence_weights(d, reject, d0))
        return pose_error(step @ truth, truth)[0]

    scaled = solve(0.005, tpl.diameter)
    paper = solve(1.0, tpl.diameter)
    no_reject = solve(1.0, np.inf)
    assert scaled < 0.0025
    assert paper > scaled + 0.002
    assert no_reject > paper + 0.005


# ----------------------------------------------------------------------------- on scans
@pytest.fixture(scope="module")
def registrar(library):
    reg = Registrar(library)
    reg.warm_up()
    return reg


@pytest.mark.parametrize("seed", [7, 21])
def test_right_template_first_and_pose_within_tolerance(seed, library, registrar):
    sim = simulate_taskboard(library, seed)
    scene = Scene(sim.organized)
    for obj in sim.objects:
        rep = registrar.fit(scene, obj.click)
        best = rep.candidates[0]
        assert best.template == obj.template
        dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, library[obj.template].symmetry)
        assert dt <= TOL_M and dr <= TOL_RAD, (obj.template, dt, math.degrees(dr))
        assert [c.rank for c in rep.candidates] == list(range(1, len(library) + 1))
        # the specific templates' probabilities share 1 with "no template fits here"
        # (likelihood 1/NO_MATCH_RESIDUAL); the primitives' among themselves
        for pool in (False, True):
            cands = [c for c in rep.candidates if (c.primitive is not None) == pool]
            total = sum(c.likelihood for c in cands)
            assert sum(c.probability for c in cands) == pytest.approx(
                total / (total + 1.0 / NO_MATCH_RESIDUAL)
            )
        assert best.fits and best.coverage >= registrar.settings.verdict.min_coverage
        specific = [c for c in rep.candidates if c.primitive is None]
        assert rep.candidates[: len(specific)] == tuple(specific)  # primitives after them
        assert all(a.likelihood >= b.likelihood for a, b in zip(specific, specific[1:]))


@pytest.mark.parametrize("viewpoint", [True, False])
def test_every_candidate_judged_together_gets_the_verdict_it_gets_alone(library, viewpoint):
    """The verdicts of a click's candidates come from one pass over all of them; each must be
    exactly what judging that candidate alone gives (and the winner fits, the rest vary)."""
    from affordance_registration.core.registration.scoring import judge

    sim = simulate_taskboard(library, 12)
    scene = Scene(sim.organized, sensor_origin=None if viewpoint else NO_VIEWPOINT)
    reg = Registrar(library)
    for obj in sim.objects[:3]:
        rep = reg.fit(scene, obj.click)
        models = [reg._model(c.template, c.joints, c.scale, c.dimensions) for c in rep.candidates]
        together = judge(rep.context, models, rep.candidates, reg.settings)
        alone = [
            judge(rep.context, [m], [c], reg.settings)[0] for m, c in zip(models, rep.candidates)
        ]
        assert (
            [(c.coverage, c.inlier_rmse, c.fits) for c in together]
            == [(c.coverage, c.inlier_rmse, c.fits) for c in alone]
            == [(c.coverage, c.inlier_rmse, c.fits) for c in rep.candidates]
        )
        assert together[0].fits and len({c.coverage for c in together}) > 1


def test_objects_lying_on_a_table(library, registrar):
    sim = simulate_taskboard(library, 6, layout="table")
    scene = Scene(sim.organized)
    good = 0
    for obj in sim.objects:
        assert obj.click is not None
        best = registrar.fit(scene, obj.click).candidates[0]
        dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, library[obj.template].symmetry)
        good += best.template == obj.template and dt <= TOL_M and dr <= TOL_RAD
    assert good >= 4


def test_refit_returns_to_the_object_but_not_far_away(library, registrar, panel_scene):
    obj = panel_scene.objects[1]
    ctx = registrar.prepare(Scene(panel_scene.organized), obj.click)
    off = obj.T_scene_model.copy()
    off[:3, 3] += [0.012, -0.008, 0.0]
    res = registrar.refit(ctx, obj.template, off)
    dt, dr = pose_error(res.T_scene_model, obj.T_scene_model, library[obj.template].symmetry)
    assert dt < TOL_M and dr < TOL_RAD
    # an operator who moved the template 10 cm away is not overruled by a jump back
    far = obj.T_scene_model.copy()
    far[:3, 3] += [0.10, 0.0, 0.0]
    res = registrar.refit(ctx, obj.template, far)
    assert (
        np.linalg.norm(res.T_scene_model[:3, 3] - far[:3, 3]) <= registrar.settings.refit.max_move
    )


def test_paper_method_runs_as_published(library, panel_scene):
    settings = FitSettings(method="paper", paper_restarts=3, paper_iterations=20)
    rep = Registrar(library, settings).fit(
        Scene(panel_scene.organized), panel_scene.objects[0].click
    )
    assert len(rep.candidates) == len(library)
    assert all(c.iterations <= 3 * 20 for c in rep.candidates)
    assert rep.candidates[0].likelihood == pytest.approx(1 / rep.candidates[0].residual)


def test_clear_errors(library, registrar, tmp_path):
    with pytest.raises(SceneError, match="no finite points"):
        Scene(np.full((10, 3), np.nan))
    with pytest.raises(SceneError, match="shape"):
        Scene(np.zeros((10, 2)))
    scene = Scene(np.random.default_rng(0).uniform(-1, 1, (5000, 3)) + [0, 0, 2])
    with pytest.raises(SceneError, match="from the nearest scanned point"):
        registrar.fit(scene, [10.0, 0.0, 0.0])
    with pytest.raises(SceneError, match="finite"):
        registrar.fit(scene, [np.nan, 0.0, 1.0])
    with pytest.raises(SceneError, match="finite"):
        registrar.fit(scene, [np.inf, 0.0, 1.0])
    with pytest.raises(RegistrationError, match="empty"):
        Registrar(TemplateLibrary([]))
    with pytest.raises(RegistrationError, match="mode"):
        FitSettings(mode="sideways").validate()
    for name in ("joint_sweep", "scale_sweep"):  # a sweep of no steps has no step size
        with pytest.raises(
            RegistrationError, match=f"articulation.{name} must be an integer >= 1"
        ):
            FitSettings().with_(**{f"articulation.{name}": 0})
    # NaN rows are dropped, the rest is fitted
    pts = np.vstack([scene.points, np.full((100, 3), np.nan)])
    assert Scene(pts).dropped == 100


def test_scene_part_around_a_click_is_the_finite_points_within_reach(panel_scene):
    """A click reads only the part of the cloud near it: the points within the radius of it
    (holes of the organized cloud dropped there), the same as cropping the finite points; a
    click far from every point gets no part."""
    cloud = panel_scene.organized
    scene = Scene(cloud)
    assert scene.size == cloud.shape[0] * cloud.shape[1]
    finite = cloud.reshape(-1, 3)[np.isfinite(cloud.reshape(-1, 3)).all(axis=1)].astype(float)
    assert scene.dropped == scene.size - len(finite) > 0
    for obj in panel_scene.objects:
        part = scene.around(obj.click, 0.2)
        expected = finite[np.linalg.norm(finite - obj.click, axis=1) <= 0.2]
        assert len(expected) > 100
        np.testing.assert_array_equal(part.points, expected)
        assert np.all(part.sensor_origin == scene.sensor_origin)
    assert scene.around([10.0, 0.0, 0.0], 0.2) is None


def test_model_cache_is_safe_under_threads(library):
    """Concurrent fits share one cache of posed samples and KD-trees: every thread gets the
    samples of the joint value and scale it asked for (even while a small cache evicts), and
    one template's dense surface is built once for all of them."""
    from concurrent.futures import ThreadPoolExecutor

    from affordance_registration.core.registration.model import ModelCache

    tpl = library["ball_valve"]
    cache = ModelCache(max_posed=3)
    jobs = [(q, sc, n) for q in (0.0, 0.4, 1.2) for sc in (1.0, 1.15) for n in (64, 96)] * 4

    def posed(job):
        q, sc, n = job
        return cache.model(tpl, q, sc, articulated=True).samples(n)

    with ThreadPoolExecutor(6) as pool:
        got = list(pool.map(posed, jobs))
        surfaces = list(pool.map(lambda _: cache.surface(tpl), range(12)))
    for (q, sc, n), (P, N) in zip(jobs, got):
        P0, N0, moving = tpl.part_samples(n, seed=1)
        P_ref, N_ref = tpl.pose_parts(P0, N0, moving, q, sc)
        assert np.array_equal(P, P_ref) and np.array_equal(N, N_ref), (q, sc, n)
    assert all(s is surfaces[0] for s in surfaces)


def test_library_prefilter_sets_clearly_worse_templates_aside(library, panel_scene):
    """With more templates than the prefilter keeps, the clearly worse ones leave after the
    first coarse iterations: each template still has one candidate, those set aside rank
    behind the fitted ones, the true template is fitted and ranked first at its pose; with the
    prefilter off nothing is set aside and the winner is the same."""
    from affordance_registration.core.transforms import pose_error
    from affordance_registration.evaluation.bench import variant_library
    from affordance_registration.evaluation.simulation import POSE_TOL_M, POSE_TOL_RAD

    big = variant_library(library.specific(), 15)
    assert len(big) == 15 and "ball_valve@s0.75" in big
    scene = Scene(panel_scene.organized)
    on, off = Registrar(big), Registrar(big, FitSettings().with_(**{"prefilter.keep": 0}))
    decided = 0
    for obj in panel_scene.objects[:3]:
        cands = on.fit(scene, obj.click).candidates
        assert sorted(c.template for c in cands) == sorted(big)
        aside = [c.prefiltered for c in cands]
        assert aside == sorted(aside)  # the set-aside ones behind the others
        assert [c.to_dict()["prefiltered"] for c in cands] == aside  # what status / --json say
        # the fitted ones carry the verdict; the coarse poses set aside are not judged
        assert [c.fits is None for c in cands] == aside
        assert all(c.coverage == 0.0 and c.inlier_rmse == 0.0 for c in cands if c.prefiltered)
        assert sum(not a for a in aside) >= FitSettings().prefilter.keep
        decided += any(aside)
        assert cands[0].template == obj.template and not cands[0].prefiltered
        dt, dr = pose_error(
            cands[0].T_scene_model, obj.T_scene_model, library[obj.template].symmetry
        )
        assert dt <= POSE_TOL_M and dr <= POSE_TOL_RAD
        plain = off.fit(scene, obj.click).candidates
        assert not any(c.prefiltered for c in plain)
        assert plain[0].template == obj.template
    assert decided >= 1


def test_a_template_set_aside_is_fitted_and_judged_when_shown(library, panel_scene):
    """The operator shows a candidate the prefilter set aside: the engine fits it then (its
    pose was the coarse stage's) and it gets its verdict; it stays ranked where it was."""
    from affordance_registration.core.engine import AffordanceEngine
    from affordance_registration.evaluation.bench import variant_library

    engine = AffordanceEngine(variant_library(library.specific(), 15))
    engine.set_scene(panel_scene.organized, frame_id="cam")
    obj = panel_scene.objects[0]
    engine.click(obj.click)
    before = engine.status()["objects"][0]["candidates"]
    k, aside = next((k, c) for k, c in enumerate(before) if c["prefiltered"])
    assert aside["fits"] is None
    engine.select_model(aside["template"])
    after = engine.status()["objects"][0]
    shown = after["candidates"][after["shown"]]
    assert after["shown"] == k and shown["template"] == aside["template"]
    assert shown["fits"] is not None and not shown["prefiltered"]
    assert shown["coverage"] > 0.0 and shown["rank"] == aside["rank"]
    assert shown["pose"] != aside["pose"]


def test_leaders_are_finished_and_ranked_on_the_fine_residual(library):
    """Near shapes swap places at medium resolution: with squeezed copies of every template
    (y or z x 0.7) in the library, the copy of the grab handle (seed 1001) and of the ball
    valve (seed 1006) out-scored the true template there and were ranked first; and in the
    five-template library a ball valve's medium fit lay flipped behind a quarter-turn valve
    (seed 1015). The leaders -- the winner and the runners-up within ``finish.margin`` -- are
    finished alike (yaw sweep, fine stage) and ranked on that: the true template first, at its
    pose (with the winner alone finished, as before, all three ranked the wrong template first)."""
    from affordance_registration.evaluation.bench import (
        MIN_VISIBLE,
        VARIANT_SCALES,
        variant_library,
    )

    squeezed = tuple(v for v in VARIANT_SCALES if v[0] in ("y0.7", "z0.7"))
    big = variant_library(library.specific(), 15, squeezed)
    assert "grab_handle@y0.7" in big and "ball_valve@z0.7" in big
    for lib, seed, k in ((big, 1001, 3), (big, 1006, 0), (library, 1015, 0)):
        sim = simulate_taskboard(library, seed)
        obj = [o for o in sim.objects if o.visible_points >= MIN_VISIBLE][k]
        cands = Registrar(lib).fit(Scene(sim.organized), obj.click).candidates
        assert cands[0].template == obj.template, (seed, [c.template for c in cands[:3]])
        dt, dr = pose_error(
            cands[0].T_scene_model, obj.T_scene_model, library[obj.template].symmetry
        )
        assert dt <= TOL_M and dr <= TOL_RAD, (seed, dt, math.degrees(dr))
        assert len({c.template for c in cands}) == len(lib)


def _ribs_and_wall(seed: int):
    """A ribbed surface 0.25 m across (1 cm ripples 6 cm apart: the muscles on a statue's
    back) and a flat wall 0.3 m across with a 5 mm peak-to-peak depth wave and 2 mm noise (a
    depth camera's distortion) holding a 4 cm box; seen from 1 m along +z."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.125, 0.125, size=(6000, 2))
    ribs = np.column_stack([xy, 0.01 * np.sin(2 * math.pi * xy[:, 0] / 0.06 + seed)])
    xy = rng.uniform(-0.15, 0.15, size=(8000, 2))
    wave = 0.0025 * np.sin(2 * math.pi * xy[:, 0] / 0.25 + seed)
    wall = np.column_stack([xy, wave + rng.normal(scale=0.002, size=len(xy))])
    box = np.column_stack(
        [rng.uniform(-0.02, 0.02, size=(1500, 2)), rng.uniform(0.0, 0.04, size=1500)]
    )
    return ribs, np.vstack([wall, box])


@pytest.mark.parametrize("seed", range(3))
def test_a_support_plane_is_flat_not_a_slab_through_a_curved_object(seed):
    """RANSAC's best "plane" through a ribbed surface holds two fifths of it within the plane
    threshold, but its inliers' surface normals do not agree with it: no support plane, the
    cluster keeps the whole surface. A wall under depth-camera distortion and noise stays the
    support, and the cluster is the box standing on it: the wall's points the noise lifts past
    the plane threshold (flat, along the plane) are the wall's, not the box's."""
    ribs, wall = _ribs_and_wall(seed)
    ctx = Scene(ribs, sensor_origin=[0, 0, 1.0]).prepare_click(ribs[0], 0.15)
    assert ctx.support is None and len(ctx.cluster) >= 0.9 * len(ctx.crop)
    click = np.array([0.0, 0.0, 0.04])
    ctx = Scene(wall, sensor_origin=[0, 0, 1.0]).prepare_click(click, 0.15)
    assert ctx.support is not None and abs(ctx.support.normal[2]) > 0.99
    assert ctx.plane is not None
    assert np.all(np.abs(ctx.cluster[:, :2]).max(axis=0) < 0.035)


def test_each_template_keeps_its_best_restarts_through_the_coarse_stage(library, panel_scene):
    """After the first coarse iterations a template's restarts beyond its best ``coarse.keep``
    leave (its best mounted one always goes on); any scores, any template."""
    from affordance_registration.core.registration.hypotheses import (
        MOUNTED,
        best_per_template,
        initial_hypotheses,
    )

    reg = Registrar(library)
    ctx = reg.prepare(Scene(panel_scene.organized), panel_scene.objects[0].click)
    variants, _ = reg._variants(list(library))
    hyps = initial_hypotheses(ctx, variants, reg.settings, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for keep in (1, 3, 8):
        score = rng.uniform(size=len(hyps))
        kept = best_per_template(hyps, score, keep)
        assert np.all(np.diff(kept) > 0)
        for i in np.unique(hyps.index):
            mine = np.flatnonzero(hyps.index == i)
            best = set(mine[np.argsort(score[mine])[:keep]].tolist())
            mounted = mine[hyps.family[mine] == MOUNTED]
            wanted = best | ({int(mounted[np.argmin(score[mounted])])} if len(mounted) else set())
            assert set(kept[hyps.index[kept] == i].tolist()) == wanted, (keep, i)
    assert np.array_equal(best_per_template(hyps, score, 0), np.arange(len(hyps)))


def test_the_fine_stage_stops_close_to_where_it_would_converge_fully(
    library, panel_scene, monkeypatch
):
    """The fine stage stops at ``FINE_CONVERGED`` times the other stages' step thresholds: on
    every clicked object, started 3 mm and 2 degrees off the fit, it ends within 0.3 mm and
    0.3 degrees of where steps below the plain thresholds would take it (0.06 mm and 0.18
    degrees on this scene: a handwheel's turn about its axis is the weakly held direction that
    creeps on; 0.25 degrees at 5 times), and in fewer iterations overall. (30 times the
    thresholds: 0.36 mm off.)"""
    from affordance_registration.core.registration import icp as icp_module
    from affordance_registration.core.transforms import axis_angle_matrix

    registrar = Registrar(library)
    s = registrar.settings
    scene = Scene(panel_scene.organized)
    rng = np.random.default_rng(3)
    its = {True: 0, False: 0}
    factor = icp_module.FINE_CONVERGED
    assert factor > 1.0
    for obj in panel_scene.objects:
        if obj.visible_points < 200:
            continue
        ctx = registrar.prepare(scene, obj.click)
        model = registrar._model(obj.template)
        dR = axis_angle_matrix(rng.normal(size=3), math.radians(2.0))
        T = obj.T_scene_model
        off = rng.normal(size=3)
        R0, t0 = dR @ T[:3, :3], T[:3, 3] + 0.003 * off / np.linalg.norm(off)
        ends = {}
        for loose in (True, False):
            monkeypatch.setattr(icp_module, "FINE_CONVERGED", factor if loose else 1.0)
            fit = icp_module.fine_stage(ctx, model, R0, t0, s.stages.fine, s)
            ends[loose] = make_T(fit.R[0], fit.t[0])
            its[loose] += fit.iterations
        dt, dr = pose_error(ends[True], ends[False])
        assert dt <= 3e-4 and dr <= math.radians(0.3), (obj.template, dt, math.degrees(dr))
    assert its[True] < its[False]


def test_a_near_tie_is_decided_on_fully_converged_fine_stages(library, monkeypatch):
    """Seed 1006's grab handle in the 40-template bench library: the handle and its copy
    squeezed to 0.7 in y finish within 0.1% of each other when the fine stage stops at
    ``FINE_CONVERGED`` x the step thresholds, and the copy ranks first; finished again to the
    plain thresholds (the leaders within ``NEAR_TIE``), the handle does, 1% ahead. (Recorded
    with the first look on the coarse stage's samples: the 40-template library's screening on
    ``prefilter.samples`` finishes this click 2.0% apart, the copy first, outside the tie.)"""
    from affordance_registration.core.registration import registrar as registrar_module
    from affordance_registration.evaluation.bench import MIN_VISIBLE, variant_library

    big = variant_library(library.specific(), 40)
    assert "grab_handle@y0.7" in big
    sim = simulate_taskboard(library, 1006)
    obj = [o for o in sim.objects if o.visible_points >= MIN_VISIBLE][3]
    assert obj.template == "grab_handle"
    scene = Scene(sim.organized)
    fitter = Registrar(big, FitSettings().with_(**{"prefilter.samples": 0}))
    near_tie = registrar_module.NEAR_TIE
    assert near_tie > 1.001
    firsts = {}
    for tie in (near_tie, 1.0):
        monkeypatch.setattr(registrar_module, "NEAR_TIE", tie)
        cands = fitter.fit(scene, obj.click).candidates
        firsts[tie] = [c.template for c in cands[:2]]
        assert sorted(firsts[tie]) == ["grab_handle", "grab_handle@y0.7"]
        if tie == 1.0:  # stopped early, the two are a coin flip apart
            assert cands[1].residual <= 1.001 * cands[0].residual
    assert firsts[near_tie][0] == "grab_handle" and firsts[1.0][0] == "grab_handle@y0.7"


def test_the_held_out_variant_family_is_rigid_stretches_along_random_directions(library):
    """The bench's held-out library family: each variant is its template stretched or squeezed
    by 20-50% along one direction (volume by that factor, the other two directions kept), not
    along an axis of the template's frame; the same seed, the same family."""
    from affordance_registration.evaluation.bench_rows import stretched_library

    base = library.specific()
    big, again = stretched_library(base, 40), stretched_library(base, 40)
    assert len(big) == 40 and list(big) == list(again)
    for name in big:
        if "@" not in name:
            continue
        src = base[name.split("@")[0]].mesh_at(0.0, 1.0)
        mesh = big[name].mesh_at(0.0, 1.0)
        np.testing.assert_array_equal(mesh.vertices, again[name].mesh_at(0.0, 1.0).vertices)
        # the linear map taking the template's vertices to the variant's: I + (f - 1) u u^T
        M = np.linalg.lstsq(src.vertices, mesh.vertices, rcond=None)[0].T
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        assert np.allclose(M, M.T, atol=1e-9)
        stretch = w[np.argmax(np.abs(w - 1.0))]
        assert 0.2 - 1e-9 <= abs(stretch - 1.0) <= 0.5 + 1e-9
        assert np.sum(np.abs(w - 1.0) < 1e-9) == 2  # the other two directions kept
        u = V[:, np.argmax(np.abs(w - 1.0))]
        assert np.max(np.abs(u)) < 1.0 - 1e-3  # not along a frame axis


def test_the_bench_prints_the_held_out_family_row():
    """format_table names the held-out family's 40-template row with its ratio to the five."""
    from affordance_registration.evaluation.bench import format_table

    rows = [
        {
            "templates": n,
            "clicks": 40,
            "median_s": s,
            "ratio_to_first": r,
            "top1": t,
            "prefilter_decided": d,
            "prefilter_set_aside_per_click": a,
            "true_template_set_aside": 0,
        }
        for n, s, r, t, d, a in ((5, 0.3, 1.0, 1.0, 0.0, 0.0), (40, 0.6, 1.97, 0.925, 1.0, 33.6))
    ]
    table = format_table(
        {
            "rows": [],
            "refit": {"median_s": 0.01, "success": 1.0},
            "scenes": 1,
            "pose_tolerance": {"m": 0.005, "deg": 5.0},
            "machine": {"cpus": 2},
            "library_sizes_held_out_family": rows,
        }
    )
    line = next(x for x in table.splitlines() if x.startswith("held-out variant family"))
    assert "library of 40 templates" in line and "= 1.97x the five" in line, line
    assert "true template first 92.5%" in line and "library of 5 " not in table, table


def test_a_handle_clicked_near_one_end_of_its_bar_is_found(library, registrar):
    """An operator clicks a grab handle's bar near one end: the cluster points within the
    template's radius of the click are mostly that end's, so the yaw sweeps starting there are
    centimetres off; they also start over the clicked segment's middle. The grab handles of ten
    panels, each clicked near both ends of its bar (among the 10% of the bar's points farthest
    out on that side): at least 18 of the 20 within 5 mm / 5 deg (this code: 19; without the
    second start 13)."""
    from affordance_registration.core.transforms import invert

    ok = n = 0
    for seed in range(8000, 8010):
        sim = simulate_taskboard(library, seed)
        scene = Scene(sim.organized)
        pts = sim.organized.reshape(-1, 3)
        for j, obj in enumerate(sim.objects):
            if obj.template != "grab_handle" or obj.visible_points < 200:
                continue
            mine = pts[sim.labels.reshape(-1) == j + 1]
            T = invert(obj.T_scene_model)
            local = mine @ T[:3, :3].T + T[:3, 3]
            bar = local[:, 2] >= local[:, 2].min() + 0.33 * np.ptp(local[:, 2])
            for side in (1.0, -1.0):
                x = side * local[:, 0]
                on = np.flatnonzero(bar & (x > 0))
                click = mine[on[np.argsort(x[on])[int(0.9 * len(on))]]]
                best = registrar.fit(scene, click).candidates[0]
                dt, da = pose_error(
                    best.T_scene_model, obj.T_scene_model, library["grab_handle"].symmetry
                )
                n += 1
                ok += best.template == "grab_handle" and dt <= TOL_M and da <= TOL_RAD
    assert n == 20 and ok >= 18, (ok, n)
