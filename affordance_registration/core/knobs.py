# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Declared parameters ("knobs"): a field of a frozen dataclass with its default, a one-line
doc, the rule its value follows and its unit, declared once.

The fitting settings (:mod:`.registration.settings`), the operator's (:mod:`.operator`) and the
browser station's (``ros/station/parameters.py``) are made of knobs; the node parameters, the
settings files, the command-line options, the parameter file and the tables of
``msg_docs/README.md`` are generated from the declarations, so a parameter has one name, one
default, one unit and one rule everywhere. :func:`check_knob` validates a value by its rule with
one line naming the knob (for start-up, ``ros2 param set`` and settings files alike).
"""

from __future__ import annotations

import math
from dataclasses import field, fields
from typing import NamedTuple

from .errors import AffordanceError

__all__ = [
    "knob",
    "describe_rule",
    "check_knob",
    "check_all",
    "declared",
    "described",
    "Declared",
    "POSITIVE",
    "COUNT",
    "COUNT0",
    "FRACTION",
    "SWITCH",
    "NUMBER",
    "INTEGER",
    "TEXT",
    "POINT",
    "MAX_COUNT",
]

#: the rules a knob's value follows (``knob(rule=...)``); a tuple of strings is a choice
POSITIVE, COUNT, COUNT0, FRACTION, SWITCH = "positive", "count", "count0", "fraction", "switch"
NUMBER, INTEGER, TEXT, POINT = "number", "integer", "text", "point"
#: the largest value of any count (samples, points, iterations): a fit's memory grows with them
#: (coarse.samples 20,000 takes 1.8 GB, 100,000 more than 8 GB) -- no count needs more
MAX_COUNT = 10_000
_RULE_TEXT = {
    POSITIVE: "a positive number",
    COUNT: "an integer >= 1",
    COUNT0: "an integer >= 0",
    FRACTION: "a number in (0, 1]",
    SWITCH: "true or false",
    NUMBER: "a number",
    INTEGER: "an integer",
    TEXT: "text",
    POINT: "3 numbers",
}


def knob(default, doc: str, rule=None, limits: tuple | None = None, unit: str = ""):
    """A declared field: its ``default``, a one-line ``doc`` (a node parameter's description),
    its ``rule`` -- :data:`POSITIVE` (the default for a float), :data:`COUNT` (for an int),
    :data:`COUNT0`, :data:`FRACTION`, :data:`SWITCH` (for a bool), :data:`NUMBER`,
    :data:`INTEGER`, :data:`TEXT` (for a str), :data:`POINT` (3 finite numbers) or a tuple of
    choices --, ``limits`` (lo, hi) that bound it further, and its ``unit`` ("m", "s", "deg";
    '' for none)."""
    if rule is None:
        rule = (
            SWITCH
            if isinstance(default, bool)
            else COUNT
            if isinstance(default, int)
            else TEXT
            if isinstance(default, str)
            else POSITIVE
        )
    if isinstance(default, list):  # a dataclass default must not be mutable
        value = tuple(default)
        return field(
            default_factory=lambda: list(value),
            metadata={"doc": doc, "rule": rule, "limits": limits, "unit": unit},
        )
    return field(
        default=default, metadata={"doc": doc, "rule": rule, "limits": limits, "unit": unit}
    )


def describe_rule(f) -> str:
    """A knob's rule as a person reads it ("a positive number", "one of: auto, free")."""
    rule, limits = f.metadata["rule"], f.metadata["limits"]
    if isinstance(rule, tuple):
        return "one of: " + ", ".join(rule)
    text = _RULE_TEXT[rule]
    if limits is None and rule in (COUNT, COUNT0):
        return f"{text}, at most {MAX_COUNT}"
    return text if limits is None else f"{text} in [{limits[0]}, {limits[1]}]"


def _finite_number(v) -> bool:
    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    except OverflowError:  # an integer of hundreds of digits
        return False


def _follows(rule, limits, v) -> bool:
    if isinstance(rule, tuple):
        return isinstance(v, str) and v in rule
    if rule == SWITCH:
        return isinstance(v, bool)
    if rule == TEXT:
        return isinstance(v, str)
    if rule == POINT:  # (a ROS double array comes as an array.array)
        return (
            not isinstance(v, (str, bytes))
            and hasattr(v, "__len__")
            and len(v) == 3
            and all(_finite_number(x) for x in v)
            and (limits is None or all(limits[0] <= x <= limits[1] for x in v))
        )
    if rule in (COUNT, COUNT0, INTEGER):
        ok = isinstance(v, int) and not isinstance(v, bool)
        if ok and rule != INTEGER:
            ok = (1 if rule == COUNT else 0) <= v <= (MAX_COUNT if limits is None else limits[1])
    else:
        ok = _finite_number(v) and (rule == NUMBER or (v > 0 and (rule != FRACTION or v <= 1)))
    return ok and (limits is None or limits[0] <= v <= limits[1])


def check_knob(name: str, f, v, error=AffordanceError) -> None:
    """Raise ``error`` with one line naming the knob ``name`` (declared by ``f``) when ``v``
    does not follow its rule."""
    if not _follows(f.metadata["rule"], f.metadata["limits"], v):
        raise error(f"{name} must be {describe_rule(f)}, got {_shown(v)}{_number_as_text(v)}")


def check_all(obj, error=AffordanceError, prefix: str = "") -> None:
    """:func:`check_knob` for every declared field of the dataclass ``obj``."""
    for f in fields(obj):
        if "rule" in f.metadata:
            check_knob(prefix + f.name, f, getattr(obj, f.name), error)


class Declared(NamedTuple):
    """One declared parameter as the documents and the nodes use it."""

    name: str
    default: object
    doc: str
    rule: str  #: as a person reads it (:func:`describe_rule`)
    unit: str
    field: object  #: the dataclass field (its rule and limits for :func:`check_knob`)


def declared(cls) -> list[Declared]:
    """The knobs of the dataclass ``cls``, in declaration order."""
    out = []
    for f in fields(cls):
        if "rule" not in f.metadata:
            continue
        default = f.default_factory() if callable(f.default_factory) else f.default
        out.append(
            Declared(f.name, default, f.metadata["doc"], describe_rule(f), f.metadata["unit"], f)
        )
    return out


def described(d: Declared) -> str:
    """A declared parameter's description with its unit ("... (m/s)"), as a node gives it."""
    return f"{d.doc} ({d.unit})" if d.unit else d.doc


def _number_as_text(v) -> str:
    """A hint where a number came as text: YAML 1.1 reads ``1e-3`` (no dot) as a string."""
    if not isinstance(v, str) or "e" not in v.lower():
        return ""
    try:
        number = float(v)
    except ValueError:
        return ""
    return (
        " (text: YAML reads a number in e-notation as one only with a dot, as 1.0e-3)"
        if math.isfinite(number)
        else ""
    )


def _shown(v) -> str:
    """``repr(v)``, cut to 80 characters (an integer of thousands of digits has no repr)."""
    try:
        text = repr(v)
    except ValueError:
        return "an integer of more than 4300 digits"
    return text if len(text) <= 80 else text[:77] + "..."
