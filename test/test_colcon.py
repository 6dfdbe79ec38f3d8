# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The package as a ROS 2 developer builds it: a colcon workspace with the package in ``src/``,
built with ``colcon build`` and with ``colcon build --symlink-install`` (colcon-common-extensions
and ament_package from the test extra), each install used the way ``ros2 run`` uses it -- the
workspace's ``local_setup.sh`` sourced, the executables run from
``install/affordance_registration/lib/affordance_registration/``.

The workspace is a copy of this checkout in a temporary folder; the builds take about 20 s on an
idle machine. ``colcon test`` is checked to discover and run the package's tests through pytest
on one quick test file, and to collect the whole suite when given no file (running all of it
inside it would repeat ``make test``)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from browser_helpers import free_port

ROOT = Path(__file__).resolve().parents[1]
PKG = "affordance_registration"
VENV_BIN = Path(sys.executable).parent
#: what a developer's checkout holds that is not the package's source
IGNORE = shutil.ignore_patterns(
    ".venv",
    ".git",
    "__pycache__",
    "*.egg-info",
    ".pytest_cache",
    ".hypothesis",
    "demo_output",
    "bench_output",
    "station_output",
    "build",
    "install",
    "log",
)
SCRIPTS = (
    "affordance-registration",
    "affordance_engine",
    "affordance_spacemouse",
    "affordance_station",
    "affordance_simulated_scan",
    "affordance_file_scan",
)

pytestmark = pytest.mark.colcon


def _env() -> dict:
    """This process's environment without a sourced workspace, the venv's tools first."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH")
    }
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    return env


class Workspace:
    def __init__(self, root: Path, kind: str):
        self.root, self.kind = root, kind
        self.build = root / f"build_{kind}"
        self.install = root / f"install_{kind}"
        self.prefix = self.install / PKG
        self.lib = self.prefix / "lib" / PKG
        self.share = self.prefix / "share" / PKG

    def sourced(self, argv, **kw) -> list[str]:
        """``argv`` run in a shell that sourced the install's local_setup.sh first."""
        return ["sh", "-c", f'. "{self.install}/local_setup.sh" && exec "$@"', "sh", *argv]

    def run(self, argv, timeout=300, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(
            self.sourced([str(a) for a in argv]),
            capture_output=True,
            text=True,
            timeout=timeout,
            env=_env(),
            cwd=kw.get("cwd", "/"),
        )

    def start(self, argv, log: Path) -> subprocess.Popen:
        handle = open(log, "w")
        return subprocess.Popen(
            self.sourced([str(a) for a in argv]),
            stdout=handle,
            stderr=subprocess.STDOUT,
            env=_env(),
            cwd="/",
            start_new_session=True,
        )


def _colcon_argv(*args, log_base="log") -> list[str]:
    return [str(VENV_BIN / "colcon"), "--log-base", log_base, *args]


def _colcon(root: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        _colcon_argv(*args), cwd=root, capture_output=True, text=True, env=_env(), timeout=600
    )


def _started(argv, cwd) -> subprocess.Popen:
    return subprocess.Popen(
        argv, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env()
    )


def _finished(proc: subprocess.Popen, timeout: float) -> subprocess.CompletedProcess:
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        stdout, stderr = proc.communicate()
        raise
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


@pytest.fixture(scope="module")
def workspaces(tmp_path_factory):
    """The plain and the symlink install of one workspace, built at the same time (separate
    build, install and log folders: the two builds share only the read-only src/)."""
    root = tmp_path_factory.mktemp("colcon_ws")
    shutil.copytree(ROOT, root / "src" / PKG, ignore=IGNORE, symlinks=True)
    kinds = (("plain", []), ("symlink", ["--symlink-install"]))
    builds = {}
    try:
        for kind, extra in kinds:
            ws = Workspace(root, kind)
            builds[kind] = (
                ws,
                extra,
                _started(
                    _colcon_argv(
                        "build",
                        "--build-base",
                        ws.build.name,
                        "--install-base",
                        ws.install.name,
                        "--event-handlers",
                        "console_direct+",
                        *extra,
                        log_base=f"log_{kind}",
                    ),
                    root,
                ),
            )
        built = {}
        for kind, (ws, extra, proc) in builds.items():
            out = _finished(proc, 600)
            assert out.returncode == 0, (
                f"colcon build {' '.join(extra)}:\n{out.stdout[-3000:]}{out.stderr[-3000:]}"
            )
            # setuptools says nothing about options it does not know (tests_require was one)
            assert "Unknown distribution option" not in out.stdout + out.stderr
            built[kind] = ws
    finally:
        for _, _, proc in builds.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return built


def _stop(proc: subprocess.Popen) -> int | None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            return proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5)
            return None
    return proc.returncode


def _wait_log(log: Path, proc: subprocess.Popen, text: str, timeout: float) -> str:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = log.read_text()
        if text in got:
            return got
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise AssertionError(f"no '{text}' in {log.name}:\n{log.read_text()[-3000:]}")


def test_symlink_install_links_the_share_files(workspaces):
    """What the template folder check has to follow: --symlink-install links every file on its
    own, into the build folder's links to src/."""
    ws = workspaces["symlink"]
    yaml_file = ws.share / "models" / "ball_valve.yaml"
    assert yaml_file.is_symlink()
    assert (ws.share / "models" / "meshes" / "ball_valve.stl").is_symlink()
    assert not (workspaces["plain"].share / "models" / "ball_valve.yaml").is_symlink()


@pytest.mark.parametrize("kind", ["plain", "symlink"])
def test_every_console_script_is_installed_for_ros2_run(workspaces, kind):
    ws = workspaces[kind]
    for script in SCRIPTS:
        path = ws.lib / script
        assert path.is_file() and os.access(path, os.X_OK), path
    out = ws.run([ws.lib / "affordance-registration", "--help"])
    assert out.returncode == 0 and "station" in out.stdout, out.stderr
    # `ros2 launch affordance_registration engine.launch.py` finds it in the share folder
    assert (ws.share / "launch" / "engine.launch.py").is_file()
    # the installed code runs, not this checkout's
    where = ws.run(
        [VENV_BIN / "python", "-c", "import affordance_registration as a; print(a.__file__)"]
    )
    assert where.stdout.startswith(str(ws.root)), where.stdout + where.stderr


@pytest.mark.parametrize("kind", ["plain", "symlink"])
def test_installed_nodes_start_and_talk(workspaces, kind, tmp_path):
    """``ros2 run``-style: the installed engine loads the installed library (the plain
    install's by default, the symlink install's given as its share folder of links: the case
    that failed the template folder check), the
    installed simulated scan feeds it, the installed station serves its page; each stops on
    SIGINT."""
    ws = workspaces[kind]
    port = free_port()
    procs = {}
    logs = {name: tmp_path / f"{name}.log" for name in ("engine", "scan", "station", "spacemouse")}
    library = [] if kind == "plain" else ["-p", f"templates_dir:={ws.share / 'models'}"]
    try:
        procs["engine"] = ws.start(
            [
                ws.lib / "affordance_engine",
                "--ros-args",
                *library,
                "-p",
                f"registrations_file:={tmp_path / 'r.yaml'}",
            ],
            logs["engine"],
        )
        procs["scan"] = ws.start(
            [ws.lib / "affordance_simulated_scan", "--ros-args", "-p", "seed:=3"], logs["scan"]
        )
        if kind == "plain":  # no device here: it says it is looking for one, and waits
            procs["spacemouse"] = ws.start([ws.lib / "affordance_spacemouse"], logs["spacemouse"])
            _wait_log(logs["spacemouse"], procs["spacemouse"], "looking for a SpaceMouse", 120)
        if kind == "symlink":
            procs["station"] = ws.start(
                [ws.lib / "affordance_station", "--ros-args", "-p", f"port:={port}"],
                logs["station"],
            )
            _wait_log(
                logs["station"],
                procs["station"],
                f"operator station on http://127.0.0.1:{port}",
                120,
            )
        _wait_log(
            logs["engine"], procs["engine"], "ready: 7 templates (ball_valve, box, cylinder, ", 120
        )
        _wait_log(logs["scan"], procs["scan"], "simulated panel scan (seed 3)", 120)
        # the engine logs the scan's cloud when it arrives: the nodes talk over DDS
        _wait_log(logs["engine"], procs["engine"], "cloud: ", 120)
    finally:
        codes = {name: _stop(p) for name, p in procs.items()}
    assert all(code is not None for code in codes.values()), codes


def test_demo_runs_from_the_symlink_install(workspaces, tmp_path):
    """``affordance-registration demo`` from the install: the recorded session is installed
    with the package (share/affordance_registration/test/data/session)."""
    ws = workspaces["symlink"]
    assert (ws.share / "test" / "data" / "session" / "bag" / "metadata.yaml").exists()
    out = ws.run(
        [ws.lib / "affordance-registration", "demo", "--out", tmp_path / "demo"], timeout=400
    )
    assert out.returncode == 0 and out.stdout.strip().endswith("DEMO OK"), (
        out.stdout[-2000:] + out.stderr[-2000:]
    )
    assert (tmp_path / "demo" / "registrations.yaml").is_file()


def test_colcon_test_runs_the_package_tests(workspaces):
    """``colcon test`` finds pytest for the package and runs the test files it is given; the
    results land in pytest.xml for ``colcon test-result``."""
    ws = workspaces["plain"]
    out = _colcon(
        ws.root,
        "test",
        "--build-base",
        ws.build.name,
        "--install-base",
        ws.install.name,
        "--event-handlers",
        "console_direct+",
        "--pytest-args",
        "test/test_files.py",
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    report = ET.parse(ws.build / PKG / "pytest.xml").getroot()
    suite = report if report.tag == "testsuite" else report.find("testsuite")
    assert (
        int(suite.get("tests")) >= 1
        and int(suite.get("failures")) == 0
        and int(suite.get("errors")) == 0
    )
    result = _colcon(ws.root, "test-result", "--test-result-base", ws.build.name)
    assert result.returncode == 0, result.stdout + result.stderr


def test_colcon_test_collects_the_whole_suite(workspaces):
    """Without arguments ``colcon test`` runs the whole suite: in the workspace pytest collects
    every test the source tree's ``make test`` collects (collected only: running it here would
    repeat ``make test``)."""
    ws = workspaces["plain"]
    # the source tree's collection runs while the workspace's does (each is mostly imports)
    here = _started(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "test"],
        ROOT,
    )
    try:
        out = _colcon(
            ws.root,
            "test",
            "--build-base",
            ws.build.name,
            "--install-base",
            ws.install.name,
            "--event-handlers",
            "console_direct+",
            "--pytest-args",
            "--collect-only",
            "-q",
        )
    finally:
        here = _finished(here, 300)
    counted = [re.search(r"(\d+) tests? collected", o) for o in (out.stdout, here.stdout)]
    assert all(counted), out.stdout[-2000:] + here.stdout[-2000:]
    in_workspace, in_tree = (int(m.group(1)) for m in counted)
    assert in_workspace == in_tree > 300, (in_workspace, in_tree)
