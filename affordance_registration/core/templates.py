# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The template library: an ordered, read-only name -> template mapping loaded from a directory
of template files (the package's own ``models/`` by default).

The template object is :mod:`~affordance_registration.core.affordance_template`'s, its file
format and checks :mod:`~affordance_registration.core.template_files`', the mesh geometry both
use :mod:`~affordance_registration.core.meshes`'; the names the rest of the package imports from
here are re-exported.
"""

from __future__ import annotations

import os
from typing import Iterator, Mapping

from .affordance_template import AffordanceTemplate, Joint, Symmetry
from .errors import TemplateError
from .meshes import PRIMITIVES, mesh_distance, primitive_mesh
from .template_files import load_template

__all__ = [
    "Symmetry",
    "Joint",
    "AffordanceTemplate",
    "TemplateLibrary",
    "default_models_dir",
    "load_template",
    "PRIMITIVES",
    "primitive_mesh",
    "mesh_distance",
]


def default_models_dir() -> str:
    """The package's own template library: the source tree's models/ (editable install or
    checkout), else ``share/affordance_registration/models`` of the install prefix."""
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    candidates = [os.path.join(here, "models")]
    try:  # colcon / ament install
        from ament_index_python.packages import get_package_share_directory

        candidates.append(
            os.path.join(get_package_share_directory("affordance_registration"), "models")
        )
    except Exception:
        pass
    import sys

    candidates.append(os.path.join(sys.prefix, "share", "affordance_registration", "models"))
    for c in candidates:
        if os.path.isdir(c) and any(f.endswith(".yaml") for f in os.listdir(c)):
            return c
    raise TemplateError(
        "the package's models/ directory was not found; pass a templates directory explicitly"
    )


class TemplateLibrary(Mapping):
    """An ordered, read-only name -> :class:`AffordanceTemplate` mapping."""

    def __init__(self, templates=()):
        self._templates: dict[str, AffordanceTemplate] = {}
        for t in templates:
            if t.name in self._templates:
                raise TemplateError(
                    f"{t.path}: key 'name': duplicate template name '{t.name}' "
                    f"(also in {self._templates[t.name].path})"
                )
            self._templates[t.name] = t

    @classmethod
    def load(cls, source: str | None = None) -> "TemplateLibrary":
        """Load a directory of ``*.yaml`` templates, or one YAML file. ``None`` loads the
        package's own models. An empty directory is an error."""
        source = default_models_dir() if source is None else str(source)
        if os.path.isdir(source):
            files = sorted(
                os.path.join(source, f)
                for f in os.listdir(source)
                if f.endswith((".yaml", ".yml")) and not f.startswith(".")
            )
            if not files:
                raise TemplateError(f"{source}: no template files (*.yaml) in this directory")
        elif os.path.isfile(source):
            files = [source]
        else:
            raise TemplateError(f"{source}: no such template file or directory")
        return cls(load_template(f) for f in files)

    def __getitem__(self, name: str) -> AffordanceTemplate:
        try:
            return self._templates[name]
        except KeyError:
            raise KeyError(
                f"no template named '{name}' (have: {', '.join(self._templates)})"
            ) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._templates)

    def __len__(self) -> int:
        return len(self._templates)

    @property
    def max_diameter(self) -> float:
        """The largest template's diameter (m): it sets the crop around a click. Primitives
        count only in a library of primitives alone (their size is what a fit finds)."""
        specific = [t for t in self._templates.values() if t.primitive is None]
        return max(t.diameter for t in (specific or self._templates.values()))

    def specific(self) -> "TemplateLibrary":
        """The library less its primitives."""
        return TemplateLibrary(t for t in self._templates.values() if t.primitive is None)
