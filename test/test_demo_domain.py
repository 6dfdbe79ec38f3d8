# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A demo keeps to itself: `affordance-registration station --demo` started without
ROS_DOMAIN_ID runs its nodes in a ROS domain of its own and says which -- the engine answers
there, not in the domain this test runs in (where engines of other tests, or of other users of
the machine, may be)."""

import json
import os
import re
import signal
import subprocess
import sys
import time

import rclpy
from browser_helpers import free_port
from rclpy.executors import SingleThreadedExecutor
from ros_helpers import LATCHED, ros_env
from std_msgs.msg import String

from affordance_registration.cli import DEMO_DOMAINS


def test_station_demo_without_a_domain_takes_its_own_and_says_which(tmp_path, ros_context):
    env = ros_env()
    env.pop("ROS_DOMAIN_ID", None)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "affordance_registration.cli",
            "station",
            "--demo",
            "--port",
            str(free_port()),
            "--out",
            str(tmp_path / "out"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        start_new_session=True,
    )
    context = rclpy.Context()
    try:
        first, second = proc.stdout.readline(), proc.stdout.readline()
        assert first.startswith("operator station: "), first + second
        found = re.search(r"in ROS domain (\d+), its own \(ROS_DOMAIN_ID was not set", second)
        assert found, second
        domain = int(found.group(1))
        assert domain in DEMO_DOMAINS and str(domain) != os.environ["ROS_DOMAIN_ID"]
        # a node in that domain hears the demo's engine (with the simulated scan)
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node("demo_domain_listener", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        heard = []
        node.create_subscription(
            String, "/affordance_engine/status", lambda m: heard.append(m.data), LATCHED
        )
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (
            heard and (json.loads(heard[-1]).get("node") or {}).get("cloud")
        ):
            executor.spin_once(timeout_sec=0.1)
        assert heard and json.loads(heard[-1])["node"]["cloud"], "no engine in the demo's domain"
        executor.remove_node(node)
        node.destroy_node()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0, proc.stdout.read()
    finally:
        if context.ok():
            rclpy.shutdown(context=context)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
