# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Operator input in one ordered stream.

Everything the operator does -- clicks, SpaceMouse twists and buttons, service calls, marker drags
and menu entries, view poses -- goes through one :class:`OperatorStream` and is handled in the
order it arrived, one input at a time, by one worker. So an action pressed right after a click
acts on that click's object however long the fit takes, and twists that arrive while a fit is
pending move the object that fit produces.

The stream also owns what would otherwise depend on when messages happen to be handled:

* **twist integration**: each twist is held for the time between it and the previous one of the
  same burst, measured with the inputs' own time stamps (when the sender stamped them; for ROS,
  the publisher's source time stamp), not with when the worker got round to it -- a loaded
  machine that hands the node a burst late moves the object just as far;
* **the idle refit**: once the twists stop for ``refit_idle_s`` (and nothing else is queued),
  the moved object is refitted;
* **refit before leave**: a refit still waiting for the twists to stop belongs to the object
  they moved, so it runs before any input that leaves that object (a click, accept, next /
  previous / select model, discard); undo, refit, a joint step and a marker drag make it moot;
* **button edges**: a Joy message acts on the buttons that went down since the previous one;
* **joint-axis hysteresis**: a Joy axis steps the joint once per push past the threshold and
  re-arms only after it comes back below half of it.

Each kind of input is a small frozen record (:class:`Click`, :class:`Action`, :class:`Twist`,
:class:`Joy`, :class:`View`, :class:`Pose`, :class:`CancelDrag`, :class:`NewCloud`). The stream
never calls into the node it runs in: it is given what it needs -- a
:class:`~.scene_feed.SceneFeed` (the latest cloud and a transform lookup), an
:class:`~.persistence.Autosave` (where the registrations are written) -- and it puts what came of
each input, and that something changed, into an :class:`~.inputs.Outbox`, which the node
publishes from.

Pure Python with an injectable clock (and sleep): tests drive it in simulated time without ROS.
The ROS node converts messages into :meth:`OperatorStream.submit` calls and publishes what changed.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from .corrections import R_VIEW_SPACENAV
from .errors import AffordanceError
from .inputs import (
    INDEPENDENT,
    Action,
    CancelDrag,
    Click,
    Joy,
    NewCloud,
    OperatorInput,
    Outbox,
    Pose,
    Twist,
    View,
)
from .persistence import Autosave
from .scene_feed import SceneFeed

__all__ = [
    "OperatorSettings",
    "OperatorInput",
    "OperatorStream",
    "Outbox",
    "Click",
    "Action",
    "Twist",
    "Joy",
    "View",
    "Pose",
    "CancelDrag",
    "NewCloud",
    "ACTIONS",
    "LEAVING_ACTIONS",
    "MAX_QUEUED_PER_SOURCE",
    "CLICK_DEPTH",
]

#: actions the stream accepts (``Action(name)``); ``joint_value``, ``select_model`` and
#: ``dimension`` carry an argument (the joint value, the template name, a primitive's (dimension
#: name, value in m or None, steps or None)) in ``argument``
ACTIONS = (
    "next_model",
    "previous_model",
    "select_model",
    "accept",
    "refit",
    "undo",
    "discard",
    "save",
    "joint_plus",
    "joint_minus",
    "joint_value",
    "dimension",
)
#: inputs that leave the shown object: a refit still waiting for the twists to stop runs first
LEAVING_ACTIONS = ("click", "next_model", "previous_model", "select_model", "accept", "discard")
#: actions that make a waiting twist refit moot (they refit themselves, or revert the twists)
SETTLING_ACTIONS = ("refit", "undo", "joint_plus", "joint_minus", "joint_value", "dimension")
#: inputs one source may have waiting; more are refused (a flood cannot grow the queue)
MAX_QUEUED_PER_SOURCE = 500
#: unstarted clicks one source may have waiting: two quick clicks on two objects are both fitted;
#: a third supersedes the newer waiting one (the first and the latest intent are kept)
CLICK_DEPTH = 2

#: the actions Joy buttons can be mapped to
BUTTON_ACTIONS = (
    "next_model",
    "previous_model",
    "accept",
    "refit",
    "undo",
    "discard",
    "joint_plus",
    "joint_minus",
)


@dataclass(frozen=True)
class OperatorSettings:
    """How operator input is interpreted (lengths m, angles rad, times s)."""

    linear_gain: float = 0.1  #: m/s per unit of twist linear
    angular_gain: float = 0.6  #: rad/s per unit of twist angular
    #: axes of the twists: "spacenav" (device axes: x away from the user, y left, z up) or
    #: "view" (x right, y up, z to the viewer)
    twist_frame: str = "spacenav"
    max_twist_dt: float = 0.1  #: longest time one twist is held
    first_twist_dt: float = 1.0 / 30  #: the first twist of a burst: one frame of a 30 Hz device
    max_speed: float = 2.0  #: m/s; a faster twist (after the gain) is refused
    max_turn_rate: float = 10.0  #: rad/s; likewise
    refit_idle_s: float = 0.5  #: refit once the twists stopped this long
    #: Joy button per action (action name -> button index; -1 or absent: none)
    buttons: tuple = (("next_model", 0), ("accept", 1))
    joint_axis: int = -1  #: Joy axis stepping the joint (-1: none)
    joint_axis_threshold: float = 0.5  #: how far the axis must be pushed to step
    #: a new cloud refits the selected (not yet accepted) object from its current pose, at most
    #: once every ``follow_period_s``
    follow_clouds: bool = True
    follow_period_s: float = 0.5

    def validate(self) -> "OperatorSettings":
        if self.twist_frame not in ("spacenav", "view"):
            raise AffordanceError(
                f"twist_frame must be 'spacenav' or 'view', got {self.twist_frame!r}"
            )
        for name in ("linear_gain", "angular_gain", "follow_period_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise AffordanceError(f"{name} must be a finite number >= 0, got {v!r}")
        for name in (
            "max_twist_dt",
            "first_twist_dt",
            "refit_idle_s",
            "joint_axis_threshold",
            "max_speed",
            "max_turn_rate",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise AffordanceError(f"{name} must be a positive number, got {v!r}")
        for action, _ in self.buttons:
            if action not in BUTTON_ACTIONS:
                raise AffordanceError(
                    f"no Joy action {action!r} (one of {', '.join(BUTTON_ACTIONS)})"
                )
        return self

    def button_map(self) -> dict:
        return {a: int(b) for a, b in self.buttons if int(b) >= 0}


# ============================================================================ the stream
class OperatorStream:
    """The ordered stream of operator input in front of an
    :class:`~affordance_registration.core.engine.AffordanceEngine`, given its scene ``feed``,
    its ``outbox`` and its registrations' ``saver`` (see the module docstring; each has a default
    for a stream without a node).

    ``clock()`` (s, monotonic) and ``sleep(s)`` are injectable. Submit from any thread; handle
    with :meth:`run` (a worker thread) or, in tests, :meth:`process_pending`.
    """

    def __init__(
        self,
        engine,
        settings: OperatorSettings | None = None,
        clock=time.monotonic,
        sleep=time.sleep,
        *,
        feed: SceneFeed | None = None,
        outbox: Outbox | None = None,
        saver: Autosave | None = None,
    ):
        self.engine = engine
        self.settings = (settings or OperatorSettings()).validate()
        self.clock, self.sleep = clock, sleep
        if outbox is None:
            outbox = feed.outbox if feed is not None else Outbox()
        #: what came of each input and that the state changed, for the node to publish
        self.outbox = outbox
        #: the engine's scene from the latest cloud, clicks in its frame (without a node: the
        #: scene the engine has, clicks in its frame)
        self.feed = feed if feed is not None else SceneFeed(outbox=outbox)
        #: where the registrations are written (without a node: ``save`` writes
        #: affordance_registrations.yaml, locked from the first save; changes are not written
        #: on their own)
        self.saver = (
            saver
            if saver is not None
            else Autosave("affordance_registrations.yaml", enabled=False)
        )
        self._cv = threading.Condition()
        self._queue: collections.deque[OperatorInput] = collections.deque()
        self._busy: str | None = None
        self._handled: dict[str, int] = {}
        self._received: dict[str, int] = {}
        # twist bursts and the refit waiting for them to stop
        self._pending_refit = False
        self._last_twist_arrived: float | None = None
        self._last_twist_stamp: float | None = None
        # Joy state: previous buttons, joint axis armed sign
        self._buttons: tuple = ()
        self._axis_sign = 0
        self._last_follow = -math.inf

    # ------------------------------------------------------------------ settings
    def configure(self, settings: OperatorSettings) -> None:
        """Use new settings from the next input on."""
        settings = settings.validate()
        with self._cv:
            self.settings = settings
            self._cv.notify_all()

    # ------------------------------------------------------------------ input
    def submit(self, item: OperatorInput) -> None:
        """Append an input to the stream (any thread).

        Bounded per source: when :data:`CLICK_DEPTH` clicks of a source are already waiting, a
        new one supersedes the newest of them, when only views and clouds were queued after it
        (so nothing queued meant that click's object) -- a flood of clicks from one client
        leaves two waiting, the first and the latest; the superseded one is reported (and
        replied to) as such. A source with
        :data:`MAX_QUEUED_PER_SOURCE` inputs waiting has any further one refused."""
        dropped = []
        with self._cv:
            self._received[item.source] = self._received.get(item.source, 0) + 1
            waiting_clicks = sum(
                1 for q in self._queue if isinstance(q, Click) and q.source == item.source
            )
            if isinstance(item, Click) and waiting_clicks >= CLICK_DEPTH:
                for i in range(len(self._queue) - 1, -1, -1):
                    old = self._queue[i]
                    if isinstance(old, Click) and old.source == item.source:
                        del self._queue[i]  # by position: inputs hold arrays (no ==)
                        dropped.append(
                            (
                                old,
                                "superseded by a newer click from the same "
                                "source before its fit started",
                            )
                        )
                        break
                    if not isinstance(old, INDEPENDENT):
                        break
            waiting = sum(1 for q in self._queue if q.source == item.source)
            if waiting >= MAX_QUEUED_PER_SOURCE:
                dropped.append(
                    (item, f"refused: {waiting} inputs from this source are already waiting")
                )
            else:
                self._queue.append(replace(item, arrived=self.clock()))
            for old, _ in dropped:
                self._handled[old.source] = self._handled.get(old.source, 0) + 1
            self._cv.notify_all()
        for old, why in dropped:
            self._say(
                "queue",
                False,
                f"{_kind(old).replace('_', ' ')} from {old.source or 'an input'} {why}",
            )
            if old.reply is not None:
                old.reply(False, f"{_kind(old).replace('_', ' ')} {why}")

    def click(
        self, point, frame: str = "", source: str = "click", reply=None, stamp: float | None = None
    ) -> None:
        """A click at ``point`` in ``frame``, made at ``stamp`` (s; the frame is looked up then;
        None: the latest)."""
        self.submit(
            Click(np.asarray(point, dtype=float), frame, stamp, source=source, reply=reply)
        )

    def action(self, name: str, argument=None, source: str = "", reply=None) -> None:
        self.submit(Action(name, argument, source=source or name, reply=reply))

    def twist(self, linear, angular, stamp: float | None = None, source: str = "twist") -> None:
        self.submit(
            Twist(
                np.asarray(linear, dtype=float),
                np.asarray(angular, dtype=float),
                stamp,
                source=source,
            )
        )

    def joy(self, buttons, axes=(), source: str = "joy") -> None:
        self.submit(
            Joy(tuple(int(b) for b in buttons), tuple(float(a) for a in axes), source=source)
        )

    def view(self, T_scene_view, source: str = "view") -> None:
        self.submit(View(np.asarray(T_scene_view, dtype=float), source=source))

    def pose(
        self, T_scene_model, release: bool = False, source: str = "pose", target: int | None = None
    ) -> None:
        self.submit(
            Pose(np.asarray(T_scene_model, dtype=float), bool(release), target, source=source)
        )

    def cancel_drag(self, target: int | None = None, source: str = "pose") -> None:
        """The drag of ``target`` ended without a release (its client went away or silent):
        the object goes back where the drag started."""
        self.submit(CancelDrag(target, source=source))

    def new_cloud(self) -> None:
        """A new cloud arrived: the selected object follows it (in order with the operator's
        input; one such input waits in the queue at most)."""
        with self._cv:
            if any(isinstance(item, NewCloud) for item in self._queue):
                return
        self.submit(NewCloud(source="cloud"))

    # ------------------------------------------------------------------ state
    def status(self) -> dict:
        """``busy`` (what the worker does now, or None), ``queued`` inputs, ``received`` and
        ``handled`` inputs per source, ``pending_refit`` (twists moved the object and its refit
        waits for them to stop) and ``idle`` (none of these)."""
        with self._cv:
            return {
                "busy": self._busy,
                "queued": len(self._queue),
                "received": dict(self._received),
                "handled": dict(self._handled),
                "pending_refit": self._pending_refit,
                "idle": self._busy is None and not self._queue and not self._pending_refit,
            }

    def idle_refit_due(self) -> float | None:
        """When the waiting twist refit becomes due (clock time), or None."""
        with self._cv:
            if not self._pending_refit or self._last_twist_arrived is None:
                return None
            return self._last_twist_arrived + self.settings.refit_idle_s

    # ------------------------------------------------------------------ handling
    def process_pending(self) -> int:
        """Handle everything queued, then the idle refit if the clock says it is due. Returns the
        number of inputs handled (the refit not counted). For tests in simulated time."""
        n = 0
        while self._step():
            n += 1
        self._idle_refit_if_due()
        return n

    def run(self, stop: threading.Event) -> None:
        """The worker loop: handle inputs in order until ``stop`` is set; refit moved objects
        once the twists stopped."""
        while not stop.is_set():
            with self._cv:
                if not self._queue:
                    due = self.idle_refit_due()
                    wait = 0.1 if due is None else min(0.1, max(0.0, due - self.clock()))
                    self._cv.wait(timeout=wait)
            if not self._step():
                self._idle_refit_if_due()

    def _step(self) -> bool:
        with self._cv:
            if not self._queue:
                return False
            item = self._queue.popleft()
            self._busy = _describe(item, len(self._queue))
        registered = self.engine.state.registered
        try:
            ok, message = self._handle(item)
        except AffordanceError as exc:
            ok, message = False, str(exc)
        except Exception as exc:  # a bug must not kill the worker or leave a caller waiting
            ok, message = False, f"internal error while handling {item.kind}: {exc!r}"
        if self.engine.state.registered is not registered:
            try:  # durable before it is acknowledged
                saved = self.saver.persist(self.engine, False)
                message = "; ".join(m for m in (message, saved) if m)
            except AffordanceError as exc:
                ok, message = False, f"{message}; NOT saved: {exc}"
            except Exception as exc:
                ok, message = False, f"{message}; NOT saved: internal error: {exc!r}"
        if message:
            self._say(_kind(item), ok, message)
        if item.reply is not None:
            item.reply(ok, message)
        with self._cv:
            self._busy = None
            self._handled[item.source] = self._handled.get(item.source, 0) + 1
        self.outbox.changed()
        return True

    def _idle_refit_if_due(self) -> None:
        due = self.idle_refit_due()
        with self._cv:
            if due is None or self._queue or self.clock() < due:
                return
            self._pending_refit = False
            self._busy = "refitting after the SpaceMouse stopped"
        try:
            self._say("refit", *self._refit())
        except AffordanceError as exc:
            self._say("refit", False, str(exc))
        finally:
            with self._cv:
                self._busy = None
            self.outbox.changed()

    def _say(self, kind: str, ok: bool, message: str) -> None:
        """An outcome into the outbox; a failed action's line names the action ("accept: no
        object selected ...": the reply to the input itself does not)."""
        if not ok and kind in ACTIONS:
            message = f"{kind.replace('_', ' ')}: {message}"
        self.outbox.outcome(kind, ok, message)

    def _handle(self, item: OperatorInput) -> tuple[bool, str]:
        match item:
            case Twist():
                return self._on_twist(item)
            case Joy():
                return self._on_joy(item)
            case View():
                self.engine.set_view(item.T_scene_view)
                return True, ""
            case Pose():
                return self._on_pose(item)
            case Click():
                self._settle("click")
                return self._on_click(item)
            case Action():
                return self._act(item.name, item.argument)
            case NewCloud():
                return self._follow()
            case CancelDrag():
                return True, self.engine.cancel_drag(item.target)
        raise AffordanceError(f"unknown operator input {item!r}")

    def _settle(self, action: str) -> None:
        """Before an input that leaves the object, the refit its twists are waiting for; before
        one that refits or reverts anyway, nothing."""
        if not self._pending_refit:
            return
        if action in LEAVING_ACTIONS:
            self._pending_refit = False
            ok, message = self._refit()
            self._say("refit", ok, message)
        elif action in SETTLING_ACTIONS or action == "pose":
            self._pending_refit = False

    def _refit(self) -> tuple[bool, str]:
        self.feed.refresh(self.engine)
        return True, self.engine.refit()

    def _on_click(self, item: Click) -> tuple[bool, str]:
        self.outbox.busy()
        self.feed.refresh(self.engine)
        point = self.feed.express(item.point, item.frame, item.stamp, self.engine.frame_id)
        return True, self.engine.click(point)

    def _act(self, action: str, argument=None) -> tuple[bool, str]:
        if action not in ACTIONS:
            raise AffordanceError(f"unknown action {action!r}")
        self._settle(action)
        if action in ("refit", "joint_plus", "joint_minus", "joint_value", "dimension"):
            self.feed.refresh(self.engine)
        engine = self.engine
        match action:
            case "save":
                return True, self.saver.persist(self.engine, True)
            case "refit":
                return True, engine.refit()
            case "joint_plus":
                return True, engine.correct_joint(steps=1.0)
            case "joint_minus":
                return True, engine.correct_joint(steps=-1.0)
            case "joint_value":
                return True, engine.correct_joint(value=argument)
            case "dimension":
                name, value, steps = argument
                return True, engine.correct_dimension(name, value=value, steps=steps)
            case "select_model":
                return True, engine.select_model(argument)
            case "next_model":
                return True, engine.next_model()
            case "previous_model":
                return True, engine.previous_model()
            case "accept":
                return True, engine.accept()
            case "undo":
                return True, engine.undo()
            case "discard":
                return True, engine.discard()
        raise AffordanceError(f"unknown action {action!r}")

    def _on_twist(self, item: Twist) -> tuple[bool, str]:
        s = self.settings
        lin, ang = item.linear, item.angular
        if not (np.all(np.isfinite(lin)) and np.all(np.isfinite(ang))):
            raise AffordanceError("ignored a twist with NaN/inf values")
        if not (np.any(lin) or np.any(ang)):
            return True, ""  # released: the idle refit takes over
        stamp = item.arrived if item.stamp is None else item.stamp
        prev = self._last_twist_stamp
        gap = math.inf if prev is None else stamp - prev
        # the first twist of a burst counts as one frame of the device
        dt = s.first_twist_dt if not 0 <= gap <= s.refit_idle_s else min(gap, s.max_twist_dt)
        self._last_twist_stamp = stamp
        self._last_twist_arrived = item.arrived
        if s.twist_frame == "spacenav":
            lin, ang = R_VIEW_SPACENAV @ lin, R_VIEW_SPACENAV @ ang
        lin, ang = lin * s.linear_gain, ang * s.angular_gain
        speed, rate = float(np.linalg.norm(lin)), float(np.linalg.norm(ang))
        if speed > s.max_speed or rate > s.max_turn_rate:
            raise AffordanceError(
                f"ignored a twist of {speed:.3g} m/s, {rate:.3g} rad/s (at most "
                f"{s.max_speed:g} m/s, {s.max_turn_rate:g} rad/s)"
            )
        try:
            self.engine.correct_twist(lin, ang, dt)
        except AffordanceError as exc:
            raise AffordanceError(f"twist ignored: {exc}") from None
        self._pending_refit = True
        return True, ""  # a burst is reported by its refit, not per message

    def _on_joy(self, item: Joy) -> tuple[bool, str]:
        s = self.settings
        buttons, axes = item.buttons, item.axes
        previous = self._buttons + (0,) * max(0, len(buttons) - len(self._buttons))
        self._buttons = buttons
        pressed = [
            action
            for action, b in s.button_map().items()
            if b < len(buttons) and buttons[b] and not previous[b]
        ]
        a = s.joint_axis
        if 0 <= a < len(axes):
            v = axes[a]
            v = v if math.isfinite(v) else 0.0
            if self._axis_sign and abs(v) < 0.5 * s.joint_axis_threshold:
                self._axis_sign = 0  # back near the centre: re-armed
            elif not self._axis_sign and abs(v) >= s.joint_axis_threshold:
                self._axis_sign = 1 if v > 0 else -1
                pressed.append("joint_plus" if v > 0 else "joint_minus")
        results = []
        for action in pressed:  # each press in order, as if pressed one after the other
            try:
                results.append((True, self._act(action)[1]))
            except AffordanceError as exc:
                results.append((False, f"{action.replace('_', ' ')}: {exc}"))
        if not results:
            return True, ""
        return all(ok for ok, _ in results), "; ".join(m for _, m in results if m)

    def _follow(self) -> tuple[bool, str]:
        """The selected object follows a new cloud -- unless the operator is pushing it (its
        refit will use the new cloud) or it followed one moments ago."""
        s = self.settings
        now = self.clock()
        if (
            not s.follow_clouds
            or self._pending_refit
            or now - self._last_follow < s.follow_period_s
        ):
            return True, ""
        self.feed.refresh(self.engine)
        message = self.engine.follow_scene()
        if message is None:
            return True, ""
        self._last_follow = now
        return True, message

    def _on_pose(self, item: Pose) -> tuple[bool, str]:
        if item.target is not None:
            active = self.engine.active_object()
            if active is None or active.id != item.target:
                now = f"object {active.id} is" if active is not None else "no object is"
                raise AffordanceError(
                    f"{'release' if item.release else 'drag'} refused: it "
                    f"started on object {item.target}, and {now} selected "
                    f"now"
                )
        self._settle("pose")
        message = self.engine.correct_pose(item.T_scene_model, drag=True)
        if not item.release:
            return True, ""
        self.engine.end_drag()
        self.feed.refresh(self.engine)
        return True, f"{message}; {self.engine.refit()}"


def _kind(item: OperatorInput) -> str:
    """The name an input's outcome is reported under: an action's name, else its kind."""
    return item.name if isinstance(item, Action) else item.kind


def _describe(item: OperatorInput, queued: int) -> str:
    text = item.name if isinstance(item, Action) else item.doing
    return f"{text} ({queued} more queued)" if queued else text
