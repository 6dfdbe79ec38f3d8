# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""``affordance_spacemouse``: 3Dconnexion SpaceMouse -> ``spacenav/twist`` and ``spacenav/joy``,
read with hidapi -- a drop-in for the spacenav driver, without spacenavd.

Axis convention (the spacenav driver's, checked against its source and spacenavd's defaults): the
raw HID axes are x right, y towards the user, z down (and rotations about those). spacenavd swaps
y/z and inverts y, z, ry, rz; the ROS driver then publishes REP-103 axes (x forward = away from
the user, y left, z up)::

    linear  = (-hid_y,  -hid_x,  -hid_z)  / full_scale * linear_scale
    angular = (-hid_ry, -hid_rx, -hid_rz) / full_scale * angular_scale

``full_scale`` defaults to 512 like the spacenav driver (raw values reach about +-350, so outputs
reach about +-0.7). Joy axes are the same six values in that order (not scaled), buttons are the
device's button bits.

Reports: older devices send translation (report 1, three int16 LE) and rotation (report 2)
separately; newer wireless ones send all six axes in one 12-byte report 1; report 3 is the button
bitfield. Other reports (battery...) and short ones are dropped.

The parsing here is pure (no ROS); the hidapi calls sit behind :class:`HidBackend`, so a
:class:`FifoBackend` can feed recorded or scripted reports (tests, demos).
"""

from __future__ import annotations

import json
import os
import queue
import struct
import threading
import time
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DEVICES",
    "SKIP",
    "DeviceInfo",
    "parse_report",
    "AxisState",
    "to_ros",
    "HidBackend",
    "HidapiBackend",
    "FifoBackend",
    "find_device",
    "list_devices",
    "main",
]


@dataclass(frozen=True)
class DeviceInfo:
    name: str
    buttons: int


#: (vendor, product) -> device. 0x046d: the Logitech-era 3Dconnexion devices.
DEVICES = {
    (0x046D, 0xC623): DeviceInfo("SpaceTraveler", 8),
    (0x046D, 0xC625): DeviceInfo("SpacePilot", 21),
    (0x046D, 0xC626): DeviceInfo("SpaceNavigator", 2),
    (0x046D, 0xC627): DeviceInfo("SpaceExplorer", 15),
    (0x046D, 0xC628): DeviceInfo("SpaceNavigator for Notebooks", 2),
    (0x046D, 0xC629): DeviceInfo("SpacePilot Pro", 31),
    (0x046D, 0xC62B): DeviceInfo("SpaceMouse Pro", 15),
    (0x256F, 0xC62E): DeviceInfo("SpaceMouse Wireless (cable)", 2),
    (0x256F, 0xC62F): DeviceInfo("SpaceMouse Wireless (receiver)", 2),
    (0x256F, 0xC631): DeviceInfo("SpaceMouse Pro Wireless (cable)", 15),
    (0x256F, 0xC632): DeviceInfo("SpaceMouse Pro Wireless (receiver)", 15),
    (0x256F, 0xC633): DeviceInfo("SpaceMouse Enterprise", 31),
    (0x256F, 0xC635): DeviceInfo("SpaceMouse Compact", 2),
    (0x256F, 0xC652): DeviceInfo("3Dconnexion Universal Receiver", 15),
}
#: 3Dconnexion products that are not 6-DoF mice (CadMouse family, keyboards): never opened.
SKIP = {
    (0x256F, pid)
    for pid in (0xC650, 0xC651, 0xC654, 0xC655, 0xC656, 0xC657, 0xC658, 0xC664, 0xC665)
}


def parse_report(data) -> tuple[str, tuple] | None:
    """One HID input report (report id first) -> ("translation", (x, y, z)),
    ("rotation", (rx, ry, rz)), ("motion", (x, y, z, rx, ry, rz)), ("buttons", bits) or None
    for reports to drop (other ids, too short)."""
    data = bytes(data)
    if len(data) < 2:
        return None
    rid = data[0]
    if rid == 1 and len(data) >= 13:
        return "motion", struct.unpack_from("<6h", data, 1)
    if rid == 1 and len(data) >= 7:
        return "translation", struct.unpack_from("<3h", data, 1)
    if rid == 2 and len(data) >= 7:
        return "rotation", struct.unpack_from("<3h", data, 1)
    if rid == 3:
        return "buttons", int.from_bytes(data[1:], "little")
    return None


class AxisState:
    """Latest raw HID axes (x, y, z, rx, ry, rz) and button bits of one device."""

    def __init__(self, n_buttons: int = 2):
        self.raw = np.zeros(6)
        self.bits = 0
        self.n_buttons = n_buttons
        self.last_motion = 0.0

    def update(self, parsed, now: float) -> str | None:
        """Apply a parsed report; returns "motion" or "buttons" when something changed."""
        if parsed is None:
            return None
        kind, value = parsed
        if kind == "buttons":
            if value == self.bits:
                return None
            self.bits = value
            return "buttons"
        if kind == "translation":
            self.raw[:3] = value
        elif kind == "rotation":
            self.raw[3:] = value
        else:
            self.raw[:] = value
        self.last_motion = now
        return "motion"

    @property
    def buttons(self) -> list[int]:
        n = max(self.n_buttons, self.bits.bit_length())
        return [(self.bits >> i) & 1 for i in range(n)]


def to_ros(raw, full_scale: float, deadband: float, linear_scale, angular_scale):
    """Raw HID axes -> (linear (3,), angular (3,), joy axes (6,)) in the spacenav convention.
    ``deadband`` is a fraction of full scale applied per axis."""
    r = np.asarray(raw, dtype=float) / full_scale
    r[np.abs(r) < deadband] = 0.0
    axes = np.array([-r[1], -r[0], -r[2], -r[4], -r[3], -r[5]])
    return axes[:3] * np.asarray(linear_scale), axes[3:] * np.asarray(angular_scale), axes


# ------------------------------------------------------------------------------- backends
class HidBackend:
    """The hidapi calls the node needs. ``enumerate()`` -> list of dicts with vendor_id,
    product_id, path, product_string; ``open(path)`` -> handle with ``read(size, timeout_ms)``
    (list of ints, [] on timeout, OSError when the device is gone) and ``close()``."""

    def enumerate(self) -> list[dict]:
        raise NotImplementedError

    def open(self, path):
        raise NotImplementedError


class HidapiBackend(HidBackend):
    def __init__(self):
        import hid  # the hidapi package

        self._hid = hid

    def enumerate(self) -> list[dict]:
        return list(self._hid.enumerate())

    def open(self, path):
        dev = self._hid.device()
        dev.open_path(path if isinstance(path, bytes) else str(path).encode())
        return dev


class FifoBackend(HidBackend):
    """Scripted devices for tests and demos: JSON lines on a FIFO (or file) ::

    {"plug": {"path": "fake0", "vendor_id": 9583, "product_id": 50741, "product": "..."}}
    {"report": [1, 10, 0, 0, 0, 0, 0]}        # to the open device
    {"unplug": "fake0"}
    {"plug": {"path": "fake1", ..., "deny": true}}   # opening it: permission denied
    """

    def __init__(self, path: str):
        self.path = path
        self._devices: dict[str, dict] = {}
        self._denied: set[str] = set()
        self._reports: dict[str, queue.Queue] = {}
        self._lock = threading.Lock()
        threading.Thread(target=self._reader, daemon=True).start()

    def _reader(self):
        while True:
            try:
                with open(self.path, encoding="utf-8", errors="replace") as handle:  # blocks
                    for line in handle:
                        self._command(line)
            except OSError:
                time.sleep(0.1)

    def _command(self, line: str) -> None:
        """One scripted line; anything malformed is skipped (the reader keeps going)."""
        try:
            cmd = json.loads(line)
        except (ValueError, RecursionError):
            return
        if not isinstance(cmd, dict):
            return
        try:
            self._apply(cmd)
        except (KeyError, TypeError, ValueError):
            return

    def _apply(self, cmd: dict) -> None:
        with self._lock:
            if "plug" in cmd:
                d = cmd["plug"]
                path = str(d["path"])
                device = {
                    "vendor_id": int(d["vendor_id"]),
                    "product_id": int(d["product_id"]),
                    "path": path.encode(),
                    "product_string": str(d.get("product", "")),
                }
                self._devices[path] = device
                self._reports[path] = queue.Queue()
                if d.get("deny"):
                    self._denied.add(path)
                else:
                    self._denied.discard(path)
            elif "unplug" in cmd:
                self._devices.pop(str(cmd["unplug"]), None)
            elif "report" in cmd:
                report = [int(b) & 0xFF for b in cmd["report"]]
                for q in self._reports.values():
                    q.put(report)

    def enumerate(self) -> list[dict]:
        with self._lock:
            return [dict(d) for d in self._devices.values()]

    def open(self, path):
        key = path.decode() if isinstance(path, bytes) else str(path)
        with self._lock:
            if key in self._denied:
                raise PermissionError(13, "Permission denied", key)
            if key not in self._devices:
                raise OSError(2, "open failed", key)
            q = self._reports[key]
        backend = self

        class Handle:
            def read(self, size, timeout_ms=0):
                with backend._lock:
                    if key not in backend._devices:
                        raise OSError(19, "read error: device disconnected")
                try:
                    return q.get(timeout=timeout_ms / 1000.0) if timeout_ms else q.get_nowait()
                except queue.Empty:
                    return []

            def close(self):
                pass

        return Handle()


def make_backend(spec: str) -> HidBackend:
    if spec.startswith("fifo:"):
        return FifoBackend(spec[5:])
    if spec not in ("", "hidapi"):
        raise ValueError(f"unknown hid_backend {spec!r} (hidapi or fifo:PATH)")
    return HidapiBackend()


def find_device(
    backend: HidBackend, device_path: str = "", vendor_id: int = 0, product_id: int = 0
) -> dict | None:
    """The device to open: an explicit path or vendor/product, else the first known SpaceMouse
    (CadMice and keyboards are skipped)."""
    for d in backend.enumerate():
        key = (d["vendor_id"], d["product_id"])
        path = d["path"].decode() if isinstance(d["path"], bytes) else str(d["path"])
        if device_path:
            if path == device_path:
                return d
            continue
        if vendor_id and product_id:
            if key == (vendor_id, product_id):
                return d
            continue
        if key in DEVICES and key not in SKIP:
            return d
    return None


def list_devices(backend: HidBackend | None = None) -> list[str]:
    """Human-readable lines for ``affordance-registration spacemouse --list``."""
    backend = backend or HidapiBackend()
    lines, seen = [], set()
    for d in backend.enumerate():
        key = (d["vendor_id"], d["product_id"])
        path = d["path"].decode(errors="replace") if isinstance(d["path"], bytes) else d["path"]
        if key in SKIP or key not in DEVICES or path in seen:
            continue
        seen.add(path)
        access = (
            ""
            if not path.startswith("/dev/") or os.access(path, os.R_OK | os.W_OK)
            else "  (no permission: install launch_configs/99-spacemouse.rules)"
        )
        lines.append(f"{DEVICES[key].name}  {key[0]:04x}:{key[1]:04x}  {path}{access}")
    return lines


def main(args=None) -> int:
    """Console script ``affordance_spacemouse`` (takes ``--ros-args``); the node itself is in
    :mod:`.spacemouse_node` (this module's parsing needs no ROS)."""
    from ..nodes.spacemouse_node import SpaceMouseNode
    from ..standins.spin import run_node

    return run_node(SpaceMouseNode, "affordance_spacemouse", args)


if __name__ == "__main__":
    raise SystemExit(main())
