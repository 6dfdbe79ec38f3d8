# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The command line, run as a user would: separate processes, exit codes, one-line errors."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import yaml

from affordance_registration.core.transforms import pose_error


def run(*args, check=False):
    out = subprocess.run(
        [sys.executable, "-m", "affordance_registration.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if check:
        assert out.returncode == 0, out.stderr
    return out


def run_all(*commands):
    """Independent CLI commands (argument lists) run at the same time, each its own process;
    their results in order (mostly each one's start-up: the second core takes half)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "affordance_registration.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for args in commands
    ]
    results = []
    try:
        for proc in procs:
            stdout, stderr = proc.communicate(timeout=300)
            results.append(subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return results


@pytest.fixture(scope="module")
def scene11(tmp_path_factory):
    """``simulate --seed 11``, run once for the tests that fit its scene (they only read it):
    (its folder, the command's stdout)."""
    out = tmp_path_factory.mktemp("cli") / "scene"
    res = run("simulate", "--out", str(out), "--seed", "11", check=True)
    return out, res.stdout


def test_simulate_then_fit_json_contract(scene11, library):
    out, stdout = scene11
    assert "5 objects" in stdout
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    obj = truth["objects"][0]
    fit = ("fit", "--scene", str(out / "scene.ply"), "--point", *map(str, obj["click"]))
    res, table = run_all((*fit, "--json"), fit)  # the JSON and the readable table
    assert res.returncode == 0 and table.returncode == 0, res.stderr + table.stderr
    doc = json.loads(res.stdout)
    assert set(doc) == {
        "point",
        "sensor_origin",
        "verdict",
        "no_match",
        "reason",
        "noise",
        "candidates",
        "ambiguity",
        "timing_s",
    }
    assert doc["ambiguity"]["settled"] is True and doc["ambiguity"]["kinds"] == []
    assert len(doc["point"]) == 3 and doc["sensor_origin"] == [0.0, 0.0, 0.0]
    assert doc["verdict"] == "fits" and doc["no_match"] is False
    ranks = [c["rank"] for c in doc["candidates"]]
    assert ranks == sorted(ranks) and ranks[0] == 1
    for c in doc["candidates"]:
        assert {
            "rank",
            "template",
            "likelihood",
            "residual",
            "pose",
            "coverage",
            "inlier_rmse",
            "fits",
            "converged",
            "prefiltered",
        } <= set(c)
        assert c["prefiltered"] is False  # five templates: the prefilter does not act
        assert np.asarray(c["pose"]).shape == (4, 4)
    best = doc["candidates"][0]
    assert best["template"] == obj["template"]
    # the leading candidates carry their template's waypoints, placed with their fit
    assert all("waypoints" in c for c in doc["candidates"][:3])
    assert all("waypoints" not in c for c in doc["candidates"][3:])
    tpl = library[best["template"]]
    assert [w["name"] for w in best["waypoints"]] == [w.name for w in tpl.waypoints]
    for w, declared in zip(best["waypoints"], tpl.waypoints):
        if declared.part is None:  # a fixed waypoint: the pose times the declared one
            assert np.allclose(
                w["pose"], np.asarray(best["pose"]) @ declared.T_parent_ee, atol=1e-6
            )
        assert (
            np.linalg.norm(np.asarray(w["position"]) - np.asarray(best["pose"])[:3, 3])
            < tpl.diameter
        )
    dt, dr = pose_error(
        np.asarray(best["pose"]),
        np.asarray(obj["T_scene_model"]),
        library[obj["template"]].symmetry,
    )
    assert dt < 0.005 and dr < math.radians(5)
    # the readable table names the templates in rank order, says what orders it, and gives
    # each its verdict (so a higher p below a lower one is no contradiction)
    lines = table.stdout.splitlines()
    assert lines[1].startswith(f"{obj['template']} fits")  # the verdict, then the table
    assert lines[2].startswith("ranked best first:") and "within its group" in lines[2]
    assert len(lines[2]) <= 160
    assert lines[3].split()[:3] == ["rank", "template", "verdict"]
    said = {True: "fits", False: "does not fit", None: "not judged"}
    for row, c in zip(lines[4:], doc["candidates"]):
        assert row.split()[1] == c["template"] and row[29:41].strip() == said[c["fits"]], row


def _one_line_error(res):
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr
    return lines[0]


def test_simulate_bad_input_leaves_no_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    broken = tmp_path / "lib"
    broken.mkdir()
    (broken / "valve.yaml").write_text("name: valve\nmesh: nowhere.stl\n")
    words, negative, blocked, library = run_all(
        ("simulate", "--out", str(tmp_path / "a"), "--seed", "minus one"),
        ("simulate", "--out", str(tmp_path / "b"), "--seed", "-4"),
        ("simulate", "--out", str(blocker / "out"), "--seed", "1"),
        ("simulate", "--out", str(tmp_path / "c"), "--templates", str(broken)),
    )
    # one rule, one wording, for words and for numbers out of range
    for res, out in ((words, "a"), (negative, "b")):
        line = _one_line_error(res)
        assert "--seed must be an integer in [0, 2147483647]" in line, line
        assert not (tmp_path / out).exists()
    line = _one_line_error(blocked)
    assert str(blocker / "out") in line
    line = _one_line_error(library)
    assert "valve.yaml" in line and "key 'mesh'" in line and not (tmp_path / "c").exists()


def test_fit_bad_input(tmp_path):
    line = _one_line_error(
        run("fit", "--scene", str(tmp_path / "missing.ply"), "--point", "0", "0", "1")
    )
    assert "missing.ply" in line
    (tmp_path / "empty.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 0\n"
        "property float x\nproperty float y\nproperty float z\n"
        "end_header\n"
    )
    line = _one_line_error(
        run("fit", "--scene", str(tmp_path / "empty.ply"), "--point", "0", "0", "1")
    )
    assert "no points" in line


def test_templates_the_prefilter_set_aside_have_no_verdict(tmp_path, scene11, library):
    """With 15 templates (the five and copies of them scaled 0.75 and 1.4) the prefilter sets
    clearly worse ones aside: --json gives them ``fits`` null and coverage 0, the table a '-'
    where their coverage and RMSE would be; the fitted ones carry their verdict."""
    import shutil

    from affordance_registration.core.templates import default_models_dir

    models = default_models_dir()
    lib = tmp_path / "templates"
    shutil.copytree(f"{models}/meshes", lib / "meshes")
    for name in library.specific():
        with open(f"{models}/{name}.yaml", encoding="utf-8") as f:
            doc = yaml.safe_load(f)
        for label, scale in (("", 1.0), ("_small", 0.75), ("_large", 1.4)):
            (lib / f"{name}{label}.yaml").write_text(
                yaml.safe_dump(dict(doc, name=f"{name}{label}", mesh_scale=scale))
            )
    out, _ = scene11
    obj = yaml.safe_load((out / "truth.yaml").read_text())["objects"][0]
    args = (
        "fit",
        "--scene",
        str(out / "scene.ply"),
        "--point",
        *map(str, obj["click"]),
        "--templates",
        str(lib),
    )
    as_json, as_table = run_all((*args, "--json"), args)
    assert as_json.returncode == 0 and as_table.returncode == 0, as_json.stderr + as_table.stderr
    cands = json.loads(as_json.stdout)["candidates"]
    assert len(cands) == 15 and cands[0]["template"] == obj["template"]
    aside = [c for c in cands if c["prefiltered"]]
    assert aside and all(c["fits"] is None and c["coverage"] == 0 for c in aside)
    assert all(isinstance(c["fits"], bool) for c in cands if not c["prefiltered"])
    rows = {
        line.split()[1]: line.split()
        for line in as_table.stdout.splitlines()
        if line.split()[:1] and line.split()[0].isdigit()
    }
    assert len(rows) == 15
    for c in cands:  # set aside: "not judged", its coverage, explained and rmse "-"
        row = " ".join(rows[c["template"]])
        assert ("not judged" in row and " - - - " in row) == c["prefiltered"], row


def test_settings_print_load_and_reach_the_fit(tmp_path, scene11):
    """``settings`` prints the defaults as YAML (what ``fit --settings`` reads), ``settings FILE``
    the whole of what a partial file gives; ``fit --settings`` fits with them (a 2 mm snap
    distance refuses a click 1 cm off the surface) and a bad file is one line, exit 2."""
    from affordance_registration.core.registration import FitSettings

    res = run("settings", check=True)
    assert yaml.safe_load(res.stdout) == FitSettings().to_dict()
    partial = tmp_path / "fit.yaml"
    partial.write_text("crop:\n  snap_distance: 0.002\nseed: 4\n")
    res = run("settings", str(partial), check=True)
    assert FitSettings.from_dict(yaml.safe_load(res.stdout)) == FitSettings(seed=4).with_(
        **{"crop.snap_distance": 0.002}
    )
    out, _ = scene11
    obj = yaml.safe_load((out / "truth.yaml").read_text())["objects"][0]
    off = list(obj["click"])
    off[2] -= 0.01
    args = ("fit", "--scene", str(out / "scene.ply"), "--point", *map(str, off))
    bad = (
        ("crop:\n  snap: 1\n", "unknown setting crop.snap"),
        ("mode: sideways\n", "mode must be one of: auto, mounted, free"),
        ("[1, 2\n", "not valid YAML (line 2)"),
    )
    for k, (text, _) in enumerate(bad):
        (tmp_path / f"bad{k}.yaml").write_text(text)
    snapped, default, *refused = run_all(
        (*args, "--settings", str(partial)),
        (*args, "--json"),
        *((*args, "--settings", str(tmp_path / f"bad{k}.yaml")) for k in range(len(bad))),
    )
    line = _one_line_error(snapped)
    assert "limit 0.2 cm" in line and res.returncode == 0
    assert default.returncode == 0, default.stderr  # the default 3 cm snaps it
    for (_, words), res in zip(bad, refused):
        assert res.returncode == 2 and words in _one_line_error(res), res.stderr
    res = run("settings", str(tmp_path / "nowhere.yaml"))
    assert res.returncode == 2 and "nowhere.yaml: cannot read: No such file" in _one_line_error(
        res
    )
