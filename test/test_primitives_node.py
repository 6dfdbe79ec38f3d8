# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Primitives over ROS: a real engine node in its own process, a simulated table of
boxes and cylinders on ``points``, a click: the status says "no template fits here; fitted as a
box ...", carries the dimensions, the markers draw the primitive at its size; ``~/set_dimension``
sets and steps a dimension, the status and the accepted registration keep it; malformed
messages are one line each. The marker menu's dimension entries, unit-tested."""

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from ros_helpers import LATCHED, engine_session
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from affordance_registration.core.errors import AffordanceError
from affordance_registration.evaluation.rows import simulate_primitives
from affordance_registration.ros.glue.conversions import pose_to_matrix, xyz_to_pointcloud2

FRAME = "camera_optical_frame"
NS = "/affordance_engine"


@pytest.fixture(scope="module")
def session(ros_context, tmp_path_factory):
    organized, objects = simulate_primitives(5000)
    box = next(o for o in objects if o["kind"] == "box" and o["visible"] >= 500)
    with engine_session(
        tmp_path_factory.mktemp("primitives_node"),
        {},
        "primitives_tester",
        {
            "points": (PointCloud2, "/points", 1),
            "click": (PointStamped, "/clicked_point", 10),
            "dimension": (String, f"{NS}/set_dimension", 10),
        },
        [(MarkerArray, f"{NS}/markers", LATCHED, False)],
        organized=organized,
        box=box,
    ) as s:
        s["pubs"]["points"].publish(xyz_to_pointcloud2(organized, FRAME))
        s["client"].wait_for(
            lambda: (
                (s["client"].status(f"{NS}/status") or {}).get("node", {}).get("cloud") is not None
            ),
            60,
            "the cloud",
        )
        yield s


def _status(s):
    return s["client"].status(f"{NS}/status") or {}


def _shown(s):
    objs = [o for o in _status(s).get("objects", []) if o["active"]]
    return (objs[0], objs[0]["candidates"][objs[0]["shown"]]) if objs else (None, None)


def test_a_box_is_fitted_as_a_box_with_its_dimensions(session):
    s = session
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, s["box"]["click"])
    s["pubs"]["click"].publish(msg)
    s["client"].wait_for(lambda: _shown(s)[0] is not None, 120, "the fit")
    obj, shown = _shown(s)
    assert shown["primitive"] == "box"
    assert obj["no_match"] is True and obj["verdict"].startswith(
        "no template fits here; fitted as a box"
    )
    for k, v in s["box"]["dimensions"].items():
        assert abs(shown["dimensions"][k] - v) <= 0.005, (k, shown["dimensions"], v)

    # the markers draw the box at its size: a CUBE of its dimensions, standing on its base face
    # (the marker is centred: half the height above the box's frame)
    def candidate_box():
        arr = s["client"].latest.get(f"{NS}/markers")
        ms = [m for m in (arr.markers if arr else []) if m.ns == "candidate"]
        return ms[0] if ms else None

    box = s["client"].wait_for(candidate_box, 30, "the candidate's box marker")
    d = shown["dimensions"]
    assert box.type == Marker.CUBE and not box.points
    np.testing.assert_allclose(
        [box.scale.x, box.scale.y, box.scale.z], [d["x"], d["y"], d["z"]], atol=1e-6
    )
    T_box, T_fit = pose_to_matrix(box.pose), np.asarray(shown["pose"])
    np.testing.assert_allclose(T_box[:3, 3], T_fit[:3, 3] + T_fit[:3, 2] * d["z"] / 2, atol=1e-5)
    label = [m for m in s["client"].latest[f"{NS}/markers"].markers if m.ns == "candidate_label"]
    assert label and "fitted as a box" in label[0].text


def test_set_dimension_sets_and_steps_and_the_registration_keeps_it(session):
    s = session
    _, shown = _shown(s)
    assert shown is not None and shown["primitive"] == "box"
    target = round(shown["dimensions"]["z"] + 0.02, 4)
    s["pubs"]["dimension"].publish(String(data=f"z={target}"))
    s["client"].wait_for(
        lambda: abs(_shown(s)[1]["dimensions"]["z"] - target) < 1e-4, 60, "the new height"
    )
    x = _shown(s)[1]["dimensions"]["x"]
    s["pubs"]["dimension"].publish(String(data="x-"))  # one step of dimension_step_mm
    s["client"].wait_for(
        lambda: abs(_shown(s)[1]["dimensions"]["x"] - (x - 0.005)) < 1e-4, 60, "the stepped length"
    )
    assert abs(_shown(s)[1]["dimensions"]["z"] - target) < 1e-4  # the refit kept it
    res = s["client"].call(Trigger, f"{NS}/accept")
    assert res.success, res.message
    s["client"].wait_for(lambda: _status(s).get("registered"), 30, "the registration")
    reg = _status(s)["registered"][-1]
    assert reg["primitive"] == "box" and abs(reg["dimensions"]["z"] - target) < 1e-4
    assert reg["override"] is False


@pytest.mark.parametrize(
    "text, why",
    [
        ("radius", "expected NAME=METRES"),
        ("z=nan", "expected NAME=METRES"),
        ("z=-", "expected NAME=METRES"),
        ("x" * 10_000, "characters"),
        ("radius=0.1", "no object selected"),
    ],
)
def test_malformed_or_untimely_set_dimension_is_one_line(session, text, why):
    s = session
    s["pubs"]["dimension"].publish(String(data=text))
    s["client"].wait_for(
        lambda: why in _status(s).get("node", {}).get("last_error", ""),
        30,
        f"an error saying {why!r}",
    )
    assert len(_status(s)["node"]["last_error"]) < 400
    assert s["proc"].proc.poll() is None  # the node is still running


def test_parse_dimension():
    from affordance_registration.ros.glue.conversions import parse_dimension

    assert parse_dimension(" radius=0.045 ") == ("radius", 0.045, None)
    assert parse_dimension("x+") == ("x", None, 1.0) and parse_dimension("y -") == (
        "y",
        None,
        -1.0,
    )
    for bad in ("", "=", "1=2", "x=inf", "x==1", "x + 1"):
        with pytest.raises(AffordanceError):
            parse_dimension(bad)


def test_the_marker_menu_steps_a_primitives_dimensions(library):
    from affordance_registration.core.registration import Registrar
    from affordance_registration.core.scene import Scene
    from affordance_registration.ros.standins.interactive import MENU, menu_of

    organized, objects = simulate_primitives(5000)
    cyl = next(o for o in objects if o["kind"] == "cylinder")
    best = Registrar(library).fit(Scene(organized), cyl["click"]).candidates[0]
    assert best.primitive == "cylinder"
    menu = menu_of(best)
    assert [m[0] for m in menu[: len(MENU)]] == [a for a, _ in MENU]
    assert ("dimension", ("radius", None, 1.0), "radius +") in menu
    assert ("dimension", ("length", None, -1.0), "length -") in menu
    rigid = menu_of(
        Registrar(library.specific()).fit(Scene(organized), cyl["click"]).candidates[0]
    )
    assert len(rigid) == len(MENU)
