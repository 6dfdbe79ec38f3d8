# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Articulated and scaled templates: joint values, named states and scale estimated with the pose
on simulated depth scans with ground truth."""

import math

import numpy as np
import pytest

from affordance_registration.core.registration import FitSettings, Registrar
from affordance_registration.core.scene import Scene
from affordance_registration.core.templates import TemplateLibrary
from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import (
    DepthCamera,
    NoiseModel,
    simulate_taskboard,
)

DEG5 = math.radians(5.0)


@pytest.fixture(scope="module")
def library():
    return TemplateLibrary.load()


@pytest.fixture(scope="module")
def registrar(library):
    return Registrar(library)


def _fit(registrar, sim, name):
    obj = next(o for o in sim.objects if o.template == name)
    assert obj.visible_points >= 200, "the scene must show the object"
    return obj, registrar.fit(Scene(sim.organized), obj.click).candidates[0]


@pytest.mark.parametrize("noisy", [False, True], ids=["exact", "noisy"])
def test_joint_values_recovered_on_exact_and_noisy_scans(library, registrar, noisy):
    """A lever valve nearly closed, a plug valve a third open, an e-stop pressed and a gate
    valve open: each comes back first, with its joint value within 5 deg / 2 mm, the right
    state and its position within 5 mm."""
    camera = DepthCamera(noise=None if noisy else NoiseModel(a=0.0, b=0.0, c=0.0))
    chosen = {
        "ball_valve": {"lever": 1.35},
        "quarter_turn_valve": {"handle": 0.5},
        "emergency_stop": {"button": 0.008},
        "gate_valve": {"stem": 0.03},
    }
    sim = simulate_taskboard(library, 3101, articulated=True, camera=camera, joints=chosen)
    for name, values in chosen.items():
        obj, best = _fit(registrar, sim, name)
        assert best.template == name
        ((jname, q_true),) = values.items()
        joint = library[name].joints[0]
        tol = DEG5 if joint.type == "revolute" else 0.002
        assert abs(best.joints[jname] - q_true) <= tol, (name, best.joints, q_true)
        assert best.state == obj.state
        dt, _ = pose_error(best.T_scene_model, obj.T_scene_model, library[name].symmetry)
        assert dt <= 0.005, (name, dt)


def test_half_open_valve_is_reported_between_its_states(library, registrar):
    sim = simulate_taskboard(
        library, 3102, articulated=True, joints={"ball_valve": {"lever": math.pi / 4}}
    )
    _, best = _fit(registrar, sim, "ball_valve")
    q = best.joints["lever"]
    assert abs(q - math.pi / 4) <= DEG5
    open_q, closed_q = (library["ball_valve"].states[s]["lever"] for s in ("open", "closed"))
    assert open_q + math.radians(30) < q < closed_q - math.radians(30)
    assert best.state in ("open", "closed")  # the nearest named state is still given


@pytest.mark.parametrize("scale", [0.85, 1.18])
def test_scale_recovered_within_3_percent(library, scale):
    """A grab handle allowed to come in sizes (scale: [0.8, 1.25], as the bench's variant)."""
    from affordance_registration.evaluation.simulation import sized_library

    sized = sized_library(library)
    assert sized["grab_handle"].scale_range == (0.8, 1.25)
    sim = simulate_taskboard(sized, 3103, articulated=True, scales={"grab_handle": scale})
    obj, best = _fit(Registrar(sized), sim, "grab_handle")
    assert best.template == "grab_handle"
    assert abs(best.scale / scale - 1.0) <= 0.03, best.scale
    assert obj.scale == scale


def test_rigid_settings_claim_no_joint_values(library):
    sim = simulate_taskboard(
        library, 3101, articulated=True, joints={"ball_valve": {"lever": 1.35}}
    )
    _, best = _fit(Registrar(library, FitSettings(articulated=False)), sim, "ball_valve")
    assert best.joints == {} and best.state is None and best.scale == 1.0


def test_refit_holds_a_joint_value_set_by_the_operator(library, registrar):
    sim = simulate_taskboard(
        library, 3102, articulated=True, joints={"ball_valve": {"lever": math.pi / 4}}
    )
    obj = next(o for o in sim.objects if o.template == "ball_valve")
    ctx = registrar.prepare(Scene(sim.organized), obj.click)
    held = registrar.refit(ctx, "ball_valve", obj.T_scene_model, {"lever": 1.0}, hold_joint=True)
    assert held.joints == {"lever": 1.0}
    kept = registrar.refit(ctx, "ball_valve", obj.T_scene_model, {"lever": 1.0})
    assert kept.joints == {"lever": 1.0}  # a refit of the pose keeps a given joint
    free = registrar.refit(ctx, "ball_valve", obj.T_scene_model, {"lever": 1.0}, hold_joint=False)
    assert abs(free.joints["lever"] - math.pi / 4) < abs(1.0 - math.pi / 4)


@pytest.mark.parametrize(
    "name,q", [("ball_valve", 0.7), ("gate_valve", 0.012), ("emergency_stop", 0.005)]
)
def test_joint_frame_round_trip(library, name, q):
    tpl = library[name]
    for scale in (1.0, 1.2):
        T = tpl.joint_frame(q, scale)
        assert np.allclose(T[:3, 0], tpl.joints[0].axis)  # x along the joint axis
        assert tpl.joint_value_from_frame(T, scale) == pytest.approx(q, abs=1e-9)
    # beyond the limits, clamped
    j = tpl.joints[0]
    assert tpl.joint_value_from_frame(
        tpl.joint_frame(j.upper + 0.5 * (j.upper - j.lower))
    ) == pytest.approx(j.upper)


def test_engine_joint_nudge_refits_and_undoes_in_one_step(library, tmp_path):
    """A lever valve fitted at 45 deg; the operator nudges the lever twice (+5 deg each): the
    shown candidate's joint follows exactly, the pose is refitted with it held, the state is the
    nearest named one, each nudge is one correction and one undo step; accepted and saved, the
    registration keeps joint, state and scale."""
    from affordance_registration.core.engine import AffordanceEngine, load_registrations
    from affordance_registration.core.errors import EngineStateError

    sim = simulate_taskboard(
        library, 3102, articulated=True, joints={"ball_valve": {"lever": math.pi / 4}}
    )
    obj = next(o for o in sim.objects if o.template == "ball_valve")
    engine = AffordanceEngine(library)
    engine.set_scene(sim.organized, frame_id="cam")
    engine.click(obj.click)
    fitted = engine.active_object().shown
    assert fitted.template == "ball_valve"
    q0 = fitted.joints["lever"]
    before = engine.state
    msg = engine.correct_joint(steps=1)
    assert "lever" in msg and "refit" in msg
    shown = engine.active_object().shown
    assert shown.joints["lever"] == pytest.approx(q0 + math.radians(5.0))
    assert engine.active_object().corrections == 1
    assert shown.state == library["ball_valve"].nearest_state(shown.joints)
    dt, _ = pose_error(shown.T_scene_model, obj.T_scene_model, None)
    assert dt <= 0.01  # the refit kept the valve where it is
    engine.correct_joint(steps=1)
    assert engine.active_object().shown.joints["lever"] == pytest.approx(q0 + math.radians(10.0))
    engine.undo()
    assert engine.active_object().shown.joints["lever"] == pytest.approx(q0 + math.radians(5.0))
    engine.undo()
    assert engine.state is before
    engine.correct_joint(value=99.0, refit=False)  # clamped to the limits
    assert engine.active_object().shown.joints["lever"] == pytest.approx(math.pi / 2)
    assert engine.active_object().shown.state == "closed"
    engine.accept()
    reg = engine.state.registered[-1]
    assert reg.joints == {"lever": pytest.approx(math.pi / 2)} and reg.state == "closed"
    engine.save(str(tmp_path / "regs.yaml"))
    loaded = load_registrations(str(tmp_path / "regs.yaml"), library)[-1]
    assert loaded.joints["lever"] == pytest.approx(math.pi / 2, abs=1e-6)
    assert loaded.state == "closed" and loaded.scale == 1.0
    # a template without a joint: a clear refusal
    handle = next(o for o in sim.objects if o.template == "grab_handle")
    engine.click(handle.click)
    assert engine.active_object().shown.template == "grab_handle"
    with pytest.raises(EngineStateError, match="no joint"):
        engine.correct_joint(steps=1)


def test_objects_in_their_named_states_and_nominal_size_are_reported_there(library):
    """Valves open or closed, an e-stop released and a grab handle of nominal size (in a
    library that allows sizes): the joint values the data cannot tell from a named state are
    reported at them, and the poses stay within 5 mm and 5 deg -- the extra unknowns cost no
    rigid accuracy. (The plug valve's body also fits a quarter turn off with its handle turned
    back; the winner's sweep about its axis tries the named states too. Its scale: below.)"""
    from affordance_registration.evaluation.simulation import sized_library

    sized = sized_library(library)
    chosen = {
        "ball_valve": {"lever": 0.0},
        "quarter_turn_valve": {"handle": 0.0},
        "gate_valve": {"stem": 0.0},
        "emergency_stop": {"button": 0.0},
    }
    # on this scene the free fit puts the plug valve's handle 1.7 deg off its stop (with the
    # whole valve turned to match); the preference for its named state puts it back
    sim = simulate_taskboard(
        sized, 3105, articulated=True, joints=chosen, scales={"grab_handle": 1.0}
    )
    registrar = Registrar(sized)
    for obj in sim.objects:
        _, best = _fit(registrar, sim, obj.template)
        assert best.template == obj.template
        dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, sized[obj.template].symmetry)
        assert dt <= 0.005 and dr <= DEG5, (obj.template, dt, math.degrees(dr))
        for jname, q in chosen.get(obj.template, {}).items():
            assert best.joints[jname] == pytest.approx(q, abs=1e-6), (obj.template, best.joints)
            assert best.state == obj.state


def test_a_nominal_size_handle_is_reported_at_scale_one(library):
    """A grab handle of nominal size (scene 3105) is reported at scale 1. The free fit lands
    at 0.966, 3.5 mm off, with a lower residual than scale 1 at the truth: samples the sensor
    sees at grazing angles (it returns nothing from ~70-85 deg) count against the larger
    size. Occam's razor judges scale 1 with those samples unseen
    (``articulation.scale_grazing_angle``)."""
    from affordance_registration.evaluation.simulation import sized_library

    sized = sized_library(library)
    chosen = {
        "ball_valve": {"lever": 0.0},
        "quarter_turn_valve": {"handle": 0.0},
        "gate_valve": {"stem": 0.0},
        "emergency_stop": {"button": 0.0},
    }
    sim = simulate_taskboard(
        sized, 3105, articulated=True, joints=chosen, scales={"grab_handle": 1.0}
    )
    handle = next(o for o in sim.objects if o.template == "grab_handle")
    assert handle.scale == 1.0
    assert _fit(Registrar(sized), sim, "grab_handle")[1].scale == pytest.approx(1.0)


def test_a_mounted_object_keeps_touching_its_panel(library):
    """A grab handle 17% over nominal size: scale and distance trade off along the line of
    sight unless the handle stays on the panel it is mounted on (the fit's contact with the
    plane under the click). With the contact it is right; without it its base (the mount's
    origin) stands more than twice as far off the panel."""
    from affordance_registration.evaluation.simulation import sized_library

    sized = sized_library(library)
    sim = simulate_taskboard(sized, 502, articulated=True)
    obj, best = _fit(Registrar(sized), sim, "grab_handle")
    assert obj.scale == pytest.approx(1.167, abs=0.001)
    assert best.template == "grab_handle"
    assert abs(best.scale / obj.scale - 1.0) <= 0.03, best.scale
    dt, _ = pose_error(best.T_scene_model, obj.T_scene_model, sized["grab_handle"].symmetry)
    assert dt <= 0.005
    # the contact decides it where the handle's own fit is traded along the line of sight:
    # fitted alone, with contact 1% off in scale, its base 0.8 mm from the panel; without,
    # 2.3% off, its base 2.1 mm off the panel and tilted 2.6 deg (5.7% and 5.2 mm before
    # hypotheses were told apart by where they put the centroid)
    alone = Scene(sim.organized)
    with_contact = Registrar(sized).fit(alone, obj.click, templates=["grab_handle"])
    no_contact = FitSettings().with_(**{"articulation.contact_distance": 1e-9})
    free = Registrar(sized, no_contact).fit(alone, obj.click, templates=["grab_handle"])
    assert abs(with_contact.candidates[0].scale / obj.scale - 1.0) <= 0.03
    panel = Registrar(sized).prepare(alone, obj.click).plane
    base = sized["grab_handle"].mount[:3, 3]

    def off_panel(fit):
        T = fit.T_scene_model
        return abs(float(panel.distance((T[:3, :3] @ (fit.scale * base) + T[:3, 3])[None])[0]))

    on, off = off_panel(with_contact.candidates[0]), off_panel(free.candidates[0])
    assert off > 2 * on, (on, off)


def test_a_much_bigger_handle_is_found_from_hypotheses_at_the_range_ends(library):
    """A grab handle at 1.24x: the nominal-size template alone lands on one end of it (48 mm
    off, turned 25 deg), from which no scale step recovers; hypotheses at the ends of the
    scale range from the start find it."""
    from affordance_registration.evaluation.simulation import sized_library

    sized = sized_library(library)
    sim = simulate_taskboard(sized, 522, articulated=True)
    obj, best = _fit(Registrar(sized), sim, "grab_handle")
    assert obj.scale == pytest.approx(1.244, abs=0.001)
    assert best.template == "grab_handle"
    assert abs(best.scale / obj.scale - 1.0) <= 0.03, best.scale
    dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, sized["grab_handle"].symmetry)
    assert dt <= 0.005 and dr <= DEG5, (dt, math.degrees(dr))


def test_an_open_gate_valve_is_found_from_hypotheses_at_the_far_end_of_its_stem():
    """Held-out articulated board 3011 with the whole library (primitives too): its gate valve's
    stem is out 30 mm. Fitted closed, the body tilted 55 deg to reach the wheel and a cylinder
    that does not fit ranked first; hypotheses with the stem out find it, first, fitting, with
    the stem within 2 mm and the pose within 5 mm / 5 deg."""
    from affordance_registration.evaluation.simulation import sized_library

    sized = sized_library(TemplateLibrary.load())
    sim = simulate_taskboard(sized.specific(), 3011, articulated=True)
    obj, best = _fit(Registrar(sized), sim, "gate_valve")
    assert obj.joints == {"stem": pytest.approx(0.03)}
    assert best.template == "gate_valve" and best.fits, (best.template, best.reason)
    assert abs(best.joints["stem"] - 0.03) <= 0.002, best.joints
    dt, dr = pose_error(best.T_scene_model, obj.T_scene_model, sized["gate_valve"].symmetry)
    assert dt <= 0.005 and dr <= DEG5, (dt, math.degrees(dr))
