# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ordered stream of operator input (core/operator.py) on the real engine, in simulated time:
inputs queued while a (slow) fit runs are handled in arrival order, twists are integrated over
their own time stamps, the idle refit waits for the twists to stop, a refit still waiting runs
before anything that leaves the object, Joy buttons act on edges and the joint axis has
hysteresis. No ROS."""

import math
import os
import tempfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from affordance_registration.core.corrections import R_VIEW_SPACENAV
from affordance_registration.core.engine import AffordanceEngine
from affordance_registration.core.errors import AffordanceError
from affordance_registration.core.operator import OperatorSettings, OperatorStream, Outbox
from affordance_registration.core.persistence import Autosave, RegistrationStore
from affordance_registration.core.transforms import pose_error
from affordance_registration.evaluation.simulation import simulate_taskboard

TOL_M, TOL_RAD = 0.005, math.radians(5)
FRAME = "camera_depth_optical_frame"


class SimClock:
    """Simulated time: ``sleep`` advances it."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t

    def sleep(self, seconds):
        self.t += seconds


class Recorder(Outbox):
    """An outbox without a node that keeps every outcome the stream puts into it."""

    def __init__(self):
        super().__init__()
        self.reports = []
        self.benign = []  # whether each was a refusal because the action did not apply

    def outcome(self, kind, ok, message, benign=False):
        self.reports.append((kind, ok, message))
        self.benign.append(benign)
        super().outcome(kind, ok, message, benign)


class SlowEngine(AffordanceEngine):
    """The engine with a fitter that takes ``delay`` more (simulated) seconds for every click."""

    def __init__(self, library, clock, delay):
        super().__init__(library)
        self._clock, self._delay = clock, delay

    def click(self, *args, **kwargs):
        self._clock.sleep(self._delay)
        return super().click(*args, **kwargs)


class Stream:
    """An engine on a scene and its operator stream in simulated time, recording outcomes (with
    ``slow_fit_s``, every click's fit takes that much longer)."""

    def __init__(self, library, sim, slow_fit_s=0.0, **settings):
        self.clock = SimClock()
        self.engine = (
            SlowEngine(library, self.clock, slow_fit_s)
            if slow_fit_s
            else AffordanceEngine(library)
        )
        self.engine.set_scene(sim.organized, frame_id=FRAME)
        self.outbox = Recorder()
        self.reports = self.outbox.reports
        # its own registrations file (locked while in use): not one in the working folder
        folder = tempfile.mkdtemp(prefix="ar_stream_")
        self.stream = OperatorStream(
            self.engine,
            OperatorSettings(**settings),
            self.clock,
            self.clock.sleep,
            outbox=self.outbox,
            saver=Autosave(RegistrationStore(os.path.join(folder, "r.yaml")), enabled=False),
        )

    def shown(self):
        obj = self.engine.active_object()
        return obj.shown if obj is not None else None


@pytest.fixture(scope="module")
def scene(library):
    return simulate_taskboard(library, 7)


def view_twist(view_linear, view_angular=(0.0, 0.0, 0.0)):
    """spacenav/twist axes of a view-frame push (unit gains)."""
    return R_VIEW_SPACENAV.T @ np.asarray(view_linear, float), R_VIEW_SPACENAV.T @ np.asarray(
        view_angular, float
    )


def test_an_action_during_a_slow_fit_acts_on_that_clicks_object(library, scene):
    """Click A and accept it; then click B with a 5 s fitter and press accept and next model
    while B's fit runs: both act on B, whatever the fit took."""
    s = Stream(library, scene, slow_fit_s=5.0)
    a, b = scene.objects[0], scene.objects[2]
    replies = []
    s.stream.click(a.click)
    s.stream.action("accept", reply=lambda ok, m: replies.append((ok, m)))
    s.stream.click(b.click)
    s.stream.action("next_model", reply=lambda ok, m: replies.append((ok, m)))
    s.stream.action("accept", reply=lambda ok, m: replies.append((ok, m)))
    t0 = s.clock()
    assert s.stream.status()["queued"] == 5
    assert s.stream.process_pending() == 5
    assert s.clock() - t0 == pytest.approx(10.0)  # two slow fits
    regs = s.engine.state.registered
    assert [r.template for r in regs] == [a.template, regs[1].template]
    assert regs[1].ranked_first == b.template  # B's fit, shown at rank 2, accepted
    assert regs[1].template != b.template and regs[1].model_changes == 1
    assert all(ok for ok, _ in replies) and len(replies) == 3
    assert s.stream.status()["idle"] and s.stream.status()["handled"] == {
        "click": 2,
        "accept": 2,
        "next_model": 1,
    }


def test_a_twist_burst_during_a_fit_moves_the_object_that_fit_produces(library, scene):
    """Twists stamped during B's fit reach the stream before B exists: they move B (not A) by
    exactly v * (their stamped duration + one device frame), then the idle refit lands B back
    on the object."""
    a, b = scene.objects[0], scene.objects[2]
    alone = Stream(library, scene)  # B's fit without any twist
    alone.stream.click(b.click)
    alone.stream.process_pending()
    T_b = alone.shown().T_scene_model
    s = Stream(library, scene, twist_frame="spacenav", linear_gain=0.1)
    s.stream.click(a.click)
    s.stream.process_pending()
    T_a = s.shown().T_scene_model.copy()
    s.stream.click(b.click)
    lin, ang = view_twist([0.5, 0.0, 0.0])  # 5 cm/s to the right on the screen
    for k in range(10):  # 30 Hz for 0.3 s
        s.stream.twist(lin, ang, stamp=50.0 + k / 30)
    s.stream.twist([0, 0, 0], [0, 0, 0], stamp=50.0 + 10 / 30)  # released
    s.stream.process_pending()
    moved = s.engine.active_object()
    assert moved.shown.template == b.template and moved.corrections == 1
    other = [o for o in s.engine.state.objects if o.id != moved.id]
    assert len(other) == 1 and np.array_equal(other[0].shown.T_scene_model, T_a)
    # the default view looks through the sensor: screen right = optical +x
    d = moved.shown.T_scene_model[:3, 3] - T_b[:3, 3]
    assert d == pytest.approx([0.05 * (1 / 30 + 9 / 30), 0.0, 0.0], abs=1e-12)
    assert s.stream.status()["pending_refit"]
    # not refitted until the twists have stopped for refit_idle_s
    s.clock.t += 0.4
    s.stream.process_pending()
    assert s.stream.status()["pending_refit"]
    s.clock.t += 0.2
    s.stream.process_pending()
    assert not s.stream.status()["pending_refit"]
    assert any(kind == "refit" and ok for kind, ok, _ in s.reports)
    dt, dr = pose_error(s.shown().T_scene_model, b.T_scene_model, library[b.template].symmetry)
    assert dt < TOL_M and dr < TOL_RAD


def test_accept_right_after_a_push_registers_the_refitted_pose(library, scene):
    """A push, then accept before refit_idle_s: the waiting refit runs first (on the pushed
    object), so the registration sits on the object and nothing is refitted afterwards."""
    s = Stream(library, scene)
    obj = scene.objects[2]
    s.stream.click(obj.click)
    s.stream.process_pending()
    lin, ang = view_twist([0.4, 0.0, 0.0], [0.0, 0.0, 0.3])
    for k in range(12):
        s.stream.twist(lin, ang, stamp=10.0 + k / 30)
    s.stream.action("accept")
    s.stream.process_pending()
    reg = s.engine.state.registered[-1]
    dt, dr = pose_error(reg.T_scene_model, obj.T_scene_model, library[obj.template].symmetry)
    assert reg.template == obj.template and dt < TOL_M and dr < TOL_RAD, (dt, dr)
    assert reg.corrections == 1
    kinds = [k for k, ok, _ in s.reports if ok]
    assert kinds == ["click", "refit", "accept"]
    s.clock.t += 5.0
    s.stream.process_pending()
    assert [k for k, ok, _ in s.reports if ok] == kinds  # no refit of whatever is next


def test_undo_after_a_push_needs_no_refit(library, scene):
    s = Stream(library, scene)
    obj = scene.objects[1]
    s.stream.click(obj.click)
    s.stream.process_pending()
    T0 = s.shown().T_scene_model.copy()
    lin, ang = view_twist([0.3, 0.2, 0.0])
    for k in range(6):
        s.stream.twist(lin, ang, stamp=3.0 + k / 30)
    s.stream.action("undo")
    s.clock.t += 2.0
    s.stream.process_pending()
    assert np.array_equal(s.shown().T_scene_model, T0)
    assert not any(kind == "refit" for kind, _, _ in s.reports)


@pytest.fixture(scope="module")
def fitted(library, scene):
    s = Stream(library, scene, twist_frame="view")
    s.stream.click(scene.objects[0].click)
    s.stream.process_pending()
    return s


def _burst(s, delays, handle_early=False):
    """A stamped burst arriving after ``delays``; returns the motion it caused, then undoes it."""
    T0 = s.shown().T_scene_model.copy()
    for k, delay in enumerate(delays):
        s.clock.t += delay
        s.stream.twist([0.2, -0.1, 0.3], [0.0, 0.4, 0.1], stamp=7.0 + k / 30)
        if handle_early and delay > 0.25:
            s.stream.process_pending()  # some handled at once, some later
    s.stream.process_pending()
    motion = s.shown().T_scene_model @ np.linalg.inv(T0)
    s.stream.action("undo")  # one burst = one correction
    s.stream.process_pending()
    assert np.array_equal(s.shown().T_scene_model, T0)
    return motion


@settings(max_examples=15, deadline=None)
@given(delays=st.lists(st.floats(0.0, 0.45), min_size=12, max_size=12))
def test_a_burst_moves_the_same_however_late_it_is_handled(fitted, delays):
    """Property: the motion of a stamped burst does not depend on when its messages arrive or
    are handled (a loaded machine hands them over late and in clumps)."""
    reference = _burst(fitted, [0.0] * 12)
    motion = _burst(fitted, delays, handle_early=True)
    assert np.allclose(motion, reference, atol=1e-12)
    assert np.linalg.norm(reference[:3, 3]) > 0.01  # it did move


def test_joy_buttons_act_on_press_edges(library, scene):
    s = Stream(library, scene, button_next_model=0, button_previous_model=2)
    s.stream.click(scene.objects[0].click)
    for buttons in ([1, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 0]):
        s.stream.joy(buttons, [0.0] * 6)
    s.stream.process_pending()
    obj = s.engine.active_object()
    assert obj.model_changes == 3 and obj.active == 1  # next, next, previous


def test_joint_axis_steps_once_per_push_with_hysteresis(library):
    """Axis 5 past 0.5 steps the lever once; values that hover around the threshold do not step
    again until the axis came back below half of it."""
    sim = simulate_taskboard(
        library, 3102, articulated=True, joints={"ball_valve": {"lever": math.pi / 4}}
    )
    obj = next(o for o in sim.objects if o.template == "ball_valve")
    s = Stream(library, sim, joint_axis=5, joint_axis_threshold=0.5)
    s.stream.click(obj.click)
    s.stream.process_pending()
    assert s.shown().template == "ball_valve"
    q0 = s.shown().joints["lever"]
    steps = []
    for v in (0.0, 0.6, 0.45, 0.55, 0.3, 0.7, 0.2, 0.8, -0.9, 0.0, -0.6, -0.1):
        s.stream.joy([0, 0], [0.0] * 5 + [v])
        s.stream.process_pending()
        steps.append(round((s.shown().joints["lever"] - q0) / math.radians(5)))
    assert steps == [0, 1, 1, 1, 1, 1, 1, 2, 2, 2, 1, 1]


def test_wrong_inputs_are_answered_and_reported(library, scene):
    s = Stream(library, scene)
    replies = []
    s.stream.twist([0.1, 0, 0], [0, 0, 0])
    s.stream.twist([float("nan"), 0, 0], [0, 0, 0])
    s.stream.action("accept", reply=lambda ok, m: replies.append((ok, m)))
    s.stream.action("fly_away", reply=lambda ok, m: replies.append((ok, m)))
    s.stream.action(
        "select_model", "no_such_template", reply=lambda ok, m: replies.append((ok, m))
    )
    s.stream.click([0.0, 0.0, 50.0], reply=lambda ok, m: replies.append((ok, m)))
    assert s.stream.process_pending() == 6
    assert [ok for ok, _ in replies] == [False] * 4
    assert "no object selected" in replies[0][1] and "unknown action" in replies[1][1]
    assert "cm from the nearest scanned point" in replies[3][1]
    messages = [m for _, ok, m in s.reports if not ok]
    assert any("twist ignored: no object selected" in m for m in messages)
    assert any("NaN/inf" in m for m in messages)
    # accept with nothing selected does not apply now (a warning for the node), a far click or
    # an unknown action is an error
    benign = {m: b for (_, ok, m), b in zip(s.reports, s.outbox.benign) if not ok}
    assert benign["accept: no object selected: click an object first"] is True
    assert not any(b for m, b in benign.items() if "unknown action" in m or "cm from" in m)
    # a storm of calls while a fit is queued: every one answered, in order
    s.stream.click(scene.objects[0].click)
    answers = []
    for k in range(200):
        s.stream.action(
            "next_model" if k % 2 == 0 else "previous_model",
            reply=lambda ok, m, k=k: answers.append((k, ok)),
        )
    s.stream.process_pending()
    assert [k for k, _ in answers] == list(range(200)) and all(ok for _, ok in answers)
    with pytest.raises(AffordanceError, match="twist_frame"):
        OperatorSettings(twist_frame="sideways").validate()


def test_select_model_by_name(library, scene):
    s = Stream(library, scene)
    obj = scene.objects[1]
    s.stream.click(obj.click)
    s.stream.process_pending()
    names = [c.template for c in s.engine.active_object().candidates]
    s.stream.action("select_model", names[3])
    s.stream.process_pending()
    assert s.shown().template == names[3] and s.engine.active_object().active == 3
    s.stream.action("select_model", names[0])
    s.stream.process_pending()
    assert s.shown().template == obj.template


def test_the_selected_object_follows_a_new_cloud(library, scene):
    """A new cloud (the scene moved 2 cm) refits the selected object from its current pose --
    not an undo step, at most twice a second, and not while the operator is pushing it."""
    from affordance_registration.core.transforms import make_T

    s = Stream(library, scene)
    obj = scene.objects[2]
    s.stream.click(obj.click)
    s.stream.process_pending()
    undo_depth = s.engine.status()["counts"]["undo"]
    shift = np.array([0.02, -0.01, 0.0])
    s.engine.set_scene(scene.organized + shift.astype(np.float32), frame_id=FRAME)
    s.stream.new_cloud()
    s.stream.new_cloud()  # one waits in the queue at most
    assert s.stream.status()["queued"] == 1
    s.stream.process_pending()
    moved = make_T(t=shift) @ obj.T_scene_model
    dt, dr = pose_error(s.shown().T_scene_model, moved, library[obj.template].symmetry)
    assert dt < TOL_M and dr < TOL_RAD, (dt, dr)
    assert s.engine.status()["counts"]["undo"] == undo_depth
    assert any("followed the new cloud" in m for _, ok, m in s.reports if ok)
    # within follow_period_s of the last follow, and while twists wait for their refit: no
    T_followed = s.shown().T_scene_model.copy()
    s.engine.set_scene(scene.organized, frame_id=FRAME)
    s.stream.new_cloud()
    s.stream.process_pending()
    assert np.array_equal(s.shown().T_scene_model, T_followed)
    s.clock.t += 1.0
    s.stream.twist(*view_twist([0.1, 0, 0]), stamp=1.0)
    s.stream.new_cloud()
    s.stream.process_pending()
    assert s.stream.status()["pending_refit"]  # not followed: the push's refit will
    s.clock.t += 1.0
    s.stream.process_pending()  # the idle refit, on the new cloud
    dt, dr = pose_error(s.shown().T_scene_model, obj.T_scene_model, library[obj.template].symmetry)
    assert dt < TOL_M and dr < TOL_RAD, (dt, dr)


class Watched(Recorder):
    """A recorder that notes, at every change the stream puts, the open objects as
    (id, shown candidate, has a suggested view) and the stream's ``views_due`` and ``idle``;
    ``connect``-ed, it stands for a node that publishes only when the test says
    (:meth:`publish`)."""

    def __init__(self, engine):
        super().__init__()
        self.engine, self.stream, self.changes = engine, None, []
        self.connect(lambda: None)

    def changed(self):
        objs = tuple(
            (o.id, o.active, o.suggested_view is not None) for o in self.engine.state.objects
        )
        st = self.stream.status()
        self.changes.append((objs, st["views_due"], st["idle"]))
        super().changed()

    def publish(self):
        self.drain()
        self.published()


def test_an_unsettled_clicks_view_comes_after_its_status_and_what_arrived_before_it(library):
    """The demo board's quarter-turn valve seen edge-on (unsettled): its click is committed
    without a view (the view is due: the stream is not idle); a press that arrived meanwhile
    is handled first; the view waits until the node has published the click's status, then it
    is computed and given to the object -- and to the state undo returns to, which holds the
    same answer. A second click discarded before its view was computed has it dropped: never
    computed, not in the state undo brings back. The object's fit_s is the whole click."""
    from test_sensor_move import edge_on_case

    from affordance_registration.evaluation.simulated_scan import render_organized
    from affordance_registration.evaluation.viewpoints import taskboard_meshes

    sim, T, click, _ = edge_on_case(library)
    organized, _ = render_organized(taskboard_meshes(sim, library), T, None)
    clock = SimClock()  # (frozen: the wait for the status never times out)
    engine = AffordanceEngine(library)
    engine.set_scene(organized, frame_id=FRAME, sensor_origin=T[:3, 3], T_scene_optical=T)
    box = Watched(engine)
    stream = box.stream = OperatorStream(
        engine, OperatorSettings(), clock, clock.sleep, outbox=box
    )
    stream.click(click)
    stream.action("next_model")
    assert stream.process_pending() == 2
    obj = engine.active_object()
    assert not obj.ambiguity.settled and obj.active == 1 and obj.suggested_view is None
    assert box.changes == [(((1, 0, False),), 1, False), (((1, 1, False),), 1, False)]
    timing = engine.status()["timing_s"]
    assert obj.fit_s == pytest.approx(timing["total"], abs=1e-6)
    assert timing["total"] == pytest.approx(
        timing["prepare"] + timing["fit"] + timing["ambiguity"], abs=1e-5
    )
    assert stream.process_pending() == 0 and engine.views_due == 1  # not yet published

    box.publish()
    stream.process_pending()
    assert box.changes[-1] == (((1, 1, True),), 0, True)
    assert engine.status()["timing_s"]["suggest_view"] > 0.0
    view = engine.active_object().suggested_view
    assert engine.undo() == "undid cycle"
    assert engine.active_object().active == 0 and engine.active_object().suggested_view is view

    stream.action("discard")
    stream.click(click)
    stream.action("discard")
    assert stream.process_pending() == 3 and engine.views_due == 1
    box.publish()
    stream.process_pending()
    assert engine.views_due == 0 and engine.state.objects == ()
    assert all(not any(v for *_, v in objs) for objs, *_ in box.changes[-3:])
    assert engine.undo() == "undid discard"
    again = engine.active_object()
    assert again.id == 2 and not again.ambiguity.settled and again.suggested_view is None
