# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Random-restart weighted ICP over every template, batched: the :class:`Registrar` composes
the stages of this package (see :mod:`.registrar` for the algorithm).

settings (parameters, stage constants), results (FitResult, FitReport, rank), model (the posed
model, the locked cache of samples and KD-trees), solve (closed-form and Gauss-Newton steps),
visibility, correspondences, icp, parallel (pieces of a batch side by side), scoring (the
two-way residual), hypotheses, articulation (joint values and scale), refit, primitives
(boxes and cylinders, measured), paper (the literal baseline), registrar (the composer).
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
