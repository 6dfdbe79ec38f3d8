# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""`affordance-registration station --demo` as a newcomer runs it (no browser needed): it prints
the URL once the page is served by a station talking to a live engine and a simulated scan, and
Ctrl-C stops every node. A taken port is one line and exit status 2."""

import os
import signal
import socket
import subprocess
import sys
import urllib.error
import urllib.request

import pytest
from browser_helpers import free_port
from ros_helpers import LATCHED, Client, ros_env
from std_msgs.msg import String


def test_station_demo_serves_the_page_and_stops_on_ctrl_c(tmp_path, ros_context):
    port = free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "affordance_registration.cli",
            "station",
            "--demo",
            "--port",
            str(port),
            "--out",
            str(tmp_path / "out"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ros_env(),
        start_new_session=True,
    )
    client = Client("station_demo_test")
    client.subscribe(String, "/affordance_engine/status", LATCHED)
    try:
        first = proc.stdout.readline()
        url = first.strip().removeprefix("operator station: ")
        assert url.startswith(f"http://127.0.0.1:{port}/?token=") and len(url) > 60, first
        with urllib.request.urlopen(url, timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        with pytest.raises(urllib.error.HTTPError, match="403"):  # no secret, no page
            urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30)
        # the engine has the simulated scan: a newcomer can click at once
        st = client.wait_for(
            lambda: (((client.status() or {}).get("node") or {}).get("cloud") or {}).get(
                "received"
            ),
            120,
            "the engine to receive the simulated scan",
        )
        assert st >= 1
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0, proc.stdout.read()
        log = (tmp_path / "out" / "station_demo.log").read_text()
        # the nodes' output holds the URL with the station's secret: for this user alone
        assert os.stat(tmp_path / "out" / "station_demo.log").st_mode & 0o777 == 0o600
        for node in ("affordance_engine", "affordance_simulated_scan", "affordance_station"):
            assert f"[{node}]: shutting down" in log, log[-2000:]
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_station_on_a_taken_port_is_one_line_and_exit_2():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        out = subprocess.run(
            [sys.executable, "-m", "affordance_registration.cli", "station", "--port", str(port)],
            capture_output=True,
            text=True,
            timeout=120,
            env=ros_env(),
        )
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.count("\n") == 1 and "cannot serve the page" in out.stderr, out.stderr
