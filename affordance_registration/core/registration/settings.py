"""Fitting parameters (:class:`FitSettings`, the public knobs) and the named constants of the
stages: how many samples and iterations each ICP stage runs and how far its correspondences may
reach (:class:`Stage`), the seeds, the de-duplication and convergence thresholds.

Lengths are metres, angles radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import RegistrationError

__all__ = ["FitSettings", "Stage", "CLUSTER", "FINE"]

# --------------------------------------------------------------------------- samples and seeds
SAMPLE_SEED = 1            #: template samples every stage fits and scores with
DENSE_SAMPLES = 4096       #: dense surface samples answering "nearest template surface"
DENSE_SEED = 2
REST_SAMPLES = 256         #: samples that find a pose's lowest point (resting on the plane)
CENTROID_SAMPLES = 2048    #: samples whose mean is a posed template's centroid
CENTROID_SEED = 0          #: (those of ``AffordanceTemplate.centroid``)
MOVING_OVERSAMPLING = 4    #: a moving part alone is picked from this many times the samples
REFIT_SEED_OFFSET = 7919   #: the refit's restarts draw from ``seed + REFIT_SEED_OFFSET``

# --------------------------------------------------------------------------- ICP stages
CLUSTER, FINE = "cluster", "fine"   #: ICP targets: the voxelized cluster, its full resolution
COARSE_REJECT = 0.5        #: rejection radius at a stage's start, fraction of the diameter
MEDIUM_REJECT = 0.25
SWEEP_REJECT = 0.15        #: the joint / scale sweep's hypotheses
FINE_REJECT = 0.1
SHORT_ICP = 6              #: ICP iterations of the leaders' yaw sweep and a refit's restarts
LOCAL_ICP = 4              #: ICP iterations after each local joint / scale step
CONVERGED_ROTATION = 2e-4      #: rad: an ICP step turning less than this ...
CONVERGED_TRANSLATION = 5e-5   #: m: ... and moving less than this has converged
CONVERGED_EXTRA = 1e-4         #: rad, m or scale: ... and so have joint and scale steps this small
#: the fine stage (and a refit's) has converged at this many times those steps: 0.03 deg and
#: 0.15 mm a step are far below the pose tolerance, and its iterations are the dearest (it
#: stops within 0.2 deg of the fully converged pose, a handwheel turned about its axis)
FINE_CONVERGED = 3.0
#: finished leaders within this factor of the best one's residual are finished again with the
#: plain step thresholds before the final ranking (a near tie is decided on fully converged
#: fits)
NEAR_TIE = 1.02

# --------------------------------------------------------------------------- hypotheses
RANDOM_OFFSET = 0.15       #: random restarts start up to this fraction of the diameter off
DISTINCT_DISTANCE = 0.01   #: hypotheses of one template closer than this ...
DISTINCT_ANGLE = math.radians(10.0)   #: ... and turned less than this count as one
ELONGATED = 1.44           #: main axis: in-plane spreads at least this far apart (20% in std)
REFIT_TURN = math.radians(4.0)        #: a refit's restarts turn up to this (at least half of it)

# --------------------------------------------------------------------------- scoring, contact
MIN_VISIBLE_SAMPLES = 3    #: fewer visible samples than this (or ...)
MIN_VISIBLE_FRACTION = 0.03   #: (... this fraction) and the forward residual is the cap
PLANE_BAND = 1.5           #: samples within this many plane thresholds pair with the plane
#: a candidate whose covered samples lie on the dominant plane around the click for at least this
#: fraction covers the wall, not an object: those do not count towards its coverage
PLANE_COVERED = 0.8
BACKWARD_SUBSAMPLE = 64    #: cluster points in the coarse stage's cluster -> template half
CONTACT_BAND = 0.002       #: samples this close to the lowest one rest on the plane
CONTACT_SLACK = 0.005      #: a gap to the plane within this costs nothing
JOINT_STEP_LIMIT = 1 / 8   #: a Gauss-Newton joint step moves at most this part of the range
SCALE_STEP_LIMIT = 0.05    #: ... and a scale step at most this much


@dataclass(frozen=True)
class Stage:
    """One ICP stage: ``samples`` template samples per hypothesis, at most ``iterations``
    iterations, correspondences rejected beyond ``reject`` x the model's diameter at the start
    (the radius shrinks to ``FitSettings.reject_floor``), against the ``target`` points."""

    samples: int
    iterations: int
    reject: float
    target: str = CLUSTER


def _stage(samples: str, iterations, reject: float, target: str = CLUSTER,
           doc: str = "") -> property:
    """A :class:`FitSettings` property: the :class:`Stage` with the samples of field
    ``samples`` and the iterations of field ``iterations`` (or that number)."""
    def get(settings) -> Stage:
        n_it = getattr(settings, iterations) if isinstance(iterations, str) else iterations
        return Stage(getattr(settings, samples), n_it, reject, target)
    return property(get, doc=doc)


@dataclass(frozen=True)
class FitSettings:
    """Fitting parameters (lengths in metres, angles in radians). ``fine_metric``, ``two_way``
    and ``coarse_two_way`` are accepted at their values only: the alternatives were never
    used and are gone."""

    method: str = "default"            #: "default" or "paper" (the literal baseline)
    mode: str = "auto"                 #: "auto" (plane prior + random), "mounted", "free"
    voxel: float = 0.005               #: voxel edge of the crop
    crop_factor: float = 1.0           #: crop radius = crop_factor * largest template diameter
    snap_distance: float = 0.03        #: a click farther than this from the scan is refused
    click_tolerance: float = 0.015     #: a candidate's surface should pass this close to the click
    weight_scale: float = 0.005        #: d0 in w = 1 / (1 + d / d0)
    score_cap: float = 0.01            #: per-point distance cap of the residual
    reject_floor: float = 0.015        #: ICP rejection radius shrinks to this within a stage
    free_space_margin: float = 0.01    #: depth tolerance of the visibility tests
    #: the verdict: a sample the sensor could have seen is covered with scan points this close
    coverage_distance: float = 0.005
    #: ... and a candidate fits when at least this fraction of those samples is covered
    min_coverage: float = 0.5
    #: the same without a viewpoint, where every sample counts (a one-sided scan covers about
    #: half of an object)
    min_coverage_no_viewpoint: float = 0.3
    #: ... and the template explains the clicked object: at least this share of the object's
    #: points (the cluster's segments it overlaps, ``ClickContext.segments``) lie within
    #: ``explained_distance`` of its surface -- a valve inside a box's points covers itself
    #: but explains a fraction of the box
    min_explained: float = 0.8
    explained_distance: float = 0.008
    #: ... and its residual is at most this: a template whose surface runs several
    #: millimetres off the object is some other object's
    max_residual: float = 0.005
    #: the verdict's distances (``coverage_distance``, ``explained_distance``,
    #: ``max_residual``) hold for a scan whose measured noise around the click
    #: (``ClickContext.noise``) is at most this; a noisier scan widens them in proportion
    noise_reference: float = 0.0015
    grazing_angle: float = math.radians(89.0)  #: samples seen more obliquely count as unseen
    score_samples: int = 600           #: template samples per candidate in the residual
    yaw_restarts: int = 12             #: plane-prior restarts per template (yaw sweep)
    random_restarts: int = 12          #: uniformly random restarts per template
    free_restarts: int = 40            #: random restarts per template when there is no plane
    resting_poses: int = 5             #: stable resting facets tried per template (plane found)
    resting_yaws: int = 6              #: yaw steps per resting facet
    coarse_samples: int = 64
    coarse_iterations: int = 8
    keep_per_template: int = 3
    #: after ``prefilter_iterations`` coarse iterations, each template's best this many restarts
    #: (and its best mounted one) go on through the coarse stage (0: all)
    coarse_keep: int = 12
    #: the library prefilter: in the coarse stage, the templates whose best coarse score is
    #: more than ``prefilter_margin`` x the best template's leave the fit (ranked behind the
    #: others with their coarse pose), except the ``prefilter_keep`` best (0: no prefilter)
    prefilter_keep: int = 5
    #: (the true template outside the best five scored at most 1.22 x the best on the bench's
    #: and held-out clicks with 10, 20 and 40 templates)
    prefilter_margin: float = 1.4
    #: coarse iterations before the prefilter first decides (0: only after the coarse stage;
    #: it decides again there, on the whole stage's evidence)
    prefilter_iterations: int = 3
    coarse_two_way: bool = True        #: fixed: coarse selection also scores cluster -> template
    medium_samples: int = 256
    medium_iterations: int = 10
    fine_samples: int = 1500
    fine_iterations: int = 20
    #: at most this many full-resolution cluster points are the fine stage's target (an even
    #: subset of a dense sensor's, or of a large flat object's; 0: all of them): a 1M-point
    #: camera's cluster holds about 5700, the simulated Kinect's 1900 (7 of the bench's 100
    #: clicks more than 5000)
    fine_points: int = 5000
    fine_metric: str = "plane"         #: fixed: the final stage is point-to-plane
    two_way: bool = True               #: fixed: the final stage also pairs scene points with it
    reverse_points: int = 600          #: at most this many scene points in those pairs
    yaw_sweep: int = 8                 #: leaders re-tried at this many angles about their axis
    #: ... ranked on the medium residual, the best this many again on the full one (0: all)
    yaw_sweep_keep: int = 3
    #: the leaders finished (yaw sweep, fine stage) and ranked again on the fine residual: the
    #: winner and, of the next ``finish_candidates - 1``, those with a residual within
    #: ``finish_margin`` x the winner's (1: the winner alone)
    finish_candidates: int = 4
    finish_margin: float = 1.3
    #: estimate joint values and scale where templates have them (see ``bench``'s articulated rows)
    articulated: bool = True
    articulated_candidates: int = 4    #: at most that many leading candidates get them estimated,
    articulated_margin: float = 1.3    #: those with a residual within this factor of the best
    joint_sweep: int = 11              #: joint values tried across a revolute joint's limits
    scale_sweep: int = 7               #: scales tried across a template's scale range
    #: an articulated candidate whose rigid fit touches the plane under the click (within this)
    #: keeps touching it: the joint must not be traded for the whole object floating off it
    contact_distance: float = 0.01
    #: a joint value the data cannot tell from the nearest named state (residual within this
    #: fraction) is reported at that state; likewise a scale and the nominal scale 1
    nominal_preference: float = 0.02
    nominal_scale_preference: float = 0.005
    #: where a scale is decided (against the nominal scale 1), samples seen more obliquely
    #: than this count as unseen: a sensor returns little from ~70 deg on, and samples it
    #: could not have returned count against the larger of two sizes (pose ranking keeps
    #: ``grazing_angle``)
    scale_grazing_angle: float = math.radians(80.0)
    articulation_rounds: int = 3
    #: rounds of local joint / scale steps in a leader's finish (after its yaw sweep)
    finish_articulation_rounds: int = 1
    articulation_icp: int = 5          #: ICP iterations per sweep hypothesis
    refit_restarts: int = 10
    refit_spread: float = 0.015        #: translation spread of the refit's restarts (m)
    refit_samples: int = 800
    refit_iterations: int = 12
    refit_max_move: float = 0.05       #: a refit may move at most this far from the correction
    refit_max_turn: float = math.radians(30.0)
    #: threads one click may use (the pieces of a batch side by side; 1: the calling thread
    #: alone). The numbers do not depend on it.
    threads: int = 2
    paper_restarts: int = 25
    paper_iterations: int = 100
    paper_samples: int = 500
    seed: int = 0

    def validate(self) -> "FitSettings":
        if self.method not in ("default", "paper"):
            raise RegistrationError(f"method must be 'default' or 'paper', got {self.method!r}")
        for name, only in (("fine_metric", "plane"), ("two_way", True), ("coarse_two_way", True)):
            if getattr(self, name) != only:   # switches that never left their defaults
                raise RegistrationError(f"{name} can only be {only!r} (the alternative was "
                                        f"removed), got {getattr(self, name)!r}")
        if self.mode not in ("auto", "mounted", "free"):
            raise RegistrationError(f"mode must be 'auto', 'mounted' or 'free', got {self.mode!r}")
        for name in ("voxel", "crop_factor", "snap_distance", "click_tolerance", "refit_spread",
                     "weight_scale", "score_cap", "free_space_margin", "coverage_distance",
                     "min_coverage", "min_coverage_no_viewpoint", "min_explained",
                     "explained_distance", "max_residual", "noise_reference", "grazing_angle",
                     "scale_grazing_angle", "reject_floor", "refit_max_move", "refit_max_turn",
                     "articulated_margin", "finish_margin", "contact_distance",
                     "nominal_preference", "prefilter_margin", "nominal_scale_preference"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise RegistrationError(f"{name} must be a positive number, got {v!r}")
        for name in ("coarse_samples", "coarse_iterations", "keep_per_template", "medium_samples",
                     "medium_iterations", "fine_samples", "score_samples", "reverse_points",
                     "refit_samples", "refit_iterations", "fine_iterations", "refit_restarts",
                     "threads", "finish_candidates", "paper_restarts", "paper_iterations",
                     "paper_samples", "joint_sweep", "scale_sweep"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise RegistrationError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("yaw_restarts", "random_restarts", "free_restarts", "yaw_sweep",
                     "articulated_candidates", "prefilter_keep", "prefilter_iterations",
                     "articulation_rounds", "finish_articulation_rounds", "yaw_sweep_keep",
                     "coarse_keep", "fine_points",
                     "articulation_icp",
                     "resting_poses", "resting_yaws"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 0):
                raise RegistrationError(f"{name} must be an integer >= 0, got {v!r}")
        if self.min_coverage > 1 or self.min_coverage_no_viewpoint > 1 or self.min_explained > 1:
            raise RegistrationError("min_coverage and min_explained must be at most 1")
        if self.yaw_restarts + self.random_restarts == 0 or self.free_restarts == 0:
            raise RegistrationError("at least one restart per template is needed")
        return self

    # ---------------------------------------------------------------- the stages
    coarse = _stage("coarse_samples", "coarse_iterations", COARSE_REJECT,
                    doc="Every restart of every template, on few samples.")
    medium = _stage("medium_samples", "medium_iterations", MEDIUM_REJECT,
                    doc="The best few restarts per template.")
    short = _stage("medium_samples", SHORT_ICP, MEDIUM_REJECT,
                   doc="The leaders' yaw sweep and a refit's restarts.")
    sweep = _stage("medium_samples", "articulation_icp", SWEEP_REJECT,
                   doc="Each joint value / scale hypothesis of the articulated sweep.")
    local = _stage("medium_samples", LOCAL_ICP, SWEEP_REJECT,
                   doc="Each local joint / scale step after the sweep.")
    fine = _stage("fine_samples", "fine_iterations", FINE_REJECT, FINE,
                  doc="Each leader alone, on the full-resolution cluster.")
    refit_fine = _stage("refit_samples", "refit_iterations", FINE_REJECT, FINE,
                        doc="A refit's best restart on the full-resolution cluster.")
