# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ``affordance_spacemouse`` node: a 3Dconnexion device read through a
:class:`~affordance_registration.ros.devices.spacemouse.HidBackend`, published as
``spacenav/twist`` and ``spacenav/joy`` exactly as the spacenav driver does (see :mod:`.spacemouse`
for the axes)."""

from __future__ import annotations

import math
import os
import time

import numpy as np
from geometry_msgs.msg import Twist, TwistStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import Joy

from ..devices.spacemouse import (
    DEVICES,
    AxisState,
    DeviceInfo,
    HidBackend,
    find_device,
    make_backend,
    parse_report,
    to_ros,
)
from ..glue.throttle import Throttle

__all__ = ["SpaceMouseNode", "PARAMETERS"]

#: a warning that repeats (no device, cannot open it) is logged once every this many seconds
WARN_EVERY_S = 5.0

#: name: (default, description)
PARAMETERS = {
    "hid_backend": ("hidapi", "hidapi, or fifo:PATH for scripted reports (tests, demos)"),
    "device_path": ("", "open this HID path ('' = first known SpaceMouse)"),
    "vendor_id": (0, "with product_id: open this USB id"),
    "product_id": (0, "with vendor_id: open this USB id"),
    "full_scale": (512.0, "raw value that maps to 1.0 (the spacenav driver's default)"),
    "deadband": (0.02, "per-axis deadband, fraction of full scale"),
    "linear_scale": ([1.0, 1.0, 1.0], "per-axis linear scale"),
    "angular_scale": ([1.0, 1.0, 1.0], "per-axis angular scale"),
    "publish_rate": (30.0, "Twist/Joy rate while the cap moves (Hz)"),
    "zero_when_static": (True, "publish zeros once when the cap is released"),
    "static_timeout_s": (0.25, "no motion report for this long counts as released"),
    "use_twist_stamped": (False, "publish geometry_msgs/TwistStamped instead of Twist"),
    "frame_id": ("spacenav", "frame of TwistStamped and Joy headers"),
    "retry_interval": (1.0, "seconds between attempts to find or reopen the device"),
}


class SpaceMouseNode(Node):
    """Reads the device (reopened when it comes back) and publishes twists and Joy."""

    def __init__(self, backend: HidBackend | None = None):
        super().__init__("affordance_spacemouse")
        for name, (default, desc) in PARAMETERS.items():
            self.declare_parameter(name, default, ParameterDescriptor(description=desc))
        self.p = {name: self.get_parameter(name).value for name in PARAMETERS}
        problem = self._check(self.p)
        if problem:
            raise ValueError(problem)
        self.add_on_set_parameters_callback(self._on_set)
        self.backend = backend or make_backend(self.p["hid_backend"])
        twist_type = TwistStamped if self.p["use_twist_stamped"] else Twist
        self.pub_twist = self.create_publisher(twist_type, "spacenav/twist", 10)
        self.pub_joy = self.create_publisher(Joy, "spacenav/joy", 10)
        self.hid_handle = None
        self.device = None
        self.state = AxisState()
        self._moving = False
        self._next_try = 0.0
        self._warnings = Throttle(WARN_EVERY_S)
        self._permission_reported: set[str] = set()
        self.create_timer(1.0 / self.p["publish_rate"], self._on_timer)
        self.get_logger().info("looking for a SpaceMouse")

    @staticmethod
    def _check(p) -> str | None:
        if not p["full_scale"] > 0:
            return "full_scale must be positive"
        if not 0 <= p["deadband"] < 1:
            return "deadband must be in [0, 1)"
        for k in ("linear_scale", "angular_scale"):
            if len(p[k]) != 3 or not all(math.isfinite(v) for v in p[k]):
                return f"{k} must be 3 finite numbers"
        if not p["publish_rate"] > 0 or not p["static_timeout_s"] > 0:
            return "publish_rate and static_timeout_s must be positive"
        return None

    def _on_set(self, parameters):
        new = dict(self.p)
        for prm in parameters:
            if prm.name in new:
                new[prm.name] = prm.value
        problem = self._check(new)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        if any(
            prm.name in ("hid_backend", "use_twist_stamped", "publish_rate") for prm in parameters
        ):
            return SetParametersResult(successful=False, reason="read at start only")
        self.p = new
        return SetParametersResult(successful=True)

    def _warn(self, msg: str):
        """A warning that repeats while the device is missing: once every WARN_EVERY_S."""
        if self._warnings.due(msg):
            self.get_logger().warning(msg)

    def _connect(self):
        now = time.monotonic()
        if now < self._next_try:
            return
        self._next_try = now + self.p["retry_interval"]
        d = find_device(
            self.backend, self.p["device_path"], self.p["vendor_id"], self.p["product_id"]
        )
        if d is None:
            self._warn(
                "no SpaceMouse found; retrying (affordance-registration spacemouse "
                "--list shows what is attached)"
            )
            return
        path = (
            d["path"].decode(errors="replace") if isinstance(d["path"], bytes) else str(d["path"])
        )
        try:
            self.hid_handle = self.backend.open(d["path"])
        except PermissionError:
            self._permission_error(path)
            return
        except OSError as exc:
            if path.startswith("/dev/") and not os.access(path, os.R_OK | os.W_OK):
                self._permission_error(path)
            else:
                self._warn(f"cannot open {path}: {exc}; retrying")
            return
        key = (d["vendor_id"], d["product_id"])
        info = DEVICES.get(key, DeviceInfo(d.get("product_string") or "HID device", 2))
        self.device = (path, info)
        self.state = AxisState(info.buttons)
        self.get_logger().info(f"opened {info.name} ({key[0]:04x}:{key[1]:04x}) at {path}")

    def _permission_error(self, path: str):
        if path in self._permission_reported:
            return
        self._permission_reported.add(path)
        self.get_logger().error(
            f"permission denied opening {path}: install the udev rule "
            f"launch_configs/99-spacemouse.rules into /etc/udev/rules.d/, run "
            f"'sudo udevadm control --reload && sudo udevadm trigger', and replug the device"
        )

    def _read_all(self) -> bool:
        """Drain pending reports; returns True when the buttons changed."""
        changed = False
        now = time.monotonic()
        for _ in range(64):
            try:
                data = self.hid_handle.read(64, 0)
            except (OSError, ValueError) as exc:
                self.get_logger().warning(
                    f"{self.device[1].name} disconnected ({exc}); waiting for it to come back"
                )
                try:
                    self.hid_handle.close()
                except Exception:
                    pass
                self.hid_handle, self.device = None, None
                self.state = AxisState(self.state.n_buttons)
                self._publish(force_zero=True)
                return False
            if not data:
                break
            if self.state.update(parse_report(data), now) == "buttons":
                changed = True
        return changed

    def _on_timer(self):
        if self.hid_handle is None:
            self._connect()
            return
        if self._read_all():
            self._publish_joy()  # button changes go out at once
        if self.hid_handle is None:
            return
        now = time.monotonic()
        if (
            self.p["zero_when_static"]
            and now - self.state.last_motion > self.p["static_timeout_s"]
        ):
            self.state.raw[:] = 0.0
        moving = bool(np.any(self.state.raw))
        if moving or self._moving:
            self._publish()
        self._moving = moving

    def _values(self):
        return to_ros(
            self.state.raw,
            self.p["full_scale"],
            self.p["deadband"],
            self.p["linear_scale"],
            self.p["angular_scale"],
        )

    def _publish(self, force_zero: bool = False):
        lin, ang, axes = self._values()
        if force_zero:
            lin, ang, axes = np.zeros(3), np.zeros(3), np.zeros(6)
        if self.p["use_twist_stamped"]:
            msg = TwistStamped()
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.header.frame_id = self.p["frame_id"]
            t = msg.twist
        else:
            msg = Twist()
            t = msg
        t.linear.x, t.linear.y, t.linear.z = map(float, lin)
        t.angular.x, t.angular.y, t.angular.z = map(float, ang)
        self.pub_twist.publish(msg)
        self._publish_joy(axes)

    def _publish_joy(self, axes=None):
        if axes is None:
            axes = self._values()[2]
        joy = Joy()
        joy.header.stamp = self.get_clock().now().to_msg()
        joy.header.frame_id = self.p["frame_id"]
        joy.axes = [float(v) for v in axes]
        joy.buttons = self.state.buttons
        self.pub_joy.publish(joy)
