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
