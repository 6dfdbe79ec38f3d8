# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""No module of the package is longer than MAX_LINES: a module holds one concept, and a newcomer
reads it whole. One that outgrows the limit is split by concept, as core/templates.py (the
template object, its file format, mesh geometry, the library) and core/scene.py (the cloud, the
voxel grid, the plane, the segmentation, the click context) are."""
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "affordance_registration"
MAX_LINES = 600


def long_modules(root: Path, limit: int = MAX_LINES) -> dict:
    """Every ``*.py`` below ``root`` of more than ``limit`` lines: relative path -> lines."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > limit:
            out[path.relative_to(root).as_posix()] = lines
    return out


def test_no_module_is_longer_than_the_limit():
    assert (PACKAGE / "core" / "scene.py").is_file()          # the package really is there
    long = long_modules(PACKAGE)
    assert long == {}, f"modules over {MAX_LINES} lines (split them by concept): {long}"


def test_the_count_finds_a_module_one_line_over(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "long.py").write_text("x = 1\n" * (MAX_LINES + 1))
    (tmp_path / "exact.py").write_text("x = 1\n" * MAX_LINES)
    (tmp_path / "notes.txt").write_text("x\n" * (2 * MAX_LINES))
    assert long_modules(tmp_path) == {"sub/long.py": MAX_LINES + 1}
