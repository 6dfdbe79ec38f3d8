# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""docs/ARCHITECTURE.md is true to the code: every path it names (in backquotes or in the tree of
the layers) exists, and every module, class, function, method, constant or fitting knob it
writes in backquotes is defined in the package (read with ``ast``; the knobs' names are
``FitSettings.knobs()``).

What a backquoted text is taken for:

* a path (it has a ``/`` or a file's extension): the file or folder, from the repository, from
  the package or -- a bare file name -- anywhere in the package; ``dir/module.NAME`` is a name in
  that module. A ``/`` without an extension whose first part is no folder of ours is a ROS type
  (``geometry_msgs/PointStamped``) and a ``~/`` one a node's topic: not checked.
* ``a.b.c`` (``name(...)`` as ``name``): a fitting knob (``viewpoint.margin``), or a module --
  named by its last parts (``scoring``, ``stages.primitives``) -- and a name in it, and so on
  into a class's members (its bases' too); or a class and its members (``Registrar.fit``); or
  a name of Python's standard library (``dataclasses.replace``, imported).
* a bare name: a name defined anywhere in the package (a module, class, function, method,
  attribute, constant), a knob or a group of knobs, a Python keyword, a string the package
  uses (a topic, a parameter, a command: ``clicked_point``, ``publish_rate``, ``bench``) or a
  folder of the repository (``msg_docs``).

Text with a space in it (a command line, a YAML line) or a placeholder (``fit.<group>.<knob>``)
is prose, not a name.
"""

from __future__ import annotations

import ast
import importlib
import keyword
import re
import sys
from functools import cached_property
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "affordance_registration"
DOC = ROOT / "docs" / "ARCHITECTURE.md"
EXTENSIONS = ("py", "yaml", "yml", "md", "json", "msg", "srv", "html", "js", "css", "txt", "toml")
IDENTIFIER = r"[A-Za-z_]\w*"


class Code:
    """What the package defines, read from its source: its modules by dotted name, the names
    each defines at its top level (imports included: a package re-exports), every class's
    members and bases, every name defined anywhere, every string constant."""

    def __init__(self, package: Path = PACKAGE):
        self.package = package
        self.modules: dict[str, ast.Module] = {}
        for path in sorted(package.rglob("*.py")):
            parts = path.relative_to(package).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            self.modules[name] = ast.parse(path.read_text(encoding="utf-8"))
        self.classes: dict[str, list[ast.ClassDef]] = {}
        self.defined: set[str] = set(p.split(".")[-1] for p in self.modules if p)
        self.strings: set[str] = set()
        for tree in self.modules.values():
            for node in ast.walk(tree):
                if isinstance(node, ast.ClassDef):
                    self.classes.setdefault(node.name, []).append(node)
                    self.defined.add(node.name)
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    self.defined.add(node.name)
                    self.defined.update(a.arg for a in node.args.args + node.args.kwonlyargs)
                elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                    self.defined.add(node.id)
                elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                    self.defined.add(node.attr)
                elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                    self.strings.add(node.value)

    @staticmethod
    def top_level(tree: ast.Module) -> set:
        """The names a module defines or imports at its top level."""
        out = set()
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                out.add(node.name)
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                out.update((a.asname or a.name).split(".")[0] for a in node.names)
            elif (
                isinstance(node, ast.Assign)
                and [getattr(t, "id", None) for t in node.targets] == ["_PUBLIC"]
                and isinstance(node.value, ast.Dict)
            ):  # a package's lazy re-exports: {name: the module it is imported from}
                out.update(k.value for k in node.value.keys if isinstance(k, ast.Constant))
                out.add("_PUBLIC")
            else:
                for sub in ast.walk(node):
                    if isinstance(sub, ast.Name) and isinstance(sub.ctx, ast.Store):
                        out.add(sub.id)
        return out

    def members(self, cls: str, seen=None) -> set:
        """A class's methods, class attributes and fields, the attributes its methods set on
        ``self``, and its bases' (those of the package)."""
        seen = set() if seen is None else seen
        if cls in seen:
            return set()
        seen.add(cls)
        out = set()
        for node in self.classes.get(cls, []):
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    out.add(item.name)
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    out.add(item.target.id)
                elif isinstance(item, ast.Assign):
                    out.update(t.id for t in item.targets if isinstance(t, ast.Name))
            for sub in ast.walk(node):
                if (
                    isinstance(sub, ast.Attribute)
                    and isinstance(sub.ctx, ast.Store)
                    and isinstance(sub.value, ast.Name)
                    and sub.value.id == "self"
                ):
                    out.add(sub.attr)
            for base in node.bases:
                name = base.id if isinstance(base, ast.Name) else getattr(base, "attr", None)
                if name is not None:
                    out |= self.members(name, seen)
        return out

    def in_class(self, cls: str, chain: list) -> bool:
        """Whether ``cls`` has the member ``chain[0]`` (and a class member the rest)."""
        if not chain:
            return True
        if chain[0] not in self.members(cls):
            return False
        return len(chain) == 1 or (chain[0] in self.classes and self.in_class(chain[0], chain[1:]))

    def in_module(self, module: str, chain: list) -> bool:
        """Whether the module defines ``chain[0]`` (a class: and the rest as its members; a
        module below a package: the rest in it)."""
        if f"{module}.{chain[0]}" in self.modules:
            return len(chain) == 1 or self.in_module(f"{module}.{chain[0]}", chain[1:])
        if chain[0] not in self.top_level(self.modules[module]):
            return False
        return len(chain) == 1 or (chain[0] in self.classes and self.in_class(chain[0], chain[1:]))

    def dotted(self, parts: list) -> bool:
        """Whether ``a.b.c`` names something: a module (by its last parts) and names in it,
        or a class and its members."""
        for k in range(len(parts) - 1, 0, -1):
            suffix = ".".join(parts[:k])
            for module in self.modules:
                if (module == suffix or module.endswith("." + suffix)) and self.in_module(
                    module, parts[k:]
                ):
                    return True
        return parts[0] in self.classes and self.in_class(parts[0], parts[1:])

    @cached_property
    def knobs(self) -> set:
        """Every fitting knob's dotted name and every group's name."""
        from affordance_registration.core.registration import FitSettings

        names = {name for name, *_ in FitSettings.knobs()}
        return names | {name.split(".")[0] for name in names}


def inline_code(text: str) -> list:
    """The backquoted texts of a markdown document, outside its fenced blocks."""
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return re.findall(r"`([^`\n]+)`", prose)


def tree_paths(text: str) -> list:
    """The paths of the fenced tree of the layers: each line's first word that ends in ``/``
    or ``.py`` under the folders above it (two spaces of indent a level)."""
    out = []
    for block in re.findall(r"^```\n(.*?)^```", text, flags=re.S | re.M):
        stack: list = []
        for line in block.splitlines():
            m = re.match(r"^( *)(\S+)( {2,}|$)", line)
            if m is None or not re.fullmatch(r"[\w.-]+(/|\.py)", m.group(2)):
                continue
            depth = len(m.group(1)) // 2
            stack = stack[:depth] + [m.group(2).rstrip("/")]
            out.append("/".join(stack) + ("/" if m.group(2).endswith("/") else ""))
    return out


def _path_exists(code: Code, text: str, root: Path) -> bool | None:
    """Whether the path ``text`` exists (None: not one of ours)."""
    module = re.fullmatch(rf"(.+/)?({IDENTIFIER})\.({IDENTIFIER})", text)
    if module and module.group(3) not in EXTENSIONS:  # dir/module.NAME
        path = f"{module.group(1) or ''}{module.group(2)}.py"
        for base in (root, root / "affordance_registration"):
            if (base / path).is_file():
                dotted = (base / path).relative_to(code.package).with_suffix("").parts
                return code.in_module(".".join(dotted), [module.group(3)])
        return False
    for base in (root, root / "affordance_registration"):
        if (base / text).exists():
            return True
    if "/" not in text:  # a bare file name: anywhere in the package
        return any(code.package.rglob(text))
    has_extension = re.search(rf"\.({'|'.join(EXTENSIONS)})$", text) is not None
    first = text.split("/")[0]
    ours = (root / first).is_dir() or (root / "affordance_registration" / first).is_dir()
    if not has_extension and not text.endswith("/") and not ours:
        return None  # a ROS type, geometry_msgs/PointStamped
    return False


def _stdlib(name: str) -> bool:
    """Whether ``module.name`` is in Python's standard library (``dataclasses.replace``)."""
    module, _, rest = name.partition(".")
    if module not in sys.stdlib_module_names:
        return False
    value = importlib.import_module(module)
    for part in rest.split("."):
        value = getattr(value, part, None)
    return value is not None


def names_missing(text: str, code: Code | None = None, root: Path = ROOT) -> list:
    """The backquoted names and the tree's paths of markdown ``text`` the code does not have
    (see the module)."""
    code = code or Code()
    out = [p for p in tree_paths(text) if not (root / p).exists()]
    for raw in inline_code(text):
        token = raw.strip()
        call = re.fullmatch(rf"({IDENTIFIER}(?:\.{IDENTIFIER})*)\(.*\)", token)
        if call:
            token = call.group(1)
        if not token or token.startswith("~") or "<" in token or " " in token:
            continue  # a topic, a placeholder, prose
        if "/" in token or re.search(rf"\.({'|'.join(EXTENSIONS)})$", token):
            if _path_exists(code, token, root) is False:
                out.append(raw)
            continue
        if re.fullmatch(rf"{IDENTIFIER}(\.{IDENTIFIER})+", token):
            if (
                token not in code.knobs
                and not code.dotted(token.split("."))
                and not _stdlib(token)
            ):
                out.append(raw)
            continue
        name = token.rstrip(":")  # (a YAML key)
        if keyword.iskeyword(name) or re.fullmatch(r"__\w+__", name):
            continue
        if (
            not ({name} & (code.defined | code.knobs | code.strings))
            and not (root / name).exists()
        ):
            out.append(raw)
    return out


def test_every_name_and_path_in_architecture_md_exists():
    text = DOC.read_text(encoding="utf-8")
    assert len(inline_code(text)) > 50 and len(tree_paths(text)) > 10  # (the parsers found them)
    assert names_missing(text) == []


def test_a_misspelt_name_or_path_is_found(tmp_path):
    """Each kind of name, once as the code has it and once misspelt: only the misspelt are
    reported."""
    doc = tmp_path / "ARCHITECTURE.md"
    right = [
        "`core/registration/registrar.py`",
        "`core/registration/stages/`",
        "`hypotheses.py`",
        "`evaluation/realdata.HELD_OUT`",
        "`Registrar.fit(scene, point)`",
        "`scoring.judge`",
        "`stages.primitives.run`",
        "`registration.Registrar`",
        "`FitReport.timing_s`",
        "`viewpoint.margin`",
        "`ClickContext`",
        "`clicked_point`",
        "`geometry_msgs/PointStamped`",
        "`~/status`",
        "`affordance-registration fit`",
        "`dataclasses.replace`",
    ]
    wrong = [
        "`core/registration/registrr.py`",
        "`core/registraton/`",
        "`hypothesis.py`",
        "`evaluation/realdata.HELD_IN`",
        "`Registrar.fitt(scene, point)`",
        "`scoring.judg`",
        "`stages.primitive.run`",
        "`FitReport.timings`",
        "`viewpoint.margn`",
        "`ClickContxt`",
        "`clicked_pont`",
        "`dataclasses.replac`",
    ]
    tree = "```\naffordance_registration/\n  core/\n    engine.py   x\n    engin.py    y\n```\n"
    doc.write_text(tree + "\n".join(right + wrong) + "\n")
    missing = names_missing(doc.read_text())
    assert missing == ["affordance_registration/core/engin.py"] + [w.strip("`") for w in wrong]
