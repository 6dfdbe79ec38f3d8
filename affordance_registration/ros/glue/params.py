"""The engine node's parameters: the table (default, description, constraint), their
declaration, validation, and the core settings they make.

Validation is a pure function of the values (:func:`check`), shared by the node's start-up and its
set-parameters callback, so a bad value is refused with the same reason either way.
"""
from __future__ import annotations

import math

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from ...core.errors import AffordanceError
from ...core.operator import BUTTON_ACTIONS, OperatorSettings
from ...core.registration import FitSettings
from .frames import StaticFrames

__all__ = ["PARAMETERS", "READ_ONLY", "FIT_PARAMETERS", "declare", "check", "fit_settings",
           "operator_settings"]

# name: (default, description, (min, max) or choices or None)
PARAMETERS = {
    "templates_dir": ("", "template library directory ('' = the package's models/)", None),
    "fit_mode": ("auto", "auto: mounting plane prior + resting + random; mounted; free",
                 ("auto", "mounted", "free")),
    "estimate_joints": (True, "fit joint values (valve open/closed) and scale where templates "
                              "have them; false: rigid templates only", None),
    "voxel_size": (0.005, "voxel edge of the crop around a click (m)", (0.001, 0.05)),
    "weight_scale": (0.005, "d0 of the correspondence weight 1/(1+d/d0) (m)", (0.0005, 0.1)),
    "snap_distance": (0.03, "a click farther than this from the cloud is refused (m)", (0.001, 1.0)),
    "seed": (0, "random seed of the restarts", (0, 2**31 - 1)),
    "linear_gain": (0.1, "m/s per unit of spacenav/twist linear", (0.0, 10.0)),
    "angular_gain": (0.6, "rad/s per unit of spacenav/twist angular", (0.0, 20.0)),
    "twist_frame": ("spacenav", "axes of spacenav/twist: spacenav (REP-103 device axes: x away "
                    "from the user, y left, z up) or view (x right, y up, z to the viewer)",
                    ("spacenav", "view")),
    "twist_stamped": (False, "spacenav/twist is geometry_msgs/TwistStamped (the spacenav driver's "
                              "and affordance_spacemouse's use_twist_stamped): twists are held "
                              "for the time between their header stamps; read at start", None),
    "max_twist_dt": (0.1, "longest time one twist message is integrated over (s)", (0.001, 1.0)),
    "refit_idle_s": (0.5, "refit after the twists stop for this long (s)", (0.05, 30.0)),
    "button_next_model": (0, "Joy button for next model (-1: none)", (-1, 63)),
    "button_accept": (1, "Joy button for accept (-1: none)", (-1, 63)),
    "button_previous_model": (-1, "Joy button for previous model (-1: none)", (-1, 63)),
    "button_refit": (-1, "Joy button for refit (-1: none)", (-1, 63)),
    "button_undo": (-1, "Joy button for undo (-1: none)", (-1, 63)),
    "button_discard": (-1, "Joy button for discard (-1: none)", (-1, 63)),
    "button_joint_plus": (-1, "Joy button stepping the shown object's joint up (-1: none)",
                          (-1, 63)),
    "button_joint_minus": (-1, "Joy button stepping the shown object's joint down (-1: none)",
                           (-1, 63)),
    "joint_axis": (-1, "Joy axis stepping the joint once per push past joint_axis_threshold, "
                       "in the push's direction; re-armed below half of it (-1: none)", (-1, 63)),
    "joint_axis_threshold": (0.5, "how far joint_axis must be pushed to step", (0.05, 1.0)),
    "joint_step_deg": (5.0, "one joint step of a revolute joint (deg)", (0.1, 90.0)),
    "joint_step_mm": (2.0, "one joint step of a prismatic joint (mm)", (0.1, 100.0)),
    "dimension_step_mm": (5.0, "one step of a primitive's dimension (mm), ~/set_dimension "
                               "NAME+ / NAME-", (0.1, 100.0)),
    "static_transforms": ([], "'parent child x y z qx qy qz qw' entries for frames TF does not "
                          "know", None),
    "registrations_file": ("affordance_registrations.yaml", "the session's registrations (YAML): "
                           "~/save writes it, autosave rewrites it after every change, resume "
                           "reads it at start", None),
    "resume": (True, "at start, load the registrations in registrations_file (a restarted "
                     "engine continues its session); false: a fresh session -- the file found "
                     "there is kept as a backup when first replaced; read at start", None),
    "autosave": (True, "write registrations_file (atomically) after every accept, undo or load "
                       "that changes the registrations, before the action is answered; false: "
                       "only ~/save and shutdown write it", None),
    "sensor_origin": ([0.0, 0.0, 0.0], "sensor position in the cloud frame (m), used when "
                      "sensor_frame is ''", None),
    "sensor_frame": ("", "where the scans are taken from: '' = sensor_origin in the cloud frame "
                         "(default: the cloud frame's origin); a frame name = that frame's "
                         "origin, looked up through TF / static_transforms (a cloud in "
                         "base_link or map); 'none' = no single viewpoint (an accumulated map: "
                         "fitted without the visibility terms)", None),
    "points_reliable": (True, "subscribe to points with reliable QoS (false: best effort, for "
                              "sensor drivers publishing with SensorDataQoS); read at start", None),
    "publish_rate": (20.0, "highest rate of marker/status updates (Hz)", (1.0, 100.0)),
    "interactive_namespace": ("/affordance_correction", "interactive marker server namespace "
                              "(one level); read at start", None),
    "interactive_orientation": ("object", "interactive marker controls aligned with the object "
                                "or the operator's view", ("object", "view")),
    "refit_on_new_cloud": (True, "a new cloud refits the selected (not yet accepted) object "
                                 "from its current pose, at most twice a second", None),
    "test_slow_fit_s": (0.0, "test only: every click's fit takes at least this long (s), to "
                             "show that input stays in order behind a slow fit", (0.0, 60.0)),
}
READ_ONLY = {"points_reliable", "interactive_namespace", "twist_stamped", "resume"}
#: parameters that make the fitting settings (a change rebuilds the registrar)
FIT_PARAMETERS = {"fit_mode", "voxel_size", "weight_scale", "snap_distance", "seed",
                  "estimate_joints"}


def _descriptor(name, description, constraint) -> ParameterDescriptor:
    desc = ParameterDescriptor(description=description, read_only=name in READ_ONLY)
    if isinstance(constraint, tuple) and isinstance(constraint[0], str):
        desc.additional_constraints = "one of: " + ", ".join(constraint)
    elif isinstance(constraint, tuple):
        desc.additional_constraints = f"range [{constraint[0]}, {constraint[1]}]"
    return desc


def declare(node) -> dict:
    """Declare every parameter on ``node``; returns name -> value (overrides applied). A bad
    value raises :class:`AffordanceError` with the reason."""
    for name, (default, description, constraint) in PARAMETERS.items():
        # an empty list would be declared as a byte array: declare string lists by type
        value = Parameter.Type.STRING_ARRAY if default == [] else default
        node.declare_parameter(name, value, _descriptor(name, description, constraint))
    values = {}
    for name, (default, _, _) in PARAMETERS.items():
        try:
            value = node.get_parameter(name).value
        except ParameterUninitializedException:   # a list declared by type, not overridden
            value = None
        values[name] = list(default) if value is None else value
    problem = check(values)
    if problem:
        raise AffordanceError(f"bad parameter: {problem}")
    return values


def _check_one(name: str, value) -> str | None:
    default, _, constraint = PARAMETERS[name]
    if isinstance(default, bool):
        return None if isinstance(value, bool) else f"{name} must be true or false"
    if isinstance(default, (int, float)):
        if not isinstance(value, (int, float)) or isinstance(value, bool) or \
                not math.isfinite(value):
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


def fit_settings(p: dict) -> FitSettings:
    return FitSettings(mode=p["fit_mode"], voxel=float(p["voxel_size"]),
                       weight_scale=float(p["weight_scale"]),
                       snap_distance=float(p["snap_distance"]), seed=int(p["seed"]),
                       articulated=bool(p["estimate_joints"]))


def operator_settings(p: dict) -> OperatorSettings:
    return OperatorSettings(
        linear_gain=float(p["linear_gain"]), angular_gain=float(p["angular_gain"]),
        twist_frame=p["twist_frame"], max_twist_dt=float(p["max_twist_dt"]),
        refit_idle_s=float(p["refit_idle_s"]),
        buttons=tuple((a, int(p[f"button_{a}"])) for a in BUTTON_ACTIONS),
        joint_axis=int(p["joint_axis"]), joint_axis_threshold=float(p["joint_axis_threshold"]),
        follow_clouds=bool(p["refit_on_new_cloud"]), slow_fit_s=float(p["test_slow_fit_s"]))
