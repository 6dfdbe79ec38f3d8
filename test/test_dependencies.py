# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Every module the package imports -- at run time (``affordance_registration/``) and in its tests
(``test/``) -- is declared: in package.xml under a rosdep key (exec_depend for run time,
test_depend or exec_depend for the tests) or named in its pip-only comment, and in setup.py (a
pinned requirement, or a dependency of one, as installed in this environment). Every XML file
of the package is well-formed."""

from __future__ import annotations

import ast
import importlib.metadata as md
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: this package, and the test folder's own modules (helpers, tests importing each other)
LOCAL = {"affordance_registration"} | {p.stem for p in (ROOT / "test").glob("*.py")}
#: import name -> its rosdep key (ROS packages: the package name itself)
ROSDEP = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "trimesh": "python3-trimesh-pip",
    "open3d": "python3-open3d-pip",
    "hid": "python3-hidapi",
    "rosbags": "python3-rosbags-pip",
    "lz4": "python3-lz4",
    "PIL": "python3-pil",
    "pytest": "python3-pytest",
    "hypothesis": "python3-hypothesis",
}
ROS_PACKAGES = {
    "rclpy",
    "rcl_interfaces",
    "ament_index_python",
    "sensor_msgs",
    "geometry_msgs",
    "visualization_msgs",
    "std_msgs",
    "std_srvs",
    "tf2_msgs",
    "builtin_interfaces",
    "shape_msgs",
    "moveit_msgs",
    "vision_msgs",
    "object_recognition_msgs",
}
#: built into the venv by ros/standins/interfaces/build.py (no wheel); a ROS install has them
#: (object_recognition_msgs is nested by moveit_msgs, which brings it there)
VENV_BUILT = {"tf2_msgs", "moveit_msgs", "vision_msgs", "object_recognition_msgs"}
#: imported, no rosdep key: named in package.xml's pip-only comments
PIP_ONLY = {
    "viser",
    "pykdtree",
    "numba",
    "threadpoolctl",
    "playwright",
    "small_gicp",
    "colcon_core",
    "ament_package",
    "websockets",
    "msgspec",
    "markdown_it",
}
#: imported only by ros/standins/interfaces/build.py, which builds tf2_msgs into a venv (a ROS
#: install has tf2_msgs): setup.py's INTERFACE_BUILD_REQUIRES, no package.xml entry
VENV_BUILD_ONLY = {
    "rosidl_adapter",
    "rosidl_cli",
    "rosidl_generator_c",
    "rosidl_generator_py",
    "rosidl_generator_type_description",
    "rosidl_typesupport_c",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_introspection_c",
}
#: declared, not imported, and why
NOT_IMPORTED = {
    "rmw_fastrtps_cpp": "the RMW implementation the launch files and the Fast DDS profile select",
    "libusb-1.0": "a system library open3d's wheel links against",
    "builtin_interfaces": "the stamps of every message; a dependency of the tf2_msgs "
    "the venv build makes",
}
#: imported when present, else done without: module -> its rosdep key
OPTIONAL = {
    "tf2_ros": "tf2_ros_py",  # ros/glue/tf.py: tf2_ros' buffer, else /tf read directly
    # ros/standins/interactive.py: its server, else the package's own
    "interactive_markers": "interactive_markers",
    # launch/engine.launch.py: `ros2 launch` in a ROS install (the pip-only install starts the
    # YAML launch files with `affordance-registration launch`)
    "launch": "launch",
    "launch_ros": "launch_ros",
}


def _imports(folder: Path) -> dict[str, set[str]]:
    """Top-level module -> the files importing it (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for path in sorted(folder.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in LOCAL:
                    found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


def _package_xml() -> tuple[dict[str, set[str]], str]:
    root = ET.parse(ROOT / "package.xml").getroot()
    deps: dict[str, set[str]] = {}
    for e in root:
        if isinstance(e.tag, str) and e.tag.endswith("depend"):
            deps.setdefault(e.tag, set()).add(e.text.strip())
    comments = (ROOT / "package.xml").read_text()
    pip_text = " ".join(re.findall(r"<!--(.*?)-->", comments, re.S))
    return deps, pip_text


def canonicalize_name(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


class Requirement:
    """A requirement string's name, extras and marker (the subset of PEP 508 setup.py and the
    installed metadata use here)."""

    def __init__(self, text: str):
        spec, _, self.marker = (part.strip() for part in text.partition(";"))
        m = re.match(r"([A-Za-z0-9._-]+)\s*(?:\[([^\]]*)\])?", spec)
        self.name = m.group(1)
        self.extras = {e.strip() for e in (m.group(2) or "").split(",") if e.strip()}

    def wanted(self, extras: set[str]) -> bool:
        """Platform markers count as met (the closure may grow, never shrink); an
        ``extra == 'x'`` marker only for a requested extra."""
        want = re.findall(r"extra\s*==\s*['\"]([^'\"]+)['\"]", self.marker)
        return not want or any(
            canonicalize_name(w) in {canonicalize_name(e) for e in extras} for w in want
        )


def _setup_requirements() -> list[Requirement]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    reqs: list[str] = []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Assign)
            and isinstance(node.value, ast.List)
            and any(getattr(t, "id", "").endswith("_REQUIRES") for t in node.targets)
        ):
            reqs += ast.literal_eval(node.value)
        if isinstance(node, ast.keyword) and node.arg == "extras_require":
            for value in node.value.values:
                if isinstance(value, ast.List):
                    reqs += [
                        ast.literal_eval(v) for v in value.elts if isinstance(v, ast.Constant)
                    ]
    return [Requirement(r) for r in reqs]


def _closure(reqs: list[Requirement]) -> set[str]:
    """The distributions these requirements bring in, as installed here."""
    seen: set[str] = set()
    todo = list(reqs)
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        if name in seen:
            continue
        seen.add(name)
        try:
            sub = md.requires(req.name) or []
        except md.PackageNotFoundError:
            continue
        todo += [r for r in map(Requirement, sub) if r.wanted(req.extras)]
    return seen


def test_every_import_is_declared_in_package_xml():
    deps, pip_text = _package_xml()
    run_deps = deps.get("exec_depend", set()) | deps.get("depend", set())
    test_deps = run_deps | deps.get("test_depend", set())
    problems = []
    for folder, declared, kind in (
        (ROOT / PACKAGE_DIR, run_deps, "exec_depend"),
        (ROOT / "launch", run_deps, "exec_depend"),
        (ROOT / "test", test_deps, "test_depend"),
    ):
        for module, files in sorted(_imports(folder).items()):
            if module in VENV_BUILD_ONLY:
                if any(
                    f != "affordance_registration/ros/standins/interfaces/build.py" for f in files
                ):
                    problems.append(f"{module}: imported outside interfaces/build.py: {files}")
                continue
            if module in PIP_ONLY:
                if module.replace("_core", "").replace("_", "") not in pip_text.replace(
                    "-", ""
                ).replace("_", ""):
                    problems.append(f"{module} is pip-only but package.xml does not say so")
                continue
            key = module if module in ROS_PACKAGES else ROSDEP.get(module, OPTIONAL.get(module))
            if key is None:
                problems.append(
                    f"{module} (imported by {sorted(files)[0]}) has no rosdep key "
                    f"in this test: declare it in package.xml and here"
                )
            elif key not in declared:
                problems.append(f"{module}: package.xml lacks <{kind}>{key}</{kind}>")
    assert not problems, "\n".join(problems)


def test_every_package_xml_dependency_is_used_or_explained():
    deps, _ = _package_xml()
    imported = (
        set(_imports(ROOT / PACKAGE_DIR))
        | set(_imports(ROOT / "launch"))
        | set(_imports(ROOT / "test"))
    )
    keys = {ROSDEP.get(m, OPTIONAL.get(m, m)) for m in imported}
    declared = set().union(*deps.values())
    unexplained = sorted(declared - keys - set(NOT_IMPORTED))
    assert not unexplained, f"declared in package.xml, never imported: {unexplained}"


def test_every_import_is_installed_by_setup_py():
    """Each imported distribution is a setup.py requirement or comes with one (as installed
    here); tf2_msgs, moveit_msgs and vision_msgs are built into the venv by
    ros/standins/interfaces/build.py."""
    reqs = _setup_requirements()
    named = {canonicalize_name(r.name) for r in reqs}
    closure = _closure(reqs)
    dists = md.packages_distributions()
    problems = []
    for module in sorted(set(_imports(ROOT / PACKAGE_DIR)) | set(_imports(ROOT / "test"))):
        if module in OPTIONAL:
            continue
        if module in VENV_BUILT:
            assert (ROOT / PACKAGE_DIR / "ros" / "standins" / "interfaces" / module).is_dir()
            continue
        names = {canonicalize_name(d) for d in dists.get(module, [])}
        if not names:
            if module == "small_gicp" and "small-gicp" in named:  # the optional bench extra
                continue
            problems.append(f"{module}: not installed here and not named in setup.py")
        elif not names & closure:
            problems.append(
                f"{module} ({', '.join(sorted(names))}) does not come with any "
                f"setup.py requirement"
            )
    assert not problems, "\n".join(problems)


def test_every_xml_file_is_well_formed():
    files = [
        p
        for p in ROOT.rglob("*.xml")
        if not ({".venv", ".git", "build", "install", "log"} & set(p.relative_to(ROOT).parts))
    ]
    assert ROOT / "package.xml" in files and ROOT / "launch_configs" / "fastdds_shm.xml" in files
    for path in files:
        ET.parse(path)  # raises ParseError (naming the line) when it is not well-formed


PACKAGE_DIR = "affordance_registration"
