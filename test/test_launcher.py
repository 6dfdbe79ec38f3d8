# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The YAML launch-file runner: parsing, substitutions, and starting/stopping real nodes."""

import os
import sys
import time

import numpy as np
import pytest
from ros_helpers import LATCHED, Client, NodeProcess, get_parameters
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from affordance_registration.ros.glue.conversions import xyz_to_pointcloud2
from affordance_registration.ros.standins.launcher import (
    Launcher,
    LaunchError,
    NodeAction,
    package_share,
    parse_launch_file,
)

LAUNCH = os.path.join(
    package_share("affordance_registration"), "launch_configs", "affordance_engine.launch.yaml"
)


def test_package_launch_file_parses_with_arguments():
    (node,) = parse_launch_file(LAUNCH, {"points": "/camera/depth/points"})
    cmd = node.command()
    assert os.path.basename(cmd[0]) == "affordance_engine"
    assert cmd[cmd.index("--ros-args") + 1 :][:2] == ["-r", "__node:=affordance_engine"]
    assert "points:=/camera/depth/points" in cmd
    assert "clicked_point:=clicked_point" in cmd
    params = cmd[cmd.index("--params-file") + 1]
    assert params.endswith("launch_configs/affordance_engine.params.yaml") and os.path.isfile(
        params
    )


def test_substitutions_and_errors(tmp_path, monkeypatch):
    monkeypatch.setenv("AR_TEST_NS", "station_1")
    f = tmp_path / "x.launch.yaml"
    f.write_text(
        "launch:\n"
        "- arg: {name: gain, default: '0.3'}\n"
        "- node:\n"
        "    pkg: affordance_registration\n"
        "    exec: affordance_engine\n"
        "    namespace: $(env AR_TEST_NS)\n"
        "    param:\n"
        "    - {name: linear_gain, value: $(var gain)}\n"
        "    - {name: fit.mode, value: $(env AR_UNSET_VAR free)}\n"
        "    args: --foo\n"
    )
    (node,) = parse_launch_file(str(f), {"gain": "0.7"})
    cmd = node.command()
    assert "__ns:=/station_1" in cmd and "linear_gain:=0.7" in cmd and "fit.mode:=free" in cmd
    assert cmd[1] == "--foo"
    with pytest.raises(LaunchError, match="unknown launch argument"):
        parse_launch_file(str(f), {"nope": "1"})
    bad = tmp_path / "bad.launch.yaml"
    bad.write_text("launch:\n- include: {file: other.yaml}\n")
    with pytest.raises(LaunchError, match=r"launch\[0\]: unsupported action 'include'"):
        parse_launch_file(str(bad))
    bad.write_text("launch:\n- node: {pkg: affordance_registration, exec: no_such_exe}\n")
    with pytest.raises(LaunchError, match="no_such_exe"):
        parse_launch_file(str(bad))[0].command()
    with pytest.raises(LaunchError, match="cannot read"):
        parse_launch_file(str(tmp_path / "missing.yaml"))
    # a node's key written twice: PyYAML kept the last one silently
    bad.write_text(
        "launch:\n- node:\n    pkg: affordance_registration\n"
        "    exec: affordance_engine\n    exec: affordance_spacemouse\n"
    )
    with pytest.raises(LaunchError, match=r"\(line 5\): the key 'exec' is written twice"):
        parse_launch_file(str(bad))


def test_an_empty_argument_is_passed_as_the_empty_string():
    """rcl refuses ``-p name:=`` at start: the launch file's empty ``settings_file`` default
    goes to the node as the empty string, a given file as its path."""
    (node,) = parse_launch_file(LAUNCH, {})
    assert 'settings_file:=""' in node.command()
    (node,) = parse_launch_file(LAUNCH, {"settings_file": "/tmp/fit.yaml"})
    assert "settings_file:=/tmp/fit.yaml" in node.command()


def test_launch_starts_the_engine_and_stops_it_cleanly(ros_context, tmp_path):
    """The launcher, as a user runs it (with the shared-memory Fast DDS profile): the node comes
    up with the remap and the settings file applied, serves, and stops on Ctrl-C. (The tests
    that start the engine from the launch file without arguments -- the demo, the session
    replay -- start it with the empty settings file.)"""
    (tmp_path / "fit.yaml").write_text("coarse:\n  samples: 32\n")
    proc = NodeProcess(
        [
            sys.executable,
            "-m",
            "affordance_registration.cli",
            "launch",
            LAUNCH,
            "points:=/test_launch/cloud",
            f"settings_file:={tmp_path / 'fit.yaml'}",
            f"registrations_file:={tmp_path / 'r.yaml'}",
            "--shm",
        ],
        tmp_path / "launch.log",
    )
    client = Client("launch_tester")
    try:
        client.subscribe(String, "/affordance_engine/status", LATCHED)
        pub = client.node.create_publisher(PointCloud2, "/test_launch/cloud", 1)
        client.wait_for_subscribers(pub, timeout=30)
        res = client.call(Trigger, "/affordance_engine/accept", timeout=20)
        assert not res.success and "no object selected" in res.message
        assert get_parameters(client, ["fit.coarse.samples"]) == {"fit.coarse.samples": 32}
        pub.publish(xyz_to_pointcloud2(np.random.default_rng(0).uniform(0, 1, (100, 3)), "cam"))
        client.wait_for_cloud(what="the cloud on the remapped topic")
        code, _ = proc.interrupt(timeout=30)
        assert code == 0, proc.output()  # ended on SIGINT: no SIGTERM, no SIGKILL
        assert "shutting down" in proc.output()
        assert "ended with" not in proc.output()
    finally:
        client.close()
        proc.kill()


def _script(folder, name: str, body: str) -> None:
    path = folder / name
    path.write_text(f"#!{sys.executable}\nimport pathlib, signal, sys, time\n{body}\n")
    path.chmod(0o755)


def test_stop_escalates_and_names_the_node_that_did_not_end_cleanly(tmp_path, monkeypatch):
    """One real process that ends on SIGINT, one that ignores it: the launcher SIGTERMs the
    second after the grace, says so, and returns 1; the first ends unremarked."""
    ready = tmp_path / "ready"
    ready.mkdir()
    common = (
        "signal.signal(signal.SIGINT, {})\n"
        f"pathlib.Path({str(ready)!r}, sys.argv[0].rsplit('/', 1)[-1]).touch()\n"
        "while True: time.sleep(0.05)\n"
    )
    _script(tmp_path, "polite_node_x", common.format("lambda *a: sys.exit(0)"))
    _script(tmp_path, "stubborn_node_x", common.format("signal.SIG_IGN"))
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    lines = []
    launcher = Launcher(
        [
            NodeAction("p", "polite_node_x", name="polite"),
            NodeAction("p", "stubborn_node_x", name="stubborn"),
        ],
        grace=0.5,
        log=lines.append,
    )
    launcher.start()
    try:
        deadline = time.monotonic() + 60
        while len(list(ready.iterdir())) < 2:  # both have their SIGINT handler set
            assert time.monotonic() < deadline and all(p.poll() is None for p in launcher.procs)
            time.sleep(0.05)
        assert launcher.stop() == 1
    finally:
        for p in launcher.procs:
            if p.poll() is None:
                p.kill()
    ended = [line for line in lines if "ended with" in line]
    assert len(ended) == 1 and "stubborn" in ended[0], lines
    assert "signal SIGTERM after SIGTERM" in ended[0]
