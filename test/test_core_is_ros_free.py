# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The layers stay apart, checked in fresh interpreters: core/ and the ROS-free evaluation
modules never import ROS, and no product module (core/, ros/, the CLI's product commands) imports
the evaluation package."""

import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "affordance_registration"
#: the evaluation modules that are ROS nodes or drive them (the simulated sensor, the recorded
#: operator session, the bench's latencies over ROS); every other evaluation module is ROS-free
#: like core
EVALUATION_ROS = (
    "affordance_registration.evaluation.session",
    "affordance_registration.evaluation.simulated_scan",
    "affordance_registration.evaluation.ros_latency",
)
ROS_MODULES = (
    "rclpy",
    "sensor_msgs",
    "geometry_msgs",
    "visualization_msgs",
    "std_msgs",
    "std_srvs",
    "viser",
)


def _loaded_after_importing(packages: list[str], skip: tuple[str, ...] = ()) -> set[str]:
    code = (
        "import sys, importlib, pkgutil\n"
        f"for name in {packages!r}:\n"
        "    pkg = importlib.import_module(name)\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, name + '.'):\n"
        f"        if not m.name.startswith({skip!r}):\n"
        "            importlib.import_module(m.name)\n"
        "print(' '.join(sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_importing_core_and_evaluation_loads_no_ros():
    loaded = _loaded_after_importing(
        ["affordance_registration.core", "affordance_registration.evaluation"], EVALUATION_ROS
    )
    bad = sorted(m for m in loaded if m.split(".")[0] in ROS_MODULES)
    assert bad == [], f"core or evaluation pulled in ROS modules: {bad[:10]}"


def test_no_product_module_imports_the_evaluation_package():
    loaded = _loaded_after_importing(
        ["affordance_registration.core", "affordance_registration.ros"]
    )
    assert "rclpy" in loaded  # the ROS modules really were imported
    bad = sorted(m for m in loaded if m.startswith("affordance_registration.evaluation"))
    assert bad == [], f"a product module imports the evaluation package: {bad}"


def test_core_holds_no_simulator_generator_or_renderer():
    names = {p.stem for p in (PACKAGE / "core").rglob("*.py")}
    assert not names & {"simulation", "taskboard", "render", "bench", "realscans", "session"}


def test_ros_is_laid_out_by_role():
    ros = PACKAGE / "ros"
    loose = sorted(p.name for p in ros.glob("*.py"))
    assert len(loose) <= 6, loose
    roles = {p.name for p in ros.iterdir() if (p / "__init__.py").is_file()}
    assert {"nodes", "station", "glue", "standins", "devices"} <= roles, roles
