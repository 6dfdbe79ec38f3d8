# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine's state as immutable records: an object of interest and its ranked candidates
(:class:`TrackedObject`), an accepted object (:class:`Registration`) and the whole state
(:class:`EngineState`) that every action swaps and undo restores. Pure Python (no ROS)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .labels import margin_text
from .registration import FitResult, describe_primitive, no_match, verdict
from .scene import ClickContext
from .transforms import matrix_to_quat_xyzw

__all__ = ["TrackedObject", "Registration", "EngineState"]


@dataclass(frozen=True)
class TrackedObject:
    """An object of interest: a click and its ranked candidates (one per template)."""

    id: int
    click: np.ndarray = field(repr=False)
    candidates: tuple  #: FitResult, best first
    active: int = 0  #: index of the shown candidate
    refined: frozenset = frozenset()  #: candidate indices refined at full resolution
    corrections: int = 0  #: correction bursts applied by the operator
    model_changes: int = 0  #: next/previous presses
    context: ClickContext | None = field(default=None, repr=False, compare=False)
    scene_version: int = 0
    fit_s: float = 0.0  #: time the click's fit took
    #: whether the click's answer is settled (registration.ambiguity.Ambiguity; None: unknown)
    ambiguity: object = field(default=None, repr=False, compare=False)
    #: where the sensor should look from to settle it (registration.viewpoint.SuggestedView)
    suggested_view: object = field(default=None, repr=False, compare=False)

    @property
    def shown(self) -> FitResult:
        return self.candidates[self.active]

    def with_candidate(self, index: int, candidate: FitResult, **changes) -> "TrackedObject":
        """The object with candidate ``index`` replaced by ``candidate`` (and ``changes`` made to
        its other fields)."""
        cands = self.candidates[:index] + (candidate,) + self.candidates[index + 1 :]
        return replace(self, candidates=cands, **changes)

    def with_shown(self, candidate: FitResult, **changes) -> "TrackedObject":
        """The object with its shown candidate replaced by ``candidate`` (see
        :meth:`with_candidate`)."""
        return self.with_candidate(self.active, candidate, **changes)

    @property
    def shown_is_the_answer(self) -> bool:
        """The shown candidate is the verdict's own answer where no specific template fits: the
        primitive that fits there."""
        return self.shown.primitive is not None and bool(self.shown.fits)

    @property
    def override(self) -> bool:
        """Accepting the shown candidate goes against the verdict: it does not fit (``fits``
        false), or the verdict is "no template fits here" and it is not the primitive that fits
        there."""
        return self.shown.fits is False or (self.no_match and not self.shown_is_the_answer)

    def to_dict(self, active_id) -> dict:
        """The object in the engine's status (``active``: it is the selected one)."""
        return {
            "id": self.id,
            "active": self.id == active_id,
            "shown": self.active,
            "click": [round(float(v), 6) for v in self.click],
            "corrections": self.corrections,
            "model_changes": self.model_changes,
            "no_match": self.no_match,
            "verdict": verdict(self.candidates),
            "reason": self.candidates[0].reason if self.candidates else None,
            "candidates": [c.to_dict() for c in self.candidates],
            "ambiguity": None if self.ambiguity is None else self.ambiguity.to_dict(),
            "suggested_view": None
            if self.suggested_view is None
            else self.suggested_view.to_dict(),
        }

    @property
    def no_match(self) -> bool:
        """The absolute verdict: no specific template fits here -- the best candidate is
        refused (``FitResult.fits`` false, its ``reason`` says why) or is a primitive (the
        candidates are still listed)."""
        return no_match(self.candidates)

    def describe(self) -> str:
        """One line on the shown candidate: the verdict, template, state, scale, rank, its
        margin over the runner-up (or against the best) and coverage."""
        c = self.shown
        extra = f" — {c.state}" if c.state else ""
        if c.scale != 1.0:
            extra += f" — scale {c.scale:.2f}"
        if c.primitive is not None:
            extra += f" — {describe_primitive(c)}"
        best = self.candidates[0]
        said = verdict(self.candidates)
        why = f" ({best.reason})" if best.reason else ""
        said = f"{said}{why}; showing " if self.no_match else ""
        # how far it leads, as the station and the markers say it (core.labels): the
        # probability is shared with every template and "no template fits here", so a right
        # fit reads 0.3-0.4 -- a number that reads as doubt
        margin = margin_text([k.probability for k in self.candidates], self.active)
        doubt = (
            f" — {self.ambiguity.describe()}"
            if self.ambiguity is not None and not self.ambiguity.settled
            else ""
        )
        return (
            f"{said}{c.template}{extra} — rank {self.active + 1}/{len(self.candidates)}"
            f"{' — ' + margin if margin else ''} — coverage {c.coverage:.2f}{doubt}"
        )


@dataclass(frozen=True)
class Registration:
    """An accepted object."""

    id: int
    template: str
    T_scene_model: np.ndarray = field(repr=False)
    likelihood: float
    probability: float
    residual: float
    click: np.ndarray = field(repr=False)
    frame_id: str = ""
    joints: dict = field(default_factory=dict)  #: joint name -> value (rad or m)
    state: str | None = None  #: the nearest named state
    scale: float = 1.0  #: uniform scale of the template
    primitive: str | None = None  #: "box" / "cylinder" for a primitive
    dimensions: dict = field(default_factory=dict)  #: a primitive's dimensions (m)
    ranked_first: str = ""  #: the template the fit ranked first
    model_changes: int = 0  #: next/previous presses before accepting
    corrections: int = 0  #: correction bursts before accepting
    fit_s: float = 0.0  #: time the click's fit took
    #: accepted against the verdict (an operator override): the accepted candidate does not
    #: fit (``fits`` false), or the object's verdict was "no template fits here" and it is not
    #: the primitive that fits there
    override: bool = False

    @classmethod
    def of(cls, obj: TrackedObject, frame_id: str) -> "Registration":
        """The registration of ``obj``'s shown candidate."""
        c = obj.shown
        return cls(
            id=obj.id,
            template=c.template,
            T_scene_model=c.T_scene_model,
            likelihood=c.likelihood,
            probability=c.probability,
            residual=c.residual,
            click=obj.click,
            frame_id=frame_id,
            joints=dict(c.joints),
            state=c.state,
            scale=c.scale,
            primitive=c.primitive,
            dimensions=dict(c.dimensions),
            ranked_first=obj.candidates[0].template,
            model_changes=obj.model_changes,
            corrections=obj.corrections,
            fit_s=obj.fit_s,
            override=obj.override,
        )

    def to_dict(self) -> dict:
        T = self.T_scene_model
        return {
            "id": self.id,
            "template": self.template,
            "frame_id": self.frame_id,
            "pose": [[round(float(v), 9) for v in row] for row in T],
            "position": [round(float(v), 9) for v in T[:3, 3]],
            "orientation_xyzw": [round(float(v), 9) for v in matrix_to_quat_xyzw(T[:3, :3])],
            "likelihood": round(float(self.likelihood), 6),
            "probability": round(float(self.probability), 6),
            "residual": round(float(self.residual), 9),
            "click": [round(float(v), 6) for v in self.click],
            "joints": {k: round(float(v), 6) for k, v in self.joints.items()},
            "state": self.state,
            "scale": round(float(self.scale), 6),
            "primitive": self.primitive,
            "dimensions": {k: round(float(v), 6) for k, v in self.dimensions.items()}
            if self.primitive
            else None,
            "ranked_first": self.ranked_first,
            "model_changes": self.model_changes,
            "corrections": self.corrections,
            "fit_s": round(float(self.fit_s), 6),
            "override": self.override,
        }


@dataclass(frozen=True)
class EngineState:
    objects: tuple = ()  #: TrackedObject, objects of interest not yet accepted
    active_id: int | None = None  #: the selected object of interest
    registered: tuple = ()  #: Registration
    next_id: int = 1

    def fit_of(self, object_id: int):
        """The registration ``object_id``, else the shown candidate (a FitResult) of the open
        object ``object_id``, else None."""
        for reg in self.registered:
            if reg.id == object_id:
                return reg
        return next((o.shown for o in self.objects if o.id == object_id), None)
