# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The README runs as written: its Python snippets execute unchanged, every command and option of
``affordance-registration`` has help text and is in the README's command list, and every node
executable has its section in msg_docs."""

import argparse
import ast
import re
import subprocess
import sys
from pathlib import Path

from affordance_registration.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
MSG_DOCS = (ROOT / "msg_docs" / "README.md").read_text()


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)


def _commands(parser, prefix=()):
    """(command words, parser) of every (sub)command."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name), sub, action
                yield from _commands(sub, (*prefix, name))


def _command_list() -> str:
    section = README.split("## Command line", 1)[1]
    return re.search(r"```\n(.*?)```", section, re.S).group(1)


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


def test_every_cli_option_has_help_text():
    missing = []
    for words, sub, group in _commands(build_parser()):
        choice_help = {a.dest: a.help for a in group._choices_actions}
        if not choice_help.get(words[-1]):
            missing.append(" ".join(words))
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if not action.help:
                missing.append(
                    f"{' '.join(words)} {'/'.join(action.option_strings) or action.dest}"
                )
    assert not missing, f"no help text: {missing}"


def test_readme_lists_every_command_and_option():
    listed = _command_list()
    missing = []
    for words, sub, _ in _commands(build_parser()):
        if any(isinstance(a, argparse._SubParsersAction) for a in sub._actions):
            continue  # 'bag': its own commands are listed
        line = f"affordance-registration {' '.join(words)}"
        if line not in listed:
            missing.append(line)
            continue
        # the command's lines: from its first mention to the next command
        block = listed[listed.index(line) :]
        nxt = block.find("\naffordance-registration ", 1)
        block = block if nxt < 0 else block[:nxt]
        for action in sub._actions:
            for opt in action.option_strings:
                if opt.startswith("--") and opt != "--help" and opt not in block:
                    missing.append(f"{line} {opt}")
    assert not missing, f"not in the README's command list: {missing}"


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
