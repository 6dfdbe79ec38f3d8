# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ``affordance-registration`` command.

Subcommands: fit, settings, simulate, bench, trust, demo, generate-models (and the ROS ones:
launch, bag, spacemouse, station, when their modules are present). Errors print one line naming
the problem and exit with status 2; nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

from .cli_args import EXIT_ERROR, Parser, add_bag_parser, path_arg, quiet_stdout
from .core.errors import AffordanceError

#: the largest --seed (a node's integer parameter holds it; fit.seed's bound too)
MAX_SEED = 2**31 - 1
#: how many of the ranked candidates `fit --json` gives waypoints (the ones an operator looks at)
LEADING = 3


def _fail(msg: str) -> int:
    # (one line whatever the message holds: a path or a key with a newline in it)
    msg = str(msg).replace("\r", "\\r").replace("\n", "\\n")
    print(f"affordance-registration: error: {msg}", file=sys.stderr)
    return EXIT_ERROR


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_SEED:
        raise AffordanceError(f"--seed must be an integer in [0, {MAX_SEED}], got {text!r}")
    return value


def _library(path):
    from .core.templates import TemplateLibrary

    return TemplateLibrary.load(path)


# ---------------------------------------------------------------------------- fit
def _sensor_origin(values):
    """``--sensor-origin``: None (not given: the file's VIEWPOINT or the frame's origin),
    ``"none"`` or 3 numbers."""
    if values is None:
        return None
    if len(values) == 1 and values[0].strip().lower() == "none":
        return "none"
    try:
        origin = [float(v) for v in values]
    except ValueError:
        origin = []
    if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
        raise AffordanceError(
            f"--sensor-origin takes X Y Z (3 finite numbers) or 'none', got {' '.join(values)!r}"
        )
    return origin


def cmd_fit(args) -> int:
    from .core.registration import FitSettings, Registrar, describe_primitive, no_match, verdict
    from .core.scene import UNITS, Scene

    origin = _sensor_origin(args.sensor_origin)
    unit = UNITS[args.units]  # --point, --sensor-origin and the file: in --units
    if isinstance(origin, list):
        origin = [v * unit for v in origin]
    lib = _library(args.templates)
    scene = Scene.from_file(args.scene, sensor_origin=origin, scale=unit)
    given = {
        "seed": None if args.seed is None else _seed(args.seed),
        "method": args.method,
        "mode": args.mode,
    }  # the flags given override the file
    settings = (FitSettings.load(args.settings) if args.settings else FitSettings()).with_(
        **{k: v for k, v in given.items() if v is not None}
    )
    registrar = Registrar(lib, settings)
    registrar.warm_up()  # one-off start-up cost, not part of a click
    report = registrar.fit(scene, [v * unit for v in args.point])
    best = report.candidates[0]
    refused = no_match(report.candidates)
    doc = {
        "point": [round(float(v), 6) for v in report.point],
        "sensor_origin": None
        if scene.sensor_origin is None
        else [round(float(v), 6) for v in scene.sensor_origin],
        "verdict": verdict(report.candidates),
        "no_match": refused,
        "reason": best.reason,
        "noise": round(float(best.noise), 9),
        "candidates": [c.to_dict() for c in report.candidates],
        "ambiguity": report.ambiguity.to_dict(),
        "timing_s": {k: round(v, 6) for k, v in report.timing_s.items()},
    }
    view = registrar.suggest_view(report, scene=scene) if args.suggest_view else None
    if args.suggest_view:
        doc["suggested_view"] = None if view is None else view.to_dict()
    if args.json:
        from .core.waypoints import waypoints_dict

        for entry, c in zip(doc["candidates"][:LEADING], report.candidates):
            entry["waypoints"] = waypoints_dict(lib, c)  # the leaders': in the scene frame
        print(json.dumps(doc, indent=2))
        return 0
    print(
        f"click snapped to ({', '.join(f'{v:.3f}' for v in report.point)}); "
        f"{len(report.candidates)} templates fitted in {report.timing_s['total']:.3f} s"
    )
    if not refused:
        print(
            f"{best.template} fits: it covers {best.coverage:.0%} of its visible surface and "
            f"explains {best.explained:.0%} of the clicked object"
        )
    else:
        specific = next((c for c in report.candidates if c.primitive is None), None)
        why = (
            f" (the best template, {specific.template}: {specific.reason})"
            if specific is not None and specific.reason
            else ""
        )
        print(f"{verdict(report.candidates)}{why}")
    print(
        "ranked best first: templates by likelihood, then primitives (first only where no "
        "template fits); p is within its group, beside 'no template fits here'"
    )
    print(
        f"{'rank':>4}  {'template':<22} {'verdict':<12} {'p':>5} {'residual mm':>11} "
        f"{'coverage':>8} {'explained':>9} {'rmse mm':>7}  position (m)"
    )
    for c in report.candidates:
        pos = c.T_scene_model[:3, 3]
        judged = (
            f"{c.coverage:>8.2f} {c.explained:>9.2f} {c.inlier_rmse * 1000:>7.2f}"
            if c.fits is not None
            else f"{'-':>8} {'-':>9} {'-':>7}"
        )  # set aside: not judged
        said = {True: "fits", False: "does not fit", None: "not judged"}[c.fits]
        size = f"  {describe_primitive(c)}" if c.primitive else ""
        print(
            f"{c.rank:>4}  {c.template:<22} {said:<12} {c.probability:>5.2f} "
            f"{c.residual * 1000:>11.2f} {judged}  ({pos[0]:.3f}, {pos[1]:.3f}, {pos[2]:.3f})"
            f"{size}"
        )
    print(report.ambiguity.describe())
    if args.suggest_view:
        print(
            f"suggested view: {view.describe()}"
            if view is not None
            else "suggested view: none (the click is settled, or the scan has no viewpoint)"
        )
    return 0


def cmd_settings(args) -> int:
    from .core.registration import FitSettings

    if args.node_params or args.markdown:
        from .ros.glue import params

        if args.node_params:
            print(params.params_file(), end="")
        elif args.markdown == "station":
            from .ros.station.parameters import station_table

            print(station_table(), end="")
        else:
            print(params.node_table() if args.markdown == "node" else params.fit_table(), end="")
    else:
        print((FitSettings.load(args.file) if args.file else FitSettings()).dump(), end="")
    return 0


# ---------------------------------------------------------------------------- simulate
def cmd_simulate(args) -> int:
    from .evaluation.simulation import DepthCamera, FaultModel, simulate_taskboard, write_scene

    seed = _seed(args.seed)
    lib = _library(args.templates)
    camera = DepthCamera(faults=FaultModel()) if args.faults else None
    sim = simulate_taskboard(lib, seed, layout=args.layout, camera=camera)
    paths = write_scene(sim, args.out)
    print(
        f"simulated {args.layout} scene (seed {seed}): {len(sim.points)} points, "
        f"{len(sim.objects)} objects -> {args.out}"
    )
    for o in sim.objects:
        p = o.T_scene_model[:3, 3]
        click = (
            "none visible"
            if o.click is None
            else "click (" + ", ".join(f"{v:.3f}" for v in o.click) + ")"
        )
        print(
            f"  {o.template:<22} at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}), "
            f"{o.visible_points} visible points, {click}"
        )
    for name in ("scene.ply", "truth.yaml", "scene_organized.npy"):
        print(f"  wrote {paths[name]}")
    return 0


# ---------------------------------------------------------------------------- bench
def cmd_bench(args) -> int:
    from .evaluation.bench import format_table, run_bench

    log = lambda *a: print(*a, file=sys.stderr, flush=True)
    if os.path.exists(args.out) and not os.path.isdir(args.out):  # (said before the long run)
        raise AffordanceError(f"--out {args.out} is not a folder")
    if args.row == "trust":  # the trust rows alone (issue 59)
        from .evaluation.composite import composite_rows, format_lines

        samples = None if args.all_composites else 1 if args.quick else 5
        trust = composite_rows(samples=samples, log=log)
        if trust.get("left_out"):
            print(f"error: {trust['left_out']}", file=sys.stderr)
            return 2
        print("\n".join(format_lines(trust["summary"])))
        return 0
    if args.row == "viewpoint":  # one row alone (its own seeds): for its numbers
        from .evaluation.viewpoints import format_row, viewpoint_row

        print("\n".join(format_row(viewpoint_row(log=log))))
        return 0
    if args.row == "browser-operator":
        from .evaluation.bench_rows import browser_operator_bench
        from .evaluation.browser_operator import format_row

        seeds = range(1000, 1001 if args.quick else 1002)
        row = browser_operator_bench(seeds, 2 if args.quick else 6, log)
        if row is None:
            raise AffordanceError("the browser operator row needs the ROS packages")
        print("\n".join(format_row(row)))
        return 0
    result = run_bench(
        quick=args.quick,
        scenes=args.scenes,
        paper_clicks=args.paper_clicks,
        out=args.out,
        log=log,
        all_composites=args.all_composites,
    )
    print(format_table(result))
    if result.get("written"):
        print("written: " + ", ".join(result["written"]))
    return 0


# ---------------------------------------------------------------------------- demo
def print_session_table(rows, out=print) -> None:
    """The paper-style table, a verdict per row (PASS, or FAIL and why), and a summary line."""
    from .evaluation.simulation import failures

    out(
        f"{'true template':<20} {'ranked first':<20} {'changes':>7} {'corrections':>11} "
        f"{'fit s':>6} {'error':>14}  verdict"
    )
    for r in rows:
        err = (
            "-"
            if not math.isfinite(r["error_mm"])
            else f"{r['error_mm']:.1f} mm {r['error_deg']:.1f}°"
        )
        why = r["why"] if "why" in r else "; ".join(failures(r))
        verdict = "PASS" if r["ok"] else f"FAIL ({why})"
        out(
            f"{r['template']:<20} {r['ranked_first']:<20} {r['model_changes']:>7} "
            f"{r['corrections']:>11} {r['fit_s']:>6.2f} {err:>14}  {verdict}"
        )
    n = len(rows)
    ok = sum(r["ok"] for r in rows)
    first = sum(r["ranked_first"] == r["template"] for r in rows)
    out(
        f"{ok}/{n} objects registered within tolerance; {first}/{n} "
        f"ranked first; {sum(r['model_changes'] for r in rows) / max(n, 1):.1f} model changes and "
        f"{sum(r['corrections'] for r in rows) / max(n, 1):.1f} corrections per object; mean fit "
        f"{sum(r['fit_s'] for r in rows) / max(n, 1):.2f} s (paper: 4.84 s)"
    )


def verdict_line(rows) -> str:
    """'DEMO OK' or 'DEMO FAILED: ' and the failing rows."""
    from .evaluation.simulation import failures

    failed = [
        f"{r['template']} ({r['why'] if 'why' in r else '; '.join(failures(r))})"
        for r in rows
        if not r["ok"]
    ]
    if not rows:
        return "DEMO FAILED: no object was registered"
    return "DEMO OK" if not failed else "DEMO FAILED: " + "; ".join(failed)


def _core_demo(args) -> int:
    from .evaluation.core_demo import run_core_demo

    seed = _seed(args.seed)
    rows, saved = run_core_demo(_library(args.templates), seed, args.out)
    print(f"simulated taskboard (seed {seed}), core engine without ROS:")
    print_session_table(rows)
    print(saved)
    print(verdict_line(rows))
    return 0 if rows and all(r["ok"] for r in rows) else 1


#: the ROS domains a demo picks its own from (even numbers: the test suite's processes take odd
#: ones); a demo's nodes must not hear other engines of this machine in the default domain
DEMO_DOMAINS = range(2, 101, 2)


def own_domain() -> str:
    """Put the nodes a demo starts (and this process) in a ROS domain of their own unless
    ``ROS_DOMAIN_ID`` is set; returns the words saying which. (Engines of the package running
    on the default domain of the same machine were heard as the demo's own: a TF check saw
    their registrations.)"""
    given = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if given:
        return f"ROS domain {given} (ROS_DOMAIN_ID)"
    domain = DEMO_DOMAINS[os.getpid() % len(DEMO_DOMAINS)]
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    return (
        f"ROS domain {domain}, its own (ROS_DOMAIN_ID was not set; set it, e.g. "
        f"ROS_DOMAIN_ID={domain} for RViz, to share the demo's topics)"
    )


def default_session_dir() -> str:
    from .core.templates import default_models_dir

    return os.path.join(os.path.dirname(default_models_dir()), "test", "data", "session")


def cmd_trust(args) -> int:
    from .evaluation.composite import format_lines, run

    summary, records = run(
        args.kind,
        args.seeds,
        args.out,
        refined=args.refined,
        save=args.save,
        log=lambda line: print(line, file=sys.stderr, flush=True),
    )
    print("\n".join(format_lines(summary)))
    print(f"{len(records)} records written to {os.path.abspath(args.out)}")
    return 0


def cmd_demo(args) -> int:
    """The main job: the full ROS 2 pipeline on the bundled recorded session."""
    if args.core:
        return _core_demo(args)
    from .evaluation.session import replay_session

    session = args.session or default_session_dir()
    if not os.path.isdir(session):
        raise AffordanceError(f"no recorded session at {session}")
    domain = own_domain()
    print(
        f"replaying the recorded operator session {session} into a live affordance_engine "
        f"node (started from launch_configs/affordance_engine.launch.yaml) in {domain} ...",
        flush=True,
    )
    result = replay_session(session, args.out)
    print_session_table(result["rows"])
    print(f"{result['played']} messages replayed in {result['played_s']:.1f} s; {result['saved']}")
    print(f"wrote {result['status']} and {result['picture']}")
    print(verdict_line(result["rows"]))
    return 0 if result["ok"] else 1


def cmd_session(args) -> int:
    """Record a new operator session (simulated scene, live engine, simulated operator)."""
    from .evaluation.session import record_session

    print(f"recording a simulated operator session (seed {_seed(args.seed)}) into {args.out} ...")
    result = record_session(args.out, seed=_seed(args.seed))
    print_session_table(result["rows"])
    print(f"recorded {result['counts']} into {result['bag']}")
    return 0


# ---------------------------------------------------------------------------- station
def cmd_station(args) -> int:
    """The browser operator station (``--demo``: with an engine node and a simulated scan;
    ``--scene FILE``: with an engine node and that scan)."""
    # (from the light parameters module: --demo and --scene start the station as a node of
    # their own, and a refusal is said before the node module's imports)
    from .ros.station.parameters import check_port

    if args.demo and args.scene:
        raise AffordanceError("--demo and --scene exclude each other (--demo simulates a scan)")
    scene = origin = None
    if args.scene:  # the file is checked here, so a bad one is one line before any node starts
        from .ros.station.scene import read_scan

        scene = os.path.abspath(args.scene)
        scan = read_scan(scene, args.units)
        if scan.warning:
            print(f"affordance-registration: warning: {scan.warning}", file=sys.stderr)
        origin = "[" + ", ".join(f"{float(v)!r}" for v in scan.sensor_origin) + "]"
    check_port(args.host, args.port)
    if not args.demo and not scene:
        from .ros.station.node import main as station_main

        return station_main(
            [
                "--ros-args",
                "-p",
                f"host:={args.host}",
                "-p",
                f"port:={args.port}",
                "-p",
                f"up:={args.up}",
            ]
        )
    import signal
    import threading
    import urllib.request

    from .ros.standins.launcher import Launcher, package_share, parse_launch_file

    if args.demo:  # (checked before --out is made: a refusal leaves no folder)
        from .evaluation.simulated_scan import check_first_view

        check_first_view(args.first_view, _library(None))
        _seed(args.seed)
    os.makedirs(args.out, exist_ok=True)
    domain = own_domain()
    registrations = os.path.abspath(os.path.join(args.out, "registrations.yaml"))
    given = {
        "host": args.host,
        "port": str(args.port),
        "registrations_file": registrations,
        "up": args.up,
    }
    if scene:
        launch_name, log_name = "station_scene.launch.yaml", "station_scene.log"
        given.update(scene=scene, units=args.units, sensor_origin=origin)
        what = f"an engine node and the scan {scene} (in {args.units})"
    else:
        launch_name, log_name = "station_demo.launch.yaml", "station_demo.log"
        given.update(seed=str(_seed(args.seed)), first_view=args.first_view)
        what = f"an engine node and a simulated taskboard scan (seed {_seed(args.seed)})"
    launch = os.path.join(package_share("affordance_registration"), "launch_configs", launch_name)
    nodes = parse_launch_file(launch, given)
    log_path = os.path.join(args.out, log_name)
    # the station's access secret, handed to it through its environment (not its command line,
    # which every local user can read), and shown in the URL printed below
    from .ros.station.access import SECRET_ENV, new_secret

    secret = os.environ.get(SECRET_ENV) or new_secret()
    os.environ[SECRET_ENV] = secret
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    # the nodes' output holds the station's URL with its secret: a file for this user alone
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
    os.fchmod(fd, 0o600)
    with os.fdopen(fd, "w") as log:
        # a loaded machine may need more than the default 2 s for a node to stop on SIGINT
        # (what it starts, and a node that did not end cleanly, are named in the log)
        launcher = Launcher(
            nodes, log=lambda m: print(m, file=log, flush=True), output=log, grace=10.0
        )
        launcher.start()
        url = f"http://{args.host}:{args.port}/?token={secret}"
        deadline = time.monotonic() + 120
        while not stop.is_set():
            if any(p.poll() is not None for p in launcher.procs):
                launcher.stop()
                raise AffordanceError(f"a node stopped; see {log_path}")
            try:
                urllib.request.urlopen(url, timeout=1).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    launcher.stop()
                    raise AffordanceError(
                        f"the station did not come up on {url}; see {log_path}"
                    ) from None
                time.sleep(0.3)
        print(
            f"operator station: {url}\n  {what} are running in {domain}; Save writes "
            f"{registrations}; node logs in {log_path}; Ctrl-C stops everything",
            flush=True,
        )
        code = launcher.wait(stop.is_set)
        if code:
            print(f"a node did not stop cleanly; see {log_path}", file=sys.stderr, flush=True)
        return code


# ---------------------------------------------------------------------------- bag
def cmd_bag(args) -> int:
    from .ros.standins.bag import RATE_LIMITS, BagError, bag_info, check_number, topic_name

    if args.bag_command == "info":
        info = bag_info(args.bag)
        print(f"bag {info['path']}: {info['messages']} messages, {info['duration_s']:.2f} s")
        for t in info["topics"]:
            print(f"  {t['topic']:<32} {t['type']:<36} {t['count']:>6}")
        return 0
    # every option checked before a node starts or a file is made
    if args.bag_command == "record":
        if args.duration is not None:
            check_number("--duration", args.duration, positive=True)
        for topic in args.topics:
            topic_name(topic)
    else:
        check_number("--rate", args.rate, positive=True, limits=RATE_LIMITS)
        check_number("--start-offset", args.start_offset)
        check_number("--wait-for-subscribers", args.wait_for_subscribers)
        check_number("--pace-timeout", args.pace_timeout, positive=True)
        topic_name(args.status_topic)
    import signal
    import threading

    from .ros.standins.spin import background_node

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    with background_node("affordance_bag") as node:
        if args.bag_command == "record":
            from .ros.standins.bag import Recorder

            recorder = Recorder(node, args.out, args.topics)
            try:
                t0 = time.monotonic()
                while (
                    not stop.is_set()
                    and recorder.error is None
                    and (args.duration is None or time.monotonic() - t0 < args.duration)
                ):
                    time.sleep(0.05)
            except BaseException:
                recorder.abort()
                raise
            counts = recorder.close()
            if recorder.error is not None:
                raise BagError(
                    f"{recorder.error}; recording stopped"
                    + (
                        f", the {sum(counts.values())} messages recorded before are in {args.out}"
                        if recorder.kept
                        else f", {args.out} removed"
                    )
                )
            print(f"recorded {sum(counts.values())} messages into {args.out}: {counts}")
        else:
            from .ros.standins.bag import Player, StatusPacer

            pace = StatusPacer(node, args.status_topic, args.pace_timeout) if args.paced else None
            player = Player(
                node,
                args.bag,
                rate=args.rate,
                start_offset=args.start_offset,
                topics=args.topics or None,
                loop=args.loop,
                pace=pace,
            )
            if (
                args.wait_for_subscribers
                and not player.wait_for_subscribers(args.wait_for_subscribers, stop)
                and not stop.is_set()
            ):
                print("not every topic has a subscriber; playing anyway", file=sys.stderr)
            n = player.play(stop)
            print(f"played {n} messages from {args.bag}")
    return 0


# ---------------------------------------------------------------------------- launch
def cmd_launch(args) -> int:
    from .ros.standins.launcher import LaunchError, package_share, run_launch_file

    arguments = {}
    for item in args.arguments:
        if ":=" not in item:
            raise LaunchError(f"launch arguments are NAME:=VALUE, got {item!r}")
        name, value = item.split(":=", 1)
        arguments[name] = value
    profile = args.fastdds_profile
    if args.shm and not profile:
        profile = os.path.join(
            package_share("affordance_registration"), "launch_configs", "fastdds_shm.xml"
        )
    return run_launch_file(args.file, arguments, profile)


# ---------------------------------------------------------------------------- spacemouse
def cmd_spacemouse(args) -> int:
    from .ros.devices.spacemouse import list_devices

    try:
        lines = list_devices()
    except ImportError:
        raise AffordanceError("the hidapi package is not installed (pip install hidapi)") from None
    if not lines:
        print("no SpaceMouse attached")
    for line in lines:
        print(line)
    return 0


# ---------------------------------------------------------------------------- models
def cmd_generate_models(args) -> int:
    from .evaluation.taskboard import write_library

    for path in write_library(args.out):
        print(f"wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="affordance-registration",
        description="Click-to-fit affordance template registration (ROS 2).",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    p = sub.add_parser("fit", help="fit every template around a point of a scanned scene")
    p.add_argument(
        "--scene", required=True, help="scene file: PLY, PCD or organized .npy (in --units)"
    )
    p.add_argument(
        "--point",
        required=True,
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="the click: a point on the object, in the scene's frame and --units "
        "(snapped to the nearest scanned point within 3 cm)",
    )
    p.add_argument(
        "--units",
        choices=("m", "cm", "mm"),
        default="m",
        help="units of the scene file, --point and --sensor-origin (default m); "
        "the output is in metres",
    )
    p.add_argument(
        "--templates", default=None, help="template directory (default: package models)"
    )
    p.add_argument(
        "--settings",
        metavar="FILE",
        help="fitting settings (YAML, as the settings "
        "command prints; knobs left out: defaults); --seed, --method, --mode override",
    )
    p.add_argument(
        "--seed", help="seed of the random restarts (default 0; the same seed gives the same fit)"
    )
    p.add_argument(
        "--method",
        choices=("default", "paper"),
        default=None,
        help="default (default): this package's fitter; paper: the paper's method "
        "implemented literally (slow; the bench's baseline)",
    )
    p.add_argument(
        "--mode",
        choices=("auto", "mounted", "free"),
        default=None,
        help="auto (default): mounting-plane prior, resting poses and random "
        "restarts; mounted: the plane prior only; free: no mounting prior",
    )
    p.add_argument(
        "--sensor-origin",
        nargs="+",
        default=None,
        metavar="X_Y_Z|none",
        help="where the scan was taken from, in the scene's frame (--units); 'none' for a "
        "cloud with no single viewpoint (an accumulated map: no visibility "
        "terms); default: a PCD's VIEWPOINT, else the frame's origin",
    )
    p.add_argument("--json", action="store_true", help="print the ranked candidates as JSON")
    p.add_argument(
        "--suggest-view",
        action="store_true",
        help="for an unsettled click, where the sensor should look from to settle "
        "it (an optical-frame pose in the scene's frame; bounds: fit.viewpoint.*)",
    )
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("settings", help="print the fitting settings (YAML): defaults or a file's")
    p.add_argument("file", nargs="?", help="a settings file to check and print in full")
    which = p.add_mutually_exclusive_group()
    which.add_argument(
        "--node-params", action="store_true", help="the node's parameter file instead"
    )
    which.add_argument(
        "--markdown",
        nargs="?",
        const="fit",
        choices=("fit", "node", "station"),
        help="a table of msg_docs/README.md instead: the engine node's fit.* parameters (fit, "
        "the default), its other parameters (node) or the station's (station)",
    )
    p.set_defaults(func=cmd_settings)

    p = sub.add_parser("simulate", help="render a simulated taskboard scan with ground truth")
    p.add_argument(
        "--out", type=path_arg, required=True, help="output folder (scene.ply, truth.yaml, ...)"
    )
    p.add_argument("--seed", default="0", help="the simulated scene (default 0)")
    p.add_argument(
        "--layout",
        choices=("panel", "table"),
        default="panel",
        help="panel (default): objects mounted on a wall panel; table: lying on a "
        "table in resting poses",
    )
    p.add_argument(
        "--templates", default=None, help="template directory (default: package models)"
    )
    p.add_argument(
        "--faults",
        action="store_true",
        help="what real depth cameras do: flying pixels on depth edges, a smooth "
        "depth distortion, dropouts on dark patches and at grazing angles, more "
        "range noise (evaluation.simulation.FaultModel's defaults)",
    )
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("bench", help="speed and accuracy against baselines, in one run")
    p.add_argument("--quick", action="store_true", help="4 scenes, paper method on 5 clicks")
    p.add_argument("--scenes", type=int, default=None, help="panel scenes (default 20)")
    p.add_argument(
        "--paper-clicks",
        type=int,
        default=None,
        help="clicks for the slow paper baseline (default 25; 0 = all)",
    )
    p.add_argument(
        "--out",
        type=path_arg,
        default="bench_output",
        metavar="DIR",
        help="folder for the results (benchmark.json), the settings they were measured with "
        "(benchmark.settings.yaml) and their rendering (BENCHMARK.md); default bench_output",
    )
    p.add_argument(
        "--row",
        choices=("viewpoint", "trust", "browser-operator"),
        help="run that row alone and print it (browser-operator: the scripted operator in the "
        "browser, on 2 simulated taskboards and 6 shared real scans; --quick: 1 and 2)",
    )
    p.add_argument(
        "--all-composites",
        action="store_true",
        help="the trust rows on every composite seed (20 development and 20 held-out of each "
        "kind), not a sample of 5 + 5",
    )
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser(
        "trust",
        help="click every labelled object of composite (or learn) real scenes and judge the "
        "shown fit against the labels (needs the shared mOSD scans)",
    )
    p.add_argument(
        "--kind",
        choices=("mixed", "complex", "learn"),
        default="mixed",
        help="composite scenes of several learn scenes' objects (mixed, complex) or the learn "
        "scenes themselves; default mixed",
    )
    p.add_argument(
        "--seeds",
        default="0-19",
        help="composite seeds: N, N-M, comma-separated (development 0-19, held-out 100-119)",
    )
    p.add_argument(
        "--out", type=path_arg, required=True, help="the JSON file of every click's record"
    )
    p.add_argument(
        "--refined", action="store_true", help="also score each fit refined on the labels"
    )
    p.add_argument(
        "--save", type=path_arg, help="a folder to write the composite scenes into (PCD)"
    )
    p.set_defaults(func=cmd_trust)

    p = sub.add_parser(
        "demo",
        help="the main job: replay the bundled operator session into a "
        "live engine node, print the results, write demo_output/; its nodes run in a ROS "
        "domain of their own unless ROS_DOMAIN_ID is set (it says which)",
    )
    p.add_argument("--session", default=None, help="a recorded session (default: the bundled one)")
    p.add_argument(
        "--out", type=path_arg, default="demo_output", help="output folder (default demo_output)"
    )
    p.add_argument(
        "--core",
        action="store_true",
        help="no ROS: a simulated operator on the core engine in this process",
    )
    p.add_argument("--seed", default="7", help="with --core: the simulated scene (default 7)")
    p.add_argument(
        "--templates",
        default=None,
        help="with --core: template directory (default: package models)",
    )
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser(
        "session",
        help="record a simulated operator session (scene, engine node, "
        "operator over ROS) as a rosbag2 bag",
    )
    p.add_argument("--out", type=path_arg, required=True, help="folder for the bag and truth.yaml")
    p.add_argument("--seed", default="7", help="the simulated scene (default 7)")
    p.set_defaults(func=cmd_session)

    _add_station_and_tool_parsers(sub)
    return parser


def _add_station_and_tool_parsers(sub) -> None:
    """The ``station``, ``bag``, ``launch``, ``spacemouse`` and ``generate-models`` commands."""
    p = sub.add_parser(
        "station",
        help="the browser operator station (viser), a client of the "
        "engine node; --demo: with an engine and a simulated scan (--demo and --scene run "
        "their nodes in a ROS domain of their own unless ROS_DOMAIN_ID is set, and say which)",
    )
    p.add_argument(
        "--demo",
        action="store_true",
        help="also start an engine node and a simulated taskboard scan",
    )
    p.add_argument(
        "--scene",
        default=None,
        metavar="FILE",
        help="also start an engine node and publish this PLY, PCD or .npy scan: "
        "look at it, click, correct, accept and save (no sensor needed)",
    )
    p.add_argument(
        "--units",
        choices=("m", "cm", "mm"),
        default="m",
        help="with --scene: units of the file (default m)",
    )
    # the station's own knobs, declared once (ros/station/parameters.py): --up, --port, --host
    from .ros.station.parameters import add_options

    add_options(p)
    p.add_argument("--seed", default="7", help="with --demo: the simulated scene (default 7)")
    p.add_argument(
        "--first-view",
        default="camera",
        metavar="KIND:TEMPLATE",
        help="with --demo: where the sensor starts: camera (default) or a hard view "
        "of one object, e.g. edge-on:quarter_turn_valve (try Move sensor here)",
    )
    p.add_argument(
        "--out",
        type=path_arg,
        default="station_output",
        help="with --demo or --scene: registrations file and node logs (default station_output)",
    )
    p.set_defaults(func=cmd_station)

    add_bag_parser(sub, cmd_bag)

    p = sub.add_parser("launch", help="start the nodes of a ROS 2 YAML launch file")
    p.add_argument("file", help="a *.launch.yaml file")
    p.add_argument("arguments", nargs="*", help="launch arguments NAME:=VALUE")
    profile = p.add_mutually_exclusive_group()
    profile.add_argument(
        "--shm",
        action="store_true",
        help="use the package's Fast DDS profile (shared memory, localhost)",
    )
    profile.add_argument("--fastdds-profile", default=None, help="a Fast DDS XML profile to use")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("spacemouse", help="SpaceMouse devices")
    p.add_argument(
        "--list",
        action="store_true",
        required=True,
        help="print the attached 3Dconnexion 6-DoF devices",
    )
    p.set_defaults(func=cmd_spacemouse)

    p = sub.add_parser("generate-models", help="regenerate the taskboard templates (STL + YAML)")
    p.add_argument("--out", type=path_arg, default="models", help="output folder (default models)")
    p.set_defaults(func=cmd_generate_models)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if sys.stdout is None:  # (started with stdout closed: nothing could be said)
        return _fail("standard output is closed: nothing done")
    try:
        code = args.func(args)
        sys.stdout.flush()  # (stdout on a full disk: said here, not at exit)
        return code
    except AffordanceError as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        return 130
    except MemoryError:
        return _fail("out of memory")
    except OSError as exc:  # a path that cannot be read or written, a full disk
        quiet_stdout()
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        return _fail(f"{where}{exc.strerror or exc}")
    except Exception as exc:  # a bug: still one line (AFFORDANCE_DEBUG=1 shows where)
        if os.environ.get("AFFORDANCE_DEBUG"):
            raise
        text = str(exc).splitlines()[0] if str(exc) else ""
        return _fail(
            f"internal error: {exc.__class__.__name__}: {text} (please report it; "
            f"AFFORDANCE_DEBUG=1 shows the traceback)"
        )


if __name__ == "__main__":
    sys.exit(main())
