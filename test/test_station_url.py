# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The first URL the station prints is the one that works: ``affordance-registration station``
and the ``affordance_station`` node print the URL with the access secret on the terminal before
anything else that looks like an address (viser's own banner named the bare address, which
answers 403), it answers 200 and opens the operator page in a real browser, and the secret is
printed once -- never through the ROS logger, whose lines go to log files and /rosout."""

import os
import re
import signal
import subprocess
import sys
import time
import urllib.request

import pytest
from browser_helpers import browser_page, chromium_missing, free_port, station_command
from ros_helpers import ros_env

URL = re.compile(r"https?://\S+")


def _first_url(argv, tmp_path, timeout_s: float = 120.0):
    """Start ``argv`` (stdout and stderr merged, in the order written) and return (the process,
    the first URL it printed, everything it printed up to that line)."""
    log_dir = tmp_path / "ros_log"
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ros_env({"ROS_LOG_DIR": str(log_dir)}),
        start_new_session=True,
    )
    seen, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line)
        found = URL.search(line)
        if found:
            return proc, found.group(0), "".join(seen)
    proc.kill()
    raise AssertionError(f"no URL printed: {''.join(seen)[-2000:]}")


def _stop(proc) -> str:
    """SIGINT, then what the process printed after its URL."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
    try:
        rest, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        rest, _ = proc.communicate()
    return rest


def _logged(folder) -> str:
    out = []
    for root, _, files in os.walk(folder):
        for name in files:
            with open(os.path.join(root, name), errors="replace") as handle:
                out.append(handle.read())
    return "\n".join(out)


@pytest.mark.parametrize("command", ["station", "affordance_station"])
def test_the_first_url_printed_answers_and_opens_the_page(command, tmp_path):
    port = free_port()
    argv = (
        [sys.executable, "-m", "affordance_registration.cli", "station", "--port", str(port)]
        if command == "station"
        else station_command(port, None)
    )
    proc, url, before = _first_url(argv, tmp_path)
    try:
        assert url.startswith(f"http://127.0.0.1:{port}/?token="), before
        with urllib.request.urlopen(url, timeout=30) as answer:
            assert answer.status == 200
        if command == "station":  # the page it names opens in a real browser
            missing = chromium_missing()
            assert not missing, missing
            with browser_page(url, details=False) as page:  # (it waits for the panel)
                assert page.get_by_role("button", name="Accept", exact=True).is_visible()
    finally:
        after = _stop(proc)
    secret = url.split("token=", 1)[1]
    assert (before + after).count(secret) == 1, "the secret was printed more than once"
    assert secret not in _logged(tmp_path / "ros_log"), "the secret is in a ROS log file"
