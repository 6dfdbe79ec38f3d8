# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The README is a user's guide that runs as written: it opens with the two commands, stays
short, its Python snippet executes unchanged, its commands parse (the fitting ones run), its links
resolve, and the ROS names it gives are the ones msg_docs documents. Every node executable has
its section in msg_docs and is named in the README; every launch file is documented."""

import ast
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from affordance_registration.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
MSG_DOCS = (ROOT / "msg_docs" / "README.md").read_text()


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)


def _command_lines(text: str) -> list[list[str]]:
    """The ``affordance-registration`` command lines of the README's code blocks, as argv after
    the command (continuation lines joined, comments and redirections dropped)."""
    lines = []
    for block in re.findall(r"^```\n(.*?)^```", text, re.S | re.M):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            for i, word in enumerate(words):  # (the shell's part: a redirection, a pipe)
                if word in (">", ">>", "|", "&&"):
                    words = words[:i]
                    break
            if words and words[0].endswith("affordance-registration"):
                lines.append(words[1:])
    return lines


def _anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_readme_opens_with_the_two_commands_and_stays_a_guide():
    head = "\n".join(README.splitlines()[:6])
    assert "make demo" in head and "make test" in head, head
    assert len(README.splitlines()) <= 300


def test_readme_python_snippets_run_as_written(tmp_path):
    blocks = _python_blocks(README)
    assert blocks, "the README has no ```python snippet"
    for i, code in enumerate(blocks):
        ast.parse(code)
        out = subprocess.run(
            [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600
        )
        assert out.returncode == 0, f"README snippet {i + 1}:\n{out.stderr[-3000:]}"
    # what the integrator snippet says it does
    saved = (tmp_path / "registrations.yaml").read_text()
    assert "registrations" in saved and "accepted" in out.stdout


def test_every_readme_command_line_parses():
    commands = _command_lines(README)
    assert {argv[0] for argv in commands} >= {"station", "simulate", "fit", "launch", "bench"}
    parser = build_parser()
    for argv in commands:
        try:
            parser.parse_args(argv)
        except SystemExit:
            pytest.fail(
                f"the README's `affordance-registration {shlex.join(argv)}` does not parse"
            )


def test_the_readme_fit_commands_do_what_they_say(tmp_path):
    """The command-line section's simulate and fit lines, run as written: the click is the ball
    valve's, and the ball valve fits there."""
    command = Path(sys.executable).with_name("affordance-registration")
    runs = [argv for argv in _command_lines(README) if argv[0] in ("simulate", "fit")]
    assert [argv[0] for argv in runs] == ["simulate", "fit"], runs
    for argv in runs:
        done = subprocess.run(
            [str(command), *argv], cwd=tmp_path, capture_output=True, text=True, timeout=600
        )
        assert done.returncode == 0, done.stderr[-3000:]
    assert re.search(r"^ball_valve fits", done.stdout, re.M), done.stdout


def test_every_relative_link_of_the_documentation_resolves():
    """The README's links, and those of the pages it links (docs/, msg_docs), reach a file and,
    with an anchor, a heading of it."""
    pages = [ROOT / "README.md", ROOT / "msg_docs" / "README.md", *(ROOT / "docs").glob("*.md")]
    headings = {}
    for page in pages:
        for link in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", link):
                continue
            path, _, anchor = link.partition("#")
            target = (page.parent / path).resolve() if path else page
            assert target.exists(), f"{page.name}: {link}"
            if anchor:
                if target not in headings:
                    text = target.read_text()
                    headings[target] = {_anchor(h) for h in re.findall(r"^#+ (.*)$", text, re.M)}
                assert anchor in headings[target], f"{page.name}: {link}"
    for doc in ("msg_docs/README.md", "docs/CLI.md", "docs/TEMPLATES.md", "docs/BENCHMARK.md"):
        assert f"]({doc}" in README, f"the README does not link {doc}"


def test_the_ros_names_the_readme_gives_are_documented_in_msg_docs():
    names = set(re.findall(r"`(~/[a-z_]+)`", README))
    glance = README.split("The interface at a glance", 1)[1].split("Other executables", 1)[0]
    names |= {
        n for n in re.findall(r"`([^`\s]+)`", glance) if "." not in n and not n.startswith("fit")
    }
    assert {"~/accept", "~/save", "points", "clicked_point", "templates_dir"} <= names
    missing = sorted(n for n in names if f"`{n}`" not in MSG_DOCS)
    assert not missing, f"named in the README, not in msg_docs: {missing}"


def test_every_node_executable_has_its_msg_docs_section():
    setup = (ROOT / "setup.py").read_text()
    scripts = re.findall(r'"(affordance_[a-z_]+) = affordance_registration\.ros\.', setup)
    assert "affordance_engine" in scripts and "affordance_file_scan" in scripts
    for name in scripts:
        assert f"## Node `{name}`" in MSG_DOCS, name
        assert f"`{name}`" in README, name


def test_every_launch_file_is_documented():
    for path in sorted((ROOT / "launch_configs").glob("*.launch.yaml")):
        assert f"launch_configs/{path.name}" in README + MSG_DOCS, path.name
