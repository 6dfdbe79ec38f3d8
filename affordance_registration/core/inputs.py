# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The operator's inputs, one small frozen record per kind, and the seam between the operator
stream (:mod:`~affordance_registration.core.operator`) and the node it runs in: what the node
gives it (:class:`Cloud` records in a :class:`LatestCloud` slot; a transform lookup, see
:mod:`~affordance_registration.core.scene_feed`) and what it gives back (an :class:`Outbox` of
what changed, which the node publishes from). Nothing here calls into the node. Pure Python (no
ROS)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable, ClassVar

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
    "Cloud",
    "LatestCloud",
    "Outcome",
    "Outbox",
    "Drained",
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


# ============================================================================ the seam
@dataclass(frozen=True)
class Cloud:
    """A cloud as it arrived: its ``frame``, ``stamp`` (s; None: unstamped), ``width`` and
    ``height`` as sent, and ``read()``, which gives its points ((N, 3), NaN rows kept) -- called
    only when a fit needs them, so a fast camera costs nothing between clicks. ``read`` raises
    :class:`~affordance_registration.core.errors.AffordanceError` for points it cannot read."""

    frame: str
    stamp: float | None
    read: Callable[[], np.ndarray] = field(compare=False, repr=False)
    width: int = 0
    height: int = 1


class LatestCloud:
    """The newest cloud from ``source`` (a topic name, said in errors), set from any thread: the
    node puts every cloud here on arrival (or says why one was dropped), the stream's scene feed
    takes the latest when it needs a scene. ``count``: clouds put so far."""

    def __init__(self, source: str = "points"):
        self.source = source
        self._lock = threading.Lock()
        self._cloud: Cloud | None = None
        self._count = 0
        self.dropped = ""  #: why the latest cloud was refused ("" if it was not)

    def put(self, cloud: Cloud) -> Cloud | None:
        """Keep ``cloud`` as the latest; returns the one it replaces."""
        with self._lock:
            previous, self._cloud = self._cloud, cloud
            self._count += 1
            self.dropped = ""
            return previous

    def refuse(self, why: str) -> None:
        """A cloud arrived and was dropped: ``why`` (the previous one stays the latest)."""
        self.dropped = why

    def latest(self) -> tuple[Cloud | None, int]:
        """(the latest cloud or None, how many had been put when it came)."""
        with self._lock:
            return self._cloud, self._count

    @property
    def count(self) -> int:
        return self._count


@dataclass(frozen=True)
class Outcome:
    """What came of an input (or of a step the stream took on its own): ``kind`` names it (an
    action's name, an input's kind, "cloud", "frame", "queue"...), ``ok`` and a ``message`` for
    a person; ``benign``: a refusal because the action does not apply now (nothing selected,
    nothing to undo) -- the operator's to see, not an error."""

    kind: str
    ok: bool
    message: str
    benign: bool = False


@dataclass(frozen=True)
class Drained:
    """What an :class:`Outbox` held: the ``outcomes`` in order, whether the state changed since
    the last drain (``changed``) and whether a long step started (``busy``: say so now)."""

    outcomes: tuple = ()
    changed: bool = False
    busy: bool = False


class Outbox:
    """What changed, for the node to publish: outcomes, a change of state, the start of a long
    step. Filled from any thread (the stream's worker, the node's callbacks); ``wake()`` (given,
    now or later: the node's guard condition, say) is called after each put so that nothing
    polls; the node drains it (:meth:`drain`) where it publishes.

    A node that publishes from it says so (:meth:`connect`) and tells it each time it has
    published (:meth:`published`): then :meth:`published_since` says whether what was put up to
    a point (:meth:`put_count`) has gone out, and ``on_published()`` (given by the stream) is
    called after each publication. Without a node, everything counts as published."""

    def __init__(self, wake: Callable[[], None] | None = None):
        #: called after each put (from the putting thread)
        self.wake: Callable[[], None] = wake or (lambda: None)
        #: called after each publication (from the publishing thread)
        self.on_published: Callable[[], None] = lambda: None
        self._lock = threading.Lock()
        self._outcomes: list[Outcome] = []
        self._changed = True  # the first drain publishes what there is
        self._busy = False
        self._connected = False  # a node publishes from it
        self._puts = 0  # puts so far
        self._drained = 0  # ... of them, those the last drain took
        self._published = 0  # ... and those the node has published

    def connect(self, wake: Callable[[], None]) -> None:
        """A node drains this outbox and publishes from it: ``wake`` is called after each put,
        and the node calls :meth:`published` after each publication."""
        with self._lock:
            self._connected = True
        self.wake = wake

    def outcome(self, kind: str, ok: bool, message: str, benign: bool = False) -> None:
        """An outcome worth saying (an empty message is not)."""
        if not message:
            return
        with self._lock:
            self._outcomes.append(Outcome(kind, ok, message, benign))
            self._changed = True
            self._puts += 1
        self.wake()

    def changed(self) -> None:
        """Something the status, markers or TF show changed."""
        with self._lock:
            self._changed = True
            self._puts += 1
        self.wake()

    def busy(self) -> None:
        """A long step (a click's fit) started: the status should say so at once."""
        with self._lock:
            self._busy = self._changed = True
            self._puts += 1
        self.wake()

    def drain(self) -> Drained:
        """Everything put since the last drain (and empty the box)."""
        with self._lock:
            out = Drained(tuple(self._outcomes), self._changed, self._busy)
            self._outcomes, self._changed, self._busy = [], False, False
            self._drained = self._puts
        return out

    def pending(self) -> bool:
        """Whether anything is waiting to be drained."""
        with self._lock:
            return bool(self._outcomes) or self._changed or self._busy

    def published(self) -> None:
        """The node published what it had drained (the state as it is now)."""
        with self._lock:
            self._published = self._drained
        self.on_published()

    def put_count(self) -> int:
        """How many puts there have been so far (for :meth:`published_since`)."""
        with self._lock:
            return self._puts

    def published_since(self, count: int) -> bool:
        """Whether the first ``count`` puts have been published (always, without a node)."""
        with self._lock:
            return not self._connected or self._published >= count
