# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Random-restart weighted ICP over every template, batched: the :class:`Registrar` runs the
recipe (:mod:`.registrar`: the algorithm, and the stages in order), each stage a module of
:mod:`.stages` passing the click's :class:`~.state.FitState` on.

Below the stages: settings (parameters, stage constants), results (FitResult, FitReport, rank),
model (the posed model, the locked cache of samples and KD-trees), solve (closed-form and
Gauss-Newton steps), visibility, correspondences, icp, parallel (pieces of a batch side by
side), scoring (the two-way residual and the verdict), features, hypotheses (where ICP starts),
articulation (joint values and scale), refit (a local refit), primitives (boxes and cylinders,
measured), hidden_parts, ambiguity, viewpoint (a suggested view); services (what every stage
uses) and state (what passes from stage to stage).
"""

from .correspondences import correspondence_weights
from .model import Model
from .registrar import Registrar
from .results import (
    NO_MATCH,
    NO_MATCH_RESIDUAL,
    FitReport,
    FitResult,
    describe_primitive,
    no_match,
    rank,
    verdict,
)
from .settings import FitSettings
from .solve import weighted_rigid_fit

#: the model type every template is fitted as (rigid = joint at zero, scale one)
PosedTemplate = Model

__all__ = [
    "FitSettings",
    "FitResult",
    "FitReport",
    "Registrar",
    "PosedTemplate",
    "Model",
    "correspondence_weights",
    "weighted_rigid_fit",
    "rank",
    "NO_MATCH",
    "NO_MATCH_RESIDUAL",
    "no_match",
    "verdict",
    "describe_primitive",
]
