# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station's ROS parameters (name -> default and description) and their checks, apart from
the node so that the command line checks them before it starts one."""

from __future__ import annotations

import math
import socket

from ...core.errors import AffordanceError

__all__ = ["PARAMETERS", "UP_AXES", "check_parameters", "check_port"]

#: parameters: name -> (default, description); checked by :func:`check_parameters`
PARAMETERS = {
    "host": ("127.0.0.1", "address the page is served on (0.0.0.0: every interface)"),
    "port": (8080, "TCP port of the page"),
    "engine": (
        "/affordance_engine",
        "the engine node's name: its ~/status, ~/markers, ~/select_model and services",
    ),
    "interactive_namespace": ("/affordance_correction", "the engine's interactive markers"),
    "points_reliable": (
        True,
        "reliable 'points' subscription (false: best effort, for drivers "
        "that publish with SensorDataQoS)",
    ),
    "display_points": (60000, "most cloud points sent to the page (the cloud is thinned)"),
    "point_size": (0.003, "m, drawn size of a cloud point"),
    "color_by": (
        "auto",
        "auto (the scan's own colours -- an rgb or rgba field -- when it has them, else its "
        "intensity, else depth) | rgb | intensity | depth; the page's 'Depth colours' toggle "
        "switches to depth colours and back",
    ),
    "up": (
        "auto",
        "the world's up axis on the page: auto (an optical frame: -y; else the normal of the "
        "scan's dominant plane where the sensor sees it at a slant, else +z; then the support "
        "plane under the first click) | +x | -x | +y | -y | +z | -z",
    ),
    "sensor_origin": (
        [0.0, 0.0, 0.0],
        "m, where the scans were taken from in the cloud's frame (a PCD's VIEWPOINT): the first "
        "view looks from there",
    ),
    "fov_deg": (60.0, "vertical field of view of the page's camera"),
    "view_rate": (10.0, "Hz, highest rate of view_pose messages"),
    "cloud_rate": (2.0, "Hz, highest rate the page's cloud is replaced at"),
    "click_cone_deg": (0.5, "a click picks cloud points within this angle of its ray"),
    "fitting_marker_delay": (
        0.5,
        "s, a click still being fitted after this long gets the "
        "'fitting…' marker drawn where it landed (0: at once); the "
        "panel's Fitting line shows at once",
    ),
    "access_secret": (
        "",
        "the secret the page and its websocket need ('' = the "
        "AFFORDANCE_STATION_SECRET environment variable, else a random one "
        "per start); at least 16 characters. Undeclared once read (no GetParameters "
        "answers it); a command line is readable by every local user: prefer the "
        "environment variable",
    ),
}
UP_AXES = {
    "+x": (1, 0, 0),
    "-x": (-1, 0, 0),
    "+y": (0, 1, 0),
    "-y": (0, -1, 0),
    "+z": (0, 0, 1),
    "-z": (0, 0, -1),
}


def check_port(host: str, port: int) -> None:
    """Raise AffordanceError when ``host:port`` cannot be listened on (in use, or no such
    address): the station serves exactly where it says, or not at all."""
    if not 1 <= int(port) <= 65535:
        raise AffordanceError(f"port must be within 1-65535, got {port}")
    with socket.socket(
        socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM
    ) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, int(port)))
        except OSError as exc:
            raise AffordanceError(
                f"cannot serve the page on {host}:{port}: {exc.strerror} "
                f"(choose another with -p port:=N / --port N)"
            ) from None


def check_parameters(p: dict) -> str:
    """'' when the station's parameters are usable, else what is wrong."""
    if p["up"] != "auto" and p["up"] not in UP_AXES:
        return f"up must be auto or one of {', '.join(UP_AXES)}, got {p['up']!r}"
    if p["color_by"] not in ("auto", "rgb", "depth", "intensity"):
        return f"color_by must be auto, rgb, depth or intensity, got {p['color_by']!r}"
    origin = p["sensor_origin"]
    if len(origin) != 3 or not all(math.isfinite(float(v)) for v in origin):
        return f"sensor_origin must be 3 finite numbers (m), got {list(origin)!r}"
    if not 1000 <= int(p["display_points"]) <= 5_000_000:
        return f"display_points must be within 1000-5000000, got {p['display_points']}"
    for name, lo, hi in (
        ("point_size", 1e-4, 1.0),
        ("fov_deg", 10.0, 120.0),
        ("view_rate", 0.5, 60.0),
        ("cloud_rate", 0.1, 30.0),
        ("click_cone_deg", 0.05, 10.0),
        ("fitting_marker_delay", 0.0, 3600.0),
    ):
        if not lo <= float(p[name]) <= hi:
            return f"{name} must be within {lo}-{hi}, got {p[name]}"
    for name in ("engine", "interactive_namespace"):
        if not str(p[name]).startswith("/") or str(p[name]).rstrip("/") == "":
            return f"{name} must be an absolute name like /affordance_engine, got {p[name]!r}"
    return ""
