# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Helpers for the ROS tests: start nodes as separate processes, and a client node that spins in
a background thread of the test process."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

LATCHED = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def ros_env(extra=None) -> dict:
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env.update(extra or {})
    return env


class NodeProcess:
    """A node started as its own process; output goes to a log file; killed by PID on exit."""

    def __init__(self, argv, log_path, env=None, cwd=None):
        self.log_path = str(log_path)
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen(
            argv,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=ros_env(env),
            start_new_session=True,
            cwd=cwd,
        )

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        with open(self.log_path) as handle:
            return handle.read()

    def wait_output(self, text: str, timeout: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output():
                return True
            if self.proc.poll() is not None:
                return text in self.output()
            time.sleep(0.05)
        return False

    def interrupt(self, timeout: float = 5.0) -> tuple[int | None, float]:
        """SIGINT, then wait; returns (exit code or None, seconds taken)."""
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            code = None
        return code, time.monotonic() - t0

    def kill(self) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(timeout=5)
        self._log.close()


SLOW_ENGINE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "slow_engine_node.py")


def engine_process(
    tmp_path,
    params: dict | None = None,
    name="engine",
    slow_fit_s: float | None = None,
    params_file: str | None = None,
) -> NodeProcess:
    """The engine node as its own process (``params`` override ``params_file``); with
    ``slow_fit_s``, the real node with a fitter that takes that much longer for every click
    (``slow_engine_node.py``)."""
    node = (
        ["-m", "affordance_registration.ros.nodes.engine_node"]
        if slow_fit_s is None
        else [SLOW_ENGINE, str(slow_fit_s)]
    )
    args = [
        sys.executable,
        *node,
        "--ros-args",
        *(["--params-file", params_file] if params_file else []),
        "-p",
        f"registrations_file:={tmp_path / 'registrations.yaml'}",
    ]
    for key, value in (params or {}).items():
        args += ["-p", f"{key}:={value}"]
    return NodeProcess(args, tmp_path / f"{name}.log")


@contextlib.contextmanager
def engine_session(
    tmp_path,
    params: dict | None,
    client_name: str,
    publishers: dict,
    subscriptions=(),
    slow_fit_s: float | None = None,
    params_file: str | None = None,
    **extra,
):
    """An engine node of its own (``params``) and a client that subscribes to its status (and to
    ``subscriptions``: (type, topic, qos, keep) tuples) and publishes on ``publishers`` (key ->
    (type, topic, depth)), each matched to the node before this yields ``{"proc", "client",
    "pubs", "tmp", **extra}``. The node is stopped with SIGINT, then killed, and the tail of its
    output printed (pytest shows it for a failed test)."""
    from std_msgs.msg import String

    proc = engine_process(tmp_path, params, slow_fit_s=slow_fit_s, params_file=params_file)
    client = Client(client_name)
    try:
        client.subscribe(String, "/affordance_engine/status", LATCHED)
        for msg_type, topic, qos, keep in subscriptions:
            client.subscribe(msg_type, topic, qos, keep=keep)
        pubs = {
            key: client.node.create_publisher(msg_type, topic, depth)
            for key, (msg_type, topic, depth) in publishers.items()
        }
        for pub in pubs.values():
            client.wait_for_subscribers(pub, timeout=30)
        yield {"proc": proc, "client": client, "pubs": pubs, "tmp": tmp_path, **extra}
    finally:
        client.close()
        proc.interrupt()
        proc.kill()
        print(proc.output()[-3000:])


class Client:
    """A node in the test process, spun by a background thread."""

    def __init__(self, name: str):
        self.node = rclpy.create_node(name)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()
        self.latest: dict = {}
        self.history: dict = {}

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def subscribe(self, msg_type, topic, qos=10, keep=False):
        def cb(msg):
            self.latest[topic] = msg
            if keep:
                self.history.setdefault(topic, []).append(msg)

        self.node.create_subscription(msg_type, topic, cb, qos)

    def status(self, topic="/affordance_engine/status") -> dict | None:
        msg = self.latest.get(topic)
        return None if msg is None else json.loads(msg.data)

    def wait_for(self, predicate, timeout=60.0, what="condition"):
        deadline = time.monotonic() + timeout
        last_exc = None
        while time.monotonic() < deadline:
            try:
                value = predicate()
                if value:
                    return value
            except (KeyError, IndexError, TypeError) as exc:
                last_exc = exc
            time.sleep(0.02)
        raise AssertionError(
            f"timed out waiting for {what}" + (f" ({last_exc!r})" if last_exc else "")
        )

    def wait_for_cloud(
        self, timeout=60.0, what="the engine's cloud", topic="/affordance_engine/status"
    ):
        """Until the engine's status (on ``topic``) says it holds a cloud."""
        return self.wait_for(
            lambda: (self.status(topic) or {}).get("node", {}).get("cloud"), timeout, what
        )

    def call(self, srv_type, name, request=None, timeout=60.0):
        """The service's answer; waits for it (an event: it returns as soon as the answer is in),
        up to ``timeout`` s, generous because a busy engine answers after the fit under way."""
        client = self.node.create_client(srv_type, name)
        if not client.wait_for_service(timeout_sec=timeout):
            raise AssertionError(f"service {name} not available")
        future = client.call_async(request or srv_type.Request())
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        self.node.destroy_client(client)
        if not future.done():
            raise AssertionError(f"service {name} did not answer within {timeout} s")
        return future.result()

    def wait_for_subscribers(self, publisher, count=1, timeout=20.0):
        self.wait_for(
            lambda: publisher.get_subscription_count() >= count,
            timeout,
            f"a subscriber on {publisher.topic_name}",
        )

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2)
        self.executor.remove_node(self.node)
        self.node.destroy_node()


def get_parameters(client: "Client", names, node="/affordance_engine") -> dict:
    """The values of ``names`` (int, float, str or bool parameters) as ``node`` serves them."""
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import GetParameters

    res = client.call(
        GetParameters, f"{node}/get_parameters", GetParameters.Request(names=list(names))
    )
    field = {
        ParameterType.PARAMETER_INTEGER: "integer_value",
        ParameterType.PARAMETER_DOUBLE: "double_value",
        ParameterType.PARAMETER_STRING: "string_value",
        ParameterType.PARAMETER_BOOL: "bool_value",
    }
    return {name: getattr(value, field[value.type]) for name, value in zip(names, res.values)}


def rss_mb(pid: int) -> float:
    """The resident memory (MB) of process ``pid``, from /proc."""
    with open(f"/proc/{pid}/status") as handle:
        for line in handle:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")
