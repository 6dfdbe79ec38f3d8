# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Shared fixtures. Every test process gets its own ROS domain and log folder, and ROS discovery
stays on this machine (set before anything can import rclpy)."""

import os
import sys
import tempfile

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# `make test` runs the suite on pytest-xdist workers, which inherit the controller's environment:
# the controller (or a plain pytest run) picks an odd domain, and worker gwN the Nth odd domain
# after it, so two workers of one run never share a domain (and two runs rarely do). Test
# processes keep to odd domains: a demo started without ROS_DOMAIN_ID takes an even one
# (cli.DEMO_DOMAINS), and must not meet a test's nodes there.
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + 2 * (os.getpid() % 50)))
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _WORKER.startswith("gw") and _WORKER[2:].isdigit():
    _ODD = (int(os.environ["ROS_DOMAIN_ID"]) // 2 + int(_WORKER[2:])) % 51  # 51 odd in 0-101
    os.environ["ROS_DOMAIN_ID"] = str(1 + 2 * _ODD)
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="ar_roslog_"))
# where a node keeps its files when not told (an engine's registrations file), the run's own
os.environ["ROS_HOME"] = tempfile.mkdtemp(prefix="ar_roshome_")
# the files keeping the stations' URLs (with their secrets), in a folder of the test run's own
os.environ.setdefault("AFFORDANCE_RUNTIME_DIR", tempfile.mkdtemp(prefix="ar_runtime_"))

import pytest  # noqa: E402

try:  # a clear line, not a traceback, where the package's dependencies are missing
    import numpy  # noqa: E402,F401
    import scipy  # noqa: E402,F401
    import trimesh  # noqa: E402,F401
    import yaml  # noqa: E402,F401
    from hypothesis import settings as _hypothesis_settings  # noqa: E402
except ImportError as exc:
    raise pytest.UsageError(
        f"the tests need the package's Python dependencies ({exc}); install them into the "
        f"Python that runs the tests ({sys.executable}): pip install -r requirements.txt "
        f"-e '.[test]' (in a checkout `make setup` does that; for `colcon test`, into the "
        f"Python colcon runs with)"
    ) from None

from affordance_registration.core.templates import TemplateLibrary  # noqa: E402

# No Hypothesis deadline anywhere in the suite: these machines are shared and noisy, and a 200 ms
# per-example deadline is a wall-clock bound that a busy core breaks (a test's own @settings still
# sets its example count).
_hypothesis_settings.register_profile("suite", deadline=None)
_hypothesis_settings.load_profile("suite")


@pytest.fixture(scope="session")
def data_dir():
    """The shared real data folder (../shared/data or $AFFORDANCE_SHARED_DATA) holding the mOSD
    scenes; the test skips with one line without it."""
    from affordance_registration.evaluation import realdata as rd

    folder = rd.shared_data_dir()
    if folder is None or rd.osd_dir(folder) is None:
        pytest.skip(rd.SKIP_REASON)
    return folder


@pytest.fixture(scope="session")
def library():
    return TemplateLibrary.load()


@pytest.fixture(scope="session")
def panel_scene(library):
    from affordance_registration.evaluation.simulation import simulate_taskboard

    return simulate_taskboard(library, 7)


@pytest.fixture(scope="session")
def ros_context():
    """rclpy in the test process (one context for the session)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    yield
    rclpy.shutdown()


@pytest.fixture
def processes(tmp_path):
    """``start(argv or NodeProcess, name)``: the processes of a test (the browser tests), each
    stopped at its end (SIGINT first: a node killed outright stays in the DDS graph until its
    lease expires, and later tests would see it)."""
    from ros_helpers import NodeProcess

    started = []

    def start(argv_or_process, name=None):
        proc = (
            argv_or_process
            if isinstance(argv_or_process, NodeProcess)
            else NodeProcess(argv_or_process, tmp_path / f"{name}.log")
        )
        started.append(proc)
        return proc

    yield start
    for proc in started:
        proc.interrupt(timeout=10)
        proc.kill()
