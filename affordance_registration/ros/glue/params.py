# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The engine node's parameters: the table (default, description, constraint), their
declaration, validation, and the core settings they make.

The fitting parameters are made from :class:`FitSettings`: every knob is the parameter
``fit.<knob>`` or ``fit.<group>.<knob>`` with the knob's default and description, so a knob has
one name and one default; ``settings_file`` (a settings YAML) replaces those defaults at start.
:func:`params_file` and :func:`fit_table` write the parameter file and the documentation's table
from this module (a test keeps them equal).

Validation is a pure function of the values (:func:`check`), shared by the node's start-up and its
set-parameters callback, so a bad value is refused with the same reason either way.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import textwrap

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from ...core.errors import AffordanceError, RegistrationError
from ...core.knobs import check_knob, declared, described
from ...core.operator import OperatorSettings
from ...core.registration import FitSettings
from ...core.registration.settings import RETIRED
from .frames import StaticFrames

__all__ = [
    "PARAMETERS",
    "NODE_PARAMETERS",
    "OPERATOR_TABLE",
    "ENGINE_PARAMETERS",
    "READ_ONLY",
    "FIT_PARAMETERS",
    "FIT_PREFIX",
    "declare",
    "check",
    "fit_settings",
    "operator_settings",
    "params_file",
    "fit_table",
    "node_table",
    "registrations_path",
    "REGISTRATIONS_NAME",
]

#: the registrations file's name in ROS_HOME when ``registrations_file`` is ''
REGISTRATIONS_NAME = "affordance_registrations.yaml"


def registrations_path(value: str) -> str:
    """Where ``registrations_file`` says the registrations are: ``''`` is
    :data:`REGISTRATIONS_NAME` in ROS_HOME (``$ROS_HOME``, else ``~/.ros``, where a ROS node keeps
    its files), never the folder the node was started from."""
    if value:
        return value
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return os.path.join(home, REGISTRATIONS_NAME)


# The node's own parameters, one row each: name: (default, description, (min, max) or choices
# or None). The operator's (gains, twist times, buttons, joint and dimension steps, the refit on
# a new cloud) are OperatorSettings' knobs, declared once in core/operator.py; the fitting knobs
# FitSettings' (core/registration/settings.py).
NODE_PARAMETERS = {
    "templates_dir": (
        "",
        "template library directory ('' = the package's models/); changing it is refused while "
        "objects are open",
        None,
    ),
    "settings_file": (
        "",
        "fitting settings (YAML, as 'affordance-registration settings' prints them; knobs left "
        "out keep their defaults) that replace the fit.* parameters' defaults at start; a fit.* "
        "parameter given in a parameter file or with -p overrides it. A file that cannot be "
        "read, an unknown knob or a bad value stops the start with one line",
        None,
    ),
    "twist_stamped": (
        False,
        "spacenav/twist is geometry_msgs/TwistStamped (the spacenav driver's and "
        "affordance_spacemouse's use_twist_stamped): twists are held for the time between their "
        "header stamps -- exact, also when a bag is replayed",
        None,
    ),
    "static_transforms": (
        [],
        "'parent child x y z qx qy qz qw' entries (pose of child in parent, as "
        "static_transform_publisher takes it) for frames TF does not know",
        None,
    ),
    "registrations_file": (
        "",
        "the session's registrations (YAML): ~/save writes it, autosave rewrites it after every "
        "change, resume reads it at start; '' = affordance_registrations.yaml in ROS_HOME "
        "(~/.ros unless set), where a ROS node keeps its files, never the folder it was started "
        "from (a relative path is taken from the working folder; ~ expands); locked while the "
        "node runs (one engine per file)",
        None,
    ),
    "resume": (
        True,
        "at start, load the registrations in registrations_file: a restarted engine (after a "
        "crash, kill -9, a reboot) continues its session; false: a fresh session -- the file "
        "found there is kept as a backup when first replaced",
        None,
    ),
    "autosave": (
        True,
        "write registrations_file (atomically) after every accept, undo or load that changes "
        "the registrations, before the action is answered; false: only ~/save and a clean "
        "shutdown (SIGINT/SIGTERM) write it",
        None,
    ),
    "sensor_origin": (
        [0.0, 0.0, 0.0],
        "the sensor's position in the cloud frame (m; visibility reasoning), used when "
        "sensor_frame is ''",
        None,
    ),
    "sensor_frame": (
        "",
        "where the scans are taken from: '' = sensor_origin in the cloud frame (by default the "
        "cloud frame's origin: a cloud in its camera's frame); a frame name = that frame's "
        "origin, looked up through TF / static_transforms when the cloud comes in another frame "
        "(base_link, odom, map); 'none' = no single viewpoint (an accumulated map): fitted "
        "without the visibility terms, normals from the data. The sensor frame's pose (else the "
        "cloud frame's) is also the default view for twists: a REP-103 body or world frame "
        "(map, odom, world, base_link, *_link, *_footprint, a lidar's) is taken as x forward, z "
        "up; any other (*optical*, or a camera's own name) as an optical frame",
        None,
    ),
    "fixed_frame": (
        "",
        "the frame the scene, the objects and the registrations live in: each cloud is "
        "brought into it through TF at the cloud's stamp (odom or map for a camera on a "
        "moving robot); '' = the cloud's own frame",
        None,
    ),
    "collision_objects": (
        True,
        "publish each registration as a moveit_msgs/CollisionObject on collision_object "
        "(ADD, MOVE, REMOVE: what MoveIt's move_group listens to); false removes them",
        None,
    ),
    "points_reliable": (
        True,
        "subscribe to points with reliable QoS (false: best effort, for "
        "sensor drivers publishing with SensorDataQoS)",
        None,
    ),
    "publish_rate": (20.0, "highest rate of marker/status updates (Hz)", (1.0, 100.0)),
    "interactive_namespace": (
        "/affordance_correction",
        "interactive marker server namespace (one level)",
        None,
    ),
    "interactive_orientation": (
        "object",
        "interactive marker controls aligned with the object's axes, or with the operator's "
        "view (right, up, towards the viewer)",
        ("object", "view"),
    ),
}
#: the operator's parameters: OperatorSettings' knobs, by name
OPERATOR_TABLE = {d.name: d for d in declared(OperatorSettings)}
#: the node's parameters but the fitting knobs: its own, then the operator's
ENGINE_PARAMETERS = {
    **NODE_PARAMETERS,
    **{name: (d.default, described(d), None) for name, d in OPERATOR_TABLE.items()},
}
FIT_PREFIX = "fit."
#: the fitting settings' knobs as parameters (``fit.`` + the knob's dotted name): (code default,
#: description, rule)
FIT_TABLE = {
    FIT_PREFIX + name: (default, doc, rule) for name, default, doc, rule in FitSettings.knobs()
}
#: parameters that make the fitting settings (a change rebuilds the registrar)
FIT_PARAMETERS = frozenset(FIT_TABLE)
PARAMETERS = {
    **ENGINE_PARAMETERS,
    **{name: (default, doc, None) for name, (default, doc, _) in FIT_TABLE.items()},
}
#: read at start only (rclpy refuses a set): among them the file the node writes -- a path set
#: over the graph would have any file the node can write replaced
READ_ONLY = {
    "registrations_file",
    "points_reliable",
    "interactive_namespace",
    "twist_stamped",
    "resume",
    "settings_file",
}


def _rule(name: str) -> str:
    """A parameter's rule as a person reads it (its knob's, or its row's constraint)."""
    if name in FIT_TABLE:
        rule = FIT_TABLE[name][2]
    elif name in OPERATOR_TABLE:
        rule = OPERATOR_TABLE[name].rule
    else:
        default, _, constraint = PARAMETERS[name]
        if isinstance(constraint, tuple) and isinstance(constraint[0], str):
            rule = "one of: " + ", ".join(constraint)
        elif isinstance(constraint, tuple):
            rule = f"range [{constraint[0]}, {constraint[1]}]"
        elif isinstance(default, bool):
            rule = "true or false"
        elif isinstance(default, list):
            rule = "a list"
        else:
            rule = "text"
    return rule + ("; read only" if name in READ_ONLY else "")


def _descriptor(name, description, constraint) -> ParameterDescriptor:
    desc = ParameterDescriptor(description=description, read_only=name in READ_ONLY)
    desc.additional_constraints = _rule(name).removesuffix("; read only")
    return desc


def declare(node) -> dict:
    """Declare every parameter on ``node``; returns name -> value (overrides applied). A bad
    value raises :class:`AffordanceError` with the reason. The ``fit.*`` parameters start from
    ``settings_file`` (when given), then the overrides apply."""
    name = "settings_file"
    node.declare_parameter(name, "", _descriptor(name, *PARAMETERS[name][1:]))
    path = node.get_parameter(name).value
    defaults = _flat(FitSettings.load(path) if path else FitSettings())
    for name, (default, description, constraint) in PARAMETERS.items():
        if name == "settings_file":
            continue
        # an empty list would be declared as a byte array: declare string lists by type
        value = Parameter.Type.STRING_ARRAY if default == [] else defaults.get(name, default)
        node.declare_parameter(name, value, _descriptor(name, description, constraint))
    values = {}
    for name, (default, _, _) in PARAMETERS.items():
        try:
            value = node.get_parameter(name).value
        except ParameterUninitializedException:  # a list declared by type, not overridden
            value = None
        values[name] = list(default) if value is None else value
    problem = check(values)
    if problem:
        raise AffordanceError(f"bad parameter: {problem}")
    return values


#: parameters of the node's earlier releases, and what sets the same knob now
RENAMED = {
    "voxel_size": "fit.crop.voxel",
    "fit_mode": "fit.mode",
    "estimate_joints": "fit.articulated",
    "weight_scale": "fit.icp.weight_scale",
    "snap_distance": "fit.crop.snap_distance",
    "seed": "fit.seed",
}


def unknown_overrides(overrides) -> list[str]:
    """One line for each parameter given to the node (``-p``, a parameter file) that it does
    not have -- ROS would ignore it silently, so a typo or an old name would change nothing --
    with the name meant where one is close; a fit knob of an earlier version says so."""
    lines = []
    for name in sorted(set(overrides) - set(PARAMETERS) - {"use_sim_time"}):
        retired = RETIRED.get(name[len(FIT_PREFIX) :]) if name.startswith(FIT_PREFIX) else None
        if retired:
            lines.append(f"parameter '{name}' is retired (replaced by {retired}) and is ignored")
            continue
        meant = RENAMED.get(name) or next(
            iter(difflib.get_close_matches(name, PARAMETERS, 1)), None
        )
        lines.append(
            f"parameter '{name}' is not one of this node's and is ignored"
            + (f" (did you mean '{meant}'?)" if meant else "")
        )
    return lines


def _check_one(name: str, value) -> str | None:
    if name in FIT_PARAMETERS:
        try:
            FitSettings().with_(**{name[len(FIT_PREFIX) :]: value})
        except RegistrationError as exc:
            return f"{FIT_PREFIX}{exc}"
        return None
    if name in OPERATOR_TABLE:
        try:
            check_knob(name, OPERATOR_TABLE[name].field, value)
        except AffordanceError as exc:
            return str(exc)
        return None
    default, _, constraint = PARAMETERS[name]
    if isinstance(default, bool):
        return None if isinstance(value, bool) else f"{name} must be true or false"
    if isinstance(default, (int, float)):
        if (
            not isinstance(value, (int, float))
            or isinstance(value, bool)
            or not math.isfinite(value)
        ):
            return f"{name} must be a number"
        if isinstance(default, int) and not float(value).is_integer():
            return f"{name} must be an integer"
        lo, hi = constraint
        return None if lo <= value <= hi else f"{name} = {value} is outside [{lo}, {hi}]"
    if isinstance(constraint, tuple) and value not in constraint:
        return f"{name} must be one of {', '.join(constraint)}, got {value!r}"
    return None


def check(values: dict) -> str | None:
    """The first problem with ``values`` (name -> value; unknown names are ignored), or None."""
    for name, value in values.items():
        if name in PARAMETERS:
            problem = _check_one(name, value)
            if problem:
                return problem
    if "static_transforms" in values:
        try:
            StaticFrames(values["static_transforms"])
        except AffordanceError as exc:
            return str(exc)
    if "sensor_origin" in values:
        origin = values["sensor_origin"]
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            return "sensor_origin must be 3 finite numbers"
    return None


def _flat(settings: FitSettings) -> dict:
    """The settings as ``fit.*`` parameter values."""
    out = {}
    for key, value in settings.to_dict().items():
        if isinstance(value, dict):
            out.update({f"{FIT_PREFIX}{key}.{k}": v for k, v in value.items()})
        else:
            out[FIT_PREFIX + key] = value
    return out


def fit_settings(p: dict) -> FitSettings:
    """The fitting settings the ``fit.*`` values of ``p`` make (RegistrationError: one line)."""
    try:
        return FitSettings().with_(**{name[len(FIT_PREFIX) :]: p[name] for name in FIT_TABLE})
    except RegistrationError as exc:
        raise RegistrationError(f"{FIT_PREFIX}{exc}") from None


def operator_settings(p: dict) -> OperatorSettings:
    """The operator's settings the values of ``p`` make (its knobs by their own names)."""
    return OperatorSettings(**{name: p[name] for name in OPERATOR_TABLE})


# ---------------------------------------------------------------------------- the documents
def _value(value) -> str:
    """A default as YAML and the docs write it (JSON is YAML: exact floats, quoted strings)."""
    return json.dumps(value)


def _comment(text: str, indent: str) -> list:
    return textwrap.wrap(text, 100, initial_indent=indent + "# ", subsequent_indent=indent + "# ")


def params_file() -> str:
    """``launch_configs/affordance_engine.params.yaml``: every parameter at its default, with
    its description."""
    lines = [
        "# Parameters of the affordance_engine node, each at its default (msg_docs/README.md",
        "# describes them). Made by `affordance-registration settings --node-params`; a test",
        "# keeps this file equal to the code. fit.* are the fitting settings (FitSettings).",
        "affordance_engine:",
        "  ros__parameters:",
    ]
    for name, (default, description, _) in ENGINE_PARAMETERS.items():
        lines += _comment(description, "    ")
        if default == []:  # a parameter file cannot give an empty list
            lines.append(f'    # {name}: ["parent child x y z qx qy qz qw"]')
        else:
            lines.append(f"    {name}: {_value(default)}")
    lines += [
        "    # The fitting settings (FitSettings), each at its default. Uncomment one to change",
        "    # it, or give several in settings_file: a fit.* parameter given here or with -p",
        "    # overrides the file.",
    ]
    for name, (default, description, _) in FIT_TABLE.items():
        lines += _comment(description, "    ")
        lines.append(f"    # {name}: {_value(default)}")
    return "\n".join(lines) + "\n"


def node_table() -> str:
    """The documentation's table of the node's parameters but the fitting knobs (markdown)."""
    rows = ["| name | default | rule | meaning |", "|---|---|---|---|"]
    for name, (default, description, _) in ENGINE_PARAMETERS.items():
        rows.append(f"| `{name}` | `{_value(default)}` | {_rule(name)} | {description} |")
    return "\n".join(rows) + "\n"


def fit_table() -> str:
    """The documentation's table of the ``fit.*`` parameters (markdown)."""
    rows = ["| name | default | rule | meaning |", "|---|---|---|---|"]
    for name, (default, description, rule) in FIT_TABLE.items():
        rows.append(f"| `{name}` | `{_value(default)}` | {rule} | {description} |")
    return "\n".join(rows) + "\n"
