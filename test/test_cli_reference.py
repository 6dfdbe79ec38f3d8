# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""docs/CLI.md is the reference the parser writes (``reference``): a command or option added,
renamed or reworded without regenerating it fails here. Every command and option has help text,
and the reference names each in its command's section.

Regenerate: ``.venv/bin/python test/test_cli_reference.py --write``."""

import argparse
import sys
from pathlib import Path

from affordance_registration.cli import build_parser
from affordance_registration.cli_args import reference, subcommands

CLI_MD = Path(__file__).resolve().parents[1] / "docs" / "CLI.md"


def test_docs_cli_is_what_the_parser_writes():
    assert CLI_MD.read_text() == reference(build_parser()) + "\n", (
        "docs/CLI.md is not the parser's reference: .venv/bin/python "
        "test/test_cli_reference.py --write"
    )


def test_every_command_and_option_has_help_text():
    missing = []
    for words, sub, text in subcommands(build_parser()):
        if not text:
            missing.append(" ".join(words))
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if not action.help:
                missing.append(
                    f"{' '.join(words)} {'/'.join(action.option_strings) or action.dest}"
                )
    assert not missing, f"no help text: {missing}"


def test_the_reference_names_every_command_and_option_in_its_section():
    text = reference(build_parser())
    sections = dict(
        (part.split("\n", 1)[0], part) for part in text.split("\n## ")[1:]
    )  # "fit" -> its section
    missing = []
    for words, sub, help_text in subcommands(build_parser()):
        section = sections.get(" ".join(words))
        if section is None or help_text[:20].lower() not in section.lower():
            missing.append(" ".join(words))
            continue
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if action.option_strings:  # its bullet: "- `--out DIR`: ..."
                bullets = [f"- `{' '.join(action.option_strings)}"]
            else:  # "- `file`", "- `[file]`", "- `[arguments ...]`"
                bullets = [f"- `{action.dest}", f"- `[{action.dest}"]
            if not any(bullet in section for bullet in bullets):
                missing.append(f"{' '.join(words)} {action.option_strings or action.dest}")
    assert not missing, f"not in the reference: {missing}"


if __name__ == "__main__":
    if sys.argv[1:] == ["--write"]:
        CLI_MD.write_text(reference(build_parser()) + "\n")
        print(f"wrote {CLI_MD}")
    else:
        sys.exit("usage: test_cli_reference.py --write")
