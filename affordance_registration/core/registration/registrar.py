# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The registrar: every template fitted around a click, ranked -- the algorithm, composed of
the stages in this package.

The method of record (Hagenow et al.): correspondences from template samples to the nearest scene
points; a correspondence whose distance d exceeds the template diameter is rejected; the rest are
weighted w = 1/(1+d); the weighted rigid transform is solved in closed form (SVD); iterate.
Restarts start from random orientations and offsets around the click; a template's likelihood is
the inverse of its residual. ``method="paper"`` runs that literally (:mod:`.paper`).

The default method keeps the spirit and fixes what a literal implementation gets wrong on
one-sided scans (the README's benchmark measures both):

* the weight keeps the paper's form but scales the distance, w = 1/(1 + d/d0), d0 = 5 mm
  (``icp.weight_scale``) -- with d in metres the paper's weight is ~1 for every useful d;
* only template samples that face the sensor and are not hidden behind observed surfaces take part
  (a range image of the crop answers "hidden?" and "did the sensor see through here?");
* the residual is two-way and capped: template -> scene (free-space violations count as the cap)
  and scene cluster -> template, so neither a thin template lying flat nor a small template hiding
  inside a big object can win;
* all restarts of all templates advance together (one KD query per iteration, a batched weighted
  SVD), coarse to fine: 64 samples for every restart -> the best 3 per template at 256 -> rank ->
  the winner and the runners-up close to it at 1500 -> ranked again (near shapes, such as a
  template and a squeezed copy of it, can swap places at 256 samples);
* initial orientations come from the mounting plane under the click (template +z along its
  normal, a yaw sweep), from the template's stable resting facets on that plane (objects lying
  on a table) and from uniform random ones; the best mounted hypothesis always reaches the
  medium stage;
* the operator clicked *on* the object: candidates are centred on the cluster points near the
  click and pay for a surface that misses the click by more than ``scoring.click_tolerance``;
* directions in which the sensor returned nothing (outside the image, dropouts) are no evidence
  either way: samples there neither pull nor count;
* every scene frame is alike: visibility is reasoned from the sensor origin (a range image
  binned about the ray to the click) or left out for a cloud with no single viewpoint, and
  every random draw and grid is laid out in a frame attached to the scan around the click, so
  a rigidly moved scene gives the rigidly moved fit;
* each candidate gets an absolute verdict besides its rank (``coverage``, ``inlier_rmse``,
  ``fits``): when the best one does not fit, no template fits here;
* articulated templates (a joint with its moving part, or a scale range) among the leading
  candidates get their joint value and scale with the pose: a sweep across the joint's limits
  (the fixed part held, or moved back with the moving part left where the data put it), local
  steps, and a fine stage whose point-to-plane Gauss-Newton step has a column for the joint and
  one for the scale besides the six of the pose. A fit resting on the plane under the click keeps
  resting on it, and a joint value or scale the data cannot tell from a named state or scale 1 is
  reported there, so the extra unknowns cost no rigid accuracy (scale 1 judged with samples at
  grazing angles beyond ``articulation.scale_grazing_angle`` unseen: they count against the larger
  size).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from ..errors import RegistrationError
from ..plane import ransac_plane
from ..scene import ClickContext, Scene
from ..templates import TemplateLibrary
from ..voxels import voxel_downsample
from .ambiguity import Ambiguity, assess
from .articulation import articulate, prefer_nominal
from .hidden_parts import with_hidden_parts
from .hypotheses import (
    Hypotheses,
    best_per_template,
    initial_hypotheses,
    keep_distinct,
    prefilter,
    yaw_sweep_starts,
)
from .icp import fine_stage, icp
from .model import Batch, Model, ModelCache
from .paper import PaperMethod
from .parallel import run, single_threaded_blas
from .primitives import (
    REFINE_SHARE,
    fit_primitive,
    object_points,
    past_crop,
    refine_primitive,
    stacked,
    truncated,
)
from .refit import refit
from .results import FitReport, FitResult, rank
from .scoring import distinguished, explained_share, judge, result, results, scores
from .settings import NEAR_TIE, REST_SAMPLES, SAMPLE_SEED, FitSettings
from .viewpoint import suggest_view

__all__ = ["Registrar"]

BACKWARD_SUBSAMPLE = 64  #: cluster points in the coarse stage's cluster -> template half
#: the click contexts whose primitive fits are kept for their refits' verdicts
PRIMITIVES_KEPT = 8
OCCLUDER_VOXEL = 0.01  #: m: the scan beyond the crop hides a suggested view at this grain
#: a click without a support plane in its crop: the wider scan's dominant plane (holding at least
#: this share of it) is the surface a suggested view stays in front of
SUPPORT_FRACTION = 0.2

#: a primitive's object running past the crop (:func:`.primitives.truncated`) is measured again
#: in a crop this many times as large
WIDER = 2.0
#: :meth:`Registrar._worth` judges a leader's explained share on an even subsample of this many
#: cluster points (its margins are wide: a few points' noise does not matter)
WORTH_POINTS = 400


class Registrar:
    """Fits a template library to clicks in scenes. Thread-safe for concurrent ``fit`` and
    ``refit`` calls (the per-template caches are filled under locks)."""

    def __init__(self, library: TemplateLibrary, settings: FitSettings | None = None):
        if library is None or len(library) == 0:
            raise RegistrationError("the template library is empty: nothing to fit")
        self.library = library
        self.settings = (settings or FitSettings()).validate()
        self.models = ModelCache()
        self.paper = PaperMethod(library, self.settings)
        # the primitives fitted to the last few clicks (a refit's verdict asks what the
        # click's asked): id(context) -> (context, fitted)
        self._primitives_seen: OrderedDict = OrderedDict()
        self._primitives_lock = threading.Lock()

    # ------------------------------------------------------------------ public API
    def warm_up(self) -> None:
        """Compute every template's samples, diameter, resting poses and dense surface now
        (they are cached), so the first click costs what every later one does."""
        s = self.settings
        for tpl in self.library.values():
            for n in {
                s.coarse.samples,
                s.medium.samples,
                s.fine.samples,
                s.scoring.samples,
                s.refit.samples,
                REST_SAMPLES,
            }:
                tpl.samples(n, seed=SAMPLE_SEED)
            tpl.centroid, tpl.diameter
            tpl.resting_rotations(s.hypotheses.resting_poses)
            self.models.surface(tpl)

    def prepare(self, scene: Scene, click, radius: float | None = None) -> ClickContext:
        """Snap the click to the surface and prepare the crop around it (``radius``, m: by
        default the library's, ``crop.factor`` times its largest template). Only the part of
        the scene that can be in the crop is read (one pass over the cloud): the points within
        the crop radius plus the snap distance of the click hold the snapped point and its
        crop."""
        s = self.settings
        radius = s.crop.factor * self.library.max_diameter if radius is None else radius
        with single_threaded_blas():
            part = scene.around(click, radius + s.crop.snap_distance)
            snapped = (scene if part is None else part).snap(
                click, s.crop.snap_distance
            )  # None: why
            return part.prepare_click(
                snapped,
                radius=radius,
                voxel=s.crop.voxel,
                seed=s.seed,
                threads=s.threads,
                fine_points=s.fine.points,
            )

    def fit(self, scene: Scene, click, templates=None) -> FitReport:
        """Fit every template (or the named ones) around ``click`` (3,) in ``scene``.

        Returns the candidates ranked best first, one per template."""
        t0 = time.perf_counter()
        with single_threaded_blas():
            ctx = self.prepare(scene, click)
            t1 = time.perf_counter()
            names = list(self.library) if templates is None else list(templates)
            if not names:
                raise RegistrationError("no templates to fit")
            specific = [n for n in names if self.library[n].primitive is None]
            primitives = [n for n in names if self.library[n].primitive is not None]
            alternatives = ()
            if self.settings.method == "paper":
                candidates = self.paper.fit(ctx, specific) if specific else ()
            else:
                candidates, alternatives = (
                    self._fit_default(ctx, specific) if specific else ((), ())
                )
            t_prim = time.perf_counter()
            if primitives:
                # (a specific template that fits ranks above them: they are not refined)
                refine = not any(r.fits for r in candidates)
                fitted = self._fit_primitives(ctx, primitives, scene, refine)
                if not refine:
                    # ... when the scan shows what sets it apart from the primitive
                    candidates = self._distinguished(ctx, candidates, fitted)
                    if not any(r.fits for r in candidates):
                        fitted = self._fit_primitives(ctx, primitives, scene, True)
                self._remember_primitives(ctx, fitted)
                candidates = rank(list(candidates) + fitted)
            t2 = time.perf_counter()
            ambiguity = self.assess(ctx, candidates, alternatives)
        t3 = time.perf_counter()
        timing = {"prepare": t1 - t0, "fit": t2 - t1, "total": t2 - t0, "ambiguity": t3 - t2}
        if primitives:
            timing["primitives"] = t2 - t_prim
        return FitReport(
            point=ctx.click,
            candidates=candidates,
            timing_s=timing,
            context=ctx,
            alternatives=alternatives,
            ambiguity=ambiguity,
        )

    def assess(self, ctx: ClickContext, candidates, alternatives=()) -> Ambiguity:
        """Whether the ranked ``candidates`` of a click settle it (:func:`.ambiguity.assess`;
        nothing about them changes)."""
        s, model_of = self.settings, self._model_of

        def refine(r: FitResult) -> FitResult:  # a second pose, finished as a leader is
            fit = fine_stage(
                ctx, model_of(r), r.T_scene_model[:3, :3], r.T_scene_model[:3, 3], s.stages.fine, s
            )
            return result(ctx, fit.models[0], fit.R[0], fit.t[0], s)

        with single_threaded_blas():
            return assess(ctx, candidates, alternatives, model_of, s, refine)

    def suggest_view(
        self,
        report: FitReport,
        T_scene_optical: np.ndarray | None = None,
        scene: Scene | None = None,
    ):
        """Where the sensor should look from to settle an unsettled click
        (:func:`.viewpoint.suggest_view`), or None when it is settled or the scan has no
        viewpoint. ``T_scene_optical``: the sensor's current pose (its roll is kept);
        ``scene``: the whole scan, whose points within ``viewpoint.max_distance`` of the click
        (``OCCLUDER_VOXEL`` apart) may hide the object too (else only the crop's)."""
        amb = report.ambiguity or self.assess(
            report.context, report.candidates, report.alternatives
        )
        if amb.settled:
            return None
        ctx = report.context
        with single_threaded_blas():
            occluders, support = None, ctx.support
            if scene is not None:
                near = scene.around(report.point, self.settings.viewpoint.max_distance)
                occluders = (
                    None
                    if near is None
                    else voxel_downsample(  # a grid on the scan
                        near.points, OCCLUDER_VOXEL, report.point, ctx.frame
                    )
                )
                if support is None and occluders is not None:  # the wider scan's own plane
                    support = ransac_plane(
                        occluders,
                        OCCLUDER_VOXEL,
                        SUPPORT_FRACTION,
                        ctx.sensor_origin,
                        self.settings.seed,
                    )
            return suggest_view(ctx, amb, self.settings, T_scene_optical, occluders, support)

    def refit(
        self,
        ctx: ClickContext,
        template: str,
        T_init: np.ndarray,
        joints: dict | None = None,
        scale: float = 1.0,
        hold_joint: bool | None = None,
        dimensions: dict | None = None,
        scene: Scene | None = None,
    ) -> FitResult:
        """Refine ``template`` locally from ``T_init`` (an operator's correction): a few small
        perturbations, medium then fine ICP. The result never strays farther than
        ``refit.max_move`` / ``refit.max_turn`` from ``T_init``: a refit that would jump back to a
        pose the operator moved away from keeps the closest acceptable pose instead.

        An articulated template starts from ``joints`` (name -> value) and ``scale`` (with
        ``settings.articulated``). ``hold_joint`` keeps the joint value as given and refines the
        pose and scale only; by default (None) a joint value that is given is kept -- estimated
        once with the click, then changed by the operator's joint corrections, not by refits of
        the pose -- and one that is not given is estimated. A primitive keeps ``dimensions``
        as given (the operator's or the click's); without them they are measured again.
        ``scene``: the scan ``ctx`` was cut from -- the verdict asks what the click's asked
        (a primitive's object running past the crop is measured in a wider one from it)."""
        t0 = time.perf_counter()
        if self.library[template].primitive is not None:
            ctx = ctx.with_insides()
            with single_threaded_blas():
                wide, measured, past = self._measured(ctx, scene)
                res = self._judged(
                    ctx,
                    [
                        fit_primitive(
                            ctx,
                            self.library[template],
                            self.models,
                            self.settings,
                            dimensions,
                            T_init,
                            measured if wide is ctx else None,
                        )
                    ],
                )[0]
                cut = stacked(ctx, measured) if wide is ctx and not res.fits else None
                if cut is not None:  # on a stack: as at the click (_fit_primitives)
                    alt = self._judged(
                        cut[0],
                        [
                            fit_primitive(
                                cut[0],
                                self.library[template],
                                self.models,
                                self.settings,
                                dimensions,
                                T_init,
                                cut[1],
                            )
                        ],
                    )[0]
                    res = alt if alt.fits else res
                res = past_crop(wide, past, [res])[0]
            return replace(res, time_s=time.perf_counter() - t0)
        model = self._model(template, joints, scale)
        with single_threaded_blas():
            res = refit(
                ctx,
                model,
                T_init,
                self.settings,
                hold_joint=bool(joints) if hold_joint is None else hold_joint,
            )
            res = self._judged(ctx, [res])[0]
            if res.fits:  # as at the click: it must show more than a primitive does
                res = self._distinguished(ctx, [res], self._primitives_for(ctx, scene))[0]
        return replace(res, time_s=time.perf_counter() - t0)

    def _primitives_for(self, ctx: ClickContext, scene: Scene | None = None) -> list:
        """The library's primitives fitted to ``ctx``'s click: those its fit found (kept for
        the last ``PRIMITIVES_KEPT`` click contexts), else measured now (and kept)."""
        names = [n for n in self.library if self.library[n].primitive is not None]
        if not names or ctx.sensor_origin is None:
            return []
        with self._primitives_lock:
            hit = self._primitives_seen.get(id(ctx))
        if hit is not None and hit[0] is ctx:
            return hit[1]
        fitted = self._fit_primitives(ctx, names, scene, refine=False)
        self._remember_primitives(ctx, fitted)
        return fitted

    def _remember_primitives(self, ctx: ClickContext, fitted: list) -> None:
        with self._primitives_lock:
            self._primitives_seen[id(ctx)] = (ctx, list(fitted))
            self._primitives_seen.move_to_end(id(ctx))
            while len(self._primitives_seen) > PRIMITIVES_KEPT:
                self._primitives_seen.popitem(last=False)

    # ------------------------------------------------------------------ the default method
    def _fit_default(self, ctx: ClickContext, names: list[str]) -> tuple:
        """The default method, stage by stage: (the ranked candidates, every medium-stage
        hypothesis's result)."""
        s = self.settings
        t0 = time.perf_counter()
        rng = np.random.default_rng(s.seed)
        # 1. initial hypotheses for every template: plane prior (yaw sweep), resting poses,
        #    uniform random; a template that comes in sizes also at the ends of its range
        variants, template_of = self._variants(names)
        hyps = initial_hypotheses(ctx, variants, s, rng).relabelled(template_of)
        # 2. coarse ICP, all restarts of all templates together; a library larger than the
        #    prefilter keeps: the templates clearly worse than the leaders after the first
        #    coarse iterations leave there, and those clearly worse after the coarse stage (3.)
        #    (and each template's restarts beyond its best ``coarse.keep`` leave there too)
        split = s.prefilter.iterations if 0 < s.prefilter.keep < len(names) or s.coarse.keep else 0
        set_aside = ()
        if 0 < split < s.coarse.iterations:
            # (a library of more than twice what the prefilter keeps takes its first look on
            #  prefilter.samples template samples and as many cluster points)
            screen = s.prefilter.samples if 0 < 2 * s.prefilter.keep < len(names) else 0
            look = replace(s.stages.coarse, samples=screen) if screen else s.stages.coarse
            hyps = hyps.after(icp(ctx, hyps, look, s, span=(0, split)))
            score = scores(
                ctx,
                hyps,
                s,
                look.samples,
                min(screen, BACKWARD_SUBSAMPLE) if screen else BACKWARD_SUBSAMPLE,
            )
            hyps, score, set_aside = prefilter(hyps, score, names, s)
            hyps = hyps.take(best_per_template(hyps, score, s.coarse.keep))
            hyps = hyps.after(
                icp(ctx, hyps, s.stages.coarse, s, span=(split, s.coarse.iterations))
            )
        else:
            hyps = hyps.after(icp(ctx, hyps, s.stages.coarse, s))
        score = scores(ctx, hyps, s, s.coarse.samples, BACKWARD_SUBSAMPLE)
        # (and again on the whole coarse stage's evidence: the medium stage is the dearer one)
        hyps, score, late = prefilter(hyps, score, names, s)
        set_aside += late
        # 4. the best distinct few per template, refined at medium resolution
        hyps = hyps.take(keep_distinct(hyps, score, len(names), s.coarse.keep_per_template))
        hyps = hyps.after(icp(ctx, hyps, s.stages.medium, s))
        # 5. rank: the best hypothesis per template by the two-way residual (the prefilter's
        #    behind)
        best, every = self._best_per_template(ctx, hyps)
        ranked = rank(best + set_aside)
        # 6. articulated templates among the leaders: joint value and scale with the pose
        ranked, models = self._articulate_leaders(ctx, ranked, hyps.iterations)
        # 7. the leaders -- the winner and the runners-up close to it: each a sweep about its
        #    mounting axis (near-symmetric handles), then alone at full resolution, then
        #    (articulated) towards a named state and scale 1; ranked again on those residuals
        ranked = self._finish_leaders(ctx, ranked, models, hyps.iterations)
        # 8. the absolute verdict on every fitted candidate: coverage, inlier RMSE, fits or
        #    not (those the prefilter set aside have coarse poses: not judged, ``fits`` None,
        #    until a refit fits them -- the engine's when one is first shown)
        fitted = [r for r in ranked if not r.prefiltered]
        judged = self._judged(ctx, fitted) + [r for r in ranked if r.prefiltered]
        total = time.perf_counter() - t0
        return rank([replace(r, time_s=total) for r in judged]), tuple(every)

    def _model_of(self, r: FitResult) -> Model:
        return self._model(r.template, r.joints, r.scale, r.dimensions)

    def model_of(self, result: FitResult) -> Model:
        """The model ``result`` was fitted as: its template at its joint values, scale and
        size."""
        return self._model_of(result)

    def _judged(self, ctx: ClickContext, results) -> list:
        """Each result with its verdict (:func:`.scoring.judge`)."""
        results = list(results)
        return judge(ctx, [self._model_of(r) for r in results], results, self.settings)

    def _distinguished(self, ctx: ClickContext, candidates, primitives) -> list:
        """``candidates`` with the fitting specific ones tested against the best fitting of
        ``primitives`` (:func:`.scoring.distinguished`); unchanged when none of those fits."""
        fitting = [r for r in primitives if r.fits]
        if not fitting:
            return list(candidates)
        best = max(fitting, key=lambda r: r.likelihood)
        tested = [r for r in candidates if r.fits and r.primitive is None]
        done = dict(
            zip(
                map(id, tested),
                distinguished(
                    ctx,
                    [self._model_of(r) for r in tested],
                    tested,
                    self._model_of(best),
                    best,
                    self.settings,
                ),
            )
        )
        return [done.get(id(r), r) for r in candidates]

    def _fit_primitives(
        self, ctx: ClickContext, names: list[str], scene: Scene | None = None, refine: bool = True
    ) -> list:
        """The primitive templates ``names``, measured and refined (:mod:`.primitives`),
        judged; with ``refine``, those that may lead refined
        (:func:`.primitives.refine_primitive`). An object that runs past the crop is measured again
        in a crop WIDER times as large (from ``scene``): a box longer than the library's templates
        is still a box; a wall runs past that one too, and is refused. With ``refine`` (no specific
        template fits), where none fits or a box does, boxes stacked that the segments took for one
        object (:func:`.primitives.stacked`) are measured and judged on the clicked one."""
        t0 = time.perf_counter()
        ctx, measured, past = self._measured(ctx.with_insides(), scene)  # once for them all
        judged = self._primitives_on(ctx, scene, names, measured, refine)
        lead = max(judged, key=lambda r: (bool(r.fits), r.likelihood))  # (a box has one top)
        cut = (
            stacked(ctx, measured)
            if refine and (not lead.fits or lead.primitive == "box")
            else None
        )
        if cut is not None:
            on_part = self._primitives_on(cut[0], scene, names, cut[1], refine)
            judged = on_part if any(r.fits for r in on_part) else judged
        total = time.perf_counter() - t0
        return past_crop(ctx, past, [replace(r, time_s=total) for r in judged])

    def _primitives_on(self, ctx: ClickContext, scene, names, measured, refine: bool) -> list:
        """The primitives ``names`` measured on ``measured`` (:func:`.primitives.object_points`'
        tuple) and on it with the pieces something in front splits off
        (:func:`.hidden_parts.with_hidden_parts`), those that may lead refined with ``refine``,
        judged in ``ctx``."""

        def fit_on(points, k):
            return fit_primitive(
                ctx,
                self.library[names[k]],
                self.models,
                self.settings,
                measured=points,
                refine=False,
            )

        fitted = with_hidden_parts(
            ctx,
            scene,
            measured,
            [fit_on(measured, k) for k in range(len(names))],
            fit_on,
            self._model_of,
            self.settings,
        )
        # (refining costs an ICP: only the primitives that may lead are refined)
        lead = max(r.likelihood for r in fitted)
        return self._judged(
            ctx,
            [
                refine_primitive(ctx, self.library[n], self.models, self.settings, r)
                if refine and r.likelihood >= REFINE_SHARE * lead
                else r
                for n, r in zip(names, fitted)
            ],
        )

    def _measured(self, ctx: ClickContext, scene: Scene | None) -> tuple:
        """(the context, the clicked object's points in it, whether they run past its crop).
        Where they run past ``ctx``'s, they are measured again in a crop WIDER times as large
        from ``scene``, kept where they run past ``ctx``'s crop there too; else ``ctx`` held
        all of it (the wider crop's coarser segments split it: a box another stands on)."""
        measured = object_points(ctx)
        past = truncated(ctx, measured)
        if not past or scene is None:
            return ctx, measured, past
        wide = self.prepare(scene, ctx.click, WIDER * ctx.radius).with_insides()
        again = object_points(wide)
        return (
            (wide, again, truncated(wide, again))
            if truncated(ctx, again)
            else (ctx, measured, False)
        )

    def _variants(self, names: list[str]):
        """The models the hypotheses start from -- every template rigid, and with
        ``settings.articulated`` a template that comes in sizes also at both ends of its range
        -- and the index into ``names`` of each."""
        tpls = [self.library[n] for n in names]
        variants = [(i, self.models.model(tpl)) for i, tpl in enumerate(tpls)]
        if self.settings.articulated:
            variants += [
                (i, self.models.model(tpl, 0.0, g, articulated=True))
                for i, tpl in enumerate(tpls)
                if tpl.scale_range is not None
                for g in tpl.scale_range
                if g != 1.0
            ]
        return [m for _, m in variants], np.array([i for i, _ in variants])

    def _best_per_template(self, ctx: ClickContext, hyps: Hypotheses) -> tuple:
        """Each template's best hypothesis by the residual, ranked, and every hypothesis's
        result (the ambiguity's second poses)."""
        best: dict[int, FitResult] = {}
        every = results(ctx, hyps, self.settings, hyps.iterations, hyps.converged)
        for i, res in zip(hyps.index.tolist(), every):
            if i not in best or res.likelihood > best[i].likelihood:
                best[i] = res
        return rank(best.values()), every

    def _articulate_leaders(self, ctx: ClickContext, ranked: tuple, iterations: int):
        """Joint values and scale of the articulated templates among the leading candidates
        (at most ``articulation.candidates``, residual within ``articulation.margin`` of the
        best): a rigid fit of a valve with its handle turned can rank behind a wrong template.
        Returns (ranked again, {template: its articulated model})."""
        s = self.settings
        models: dict[str, Model] = {}
        if not s.articulated:
            return ranked, models

        def estimate(r: FitResult):
            tpl = self.library[r.template]
            start = self.models.model(tpl, tpl.joint_value(r.joints), r.scale, articulated=True)
            model, R, t, converged = articulate(
                ctx, start, r.T_scene_model[:3, :3], r.T_scene_model[:3, 3], s
            )
            return model, result(ctx, model, R, t, s, iterations, converged)

        # the best first (the others' margin is to its estimate), then the others side by side
        # (and none for a leader that cannot come to fit)
        leaders = [
            r for r in ranked[: s.articulation.candidates] if self.library[r.template].articulated
        ]
        for first in (True, False):
            todo = self._worth(
                ctx,
                [
                    r
                    for r in leaders
                    if (r.template == ranked[0].template) == first
                    and r.residual <= s.articulation.margin * ranked[0].residual
                ],
                {},
                s.articulation.explained_margin,
            )[0]
            for r, (model, res) in zip(
                todo, run([lambda r=r: estimate(r) for r in todo], s.threads)
            ):
                models[r.template] = model
                ranked = tuple(res if x.template == r.template else x for x in ranked)
        return rank(ranked), models

    def _finish_leaders(
        self, ctx: ClickContext, ranked: tuple, models: dict, iterations: int
    ) -> tuple:
        """The leading candidates finished (:meth:`_finish`) side by side and ranked
        again: the best and those of the next ``finish_candidates - 1`` fitted on (not set
        aside by the prefilter) whose residual is within ``finish.margin`` of the best's. Two
        near shapes (a template and a squeezed copy of it) can swap places at medium
        resolution; the fine stage tells them apart (and where they finish within
        ``NEAR_TIE`` of each other, fine stages run to the plain step thresholds do). A
        finished residual is never above the one it started from, and every candidate left
        out ranked behind those finished, so the ranking stays consistent. A leader that
        cannot come to fit (:meth:`_worth`) keeps its medium-resolution result."""
        s = self.settings
        n = 1
        while (
            n < min(s.finish.candidates, len(ranked))
            and not ranked[n].prefiltered
            and ranked[n].residual <= s.finish.margin * ranked[0].residual
        ):
            n += 1
        leaders, hopeless = self._worth(ctx, ranked[:n], models, s.finish.explained_margin)
        if not leaders:
            return rank(hopeless + list(ranked[n:]))

        def lead(win):
            swept = self._before_fine(ctx, win, models)
            return swept, self._finish(ctx, win, swept, iterations)

        swept, done = map(list, zip(*run([lambda r=r: lead(r) for r in leaders], s.threads)))
        # a near tie -- a template and a squeezed copy of it can finish within 0.1% of each
        # other -- is decided on fine stages run to the plain step thresholds (not
        # FINE_CONVERGED x them)
        best = min(r.residual for r in done)
        tied = [k for k in range(len(done)) if done[k].residual <= NEAR_TIE * best]
        if len(tied) > 1:
            again = run(
                [
                    lambda k=k: self._finish(ctx, leaders[k], swept[k], iterations, 1.0)
                    for k in tied
                ],
                s.threads,
            )
            for k, r in zip(tied, again):
                done[k] = r
        return rank(list(done) + hopeless + list(ranked[n:]))

    def _worth(self, ctx: ClickContext, leaders, models: dict, margin: float) -> tuple:
        """(the ``leaders`` to work on, those left as they are): a leader that explains less
        than ``verdict.min_explained - margin`` of the clicked object's points
        (:func:`.scoring.explained_share`) cannot come to fit -- a valve in a box's points --
        and is not worked on. Without a viewpoint (no such share) every leader is."""
        s = self.settings
        leaders = list(leaders)
        floor = s.verdict.min_explained - margin
        if ctx.sensor_origin is None or floor <= 0.0:
            return leaders, []
        share = explained_share(
            ctx,
            [
                models.get(r.template) or self._model(r.template, r.joints, r.scale)
                for r in leaders
            ],
            leaders,
            s,
            WORTH_POINTS,
        )
        return (
            [r for r, e in zip(leaders, share) if e >= floor],
            [r for r, e in zip(leaders, share) if e < floor],
        )

    def _before_fine(self, ctx: ClickContext, win: FitResult, models: dict) -> tuple:
        """A leader's yaw sweep (and, articulated, its joint once more after it):
        (model, R, t) for its fine stage."""
        s = self.settings
        model = models.get(win.template)
        if model is None:
            model = self.models.model(self.library[win.template])
        model, R, t = self._yaw_sweep(
            ctx, model, win.T_scene_model[:3, :3], win.T_scene_model[:3, 3]
        )
        if model.articulated:  # the joint after the sweep, once more
            model, R, t, _ = articulate(
                ctx, model, R, t, s, sweep=False, rounds=s.articulation.finish_rounds
            )
        return model, R, t

    def _finish(
        self,
        ctx: ClickContext,
        win: FitResult,
        swept: tuple,
        iterations: int,
        converge: float | None = None,
    ) -> FitResult:
        """A leader's fine stage from ``swept`` (:meth:`_before_fine`; joint and scale once
        more, articulated) and Occam's razor for its joint value and scale (``converge``: as
        :func:`.icp.icp`'s); never worse than ``win``."""
        s = self.settings
        model, R, t = swept
        fit = fine_stage(ctx, model, R, t, s.stages.fine, s, converge=converge)
        final = result(
            ctx,
            fit.models[0],
            fit.R[0],
            fit.t[0],
            s,
            iterations + fit.iterations,
            fit.converged[0],
        )
        if final.likelihood < win.likelihood:
            final = win
        if model.articulated:
            final = prefer_nominal(
                ctx,
                self._model(final.template, final.joints, final.scale),
                final,
                s,
                iterations,
                converge,
            )
        return final

    def _yaw_sweep(self, ctx: ClickContext, model: Model, R, t):
        """The pose turned about its template's mounting / symmetry axis in ``finish.yaw_sweep``
        steps over one symmetry period, each refined; the best by the residual. An articulated
        model is also swept at its template's named states (a valve body turned a quarter with
        its handle turned back matches the handle alone, and the joint is held in the sweep).
        (model, R, t)"""
        s = self.settings
        if s.finish.yaw_sweep <= 1:
            return model, R, t
        variants = [model]
        if model.articulated:
            tpl = model.template
            variants += [
                model.with_values(q=q)
                for q in sorted({float(tpl.joint_value(v)) for v in tpl.states.values()})
                if q != model.q
            ]
        starts = [yaw_sweep_starts(m, R, t, s.finish.yaw_sweep) for m in variants]
        models = [m for m in variants for _ in range(s.finish.yaw_sweep)]
        swept = icp(
            ctx,
            Batch.of(
                models,
                np.concatenate([a for a, _ in starts]),
                np.concatenate([b for _, b in starts]),
            ),
            s.stages.short,
            s,
        )
        swept = Batch(swept.models, swept.R, swept.t)
        # ranked on the medium residual; the best few again on the full one
        keep = np.arange(len(swept))
        if 0 < s.finish.yaw_sweep_keep < len(swept):
            cheap = scores(ctx, swept, s, s.medium.samples, s.medium.samples)
            keep = np.sort(np.argsort(cheap, kind="stable")[: s.finish.yaw_sweep_keep])
        residuals = [r.residual for r in results(ctx, swept.take(keep), s)]
        best = int(keep[int(np.argmin(residuals))])
        return models[best], swept.R[best], swept.t[best]

    def _model(
        self,
        template: str,
        joints: dict | None = None,
        scale: float = 1.0,
        dimensions: dict | None = None,
    ) -> Model:
        """The model to fit: with ``settings.articulated``, an articulated template posed at
        ``joints`` (clipped to its limits) and ``scale`` (clipped to its range); else rigid.
        A primitive at ``dimensions`` (clipped to its ranges)."""
        base = self.library[template]
        if base.primitive is not None:
            return self.models.model(base.sized(dimensions or base.dimensions))
        if not (self.settings.articulated and base.articulated):
            return self.models.model(base)
        j = base.joint
        q = float(np.clip(base.joint_value(joints or {}), j.lower, j.upper)) if j else 0.0
        lo_hi = base.scale_range
        scale = float(np.clip(scale, *lo_hi)) if lo_hi is not None else 1.0
        return self.models.model(base, q, scale, articulated=True)
