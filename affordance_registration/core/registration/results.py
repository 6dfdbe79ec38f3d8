"""What a fit returns: one :class:`FitResult` per template, ranked into a :class:`FitReport`."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..scene import ClickContext
from .model import Batch

__all__ = ["FitResult", "FitReport", "IcpResult", "rank", "NO_MATCH", "NO_MATCH_RESIDUAL"]


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
    ``FitSettings.coverage_distance``; ``inlier_rmse`` the RMS distance of those points (m);
    ``fits`` whether coverage reaches ``FitSettings.min_coverage`` (None: not judged, as for
    the literal baseline and the candidates the library prefilter set aside; their coverage and
    inlier_rmse are then 0)."""

    template: str
    T_scene_model: np.ndarray = field(repr=False)   #: 4x4, model -> scene
    residual: float                                  #: m, two-way capped mean distance
    likelihood: float                                #: 1 / residual (the ranking field)
    probability: float = 0.0
    inlier_fraction: float = 0.0                     #: visible samples within the cap
    iterations: int = 0
    time_s: float = 0.0
    rank: int = 0                                    #: 1 = best
    joints: dict = field(default_factory=dict)       #: joint name -> value (rad or m)
    scale: float = 1.0                               #: uniform scale of the template
    state: str | None = None                         #: the nearest named state
    #: whether the last ICP stage of this candidate converged before its iteration limit
    #: (None: no ICP ran, e.g. the literal baseline's own loop)
    converged: bool | None = None
    coverage: float = 0.0
    inlier_rmse: float = 0.0                         #: m
    fits: bool | None = None
    #: set aside by the library prefilter after the coarse stage: pose and residual are that
    #: stage's (fewer samples), and it ranks behind every candidate that was fitted on
    prefiltered: bool = False

    def to_dict(self) -> dict:
        return {"rank": self.rank, "template": self.template,
                "joints": {k: round(float(v), 6) for k, v in self.joints.items()},
                "scale": round(float(self.scale), 6), "state": self.state,
                "likelihood": round(self.likelihood, 6), "probability": round(self.probability, 6),
                "residual": round(self.residual, 9), "inlier_fraction": round(self.inlier_fraction, 4),
                "coverage": round(float(self.coverage), 4),
                "inlier_rmse": round(float(self.inlier_rmse), 9), "fits": self.fits,
                "iterations": self.iterations, "converged": self.converged,
                "prefiltered": self.prefiltered, "time_s": round(self.time_s, 6),
                "pose": [[round(float(v), 9) for v in row] for row in self.T_scene_model]}


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
    """The ranked candidates of one click (best first) and where the time went."""

    point: np.ndarray
    candidates: tuple
    timing_s: dict
    context: ClickContext = field(repr=False)


def rank(results, no_match_likelihood: float = 1.0 / NO_MATCH_RESIDUAL) -> tuple:
    """``results`` (FitResult) best first by likelihood -- those the library prefilter set
    aside behind the others -- with ``rank`` (1 = best) and ``probability`` (the likelihood
    over the sum of all and ``no_match_likelihood``, that of "no template fits here"; 0 for a
    ranking of scores that are not likelihoods) filled in."""
    results = sorted(results, key=lambda r: (r.prefiltered, -r.likelihood))
    total = (sum(r.likelihood for r in results) + no_match_likelihood) or 1.0
    return tuple(replace(r, rank=i, probability=r.likelihood / total)
                 for i, r in enumerate(results, start=1))
