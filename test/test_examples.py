# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Every file of examples/ runs as its docstring says, each in its own process, and does what it
prints: the fit lands on the truth, the own library's template is fitted, the engine node's
accept and save write the registration, the station serves its page."""

import os
import re
import signal
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import yaml

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(name: str, *args, cwd) -> str:
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr[-3000:]
    return done.stdout


def test_every_example_is_run_here():
    tested = set(re.findall(r'"(\w+\.py)"', Path(__file__).read_text()))
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_fit_scan_file_fits_the_clicked_object_of_a_simulated_scan(tmp_path):
    out = run("fit_scan_file.py", cwd=tmp_path)
    truth = re.search(r"^truth: (\w+); the best is ([\d.]+) mm and ([\d.]+) deg", out, re.M)
    assert truth, out
    template, mm, deg = truth.group(1), float(truth.group(2)), float(truth.group(3))
    assert re.search(rf"^  1\. {template} .* fits$", out, re.M), out
    assert f"best: {template} at" in out
    assert mm <= 5 and deg <= 5, out


def test_own_library_writes_a_template_folder_and_fits_its_template(tmp_path):
    from affordance_registration import TemplateLibrary

    folder = tmp_path / "my_templates"
    out = run("own_library.py", folder, cwd=tmp_path)
    assert sorted(p.name for p in folder.iterdir()) == ["rotary_switch.stl", "rotary_switch.yaml"]
    assert list(TemplateLibrary.load(str(folder))) == ["rotary_switch"]
    assert "rotary_switch, fits: True" in out, out
    error = re.search(r"^pose error ([\d.]+) mm, ([\d.]+) deg$", out, re.M)
    assert error and float(error.group(1)) <= 5 and float(error.group(2)) <= 5, out


def test_engine_node_example_accepts_and_saves_over_ros(tmp_path):
    out = run("engine_node.py", tmp_path / "out", cwd=tmp_path)
    clicked = re.search(r"^clicked (\w+): shown (\w+), fits: True$", out, re.M)
    assert clicked and clicked.group(1) == clicked.group(2), out
    assert re.search(rf"^accept: accepted {clicked.group(1)} as object 1", out, re.M), out
    assert "save: saved 1 registration(s)" in out, out
    saved = yaml.safe_load((tmp_path / "out" / "registrations.yaml").read_text())
    assert [r["template"] for r in saved["registrations"]] == [clicked.group(1)]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_station_on_file_serves_its_page_until_interrupted(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, str(EXAMPLES / "station_on_file.py"), "--port", str(free_port())]
        + ["--out", str(tmp_path / "station")],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        lines = []
        for line in proc.stdout:  # until it says where the page is (or stops)
            lines.append(line)
            if line.startswith("open http"):
                break
        url = re.search(r"^open (http://\S+)", "".join(lines), re.M)
        assert url, "".join(lines)
        with urllib.request.urlopen(url.group(1), timeout=60) as page:
            assert page.status == 200
            assert b"<html" in page.read().lower()
        proc.send_signal(signal.SIGINT)  # as Ctrl-C: the station stops its nodes, then exits
        log = tmp_path / "station" / "station_scene.log"
        assert proc.wait(timeout=120) == 0, proc.stderr.read()[-2000:] + (
            log.read_text()[-3000:] if log.is_file() else ""
        )
        assert (tmp_path / "station" / "station_scene.log").is_file()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
