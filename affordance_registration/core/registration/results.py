# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What a fit returns: one :class:`FitResult` per template, ranked into a :class:`FitReport`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..scene import ClickContext
from .model import Batch

__all__ = [
    "FitResult",
    "FitReport",
    "IcpResult",
    "rank",
    "NO_MATCH",
    "NO_MATCH_RESIDUAL",
    "no_match",
    "verdict",
    "describe_primitive",
]


#: the residual (m) at which a fit is as likely as "no template fits here": the likelihood of
#: that answer, 1 / NO_MATCH_RESIDUAL, takes part in every click's probabilities, so a poor fit
#: never reads 1.00 however few templates there are
NO_MATCH_RESIDUAL = 0.005
#: the verdict's text when the best candidate does not fit (``FitResult.fits`` false)
NO_MATCH = "no template fits here"


@dataclass(frozen=True)
class FitResult:
    """One fitted candidate. Candidates are ranked by ``likelihood`` (higher is better), which is
    the inverse of ``residual``; ``probability`` is the likelihood normalized over the click's
    candidates and the answer "no template fits here" (likelihood 1 / ``NO_MATCH_RESIDUAL``).

    The absolute verdict, whatever the other candidates score: ``coverage`` is the fraction of
    the template surface the sensor could have seen that has scan points within
    ``FitSettings.verdict.coverage_distance``; ``inlier_rmse`` the RMS distance of those points
    (m); ``fits`` whether coverage reaches ``FitSettings.verdict.min_coverage`` (None: not judged,
    as for the literal baseline and the candidates the library prefilter set aside; their coverage
    and inlier_rmse are then 0)."""

    template: str
    T_scene_model: np.ndarray = field(repr=False)  #: 4x4, model -> scene
    residual: float  #: m, two-way capped mean distance
    likelihood: float  #: 1 / residual (the ranking field)
    probability: float = 0.0
    inlier_fraction: float = 0.0  #: visible samples within the cap
    iterations: int = 0
    time_s: float = 0.0
    rank: int = 0  #: 1 = best
    joints: dict = field(default_factory=dict)  #: joint name -> value (rad or m)
    scale: float = 1.0  #: uniform scale of the template
    state: str | None = None  #: the nearest named state
    #: whether the last ICP stage of this candidate converged before its iteration limit
    #: (None: no ICP ran, e.g. the literal baseline's own loop)
    converged: bool | None = None
    coverage: float = 0.0
    inlier_rmse: float = 0.0  #: m
    fits: bool | None = None
    #: set aside by the library prefilter after the coarse stage: pose and residual are that
    #: stage's (fewer samples), and it ranks behind every candidate that was fitted on
    prefiltered: bool = False
    #: the share of the clicked object's points on the candidate's surface (the verdict)
    explained: float = 0.0
    #: m, the residual the verdict reads: template -> scene as ranked, and the clicked
    #: object's points (not the touching neighbours of the cluster) -> template
    object_residual: float = 0.0
    noise: float = 0.0  #: m, the scan's noise around the click
    reason: str | None = None  #: why it does not fit (None: it fits)
    #: a primitive template's kind ("box", "cylinder") and fitted dimensions (m: a box's
    #: "x", "y", "z", a cylinder's "radius", "length"); None and {} for a specific template
    primitive: str | None = None
    dimensions: dict = field(default_factory=dict)
    #: of the surface that sets a specific template apart from the primitive fitting the same
    #: click, the share the sensor saw (:func:`.scoring.distinguished`; None: not measured)
    distinct: float | None = None
    #: of the clicked object's points, the share on a primitive's surface, and of the scan's
    #: points on its surface, the share that is the object's (:mod:`.explains`; None: not
    #: measured, as for a specific template)
    recall: float | None = None
    precision: float | None = None

    def to_dict(self) -> dict:
        return {
            "rank": self.rank,
            "template": self.template,
            "joints": {k: round(float(v), 6) for k, v in self.joints.items()},
            "scale": round(float(self.scale), 6),
            "state": self.state,
            "likelihood": round(self.likelihood, 6),
            "probability": round(self.probability, 6),
            "residual": round(self.residual, 9),
            "inlier_fraction": round(self.inlier_fraction, 4),
            "coverage": round(float(self.coverage), 4),
            "inlier_rmse": round(float(self.inlier_rmse), 9),
            "explained": round(float(self.explained), 4),
            "object_residual": round(float(self.object_residual), 9),
            "noise": round(float(self.noise), 9),
            "fits": self.fits,
            "reason": self.reason,
            "primitive": self.primitive,
            "dimensions": {k: round(float(v), 6) for k, v in self.dimensions.items()}
            if self.primitive
            else None,
            "distinct": None if self.distinct is None else round(float(self.distinct), 4),
            "recall": None if self.recall is None else round(float(self.recall), 4),
            "precision": None if self.precision is None else round(float(self.precision), 4),
            "iterations": self.iterations,
            "converged": self.converged,
            "prefiltered": self.prefiltered,
            "time_s": round(self.time_s, 6),
            "pose": [[round(float(v), 9) for v in row] for row in self.T_scene_model],
        }


@dataclass(frozen=True)
class IcpResult(Batch):
    """What an ICP stage returns for its batch of B hypotheses (like small_gicp's
    ``RegistrationResult``): the models (their joint values and scales as fitted) and poses,
    the iterations run and which hypotheses converged (their last step below the thresholds),
    (B,) bool."""

    iterations: int
    converged: np.ndarray


@dataclass(frozen=True)
class FitReport:
    """The ranked candidates of one click (best first), where the time went and whether the
    answer is settled."""

    point: np.ndarray
    candidates: tuple
    timing_s: dict
    context: ClickContext = field(repr=False)
    #: the fit's other hypotheses (FitResult, medium stage: each template's distinct poses),
    #: which the ambiguity reads for a second pose of the best template
    alternatives: tuple = field(default=(), repr=False)
    #: whether the answer is settled (:class:`~.ambiguity.Ambiguity`; None: not assessed)
    ambiguity: object = None


def rank(results, no_match_likelihood: float = 1.0 / NO_MATCH_RESIDUAL) -> tuple:
    """``results`` (FitResult) best first by likelihood -- those the library prefilter set
    aside behind the others -- with ``rank`` (1 = best) and ``probability`` (the likelihood
    over the sum of all and ``no_match_likelihood``, that of "no template fits here"; 0 for a
    ranking of scores that are not likelihoods) filled in.

    Primitives describe the "no template fits here" answer: a specific template that fits
    ranks above every primitive; when none fits, a primitive that fits leads; where nothing
    fits, the group whose best explains more of the clicked object (``explained``) leads -- the
    specific templates on a tie (the right object refused at its right pose is shown rather
    than a box around it and its neighbour; a box refused for the table at its base rather
    than a valve that explains a fifth of the box). Their probabilities are shared among the
    specific templates; a primitive's among the primitives (each with the no-match answer)."""
    results = list(results)
    fits = {
        p: any(r.fits and (r.primitive is not None) == p for r in results) for p in (False, True)
    }
    if fits[False]:
        lead = False
    elif fits[True]:
        lead = True
    else:
        most = {
            p: max(
                (
                    r.explained
                    for r in results
                    if (r.primitive is not None) == p and not r.prefiltered
                ),
                default=-1.0,
            )
            for p in (False, True)
        }
        lead = most[True] > most[False]

    def group(r: FitResult) -> int:
        return 0 if (r.primitive is not None) == lead else 1

    results.sort(key=lambda r: (r.prefiltered, group(r), -r.likelihood))
    total = {
        p: (
            sum(r.likelihood for r in results if (r.primitive is not None) == p)
            + no_match_likelihood
        )
        or 1.0
        for p in (False, True)
    }
    return tuple(
        replace(r, rank=i, probability=r.likelihood / total[r.primitive is not None])
        for i, r in enumerate(results, start=1)
    )


def no_match(candidates) -> bool:
    """The verdict on a click's ranked ``candidates``: no specific template fits -- the best is
    refused (``fits`` False) or is a primitive."""
    return bool(candidates) and (
        candidates[0].fits is False or candidates[0].primitive is not None
    )


def describe_primitive(r: FitResult) -> str:
    """'a box 0.21 x 0.12 x 0.08 m', 'a cylinder r 0.035 m x 0.12 m'."""
    d = r.dimensions
    if r.primitive == "box":
        return f"a box {d['x']:.2f} x {d['y']:.2f} x {d['z']:.2f} m"
    return f"a cylinder r {d['radius']:.3f} m x {d['length']:.2f} m"


def verdict(candidates) -> str:
    """The verdict's text: "fits", "no template fits here", or "no template fits here;
    fitted as a box 0.21 x 0.12 x 0.08 m" when the best is a primitive that fits."""
    if not no_match(candidates):
        return "fits"
    best = candidates[0]
    if best.primitive is not None and best.fits:
        return f"{NO_MATCH}; fitted as {describe_primitive(best)}"
    return NO_MATCH
