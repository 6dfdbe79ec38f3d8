# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The station's parameters, declared once as knobs (:class:`StationSettings`: name, default,
doc, rule, unit) -- the node's ROS parameters, the command line's ``station`` options
(:func:`add_options`) and the documentation's table (:func:`station_table`) are made from them
-- and their checks, apart from the node so that the command line checks them before it starts
one."""

from __future__ import annotations

import json
import socket
from dataclasses import dataclass

from ...core.errors import AffordanceError
from ...core.knobs import (
    COUNT,
    INTEGER,
    NUMBER,
    POINT,
    POSITIVE,
    TEXT,
    check_knob,
    declared,
    described,
    knob,
)

__all__ = [
    "StationSettings",
    "STATION_TABLE",
    "PARAMETERS",
    "UP_AXES",
    "check_parameters",
    "check_port",
    "add_options",
    "station_table",
]

UP_AXES = {
    "+x": (1, 0, 0),
    "-x": (-1, 0, 0),
    "+y": (0, 1, 0),
    "-y": (0, -1, 0),
    "+z": (0, 0, 1),
    "-z": (0, 0, -1),
}


@dataclass(frozen=True)
class StationSettings:
    """The station's parameters: each a ROS parameter of the ``affordance_station`` node."""

    host: str = knob(
        "127.0.0.1",
        "address the page is served on (127.0.0.1: this machine only; 0.0.0.0: every interface)",
        TEXT,
    )
    port: int = knob(8080, "TCP port of the page", INTEGER, (1, 65535))
    engine: str = knob(
        "/affordance_engine",
        "the engine node's name: its ~/status, ~/markers, ~/select_model and services",
        TEXT,
    )
    interactive_namespace: str = knob(
        "/affordance_correction", "the engine's interactive markers", TEXT
    )
    points_reliable: bool = knob(
        True,
        "reliable 'points' subscription (false: best effort, for drivers that publish with "
        "SensorDataQoS)",
    )
    display_points: int = knob(
        60000,
        "most cloud points sent to the page: one cloud point per voxel, the voxel edge adapted "
        "to the budget. Sized for a browser without a GPU (software WebGL spent about a core on "
        "an idle page of 200000 points, a fifth of one at 60000); with a GPU, raise it",
        COUNT,
        (1000, 5_000_000),
    )
    point_size: float = knob(0.003, "drawn size of a cloud point", POSITIVE, (1e-4, 1.0), "m")
    color_by: str = knob(
        "auto",
        "auto: the cloud's own colours (an rgb or rgba field) when it has them, else its "
        "intensity, else depth; the page's 'Depth colours' switches to depth colours and back",
        ("auto", "rgb", "intensity", "depth"),
    )
    up: str = knob(
        "auto",
        "the world's up axis on the page: auto = an optical frame's -y, else the normal of the "
        "scan's dominant plane where the sensor sees it at a slant (a table), else +z; then "
        "the support plane under the first click",
        ("auto", *UP_AXES),
    )
    sensor_origin: list = knob(
        [0.0, 0.0, 0.0],
        "where the scans were taken from in the cloud's frame (a PCD's VIEWPOINT under "
        "station --scene): the first view looks from there",
        POINT,
        unit="m",
    )
    fov_deg: float = knob(
        60.0, "vertical field of view of the page's camera", POSITIVE, (10.0, 120.0), "deg"
    )
    view_rate: float = knob(
        10.0, "highest rate of view_pose messages", POSITIVE, (0.5, 60.0), "Hz"
    )
    cloud_rate: float = knob(
        2.0, "highest rate the page's cloud is replaced at", POSITIVE, (0.1, 30.0), "Hz"
    )
    click_cone_deg: float = knob(
        0.5,
        "a click picks cloud points within this angle of its ray",
        POSITIVE,
        (0.05, 10.0),
        "deg",
    )
    fitting_marker_delay: float = knob(
        0.5,
        "a click still being fitted after this long gets the 'fitting…' marker drawn where it "
        "landed (0: at once); the panel says 'Fitting your click' at once",
        NUMBER,
        (0.0, 3600.0),
        "s",
    )
    access_secret: str = knob(
        "",
        "the secret the page and its websocket need ('' = the AFFORDANCE_STATION_SECRET "
        "environment variable, else a random one per start); at least 16 characters, no "
        "spaces, ; , & = ? # % or quotes. "
        "Undeclared once read (no GetParameters answers it); a command line is readable by "
        "every local user: prefer the environment variable",
        TEXT,
    )


#: the station's knobs, by name
STATION_TABLE = {d.name: d for d in declared(StationSettings)}
#: the node's parameters: name -> (default, description)
PARAMETERS = {name: (d.default, described(d)) for name, d in STATION_TABLE.items()}


def add_options(parser, names=("up", "port", "host")) -> None:
    """The ``station`` command's options for the knobs ``names`` (``--up`` ...), with their
    defaults, choices and docs."""
    for name in names:
        d = STATION_TABLE[name]
        rule = d.field.metadata["rule"]
        kwargs = {"default": d.default, "help": f"{described(d)} (default {d.default})"}
        if isinstance(rule, tuple):
            kwargs["choices"] = rule
            if any(c.startswith("-") for c in rule):
                kwargs["help"] += "; a leading '-' needs the form --NAME=-y".replace("NAME", name)
        elif isinstance(d.default, int):
            kwargs["type"] = int
        parser.add_argument(f"--{name}", **kwargs)


def station_table() -> str:
    """The documentation's table of the station's parameters (markdown)."""
    rows = ["| name | default | rule | meaning |", "|---|---|---|---|"]
    for name, d in STATION_TABLE.items():
        rows.append(f"| `{name}` | `{json.dumps(d.default)}` | {d.rule} | {described(d)} |")
    return "\n".join(rows) + "\n"


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
    """'' when the station's parameters are usable, else what is wrong (the first problem)."""
    for name, d in STATION_TABLE.items():
        try:
            check_knob(name, d.field, p[name])
        except AffordanceError as exc:
            return str(exc)
    for name in ("engine", "interactive_namespace"):
        if not str(p[name]).startswith("/") or str(p[name]).rstrip("/") == "":
            return f"{name} must be an absolute name like /affordance_engine, got {p[name]!r}"
    return ""
