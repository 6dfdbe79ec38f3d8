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
from ...core.operator import BUTTON_ACTIONS, OperatorSettings
from ...core.registration import FitSettings
from .frames import StaticFrames

__all__ = [
    "PARAMETERS",
    "NODE_PARAMETERS",
    "READ_ONLY",
    "FIT_PARAMETERS",
    "FIT_PREFIX",
    "declare",
    "check",
    "fit_settings",
    "operator_settings",
    "params_file",
    "fit_table",
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


# name: (default, description, (min, max) or choices or None)
NODE_PARAMETERS = {
    "templates_dir": ("", "template library directory ('' = the package's models/)", None),
    "settings_file": (
        "",
        "fitting settings (YAML, as 'affordance-registration settings' prints) "
        "that replace the fit.* parameters' defaults ('' = none); read at "
        "start",
        None,
    ),
    "linear_gain": (0.1, "m/s per unit of spacenav/twist linear", (0.0, 10.0)),
    "angular_gain": (0.6, "rad/s per unit of spacenav/twist angular", (0.0, 20.0)),
    "twist_frame": (
        "spacenav",
        "axes of spacenav/twist: spacenav (REP-103 device axes: x away "
        "from the user, y left, z up) or view (x right, y up, z to the viewer)",
        ("spacenav", "view"),
    ),
    "twist_stamped": (
        False,
        "spacenav/twist is geometry_msgs/TwistStamped (the spacenav driver's "
        "and affordance_spacemouse's use_twist_stamped): twists are held "
        "for the time between their header stamps; read at start",
        None,
    ),
    "max_twist_dt": (0.1, "longest time one twist message is integrated over (s)", (0.001, 1.0)),
    "refit_idle_s": (0.5, "refit after the twists stop for this long (s)", (0.05, 30.0)),
    "button_next_model": (0, "Joy button for next model (-1: none)", (-1, 63)),
    "button_accept": (1, "Joy button for accept (-1: none)", (-1, 63)),
    "button_previous_model": (-1, "Joy button for previous model (-1: none)", (-1, 63)),
    "button_refit": (-1, "Joy button for refit (-1: none)", (-1, 63)),
    "button_undo": (-1, "Joy button for undo (-1: none)", (-1, 63)),
    "button_discard": (-1, "Joy button for discard (-1: none)", (-1, 63)),
    "button_joint_plus": (
        -1,
        "Joy button stepping the shown object's joint up (-1: none)",
        (-1, 63),
    ),
    "button_joint_minus": (
        -1,
        "Joy button stepping the shown object's joint down (-1: none)",
        (-1, 63),
    ),
    "joint_axis": (
        -1,
        "Joy axis stepping the joint once per push past joint_axis_threshold, "
        "in the push's direction; re-armed below half of it (-1: none)",
        (-1, 63),
    ),
    "joint_axis_threshold": (0.5, "how far joint_axis must be pushed to step", (0.05, 1.0)),
    "joint_step_deg": (5.0, "one joint step of a revolute joint (deg)", (0.1, 90.0)),
    "joint_step_mm": (2.0, "one joint step of a prismatic joint (mm)", (0.1, 100.0)),
    "dimension_step_mm": (
        5.0,
        "one step of a primitive's dimension (mm), ~/set_dimension NAME+ / NAME-",
        (0.1, 100.0),
    ),
    "static_transforms": (
        [],
        "'parent child x y z qx qy qz qw' entries for frames TF does not know",
        None,
    ),
    "registrations_file": (
        "",
        "the session's registrations (YAML): "
        "~/save writes it, autosave rewrites it after every change, resume "
        "reads it at start; locked while the node runs (one engine per file); read at start "
        "('' = affordance_registrations.yaml in ROS_HOME, ~/.ros by default; a relative path is "
        "taken from the working folder)",
        None,
    ),
    "resume": (
        True,
        "at start, load the registrations in registrations_file (a restarted "
        "engine continues its session); false: a fresh session -- the file found "
        "there is kept as a backup when first replaced; read at start",
        None,
    ),
    "autosave": (
        True,
        "write registrations_file (atomically) after every accept, undo or load "
        "that changes the registrations, before the action is answered; false: "
        "only ~/save and shutdown write it",
        None,
    ),
    "sensor_origin": (
        [0.0, 0.0, 0.0],
        "sensor position in the cloud frame (m), used when sensor_frame is ''",
        None,
    ),
    "sensor_frame": (
        "",
        "where the scans are taken from: '' = sensor_origin in the cloud frame "
        "(default: the cloud frame's origin); a frame name = that frame's "
        "origin, looked up through TF / static_transforms (a cloud in "
        "base_link or map); 'none' = no single viewpoint (an accumulated map: "
        "fitted without the visibility terms)",
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
        "sensor drivers publishing with SensorDataQoS); read at start",
        None,
    ),
    "publish_rate": (20.0, "highest rate of marker/status updates (Hz)", (1.0, 100.0)),
    "interactive_namespace": (
        "/affordance_correction",
        "interactive marker server namespace (one level); read at start",
        None,
    ),
    "interactive_orientation": (
        "object",
        "interactive marker controls aligned with the object or the operator's view",
        ("object", "view"),
    ),
    "refit_on_new_cloud": (
        True,
        "a new cloud refits the selected (not yet accepted) object "
        "from its current pose, at most twice a second",
        None,
    ),
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
    **NODE_PARAMETERS,
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


def _descriptor(name, description, constraint) -> ParameterDescriptor:
    desc = ParameterDescriptor(description=description, read_only=name in READ_ONLY)
    if name in FIT_TABLE:
        desc.additional_constraints = FIT_TABLE[name][2]
    elif isinstance(constraint, tuple) and isinstance(constraint[0], str):
        desc.additional_constraints = "one of: " + ", ".join(constraint)
    elif isinstance(constraint, tuple):
        desc.additional_constraints = f"range [{constraint[0]}, {constraint[1]}]"
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
    with the name meant where one is close."""
    lines = []
    for name in sorted(set(overrides) - set(PARAMETERS) - {"use_sim_time"}):
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
    return OperatorSettings(
        linear_gain=float(p["linear_gain"]),
        angular_gain=float(p["angular_gain"]),
        twist_frame=p["twist_frame"],
        max_twist_dt=float(p["max_twist_dt"]),
        refit_idle_s=float(p["refit_idle_s"]),
        buttons=tuple((a, int(p[f"button_{a}"])) for a in BUTTON_ACTIONS),
        joint_axis=int(p["joint_axis"]),
        joint_axis_threshold=float(p["joint_axis_threshold"]),
        follow_clouds=bool(p["refit_on_new_cloud"]),
    )


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
    for name, (default, description, _) in NODE_PARAMETERS.items():
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


def fit_table() -> str:
    """The documentation's table of the ``fit.*`` parameters (markdown)."""
    rows = ["| name | default | rule | meaning |", "|---|---|---|---|"]
    for name, (default, description, rule) in FIT_TABLE.items():
        rows.append(f"| `{name}` | `{_value(default)}` | {rule} | {description} |")
    return "\n".join(rows) + "\n"
