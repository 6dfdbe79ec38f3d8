# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Saved files are written atomically: all or nothing, no temporary files left behind."""

import os

import pytest

from affordance_registration.core.files import write_atomically


def test_files_land_together_or_not_at_all(tmp_path):
    a, b = tmp_path / "a.yaml", tmp_path / "sub" / "b.bin"
    assert write_atomically({str(a): "first ü", str(b): b"\x00\x01"}) == [str(a), str(b)]
    assert a.read_text(encoding="utf-8") == "first ü" and b.read_bytes() == b"\x00\x01"
    # the second target is a folder: nothing is replaced, the first file keeps its content
    (tmp_path / "taken").mkdir()
    with pytest.raises(OSError):
        write_atomically({str(a): "second", str(tmp_path / "taken"): "x"})
    assert a.read_text(encoding="utf-8") == "first ü"
    leftovers = [f for f in os.listdir(tmp_path) if f.startswith(".")]
    assert leftovers == [] and sorted(os.listdir(tmp_path)) == ["a.yaml", "sub", "taken"]


def test_read_yaml_refuses_a_key_twice_but_lets_a_merged_key_be_overridden(tmp_path):
    """A mapping with one key twice is a mistake (PyYAML keeps the last silently); YAML's merge
    key ``<<`` brings keys that the mapping may override, as YAML intends."""
    from affordance_registration.core.errors import AffordanceError
    from affordance_registration.core.files import read_yaml

    path = tmp_path / "a.yaml"
    path.write_text("base: &b {x: 1, y: 2}\nuse:\n  <<: *b\n  y: 3\n")
    assert read_yaml(str(path), AffordanceError) == {
        "base": {"x": 1, "y": 2},
        "use": {"x": 1, "y": 3},
    }
    path.write_text("use:\n  y: 1\n  z: 2\n  y: 3\n")
    with pytest.raises(
        AffordanceError,
        match=r"a.yaml: not valid YAML \(line 4\): the key 'y' is "
        r"written twice$",
    ):
        read_yaml(str(path), AffordanceError)
    path.write_text("")
    assert read_yaml(str(path), AffordanceError) is None
    path.write_text("x: 1\n" * 10)
    with pytest.raises(AffordanceError, match="larger than 0 kB: not a thing"):
        read_yaml(str(path), AffordanceError, max_bytes=20, kind="thing")
