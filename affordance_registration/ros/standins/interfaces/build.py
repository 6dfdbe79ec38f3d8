# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Generate and build the ``tf2_msgs`` interfaces (TFMessage, TF2Error) into a Python prefix.

    python -m affordance_registration.ros.standins.interfaces.build [--prefix PREFIX]

ROS 2 Jazzy's PyPI wheels bring rclpy and the common message packages but not tf2_msgs, so the
pip-only install builds it here, the way ``rosidl_generate_interfaces`` would in a colcon
workspace: the rosidl generators (C, Python, type descriptions) and typesupports (C, Fast DDS,
introspection) from the wheels that ``ros-jazzy-rclpy`` installs (pinned in setup.py's ``ros``
extra) write the sources, gcc/g++ compile them, and the result lands where the wheels put their
own message packages: ``lib/lib<pkg>__*.so`` (the wheels' start-up hook puts ``PREFIX/lib`` on
the library path, where the typesupport dispatch looks for them), the Python package in
site-packages (its extension modules find their libraries by rpath), ``share/tf2_msgs`` and the
ament index. ``from tf2_msgs.msg import TFMessage`` then works, with Jazzy's type hash, and talks
to tf2_ros nodes anywhere.

The generator classes are called directly instead of through ``rosidl generate``: the
rosidl_generator_py wheel declares its entry point twice, which the command's strict entry-point
lookup refuses; and .msg files are translated with rosidl_adapter's converter directly (its
command-line wrapper needs catkin_pkg only to locate a package.xml).

Prints one line. Exit status 0 when built, or when tf2_msgs already comes from elsewhere (a ROS
install); otherwise ``tf2_msgs not built: REASON`` and exit status 1, and the prefix is left as it
was (everything is built in a temporary directory first).
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
from pathlib import Path

PACKAGE = "tf2_msgs"
MESSAGES = ("TFMessage", "TF2Error")
DEPENDENCIES = ("geometry_msgs", "std_msgs", "builtin_interfaces")  # what TFMessage nests
TYPESUPPORTS = (
    "rosidl_typesupport_c",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_introspection_c",
)
SOURCE_DIR = Path(__file__).resolve().parent / PACKAGE

__all__ = ["BuildError", "build", "main"]


class BuildError(Exception):
    """Why the interfaces could not be built (one line)."""


def _site_packages(prefix: Path) -> Path:
    return Path(sysconfig.get_path("platlib", vars={"base": str(prefix), "platbase": str(prefix)}))


def _external_tf2_msgs(prefix: Path) -> str | None:
    """Where tf2_msgs is importable from, if not from ``prefix`` (a ROS install's)."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.origin:
        return None
    origin = Path(spec.origin).resolve()
    return None if origin.is_relative_to(prefix.resolve()) else str(origin.parent)


def generate(ros_prefix: Path, out: Path) -> Path:
    """Write the generated sources under ``out`` (one folder per generator); returns the folder
    of the type descriptions (JSON)."""
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join(
        [str(ros_prefix)]
        + [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    )
    with contextlib.redirect_stdout(io.StringIO()):  # the generators narrate every file
        from rosidl_adapter.msg import convert_msg_to_idl
        from rosidl_generator_c.cli import GenerateC
        from rosidl_generator_py.cli import GeneratePython
        from rosidl_generator_type_description.cli import HashTypeDescription
        from rosidl_typesupport_c.cli import GenerateCTypesupport
        from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
        from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

        idl_root = out / "idl"
        idl_files = []
        for name in MESSAGES:
            idl = convert_msg_to_idl(
                SOURCE_DIR, PACKAGE, Path("msg") / f"{name}.msg", idl_root / "msg"
            )
            idl_files.append(f"{idl_root}:msg/{idl.name}")
        include_paths = [str(ros_prefix / "share" / dep) for dep in DEPENDENCIES]
        descriptions = out / "type_description"
        hashes = HashTypeDescription("type_description").generate_type_hashes(
            PACKAGE, idl_files, include_paths, output_path=descriptions
        )
        # each generator writes under out/<kind>/tf2_msgs so that includes read "tf2_msgs/msg/..."
        GenerateC("c").generate(
            PACKAGE, idl_files, include_paths, out / "c" / PACKAGE, type_description_files=hashes
        )
        for kind, extension in (
            ("typesupport_c", GenerateCTypesupport),
            ("fastrtps_c", GenerateFastRTPSCTypesupport),
            ("introspection_c", GenerateIntrospectionCTypesupport),
            ("py", GeneratePython),
        ):
            extension(kind).generate(PACKAGE, idl_files, include_paths, out / kind / PACKAGE)
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
    ros_prefix: Path, gen: Path, stage: Path, site_rel: Path, cc: list[str], cxx: list[str]
) -> None:
    """Compile the generated sources into ``stage`` laid out like the prefix (``lib/`` and
    ``site_rel/tf2_msgs``) with the compilers ``cc`` and ``cxx`` (command lines)."""
    python_include = _python_include()
    import numpy

    ros_include = ros_prefix / "include"
    includes = [gen / "c", gen / "fastrtps_c", gen / "introspection_c", ros_include] + sorted(
        p for p in ros_include.iterdir() if p.is_dir()
    )
    lib = stage / "lib"
    pkg_dir = stage / site_rel / PACKAGE
    lib.mkdir(parents=True)
    pkg_dir.mkdir(parents=True)
    flags = ["-O2", "-fPIC", "-shared", "-w"] + [f"-I{p}" for p in includes]
    lib_dirs = [f"-L{ros_prefix / 'lib'}", f"-L{lib}"]
    own = f"-l{PACKAGE}__rosidl_generator_c"

    def deps(kind: str) -> list[str]:
        return [f"-l{dep}__{kind}" for dep in DEPENDENCIES]

    def library(compiler, kind, sources, libs, extra=()):
        return (
            compiler
            + flags
            + list(extra)
            + [str(s) for s in sorted(sources)]
            + ["-o", str(lib / f"lib{PACKAGE}__{kind}.so")]
            + lib_dirs
            + ["-Wl,-rpath,$ORIGIN"]
            + libs
            + ["-lrosidl_runtime_c", "-lrcutils"]
        )

    msg = Path(PACKAGE) / "msg"
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
            str(gen / "py" / PACKAGE / f"_{PACKAGE}_s.ep.{ts}.c"),
            "-o",
            str(pkg_dir / f"{PACKAGE}_s__{ts}{suffix}"),
        ]
        + lib_dirs
        + [
            f"-Wl,-rpath,$ORIGIN/{to_lib}",
            f"-l{PACKAGE}__rosidl_generator_py",
            f"-l{PACKAGE}__{ts}",
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
        gen / "py" / PACKAGE / "msg", pkg_dir / "msg", ignore=shutil.ignore_patterns("*.c")
    )


def stage_share(gen: Path, descriptions: Path, stage: Path) -> None:
    """The definitions (.msg, .idl, .json) and the ament index entries of the package."""
    share = stage / "share" / PACKAGE / "msg"
    share.mkdir(parents=True)
    files = []
    for name in MESSAGES:
        for src in (
            SOURCE_DIR / "msg" / f"{name}.msg",
            gen / "idl" / "msg" / f"{name}.idl",
            descriptions / "msg" / f"{name}.json",
        ):
            shutil.copy2(src, share / src.name)
            if src.suffix != ".json":
                files.append(f"msg/{src.name}")
    index = stage / "share" / "ament_index" / "resource_index"
    (index / "packages").mkdir(parents=True)
    (index / "packages" / PACKAGE).write_text("")
    (index / "rosidl_interfaces").mkdir()
    (index / "rosidl_interfaces" / PACKAGE).write_text("\n".join(files) + "\n")


def install(stage: Path, prefix: Path, site_rel: Path) -> None:
    """Copy the staged tree into the prefix; the Python package is replaced whole."""
    target_pkg = prefix / site_rel / PACKAGE
    if target_pkg.exists():
        shutil.rmtree(target_pkg)
    for src in sorted(p for p in stage.rglob("*") if p.is_file()):
        dst = prefix / src.relative_to(stage)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.tmp")
        shutil.copy2(src, tmp)
        os.replace(tmp, dst)  # a running process keeps the library it has mapped


def build(prefix: Path, ros_prefix: Path | None = None, force: bool = False) -> str:
    """Generate, compile and install tf2_msgs into ``prefix``; returns what was done (one
    line). ``ros_prefix``: where the ROS wheels are (default: this interpreter's prefix);
    ``force``: build even where tf2_msgs is importable from elsewhere."""
    prefix = prefix.resolve()
    ros_prefix = (ros_prefix or Path(sys.prefix)).resolve()
    external = None if force else _external_tf2_msgs(prefix)
    if external:
        return f"tf2_msgs: using {external} (nothing to build)"
    if not (ros_prefix / "share" / "rosidl_generator_c").is_dir():
        raise BuildError(
            f"the rosidl wheels are not installed in {ros_prefix} (pip install -e '.[ros]')"
        )
    site_rel = _site_packages(prefix).relative_to(prefix)
    cc, cxx = _compiler("CC", "gcc"), _compiler("CXX", "g++")
    _python_include()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="tf2_msgs_build_") as tmp:
        gen, stage = Path(tmp) / "gen", Path(tmp) / "stage"
        try:
            descriptions = generate(ros_prefix, gen)
        except BuildError:
            raise
        except Exception as exc:  # the generators raise whatever their templates raise
            raise BuildError(f"generating the sources failed: {exc!r}"[:300]) from None
        compile_sources(ros_prefix, gen, stage, site_rel, cc, cxx)
        stage_share(gen, descriptions, stage)
        install(stage, prefix, site_rel)
    return f"tf2_msgs: built {', '.join(MESSAGES)} into {prefix} ({time.monotonic() - t0:.1f} s)"


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
        help="build even where tf2_msgs is importable from elsewhere",
    )
    args = parser.parse_args(argv)
    try:
        sys.stdout.write(f"{build(Path(args.prefix), force=args.force)}\n")
        return 0
    except (BuildError, OSError) as exc:
        sys.stdout.write(f"tf2_msgs not built: {exc}; the engine node runs without TF output\n")
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
