# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine node's parameters are the code's: the shipped parameter file and the tables in
msg_docs/README.md name every parameter with the code's default, and the fitting knobs are the
``fit.*`` parameters made from FitSettings -- a real node started with a settings file and a
parameter file takes them in that order, refuses a bad one naming it, and a change rebuilds
its fitter."""

import os
import re
import sys

import pytest
import yaml
from geometry_msgs.msg import PointStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from ros_helpers import LATCHED, NodeProcess, engine_session, get_parameters
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from affordance_registration.core.registration import FitSettings
from affordance_registration.evaluation.simulation import simulate_taskboard
from affordance_registration.ros.glue import params
from affordance_registration.ros.glue.conversions import xyz_to_pointcloud2

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PARAMS_FILE = os.path.join(ROOT, "launch_configs", "affordance_engine.params.yaml")
MSG_DOCS = os.path.join(ROOT, "msg_docs", "README.md")
NS = "/affordance_engine"
FRAME = "camera_depth_optical_frame"


def test_the_parameter_file_is_made_from_the_code():
    with open(PARAMS_FILE, encoding="utf-8") as handle:
        text = handle.read()
    assert text == params.params_file(), (
        "regenerate: affordance-registration settings --node-params > " + PARAMS_FILE
    )
    active = yaml.safe_load(text)["affordance_engine"]["ros__parameters"]
    assert active == {
        name: default
        for name, (default, _, _) in params.ENGINE_PARAMETERS.items()
        if default != []
    }
    commented = dict(re.findall(r"^    # (fit\.[\w.]+): (.+)$", text, flags=re.M))
    assert {k: yaml.safe_load(v) for k, v in commented.items()} == {
        name: default for name, (default, _, _) in params.FIT_TABLE.items()
    }


def _block(doc: str, name: str) -> str:
    """The generated table between ``<!-- NAME: ... -->`` and ``<!-- end NAME -->``."""
    begin = doc.index(f"<!-- {name}:")
    return doc[doc.index("\n", begin) + 1 : doc.index(f"<!-- end {name} -->")]


def test_msg_docs_tables_are_made_from_the_code():
    """The engine's parameters (its own and the operator's knobs), its fit.* knobs and the
    station's knobs: each table of msg_docs/README.md is the one the code makes."""
    from affordance_registration.ros.station.parameters import station_table

    with open(MSG_DOCS, encoding="utf-8") as handle:
        doc = handle.read()
    assert _block(doc, "fit-parameters") == params.fit_table(), (
        "regenerate: affordance-registration settings --markdown"
    )
    assert _block(doc, "node-parameters") == params.node_table(), (
        "regenerate: affordance-registration settings --markdown node"
    )
    assert _block(doc, "station-parameters") == station_table(), (
        "regenerate: affordance-registration settings --markdown station"
    )


def test_the_operators_parameters_are_its_knobs_one_name_one_unit():
    """Each of the operator's parameters is OperatorSettings' knob of the same name (default,
    rule, unit in its description): the core and the node cannot disagree."""
    from affordance_registration.core.knobs import declared
    from affordance_registration.core.operator import OperatorSettings

    knobs = declared(OperatorSettings)
    assert [d.name for d in knobs] == list(params.OPERATOR_TABLE)
    assert not set(params.OPERATOR_TABLE) & set(params.NODE_PARAMETERS)
    for d in knobs:
        default, description, _ = params.PARAMETERS[d.name]
        assert default == d.default and description.startswith(d.doc)
        assert not d.unit or description.endswith(f"({d.unit})")
    values = {n: d for n, (d, _, _) in params.ENGINE_PARAMETERS.items()}
    assert params.operator_settings(values) == OperatorSettings()
    assert params.check({"joint_step_deg": 120.0}) == (
        "joint_step_deg must be a positive number in [0.1, 90.0], got 120.0"
    )
    assert "twist_frame must be one of: spacenav, view" in params.check({"twist_frame": "x"})


def test_every_knob_is_a_parameter_with_its_code_default_and_description():
    knobs = FitSettings.knobs()
    assert [f"fit.{name}" for name, *_ in knobs] == list(params.FIT_TABLE)
    assert all(
        params.PARAMETERS[f"fit.{name}"][:2] == (default, doc) for name, default, doc, _ in knobs
    )
    for old in (
        "voxel_size",
        "fit_mode",
        "estimate_joints",
        "weight_scale",
        "snap_distance",
        "seed",
        "test_slow_fit_s",
    ):
        assert old not in params.PARAMETERS
    assert (
        params.check({"fit.crop.voxel": 1.0})
        == "fit.crop.voxel must be a positive number in [0.001, 0.05], got 1.0"
    )
    assert params.check({"fit.seed": 7, "fit.mode": "free"}) is None


ANY_VALUE = st.one_of(
    st.booleans(),
    st.integers(-(2**40), 2**40),
    st.floats(allow_nan=True),
    st.text(max_size=8),
    st.sampled_from(["auto", "free", "paper", ""]),
)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(params.FIT_TABLE)), ANY_VALUE)
def test_any_value_of_a_fit_parameter_is_taken_or_refused_with_one_line_naming_it(name, value):
    """What the set-parameters callback checks: a value is refused with one line naming the
    parameter, or it makes settings that hold it."""
    problem = params.check({name: value})
    if problem is not None:
        assert problem.startswith(name + " ") and "\n" not in problem, problem
        return
    values = {n: d for n, (d, _, _) in params.FIT_TABLE.items()}
    values[name] = value
    knob = params.fit_settings(values).to_dict()
    for part in name[len(params.FIT_PREFIX) :].split("."):
        knob = knob[part]
    assert knob == value


def _set(client, name, value):
    kind = {
        int: ("PARAMETER_INTEGER", "integer_value"),
        float: ("PARAMETER_DOUBLE", "double_value"),
    }
    type_name, field = kind[type(value)]
    pv = ParameterValue(type=getattr(ParameterType, type_name), **{field: value})
    req = SetParameters.Request(parameters=[Parameter(name=name, value=pv)])
    return client.call(SetParameters, f"{NS}/set_parameters", req).results[0]


@pytest.fixture(scope="module")
def configured(ros_context, tmp_path_factory, library):
    """A node started with a settings file (snap distance 2 mm, 32 coarse samples, seed 9) and
    the shipped parameter file with every fit.* line uncommented but the coarse samples, and
    fit.seed set to 5 there."""
    tmp = tmp_path_factory.mktemp("fit_parameters")
    (tmp / "fit.yaml").write_text(
        "seed: 9\ncoarse:\n  samples: 32\ncrop:\n  snap_distance: 0.002\n"
    )
    text = re.sub(
        r"^    # (fit\.(?!coarse\.samples)[\w.]+: )", r"    \1", params.params_file(), flags=re.M
    ).replace("    fit.seed: 0\n", "    fit.seed: 5\n")
    text = text.replace("    fit.crop.snap_distance: 0.03\n", "")  # the file's 2 mm stays
    (tmp / "engine.params.yaml").write_text(text)
    # an old name and a typo: ROS would ignore both silently, the node says so
    with engine_session(
        tmp,
        {
            "settings_file": str(tmp / "fit.yaml"),
            "voxel_size": "0.01",
            "fit.crop.snap_distanse": "0.01",
            "fit.verdict.explained_margin": "0.05",
        },
        "fit_params_tester",
        {"points": (PointCloud2, "/points", 1), "click": (PointStamped, "/clicked_point", 10)},
        params_file=str(tmp / "engine.params.yaml"),
        sim=simulate_taskboard(library, 7),
    ) as s:
        yield s


def test_a_settings_file_then_the_parameter_file_make_the_fit_parameters(configured):
    got = get_parameters(
        configured["client"],
        [
            "fit.seed",
            "fit.coarse.samples",
            "fit.crop.snap_distance",
            "fit.crop.voxel",
            "fit.mode",
            "fit.articulated",
        ],
    )
    assert got == {
        "fit.seed": 5,
        "fit.coarse.samples": 32,
        "fit.crop.snap_distance": 0.002,
        "fit.crop.voxel": 0.005,
        "fit.mode": "auto",
        "fit.articulated": True,
    }


def test_a_parameter_the_node_does_not_have_is_named_with_the_one_meant(configured):
    out = configured["proc"].output()
    assert (
        "parameter 'voxel_size' is not one of this node's and is ignored (did you mean "
        "'fit.crop.voxel'?)" in out
    )
    assert (
        "parameter 'fit.crop.snap_distanse' is not one of this node's and is ignored (did "
        "you mean 'fit.crop.snap_distance'?)" in out
    )
    assert (
        "parameter 'fit.verdict.explained_margin' is retired (replaced by the description "
        "length against a fitting primitive (docs/TUNING.md, verdict)) and is ignored" in out
    )
    assert get_parameters(configured["client"], ["fit.crop.voxel"]) == {"fit.crop.voxel": 0.005}


def test_a_fit_parameter_change_is_validated_and_rebuilds_the_fitter(configured):
    s = configured
    client = s["client"]
    client.subscribe(String, f"{NS}/status", LATCHED)
    bad = _set(client, "fit.coarse.samples", 0)
    assert (
        not bad.successful
        and bad.reason == "fit.coarse.samples must be an integer >= 1, at most 10000, got 0"
    )
    bad = _set(client, "fit.hypotheses.yaw_restarts", 0)  # fine alone ...
    assert bad.successful
    bad = _set(client, "fit.hypotheses.random_restarts", 0)  # ... not with this one too
    assert not bad.successful and "at least one restart per template" in bad.reason
    assert get_parameters(client, ["fit.hypotheses.random_restarts"]) == {
        "fit.hypotheses.random_restarts": 12
    }
    assert _set(client, "fit.hypotheses.yaw_restarts", 12).successful
    sim = s["sim"]
    obj = max(sim.objects, key=lambda o: o.visible_points)
    s["pubs"]["points"].publish(xyz_to_pointcloud2(sim.organized, FRAME))
    client.wait_for(
        lambda: (client.status(f"{NS}/status") or {}).get("node", {}).get("cloud"), 30, "the cloud"
    )
    off = obj.click.copy()
    off[2] -= 0.01  # 1 cm in front of the surface
    msg = PointStamped()
    msg.header.frame_id = FRAME
    msg.point.x, msg.point.y, msg.point.z = map(float, off)
    s["pubs"]["click"].publish(msg)
    client.wait_for(
        lambda: "limit 0.2 cm" in client.status(f"{NS}/status")["node"]["last_error"],
        60,
        "the click refused at the settings file's 2 mm",
    )
    assert _set(client, "fit.crop.snap_distance", 0.03).successful
    s["pubs"]["click"].publish(msg)
    st = client.wait_for(
        lambda: client.status(f"{NS}/status")["objects"] and client.status(f"{NS}/status"),
        90,
        "the click fitted at 3 cm",
    )
    assert st["objects"][0]["candidates"][0]["template"] == obj.template


def test_a_bad_settings_file_stops_the_start_with_one_line(ros_context, tmp_path):
    bad = tmp_path / "fit.yaml"
    bad.write_text("coarse:\n  sample: 32\n")
    proc = NodeProcess(
        [
            sys.executable,
            "-m",
            "affordance_registration.ros.nodes.engine_node",
            "--ros-args",
            "-p",
            f"settings_file:={bad}",
            "-p",
            f"registrations_file:={tmp_path / 'r.yaml'}",
        ],
        tmp_path / "bad.log",
    )
    try:
        code = proc.proc.wait(timeout=60)
        out = proc.output()
        assert code == 2, out
        line = [ln for ln in out.splitlines() if "cannot start" in ln]
        assert line == [
            f"affordance_engine: cannot start: settings file {bad}: unknown setting "
            f"coarse.sample (one of: samples, iterations, reject, keep, "
            f"keep_per_template)"
        ], out
        assert "Traceback" not in out
    finally:
        proc.kill()
