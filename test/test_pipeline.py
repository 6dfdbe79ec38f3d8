# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The fit as a pipeline: the recipe's stages pass one frozen state on, none changes the state it
is given, run one by one they give what ``Registrar.fit`` gives, and each adds its own time to
the report."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from affordance_registration.core.registration import FitSettings, Registrar
from affordance_registration.core.registration.registrar import METHODS, default, fit_click
from affordance_registration.core.registration.stages import (
    articulate,
    assess,
    coarse,
    finish,
    hypothesise,
    judge,
    medium,
    prefilter,
    prepare,
    primitives,
    rank,
)
from affordance_registration.core.registration.state import FitState
from affordance_registration.core.scene import Scene

METHOD_STAGES = ("hypothesise", "coarse", "prefilter", "medium", "rank", "articulate", "finish")


def _same(a, b) -> bool:
    return [(c.template, c.residual, c.T_scene_model.tolist()) for c in a] == [
        (c.template, c.residual, c.T_scene_model.tolist()) for c in b
    ]


def _arrays(state: FitState) -> list:
    """Copies of the arrays a state holds (a stage must not change them in place)."""
    hyps = state.hyps
    out = [] if hyps is None else [hyps.R.copy(), hyps.t.copy(), hyps.index.copy()]
    return out + ([] if state.scores is None else [state.scores.copy()])


def test_the_stages_one_by_one_give_the_fit_and_leave_each_state_as_it_was(library, panel_scene):
    """Each stage returns a new state (the frozen one it was given is as it was: its fields the
    same objects, their arrays unchanged); the stages run by hand in the recipe's order give
    ``Registrar.fit``'s candidates, exactly."""
    reg = Registrar(library)
    scene, click = Scene(panel_scene.organized), panel_scene.objects[0].click
    state = FitState.start(reg.services, scene, click, list(library))
    assert state.specific and state.primitives  # the library has both kinds
    with pytest.raises(dataclasses.FrozenInstanceError):
        state.candidates = ()
    steps = [prepare.run, hypothesise.run]
    steps += (
        [coarse.first_look, prefilter.run, coarse.rest] if coarse.pause(state) else [coarse.run]
    )
    steps += [prefilter.run, medium.run, rank.run, articulate.run, finish.run, judge.run]
    steps += [primitives.run, assess.run]
    for step in steps:
        before = {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}
        arrays = _arrays(state)
        after = step(state)
        assert after is not state  # (each had something to do here)
        assert all(getattr(state, name) is value for name, value in before.items()), step
        assert all(np.array_equal(a, b) for a, b in zip(arrays, _arrays(state))), step
        assert after.timing[: len(state.timing)] == state.timing  # one entry more, its own
        assert len(after.timing) == len(state.timing) + 1 and after.timing[-1][1] >= 0.0
        state = after
    report = reg.fit(scene, click)
    assert _same(state.candidates, report.candidates)
    assert state.ambiguity.to_dict() == report.ambiguity.to_dict()
    again = fit_click(FitState.start(reg.services, scene, click, list(library)))
    assert _same(again.candidates, report.candidates)


def test_each_stage_adds_its_own_time_to_the_report(library, panel_scene):
    """``timing_s`` keeps prepare, fit, total, ambiguity (and primitives where the library has
    them) and adds the time of each stage that ran under its name (rigid: no articulate): fit
    is the stages' between the crop and the ambiguity, total the whole click: the crop's, the
    fit's and the ambiguity's."""
    scene = Scene(panel_scene.organized)
    click = panel_scene.objects[0].click
    for lib, settings in ((library, None), (library.specific(), FitSettings(articulated=False))):
        timing = Registrar(lib, settings).fit(scene, click).timing_s
        stages = {k: v for k, v in timing.items() if k in METHOD_STAGES + ("judge", "primitives")}
        wanted = set(METHOD_STAGES) | {"judge"} | ({"primitives"} if lib is library else set())
        assert set(stages) == wanted - ({"articulate"} if settings else set())
        assert all(v >= 0.0 for v in timing.values())
        assert timing["fit"] == pytest.approx(sum(stages.values()), abs=1e-9)
        assert timing["total"] == pytest.approx(
            timing["prepare"] + timing["fit"] + timing["ambiguity"], abs=1e-9
        )
        assert timing["ambiguity"] > 0.0
        assert {"prepare", "ambiguity"} <= set(timing) and "assess" not in timing


def test_the_method_setting_picks_a_recipe(library, panel_scene):
    """Every method ``FitSettings.method`` accepts is an entry of ``METHODS``; the paper's is
    one stage in the default's place (its own time, no default stage's)."""
    rule = next(f for f in dataclasses.fields(FitSettings) if f.name == "method").metadata["rule"]
    assert set(METHODS) == set(rule) and METHODS["default"] is default
    reg = Registrar(library.specific(), FitSettings(method="paper", paper_restarts=2))
    timing = reg.fit(Scene(panel_scene.organized), panel_scene.objects[0].click).timing_s
    assert "paper" in timing and not set(METHOD_STAGES) & set(timing)
    assert timing["fit"] == pytest.approx(timing["paper"], abs=1e-9)
    assert np.isfinite(timing["total"])
