# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Drive the engine node from Python: start ``affordance_engine``, publish a cloud and a click as
a sensor and RViz would, read the fit from ``~/status``, then accept and save it through the
node's services (rclpy).

    python examples/engine_node.py [FOLDER]

The registrations file goes to FOLDER (default: a temporary folder). The cloud is a simulated
taskboard scan standing in for your sensor; msg_docs/README.md lists every topic, service and
parameter of the node.
"""

import json
import os
import signal
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # DDS stays on this machine

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from geometry_msgs.msg import PointStamped  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from affordance_registration import TemplateLibrary  # noqa: E402
from affordance_registration.evaluation.simulation import simulate_taskboard  # noqa: E402

FRAME = "camera_depth_optical_frame"
ENGINE = "/affordance_engine"
#: the status is latched (transient local): a late subscriber still gets the latest
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def cloud_message(points: np.ndarray) -> PointCloud2:
    """An unorganized PointCloud2 of float32 x, y, z (any layout with float x y z will do)."""
    msg = PointCloud2()
    msg.header.frame_id = FRAME
    msg.height, msg.width = 1, len(points)
    msg.fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
        for i, n in enumerate("xyz")
    ]
    msg.point_step, msg.row_step = 12, 12 * len(points)
    msg.is_dense = True
    msg.data = np.ascontiguousarray(points, dtype="<f4").tobytes()
    return msg


def wait_until(node, condition, what: str, timeout: float = 180.0, every=None):
    """Spin ``node`` until ``condition()`` holds (calling ``every()`` once a second)."""
    deadline, next_call = time.monotonic() + timeout, 0.0
    while not condition():
        if time.monotonic() > deadline:
            sys.exit(f"gave up waiting for {what}")
        if every is not None and time.monotonic() >= next_call:
            every()
            next_call = time.monotonic() + 1.0
        rclpy.spin_once(node, timeout_sec=0.1)


def call(node, service: str) -> Trigger.Response:
    client = node.create_client(Trigger, f"{ENGINE}/{service}")
    wait_until(node, lambda: client.wait_for_service(timeout_sec=0.1), f"{service}")
    future = client.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, future)
    return future.result()


def main(folder: str) -> None:
    registrations = os.path.join(folder, "registrations.yaml")
    engine_exe = os.path.join(os.path.dirname(sys.executable), "affordance_engine")
    engine = subprocess.Popen(
        [engine_exe, "--ros-args", "-p", f"registrations_file:={registrations}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    rclpy.init()
    node = rclpy.create_node("engine_example")
    try:
        status = {}

        def on_status(msg: String) -> None:
            status.update(json.loads(msg.data))

        node.create_subscription(String, f"{ENGINE}/status", on_status, LATCHED)
        points = node.create_publisher(PointCloud2, "points", 1)
        clicks = node.create_publisher(PointStamped, "clicked_point", 10)

        scan = simulate_taskboard(TemplateLibrary.load(), 7)  # stands in for your sensor
        cloud = cloud_message(scan.points)
        # the engine keeps the latest cloud; send it until the status says the engine has one
        wait_until(
            node,
            lambda: status.get("node", {}).get("cloud"),
            "the engine to hold the cloud",
            every=lambda: points.publish(cloud),
        )
        print(f"engine holds the cloud: {status['node']['cloud']['width']} points in {FRAME}")

        truth = scan.objects[0]
        click = PointStamped()
        click.header.frame_id = FRAME
        click.point.x, click.point.y, click.point.z = (float(v) for v in truth.click)
        wait_until(node, lambda: clicks.get_subscription_count() > 0, "the click's reader")
        clicks.publish(click)  # as RViz's "Publish Point" does
        wait_until(
            node,
            lambda: status.get("objects") and status["node"].get("idle"),
            "the click's fit",
        )
        shown = status["objects"][0]
        best = shown["candidates"][shown["shown"]]
        print(f"clicked {truth.template}: shown {best['template']}, fits: {best['fits']}")

        print(f"accept: {call(node, 'accept').message}")
        print(f"save: {call(node, 'save').message}")
    finally:
        node.destroy_node()
        rclpy.shutdown()
        engine.send_signal(signal.SIGINT)  # the node stops cleanly on SIGINT
        try:
            engine.wait(timeout=30)
        except subprocess.TimeoutExpired:
            engine.kill()
            engine.wait()
    print(f"registrations file: {registrations}")


if __name__ == "__main__":
    if len(sys.argv) > 1:
        os.makedirs(sys.argv[1], exist_ok=True)
        main(os.path.abspath(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(tmp)
