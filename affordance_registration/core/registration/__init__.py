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

from __future__ import annotations

import importlib

#: where each public name lives: imported with it on first use, so that what needs only the
#: settings (``affordance-registration settings``, a node's parameter checks) does not load the
#: fitting stack (scipy, trimesh, numba) with them
_PUBLIC = {
    "correspondence_weights": ".correspondences",
    "Model": ".model",
    "PosedTemplate": ".model",
    "Registrar": ".registrar",
    "NO_MATCH": ".results",
    "NO_MATCH_RESIDUAL": ".results",
    "FitReport": ".results",
    "FitResult": ".results",
    "describe_primitive": ".results",
    "no_match": ".results",
    "rank": ".results",
    "verdict": ".results",
    "FitSettings": ".settings",
    "weighted_rigid_fit": ".solve",
}

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


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    #: the model type every template is fitted as (rigid = joint at zero, scale one)
    attr = "Model" if name == "PosedTemplate" else name
    value = getattr(importlib.import_module(module, __name__), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
