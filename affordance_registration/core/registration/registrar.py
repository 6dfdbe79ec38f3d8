# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The registrar: every template fitted around a click, ranked -- the recipe (the stages of
:mod:`.stages` in order, :func:`fit_click` and :func:`default`) and the public API that runs it
(:class:`Registrar`).

The method of record (Hagenow et al.): correspondences from template samples to the nearest scene
points; a correspondence whose distance d exceeds the template diameter is rejected; the rest are
weighted w = 1/(1+d); the weighted rigid transform is solved in closed form (SVD); iterate.
Restarts start from random orientations and offsets around the click; a template's likelihood is
the inverse of its residual. ``method="paper"`` runs that literally (:mod:`.stages.paper`).

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

import time
from dataclasses import replace

import numpy as np

from ..errors import RegistrationError
from ..plane import ransac_plane
from ..scene import ClickContext, Scene
from ..templates import TemplateLibrary
from ..voxels import voxel_downsample
from .ambiguity import Ambiguity
from .model import Model
from .parallel import single_threaded_blas
from .results import FitReport, FitResult
from .services import Services
from .settings import NEAR_TIE, REST_SAMPLES, SAMPLE_SEED, FitSettings
from .stages import (
    articulate,
    assess,
    coarse,
    finish,
    hypothesise,
    judge,
    medium,
    paper,
    prefilter,
    prepare,
    primitives,
    rank,
)
from .stages import refit as refitting
from .state import FitState
from .viewpoint import suggest_view

__all__ = ["Registrar", "fit_click", "default", "METHODS"]

OCCLUDER_VOXEL = 0.01  #: m: the scan beyond the crop hides a suggested view at this grain
#: a click without a support plane in its crop: the wider scan's dominant plane (holding at least
#: this share of it) is the surface a suggested view stays in front of
SUPPORT_FRACTION = 0.2


# ---------------------------------------------------------------------- the recipe
def fit_click(state: FitState) -> FitState:
    """One click, stage by stage: the crop, the templates fitted by the settings' method, the
    primitives measured, the answer assessed."""
    state = prepare.run(state)  # the click snapped, the crop: plane, cluster, segments
    state = METHODS[state.settings.method](state)  # every template fitted, ranked, judged
    state = primitives.run(state)  # boxes and cylinders measured, ranked with them
    return assess.run(state)  # settled, or the rivals a view should tell apart


def default(state: FitState) -> FitState:
    """The default method (the module docstring says why each stage is there)."""
    if not state.specific:  # (primitives alone are measured, not fitted)
        return state
    state = hypothesise.run(state)  # plane prior, facets, random; sizes and slides at both ends
    if coarse.pause(state):  # every restart on few samples, with the prefilter's first look:
        state = coarse.first_look(state)  # the first prefilter.iterations iterations
        state = prefilter.run(state)  # the templates clearly worse than the leaders leave
        state = coarse.rest(state)  # each template's best coarse.keep restarts go on
    else:
        state = coarse.run(state)
    state = prefilter.run(state)  # again, on the whole coarse stage's evidence
    state = medium.run(state)  # the best distinct few per template at medium resolution
    state = rank.run(state)  # each template's best hypothesis by the two-way residual
    state = articulate.run(state)  # joint value and scale of the articulated leaders
    state = finish.run(state, NEAR_TIE)  # the leaders: yaw sweep, fine stage; ranked again
    return judge.run(state)  # the absolute verdict on every fitted candidate


#: the methods ``FitSettings.method`` names: the default one, and the paper's literally
METHODS = {"default": default, "paper": paper.run}


# ---------------------------------------------------------------------- the public API
class Registrar:
    """Fits a template library to clicks in scenes. Thread-safe for concurrent ``fit`` and
    ``refit`` calls (the per-template caches are filled under locks)."""

    def __init__(self, library: TemplateLibrary, settings: FitSettings | None = None):
        if library is None or len(library) == 0:
            raise RegistrationError("the template library is empty: nothing to fit")
        self.services = Services(library, (settings or FitSettings()).validate())

    @property
    def library(self) -> TemplateLibrary:
        return self.services.library

    @property
    def settings(self) -> FitSettings:
        return self.services.settings

    @property
    def models(self):
        """The :class:`~.model.ModelCache` every fit of this registrar shares."""
        return self.services.models

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
        """Snap the click to the surface and prepare the crop around it
        (:func:`.stages.prepare.click_context`; ``radius``, m: by default the library's,
        ``crop.factor`` times its largest template)."""
        return prepare.click_context(self.services, scene, click, radius)

    def fit(self, scene: Scene, click, templates=None) -> FitReport:
        """Fit every template (or the named ones) around ``click`` (3,) in ``scene``
        (:func:`fit_click`, the recipe). Returns the candidates ranked best first, one per
        template."""
        names = list(self.library) if templates is None else list(templates)
        if not names:
            raise RegistrationError("no templates to fit")
        with single_threaded_blas():
            state = fit_click(FitState.start(self.services, scene, click, names))
        return state.report()

    def assess(self, ctx: ClickContext, candidates, alternatives=()) -> Ambiguity:
        """Whether the ranked ``candidates`` of a click settle it
        (:func:`.stages.assess.ambiguity_of`; nothing about them changes)."""
        return assess.ambiguity_of(self.services, ctx, candidates, alternatives)

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
        res = refitting.run(
            self.services, ctx, template, T_init, joints, scale, hold_joint, dimensions, scene
        )
        return replace(res, time_s=time.perf_counter() - t0)

    # (the tests ask for these by their old names)
    def _model(
        self,
        template: str,
        joints: dict | None = None,
        scale: float = 1.0,
        dimensions: dict | None = None,
    ) -> Model:
        """:meth:`.services.Services.model`."""
        return self.services.model(template, joints, scale, dimensions)

    def _variants(self, names: list[str]):
        """:func:`.stages.hypothesise.variants`."""
        return hypothesise.variants(self.services, names)
