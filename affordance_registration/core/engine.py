# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""AffordanceEngine: objects of interest, ranked candidates, cycling, corrections, refit, accept,
undo, save and load. Pure Python (no ROS); the ROS node is a thin wrapper around it.

State is kept in immutable records (:class:`EngineState` and its parts, in ``tracked.py``), so
undo restores the previous state exactly, and every action swaps the whole state under a lock: the
engine is safe to call from several threads. Fitting runs outside the lock; only its result is
committed under it. The registrations file's format is read and written in ``persistence.py``.

A click's object is committed as soon as its fit is judged and assessed (settled or not): where
the sensor should look from to settle an unsettled one is not on the click's path. It is due
(:attr:`AffordanceEngine.views_due`) and computed by :meth:`AffordanceEngine.suggest_view`
when the caller has nothing else to do (the operator stream, once the click's status went out).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from .corrections import apply_twist, view_from_optical
from .errors import AffordanceError, EngineStateError, SceneError, bounded
from .memo import PerRecord
from .persistence import REGISTRATIONS_FORMAT, load_registrations, save_registrations
from .registration import NO_MATCH, FitReport, FitResult, FitSettings, Registrar
from .scene import Scene
from .templates import TemplateLibrary
from .tracked import EngineState, Registration, TrackedObject
from .transforms import finite_transform, is_rigid
from .waypoints import Trajectory, trajectory, waypoints_dict

__all__ = [
    "AffordanceEngine",
    "TrackedObject",
    "Registration",
    "EngineState",
    "load_registrations",
    "save_registrations",
    "REGISTRATIONS_FORMAT",
]


@dataclass(frozen=True, eq=False)
class _ViewDue:
    """An unsettled click's answer whose suggested view is still to be computed: the object,
    the report of its fit (its ``ambiguity`` is the answer: the states that hold it get the
    view), the scene it was fitted in and the sensor's pose then (None: unknown), and the
    click's timing as the status shows it (the view's time joins it there)."""

    object_id: int
    report: FitReport
    scene: Scene
    T_scene_optical: np.ndarray | None
    timing: dict


class AffordanceEngine:
    """The operator-facing registration engine.

    Every action returns a message a person can read, or raises :class:`EngineStateError` when it
    does not apply now (nothing selected, nothing to undo, no joint...) and :class:`SceneError` for
    a bad click. ``select_radius``: a click within this fraction of the shown template's diameter
    from an object's centre selects that object instead of starting a new one.
    """

    def __init__(
        self,
        library: TemplateLibrary,
        settings: FitSettings | None = None,
        select_radius: float = 0.4,
        undo_depth: int = 200,
        joint_step_rad: float = math.radians(5.0),
        joint_step_m: float = 0.002,
        reach_m: float = 1.0,
        dimension_step_m: float = 0.005,
    ):
        self.reach_m = float(reach_m)  #: corrections keep an object this close to its click
        self.registrar = Registrar(library, settings)
        self.registrar.warm_up()
        self.library = library
        self.select_radius = float(select_radius)
        self.undo_depth = int(undo_depth)
        self.joint_step_rad = float(joint_step_rad)  #: one joint nudge, revolute (rad)
        self.joint_step_m = float(joint_step_m)  #: one joint nudge, prismatic (m)
        self.dimension_step_m = float(dimension_step_m)  #: one nudge of a primitive's size (m)
        self._lock = threading.RLock()
        self._state = EngineState()
        self._undo: list[tuple[EngineState, str]] = []
        self._scene: Scene | None = None
        self._scene_version = 0
        self._frame_id = ""
        self._T_scene_view: np.ndarray | None = None
        self._T_scene_optical: np.ndarray | None = None
        self._last_action = ""
        self._last_timing: dict = {}
        self._entries = PerRecord(
            lambda r, lib: dict(r.to_dict(), waypoints=waypoints_dict(lib, r))
        )
        #: the drag in progress: (object id, candidate index, pose and corrections before it)
        self._drag_start: tuple | None = None
        #: unsettled clicks whose suggested view is still to be computed, by object id
        self._views_due: dict[int, _ViewDue] = {}

    def configure(
        self, settings: FitSettings | None = None, library: TemplateLibrary | None = None
    ) -> None:
        """Use new fitting settings and/or a new template library from the next fit on.
        Registrations are kept; a new library is refused while objects of interest are open
        (their candidates refer to the old templates)."""
        library = library or self.library
        registrar = Registrar(library, settings or self.registrar.settings)
        registrar.warm_up()
        with self._lock:
            if library is not self.library and self._state.objects:
                raise EngineStateError(
                    "accept or discard the open objects before changing the template library"
                )
            self.registrar, self.library = registrar, library

    # ------------------------------------------------------------------ state access
    @property
    def state(self) -> EngineState:
        return self._state

    @property
    def frame_id(self) -> str:
        return self._frame_id

    @property
    def has_scene(self) -> bool:
        return self._scene is not None

    def active_object(self) -> TrackedObject | None:
        with self._lock:
            return self._find(self._state.active_id)

    def _find(self, obj_id) -> TrackedObject | None:
        for o in self._state.objects:
            if o.id == obj_id:
                return o
        return None

    def _commit(self, new_state: EngineState, action: str, coalesce: bool = False) -> None:
        """Swap in a new state, remembering the old one for undo (call with the lock held)."""
        if not (coalesce and self._last_action == action and self._undo):
            self._undo.append((self._state, action))
            del self._undo[: -self.undo_depth]
        self._state = new_state
        self._last_action = action

    def _replace_object(self, obj: TrackedObject) -> EngineState:
        objs = tuple(obj if o.id == obj.id else o for o in self._state.objects)
        return replace(self._state, objects=objs)

    def _require_active(self) -> TrackedObject:
        obj = self._find(self._state.active_id)
        if obj is None:
            raise EngineStateError("no object selected: click an object first")
        return obj

    # ------------------------------------------------------------------ inputs
    def set_scene(
        self,
        points,
        frame_id: str = "",
        sensor_origin=None,
        T_scene_optical: np.ndarray | None = None,
    ) -> int:
        """Replace the scene (the latest cloud). Returns the number of points the cloud has,
        holes included (counting the finite ones would cost a pass over the cloud that a click
        does not need). Existing objects keep their crops until they are refitted, which
        re-crops the new scene.

        ``sensor_origin`` as for :class:`~affordance_registration.core.scene.Scene` (None: the
        frame's origin; ``"none"``: no single viewpoint). ``T_scene_optical`` (4x4): the
        sensor's pose as an optical frame (x right, y down, z forward) in the scene frame, for
        the default view of twists; None: an optical frame with the scene frame's axes at the
        sensor origin (a cloud in its camera's optical frame)."""
        scene = (
            points
            if isinstance(points, Scene)
            else Scene(points, sensor_origin=sensor_origin, frame_id=frame_id)
        )
        if T_scene_optical is not None:
            T_scene_optical = finite_transform(T_scene_optical, "the sensor pose")
        with self._lock:
            self._scene = scene
            self._scene_version += 1
            self._frame_id = frame_id or scene.frame_id
            self._T_scene_optical = T_scene_optical
        return scene.size

    def reexpress(self, T_new_old: np.ndarray, new_frame: str) -> str:
        """The scene's frame changes (the cloud now comes in ``new_frame``): every open object,
        registration, the undo history, the drag in progress and the view are re-expressed in
        the new frame, ``T_new_old`` (4x4, rigid) being the old frame's pose in the new one.
        Open objects are re-cropped on their next refit. Returns a line saying what moved."""
        T = finite_transform(T_new_old, "the transform between the old and the new frame")

        def obj_in_new(o: TrackedObject) -> TrackedObject:
            cands = tuple(replace(c, T_scene_model=T @ c.T_scene_model) for c in o.candidates)
            return replace(o, candidates=cands, click=T[:3, :3] @ o.click + T[:3, 3], context=None)

        def reg_in_new(r: Registration) -> Registration:
            if r.frame_id and r.frame_id.lstrip("/") == new_frame.lstrip("/"):
                return r  # already in the new frame
            return replace(
                r,
                T_scene_model=T @ r.T_scene_model,
                click=T[:3, :3] @ r.click + T[:3, 3],
                frame_id=new_frame,
            )

        def state_in_new(st: EngineState) -> EngineState:
            return replace(
                st,
                objects=tuple(obj_in_new(o) for o in st.objects),
                registered=tuple(reg_in_new(r) for r in st.registered),
            )

        with self._lock:
            old = self._frame_id
            self._state = state_in_new(self._state)
            self._undo = [(state_in_new(st), action) for st, action in self._undo]
            if self._drag_start is not None:
                obj_id, index, T_before, corrections = self._drag_start
                self._drag_start = (obj_id, index, T @ T_before, corrections)
            if self._T_scene_view is not None:
                self._T_scene_view = T @ self._T_scene_view
            self._views_due.clear()  # (they would be computed in the old frame)
            self._frame_id = new_frame
            n, m = len(self._state.objects), len(self._state.registered)
        return (
            f"the cloud's frame changed from '{bounded(old)}' to '{bounded(new_frame)}': "
            f"{n} open object(s) and {m} registration(s) re-expressed in it through TF"
        )

    def close_open_objects(self, why: str) -> str:
        """Close every open object (they cannot be carried over: ``why``), and forget the undo
        history (its states hold them). Registrations keep their own frame. Returns the line."""
        with self._lock:
            ids = [o.id for o in self._state.objects]
            self._state = replace(self._state, objects=(), active_id=None)
            self._undo.clear()
            self._drag_start = None
            self._views_due.clear()
            self._last_action = "close"
        closed = (
            f"open object(s) {', '.join(map(str, ids))} closed"
            if ids
            else "no open object to close"
        )
        return f"{why}: {closed}; registrations keep their own frame_id"

    def set_view(self, T_scene_view: np.ndarray | None) -> None:
        """The operator's view pose (x right, y up, z to the viewer) in the scene frame, or None
        for the default: looking through the sensor (see :meth:`set_scene`)."""
        if T_scene_view is not None:
            T_scene_view = finite_transform(T_scene_view, "view pose")
        with self._lock:
            self._T_scene_view = T_scene_view

    def view_pose(self) -> np.ndarray:
        with self._lock:
            if self._T_scene_view is not None:
                return self._T_scene_view
            if self._T_scene_optical is not None:
                return view_from_optical(self._T_scene_optical)
            origin = None if self._scene is None else self._scene.sensor_origin
            T = np.eye(4)
            T[:3, 3] = np.zeros(3) if origin is None else origin
            return view_from_optical(T)

    # ------------------------------------------------------------------ actions
    def click(self, point) -> str:
        """Select the object of interest near ``point`` or fit every template around it."""
        with self._lock:
            scene, version = self._scene, self._scene_version
            T_scene_optical = self._T_scene_optical
            if scene is None:
                raise EngineStateError("no point cloud received yet: cannot fit a click")
            p = np.asarray(point, dtype=float).reshape(-1)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise SceneError(f"click must be 3 finite numbers, got {point!r}")
            for obj in self._state.objects:
                T = obj.shown.T_scene_model
                tpl = self.geometry(obj.shown)
                centre = T[:3, :3] @ tpl.centroid + T[:3, 3]
                if np.linalg.norm(p - centre) <= self.select_radius * tpl.diameter:
                    if obj.id != self._state.active_id:
                        self._commit(replace(self._state, active_id=obj.id), "select")
                    return f"selected object {obj.id}: {obj.describe()}"
        report = self.registrar.fit(scene, p)  # outside the lock: fitting takes time
        with self._lock:
            obj = TrackedObject(
                id=self._state.next_id,
                click=report.point,
                candidates=report.candidates,
                refined=frozenset({0}),
                context=report.context,
                scene_version=version,
                fit_s=report.timing_s["total"],
                ambiguity=report.ambiguity,
            )
            self._commit(
                replace(
                    self._state,
                    objects=self._state.objects + (obj,),
                    active_id=obj.id,
                    next_id=obj.id + 1,
                ),
                "click",
            )
            self._fitted(obj.id, report, scene, T_scene_optical)
            return f"object {obj.id}: {obj.describe()} ({report.timing_s['total']:.2f} s)"

    def _fitted(self, obj_id: int, report: FitReport, scene: Scene, T_scene_optical) -> None:
        """A click's fit of object ``obj_id`` committed (call with the lock held): its timing
        is the status's, and its suggested view is due when the answer is unsettled (and the
        scan has a viewpoint to move)."""
        self._last_timing = timing = dict(report.timing_s)
        for key in [k for k, job in self._views_due.items() if not _holds(self._state, job)]:
            del self._views_due[key]  # (objects gone: without a stream, none would be computed)
        self._views_due.pop(obj_id, None)
        amb, ctx = report.ambiguity, report.context
        if amb is not None and not amb.settled and ctx.sensor_origin is not None:
            self._views_due[obj_id] = _ViewDue(obj_id, report, scene, T_scene_optical, timing)

    @property
    def views_due(self) -> int:
        """How many unsettled clicks wait for their suggested view (:meth:`suggest_view`)."""
        with self._lock:
            return len(self._views_due)

    def suggest_view(self) -> str | None:
        """Where the sensor should look from to settle an unsettled click
        (:meth:`Registrar.suggest_view`), computed now for one click whose view is due -- the
        selected object's first, else the newest -- and given to every state that still holds
        that click's answer: the current one and those undo returns to. An answer the current
        state no longer holds (the object was accepted, discarded, undone or fitted anew
        meanwhile) has its view dropped, uncomputed. Returns a line on what came of it, or
        None when no view was due. The view's time is its own (``SuggestedView.time_s``, and
        ``suggest_view`` in the status's timing while that is the click's)."""
        with self._lock:
            if not self._views_due:
                return None
            key = self._state.active_id
            job = self._views_due.pop(key if key in self._views_due else max(self._views_due))
            if not _holds(self._state, job):
                return f"object {job.object_id} changed: its suggested view is not needed"
        t0 = time.perf_counter()
        view = self.registrar.suggest_view(job.report, job.T_scene_optical, job.scene)
        took = time.perf_counter() - t0
        with self._lock:
            if self._last_timing is job.timing:
                self._last_timing = dict(job.timing, suggest_view=took)
            if not _holds(self._state, job):
                return f"object {job.object_id} changed: its suggested view is dropped"

            def with_view(st: EngineState) -> EngineState:
                if not _holds(st, job):
                    return st
                return replace(
                    st,
                    objects=tuple(
                        replace(o, suggested_view=view) if _answer_of(o, job) else o
                        for o in st.objects
                    ),
                )

            self._state = with_view(self._state)
            self._undo = [(with_view(st), action) for st, action in self._undo]
        if view is None:
            return f"object {job.object_id}: no view within the bounds tells its rivals apart"
        return f"object {job.object_id}: suggested view: {view.describe()} ({took:.2f} s)"

    def _cycle(self, step: int) -> str:
        with self._lock:
            obj = self._require_active()
            if len(obj.candidates) < 2:
                raise EngineStateError("only one candidate: nothing to cycle to")
        return self._show(obj, (obj.active + step) % len(obj.candidates))

    def _show(self, obj: TrackedObject, active: int) -> str:
        """Show candidate ``active`` of ``obj`` (refined at full resolution the first time it
        is shown -- one the library prefilter set aside is fitted then: its pose and residual
        were the coarse stage's, and it had no verdict; the refit runs outside the lock)."""
        ctx, candidates, refined = obj.context, obj.candidates, obj.refined
        if active not in refined and ctx is not None:
            cand = candidates[active]
            with self._lock:  # the object's own cloud: a primitive's crop may widen
                scene = self._scene if obj.scene_version == self._scene_version else None
            better = self.registrar.refit(
                ctx,
                cand.template,
                cand.T_scene_model,
                cand.joints,
                cand.scale,
                dimensions=cand.dimensions or None,
                scene=scene,
            )
            if better.likelihood >= cand.likelihood or cand.prefiltered:
                cand = replace(better, rank=cand.rank, probability=cand.probability)
            candidates = obj.with_candidate(active, cand).candidates
            refined = refined | {active}
        with self._lock:
            current = self._find(obj.id)
            if current is None or current.active != obj.active:
                raise EngineStateError("the object changed meanwhile; try again")
            new = replace(
                current,
                active=active,
                candidates=candidates,
                refined=refined,
                model_changes=current.model_changes + 1,
            )
            self._commit(self._replace_object(new), "cycle")
            return f"object {new.id}: {new.describe()}"

    def select_model(self, template: str) -> str:
        """Show the selected object's candidate of ``template`` (by name, any rank)."""
        with self._lock:
            obj = self._require_active()
            names = [c.template for c in obj.candidates]
            if template not in names:
                raise EngineStateError(
                    f"object {obj.id} has no candidate '{bounded(template)}' "
                    f"(candidates: {', '.join(names)})"
                )
            index = names.index(template)
            if index == obj.active:
                return f"object {obj.id}: {obj.describe()} (already shown)"
        return self._show(obj, index)

    def next_model(self) -> str:
        """Show the next most likely candidate of the selected object (wraps around)."""
        return self._cycle(+1)

    def previous_model(self) -> str:
        """Show the previous candidate (wraps around)."""
        return self._cycle(-1)

    def correct_twist(self, linear, angular, dt: float, T_scene_view=None) -> str:
        """Move the shown candidate by a view-frame twist (m/s, rad/s) held for ``dt`` s. Twists
        in a row form one correction (one undo step) until something else happens."""
        with self._lock:
            obj = self._require_active()
            view = self.view_pose() if T_scene_view is None else np.asarray(T_scene_view, float)
            tpl = self.geometry(obj.shown)
            T = apply_twist(obj.shown.T_scene_model, linear, angular, dt, view, tpl.centroid)
            first = self._last_action != "twist"
            new = self._with_pose(obj, T, corrections=obj.corrections + (1 if first else 0))
            self._commit(self._replace_object(new), "twist", coalesce=True)
            return f"object {obj.id}: moved {obj.shown.template}"

    def correct_pose(self, T_scene_model, drag: bool = False) -> str:
        """Set the shown candidate's pose (an absolute correction, e.g. a dragged marker).
        With ``drag``, the poses of one drag in a row form one correction (one undo step)."""
        T = np.asarray(T_scene_model, dtype=float)
        with self._lock:
            obj = self._require_active()
            first = not (drag and self._last_action == "drag")
            new = self._with_pose(obj, T, corrections=obj.corrections + (1 if first else 0))
            if drag and (first or self._drag_start is None or self._drag_start[0] != obj.id):
                self._drag_start = (obj.id, obj.active, obj.shown.T_scene_model, obj.corrections)
            self._commit(self._replace_object(new), "drag" if drag else "pose", coalesce=drag)
            return f"object {obj.id}: {obj.shown.template} placed"

    def end_drag(self) -> None:
        """The drag in progress was released (its pose stays)."""
        with self._lock:
            self._drag_start = None

    def cancel_drag(self, object_id: int | None = None) -> str:
        """Put the object of the drag in progress back where the drag started (its client went
        away or fell silent): the drag is not committed. ``object_id``: the object the drag
        started on (None: whichever it was). One undo step."""
        with self._lock:
            start, self._drag_start = self._drag_start, None
            if start is None or (object_id is not None and start[0] != object_id):
                raise EngineStateError("no drag in progress to cancel")
            obj_id, index, T_before, corrections = start
            obj = self._find(obj_id)
            if obj is None or index >= len(obj.candidates):
                raise EngineStateError(f"the dragged object {obj_id} is gone: nothing to cancel")
            cand = replace(obj.candidates[index], T_scene_model=T_before)
            self._commit(
                self._replace_object(obj.with_candidate(index, cand, corrections=corrections)),
                "cancel drag",
            )
            return (
                f"object {obj_id}: the unfinished drag was cancelled; "
                f"{cand.template} is back where the drag started"
            )

    def _with_pose(self, obj: TrackedObject, T: np.ndarray, corrections: int) -> TrackedObject:
        """``obj`` with its shown candidate at ``T`` -- refused when that is not a finite rigid
        pose or takes the object farther than ``reach_m`` from where it was clicked."""
        T = np.array(T, dtype=float)
        if not is_rigid(T):
            raise AffordanceError("the corrected pose must be a finite rigid 4x4 transform")
        tpl = self.geometry(obj.shown)
        away = float(np.linalg.norm(T[:3, :3] @ tpl.centroid + T[:3, 3] - obj.click))
        if away > self.reach_m:
            raise AffordanceError(
                f"the correction would put {obj.shown.template} {away:.3g} m "
                f"from where it was clicked (at most {self.reach_m:g} m)"
            )
        return obj.with_shown(replace(obj.shown, T_scene_model=T), corrections=corrections)

    def correct_joint(
        self, steps: float | None = None, value: float | None = None, refit: bool = True
    ) -> str:
        """Nudge the shown candidate's joint by ``steps`` joint steps (``joint_step_rad`` for a
        revolute joint, ``joint_step_m`` for a prismatic one) or set it to ``value`` (rad or m),
        clamped to its limits; then, with ``refit``, refit the pose with the joint held where
        the operator put it. One correction (one undo step with its refit)."""
        with self._lock:
            obj = self._require_active()
            tpl = self.library[obj.shown.template]
            joint = tpl.joint
            if joint is None:
                raise EngineStateError(f"{tpl.name} has no joint to move")
            q = tpl.joint_value(obj.shown.joints)
            if value is not None:
                q_new = float(value)
            elif steps is not None:
                step = self.joint_step_rad if joint.type == "revolute" else self.joint_step_m
                q_new = q + float(steps) * step
            else:
                raise AffordanceError("give a number of joint steps or a joint value")
            if not np.isfinite(q_new):
                raise AffordanceError(f"joint value must be finite, got {q_new!r}")
            q_new = float(np.clip(q_new, joint.lower, joint.upper))
            joints = {joint.name: q_new}
            cand = replace(obj.shown, joints=joints, state=tpl.nearest_state(joints))
            new = obj.with_shown(cand, corrections=obj.corrections + 1)
            self._commit(self._replace_object(new), "joint")
        unit = "deg" if joint.type == "revolute" else "mm"
        shown = np.degrees(q_new) if joint.type == "revolute" else q_new * 1000
        msg = f"object {obj.id}: {joint.name} of {tpl.name} at {shown:.1f} {unit} ({cand.state})"
        if refit:
            msg += "; " + self.refit(hold_joint=True, coalesce=True)
        return msg

    def correct_dimension(
        self, name: str, value: float | None = None, steps: float | None = None, refit: bool = True
    ) -> str:
        """Set the shown primitive's dimension ``name`` (a box's "x", "y", "z", a cylinder's
        "radius", "length") to ``value`` (m) or change it by ``steps`` of ``dimension_step_m``,
        clipped to the template's range; then, with ``refit``, refit the pose with the
        dimensions held where the operator put them. One correction (one undo step with its
        refit); later refits keep the dimensions."""
        with self._lock:
            obj = self._require_active()
            tpl = self.library[obj.shown.template]
            if tpl.primitive is None:
                raise EngineStateError(
                    f"{tpl.name} is not a primitive: it has no dimensions to set"
                )
            if name not in tpl.dimension_ranges:
                raise AffordanceError(
                    f"a {tpl.primitive} has the dimensions "
                    f"{', '.join(tpl.dimension_ranges)}, not {name!r}"
                )
            dims = dict(obj.shown.dimensions or tpl.dimensions)
            if value is not None:
                new_value = float(value)
            elif steps is not None:
                new_value = dims[name] + float(steps) * self.dimension_step_m
            else:
                raise AffordanceError("give a dimension value (m) or a number of steps")
            if not math.isfinite(new_value):
                raise AffordanceError(f"a dimension must be a finite number, got {value!r}")
            dims[name] = new_value
            dims = tpl.clip_dimensions(dims)
            new = obj.with_shown(
                replace(obj.shown, dimensions=dims), corrections=obj.corrections + 1
            )
            self._commit(self._replace_object(new), "dimension")
        msg = f"object {obj.id}: {tpl.name} {name} {dims[name] * 1000:.1f} mm"
        if refit:
            msg += "; " + self.refit(coalesce=True)
        return msg

    def geometry(self, candidate: FitResult):
        """The template a candidate is drawn and placed with (a primitive at its size)."""
        tpl = self.library[candidate.template]
        return (
            tpl.sized(candidate.dimensions)
            if tpl.primitive is not None and candidate.dimensions
            else tpl
        )

    def refit(self, hold_joint: bool | None = None, coalesce: bool = False) -> str:
        """Refit the shown candidate locally from its current (possibly corrected) pose, joint
        values and scale. Joint values the candidate has are kept (``hold_joint=False``:
        estimate them again), ones it lacks are estimated."""
        with self._lock:
            obj = self._require_active()
            scene, version = self._scene, self._scene_version
        ctx = obj.context
        if scene is not None and (ctx is None or obj.scene_version != version):
            # a newer cloud arrived: re-crop it around the object's current centre
            tpl = self.geometry(obj.shown)
            T = obj.shown.T_scene_model
            try:
                ctx = self.registrar.prepare(scene, T[:3, :3] @ tpl.centroid + T[:3, 3])
            except SceneError:
                ctx = self.registrar.prepare(scene, obj.click)
        if ctx is None:
            raise EngineStateError("no point cloud to refit against")
        t0 = time.perf_counter()
        shown = obj.shown
        res = self.registrar.refit(
            ctx,
            shown.template,
            shown.T_scene_model,
            shown.joints,
            shown.scale,
            hold_joint=hold_joint,
            dimensions=shown.dimensions or None,
            scene=scene,
        )
        if hold_joint and shown.joints:  # the operator's value, whatever the settings
            res = replace(res, joints=dict(shown.joints), state=shown.state)
        with self._lock:
            current = self._find(obj.id)
            if (
                current is None
                or current.shown.template != obj.shown.template
                or not np.array_equal(current.shown.T_scene_model, obj.shown.T_scene_model)
                or current.shown.joints != shown.joints
                or current.shown.dimensions != shown.dimensions
            ):
                raise EngineStateError("the object changed during the refit; refit again")
            cand = replace(res, rank=current.shown.rank, probability=current.shown.probability)
            new = current.with_shown(
                cand,
                context=ctx,
                scene_version=version,
                refined=current.refined | {current.active},
            )
            if coalesce:  # the refit belongs to the correction just made: one undo step
                self._state = self._replace_object(new)
            else:
                self._commit(self._replace_object(new), "refit")
            self._last_timing = {"refit": time.perf_counter() - t0}
            c = self.geometry(obj.shown).centroid  # where the object is, wherever its origin
            before, after = obj.shown.T_scene_model, res.T_scene_model
            moved = np.linalg.norm(
                after[:3, :3] @ c + after[:3, 3] - before[:3, :3] @ c - before[:3, 3]
            )
            return (
                f"object {obj.id}: refit {cand.template} (moved {moved * 1000:.1f} mm, "
                f"likelihood {cand.likelihood:.0f})"
            )

    def follow_scene(self) -> str | None:
        """Refit the selected object on the latest scene if it was fitted on an older one (a
        new cloud arrived), from its current pose, keeping its joint values; not an undo step.
        An unsettled object the operator has not touched is fitted anew at its click instead
        (all templates: a view from elsewhere can settle it). None when there is nothing to
        follow."""
        with self._lock:
            obj = self._find(self._state.active_id)
            if obj is None or self._scene is None or obj.scene_version == self._scene_version:
                return None
            scene, version = self._scene, self._scene_version
            T_scene_optical = self._T_scene_optical
        if (
            obj.ambiguity is not None
            and not obj.ambiguity.settled
            and not obj.corrections
            and not obj.model_changes
        ):  # untouched and unsettled: the click fitted anew
            report = self.registrar.fit(scene, obj.click)
            with self._lock:
                if self._find(obj.id) is not obj:
                    raise EngineStateError("the object changed during the refit; refit again")
                new = replace(
                    obj,
                    candidates=report.candidates,
                    active=0,
                    context=report.context,
                    refined=frozenset({0}),
                    scene_version=version,
                    ambiguity=report.ambiguity,
                    suggested_view=None,
                )
                self._state = self._replace_object(new)
                self._fitted(obj.id, report, scene, T_scene_optical)
                return f"object {obj.id}: fitted again on the new cloud: {new.describe()}"
        return self.refit(coalesce=True).replace(": refit ", ": followed the new cloud: ", 1)

    def accept(self) -> str:
        """Register the shown candidate of the selected object and close the object."""
        with self._lock:
            obj = self._require_active()
            reg = Registration.of(obj, self._frame_id)
            objects = tuple(o for o in self._state.objects if o.id != obj.id)
            self._commit(
                replace(
                    self._state,
                    objects=objects,
                    registered=self._state.registered + (reg,),
                    active_id=objects[-1].id if objects else None,
                ),
                "accept",
            )
            why = (
                ""
                if not reg.override
                else f" as an operator override ({NO_MATCH})"
                if obj.no_match and not obj.shown_is_the_answer
                else " as an operator override (it does not fit)"
            )
            return (
                f"accepted {reg.template} as object {obj.id}{why} "
                f"({len(self._state.registered)} registered)"
            )

    def discard(self) -> str:
        """Drop the selected object of interest."""
        with self._lock:
            obj = self._require_active()
            objects = tuple(o for o in self._state.objects if o.id != obj.id)
            self._commit(
                replace(
                    self._state, objects=objects, active_id=objects[-1].id if objects else None
                ),
                "discard",
            )
            return f"discarded object {obj.id} ({obj.shown.template})"

    def undo(self) -> str:
        """Revert the last click, selection, cycle, correction, refit, accept, discard or load."""
        with self._lock:
            if not self._undo:
                raise EngineStateError("nothing to undo")
            previous, action = self._undo.pop()
            self._state = previous
            self._last_action = "undo"
            return f"undid {action}"

    # ------------------------------------------------------------------ persistence
    def save(self, path: str) -> str:
        with self._lock:
            regs, frame = self._state.registered, self._frame_id
        written = save_registrations(path, regs, frame, self.library)
        return f"saved {len(regs)} registration(s) to {written}"

    def resume(self, registrations) -> None:
        """Start from ``registrations`` (a session resumed from its file): they become the
        registered objects, not an undo step -- undo cannot drop what was saved before."""
        regs = tuple(registrations)
        with self._lock:
            next_id = max([self._state.next_id] + [r.id + 1 for r in regs])
            self._state = replace(self._state, registered=regs, next_id=next_id)

    def load(self, path: str) -> str:
        regs = load_registrations(path, self.library)
        with self._lock:
            next_id = max([self._state.next_id] + [r.id + 1 for r in regs])
            self._commit(replace(self._state, registered=regs, next_id=next_id), "load")
            return f"loaded {len(regs)} registration(s) from {path}"

    def trajectory(self, object_id: int, state: str, waypoint: str | None = None) -> Trajectory:
        """The path of ``waypoint`` (None: the first on a moving part) of object ``object_id``
        -- a registration, or an open object's shown candidate -- from its joint value to the
        named ``state``, in the cloud frame (:func:`~.waypoints.trajectory`). One-line
        :class:`AffordanceError` for an unknown object, state or waypoint."""
        with self._lock:
            fit = self._state.fit_of(object_id)
        if fit is None or fit.template not in self.library:
            raise EngineStateError(f"no object {bounded(object_id)} (registered or open)")
        return trajectory(self.geometry(fit), fit, state, waypoint)

    # ------------------------------------------------------------------ status
    def status(self) -> dict:
        """A JSON-ready summary: objects of interest with ranked candidates, registrations;
        each with the ``waypoints`` of its shown candidate or registration (cloud frame). A
        registration is immutable: its entry is made once (``self._entries``) and copied."""
        with self._lock:
            st, lib = self._state, self.library
            return {
                "frame_id": self._frame_id,
                "active_id": st.active_id,
                "objects": [
                    dict(o.to_dict(st.active_id), waypoints=waypoints_dict(lib, o.shown))
                    for o in st.objects
                ],
                "registered": [dict(e) for e in self._entries.values(st.registered, lib)],
                "counts": {
                    "objects": len(st.objects),
                    "registered": len(st.registered),
                    "undo": len(self._undo),
                },
                "timing_s": {k: round(v, 6) for k, v in self._last_timing.items()},
            }


def _answer_of(obj: TrackedObject, job: _ViewDue) -> bool:
    """Whether ``obj`` is the object of ``job`` with that click's answer."""
    return obj.id == job.object_id and obj.ambiguity is job.report.ambiguity


def _holds(state: EngineState, job: _ViewDue) -> bool:
    """Whether ``state`` holds the answer of the click ``job`` suggests a view for."""
    return any(_answer_of(o, job) for o in state.objects)
