# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Runs a ROS 2 YAML launch file (the format ``ros2 launch`` reads) without the ros2 CLI.

Supported (what the package's own launch files and typical operator stations use)::

    launch:
    - arg: {name: points, default: /camera/depth/points}
    - arg: {name: params, default: affordance_engine.params.yaml}
    - node:
        pkg: affordance_registration
        exec: affordance_engine
        name: affordance_engine
        namespace: ""
        output: screen
        args: "--some --extra"
        param:
        - from: $(find-pkg-share affordance_registration)/launch_configs/$(var params)
        - {name: refit_idle_s, value: 0.5}
        remap:
        - {from: points, to: $(var points)}

Substitutions: ``$(var NAME)``, ``$(env NAME [DEFAULT])``, ``$(find-pkg-share PKG)``. Launch
arguments are given as ``NAME:=VALUE`` on the command line. Executables are found on PATH (a venv's
console scripts) or under ``lib/PKG`` of an ament prefix. Ctrl-C (SIGINT) or SIGTERM stops every
node: SIGINT first, SIGTERM after ``grace`` seconds (5, as ``ros2 launch``'s sigterm_timeout),
SIGKILL after another ``grace``; a node that did not end cleanly is named with its exit code or
signal.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ...core.errors import AffordanceError
from ...core.files import read_yaml

__all__ = ["LaunchError", "NodeAction", "parse_launch_file", "Launcher", "package_share"]

PACKAGE = "affordance_registration"
CLEAN_EXIT = (0, -signal.SIGINT, 130)  # ended on its own, or on our SIGINT
SIGNALS = {s.value for s in signal.Signals}


class LaunchError(AffordanceError):
    """The launch file cannot be read or run (the message names the file and entry)."""


@dataclass
class NodeAction:
    pkg: str
    executable: str
    name: str | None = None
    namespace: str | None = None
    params: list = field(default_factory=list)  # ("file", path) | ("value", name, value)
    remaps: list = field(default_factory=list)  # (from, to)
    args: list = field(default_factory=list)
    output: str = "screen"

    def command(self) -> list[str]:
        cmd = [find_executable(self.pkg, self.executable)] + list(self.args) + ["--ros-args"]
        if self.name:
            cmd += ["-r", f"__node:={self.name}"]
        if self.namespace:
            cmd += ["-r", f"__ns:=/{self.namespace.strip('/')}"]
        for p in self.params:
            if p[0] == "file":
                cmd += ["--params-file", p[1]]
            else:
                cmd += ["-p", f"{p[1]}:={_param_text(p[2])}"]
        for src, dst in self.remaps:
            cmd += ["-r", f"{src}:={dst}"]
        return cmd


def _param_text(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, dict)):
        return yaml.safe_dump(value, default_flow_style=True).strip()
    # rcl reads an override's value as YAML and refuses an empty one: '""' is the empty string
    # (what ros2 launch passes for a value that substitutes to nothing)
    return str(value) if str(value) != "" else '""'


def package_share(pkg: str) -> str:
    """The share directory of a package: ament index, else (this package) its source tree or
    ``<prefix>/share/<pkg>``."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return get_package_share_directory(pkg)
    except Exception:
        pass
    if pkg == PACKAGE:
        # the source tree: affordance_registration/ros/standins/ is three folders below it
        here = str(Path(__file__).resolve().parents[3])
        if os.path.isfile(os.path.join(here, "package.xml")):
            return here
        share = os.path.join(sys.prefix, "share", PACKAGE)
        if os.path.isdir(share):
            return share
    raise LaunchError(f"package '{pkg}' not found (no ament index entry)")


def find_executable(pkg: str, executable: str) -> str:
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        candidate = os.path.join(prefix, "lib", pkg, executable)
        if prefix and os.access(candidate, os.X_OK):
            return candidate
    venv_bin = os.path.dirname(sys.executable)
    for folder in (venv_bin, None):
        found = shutil.which(executable, path=folder) if folder else shutil.which(executable)
        if found:
            return found
    raise LaunchError(
        f"executable '{executable}' of package '{pkg}' not found on PATH or "
        f"under lib/{pkg} of AMENT_PREFIX_PATH"
    )


#: nesting depth of substitutions inside substitutions ($(find-pkg-share $(var pkg)) is 2)
MAX_SUBSTITUTION_DEPTH = 16
#: a launch file larger than this is not one (bytes)
MAX_LAUNCH_BYTES = 1_000_000


def substitute(text, variables: dict, where: str, depth: int = 0):
    """Resolve ``$(var NAME)``, ``$(env NAME [default])`` and ``$(find-pkg-share PKG)`` in
    ``text``, nested ones inside out. What a substitution yields is used as it is, never
    resolved again (an environment variable holding ``$(env X)`` stays that text), so every
    substitution terminates."""
    if not isinstance(text, str):
        return text
    out, i = [], 0
    while True:
        j = text.find("$(", i)
        if j < 0:
            out.append(text[i:])
            return "".join(out)
        out.append(text[i:j])
        k, level = j + 2, 1  # the matching ')'
        while k < len(text) and level:
            if text.startswith("$(", k):
                level, k = level + 1, k + 2
                continue
            level -= text[k] == ")"
            k += 1
        if level:
            raise LaunchError(f"{where}: unclosed substitution in {text!r}")
        if depth >= MAX_SUBSTITUTION_DEPTH:
            raise LaunchError(
                f"{where}: substitutions nested deeper than {MAX_SUBSTITUTION_DEPTH} levels"
            )
        inner = substitute(text[j + 2 : k - 1], variables, where, depth + 1)
        out.append(_resolve(inner.split(), variables, where))
        i = k


def _resolve(words: list[str], variables: dict, where: str) -> str:
    kind, args = (words[0], words[1:]) if words else ("", [])
    if kind == "var":
        if not args or args[0] not in variables:
            raise LaunchError(f"{where}: unknown launch argument '{args[0] if args else ''}'")
        return str(variables[args[0]])
    if kind == "env":
        if not args:
            raise LaunchError(f"{where}: $(env) needs a variable name")
        if args[0] in os.environ:
            return os.environ[args[0]]
        if len(args) > 1:
            return " ".join(args[1:])
        raise LaunchError(f"{where}: environment variable '{args[0]}' is not set")
    if kind == "find-pkg-share":
        if not args:
            raise LaunchError(f"{where}: $(find-pkg-share) needs a package name")
        return package_share(args[0])
    raise LaunchError(f"{where}: unsupported substitution $({kind})")


def _entries(body: dict, key: str, where: str) -> list[dict]:
    """The list of mappings under ``key`` of a node (param, remap)."""
    value = body.get(key) or []
    if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
        raise LaunchError(f"{where}: '{key}' must be a list of mappings")
    return value


def parse_launch_file(path: str, arguments: dict | None = None) -> list[NodeAction]:
    """Parse a YAML launch file into node actions (arguments resolved)."""
    doc = read_yaml(path, LaunchError, max_bytes=MAX_LAUNCH_BYTES, kind="launch file")
    if not isinstance(doc, dict) or not isinstance(doc.get("launch"), list):
        raise LaunchError(f"{path}: expected a top-level 'launch:' list")
    given = dict(arguments or {})
    variables: dict = {}
    nodes = []
    for i, entry in enumerate(doc["launch"]):
        where = f"{path}: launch[{i}]"
        if not isinstance(entry, dict) or len(entry) != 1:
            raise LaunchError(f"{where}: each entry is one action (arg or node)")
        ((kind, body),) = entry.items()
        if not isinstance(body, dict):
            raise LaunchError(f"{where}: {kind!r} needs a mapping, got {body!r}"[:300])
        if kind == "arg":
            name = body.get("name")
            if not name or not isinstance(name, str):
                raise LaunchError(f"{where}: arg needs a name")
            if name in given:
                variables[name] = given.pop(name)
            elif "default" in body:
                variables[name] = substitute(str(body["default"]), variables, where)
            else:
                raise LaunchError(
                    f"{where}: launch argument '{name}' has no default; give it as {name}:=VALUE"
                )
        elif kind == "node":
            if "pkg" not in body or "exec" not in body:
                raise LaunchError(f"{where}: node needs 'pkg' and 'exec'")
            for key in ("pkg", "exec", "name", "namespace"):
                if body.get(key) is not None and not isinstance(body[key], str):
                    raise LaunchError(f"{where}: node '{key}' must be text, got {body[key]!r}")
            sub = lambda v: substitute(v, variables, where)
            node = NodeAction(
                pkg=sub(body["pkg"]),
                executable=sub(body["exec"]),
                name=sub(body.get("name")),
                namespace=sub(body.get("namespace")),
                output=body.get("output", "screen"),
            )
            for p in _entries(body, "param", where):
                if "from" in p:
                    file_path = sub(p["from"])
                    if not os.path.isfile(file_path):
                        raise LaunchError(f"{where}: parameter file not found: {file_path}")
                    # read by the one YAML loader before a node starts: a file that is not
                    # YAML, or an alias bomb, is one line here (rcl refuses aliases itself)
                    read_yaml(
                        file_path,
                        LaunchError,
                        label=f"{where}: parameter file {file_path}",
                        max_bytes=MAX_LAUNCH_BYTES,
                        kind="parameter file",
                    )
                    node.params.append(("file", file_path))
                elif "name" in p and "value" in p:
                    node.params.append(("value", p["name"], sub(p["value"])))
                else:
                    raise LaunchError(f"{where}: a param needs 'from' or 'name' and 'value'")
            for r in _entries(body, "remap", where):
                if "from" not in r or "to" not in r:
                    raise LaunchError(f"{where}: a remap needs 'from' and 'to'")
                node.remaps.append((sub(r["from"]), sub(r["to"])))
            args = body.get("args")
            if args:
                node.args = sub(str(args)).split()
            nodes.append(node)
        else:
            raise LaunchError(f"{where}: unsupported action {kind!r} (arg and node are supported)")
    if given:
        raise LaunchError(f"{path}: unknown launch argument(s): {', '.join(map(repr, given))}")
    return nodes


class Launcher:
    """Starts the nodes of a launch file and stops them together."""

    def __init__(
        self,
        nodes: list[NodeAction],
        env: dict | None = None,
        grace: float = 5.0,
        log=None,
        output=None,
    ):
        self.nodes = nodes
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        self.grace = grace
        self.procs: list[subprocess.Popen] = []
        self.log = log or (lambda msg: sys.stderr.write(msg + "\n"))
        self.output = output  # a file for every node's output (None: as the launch file says)

    def start(self) -> None:
        """Start every node: every executable is found first (a missing one starts none);
        where one still cannot be started, the ones already started are stopped before the
        error is raised -- none is left running."""
        commands = [node.command() for node in self.nodes]
        try:
            for node, cmd in zip(self.nodes, commands):
                self.log(f"[launch] starting {node.name or node.executable}: {' '.join(cmd)}")
                out = None if node.output == "screen" else subprocess.DEVNULL
                if self.output is not None:
                    out = self.output
                self.procs.append(
                    subprocess.Popen(
                        cmd, env=self.env, stdout=out, stderr=subprocess.STDOUT if out else None
                    )
                )
        except BaseException:
            self.stop()
            raise

    def wait(self, stop_requested) -> int:
        """Run until every node exits or ``stop_requested()`` is true; returns an exit code."""
        while not stop_requested():
            if all(p.poll() is not None for p in self.procs):
                break
            time.sleep(0.1)
        return self.stop()

    def stop(self) -> int:
        """SIGINT every node still running; SIGTERM what is left after ``grace`` seconds,
        SIGKILL after another ``grace``. Logs each node that did not end cleanly (its exit
        code or signal, and the escalation it needed); returns 0 only if every node ended on
        its own or on SIGINT."""
        sent: dict[int, str] = {}
        for sig, wait in (
            (signal.SIGINT, self.grace),
            (signal.SIGTERM, self.grace),
            (signal.SIGKILL, self.grace),
        ):
            alive = [p for p in self.procs if p.poll() is None]
            if not alive:
                break
            for p in alive:
                with contextlib.suppress(ProcessLookupError):
                    p.send_signal(sig)
                sent[p.pid] = sig.name
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline and any(p.poll() is None for p in alive):
                time.sleep(0.05)
        codes = [p.wait() for p in self.procs]
        for node, proc, code in zip(self.nodes, self.procs, codes):
            if code not in CLEAN_EXIT or sent.get(proc.pid) not in (None, "SIGINT"):
                how = (
                    f"signal {signal.Signals(-code).name}"
                    if code < 0 and -code in SIGNALS
                    else f"exit code {code}"
                )
                after = f" after {sent[proc.pid]}" if proc.pid in sent else ""
                self.log(
                    f"[launch] {node.name or node.executable} (pid {proc.pid}) ended with "
                    f"{how}{after}"
                )
        return 0 if all(c in CLEAN_EXIT for c in codes) else 1


def run_launch_file(path: str, arguments: dict, fastdds_profile: str | None = None) -> int:
    """``affordance-registration launch``: start, wait for Ctrl-C / SIGTERM, stop."""
    nodes = parse_launch_file(path, arguments)
    env = dict(os.environ)
    if fastdds_profile:
        if not os.path.isfile(fastdds_profile):
            raise LaunchError(f"Fast DDS profile not found: {fastdds_profile}")
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = os.path.abspath(fastdds_profile)
        env["FASTDDS_DEFAULT_PROFILES_FILE"] = os.path.abspath(fastdds_profile)
        env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    launcher = Launcher(nodes, env)
    stop = {"flag": False}

    def on_signal(signum, frame):
        stop["flag"] = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    launcher.start()
    return launcher.wait(lambda: stop["flag"])
