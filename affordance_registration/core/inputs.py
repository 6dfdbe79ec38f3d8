# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The operator's inputs, one small frozen record per kind, and the host the operator stream
(:mod:`~affordance_registration.core.operator`) talks to: what it needs from the node it runs
in, as one :class:`OperatorHost` protocol. Pure Python (no ROS)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, ClassVar, Protocol

import numpy as np

__all__ = [
    "Click",
    "Action",
    "Twist",
    "Joy",
    "View",
    "Pose",
    "CancelDrag",
    "NewCloud",
    "OperatorInput",
    "INDEPENDENT",
    "OperatorHost",
    "StandaloneHost",
]


# ============================================================================ inputs
@dataclass(frozen=True, kw_only=True)
class _Input:
    """What every input carries. ``source``: what it came from (a topic or service name),
    counted in :meth:`OperatorStream.status` once handled; ``reply(success, message)`` is called
    once the input has been handled; ``arrived``: when the stream got it (its clock)."""

    kind: ClassVar[str]
    #: what the stream's worker is doing while it handles one (its status' ``busy``)
    doing: ClassVar[str]
    source: str = ""
    reply: Callable | None = field(default=None, compare=False)
    arrived: float = 0.0


@dataclass(frozen=True)
class Click(_Input):
    """A click at ``point`` (3,) in ``frame``, made at ``stamp`` (s; the frame is looked up then;
    None: the latest)."""

    kind: ClassVar[str] = "click"
    doing: ClassVar[str] = "fitting a click"
    point: np.ndarray
    frame: str = ""
    stamp: float | None = None


@dataclass(frozen=True)
class Action(_Input):
    """An action of :data:`ACTIONS` by ``name``, with its ``argument`` (see there)."""

    kind: ClassVar[str] = "action"
    name: str
    argument: object = None


@dataclass(frozen=True)
class Twist(_Input):
    """A SpaceMouse twist (``linear`` (3,), ``angular`` (3,)) in the ``twist_frame`` axes,
    unscaled; held for the time between its ``stamp`` and the previous twist's (s; None: when it
    arrived)."""

    kind: ClassVar[str] = "twist"
    doing: ClassVar[str] = "moving the object"
    linear: np.ndarray
    angular: np.ndarray
    stamp: float | None = None


@dataclass(frozen=True)
class Joy(_Input):
    """A Joy message: its ``buttons`` and ``axes``."""

    kind: ClassVar[str] = "joy"
    doing: ClassVar[str] = "SpaceMouse buttons"
    buttons: tuple
    axes: tuple = ()


@dataclass(frozen=True)
class View(_Input):
    """The operator's view pose T_scene_view (4x4)."""

    kind: ClassVar[str] = "view"
    doing: ClassVar[str] = "view pose"
    T_scene_view: np.ndarray


@dataclass(frozen=True)
class Pose(_Input):
    """An absolute pose T_scene_model of the shown candidate (a marker drag); ``release``: the
    drag ended, refit from it. ``target``: the object the drag started on -- refused when another
    object is selected by the time it is handled; None: the selected one."""

    kind: ClassVar[str] = "pose"
    doing: ClassVar[str] = "placing the object"
    T_scene_model: np.ndarray
    release: bool = False
    target: int | None = None


@dataclass(frozen=True)
class CancelDrag(_Input):
    """The drag of ``target`` ended without a release (see :meth:`OperatorStream.cancel_drag`)."""

    kind: ClassVar[str] = "cancel"
    doing: ClassVar[str] = "cancelling a drag"
    target: int | None = None


@dataclass(frozen=True)
class NewCloud(_Input):
    """A new cloud arrived: the selected object follows it."""

    kind: ClassVar[str] = "cloud"
    doing: ClassVar[str] = "following the new cloud"


#: one input of the stream
OperatorInput = Click | Action | Twist | Joy | View | Pose | CancelDrag | NewCloud
#: inputs queued between an unstarted click and a newer click from the same source that do not
#: belong to the older click's object: the newer click may supersede it (see ``submit``)
INDEPENDENT = (View, NewCloud)


# ============================================================================ the host
class OperatorHost(Protocol):
    """What the stream needs from the node it runs in (the engine node implements it).

    ``refresh_scene()`` makes the engine's scene the latest cloud before anything that fits;
    ``to_scene_frame(point, frame, stamp)`` expresses a click given in ``frame`` (at ``stamp``,
    s, or None: the latest) in the scene's frame (raising :class:`AffordanceError` when it
    cannot); ``report(kind, success, message, benign)`` hears every outcome (``kind`` names the
    input, for throttled logging; ``benign``: a refusal because the action does not apply now --
    nothing selected, nothing to undo -- which is the operator's to see, not an error);
    ``changed()`` is called after every handled input; ``busy(text)``
    when a click's fit starts. ``persist(explicit)`` writes the registrations: with ``True`` for
    ``save``, and with ``False`` right after any input that changed them (accept, undo, a Joy
    accept...), *before* that input is replied to, so what is acknowledged is durable; it
    returns a message to add to the reply ("" for none) or raises :class:`AffordanceError` (the
    input then fails with the reason; the registrations stay in memory).
    """

    def refresh_scene(self) -> None: ...

    def to_scene_frame(
        self, point: np.ndarray, frame: str, stamp: float | None = None
    ) -> np.ndarray: ...

    def report(self, kind: str, ok: bool, message: str, benign: bool = False) -> None: ...

    def changed(self) -> None: ...

    def busy(self, text: str | None) -> None: ...

    def persist(self, explicit: bool) -> str: ...


class StandaloneHost:
    """The host of a stream without a node: the engine's scene is used as it is, clicks are in
    its frame, outcomes go nowhere, and ``save`` writes ``registrations_file`` (changes are not
    written on their own)."""

    def __init__(self, engine, registrations_file: str = "affordance_registrations.yaml"):
        self.engine, self.registrations_file = engine, registrations_file

    def refresh_scene(self) -> None:
        pass

    def to_scene_frame(
        self, point: np.ndarray, frame: str, stamp: float | None = None
    ) -> np.ndarray:
        return point

    def report(self, kind: str, ok: bool, message: str, benign: bool = False) -> None:
        pass

    def changed(self) -> None:
        pass

    def busy(self, text: str | None) -> None:
        pass

    def persist(self, explicit: bool) -> str:
        return self.engine.save(self.registrations_file) if explicit else ""
