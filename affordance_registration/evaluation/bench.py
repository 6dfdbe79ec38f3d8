# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The performance table: speed and accuracy of the default method against baselines, measured in
one run on simulated taskboards with ground truth (``affordance-registration bench``); the rows
are :mod:`~affordance_registration.evaluation.bench_rows`' and
:mod:`~affordance_registration.evaluation.rows`', this module runs them, writes the JSON and
formats the table.

Rows: the default method (joint values and scale estimated); the same without them (rigid
only); the paper's method (literal); Open3D's point-to-point ``registration_icp`` from the same
initial hypotheses on the same crop; small_gicp's GICP likewise when it is installed (``pip
install small_gicp``). Success: the right template ranked first and its pose within 5 mm and 5
degrees of the truth, symmetry-aware. Times are per click, all five templates. Speed ratios
compare medians measured in this run. The articulated line: taskboards with valve handles at
random angles, e-stops pressed or released and (in a variant library) grab handles in sizes
0.8-1.25, seeds 3000+.

Frames and viewpoints, since nothing in the fit may assume an axis: the panel clicks
re-expressed in four non-optical frames (compared with the optical frame on the same clicks),
the panel clicks without a viewpoint (``sensor_origin none``), the panel scenes rendered with
the depth-camera fault model (:class:`FaultModel`), and the real Armadillo range scans of
``or-pcd`` (fetched with pip into a cache; left out with a line saying why when that fails).

Viewpoint advice: hard first views (grazing, occluded, far, edge-on) wrong or unsettled, re-scanned
from the suggested view, a random one and the first one again (:mod:`.viewpoints`).

Speed lines, measured click by click in turn (each click fitted by every variant before the
next, so load changes hit them alike): the default method on 1 and 2 threads and with the
compiled kernels (:mod:`..core.compiled`) off and on, and libraries of 5/10/20/40 templates
(the five and scaled / stretched variants of them) and of 5/40 of a family
made differently (random-direction stretches, kept out of the prefilter's tuning, on held-out
taskboards: seeds 7000 on), with how often the library prefilter decided. Click -> result from a
1024 x 1024 organized cloud (``Scene()`` plus the fit), and ``Scene()`` after the PointCloud2
conversion. Over ROS, the live engine node in its own process against the same fits in this one
(:mod:`.ros_latency`): click -> status over the in-process fit, status -> markers, markers
message size, idle engine CPU; and the browser station's click -> label in headless Chromium
(:mod:`.browser_latency`; left out, with its reason, where Playwright or the browser is
missing), and the operator's effort in the browser: a scripted operator registering every object
of simulated taskboards and shared real scans through the page (:mod:`.browser_operator`).

``bench --out DIR`` writes the results (``benchmark.json``), the settings they were measured with
(``benchmark.settings.yaml``) and their rendering for people (``BENCHMARK.md``: the table and
what each row measures); ``docs/`` holds the committed ones, which a test keeps equal.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import subprocess
import textwrap
import time

import numpy as np

from ..core.files import write_atomically
from ..core.registration import FitSettings, Registrar
from ..core.templates import TemplateLibrary
from .bench_rows import (
    LIBRARY_SIZES,
    MIN_VISIBLE,
    VARIANT_SCALES,
    any_frame_rows,
    articulated_rows,
    baseline_fit,
    browser_latency_bench,
    browser_operator_bench,
    evaluate_row,
    kernel_rows,
    large_cloud_row,
    library_size_rows,
    real_capture_rows,
    real_scan_rows,
    refit_times,
    ros_conversion_bench,
    ros_latency_bench,
    ros_push_refit_bench,
    simulated_jobs,
    stretched_library,
    thread_rows,
    variant_library,
)
from .browser_operator import format_row as operator_lines
from .composite import format_lines
from .realdata import DATA_ENV
from .simulation import POSE_TOL_M, POSE_TOL_RAD, sized_library
from .viewpoints import REPORT_SEEDS, TUNING_SEEDS, format_row, viewpoint_row

__all__ = [
    "run_bench",
    "format_table",
    "render_markdown",
    "write_results",
    "RESULTS_NAME",
    "SETTINGS_NAME",
    "DOC_NAME",
    "variant_library",
    "MIN_VISIBLE",
    "VARIANT_SCALES",
    "LIBRARY_SIZES",
]


#: what ``bench --out DIR`` writes into DIR: the results, their settings, their rendering
RESULTS_NAME = "benchmark.json"
SETTINGS_NAME = "benchmark.settings.yaml"
DOC_NAME = "BENCHMARK.md"


def run_bench(
    quick: bool = False,
    scenes: int | None = None,
    paper_clicks: int | None = None,
    out: str | None = "bench_output",
    log=print,
    all_composites: bool = False,
) -> dict:
    """Run the benchmark; returns the results and, with ``out`` (a folder), writes them there
    (:func:`write_results`). ``all_composites``: the trust rows on every composite seed
    (:mod:`.composite`), not a sample."""
    started = time.monotonic()
    library = (
        TemplateLibrary.load().specific()
    )  # the taskboard templates (primitives: rows of their own)
    n_scenes = scenes if scenes is not None else (4 if quick else 20)
    n_paper = paper_clicks if paper_clicks is not None else (5 if quick else 25)
    log(f"simulating {n_scenes} panel and {max(2, n_scenes // 2)} table scenes ...")
    jobs = simulated_jobs(library, range(1000, 1000 + n_scenes))
    table_jobs = simulated_jobs(library, range(2000, 2000 + max(2, n_scenes // 2)), layout="table")
    default = Registrar(library)
    paper = Registrar(library, FitSettings(method="paper"))
    default.fit(jobs[0][0], jobs[0][1].click)  # warm the template caches
    rows = []
    log("default method ...")
    rows.append(evaluate_row("default", lambda s, c: default.fit(s, c).candidates, jobs, library))
    log("default method without joint/scale estimation (articulated false) ...")
    rigid = Registrar(library, FitSettings(articulated=False))
    rows.append(
        evaluate_row("default, rigid only", lambda s, c: rigid.fit(s, c).candidates, jobs, library)
    )
    log("default method, objects lying on a table (no mounting prior) ...")
    row = evaluate_row(
        "default (table)", lambda s, c: default.fit(s, c).candidates, table_jobs, library
    )
    rows.append(row)
    step = max(1, len(jobs) // max(n_paper, 1)) if n_paper else 1
    paper_jobs = jobs[::step][:n_paper] if n_paper else jobs
    log(f"paper method on {len(paper_jobs)} clicks ...")
    rows.append(
        evaluate_row(
            "paper (literal)", lambda s, c: paper.fit(s, c).candidates, paper_jobs, library
        )
    )
    log("Open3D point-to-point ICP ...")
    rows.append(
        evaluate_row(
            "open3d icp p2p", lambda s, c: baseline_fit(default, s, c, "open3d"), jobs, library
        )
    )
    try:
        import small_gicp  # noqa: F401  (a bench-only extra)

        log("small_gicp GICP ...")
        rows.append(
            evaluate_row(
                "small_gicp gicp", lambda s, c: baseline_fit(default, s, c, "gicp"), jobs, library
            )
        )
    except ImportError:
        log("small_gicp is not installed: its row is skipped (pip install small_gicp)")
    rows += any_frame_rows(default, jobs, library, rows[0]["outcomes"], n_scenes, log)
    base = rows[0]["median_s"]
    for r in rows:
        r["ratio_to_default"] = r["median_s"] / base
        r.pop("outcomes", None)
    refit_med, refit_ok = refit_times(default, jobs, library, np.random.default_rng(5))
    log("articulated taskboards (joint values, states, scale) ...")
    articulated = articulated_rows(sized_library(library), range(3000, 3000 + max(2, n_scenes)))
    lib_jobs = _spread(jobs, 40)
    log(f"threads 1 and 2, each click by both in turn, on {len(lib_jobs)} clicks ...")
    threads_rows = thread_rows(library, lib_jobs)
    log(
        f"compiled kernels off and on, each click both ways in turn, on {len(lib_jobs)} clicks ..."
    )
    kernels = kernel_rows(library, lib_jobs)
    log(f"library sizes {', '.join(map(str, LIBRARY_SIZES))} on {len(lib_jobs)} clicks ...")
    library_rows = library_size_rows(library, lib_jobs)
    held_out = _spread(
        simulated_jobs(library, range(7000, 7000 + n_scenes)), 40
    )  # no knob chosen there
    n_held = len(held_out)
    log(f"libraries of 5 and 40 of a held-out variant family on {n_held} held-out clicks ...")
    held_out_library_rows = library_size_rows(library, held_out, (5, 40), stretched_library)
    log("click -> result on 1M-point organized clouds ...")
    large = large_cloud_row(library, range(1000, 1000 + (2 if quick else 4)), log)
    log("real range scans (the Armadillo, or-pcd) ...")
    real = real_scan_rows(library, log)
    captures = real_capture_rows(library, jobs, quick, log, all_composites)
    log("viewpoint advice on hard first views (tuning and reported seeds) ...")
    viewpoint = viewpoint_row(
        library, log, *((TUNING_SEEDS[:2], REPORT_SEEDS[:4]) if quick else ())
    )
    result = {
        "scenes": n_scenes,
        "clicks": len(jobs),
        "table_clicks": len(table_jobs),
        "real_scans": real,
        "pose_tolerance": {"m": POSE_TOL_M, "deg": math.degrees(POSE_TOL_RAD)},
        "rows": rows,
        "refit": {"median_s": refit_med, "success": refit_ok},
        "articulated": articulated,
        "library_sizes": library_rows,
        "library_sizes_held_out_family": held_out_library_rows,
        "large_cloud": large,
        "threads": threads_rows,
        "kernels": kernels,
        **captures,
        "viewpoint": {
            k: {kk: vv for kk, vv in v.items() if kk != "cases"} for k, v in viewpoint.items()
        },
        "machine": {"cpus": os.cpu_count()},
    }
    extra = ros_conversion_bench()
    if extra:
        result["conversions"] = extra
    pushed = ros_push_refit_bench(range(1000, 1000 + n_scenes), 5 if quick else 40, log)
    if pushed:
        result["push_refit_ros"] = pushed
    latency = ros_latency_bench(range(1000, 1000 + n_scenes), 5 if quick else 20, log)
    if latency:
        result["ros_latency"] = latency
    browser = browser_latency_bench(range(1000, 1000 + n_scenes), 3 if quick else 10, log)
    if browser:
        result["browser_latency"] = browser
    operator = browser_operator_bench(range(1000, 1001 if quick else 1002), 2 if quick else 6, log)
    if operator:
        result["browser_operator"] = operator
    result["run"] = {
        "commit": _commit(),
        "date": datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
        "minutes": round((time.monotonic() - started) / 60),
        "quick": quick,
    }
    if out:
        result["written"] = write_results(result, out, default.settings)
    return result


def _commit() -> str | None:
    """The package checkout's commit (short hash), None outside a git checkout."""
    try:
        done = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=os.path.dirname(os.path.abspath(__file__)),
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def write_results(result: dict, out: str, settings: FitSettings | None = None) -> list:
    """Write ``result`` into the folder ``out``: :data:`RESULTS_NAME` (the JSON),
    :data:`DOC_NAME` (:func:`render_markdown` of it) and, given the settings the run used,
    :data:`SETTINGS_NAME`; all or none of them (atomically). Returns the paths written."""
    results = os.path.join(out, RESULTS_NAME)
    files = {
        results: json.dumps(result, indent=2) + "\n",
        os.path.join(out, DOC_NAME): render_markdown(result),
    }
    if settings is not None:
        files[settings_path(results)] = settings_text(settings)
    return write_atomically(files)


#: the rows that change knobs of the default settings, and how
ROW_SETTINGS = {
    "paper (literal)": "method: paper",
    "default, rigid only": "articulated: false",
    "threads": "threads: 1 and 2",
    "library sizes": "the library, not the settings",
}


def settings_path(out: str) -> str:
    """Where the settings of the results file ``out`` go (``benchmark.json`` ->
    ``benchmark.settings.yaml``, readable by ``fit --settings``)."""
    return os.path.splitext(os.path.abspath(out))[0] + ".settings.yaml"


def settings_text(settings: FitSettings) -> str:
    """The settings the bench ran with, as a settings file naming the rows that differ."""
    rows = "".join(f"#   {row}: {change}\n" for row, change in ROW_SETTINGS.items())
    return (
        "# the fitting settings of the bench's default rows; the rows that differ:\n"
        + rows
        + settings.dump()
    )


def _pct(v) -> str:
    return "-" if v is None else f"{v:.0%}"


def _refined(r: dict) -> str:
    """The real Kinect line's note on the fits refined on the labels (label_ceiling)."""
    if r.get("refined_pass") is None:
        return ""
    return (
        f" (the same fits least-squares refined on each object's labelled points: "
        f"{_pct(r['refined_pass'])} of {r['refined_objects']})"
    )


def _real_capture_lines(result: dict) -> list:
    """The table's lines of :func:`real_capture_rows`."""
    lines = []
    accepted = [
        f"{r['method']} {_pct(r.get('right_fits_accepted'))}"
        for r in result["rows"]
        if r.get("right_fits_accepted") is not None
    ]
    if accepted:
        lines.append("right fits the verdict accepts: " + "; ".join(accepted))
    w = result.get("with_primitives")
    if w:
        lines.append(
            f"default library with the box and cylinder primitives, the panel clicks: "
            f"top-1 {w['top1']:.1%}, pose ok {w['pose_success']:.1%}, right fits "
            f"accepted {_pct(w['right_fits_accepted'])}, median {w['median_s']:.3f} s"
        )
    trust = result.get("trust") or {}
    if trust.get("left_out"):
        lines.append(f"trust (learn and composite scenes): not measured -- {trust['left_out']}")
    elif trust.get("summary"):
        lines += format_lines(trust["summary"])
    k = result.get("real_kinect")
    for part in ("tuning", "held_out"):
        r = (k or {}).get(part)
        if r and r["objects"]:
            lines.append(
                f"real Kinect (mOSD learn, {part.replace('_', '-')}, {r['objects']} objects in "
                f"{r['scenes']} scenes): refused by the library {_pct(r['refused_by_library'])}, "
                f"primitive recall {_pct(r['primitive_recall'])} / precision "
                f"{_pct(r['primitive_precision'])} (median), passing both 90% "
                f"{_pct(r['primitive_pass'])}{_refined(r)}, kind right "
                f"{_pct(r['kind_right'])}, median {r['median_s']:.2f} s a click"
                + (
                    f"; of the {r['right_objects']} whose primitive fits and passes, "
                    f"settled {_pct(r['right_settled'])}"
                    if r.get("right_objects")
                    else ""
                )
            )
    if k is not None and not any((k.get(p) or {}).get("objects") for p in ("tuning", "held_out")):
        lines.append(
            f"real Kinect (mOSD learn): not measured -- no shared mOSD scenes (set "
            f"{DATA_ENV} to the shared data folder)"
        )
    cost = (k or {}).get("cost")
    if cost:
        view = cost.get("view_median_s")
        how = (
            "the engine's click, CPU time"
            if cost.get("clock") == "cpu"
            else "one registrar's fits, wall time"
        )
        lines.append(
            f"real Kinect click against a simulated panel click, alternately "
            f"({cost['pairs']} pairs, {how}): {cost['ratio']:.2f}x "
            f"(median {cost['real_median_s']:.2f} s against {cost['simulated_median_s']:.2f} s)"
            + (
                f"; the suggested view, after the click, {view:.2f} s "
                f"({cost['views']} unsettled real clicks)"
                if view is not None
                else ""
            )
        )
    for name, r in (result.get("primitives_simulated") or {}).items():
        a = r["all"]
        lines.append(
            f"primitives on simulated {r.get('scenes', 'boxes and cylinders')} "
            f"({name}, {a['clicks']} "
            f"clicks): kind right {_pct(a['kind_right'])}, dimensions within 5 mm "
            f"{_pct(a['dims_within_5mm'])}, pose within 5 mm / 5 deg "
            f"{_pct(a['pose_ok'])}, wrong and accepted {_pct(a.get('wrong_accepted'))}, "
            f"median {a['median_s']:.2f} s"
        )
    c = result.get("clutter") or {}
    if c.get("armadillo"):
        a = c["armadillo"]
        lines.append(
            f"clutter (the Armadillo touching real mOSD objects, {a['clicks']} clicks):"
            f" ranked first {_pct(a['ranked_first'])}, found within 5 mm / 5 deg "
            f"{_pct(a['found'])}, accepted {_pct(a['fits'])}"
        )
    if c.get("armadillo_held_out"):
        a = c["armadillo_held_out"]
        lines.append(
            f"clutter, held-out scenes ({a['clicks']} clicks): ranked first "
            f"{_pct(a['ranked_first'])}, found within 5 mm / 5 deg {_pct(a['found'])}, "
            f"accepted {_pct(a['fits'])}"
        )
    for key, what in (("armadillo", "clutter"), ("milk", "PCL's milk carton")):
        if c.get(key) is None and c.get(f"{key}_why"):
            lines.append(f"{what}: not measured -- {c[f'{key}_why']}")
    if c.get("milk"):
        m = c["milk"]
        lines.append(
            f"PCL's milk carton in its real scene: ranked first {m['ranked_first']}, "
            f"{m['error_mm']} mm (at its centroid) / {m['error_deg']} deg, accepted "
            f"{m['fits']}"
        )
        box = m.get("as_box")
        if box:
            shown = (
                f"a {box['primitive']} "
                + " x ".join(f"{v:.3f}" for v in box["dimensions"].values())
                + " m"
                if box["primitive"]
                else box["template"]
            )
            body = (
                ""
                if box["body_on_box"] is None
                else f", its body on the box {_pct(box['body_on_box'])}"
            )
            lines.append(
                f"PCL's milk carton without its template (the bundled library): "
                f"shown as {shown}, accepted {box['fits']}{body}"
            )
        cost = m.get("cost")
        if cost:
            ratio = "" if cost["ratio"] is None else f" ({cost['ratio']:.1f}x)"
            lines.append(
                f"a scanned template's cost (PCL's milk carton in the bundled library, "
                f"{cost['clicks']} mOSD clicks, CPU): adds {cost['scanned_ms']:.0f} ms a click "
                f"as a point cloud against {cost['mesh_ms']:.0f} ms as a mesh{ratio}; on the "
                f"bundled library's {cost['bundled_ms']:.0f} ms; on the carton's own click "
                f"{cost['own_click_scanned_ms']:.0f} against {cost['own_click_mesh_ms']:.0f} ms"
            )
    return lines


def _spread(jobs: list, n: int) -> list:
    """At most ``n`` of ``jobs``, evenly spaced over them (every scene's clicks alike)."""
    return jobs[:: max(1, len(jobs) // n)][:n]


def format_table(result: dict) -> str:
    lines = [
        f"{'method':<20} {'clicks':>6} {'median s':>9} {'p90 s':>7} {'top-1':>7} "
        f"{'pose ok':>8} {'x default':>9}"
    ]
    for r in result["rows"]:
        lines.append(
            f"{r['method']:<20} {r['clicks']:>6} {r['median_s']:>9.3f} {r['p90_s']:>7.3f} "
            f"{r['top1']:>7.1%} {r['pose_success']:>8.1%} {r['ratio_to_default']:>8.1f}x"
        )
    for r in result["rows"]:
        if "optical_top1" in r:
            lines.append(
                "frames: "
                + "; ".join(
                    f"{k} {v['top1']:.1%} / {v['pose_success']:.1%}"
                    for k, v in r["frames"].items()
                )
                + f" -- optical on the same clicks {r['optical_top1']:.1%} / "
                f"{r['optical_pose_success']:.1%}; {r['errors']} errors"
            )
    real = result.get("real_scans")
    if real:
        lines.append(
            "real scans (Armadillo, 4 views with ground truth): "
            + "; ".join(
                f"{k}: ranked first {v['ranked_first']:.0%}, pose ok {v['pose_success']:.0%}, "
                f"median {v['median_s']:.2f} s"
                for k, v in real.items()
            )
        )
    lines += _real_capture_lines(result)
    lines += format_row(result.get("viewpoint") or {})
    lines.append(
        f"refit after a correction (1.5 cm, 8 deg): median "
        f"{result['refit']['median_s'] * 1000:.1f} ms, "
        f"lands within tolerance {result['refit']['success']:.1%}"
    )
    a = result.get("articulated")
    if a:
        lines.append(
            f"articulated ({a['clicks']} clicks, top-1 {a['top1']:.1%}): joint within "
            f"5 deg / 2 mm {a['joint_within_tol']:.1%} of {a['joints']}, state right "
            f"{a['state_right']:.1%}, scale within 3% {a['scale_within_3pct']:.1%} of "
            f"{a['scaled']}; median {a['median_s']:.3f} s = {a['time_ratio_to_rigid']:.2f}x "
            f"rigid ({a['rigid_median_s']:.3f} s)"
        )
    for key, what in (
        ("push_refit_ros", "refit after a SpaceMouse push over ROS"),
        ("ros_latency", "the engine node over ROS"),
        ("browser_latency", "the browser station"),
    ):
        if (result.get(key) or {}).get("left_out"):
            lines.append(f"{what}: left out ({result[key]['left_out']})")
    pushed = result.get("push_refit_ros")
    if pushed and not pushed.get("left_out"):
        lines.append(
            f"refit after a SpaceMouse push over ROS (the same corrections, {pushed['clicks']}"
            f" clicks): lands {pushed['ros_success']:.1%}; the core's refit from the same"
            f" corrections {pushed['core_success']:.1%}"
        )
    lat = result.get("ros_latency")
    if lat and lat["clicks"]:
        lines.append(
            f"the engine node over ROS ({lat['clicks']} clicks, each fitted in this process "
            f"too): click -> ~/status {lat['click_to_status_over_fit']:.2f}x the in-process "
            f"fit (median of ratios); ~/markers {lat['status_to_markers_ms']:.0f} ms after "
            f"the status (median); a ~/markers message with "
            f"{lat['objects_shown_last']} objects {lat['markers_bytes_last'] / 1000:.0f} kB "
            f"(largest {lat['markers_bytes_max'] / 1000:.0f} kB); idle engine "
            f"{lat['idle_engine_cores']:.3f} cores"
        )
    lines += operator_lines(result.get("browser_operator"))
    web = result.get("browser_latency")
    if web and web["clicks"]:
        lines.append(
            f"the browser station (headless Chromium, {web['clicks']} clicks, display budget "
            f"{web['display_points']:,} points): click -> label median "
            f"{web['click_to_label_s']:.2f} s (max {web['click_to_label_max_s']:.2f}); the "
            f"engine's part (clicked_point -> status) {web['engine_click_to_status_s']:.2f} s"
        )
    for r in result.get("threads", ()):
        lines.append(
            f"default method on {r['threads']} thread(s) ({r['clicks']} clicks, paired): "
            f"median {r['median_s']:.3f} s = {r['ratio_to_first']:.2f}x the first"
        )
    for r in result.get("kernels", ()):
        lines.append(
            f"default method, {r['kernels']} kernels ({r['clicks']} clicks, paired, one "
            f"thread): median {r['median_cpu_s'] * 1e3:.0f} ms CPU = "
            f"{r['cpu_ratio_to_numpy']:.2f}x the numpy path's, wall {r['ratio_to_numpy']:.2f}x"
        )
    for r in result.get("library_sizes", ()):
        lines.append(
            f"library of {r['templates']:>2} templates ({r['clicks']} clicks): median "
            f"{r['median_s']:.3f} s = {r['ratio_to_first']:.2f}x, true template first "
            f"{r['top1']:.1%}; prefilter decided on {r['prefilter_decided']:.0%} of "
            f"clicks, {r['prefilter_set_aside_per_click']:.1f} templates set aside, "
            f"the true one on {r['true_template_set_aside']} clicks"
        )
    for r in result.get("library_sizes_held_out_family", ())[1:]:
        lines.append(
            f"held-out variant family (random-direction stretches): library of "
            f"{r['templates']} templates ({r['clicks']} clicks) median {r['median_s']:.3f} s"
            f" = {r['ratio_to_first']:.2f}x the five, true template first {r['top1']:.1%}; "
            f"prefilter decided on {r['prefilter_decided']:.0%} of clicks, the true one "
            f"set aside on {r['true_template_set_aside']}"
        )
    large = result.get("large_cloud")
    if large:
        lines.append(
            f"click -> result from a {large['points']:,}-point organized cloud "
            f"(Scene() + fit, {large['clicks']} clicks): median "
            f"{large['click_to_result_s']:.3f} s (Scene() {large['scene_ms']:.1f} ms), "
            f"top-1 {large['top1']:.1%}, pose ok {large['pose_success']:.1%}"
        )
    conv = result.get("conversions")
    if conv:
        lines.append(
            f"PointCloud2 -> numpy, {conv['points']:,} organized points: median "
            f"{conv['to_numpy_ms']:.1f} ms, then Scene() {conv['scene_ms']:.1f} ms; "
            f"numpy -> PointCloud2 {conv['from_numpy_ms']:.1f} ms"
        )
    lines.append(
        f"pose ok = right template first and within {result['pose_tolerance']['m'] * 1000:.0f} mm "
        f"and {result['pose_tolerance']['deg']:.0f} deg (symmetry-aware); "
        f"{result['scenes']} panel scenes, {result['machine']['cpus']} CPUs"
    )
    return "\n".join(lines)


#: what each line of the table measures, by how the line starts (the longest start that fits):
#: (start, title, one short paragraph); BENCHMARK.md gives those of the lines it shows
ROW_NOTES = (
    (
        "method",
        "the first block",
        "One line per method, on the same simulated taskboard clicks (20 panel scenes of five "
        "objects each, seeds 1000+) unless the line says otherwise: the clicks fitted, the median "
        "and 90th-percentile time of a click with every template of the library, `top-1` the "
        "share with the true template ranked first, `pose ok` the share where it is also within "
        "5 mm and 5 deg of the truth (symmetry-aware), and the median time over the default "
        "method's in this run.",
    ),
    (
        "default ",
        "default",
        "The package's fitter with its default settings (`FitSettings()`, the node's `fit.*` "
        "defaults): joint values and scale estimated with the pose.",
    ),
    (
        "default, rigid only",
        "default, rigid only",
        "The same fitter with `articulated: false`: rigid templates, no joint value or scale "
        "estimated.",
    ),
    (
        "default (table)",
        "default (table)",
        "Objects lying on a table in their stable resting poses (table scenes, seeds 2000+): no "
        "mounting plane prior applies.",
    ),
    (
        "paper (literal)",
        "paper (literal)",
        "The method of Hagenow et al. implemented literally (`fit --method paper`), the slow "
        "baseline: run on 25 of the clicks (`--paper-clicks 0` runs all).",
    ),
    (
        "open3d icp p2p",
        "open3d icp p2p",
        "Open3D's point-to-point `registration_icp` started from the same hypotheses on the same "
        "crop, ranked by its own fitness.",
    ),
    (
        "small_gicp gicp",
        "small_gicp gicp",
        "small_gicp's GICP likewise; the line is there only where small_gicp is installed (`pip "
        "install small_gicp`, a bench-only extra).",
    ),
    (
        "frames (",
        "frames",
        "The panel clicks re-expressed in four frames that are not the camera's optical frame "
        "(scene, click and sensor origin moved together), 100 clicks in each.",
    ),
    (
        "frames:",
        "frames (each)",
        "The frames row by frame: top-1 / pose ok in a z-up base frame with the sensor 1.1 m "
        "up, a map frame metres away, an arbitrary rotation and upside down, against the optical "
        "frame on the same clicks, and the fits that raised an error.",
    ),
    (
        "no viewpoint",
        "no viewpoint",
        "The panel clicks fitted with `sensor_origin none`, as for an accumulated map: no "
        "visibility terms, normals estimated from the data.",
    ),
    (
        "sensor faults",
        "sensor faults",
        "The panel scenes rendered with the depth-camera fault model (`simulate --faults`: "
        "flying pixels, a smooth depth distortion, dropouts on dark patches and at grazing "
        "angles, more range noise).",
    ),
    (
        "real scans",
        "real scans",
        "The four Armadillo range scans of or-pcd that have ground truth, fitted with a "
        "point-cloud template made of the other views merged, of all four merged, of all four in "
        "the taskboard library, and clicked low on the statue (its lowest 5% of points).",
    ),
    (
        "right fits the verdict accepts",
        "right fits the verdict accepts",
        "Of each row's right fits (pose ok), the share the verdict accepts (`fits: true`): a "
        "right answer the operator is not told to doubt.",
    ),
    (
        "default library with the box",
        "default library with the primitives",
        "The panel clicks with the bundled library including the box and cylinder primitives: "
        "what the primitives cost and change where a known object is clicked.",
    ),
    (
        "trust, ",
        "trust (issue 59)",
        "Every labelled object of the learn scenes (by mOSD group, tuning and held-out scenes "
        "apart) and of composite scenes built from them (`evaluation/composite.py`: mixed -- "
        "3-5 boxes, cans and bowls of several scenes on one table -- and complex -- 5-8 "
        "objects, stacks, lying cylinders and books, simulated shapes that are neither box nor "
        "cylinder, hiding each other; 5 development seeds 0+ and 5 held-out seeds 100+ of each, "
        "every one of 20 + 20 with `--all-composites`) clicked in its middle and the shown "
        "candidate judged by the labels: `right` a box or cylinder shown as that primitive "
        "passing the label rule, or nothing fitting an object that is neither; `wrong and "
        "accepted` said to fit and not right; `specific claims` a taskboard template said to "
        "fit; by kind in brackets.",
    ),
    (
        "trust (learn and composite",
        "trust, not measured",
        "The trust rows without the shared mOSD scenes: what is missing.",
    ),
    (
        "real Kinect (mOSD",
        "real Kinect (mOSD learn)",
        "The labelled objects of mOSD's real Kinect scans (learn split; tuning and held-out "
        "scenes apart; `$AFFORDANCE_SHARED_DATA`): the share the library's specific templates "
        "refuse (none of these objects is in it), and the box or cylinder fitted instead, scored "
        "against the per-point labels -- recall, precision, the share passing both at 90%, the "
        "same for the fit refined on the labels (what the score allows) -- and the right kind "
        "shown; of the clicks whose shown primitive fits and passes the label score, the share "
        "whose answer is settled.",
    ),
    (
        "real Kinect click against",
        "real Kinect click against a simulated one",
        "What a real capture's click costs: one engine clicks a real mOSD object and a simulated "
        "panel object alternately -- the whole click the node runs (the fit, its verdict, the "
        "primitives, whether it is settled) -- in CPU time (the machine is shared); the median "
        "of the pairs' ratios. The suggested view of an unsettled real click, computed after the "
        "click's status went out, is timed apart. (Results without a `clock` are of one "
        "registrar's fits, in wall time.)",
    ),
    (
        "primitives on simulated",
        "primitives on simulated scenes",
        "Simulated tables of boxes and cylinders, of stacked boxes and of open-topped mugs (some "
        "seen by a faulty sensor), with true dimensions; development and held-out seeds apart. "
        "The right primitive shown, its dimensions within 5 mm, its pose within 5 mm / 5 deg, "
        "and 'wrong and accepted': the best candidate fits but is not the right primitive of the "
        "right size and pose.",
    ),
    (
        "clutter",
        "clutter",
        "The Armadillo point-cloud template standing on real mOSD tables, touching a real "
        "object (tuning tables, then held-out ones): ranked first, found within 5 mm / 5 deg, "
        "and accepted by the verdict.",
    ),
    (
        "PCL's milk carton in its real scene",
        "PCL's milk carton",
        "PCL's milk carton scene with the carton as a point-cloud template: its rank, the pose "
        "error at its centroid and the verdict.",
    ),
    (
        "PCL's milk carton without its template",
        "PCL's milk carton without its template",
        "The same carton clicked with the bundled library alone: what it is shown as, whether "
        "that is accepted, and the share of the carton's points on the fitted box.",
    ),
    (
        "a scanned template's cost",
        "a scanned template's cost",
        "What one scanned template adds to a click, against the same object as a mesh: three "
        "registrars -- the bundled library, it with PCL's milk carton as a point-cloud template, "
        "it with the box of the carton's points as a mesh template -- fit each click in turn, on "
        "mOSD objects spread over the 15 learn scenes of the earlier rounds (what the template "
        "costs every click that is not its object) and on the carton's own click; CPU time, the "
        "median over the clicks of what each adds to the bundled library's click.",
    ),
    (
        "viewpoint advice",
        "viewpoint advice",
        "Each taskboard object scanned from a hard first view (grazing, occluded, far, edge-on) "
        "and clicked; where the fit is wrong or unsettled the scene is scanned again from the "
        "suggested view, from a random view within the same bounds and from the first view "
        "again. Top-1 / pose ok of each, the suggestion's time, the hard views by kind; the "
        "indented line counts the unsettled clicks alone. `bench --row viewpoint` runs it alone.",
    ),
    (
        "refit after a correction",
        "refit after a correction",
        "A right fit moved by 1.5 cm and 8 deg, as an operator's correction, then refitted on "
        "the click's context as the click's fit left it (as the engine refits: the crop's "
        "segments, noise and search trees were found by the click): the refit's median time and "
        "the share that lands back within tolerance.",
    ),
    (
        "articulated",
        "articulated",
        "Taskboards with valve handles at random angles, e-stops pressed or released and grab "
        "handles in sizes 0.8-1.25 (seeds 3000+): joint values within 5 deg / 2 mm, the named "
        "state, the scale within 3%, and the time against the rigid fit of the same clicks.",
    ),
    (
        "refit after a SpaceMouse push",
        "refit after a SpaceMouse push over ROS",
        "The same corrections sent as SpaceMouse twists to a live engine node: the share that "
        "lands within tolerance, against the core's refit from the same corrections.",
    ),
    (
        "the engine node over ROS",
        "the engine node over ROS",
        "The engine node started from its launch file in its own process, each object clicked "
        "as RViz would: click -> `~/status` over the same fit in the bench's process (median of "
        "the ratios), `~/markers` after the status, a `~/markers` message's size, and the idle "
        "engine's CPU.",
    ),
    (
        "the browser station",
        "the browser station",
        "Click -> label in headless Chromium against the station, an engine and the panel "
        "scenes, on the page's own clock from the mouse press to the label; the engine's part is "
        "clicked_point -> status.",
    ),
    (
        "the scripted operator in the browser",
        "the scripted operator",
        "A scripted operator registers every object of simulated taskboards and shared real "
        "scans through the station's page only (`evaluation/browser_operator.py`): clicks it, "
        "reads the verdict, presses Next while the model is wrong, types a primitive's size and "
        "drags the gizmo where the fit is off (towards the simulator's pose, or the fit refined "
        "on the object's labels), Accepts, Saves. Right: the simulator's template within 5 mm "
        "and 5 degrees; on real scans the label rule. Per object: clicks, model changes, "
        "corrections, seconds from the click to the shown fit and to the accepted registration "
        "on the page's clock. The paper's Kinect figures are the line to beat.",
    ),
    (
        "default method on",
        "threads",
        "Each click fitted on 1 and on 2 threads in turn (`threads`): the median and the median "
        "of the per-click ratios to the first.",
    ),
    (
        "library of",
        "library sizes",
        "Libraries of 5, 10, 20 and 40 templates (the five and scaled or stretched copies), each "
        "click fitted by each in turn: the time against the five, the true template first, and "
        "how often the library prefilter decided and what it set aside.",
    ),
    (
        "held-out variant family",
        "held-out variant family",
        "Copies made differently (stretched or squeezed 20-50% along random directions) and kept "
        "out of the prefilter's tuning, on held-out taskboards (seeds 7000+): 40 templates "
        "against the five.",
    ),
    (
        "click -> result",
        "click -> result from a 1M-point cloud",
        "`Scene()` of a 1024 x 1024 organized cloud (a simulated camera of that resolution) plus "
        "the fit.",
    ),
    (
        "PointCloud2 -> numpy",
        "PointCloud2 conversions",
        "The node's conversion of a 1M-point organized PointCloud2 to numpy, `Scene()` of it, "
        "and numpy back to PointCloud2.",
    ),
    (
        "pose ok =",
        "the last line",
        "The tolerances of `pose ok`, the panel scenes and the machine's CPUs.",
    ),
)


def row_note(line: str) -> tuple | None:
    """The (start, title, paragraph) of :data:`ROW_NOTES` for a line of the table; None for a
    line no note describes (an indented line: part of the row above it)."""
    starts = [note for note in ROW_NOTES if line.startswith(note[0])]
    return max(starts, key=lambda note: len(note[0])) if starts else None


def _wrap(line: str, width: int = 100) -> str:
    indent = len(line) - len(line.lstrip())
    return textwrap.fill(line, width=width, subsequent_indent=" " * (indent + 2))


def render_markdown(result: dict) -> str:
    """BENCHMARK.md: the run, the table (:func:`format_table`, wrapped at 100 columns) and what
    each of its rows measures."""
    run = result.get("run") or {}
    when = ", ".join(
        part
        for part in (
            f"at commit {run['commit']}" if run.get("commit") else "",
            f"on {run['date']}" if run.get("date") else "",
            f"{run['minutes']} minutes" if run.get("minutes") is not None else "",
            f"{result['machine']['cpus']} CPUs",
            "--quick" if run.get("quick") else "",
        )
        if part
    )
    table = format_table(result)
    notes, seen = [], set()
    for line in table.splitlines():
        note = row_note(line)
        if note and note[0] not in seen:
            seen.add(note[0])
            notes.append(f"**{note[1]}** -- {note[2]}")
    intro = (
        "Speed and accuracy of the default method against the paper's method and other ICP, "
        "measured in one run of `affordance-registration bench` on simulated scenes with ground "
        "truth and on real scans. Times depend on the machine and its load: compare the ratios "
        "within a run, not times across runs."
    )
    lines = [
        "# Benchmark",
        "",
        textwrap.fill(intro, 99),
        "",
        textwrap.fill(
            f"This run: {when}." + (f" {result['note']}" if result.get("note") else ""), 99
        ),
        "",
        textwrap.fill(
            f"`affordance-registration bench --out DIR` writes {RESULTS_NAME} (the results), "
            f"{SETTINGS_NAME} (the settings they were measured with) and this file, their "
            "rendering. docs/ holds one run's three; `test/test_benchmark_doc.py` checks that "
            "docs/BENCHMARK.md is the rendering of docs/benchmark.json, so regenerate them "
            "(`bench --out docs`) rather than edit them.",
            99,
        ),
        "",
        "```",
        *(_wrap(line) for line in table.splitlines()),
        "```",
        "",
        "## What each row measures",
        "",
    ]
    for note in notes:
        lines += [textwrap.fill(note, 99), ""]
    return "\n".join(lines)
