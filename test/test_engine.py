# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine: clicks, cycling, view-frame corrections, refit, accept, undo, save/load, threads."""

import math
import threading

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from affordance_registration.core.corrections import apply_twist, twist_step, view_from_optical
from affordance_registration.core.engine import AffordanceEngine, load_registrations
from affordance_registration.core.errors import AffordanceError, EngineStateError, SceneError
from affordance_registration.core.transforms import is_rigid, make_T, pose_error, random_rotations


@pytest.fixture(scope="module")
def engine_and_scene(library, panel_scene):
    engine = AffordanceEngine(library)
    engine.set_scene(panel_scene.organized, frame_id="cam")
    return engine, panel_scene


@pytest.fixture
def engine(engine_and_scene):
    engine, _ = engine_and_scene
    while True:  # back to an empty state for every test
        try:
            engine.undo()
        except EngineStateError:
            break
    return engine


def test_view_frame_mapping():
    """A +x twist with the view looking down -z of the world moves the object along the view's
    right axis; rotations turn it about its own centre."""
    # camera above the origin looking down -z, its screen right is world -y, screen up is world +x
    R_world_view = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1.0]])
    T_view = make_T(R_world_view, [0, 0, 2.0])
    step = twist_step([0.1, 0, 0], [0, 0, 0], 0.5, T_view, centre=[1, 1, 0])
    assert np.allclose(step[:3, 3], [0, -0.05, 0])
    T_obj = make_T(t=[0.3, 0.2, 0.0])
    moved = apply_twist(T_obj, [0, 0, 0], [0, 0, math.pi / 2], 1.0, T_view, centre_model=[0, 0, 0])
    assert np.allclose(moved[:3, 3], [0.3, 0.2, 0.0])  # turned in place
    assert np.allclose(moved[:3, :3] @ [1, 0, 0], [0, 1, 0])
    # the default view looks through the sensor: screen right = optical +x, up = optical -y
    V = view_from_optical(np.eye(4))
    assert np.allclose(V[:3, :3] @ [1, 0, 0], [1, 0, 0]) and np.allclose(
        V[:3, :3] @ [0, 1, 0], [0, -1, 0]
    )
    with pytest.raises(AffordanceError):
        twist_step([np.nan, 0, 0], [0, 0, 0], 0.1, T_view, [0, 0, 0])


def test_click_cycle_correct_refit_accept_undo(engine, engine_and_scene, library):
    _, sim = engine_and_scene
    obj = sim.objects[2]
    engine.click(obj.click)
    active = engine.active_object()
    assert active.shown.template == obj.template and active.active == 0
    before = engine.state

    msg = engine.next_model()
    assert "rank 2/" in msg and engine.active_object().active == 1
    engine.previous_model()
    assert engine.active_object().active == 0
    # a burst of twists is one correction: 2 cm right on the screen
    T0 = engine.active_object().shown.T_scene_model
    for _ in range(10):
        engine.correct_twist([0.04, 0, 0], [0, 0, 0], 0.05)
    T1 = engine.active_object().shown.T_scene_model
    assert np.allclose(T1[:3, 3] - T0[:3, 3], [0.02, 0, 0], atol=1e-9)  # view right = optical +x
    assert engine.active_object().corrections == 1
    msg = engine.refit()
    dt, dr = pose_error(
        engine.active_object().shown.T_scene_model,
        obj.T_scene_model,
        library[obj.template].symmetry,
    )
    assert dt < 0.005 and dr < math.radians(5), msg
    # undo steps back exactly: refit, the twist burst, previous, next
    engine.undo()
    assert np.array_equal(engine.active_object().shown.T_scene_model, T1)
    engine.undo()
    assert np.array_equal(engine.active_object().shown.T_scene_model, T0)
    engine.undo()
    engine.undo()
    assert engine.state is before
    engine.accept()
    assert len(engine.state.registered) == 1 and engine.active_object() is None
    engine.undo()
    assert engine.state is before


def test_click_near_an_object_selects_it(engine, engine_and_scene):
    _, sim = engine_and_scene
    a, b = sim.objects[0], sim.objects[3]
    engine.click(a.click)
    engine.click(b.click)
    assert len(engine.state.objects) == 2
    msg = engine.click(a.click + np.array([0.002, 0, 0]))
    assert msg.startswith("selected object 1")
    assert len(engine.state.objects) == 2 and engine.state.active_id == 1
    engine.discard()
    assert [o.id for o in engine.state.objects] == [2]


def test_actions_at_the_wrong_moment_say_why(engine, library):
    for action in (
        engine.next_model,
        engine.previous_model,
        engine.refit,
        engine.accept,
        engine.discard,
    ):
        with pytest.raises(EngineStateError, match="no object selected"):
            action()
    with pytest.raises(EngineStateError, match="nothing to undo"):
        engine.undo()
    with pytest.raises(EngineStateError):
        engine.correct_twist([0.1, 0, 0], [0, 0, 0], 0.1)
    fresh = AffordanceEngine(library)
    with pytest.raises(EngineStateError, match="no point cloud"):
        fresh.click([0, 0, 1])
    with pytest.raises(SceneError, match="finite"):
        engine.click([np.nan, 0, 1])
    with pytest.raises(SceneError, match="cm from the nearest"):
        engine.click([5.0, 5.0, 5.0])


def test_save_and_load_round_trip(engine, engine_and_scene, tmp_path, library):
    _, sim = engine_and_scene
    for obj in sim.objects[:2]:
        engine.click(obj.click)
        engine.accept()
    path = tmp_path / "sub" / "registrations.yaml"
    engine.save(str(path))
    regs = load_registrations(str(path), library)
    assert [r.template for r in regs] == [r.template for r in engine.state.registered]
    for a, b in zip(regs, engine.state.registered):
        assert np.allclose(a.T_scene_model, b.T_scene_model, atol=1e-8)
        assert a.frame_id == "cam"
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp files
    # written with libyaml's emitter: the very text PyYAML's own safe dumper writes
    text = path.read_text(encoding="utf-8")
    assert text == yaml.safe_dump(yaml.safe_load(text), sort_keys=False)
    other = AffordanceEngine(library)
    other.load(str(path))
    assert len(other.state.registered) == 2
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        yaml.safe_dump(
            {
                "format": "affordance_registration/registrations/1",
                "registrations": [{"template": "nope", "pose": np.eye(4).tolist()}],
            }
        )
    )
    with pytest.raises(AffordanceError, match="unknown template 'nope'"):
        other.load(str(bad))
    assert len(other.state.registered) == 2  # a failed load changes nothing


def test_save_is_atomic_when_writing_fails(engine, tmp_path, monkeypatch):
    path = tmp_path / "r.yaml"
    engine.save(str(path))
    original = path.read_text()
    import affordance_registration.core.persistence as store

    def broken_dump(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(store.yaml, "dump", broken_dump)
    with pytest.raises(AffordanceError, match="cannot save"):
        engine.save(str(path))
    assert path.read_text() == original


def test_threads_do_not_corrupt_the_state(engine, engine_and_scene):
    _, sim = engine_and_scene
    engine.click(sim.objects[0].click)
    errors, done = [], []

    def worker(k):
        try:
            for _ in range(20):
                try:
                    (engine.next_model if k % 2 else engine.previous_model)()
                    done.append(k)
                except EngineStateError as exc:  # refused, not lost: a conflicting change
                    assert "changed meanwhile" in str(exc)
                engine.correct_twist([0.01, 0, 0], [0, 0, 0.1], 0.01)
        except Exception as exc:  # anything else is a bug
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    obj = engine.active_object()
    assert 0 <= obj.active < len(obj.candidates)
    assert obj.model_changes == len(done) > 0
    status = engine.status()
    assert status["counts"]["objects"] == 1 and status["objects"][0]["id"] == obj.id


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.floats(1e-4, 0.1))
def test_one_rigid_check_for_corrections_and_saved_poses(seed, shear):
    """Every rotation is rigid, with its translation, and so is one written with 6 decimals (a
    hand-written registrations file); a matrix scaled or sheared by 1e-4 or more is not --
    whether it comes as an operator's correction or from a saved file."""
    rng = np.random.default_rng(seed)
    T = make_T(random_rotations(1, rng)[0], rng.uniform(-5, 5, 3))
    assert is_rigid(T) and is_rigid(np.round(T, 6))
    bent = T.copy()
    bent[:3, :3] = bent[:3, :3] @ (np.eye(3) + shear * np.triu(np.ones((3, 3)), 1))
    scaled = T.copy()
    scaled[:3, :3] *= 1.0 + shear
    assert not is_rigid(bent) and not is_rigid(scaled)
    assert not is_rigid(np.where(np.eye(4, dtype=bool), np.nan, T)) and not is_rigid(T[:3])


def test_a_correction_or_a_saved_pose_that_is_not_rigid_is_refused(
    engine, engine_and_scene, library, tmp_path
):
    _, sim = engine_and_scene
    engine.click(sim.objects[2].click)
    T0 = engine.active_object().shown.T_scene_model
    T = T0.copy()
    T[:3, :3] *= 1.001
    with pytest.raises(AffordanceError, match="rigid"):
        engine.correct_pose(T)
    path = tmp_path / "scaled.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "format": "affordance_registration/registrations/1",
                "registrations": [{"template": sim.objects[2].template, "pose": T.tolist()}],
            }
        )
    )
    with pytest.raises(AffordanceError, match="not a rigid 4x4"):
        load_registrations(str(path), library)
    path.write_text(
        yaml.safe_dump(
            {
                "format": "affordance_registration/registrations/1",
                "registrations": [
                    {"template": sim.objects[2].template, "pose": np.round(T0, 6).tolist()}
                ],
            }
        )
    )
    assert len(load_registrations(str(path), library)) == 1


def test_a_registrations_file_that_is_not_one_is_refused_in_one_line(library, tmp_path):
    """A FIFO (it blocked the loader for good), a key written twice, values of the wrong kind
    (an internal error each), bytes that are not UTF-8: one line naming the file; nothing
    loaded."""
    import os
    import threading

    fmt = "format: affordance_registration/registrations/1\n"
    entry = "  - template: ball_valve\n    pose: " + str(np.eye(4).tolist()) + "\n"
    files = {
        "twice.yaml": fmt + "format: x\nregistrations: []\n",
        "likelihood.yaml": fmt + "registrations:\n" + entry + "    likelihood: high\n",
        "joints.yaml": fmt + "registrations:\n" + entry + "    joints: [1, 2]\n",
        "click.yaml": fmt + "registrations:\n" + entry + "    click: [1, 2]\n",
        "state.yaml": fmt + "registrations:\n" + entry + "    state: [open]\n",
        "id.yaml": fmt + "registrations:\n" + entry + "    id: 1e999\n",
        "list.yaml": fmt + "registrations: {a: 1}\n",
        "entry.yaml": fmt + "registrations:\n  - [1, 2]\n",
        "bytes.yaml": fmt.encode() + b"frame_id: \xff\n",
    }
    expected = {
        "twice.yaml": "the key 'format' is written twice",
        "likelihood.yaml": "wrong kind",
        "joints.yaml": "wrong kind",
        "click.yaml": "'click' must be three numbers",
        "state.yaml": "'state' must be text",
        "id.yaml": "wrong kind",
        "list.yaml": "'registrations' must be a list",
        "entry.yaml": "must be a mapping",
        "bytes.yaml": "not UTF-8",
        "fifo.yaml": "not a regular file (a FIFO)",
    }
    for name, text in files.items():
        (tmp_path / name).write_bytes(text if isinstance(text, bytes) else text.encode())
    os.mkfifo(tmp_path / "fifo.yaml")
    engine = AffordanceEngine(library)
    errors = {}

    def load_all():
        for name in expected:
            try:
                engine.load(str(tmp_path / name))
            except AffordanceError as exc:
                errors[name] = str(exc)

    worker = threading.Thread(target=load_all, daemon=True)
    worker.start()
    worker.join(60)
    assert not worker.is_alive(), f"a load blocked; done: {sorted(errors)}"
    for name, words in expected.items():
        assert name in errors.get(name, "") and words in errors[name], (name, errors.get(name))
        assert "\n" not in errors[name]
    assert engine.state.registered == ()
