# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What one click's fit knows between two stages (:class:`FitState`) and what makes a function a
stage (:func:`stage`).

A stage takes the state and returns the next one (``dataclasses.replace``); none changes the
state it was given, so a stage can be read, run and tested alone. :func:`stage` adds each
stage's time to the state (``FitState.timing``), and :meth:`FitState.report` turns the last
state into the :class:`~.results.FitReport` the registrar returns.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace
from types import MappingProxyType

import numpy as np

from ..click_context import ClickContext
from ..scene import Scene
from .hypotheses import Hypotheses
from .results import FitReport
from .services import Services
from .settings import FitSettings

__all__ = ["FitState", "stage", "AMBIGUITY"]

#: the stage whose time ``FitReport.timing_s`` reports as "ambiguity" (it is not the fit's)
AMBIGUITY = "assess"


@dataclass(frozen=True, eq=False)
class FitState:
    """One click's fit between two stages. Set at the start: the services, the ``scene``, the
    ``click`` as given, the templates to fit (``specific``) and the primitives to measure
    (``primitives``, names); each stage fills in what it makes."""

    services: Services = field(repr=False)
    scene: Scene = field(repr=False)
    click: np.ndarray
    specific: tuple
    primitives: tuple = ()
    #: the crop around the click (prepare)
    ctx: ClickContext | None = field(default=None, repr=False)
    #: the hypotheses the ICP stages advance (hypothesise, coarse, medium) ...
    hyps: Hypotheses | None = field(default=None, repr=False)
    #: ... and their scores after the last of them (lower is better; coarse, prefilter)
    scores: np.ndarray | None = field(default=None, repr=False)
    #: the candidates the library prefilter set aside (their coarse poses)
    set_aside: tuple = ()
    #: the candidates, ranked best first (rank on)
    candidates: tuple = ()
    #: every medium-stage hypothesis's result: the second poses the ambiguity reads
    alternatives: tuple = field(default=(), repr=False)
    #: template -> the articulated model a leader was fitted as (articulate, finish)
    articulated: MappingProxyType = field(default_factory=lambda: MappingProxyType({}), repr=False)
    #: whether the answer is settled (assess)
    ambiguity: object = None
    #: (stage, seconds) in the order the stages ran
    timing: tuple = ()

    @staticmethod
    def start(services: Services, scene: Scene, click, names) -> "FitState":
        """The state before the first stage: ``names`` split into the templates to fit and
        the primitives to measure (each must be in the library)."""
        library = services.library
        return FitState(
            services,
            scene,
            click,
            tuple(n for n in names if library[n].primitive is None),
            tuple(n for n in names if library[n].primitive is not None),
        )

    @property
    def settings(self) -> FitSettings:
        return self.services.settings

    def timed(self, name: str, seconds: float) -> "FitState":
        """This state with ``seconds`` more spent in stage ``name``."""
        return replace(self, timing=self.timing + ((name, float(seconds)),))

    def seconds(self) -> dict:
        """Stage -> the seconds spent in it so far (a stage run twice: both runs)."""
        out: dict = {}
        for name, s in self.timing:
            out[name] = out.get(name, 0.0) + s
        return out

    def fit_seconds(self) -> float:
        """The seconds spent fitting so far: every stage's but the crop's and the
        ambiguity's."""
        return sum(s for name, s in self.timing if name not in ("prepare", AMBIGUITY))

    def report(self) -> FitReport:
        """The :class:`~.results.FitReport` of the click. Its ``timing_s``: ``prepare``,
        ``fit`` (every stage after it but the ambiguity: the templates, their verdict, the
        primitives), ``ambiguity`` (whether the answer is settled), ``total`` (the three: the
        whole click), ``primitives`` where primitives were measured, and every other stage that
        ran its own time under its name."""
        seconds = self.seconds()
        ambiguity = seconds.pop(AMBIGUITY, 0.0)
        prepare = seconds.pop("prepare", 0.0)
        fit = self.fit_seconds()
        timing = {
            "prepare": prepare,
            "fit": fit,
            "total": prepare + fit + ambiguity,
            "ambiguity": ambiguity,
        }
        if "primitives" in seconds:
            timing["primitives"] = seconds.pop("primitives")
        timing.update(seconds)
        return FitReport(
            point=self.ctx.click,
            candidates=self.candidates,
            timing_s=timing,
            context=self.ctx,
            alternatives=self.alternatives,
            ambiguity=self.ambiguity,
        )


def stage(name: str):
    """Make ``fn(state, ...) -> state`` a stage named ``name``: its time is added to the state
    it returns (:meth:`FitState.timed`) -- unless it returns the state it was given (it had
    nothing to do: no primitives to measure, no joint to estimate)."""

    def decorate(fn):
        @functools.wraps(fn)
        def timed(state: FitState, *args, **kwargs) -> FitState:
            t0 = time.perf_counter()
            out = fn(state, *args, **kwargs)
            return out if out is state else out.timed(name, time.perf_counter() - t0)

        timed.stage = name
        return timed

    return decorate
