# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""docs/BENCHMARK.md is the rendering of docs/benchmark.json, as ``affordance-registration bench
--out docs`` writes the two: a hand edit of either fails here. Every line of the table has its
paragraph saying what it measures."""

import json
import subprocess
import sys
from pathlib import Path

from affordance_registration.core.registration import FitSettings
from affordance_registration.evaluation.bench import (
    DOC_NAME,
    RESULTS_NAME,
    SETTINGS_NAME,
    format_table,
    render_markdown,
    row_note,
    write_results,
)

DOCS = Path(__file__).resolve().parents[1] / "docs"
RESULTS = json.loads((DOCS / RESULTS_NAME).read_text())


def test_the_committed_benchmark_page_is_the_rendering_of_the_committed_results():
    assert (DOCS / DOC_NAME).read_text() == render_markdown(RESULTS), (
        "docs/BENCHMARK.md differs from the rendering of docs/benchmark.json: regenerate both "
        "with `affordance-registration bench --out docs`, do not edit them"
    )


def test_bench_out_writes_the_committed_files_from_the_same_results(tmp_path):
    written = write_results(RESULTS, str(tmp_path), FitSettings())
    assert sorted(Path(p).name for p in written) == sorted([RESULTS_NAME, DOC_NAME, SETTINGS_NAME])
    for name in (RESULTS_NAME, DOC_NAME):
        assert (tmp_path / name).read_text() == (DOCS / name).read_text(), name
    # the settings the committed numbers were measured with are a valid settings file
    FitSettings.load(str(DOCS / SETTINGS_NAME))


def test_every_line_of_the_table_says_what_it_measures():
    table = format_table(RESULTS).splitlines()
    assert len(table) > 40  # the full run's table, every row of it
    page = (DOCS / DOC_NAME).read_text()
    for line in table:
        if line.startswith(" "):
            continue  # (a row's indented second line: its paragraph is the row's)
        note = row_note(line)
        assert note is not None, f"no paragraph in ROW_NOTES says what this line measures: {line}"
        assert f"**{note[1]}** -- " in page, note[1]


def test_a_hand_edited_number_is_not_the_rendering():
    edited = json.loads(json.dumps(RESULTS))
    edited["rows"][0]["top1"] = 0.5
    assert render_markdown(edited) != (DOCS / DOC_NAME).read_text()
    assert " 50.0% " in render_markdown(edited)


def test_bench_refuses_an_out_that_is_not_a_folder_before_it_runs(tmp_path):
    target = tmp_path / "results.json"
    target.write_text("{}")
    done = subprocess.run(
        [sys.executable, "-m", "affordance_registration.cli", "bench", "--out", str(target)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"affordance-registration: error: --out {target} is not a folder"
    ]
    assert target.read_text() == "{}"
