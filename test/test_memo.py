# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What is made once per immutable record (``core.memo.PerRecord``) is what would be made
afresh: the engine's status entries, the ~/markers of the registrations and their TF frames
come out the same with the memo as without, whatever changed around them; the memo holds only
the records of its last call."""

import gc
import weakref
from dataclasses import dataclass, field

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import MarkerArray

from affordance_registration.core.memo import PerRecord
from affordance_registration.core.tracked import EngineState, Registration
from affordance_registration.core.transforms import axis_angle_matrix, make_T
from affordance_registration.core.waypoints import waypoints_dict
from affordance_registration.ros.glue.markers import registered_markers_memo, state_markers


@dataclass(frozen=True)
class _Record:
    value: int
    payload: list = field(default_factory=list)


def test_a_value_is_made_once_per_record_and_context():
    made = []
    memo = PerRecord(lambda r, k: made.append((r.value, k)) or r.value * k)
    a, b = _Record(1), _Record(2)
    assert memo.values([a, b], 10) == [10, 20]
    assert memo.values([b, a], 10) == [20, 10]
    assert made == [(1, 10), (2, 10)]  # nothing made again
    assert memo.values([a], 3) == [3] and made[-1] == (1, 3)  # another context: made again
    twin = _Record(1)  # equal, but another record: made for itself
    assert memo.values([a, twin], 3) == [3, 3] and made[-1] == (1, 3) and len(made) == 4


def test_the_memo_holds_only_the_records_of_its_last_call():
    memo = PerRecord(lambda r: len(r.payload))
    kept, dropped = _Record(1, [0] * 3), _Record(2, [0] * 5)
    assert memo.values([kept, dropped]) == [3, 5]
    gone = weakref.ref(dropped)
    assert memo.values([kept]) == [3]
    del dropped
    gc.collect()
    assert gone() is None  # the memo did not keep it alive


def _registrations(library) -> tuple:
    """Registrations of every kind the markers draw: waypoints, a joint, a primitive at its
    size, a scaled template, a template the library does not hold."""

    def reg(i, template, **kw):
        T = make_T(axis_angle_matrix([1, 2, 0.5], 0.3 * i), [0.1 * i, -0.05 * i, 0.9])
        return Registration(
            id=i,
            template=template,
            T_scene_model=T,
            likelihood=1.0,
            probability=0.9,
            residual=0.001,
            click=T[:3, 3],
            **kw,
        )

    return (
        reg(1, "grab_handle"),
        reg(2, "ball_valve", joints={"lever": 0.4}, state="open"),
        reg(3, "box", primitive="box", dimensions={"x": 0.2, "y": 0.1, "z": 0.05}),
        reg(4, "gate_valve", scale=1.1),
        reg(5, "not_in_this_library"),
    )


def _read_back(arr) -> MarkerArray:
    """The message as a subscriber reads it (its serialized bytes are not comparable: CDR
    padding is not zeroed)."""
    return deserialize_message(serialize_message(arr), MarkerArray)


@pytest.mark.parametrize("frame", ["cam", "base_link"])
def test_registered_markers_from_the_memo_are_those_made_afresh(library, frame):
    regs = _registrations(library)
    memo = registered_markers_memo()
    views = [
        (Time(sec=1), np.array([0.0, -1.0, 0.0])),
        (Time(sec=2, nanosec=5), np.array([0.0, 0.0, 1.0])),
    ]
    states = [
        EngineState(registered=regs),
        EngineState(registered=regs[1:]),
        EngineState(registered=regs[::-1]),
    ]
    for state in states:  # registrations dropped, reordered; stamps, views
        for stamp, up in views:
            fresh = state_markers(state, library, frame, stamp, up)
            memoised = state_markers(state, library, frame, stamp, up, memo)
            assert _read_back(memoised) == _read_back(fresh)
            assert all(
                m.header.stamp == stamp and m.header.frame_id == frame
                for m in memoised.markers[1:]
            )  # (after the DELETEALL)
    assert len(fresh.markers) > 1 + 2 * len(regs)  # meshes, labels, grippers drawn


def test_status_entries_are_made_once_and_a_caller_cannot_change_them(library, panel_scene):
    from affordance_registration.core.engine import AffordanceEngine

    engine = AffordanceEngine(library)
    engine.set_scene(panel_scene.organized, frame_id="cam")
    for obj in panel_scene.objects[:2]:
        engine.click(obj.click)
        engine.accept()
    first = engine.status()["registered"]
    assert [e["id"] for e in first] == [r.id for r in engine.state.registered]
    for entry, reg in zip(first, engine.state.registered):
        assert entry == dict(reg.to_dict(), waypoints=waypoints_dict(library, reg))
    first[0]["template"] = "changed by a caller"
    again = engine.status()["registered"]
    assert again[0]["template"] == engine.state.registered[0].template


def test_per_object_computes_once_per_live_object_and_forgets_it():
    """``per_object``: one value per live object and key (objects that are not hashable
    too), the same object on every call, and nothing kept once the object is gone."""
    from affordance_registration.core import memo

    class Unhashable:
        __hash__ = None

    made = []
    a, b = Unhashable(), Unhashable()
    first = memo.per_object(a, "x", lambda: made.append("a") or ["a"])
    assert memo.per_object(a, "x", lambda: made.append("again") or ["again"]) is first
    assert memo.per_object(a, "y", lambda: made.append("ay") or ["ay"]) == ["ay"]
    assert memo.per_object(b, "x", lambda: made.append("b") or ["b"]) == ["b"]
    assert made == ["a", "ay", "b"]
    key = id(a)
    del a
    gc.collect()
    assert key not in memo._per_object and id(b) in memo._per_object
