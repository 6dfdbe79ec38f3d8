# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What the station shows, from the engine's documented outputs alone: the drawings of its
``~/markers`` (:func:`apply_markers`) and the text of its ``~/status`` (the selected object, its
shown candidate's label and verdict, the status panel). Plain functions and records, tested
without ``rclpy.init`` or a browser."""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np
from visualization_msgs.msg import Marker, MarkerArray

from ...core.labels import REFUSED_PREFIX, standing
from ..glue.conversions import ConversionError, pose_to_matrix
from ..glue.mesh_refs import referenced_mesh
from .markup import text

__all__ = [
    "MeshDrawing",
    "TextDrawing",
    "SphereDrawing",
    "LineDrawing",
    "apply_markers",
    "active_object",
    "candidate_standing",
    "candidate_label",
    "short_label",
    "headline",
    "drag_moved",
    "HEADLINE_MAX",
    "candidate_options",
    "fitting_marker",
    "shown_markdown",
    "status_markdown",
    "suggested_pose",
]


# ============================================================================ messages -> drawings
@dataclass(frozen=True)
class MeshDrawing:
    """A mesh marker (TRIANGLE_LIST, MESH_RESOURCE, CUBE, CYLINDER): ``vertices`` (3F, 3)
    float32 in the marker's frame, ``faces`` (F, 3) uint32, ``T`` (4, 4) its pose in the
    header frame, RGB ``color`` 0-255, ``opacity``."""

    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    T: np.ndarray = field(repr=False)
    color: tuple
    opacity: float
    frame: str

    @property
    def digest(self) -> str:
        """Identity of the geometry and colour (not the pose)."""
        h = hashlib.blake2b(self.vertices.tobytes(), digest_size=12)
        h.update(repr((self.color, round(self.opacity, 3))).encode())
        return h.hexdigest()


@dataclass(frozen=True)
class TextDrawing:
    text: str
    position: np.ndarray = field(repr=False)  # (3,) in the header frame
    frame: str


@dataclass(frozen=True)
class SphereDrawing:
    position: np.ndarray = field(repr=False)
    radius: float
    color: tuple
    frame: str


@dataclass(frozen=True)
class LineDrawing:
    """A LINE_LIST marker (the engine's waypoint grippers, a suggested view's frustum):
    ``segments`` (S, 2, 3) float32 in the header frame (the marker's pose applied), ``colors``
    (S, 2, 3) uint8 (the marker's per-point colours, or its one colour)."""

    segments: np.ndarray = field(repr=False)
    colors: np.ndarray = field(repr=False)
    frame: str


def _rgb(c) -> tuple:
    return tuple(int(round(255 * min(1.0, max(0.0, v)))) for v in (c.r, c.g, c.b))


def _drawing(m: Marker):
    frame = m.header.frame_id
    if m.type == Marker.TRIANGLE_LIST:
        n = len(m.points) // 3 * 3
        if n == 0:
            return None
        verts = np.array([(p.x, p.y, p.z) for p in m.points[:n]], dtype=np.float32)
        verts *= np.array([m.scale.x or 1.0, m.scale.y or 1.0, m.scale.z or 1.0], dtype=np.float32)
        faces = np.arange(n, dtype=np.uint32).reshape(-1, 3)
        return MeshDrawing(
            verts, faces, pose_to_matrix(m.pose), _rgb(m.color), float(m.color.a), frame
        )
    if m.type in (Marker.MESH_RESOURCE, Marker.CUBE, Marker.CYLINDER):
        verts = referenced_mesh(m)  # the file read once, a shape made once
        faces = np.arange(len(verts), dtype=np.uint32).reshape(-1, 3)
        return MeshDrawing(
            verts, faces, pose_to_matrix(m.pose), _rgb(m.color), float(m.color.a), frame
        )
    if m.type == Marker.TEXT_VIEW_FACING:
        p = m.pose.position
        return TextDrawing(m.text, np.array([p.x, p.y, p.z]), frame)
    if m.type == Marker.SPHERE:
        p = m.pose.position
        return SphereDrawing(
            np.array([p.x, p.y, p.z]), 0.5 * float(m.scale.x), _rgb(m.color), frame
        )
    if m.type == Marker.LINE_LIST:
        n = len(m.points) // 2 * 2
        if n == 0:
            return None
        T = pose_to_matrix(m.pose)
        pts = np.array([(p.x, p.y, p.z) for p in m.points[:n]], dtype=float) @ T[:3, :3].T
        colors = [_rgb(c) for c in m.colors[:n]] if len(m.colors) >= n else [_rgb(m.color)] * n
        return LineDrawing(
            (pts + T[:3, 3]).astype(np.float32).reshape(-1, 2, 3),
            np.array(colors, dtype=np.uint8).reshape(-1, 2, 3),
            frame,
        )
    return None


def apply_markers(current: dict, msg: MarkerArray) -> dict:
    """The drawings after a MarkerArray: ``current`` maps (namespace, id) to a drawing;
    DELETEALL clears, DELETE removes, ADD/MODIFY sets (TRIANGLE_LIST, MESH_RESOURCE -- the
    file:// or package:// mesh loaded once --, CUBE, CYLINDER, TEXT_VIEW_FACING, SPHERE and
    LINE_LIST;
    other types, and markers that cannot be converted, are left out). Returns a new dict."""
    out = dict(current)
    for m in msg.markers:
        key = (m.ns, int(m.id))
        if m.action == Marker.DELETEALL:
            out.clear()
        elif m.action == Marker.DELETE:
            out.pop(key, None)
        elif m.action == Marker.ADD:  # ADD == MODIFY
            try:
                drawing = _drawing(m)
            except ConversionError:
                drawing = None
            if drawing is None:
                out.pop(key, None)
            else:
                out[key] = drawing
    return out


# ============================================================================ status -> text
def active_object(status: dict | None) -> dict | None:
    """The selected object of an engine status (its ``objects`` entry), or None."""
    for obj in (status or {}).get("objects") or []:
        if obj.get("active"):
            return obj
    return None


def candidate_standing(obj: dict | None) -> tuple[str, bool]:
    """(verdict text, refused) of an object's shown candidate, from what the engine's status
    has per object (``no_match``) and per candidate (``fits``, ``probability``):
    ``core.labels.standing``. ('', False) without an object."""
    if not obj or not obj.get("candidates"):
        return "", False
    cands = obj["candidates"]
    shown = int(obj.get("shown", 0))
    primitive = 0 <= shown < len(cands) and cands[shown].get("primitive") is not None
    return standing(
        bool(obj.get("no_match")),
        shown,
        [float(c.get("probability") or 0.0) for c in cands],
        [c.get("fits") for c in cands],
        primitive,
        str(obj.get("verdict") or ""),
    )


def candidate_label(obj: dict | None) -> str:
    """'#3 ball_valve (closed) — rank 1/5 — fits, 3.5x the next' for the shown candidate of an
    object; '#3 no template fits here — best guess gate_valve — rank 1/5' when the verdict
    refuses it; '' without an object."""
    if not obj or not obj.get("candidates"):
        return ""
    shown = int(obj.get("shown", 0))
    c = obj["candidates"][shown]
    state = f" ({c['state']})" if c.get("state") else ""
    text, _ = candidate_standing(obj)
    rank = f"rank {shown + 1}/{len(obj['candidates'])}"
    if text == REFUSED_PREFIX:
        return f"#{obj.get('id', '?')} {text} {c.get('template', '?')}{state} — {rank}"
    return f"#{obj.get('id', '?')} {c.get('template', '?')}{state} — {rank} — {text}"


#: the longest headline (characters): one sentence an operator reads at a glance
HEADLINE_MAX = 159
#: the longest template name a headline or a 3D label carries (a user's library may name them
#: at length; the dropdown and the details have the whole name)
NAME_MAX = 32


def _cut(text: str, limit: int) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "…"


def _shown(obj: dict) -> tuple[dict, int, int]:
    cands = obj.get("candidates") or [{}]
    shown = min(max(int(obj.get("shown", 0) or 0), 0), len(cands) - 1)
    return cands[shown], shown, len(cands)


def _name(c: dict) -> str:
    state = f" ({_cut(c['state'], 16)})" if c.get("state") else ""
    return _cut(c.get("template", "?"), NAME_MAX) + state


def short_label(obj: dict | None) -> str:
    """The 3D label of the open object: '#3 ball_valve (closed) — fits', '#3 best guess
    gate_valve — no fit', '#3 box 0.21 x 0.12 x 0.08 m' ('' without an object): the headline
    says the rest."""
    if not obj or not obj.get("candidates"):
        return ""
    c, shown, _ = _shown(obj)
    text, refused = candidate_standing(obj)
    oid = obj.get("id", "?")
    if c.get("primitive") is not None and not refused:
        what = text.split("fitted as ")[-1].removeprefix("a ")
        return f"#{oid} {_cut(what, 48)}"
    if refused:
        guess = "best guess " if shown == 0 and obj.get("no_match") else ""
        return f"#{oid} {guess}{_name(c)} — no fit"
    word = text.split(",")[0]
    if ((obj.get("ambiguity") or {}).get("settled")) is False:
        word += ", unsettled"
    return f"#{oid} {_name(c)} — {word}"


def headline(
    status: dict | None,
    connected: bool,
    engine: str,
    fitting: bool = False,
    alert: str = "",
) -> str:
    """The panel's one sentence (at most HEADLINE_MAX characters): what is shown, its verdict
    and what the operator can do -- the reasons are in the details (:func:`status_markdown`).
    ``fitting``: a click is being fitted; ``alert``: what went wrong with the operator's last
    action (shown instead, until the next one)."""
    obj = active_object(status)
    if not connected:
        text = (
            f"Engine not running: start affordance_engine ({_cut(engine, 40)}); "
            "this page recovers when it comes up."
        )
    elif alert.strip():
        alert = " ".join(alert.split())
        text = alert[0].upper() + alert[1:]
    elif fitting:
        text = "Fitting your click…"
    elif status is None:
        text = "The engine is up; waiting for its status."
    elif obj is None or not obj.get("candidates"):
        counts = status.get("counts") or {}
        n = counts.get("registered", len(status.get("registered") or []))
        text = "No object open: click one in the cloud to fit it" + (
            f"; {n} registered, Save writes them." if n else "."
        )
    else:
        c, shown, total = _shown(obj)
        said, refused = candidate_standing(obj)
        oid = obj.get("id", "?")
        rank = f" (rank {shown + 1}/{total})" if shown else ""
        unsettled = ((obj.get("ambiguity") or {}).get("settled")) is False
        if c.get("primitive") is not None and not refused:
            what = _cut(said.split("fitted as ")[-1], 60)
            text = (
                f"#{oid}{rank}: {what} (no template fits here)"
                + (", unsettled (Details says why)" if unsettled else "")
                + ". Correct its size below if it is off, then Accept, or Next."
            )
        elif refused and shown == 0 and obj.get("no_match"):
            text = (
                f"#{oid}: no template fits here (best guess {_name(c)}). Next, click elsewhere, "
                "or Accept as an override."
            )
        elif refused:
            text = f"#{oid} {_name(c)}{rank}: {said}. Previous, Next, or Accept as an override."
        elif unsettled:
            text = (
                f"#{oid} {_name(c)}{rank}: {said}, but unsettled (Details says why). Accept, "
                "Next, or drag the gizmo to correct it."
            )
        else:
            text = (
                f"#{oid} {_name(c)}{rank}: {said}. Accept, Next, or drag the gizmo to correct it."
            )
    return _cut(text, HEADLINE_MAX)


def drag_moved(
    T_start: np.ndarray, T: np.ndarray, tol_m: float = 0.001, tol_deg: float = 0.5
) -> bool:
    """Whether the gizmo moved the fit from ``T_start`` to ``T`` (4x4) by more than ``tol_m``
    or ``tol_deg``: a press on a handle that does not move it is no correction."""
    A, B = np.asarray(T_start, dtype=float), np.asarray(T, dtype=float)
    if np.linalg.norm(B[:3, 3] - A[:3, 3]) > tol_m:
        return True
    cos = (np.trace(A[:3, :3].T @ B[:3, :3]) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, cos)))) > tol_deg


def candidate_options(obj: dict | None) -> list[tuple[str, str]]:
    """(option text, template) of every ranked candidate of an object, best first."""
    out = []
    for i, c in enumerate((obj or {}).get("candidates") or []):
        verdict = {True: "fits", False: "does not fit"}.get(c.get("fits"), "not judged")
        out.append((f"{i + 1}. {c['template']} ({verdict})", c["template"]))
    return out


def fitting_marker(
    point: np.ndarray | None, sent_at: float, now: float, delay: float
) -> np.ndarray | None:
    """Where the "fitting…" marker is drawn: the point of the click being fitted (None: no
    click is) once it has waited ``delay`` s since it was sent at ``sent_at``, else None (the
    same object as ``point``: the station redraws only when it changes)."""
    return point if point is not None and now - sent_at >= delay else None


def suggested_pose(obj: dict | None) -> np.ndarray | None:
    """The sensor pose (4x4, an optical frame in the cloud's frame) the engine's status suggests
    for an unsettled object -- what "Move sensor here" sends --, or None: settled, no view found,
    or no usable pose."""
    amb = (obj or {}).get("ambiguity") or {}
    view = (obj or {}).get("suggested_view") or {}
    if (
        not isinstance(amb, dict)
        or amb.get("settled") is not False
        or not isinstance(view, dict)
        or not view.get("pose")
    ):
        return None
    try:
        T = np.asarray(view["pose"], dtype=float)
    except (TypeError, ValueError):
        return None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return None
    return T


def shown_markdown(obj: dict | None) -> str:
    """The panel's "Shown" line: the shown candidate's label (as text) or "nothing selected"."""
    label = candidate_label(obj)
    return f"**Shown**: {text(label)}" if label else "**Shown**: nothing selected"


def status_markdown(
    status: dict | None,
    connected: bool,
    engine: str,
    cloud: str,
    last_action: str,
    fitting: str = "",
    stale_error: bool = False,
) -> str:
    """The status panel: engine connection, a click being fitted (``fitting``), open object and
    its verdict, why it is unsettled and the suggested view, counts, fit time, what the engine
    is doing, its last message and error (left out when ``stale_error``: a later message came
    after it), the cloud, the reply to the last button. Every value in it is from outside the
    station (the status is anyone's JSON, the notes quote frames and replies): each is shown as
    text (:func:`.markup.text`), only the field names are markup."""
    lines = []
    if not connected:
        lines.append(
            f"**Engine not running**: nothing publishes {text(engine + '/status')} (start "
            f"`affordance_engine`; the page recovers when it comes up)"
        )
    elif status is None:
        lines.append(f"**Engine**: {text(engine)} is up, waiting for its status")
    else:
        node = status.get("node") or {}
        doing = node.get("busy") or ("refit pending" if node.get("pending_refit") else "idle")
        lines.append(
            f"**Engine**: {text(engine)} — {text(doing)}"
            + (f", {text(node['queued'])} queued" if node.get("queued") else "")
        )
    if fitting:
        lines.append(f"**Fitting**: {text(fitting)}")
    st = status or {}
    obj = active_object(st)
    lines.append(f"**Shown**: {text(candidate_label(obj)) if obj else 'nothing selected'}")
    if obj and candidate_standing(obj)[1]:
        lines.append(
            "**Verdict**: the shown candidate is refused (drawn as a grey outline); "
            "Accept registers it anyway, marked as an operator override"
        )
    amb = (obj or {}).get("ambiguity") or {}
    if amb.get("settled") is False:  # why it is not settled, and the view that would
        view = (obj.get("suggested_view") or {}).get("text")
        lines.append(
            f"**Unsettled**: {text('; '.join(str(r) for r in amb.get('reasons') or []))}"
            + (f" — **suggested view**: {text(view)}" if view else "")
        )
    counts = st.get("counts") or {}
    lines.append(
        f"**Objects**: {text(counts.get('objects', 0))} open, "
        f"{text(counts.get('registered', len(st.get('registered') or [])))} registered, "
        f"{text(counts.get('undo', 0))} undo steps"
    )
    fit_s = (st.get("timing_s") or {}).get("total")
    if fit_s is not None:
        lines.append(f"**Fit time**: {float(fit_s):.2f} s")
    node = st.get("node") or {}
    if node.get("last_message"):
        lines.append(f"**Last message**: {text(node['last_message'])}")
    if node.get("last_error") and not stale_error:
        lines.append(f"**Last error**: {text(node['last_error'])}")
    lines.append(f"**Cloud**: {text(cloud)}")
    if last_action:
        lines.append(f"**Last action**: {text(last_action)}")
    return "\n\n".join(lines)
