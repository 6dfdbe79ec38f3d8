# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ROS 2 package habits: the lint rules of ruff.toml (pyflakes, pycodestyle and a pep257
subset, as ament_flake8 and ament_pep257 check them) pass on the whole tree, and the licence the
package declares is the one it ships."""

import ast
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUFF = Path(sys.executable).parent / "ruff"


def test_ruff_passes_with_the_project_rules():
    assert (ROOT / "ruff.toml").is_file()
    out = subprocess.run(
        [str(RUFF), "check", "--no-cache", "--output-format", "concise", "."],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout[-5000:] + out.stderr[-2000:]


def test_the_code_is_as_ruff_format_writes_it():
    """``ruff format`` is the formatter: the tree is as it writes it (``ruff format .`` fixes
    it)."""
    out = subprocess.run(
        [str(RUFF), "format", "--check", "--no-cache", "affordance_registration", "test"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout[-5000:] + out.stderr[-2000:]


def private_imports(root: Path) -> list:
    """``path: module.name`` for every ``from module import _name`` below ``root``: a name two
    modules use is public in the lower one."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                found += [
                    f"{path.relative_to(root).as_posix()}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    return found


def test_no_module_imports_another_modules_private_name():
    assert private_imports(ROOT / "affordance_registration") == []


def test_a_private_import_is_found(tmp_path):
    (tmp_path / "a.py").write_text("from .b import _hidden, shown\nfrom .c import __version__\n")
    assert private_imports(tmp_path) == ["a.py: b._hidden"]


def test_ruff_finds_what_the_rules_forbid(tmp_path):
    """The configuration is in force: a file breaking each kind of rule is reported."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f():\n    return 1 \n" + "x = '" + "a" * 120 + "'\n")
    out = subprocess.run(
        [
            str(RUFF),
            "check",
            "--no-cache",
            "--config",
            str(ROOT / "ruff.toml"),
            "--output-format",
            "concise",
            str(bad),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    codes = set(re.findall(r": ([A-Z]+\d+) ", out.stdout))
    assert {"F401", "W291", "E501", "D100", "CPY001"} <= codes, out.stdout


def test_the_licence_file_is_the_declared_one():
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION" in text
    assert "END OF TERMS AND CONDITIONS" in text
    assert all(f"{n}. " in text for n in range(1, 10))  # its nine sections
    root = ET.parse(ROOT / "package.xml").getroot()
    assert [e.text for e in root.iter("license")] == ["Apache-2.0"]
    assert 'license="Apache-2.0"' in (ROOT / "setup.py").read_text()


def test_every_python_file_carries_the_copyright_and_licence_header():
    """ament_copyright's check: the copyright line (ruff's CPY001, above) and the licence the
    package declares, as an SPDX identifier, at the top of every tracked Python file."""
    files = subprocess.run(
        ["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True, timeout=60
    ).stdout.split()
    if not files:  # not a git checkout (an sdist, a colcon copy)
        files = [
            str(p.relative_to(ROOT))
            for p in ROOT.rglob("*.py")
            if not {".venv", "build", "install", "log"} & set(p.relative_to(ROOT).parts)
        ]
    assert len(files) > 100
    missing = [
        f
        for f in files
        if "# SPDX-License-Identifier: Apache-2.0\n"
        not in "".join((ROOT / f).read_text(encoding="utf-8").splitlines(True)[:3])
    ]
    assert missing == [], f"no licence header in: {missing[:10]}"
