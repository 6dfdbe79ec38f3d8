# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Fitting parameters (:class:`FitSettings`: a few top knobs and one frozen group per stage, each
read by that stage's module in :mod:`.stages`), the ICP stages they make (:class:`Stage`) and the
constants several stages share (sample seeds, the fixed stage lengths, the fine stage's
convergence). A constant one stage alone uses lives beside that stage's code.

Every knob is declared once, with its default, its one-line description and its rule
(:func:`knob`); the node's ``fit.*`` parameters, the YAML settings files and the error messages
are made from those declarations. A nested knob is named ``group.knob`` (``coarse.samples``);
override it with :meth:`FitSettings.with_` or load a file with :meth:`FitSettings.load`.

Lengths are metres, angles radians.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields, replace
from typing import NamedTuple

import yaml

from ..errors import RegistrationError
from ..files import read_yaml
from ..knobs import COUNT0, FRACTION, check_knob, describe_rule, knob

__all__ = ["FitSettings", "Stage", "Stages", "CLUSTER", "FINE", "knob"]

# --------------------------------------------------------------------------- samples and seeds
SAMPLE_SEED = 1  #: template samples every stage fits and scores with
REST_SAMPLES = 256  #: samples that find a pose's lowest point (resting on the plane)

# --------------------------------------------------------------------------- ICP stages
CLUSTER, FINE = "cluster", "fine"  #: ICP targets: the voxelized cluster, its full resolution
SWEEP_REJECT = 0.15  #: rejection radius of the joint / scale sweep's hypotheses (diameters)
SHORT_ICP = 6  #: ICP iterations of the leaders' yaw sweep and a refit's restarts
LOCAL_ICP = 4  #: ICP iterations after each local joint / scale step
#: the fine stage (and a refit's) has converged at this many times the step thresholds of
#: :mod:`.icp` (``CONVERGED_*``): 0.03 deg and 0.15 mm a step are far below the pose tolerance,
#: and its iterations are the dearest (it stops within 0.2 deg of the fully converged pose, a
#: handwheel turned about its axis)
FINE_CONVERGED = 3.0
#: finished leaders within this factor of the best one's residual are finished again with the
#: plain step thresholds before the final ranking (a near tie is decided on fully converged
#: fits)
NEAR_TIE = 1.02

# --------------------------------------------------------------------------- knobs
#: the largest settings file read (bytes): every knob set takes a few kB
MAX_SETTINGS_BYTES = 1_000_000


def _check(name: str, f, v) -> None:
    check_knob(name, f, v, RegistrationError)


@dataclass(frozen=True)
class _Group:
    """A group of knobs: validates itself on construction (one line naming the knob)."""

    #: the group's name in settings files and node parameters (``FitSettings``' field name)
    name = ""

    def __post_init__(self):
        for f in fields(self):
            _check(f"{self.name}.{f.name}" if self.name else f.name, f, getattr(self, f.name))
        self._rules()

    def _rules(self) -> None:
        """Rules across the group's knobs (none by default)."""


@dataclass(frozen=True)
class Stage:
    """One ICP stage: ``samples`` template samples per hypothesis, at most ``iterations``
    iterations, correspondences rejected beyond ``reject`` x the model's diameter at the start
    (the radius shrinks to ``FitSettings.icp.reject_floor``), against the ``target`` points."""

    samples: int
    iterations: int
    reject: float
    target: str = CLUSTER


class Stages(NamedTuple):
    """The ICP stages of a fit (:attr:`FitSettings.stages`)."""

    coarse: Stage  #: every restart of every template, on few samples
    medium: Stage  #: the best few restarts per template
    short: Stage  #: the leaders' yaw sweep and a refit's restarts
    sweep: Stage  #: each joint value / scale hypothesis of the articulated sweep
    local: Stage  #: each local joint / scale step after the sweep
    fine: Stage  #: each leader alone, on the full-resolution cluster
    refit: Stage  #: a refit's best restart on the full-resolution cluster


# --------------------------------------------------------------------------- the groups
@dataclass(frozen=True)
class CropSettings(_Group):
    """The scan around a click: what is cut out and how it is thinned (:mod:`.stages.prepare`)."""

    name = "crop"
    voxel: float = knob(0.005, "voxel edge of the crop around a click (m)", limits=(0.001, 0.05))
    factor: float = knob(1.0, "crop radius as a multiple of the largest template diameter")
    snap_distance: float = knob(
        0.03, "a click farther than this from the scan is refused (m)", limits=(0.001, 1.0)
    )


@dataclass(frozen=True)
class IcpSettings(_Group):
    """The weighted ICP every stage runs (:mod:`.icp`)."""

    name = "icp"
    weight_scale: float = knob(
        0.005, "d0 of the correspondence weight w = 1/(1 + d/d0) (m)", limits=(0.0005, 0.1)
    )
    reject_floor: float = knob(0.015, "an ICP rejection radius shrinks to this within a stage (m)")
    projective: bool = knob(
        False,
        "with a viewpoint, a sample pairs with the target point the sensor sees in its direction "
        "(the click's range image), not the nearest one (experimental: other numbers)",
    )


@dataclass(frozen=True)
class ScoringSettings(_Group):
    """The residual candidates are ranked on (:mod:`.scoring`)."""

    name = "scoring"
    cap: float = knob(0.01, "per-point distance cap of the residual (m)")
    samples: int = knob(600, "template samples per candidate in the residual")
    free_space_margin: float = knob(0.01, "depth tolerance of the visibility tests (m)")
    grazing_angle: float = knob(
        math.radians(89.0),
        "samples seen more obliquely than this count as unseen (rad)",
        limits=(0.01, math.pi),
    )
    click_tolerance: float = knob(
        0.015, "a candidate's surface should pass this close to the click (m)"
    )


@dataclass(frozen=True)
class HypothesesSettings(_Group):
    """The restarts each template starts from (:mod:`.stages.hypothesise`)."""

    name = "hypotheses"
    yaw_restarts: int = knob(12, "plane-prior restarts per template (a yaw sweep)", COUNT0)
    random_restarts: int = knob(12, "uniformly random restarts per template", COUNT0)
    free_restarts: int = knob(40, "random restarts per template when there is no plane")
    resting_poses: int = knob(
        5, "stable resting facets tried per template (a plane found)", COUNT0
    )
    resting_yaws: int = knob(6, "yaw steps per resting facet", COUNT0, limits=(0, 360))

    def _rules(self) -> None:
        if self.yaw_restarts + self.random_restarts == 0:
            raise RegistrationError(
                "hypotheses: at least one restart per template is needed "
                "(yaw_restarts + random_restarts >= 1)"
            )


@dataclass(frozen=True)
class CoarseSettings(_Group):
    """The coarse stage: every restart of every template, on few samples
    (:mod:`.stages.coarse`)."""

    name = "coarse"
    samples: int = knob(64, "template samples per restart")
    iterations: int = knob(8, "ICP iterations")
    reject: float = knob(0.5, "rejection radius at the stage's start (template diameters)")
    #: after ``prefilter.iterations`` coarse iterations, each template's best this many restarts
    #: (and its best mounted one) go on through the coarse stage
    keep: int = knob(
        12, "restarts per template kept after the prefilter's first look (0: all)", COUNT0
    )
    keep_per_template: int = knob(
        3, "distinct hypotheses per template that go on to the medium stage"
    )


@dataclass(frozen=True)
class PrefilterSettings(_Group):
    """The library prefilter: in the coarse stage, the templates whose best coarse score is more
    than ``margin`` x the best template's leave the fit (ranked behind the others with their
    coarse pose), except the ``keep`` best (:mod:`.stages.prefilter`)."""

    name = "prefilter"
    keep: int = knob(
        5, "templates never prefiltered: the best this many (0: no prefilter)", COUNT0
    )
    margin: float = knob(1.4, "a template whose coarse score exceeds this x the best leaves")
    iterations: int = knob(
        3,
        "coarse iterations before the prefilter first decides (0: only after the coarse stage)",
        COUNT0,
    )
    #: a library of more than twice ``keep`` templates is screened on fewer samples: the first
    #: look at every restart of every template is what a large library pays for (chosen on
    #: the bench's variant family, 80 clicks: 48 never set the true template aside; 32 did
    #: twice). A library of a few templates gains little and keeps its fits as they were
    samples: int = knob(
        48,
        "template samples (and cluster points) per restart in the first "
        "look, in a library of more than 2 x keep templates (0: the coarse "
        "stage's)",
        COUNT0,
    )


@dataclass(frozen=True)
class MediumSettings(_Group):
    """The medium stage: the best few restarts per template (:mod:`.stages.medium`)."""

    name = "medium"
    samples: int = knob(
        256,
        "template samples per hypothesis (also the yaw sweep's, the "
        "articulated sweep's and a refit's restarts')",
    )
    iterations: int = knob(10, "ICP iterations")
    reject: float = knob(0.25, "rejection radius at the stage's start (template diameters)")


@dataclass(frozen=True)
class FineSettings(_Group):
    """The fine stage: each leader alone, point-to-plane and two-way, on the full-resolution
    cluster (:mod:`.stages.finish`)."""

    name = "fine"
    samples: int = knob(1500, "template samples per leader")
    iterations: int = knob(20, "ICP iterations")
    reject: float = knob(
        0.1, "rejection radius at the stage's start (template diameters; also a refit's final ICP)"
    )
    #: an even subset of a dense sensor's, or of a large flat object's: a 1M-point camera's
    #: cluster holds about 5700, the simulated Kinect's 1900
    points: int = knob(
        5000, "at most this many full-resolution cluster points are the target (0: all)", COUNT0
    )
    reverse_points: int = knob(600, "at most this many scene points paired with the template")


@dataclass(frozen=True)
class FinishSettings(_Group):
    """The leaders' finish: yaw sweep, fine stage, ranked again on the fine residual
    (:mod:`.stages.finish`)."""

    name = "finish"
    yaw_sweep: int = knob(
        8, "leaders re-tried at this many angles about their axis", COUNT0, limits=(0, 360)
    )
    yaw_sweep_keep: int = knob(
        3, "of those, ranked on the medium residual, the best this many go on (0: all)", COUNT0
    )
    candidates: int = knob(
        4,
        "the winner and, of the next candidates - 1, those within margin "
        "are finished (1: the winner alone)",
    )
    margin: float = knob(1.3, "finished: a residual within this factor of the winner's")
    #: the fine stage raised a leader's explained share by at most 0.10 on the simulated
    #: panels, tables and articulated boards and 0.24 on mOSD's tuning scenes: one this far
    #: below the verdict's bar cannot come to fit, and finishing it costs a real click most of
    #: its time (several such leaders within margin of each other)
    explained_margin: float = knob(
        0.3,
        "a leader explaining less than verdict.min_explained "
        "minus this share of the clicked object's points is not "
        "finished (1: every one is)",
        FRACTION,
    )


@dataclass(frozen=True)
class ArticulationSettings(_Group):
    """Joint values and scale, where templates have them (``FitSettings.articulated``;
    :mod:`.stages.articulate`)."""

    name = "articulation"
    candidates: int = knob(4, "at most this many leading candidates get them estimated", COUNT0)
    margin: float = knob(1.3, "those with a residual within this factor of the best")
    #: a valve fitted rigidly with its handle turned explained at least 0.49 of its points on
    #: the simulated articulated boards (a rigid fit's share rose by up to 0.51 with its joint)
    explained_margin: float = knob(
        0.55,
        "a leader explaining less than verdict.min_explained "
        "minus this share of the clicked object's points gets "
        "none (1: every one does)",
        FRACTION,
    )
    joint_sweep: int = knob(
        11, "joint values tried across a revolute joint's limits", limits=(1, 360)
    )
    scale_sweep: int = knob(7, "scales tried across a template's scale range")
    #: an articulated candidate whose rigid fit touches the plane under the click keeps
    #: touching it: the joint must not be traded for the whole object floating off it
    contact_distance: float = knob(
        0.01, "a rigid fit this close to the plane under the click keeps touching it (m)"
    )
    nominal_preference: float = knob(
        0.02,
        "a joint value within this residual fraction of the "
        "nearest named state is reported at that state",
    )
    nominal_scale_preference: float = knob(0.005, "likewise a scale and the nominal scale 1")
    #: a sensor returns little from ~70 deg on, and samples it could not have returned count
    #: against the larger of two sizes (pose ranking keeps ``scoring.grazing_angle``)
    scale_grazing_angle: float = knob(
        math.radians(80.0),
        "where a scale is decided, samples seen more obliquely than this count as unseen (rad)",
        limits=(0.01, math.pi),
    )
    rounds: int = knob(
        3, "rounds of local joint / scale steps after the sweep", COUNT0, limits=(0, 20)
    )
    finish_rounds: int = knob(
        1, "rounds of local joint / scale steps in a leader's finish", COUNT0, limits=(0, 20)
    )
    sweep_iterations: int = knob(5, "ICP iterations per sweep hypothesis", COUNT0)


#: knobs of earlier versions, passed over where a settings file still has them: dotted name ->
#: what took their place
RETIRED = {
    "verdict.explained_margin": "the description length against a fitting primitive "
    "(docs/TUNING.md, verdict)",
}


@dataclass(frozen=True)
class VerdictSettings(_Group):
    """Whether the best candidate fits: it covers what the sensor could see of it, explains the
    clicked object and runs close to it (:mod:`.stages.judge`, :func:`.scoring.judge`)."""

    name = "verdict"
    coverage_distance: float = knob(
        0.005, "a sample the sensor could have seen is covered by scan points this close (m)"
    )
    min_coverage: float = knob(
        0.5, "a candidate fits when at least this fraction of those samples is covered", FRACTION
    )
    #: a one-sided scan covers about half of an object
    min_coverage_no_viewpoint: float = knob(
        0.3, "the same without a viewpoint, where every sample counts", FRACTION
    )
    #: a box behind another is seen around its edges: the part hidden behind the other is not
    #: held against its primitive (but a primitive sunk into a surface, its samples just behind
    #: it, is; and a specific template is judged on everything it faces)
    occluder_gap: float = knob(
        0.03,
        "a primitive's samples hidden at least this far behind "
        "the scan (another object in front) do not count towards "
        "its coverage (m)",
    )
    #: a valve inside a box's points covers itself but explains a fraction of the box
    min_explained: float = knob(
        0.8,
        "share of the clicked object's points within explained_distance of the template's surface",
        FRACTION,
    )
    explained_distance: float = knob(0.008, "see min_explained (m)")
    #: a template whose surface runs several millimetres off the object is some other object's
    max_residual: float = knob(
        0.005,
        "a fitting candidate's object residual (its surface "
        "and the clicked object's points) is at most this (m)",
    )
    #: an emergency stop fitted to a plain box covers the housing but not the button: what
    #: sets a template apart from the primitive that fits the same click must be seen
    distinct_distance: float = knob(
        0.01,
        "a specific template's samples this far off the "
        "surface of the primitive fitting the same click set "
        "it apart from it (m)",
    )
    min_distinct: float = knob(
        0.25,
        "a specific template fits only when at least this share "
        "of those it shows the sensor is covered",
        FRACTION,
    )
    #: a primitive explains the clicked object -- the whole of it and only it
    #: (:mod:`.explains`): the operator's question, and the label rule real scans are scored by
    min_recall: float = knob(
        0.9,
        "a primitive fits when at least this share of the clicked object's points lies on its "
        "surface (within object_distance)",
        FRACTION,
    )
    min_precision: float = knob(
        0.9,
        "... and at least this share of the scan points on its surface is the object's (not "
        "the support, not a neighbour)",
        FRACTION,
    )
    object_distance: float = knob(
        0.006,
        "a scan point lies on a primitive's surface within this (m), or noise_sigmas x "
        "the scan's noise where larger",
    )
    noise_sigmas: float = knob(3.0, "see object_distance", limits=(0.5, 20.0))
    #: a noisier scan (``ClickContext.noise``) widens the verdict's distances in proportion
    noise_reference: float = knob(
        0.0015, "the verdict's distances hold for a scan noise up to this (m)"
    )


@dataclass(frozen=True)
class RefitSettings(_Group):
    """A refit from the operator's correction (:mod:`.stages.refit`)."""

    name = "refit"
    restarts: int = knob(10, "restarts around the correction")
    spread: float = knob(0.015, "translation spread of the restarts (m)")
    samples: int = knob(800, "template samples of the final ICP")
    iterations: int = knob(12, "ICP iterations of the final ICP")
    max_move: float = knob(
        0.05, "a refit moves the object (its centroid) at most this far from the correction (m)"
    )
    max_turn: float = knob(
        math.radians(30.0), "... and turns at most this much (rad)", limits=(0.001, math.pi)
    )


@dataclass(frozen=True)
class ViewpointSettings(_Group):
    """Whether a click's answer is settled, and where the sensor should look from when it is not
    (:mod:`.stages.assess`, :mod:`.ambiguity`, :mod:`.viewpoint`): they only add information to a
    fit, never change it."""

    name = "viewpoint"
    #: the leading candidates within this factor of the best's residual are rivals: a template
    #: and a near copy of it, or one template in two poses, the data cannot tell apart
    margin: float = knob(
        1.3,
        "a candidate or pose within this factor of the best's residual "
        "is a rival (the click is unsettled)",
        limits=(1.0, 10.0),
    )
    pose_distance: float = knob(
        0.005,
        "one template's poses that put its centroid farther apart than this are distinct "
        "hypotheses (m)",
    )
    pose_angle: float = knob(
        math.radians(5.0),
        "... or turned more than this, symmetry-aware (rad)",
        limits=(0.001, math.pi),
    )
    #: a flat face seen edge-on: the residual barely changes along some motion
    weak_ratio: float = knob(
        0.01,
        "the best pose is weakly held when the smallest eigenvalue "
        "of its point-to-plane Hessian is below this x the largest",
        FRACTION,
    )
    rivals: int = knob(2, "at most this many rivals are compared for a suggested view")
    min_distance: float = knob(
        0.5, "a suggested view is at least this far from the object (m)", limits=(0.05, 50.0)
    )
    max_distance: float = knob(
        1.5, "... and at most this far (m; the two are taken in order)", limits=(0.05, 50.0)
    )
    max_angle: float = knob(
        math.radians(70.0),
        "... and turned at most this much from the current view about the object (rad)",
        limits=(0.01, math.pi),
    )
    min_elevation: float = knob(
        math.radians(20.0),
        "... and at least this high above the support plane, on its open side (rad)",
        limits=(0.01, math.pi / 2),
    )
    directions: int = knob(40, "view directions sampled within those bounds", limits=(1, 200))
    distances: int = knob(3, "distances sampled within the range, per direction", limits=(1, 10))
    samples: int = knob(1200, "template samples per hypothesis in the predicted views")
    grazing_angle: float = knob(
        math.radians(70.0),
        "a predicted surface seen more obliquely than this returns nothing (rad)",
        limits=(0.01, math.pi),
    )
    depth_difference: float = knob(
        0.01, "two predictions differ where their depths differ by more than this (m)"
    )
    visibility_weight: float = knob(
        0.1,
        "weight of the best candidate's visible surface "
        "against the rivals' differences in a view's score",
    )


#: the groups, by their field name in :class:`FitSettings`
GROUPS = {
    g.name: g
    for g in (
        CropSettings,
        IcpSettings,
        ScoringSettings,
        HypothesesSettings,
        CoarseSettings,
        PrefilterSettings,
        MediumSettings,
        FineSettings,
        FinishSettings,
        ArticulationSettings,
        VerdictSettings,
        RefitSettings,
        ViewpointSettings,
    )
}


def _group(cls):
    return field(default_factory=cls, metadata={"group": cls})


@dataclass(frozen=True)
class FitSettings:
    """Fitting parameters (lengths in metres, angles in radians): a few top knobs and one group
    per stage. Build with keywords (``FitSettings(seed=3, coarse=CoarseSettings(samples=32))``),
    :meth:`with_` (``settings.with_(**{"coarse.samples": 32})``), :meth:`from_dict` or
    :meth:`load` (YAML); every group validates itself on construction."""

    method: str = knob("default", "default or paper (the literal baseline)", ("default", "paper"))
    mode: str = knob(
        "auto",
        "auto: mounting plane prior + resting + random restarts; mounted: "
        "the plane prior only; free: no mounting prior",
        ("auto", "mounted", "free"),
    )
    articulated: bool = knob(
        True,
        "estimate joint values (valve open/closed) and scale where "
        "templates have them; false: rigid templates only",
    )
    seed: int = knob(
        0, "random seed of the restarts (fits are deterministic)", COUNT0, limits=(0, 2**31 - 1)
    )
    #: the pieces of a batch side by side; the numbers do not depend on it
    threads: int = knob(2, "threads one click may use (1: the calling thread alone)")
    #: the paper baseline (``method: paper``) has three knobs of its own, beside ``method``
    paper_restarts: int = knob(25, "paper baseline: random restarts per template", limits=(1, 250))
    paper_iterations: int = knob(100, "paper baseline: ICP iterations per restart")
    paper_samples: int = knob(500, "paper baseline: template samples", limits=(1, 2000))
    crop: CropSettings = _group(CropSettings)
    icp: IcpSettings = _group(IcpSettings)
    scoring: ScoringSettings = _group(ScoringSettings)
    hypotheses: HypothesesSettings = _group(HypothesesSettings)
    coarse: CoarseSettings = _group(CoarseSettings)
    prefilter: PrefilterSettings = _group(PrefilterSettings)
    medium: MediumSettings = _group(MediumSettings)
    fine: FineSettings = _group(FineSettings)
    finish: FinishSettings = _group(FinishSettings)
    articulation: ArticulationSettings = _group(ArticulationSettings)
    verdict: VerdictSettings = _group(VerdictSettings)
    refit: RefitSettings = _group(RefitSettings)
    viewpoint: ViewpointSettings = _group(ViewpointSettings)

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if "group" in f.metadata:
                if not isinstance(value, f.metadata["group"]):
                    raise RegistrationError(
                        f"{f.name} must be a {f.metadata['group'].__name__}, got {value!r}"
                    )
            else:
                _check(f.name, f, value)

    def validate(self) -> "FitSettings":
        """The settings (they validated themselves on construction)."""
        return self

    # ---------------------------------------------------------------- knobs by name
    @classmethod
    def knobs(cls) -> list:
        """Every knob: (dotted name, default, one-line description, rule text), top knobs first,
        then group by group."""
        out = []
        for f in fields(cls):
            group = f.metadata.get("group")
            for g in fields(group) if group else (f,):
                name = f"{f.name}.{g.name}" if group else f.name
                out.append((name, g.default, g.metadata["doc"], describe_rule(g)))
        return out

    def to_dict(self) -> dict:
        """The settings as plain data, nested by group (YAML / JSON)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = (
                {g.name: getattr(value, g.name) for g in fields(value)}
                if "group" in f.metadata
                else value
            )
        return out

    @classmethod
    def from_dict(cls, data, base: "FitSettings | None" = None) -> "FitSettings":
        """Settings from plain data nested by group (as :meth:`to_dict` makes; missing knobs keep
        ``base``'s values, by default the defaults). An unknown name or a bad value raises
        :class:`RegistrationError` with one line naming it; a RETIRED knob (a settings file
        written by an earlier version) is passed over."""
        base = base or cls()
        if not isinstance(data, dict):
            raise RegistrationError(
                f"settings must be a mapping of knobs and groups, got {type(data).__name__}"
            )
        known = {f.name: f for f in fields(cls)}
        top, groups = {}, {}
        for key, value in data.items():
            f = known.get(key)
            if f is None:
                raise RegistrationError(f"unknown setting {key!r} (one of: {', '.join(known)})")
            group = f.metadata.get("group")
            if group is None:
                top[key] = _as_type(f, value)
                continue
            if not isinstance(value, dict):
                raise RegistrationError(f"{key} must be a mapping of its knobs, got {value!r}")
            inner = {g.name: g for g in fields(group)}
            value = {n: v for n, v in value.items() if f"{key}.{n}" not in RETIRED}
            for name in value:
                if name not in inner:
                    raise RegistrationError(
                        f"unknown setting {key}.{name} (one of: {', '.join(inner)})"
                    )
            groups[key] = replace(
                getattr(base, key), **{n: _as_type(inner[n], v) for n, v in value.items()}
            )
        return replace(base, **top, **groups)

    def with_(self, **changes) -> "FitSettings":
        """These settings with knobs changed by dotted name:
        ``settings.with_(seed=3, **{"coarse.samples": 32})``."""
        nested: dict = {}
        for key, value in changes.items():
            group, dot, name = key.partition(".")
            if dot:
                nested.setdefault(group, {})[name] = value
            else:
                nested[key] = value
        return FitSettings.from_dict(nested, base=self)

    # ---------------------------------------------------------------- YAML
    def dump(self) -> str:
        """The settings as a YAML document (what :meth:`load` reads)."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    @classmethod
    def load(cls, path: str) -> "FitSettings":
        """Settings from a YAML file (all knobs optional, nested by group). A missing, unreadable
        or malformed file, an unknown name or a bad value raises :class:`RegistrationError`
        with one line."""
        path = os.path.expanduser(str(path))
        data = read_yaml(
            path,
            RegistrationError,
            label=f"settings file {path}",
            max_bytes=MAX_SETTINGS_BYTES,
            kind="settings file",
        )
        try:
            return cls.from_dict({} if data is None else data)
        except RegistrationError as exc:
            raise RegistrationError(f"settings file {path}: {exc}") from None

    # ---------------------------------------------------------------- the stages
    @property
    def stages(self) -> Stages:
        """The ICP stages these settings run."""
        c, m, f, a, r = self.coarse, self.medium, self.fine, self.articulation, self.refit
        return Stages(
            coarse=Stage(c.samples, c.iterations, c.reject),
            medium=Stage(m.samples, m.iterations, m.reject),
            short=Stage(m.samples, SHORT_ICP, m.reject),
            sweep=Stage(m.samples, a.sweep_iterations, SWEEP_REJECT),
            local=Stage(m.samples, LOCAL_ICP, SWEEP_REJECT),
            fine=Stage(f.samples, f.iterations, f.reject, FINE),
            refit=Stage(r.samples, r.iterations, f.reject, FINE),
        )


def _as_type(f, value):
    """A value read from a file for knob ``f``: an integer where a float is expected becomes
    that float (YAML's ``1`` for ``1.0``); anything else is left to the knob's rule."""
    if isinstance(f.default, float) and isinstance(value, int) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:  # hundreds of digits: the rule refuses it as it is
            return value
    return value
