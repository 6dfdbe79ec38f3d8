# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Viewpoint advice, evaluated in simulation (the bench's ``viewpoint`` row; alone:
``affordance-registration bench --row viewpoint``).

Each object of a simulated taskboard is scanned from a hard first view -- grazing (60-75 deg off
the panel normal), partly occluded (looking past a neighbouring object, 45-65 deg), far (1.5-2
m) or edge-on (76-85 deg: a handwheel seen on its rim), in turn -- and clicked. Where the first
fit is wrong or unsettled (:class:`~affordance_registration.core.registration.ambiguity.
Ambiguity`), the scene is scanned again from (a) the suggested view, (b) a random view within
the same bounds at the same distance, (c) the first view (new sensor noise); the operator clicks
the object again (its visible point nearest the first click) and each scan is fitted: top-1 and
pose-ok for each, on the same clicks. A wrong fit the ambiguity calls settled is asked for a
view all the same (counted apart: the product would not have offered one). Seeds tuned on
(``TUNING_SEEDS``) are reported apart from the others.

:func:`scan` renders any meshes from any sensor pose (the simulator's depth camera), in the
scene frame, with the sensor's origin -- what a re-scan from a suggested view needs.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..core.registration import FitSettings, Registrar
from ..core.scene import Scene
from ..core.templates import TemplateLibrary
from ..core.transforms import invert, pose_error
from .simulation import (
    POSE_TOL_M,
    POSE_TOL_RAD,
    DepthCamera,
    FaultModel,
    panel_mesh,
    simulate_taskboard,
)

__all__ = [
    "scan",
    "taskboard_meshes",
    "hard_view",
    "random_view",
    "viewpoint_row",
    "TUNING_SEEDS",
    "REPORT_SEEDS",
    "KINDS",
]

TUNING_SEEDS = range(5000, 5008)  #: the seeds the viewpoint knobs were chosen on
REPORT_SEEDS = range(6000, 6016)  #: the seeds reported (never tuned on)
KINDS = ("grazing", "occluded", "far", "edge-on")
MIN_VISIBLE = 40  #: an object the first view sees less of is not clicked


def scan(meshes, T_scene_cam: np.ndarray, rng, camera: DepthCamera | None = None):
    """A depth-camera scan of ``meshes`` ((trimesh, T_scene_mesh) in the scene frame) from the
    optical frame ``T_scene_cam``: (points (N, 3) scene frame, their labels (N,) -- the index of
    the mesh hit --, the sensor origin (3,)). ``rng`` None: without noise."""
    camera = camera or DepthCamera()
    T_cam_scene = invert(T_scene_cam)
    organized, labels = camera.render([(m, T_cam_scene @ T) for m, T in meshes], rng)
    flat, lab = organized.reshape(-1, 3).astype(float), labels.reshape(-1)
    keep = np.all(np.isfinite(flat), axis=1)
    pts = flat[keep] @ T_scene_cam[:3, :3].T + T_scene_cam[:3, 3]
    return pts, lab[keep], T_scene_cam[:3, 3].copy()


def taskboard_meshes(sim, library: TemplateLibrary) -> list:
    """The meshes of a simulated taskboard in its scene frame: the panel first, then each object
    (its joint values and scale) -- label k + 1 is object k."""
    out = [(panel_mesh(), sim.T_scene_board)]
    for o in sim.objects:
        tpl = library[o.template]
        out.append((tpl.mesh_at(tpl.joint_value(o.joints or {}), o.scale), o.T_scene_model))
    return out


def _look_at(position: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    z = target - position
    z /= np.linalg.norm(z)
    y = -(up - z * (up @ z))
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1)
    T[:3, 3] = position
    return T


def hard_view(sim, k: int, kind: str, rng) -> np.ndarray:
    """A hard first view (optical frame, scene frame) of object ``k`` of ``sim``: ``grazing``
    60-75 deg off the panel normal at 0.8-1.3 m; ``occluded`` 45-65 deg looking past the
    nearest neighbouring object; ``far`` 10-45 deg at 1.5-2 m; ``edge-on`` 76-85 deg at
    0.8-1.3 m."""
    B = sim.T_scene_board
    to_board = invert(B)
    at = [to_board[:3, :3] @ o.T_scene_model[:3, 3] + to_board[:3, 3] for o in sim.objects]
    target = at[k] + np.array([0.0, 0.0, 0.02])
    phi = rng.uniform(0, 2 * math.pi)
    if kind == "grazing":
        alpha, dist = rng.uniform(60, 75), rng.uniform(0.8, 1.3)
    elif kind == "occluded":
        alpha, dist = rng.uniform(45, 65), rng.uniform(0.8, 1.3)
        others = [a for j, a in enumerate(at) if j != k]
        if others:
            near = min(others, key=lambda a: np.linalg.norm(a[:2] - at[k][:2]))
            phi = math.atan2(near[1] - at[k][1], near[0] - at[k][0]) + rng.uniform(-0.15, 0.15)
    elif kind == "far":
        alpha, dist = rng.uniform(10, 45), rng.uniform(1.5, 2.0)
    else:  # edge-on: a handwheel, a plate seen on its rim
        alpha, dist = rng.uniform(76, 85), rng.uniform(0.8, 1.3)
    a = math.radians(alpha)
    pos = target + dist * np.array(
        [math.sin(a) * math.cos(phi), math.sin(a) * math.sin(phi), math.cos(a)]
    )
    T_board_cam = _look_at(pos, target, np.array([0.0, 1.0, 0.0]))
    return B @ T_board_cam


def random_view(origin, target, normal, distance: float, settings: FitSettings, rng):
    """A random sensor pose within the ``viewpoint`` bounds about ``target`` (uniform over the
    reachable directions), ``distance`` from it, looking at it."""
    s = settings.viewpoint
    d0 = (origin - target) / np.linalg.norm(origin - target)
    n = normal if normal @ d0 >= 0 else -normal
    for _ in range(10000):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if d @ d0 >= math.cos(s.max_angle) and d @ n >= math.sin(s.min_elevation):
            break
    return _look_at(target + distance * d, target, -n)


def _fit(registrar, pts, labels, origin, k: int, near, library, truth):
    """Fit the click on object ``k`` (its visible point nearest ``near``) of a scan; (report,
    click, top-1, pose ok, the scene) or None when the scan does not see the object."""
    mine = pts[labels == k + 1]
    if len(mine) < 10:
        return None
    click = mine[int(np.argmin(np.linalg.norm(mine - near, axis=1)))]
    scene = Scene(pts, sensor_origin=origin)
    report = registrar.fit(scene, click)
    best = report.candidates[0]
    top1 = best.template == truth.template
    dt, da = pose_error(best.T_scene_model, truth.T_scene_model, library[truth.template].symmetry)
    return report, click, top1, top1 and dt <= POSE_TOL_M and da <= POSE_TOL_RAD, scene


def _jobs(library, seeds):
    for seed in seeds:
        sim = simulate_taskboard(library, seed)
        meshes = taskboard_meshes(sim, library)
        for k in range(len(sim.objects)):
            yield seed, sim, meshes, k, KINDS[(seed + k) % len(KINDS)]


def evaluate(registrar: Registrar, library, seeds, faults: bool = False, log=None) -> dict:
    """The viewpoint evaluation on the taskboards of ``seeds`` (see the module's description)."""
    camera = DepthCamera(faults=FaultModel()) if faults else DepthCamera()
    clicks, cases, suggest_s = 0, [], []
    for seed, sim, meshes, k, kind in _jobs(library, seeds):
        rng = np.random.default_rng(seed * 100 + k)
        truth = sim.objects[k]
        T_first = hard_view(sim, k, kind, rng)
        pts, labels, origin = scan(meshes, T_first, rng, camera)
        if (labels == k + 1).sum() < MIN_VISIBLE:
            continue
        mine = pts[labels == k + 1]
        near = np.median(mine, axis=0)
        first = _fit(registrar, pts, labels, origin, k, near, library, truth)
        clicks += 1
        report, click, top1, ok, scene = first
        amb = report.ambiguity
        if ok and amb.settled:
            continue
        t0 = time.perf_counter()
        view = registrar.suggest_view(
            report if not amb.settled else _unsettled(report), T_scene_optical=T_first, scene=scene
        )
        suggest_s.append(time.perf_counter() - t0)
        case = {
            "seed": seed,
            "object": k,
            "template": truth.template,
            "kind": kind,
            "first": {"top1": top1, "ok": ok},
            "settled": amb.settled,
            "kinds": list(amb.kinds),
        }
        if view is None:
            case["suggested"] = case["random"] = case["again"] = {"top1": False, "ok": False}
            cases.append(case)
            continue
        ctx = report.context
        normal = ctx.support.normal if ctx.support is not None else -T_first[:3, 2]
        T_random = random_view(origin, view.target, normal, view.distance, registrar.settings, rng)
        for name, T in (
            ("suggested", view.T_scene_optical),
            ("random", T_random),
            ("again", T_first),
        ):
            p2, l2, o2 = scan(meshes, T, rng, camera)
            got = _fit(registrar, p2, l2, o2, k, click, library, truth)
            case[name] = (
                {"top1": False, "ok": False, "settled": False}
                if got is None
                else {"top1": got[2], "ok": got[3], "settled": got[0].ambiguity.settled}
            )
        if log:
            log(
                f"seed {seed} object {k} ({truth.template}, {kind}): first "
                f"{'ok' if ok else 'wrong'}{'' if amb.settled else ' unsettled'}; suggested "
                f"{case['suggested']['ok']}, random {case['random']['ok']}, again "
                f"{case['again']['ok']}"
            )
        cases.append(case)

    def rates(sel):
        n = len(sel)
        return {
            name: {
                "top1": sum(bool(c[name]["top1"]) for c in sel) / n if n else None,
                "pose_ok": sum(bool(c[name]["ok"]) for c in sel) / n if n else None,
            }
            for name in ("first", "suggested", "random", "again")
        }

    unsettled = [c for c in cases if not c["settled"]]
    return {
        "clicks": clicks,
        "hard": len(cases),
        "unsettled": len(unsettled),
        "wrong_but_settled": len(cases) - len(unsettled),
        **rates(cases),
        "by_kind": {kind: sum(c["kind"] == kind for c in cases) for kind in KINDS},
        "on_unsettled": rates(unsettled),
        "suggest_median_s": float(np.median(suggest_s)) if suggest_s else None,
        "suggest_max_s": float(np.max(suggest_s)) if suggest_s else None,
        "cases": cases,
    }


def _unsettled(report):
    """A wrong but settled report, asked for a view all the same (its best hypotheses)."""
    from dataclasses import replace

    return replace(report, ambiguity=replace(report.ambiguity, settled=False))


def viewpoint_row(library=None, log=None, tuning=TUNING_SEEDS, reported=REPORT_SEEDS) -> dict:
    """The bench's viewpoint row: :func:`evaluate` on the seeds tuned on and, apart, on the
    reported ones, with the default settings."""
    library = library or TemplateLibrary.load().specific()
    registrar = Registrar(library)
    registrar.warm_up()
    return {
        "tuning": evaluate(registrar, library, tuning, log=log),
        "reported": evaluate(registrar, library, reported, log=log),
    }


def format_row(row: dict) -> list:
    """The table's lines of :func:`viewpoint_row`."""
    lines = []
    for part in ("tuning", "reported"):
        r = row.get(part)
        if not r or not r["hard"]:
            continue

        def pct(r, name):
            return f"top-1 {r[name]['top1']:.0%} / pose ok {r[name]['pose_ok']:.0%}"

        lines.append(
            f"viewpoint advice ({part} seeds, {r['hard']} of {r['clicks']} hard first "
            f"views wrong or unsettled): first view {pct(r, 'first')}; re-scanned from "
            f"the suggested view {pct(r, 'suggested')}, a random view "
            f"{pct(r, 'random')}, the first view again {pct(r, 'again')}; suggestion "
            f"median {r['suggest_median_s']:.3f} s, max {r['suggest_max_s']:.3f} s; "
            + ", ".join(f"{k} {n}" for k, n in r["by_kind"].items())
        )
        u = r["on_unsettled"]
        if r["unsettled"]:
            lines.append(
                f"  on the {r['unsettled']} unsettled: first {pct(u, 'first')}; "
                f"suggested {pct(u, 'suggested')}, random {pct(u, 'random')}, again "
                f"{pct(u, 'again')}"
            )
    return lines
