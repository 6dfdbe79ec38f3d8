# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Generate and build the interfaces the package uses that have no wheel into a Python prefix.

    python -m affordance_registration.ros.standins.interfaces.build [--prefix PREFIX]

ROS 2 Jazzy's PyPI wheels bring rclpy and the common message packages but not tf2_msgs (TF),
moveit_msgs (the planning scene's CollisionObject, with the object_recognition_msgs/ObjectType it
nests) or vision_msgs (Detection3DArray), so the pip-only install builds the messages it uses of
them here -- :data:`PACKAGES`, from the definitions in the package folders beside this file,
written from the published Jazzy ones -- the way ``rosidl_generate_interfaces`` would in a colcon
workspace: the rosidl generators (C, Python, type descriptions) and typesupports (C, Fast DDS,
introspection) from the wheels that ``ros-jazzy-rclpy`` installs (pinned in setup.py's ``ros``
extra) write the sources, gcc/g++ compile them, and the result lands where the wheels put their own
message packages: ``lib/lib<pkg>__*.so`` (the wheels' start-up hook puts ``PREFIX/lib`` on the
library path, where the typesupport dispatch looks for them), the Python package in site-packages
(its extension modules find their libraries by rpath), ``share/<package>`` and the ament index.
``from tf2_msgs.msg import TFMessage`` then works, with Jazzy's type hash, and talks to tf2_ros
nodes anywhere (so do the others, with MoveIt's move_group and any vision_msgs reader). A package
is built after those of its dependencies built here.

The generator classes are called directly instead of through ``rosidl generate``: the
rosidl_generator_py wheel declares its entry point twice, which the command's strict entry-point
lookup refuses; and .msg files are translated with rosidl_adapter's converter directly (its
command-line wrapper needs catkin_pkg only to locate a package.xml).

Prints one line. Exit status 0 when built, or when the packages already come from elsewhere (a
ROS install); otherwise ``tf2_msgs not built: REASON (...)`` and exit status 1, and the prefix is
left as it was (everything is built in a temporary directory first).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import os
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Interfaces:
    """A message package built here: its ``name``, the ``messages`` it is built with (only what
    the package uses) and the packages they nest (``dependencies``: wheels, or built here
    first)."""

    name: str
    messages: tuple
    dependencies: tuple


#: what is built, in order (a package after the ones it nests)
PACKAGES = (
    Interfaces(
        "tf2_msgs", ("TFMessage", "TF2Error"), ("geometry_msgs", "std_msgs", "builtin_interfaces")
    ),
    Interfaces("object_recognition_msgs", ("ObjectType",), ()),
    Interfaces(
        "moveit_msgs",
        ("CollisionObject",),
        (
            "object_recognition_msgs",
            "shape_msgs",
            "geometry_msgs",
            "std_msgs",
            "builtin_interfaces",
        ),
    ),
    Interfaces(
        "vision_msgs",
        ("ObjectHypothesis", "BoundingBox3D", "ObjectHypothesisWithPose", "Detection3D")
        + ("Detection3DArray",),
        ("geometry_msgs", "std_msgs", "builtin_interfaces"),
    ),
)
TYPESUPPORTS = (
    "rosidl_typesupport_c",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_introspection_c",
)
SOURCE_DIR = Path(__file__).resolve().parent

__all__ = ["BuildError", "Interfaces", "PACKAGES", "build", "main"]


class BuildError(Exception):
    """Why the interfaces could not be built (one line)."""


def _site_packages(prefix: Path) -> Path:
    return Path(sysconfig.get_path("platlib", vars={"base": str(prefix), "platbase": str(prefix)}))


def _external(package: str, prefix: Path) -> str | None:
    """Where ``package`` is importable from, if not from ``prefix`` (a ROS install's)."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.origin:
        return None
    origin = Path(spec.origin).resolve()
    return None if origin.is_relative_to(prefix.resolve()) else str(origin.parent)


def generate(pkg: Interfaces, include_roots: list, out: Path) -> Path:
    """Write the generated sources of ``pkg`` under ``out`` (one folder per generator), the
    interfaces it nests found in ``include_roots`` (``share`` folders); returns the folder of
    the type descriptions (JSON)."""
    with contextlib.redirect_stdout(io.StringIO()):  # the generators narrate every file
        from rosidl_adapter.msg import convert_msg_to_idl
        from rosidl_generator_c.cli import GenerateC
        from rosidl_generator_py.cli import GeneratePython
        from rosidl_generator_type_description.cli import HashTypeDescription
        from rosidl_typesupport_c.cli import GenerateCTypesupport
        from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
        from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

        name = pkg.name
        idl_root = out / "idl"
        idl_files = []
        for message in pkg.messages:
            idl = convert_msg_to_idl(
                SOURCE_DIR / name, name, Path("msg") / f"{message}.msg", idl_root / "msg"
            )
            idl_files.append(f"{idl_root}:msg/{idl.name}")
        include_paths = [
            str(next((root / dep for root in include_roots if (root / dep).is_dir()), dep))
            for dep in pkg.dependencies
        ]
        descriptions = out / "type_description"
        hashes = HashTypeDescription("type_description").generate_type_hashes(
            name, idl_files, include_paths, output_path=descriptions
        )
        # each generator writes under out/<kind>/<pkg> so that includes read "<pkg>/msg/..."
        GenerateC("c").generate(
            name, idl_files, include_paths, out / "c" / name, type_description_files=hashes
        )
        for kind, extension in (
            ("typesupport_c", GenerateCTypesupport),
            ("fastrtps_c", GenerateFastRTPSCTypesupport),
            ("introspection_c", GenerateIntrospectionCTypesupport),
            ("py", GeneratePython),
        ):
            extension(kind).generate(name, idl_files, include_paths, out / kind / name)
    return descriptions


def _compiler(variable: str, default: str) -> list[str]:
    command = shlex.split(os.environ.get(variable, default)) or [default]
    if shutil.which(command[0]) is None:
        raise BuildError(
            f"no {'C++' if variable == 'CXX' else 'C'} compiler '{command[0]}' "
            f"(apt-get install {'g++' if variable == 'CXX' else 'gcc'})"
        )
    return command


def _run(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        lines = [ln for ln in (done.stderr + done.stdout).splitlines() if "error" in ln.lower()]
        detail = (lines or (done.stderr + done.stdout).strip().splitlines() or ["(no output)"])[0]
        raise BuildError(f"{Path(command[0]).name} failed: {detail.strip()[:300]}")


def _python_include() -> Path:
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        raise BuildError(f"no Python headers in {include} (apt-get install python3-dev)")
    return include


def compile_sources(
    pkg: Interfaces,
    ros_prefix: Path,
    gen_root: Path,
    stage: Path,
    site_rel: Path,
    cc: list[str],
    cxx: list[str],
) -> None:
    """Compile the sources generated for ``pkg`` (under ``gen_root/<pkg>``; those of packages
    built before it beside them) into ``stage`` laid out like the prefix (``lib/`` and
    ``site_rel/<pkg>``) with the compilers ``cc`` and ``cxx`` (command lines)."""
    python_include = _python_include()
    import numpy

    name = pkg.name
    gen = gen_root / name
    ros_include = ros_prefix / "include"
    includes = (
        [
            g / kind
            for g in sorted(gen_root.iterdir())
            for kind in ("c", "fastrtps_c", "introspection_c")
        ]
        + [ros_include]
        + sorted(p for p in ros_include.iterdir() if p.is_dir())
    )
    lib = stage / "lib"
    pkg_dir = stage / site_rel / name
    lib.mkdir(parents=True, exist_ok=True)
    pkg_dir.mkdir(parents=True)
    flags = ["-O2", "-fPIC", "-shared", "-w"] + [f"-I{p}" for p in includes]
    lib_dirs = [f"-L{ros_prefix / 'lib'}", f"-L{lib}"]
    own = f"-l{name}__rosidl_generator_c"

    def deps(kind: str) -> list[str]:
        return [f"-l{dep}__{kind}" for dep in pkg.dependencies]

    def library(compiler, kind, sources, libs, extra=()):
        return (
            compiler
            + flags
            + list(extra)
            + [str(s) for s in sorted(sources)]
            + ["-o", str(lib / f"lib{name}__{kind}.so")]
            + lib_dirs
            + ["-Wl,-rpath,$ORIGIN"]
            + libs
            + ["-lrosidl_runtime_c", "-lrcutils"]
        )

    msg = Path(name) / "msg"
    first = library(
        cc,
        "rosidl_generator_c",
        (gen / "c" / msg / "detail").glob("*.c"),
        deps("rosidl_generator_c"),
    )
    cxx17 = cxx + ["-std=c++17"]
    libraries = [
        library(
            cc,
            "rosidl_typesupport_introspection_c",
            (gen / "introspection_c" / msg / "detail").glob("*.c"),
            [own]
            + deps("rosidl_typesupport_introspection_c")
            + ["-lrosidl_typesupport_introspection_c"],
        ),
        library(
            cxx17,
            "rosidl_typesupport_fastrtps_c",
            (gen / "fastrtps_c" / msg / "detail").glob("*.cpp"),
            [own]
            + deps("rosidl_typesupport_fastrtps_c")
            + deps("rosidl_generator_c")
            + [
                "-lrosidl_typesupport_fastrtps_c",
                "-lrosidl_typesupport_fastrtps_cpp",
                "-lfastcdr",
                "-lrmw",
            ],
        ),
        library(
            cxx17,
            "rosidl_typesupport_c",
            (gen / "typesupport_c" / msg).glob("*.cpp"),
            [own, "-lrosidl_typesupport_c", "-lrcpputils"],
        ),
        library(
            cc,
            "rosidl_generator_py",
            (gen / "py" / msg).glob("*_s.c"),
            [own] + deps("rosidl_generator_c") + deps("rosidl_generator_py"),
            extra=[f"-I{python_include}", f"-I{numpy.get_include()}"],
        ),
    ]
    # the Python extension modules, one per typesupport, find lib/ relative to themselves
    to_lib = os.path.relpath(stage / "lib", pkg_dir)
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    modules = [
        cc
        + flags
        + [
            f"-I{python_include}",
            str(gen / "py" / name / f"_{name}_s.ep.{ts}.c"),
            "-o",
            str(pkg_dir / f"{name}_s__{ts}{suffix}"),
        ]
        + lib_dirs
        + [
            f"-Wl,-rpath,$ORIGIN/{to_lib}",
            f"-l{name}__rosidl_generator_py",
            f"-l{name}__{ts}",
            own,
            "-lrosidl_runtime_c",
            "-lrcutils",
        ]
        for ts in TYPESUPPORTS
    ]
    _run(first)
    with ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1))) as pool:
        list(pool.map(_run, libraries))
        list(pool.map(_run, modules))
    (pkg_dir / "__init__.py").write_text("")
    shutil.copytree(
        gen / "py" / name / "msg", pkg_dir / "msg", ignore=shutil.ignore_patterns("*.c")
    )


def stage_share(pkg: Interfaces, gen: Path, descriptions: Path, stage: Path) -> None:
    """The definitions (.msg, .idl, .json) and the ament index entries of ``pkg``."""
    share = stage / "share" / pkg.name / "msg"
    share.mkdir(parents=True)
    files = []
    for name in pkg.messages:
        for src in (
            SOURCE_DIR / pkg.name / "msg" / f"{name}.msg",
            gen / "idl" / "msg" / f"{name}.idl",
            descriptions / "msg" / f"{name}.json",
        ):
            shutil.copy2(src, share / src.name)
            if src.suffix != ".json":
                files.append(f"msg/{src.name}")
    index = stage / "share" / "ament_index" / "resource_index"
    (index / "packages").mkdir(parents=True, exist_ok=True)
    (index / "packages" / pkg.name).write_text("")
    (index / "rosidl_interfaces").mkdir(exist_ok=True)
    (index / "rosidl_interfaces" / pkg.name).write_text("\n".join(files) + "\n")


def install(stage: Path, prefix: Path, site_rel: Path, packages) -> None:
    """Copy the staged tree into the prefix; each Python package is replaced whole."""
    for pkg in packages:
        target_pkg = prefix / site_rel / pkg.name
        if target_pkg.exists():
            shutil.rmtree(target_pkg)
    for src in sorted(p for p in stage.rglob("*") if p.is_file()):
        dst = prefix / src.relative_to(stage)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.tmp")
        shutil.copy2(src, tmp)
        os.replace(tmp, dst)  # a running process keeps the library it has mapped


def build(prefix: Path, ros_prefix: Path | None = None, force: bool = False) -> str:
    """Generate, compile and install :data:`PACKAGES` into ``prefix``; returns what was done
    (one line). ``ros_prefix``: where the ROS wheels are (default: this interpreter's prefix);
    ``force``: build even the packages importable from elsewhere."""
    prefix = prefix.resolve()
    ros_prefix = (ros_prefix or Path(sys.prefix)).resolve()
    external = {} if force else {p.name: _external(p.name, prefix) for p in PACKAGES}
    todo = [p for p in PACKAGES if not external.get(p.name)]
    elsewhere = [f"{name} from {where}" for name, where in external.items() if where]
    if not todo:
        return f"interfaces: using {', '.join(elsewhere)} (nothing to build)"
    if not (ros_prefix / "share" / "rosidl_generator_c").is_dir():
        raise BuildError(
            f"the rosidl wheels are not installed in {ros_prefix} (pip install -e '.[ros]')"
        )
    site_rel = _site_packages(prefix).relative_to(prefix)
    cc, cxx = _compiler("CC", "gcc"), _compiler("CXX", "g++")
    _python_include()
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join(
        [str(ros_prefix)]
        + [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    )
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="interfaces_build_") as tmp:
        gen_root, stage = Path(tmp) / "gen", Path(tmp) / "stage"
        # the interfaces a package nests: built here first (staged), else the wheels'
        include_roots = [stage / "share", ros_prefix / "share", prefix / "share"]
        for pkg in todo:
            missing = [
                dep
                for dep in pkg.dependencies
                if not any((r / dep).is_dir() for r in include_roots)
            ]
            if missing:
                raise BuildError(
                    f"{pkg.name} needs {', '.join(missing)}, which is not installed "
                    f"(pip install -e '.[ros]')"
                )
            gen = gen_root / pkg.name
            try:
                descriptions = generate(pkg, include_roots, gen)
            except BuildError:
                raise
            except Exception as exc:  # the generators raise whatever their templates raise
                raise BuildError(
                    f"generating the sources of {pkg.name} failed: {exc!r}"[:300]
                ) from None
            compile_sources(pkg, ros_prefix, gen_root, stage, site_rel, cc, cxx)
            stage_share(pkg, gen, descriptions, stage)
        install(stage, prefix, site_rel, todo)
    built = "; ".join(f"{p.name} ({', '.join(p.messages)})" for p in todo)
    also = f"; using {', '.join(elsewhere)}" if elsewhere else ""
    return f"interfaces: built {built} into {prefix} ({time.monotonic() - t0:.1f} s){also}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--prefix",
        default=sys.prefix,
        help="install prefix (default: this interpreter's, i.e. the venv)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="build even the packages importable from elsewhere",
    )
    args = parser.parse_args(argv)
    try:
        sys.stdout.write(f"{build(Path(args.prefix), force=args.force)}\n")
        return 0
    except (BuildError, OSError) as exc:
        others = ", ".join(p.name for p in PACKAGES[1:])
        sys.stdout.write(
            f"tf2_msgs not built: {exc} (nor {others}); the engine node runs without TF "
            f"output, collision objects and detections\n"
        )
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
