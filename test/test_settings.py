# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The fitting settings (core/registration/settings.py): one declaration per knob, grouped by
stage; every group validates itself with one line naming the knob; plain data and YAML give the
same settings back exactly; a nested knob is overridden by its dotted name. No ROS."""

import dataclasses
import math

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from affordance_registration.core.errors import RegistrationError
from affordance_registration.core.registration import FitSettings
from affordance_registration.core.registration.settings import GROUPS, CoarseSettings

KNOBS = FitSettings.knobs()


def test_few_knobs_at_the_top_and_every_knob_declared_once_with_a_description():
    top = dataclasses.fields(FitSettings)
    assert len([f for f in top if "group" not in f.metadata]) <= 10  # the rest in groups
    names = [name for name, *_ in KNOBS]
    assert len(names) == len(set(names)) and len(names) > 50
    assert all(doc and "\n" not in doc for _, _, doc, _ in KNOBS)
    assert {f.name for f in top if "group" in f.metadata} == set(GROUPS)
    for name in ("fine_metric", "two_way", "coarse_two_way"):  # gone
        assert name not in names and f"fine.{name}" not in names


def test_the_stages_are_made_from_their_groups():
    s = FitSettings().with_(
        **{
            "coarse.samples": 32,
            "medium.iterations": 7,
            "fine.reject": 0.2,
            "articulation.sweep_iterations": 2,
            "refit.samples": 300,
        }
    )
    st_ = s.stages
    assert (st_.coarse.samples, st_.coarse.iterations, st_.coarse.reject) == (32, 8, 0.5)
    assert st_.medium.iterations == 7 and st_.short.samples == st_.medium.samples == 256
    assert st_.sweep.iterations == 2 and st_.fine.reject == st_.refit.reject == 0.2
    assert st_.refit.samples == 300 and st_.fine.target == st_.refit.target == "fine"


def test_with_changes_one_knob_and_keeps_the_rest():
    base = FitSettings(seed=4)
    s = base.with_(**{"coarse.samples": 32}, mode="free")
    assert s.coarse == CoarseSettings(samples=32) and s.mode == "free" and s.seed == 4
    assert dataclasses.replace(s, coarse=base.coarse) == base.with_(mode="free")
    assert base.seed == 4 and base.coarse.samples == 64  # frozen: the original stays


@pytest.mark.parametrize(
    "change, words",
    [
        ({"coarse.samples": 0}, "coarse.samples must be an integer >= 1, at most 10000, got 0"),
        (
            {"coarse.samples": 2.5},
            "coarse.samples must be an integer >= 1, at most 10000, got 2.5",
        ),
        # (a count is a fit's memory: 100,000,000 coarse samples took all of 24 GB)
        (
            {"coarse.samples": 100_000_000},
            "coarse.samples must be an integer >= 1, at most 10000, got 100000000",
        ),
        ({"fine.points": 10_001}, "fine.points must be an integer >= 0, at most 10000, got 10001"),
        ({"crop.voxel": -1.0}, "crop.voxel must be a positive number in [0.001, 0.05], got -1.0"),
        ({"crop.voxel": 1.0}, "crop.voxel must be a positive number in [0.001, 0.05], got 1.0"),
        ({"verdict.min_coverage": 1.5}, "verdict.min_coverage must be a number in (0, 1]"),
        ({"scoring.cap": math.nan}, "scoring.cap must be a positive number, got nan"),
        ({"articulated": "yes"}, "articulated must be true or false, got 'yes'"),
        ({"threads": True}, "threads must be an integer >= 1, at most 10000, got True"),
        ({"mode": "sideways"}, "mode must be one of: auto, mounted, free, got 'sideways'"),
        ({"seed": -1}, "seed must be an integer >= 0 in [0, 2147483647], got -1"),
        (
            {"hypotheses.yaw_restarts": 0, "hypotheses.random_restarts": 0},
            "at least one restart per template",
        ),
        ({"coarse.sample": 3}, "unknown setting coarse.sample (one of: samples, iterations"),
        ({"voxel": 0.01}, "unknown setting 'voxel'"),
        ({"coarse": 3}, "coarse must be a mapping of its knobs, got 3"),
    ],
)
def test_a_bad_knob_is_refused_with_one_line_naming_it(change, words):
    with pytest.raises(RegistrationError) as err:
        FitSettings().with_(**change)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_groups_validate_themselves_on_construction():
    with pytest.raises(RegistrationError, match="coarse.iterations must be an integer >= 1"):
        CoarseSettings(iterations=0)
    with pytest.raises(RegistrationError, match="coarse must be a CoarseSettings"):
        FitSettings(coarse={"samples": 3})


def _valid(default, rule):
    """A strategy of valid values for a knob of this default and rule."""
    if isinstance(default, bool):
        return st.booleans()
    if rule.startswith("one of: "):
        return st.sampled_from(rule[len("one of: ") :].split(", "))
    if " in [" in rule:
        lo, hi = (float(v) for v in rule.split(" in [")[1].rstrip("]").split(", "))
        return st.integers(int(lo), int(hi)) if isinstance(default, int) else st.floats(lo, hi)
    if isinstance(default, int):
        lo = 0 if ">= 0" in rule else 1
        return st.integers(lo, 10_000)
    if "in (0, 1]" in rule:
        return st.floats(1e-6, 1.0)
    return st.floats(1e-9, 1e6)


@st.composite
def _changes(draw):
    picked = draw(st.lists(st.sampled_from(KNOBS), max_size=12, unique_by=lambda k: k[0]))
    out = {name: draw(_valid(default, rule)) for name, default, _, rule in picked}
    if out.get("hypotheses.yaw_restarts") == 0 and out.get("hypotheses.random_restarts") == 0:
        out["hypotheses.random_restarts"] = 1
    return out


@settings(max_examples=200, deadline=None)
@given(_changes())
def test_plain_data_and_yaml_give_the_same_settings_back_exactly(changes):
    s = FitSettings().with_(**changes)
    assert FitSettings.from_dict(s.to_dict()) == s
    assert FitSettings.from_dict(yaml.safe_load(s.dump())) == s
    flat = {name: value for name, value in _flat(s.to_dict())}
    assert all(flat[name] == value for name, value in changes.items())


def _flat(data, prefix=""):
    for key, value in data.items():
        if isinstance(value, dict):
            yield from _flat(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def test_load_reads_a_partial_file_and_refuses_a_bad_one_with_one_line(tmp_path):
    good = tmp_path / "fit.yaml"
    good.write_text("seed: 3\ncoarse:\n  samples: 32\nverdict:\n  max_residual: 1\n")
    s = FitSettings.load(str(good))
    assert s == FitSettings(seed=3).with_(**{"coarse.samples": 32, "verdict.max_residual": 1.0})
    assert isinstance(s.verdict.max_residual, float)  # YAML's 1 for a length: 1.0
    (tmp_path / "empty.yaml").write_text("# nothing changed\n")
    assert FitSettings.load(str(tmp_path / "empty.yaml")) == FitSettings()
    cases = {
        "missing.yaml": None,
        "list.yaml": "- 1\n- 2\n",
        "broken.yaml": "coarse: [1,\n",
        "unknown.yaml": "coarse:\n  sample: 3\n",
        "bad.yaml": "fine:\n  points: -1\n",
        "bytes.yaml": b"seed: \xff\xfe\n",
        "twice.yaml": "seed: 1\nfine:\n  points: 3\nseed: 2\n",
        "enote.yaml": "crop:\n  voxel: 2e-3\n",
    }
    words = {
        "missing.yaml": ": cannot read: No such file",
        "list.yaml": "must be a mapping",
        "broken.yaml": "not valid YAML (line 2)",
        "unknown.yaml": "unknown setting coarse.sample",
        "bad.yaml": "fine.points must be an integer >= 0",
        "bytes.yaml": "not UTF-8",
        "twice.yaml": "not valid YAML (line 4): the key 'seed' is written twice",
        "enote.yaml": "got '2e-3' (text: YAML reads a number in e-notation as one only "
        "with a dot, as 1.0e-3)",
    }
    for name, text in cases.items():
        path = tmp_path / name
        if isinstance(text, bytes):
            path.write_bytes(text)
        elif text is not None:
            path.write_text(text)
        with pytest.raises(RegistrationError) as err:
            FitSettings.load(str(path))
        assert words[name] in str(err.value) and "\n" not in str(err.value), str(err.value)
        assert str(err.value).startswith(f"settings file {path}"), str(err.value)


def test_a_settings_file_of_an_earlier_version_still_loads(tmp_path):
    """A file written by `affordance-registration settings` before a knob was retired (the
    verdict's explained_margin, replaced by the description length) loads: the retired knob is
    passed over, the others are read; a misspelled one is still refused."""
    from affordance_registration.core.registration.settings import RETIRED

    assert "verdict.explained_margin" in RETIRED
    old = tmp_path / "old.yaml"
    old.write_text("verdict:\n  explained_margin: 0.05\n  max_residual: 0.004\n")
    assert FitSettings.load(str(old)) == FitSettings().with_(**{"verdict.max_residual": 0.004})
    old.write_text("verdict:\n  explained_margins: 0.05\n")
    with pytest.raises(RegistrationError, match="unknown setting verdict.explained_margins"):
        FitSettings.load(str(old))


def test_the_dump_of_the_defaults_is_every_knob_at_its_declared_default():
    data = yaml.safe_load(FitSettings().dump())
    assert dict(_flat(data)) == {name: default for name, default, _, _ in KNOBS}


def test_the_bench_writes_the_settings_it_ran_with_next_to_its_json(tmp_path):
    import json
    from pathlib import Path

    from affordance_registration.evaluation.bench import write_results

    docs = Path(__file__).resolve().parents[1] / "docs"
    result = json.loads((docs / "benchmark.json").read_text())
    ran = FitSettings(seed=2).with_(**{"coarse.samples": 48})
    written = write_results(result, str(tmp_path / "out"), ran)
    path = str(tmp_path / "out" / "benchmark.settings.yaml")
    assert path in written
    assert FitSettings.load(path) == ran


def test_the_tuning_guide_names_every_knob_with_its_default():
    """docs/TUNING.md lists each knob of FitSettings as "`name` = `default`" (a knob added,
    renamed or given another default without its trade-off written down fails here), and no
    other: a retired knob's line goes with it."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "TUNING.md").read_text()
    missing = []
    knobs = set()
    for name, default, _, _ in FitSettings.knobs():
        knobs.add(name)
        shown = str(default).lower() if isinstance(default, bool) else str(default)
        if f"- `{name}` = `{shown}`" not in text:
            missing.append(f"{name} = {shown}")
    assert missing == [], missing
    listed = re.findall(r"^- `([\w.]+)` = `", text, flags=re.MULTILINE)
    assert [n for n in listed if n not in knobs] == []
