# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""affordance_registration: click-to-fit affordance template registration for ROS 2.

The public Python API, importable from the package root::

    from affordance_registration import AffordanceEngine, TemplateLibrary, Registrar, \\
        FitSettings, Scene

Each name is imported from ``affordance_registration.core`` when first used, so importing the
package root loads neither the fitting stack nor anything of ROS. The ROS glue lives in
``affordance_registration.ros``.
"""

from __future__ import annotations

import importlib

__all__ = [
    "AffordanceEngine",
    "TemplateLibrary",
    "Registrar",
    "FitSettings",
    "Scene",
    "AffordanceError",
]

_PUBLIC = {
    "AffordanceEngine": ".core.engine",
    "TemplateLibrary": ".core.templates",
    "Registrar": ".core.registration",
    "FitSettings": ".core.registration",
    "Scene": ".core.scene",
    "AffordanceError": ".core.errors",
}


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
