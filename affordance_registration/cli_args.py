# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ``affordance-registration`` command's argument parsing: its parser class (one-line usage
errors), the path option type, stdout's last flush, the ``bag`` subcommand's options (each
checked by :func:`.cli.cmd_bag` before a node starts or a file is made), and the reference of
every command and option written from the parser (docs/CLI.md)."""

from __future__ import annotations

import argparse
import os
import re
import sys

#: the exit status of every refusal (bad input, a usage error)
EXIT_ERROR = 2


class Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (exit 2, "see --help"), and numbers such as
    ``-1e-3`` taken as values, not as options (argparse knows only ``-1`` and ``-0.5``)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(
            r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$"
            r"|^-(inf|nan)$",
            re.IGNORECASE,
        )

    def error(self, message):
        self.exit(EXIT_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def path_arg(text: str) -> str:
    """An option naming a file or folder: not empty (an empty --out wrote into the current
    folder), no NUL byte."""
    if not text.strip() or "\0" in text:
        raise argparse.ArgumentTypeError(f"{text!r} is not a path (name a file or folder)")
    return text


def quiet_stdout() -> None:
    """Whatever stdout could not take is dropped (else Python says so again at exit)."""
    try:
        sys.stdout.flush()
    except OSError:
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass


def add_bag_parser(sub, command) -> None:
    """The ``bag`` subcommand and its own subcommands, run by ``command``."""
    p = sub.add_parser("bag", help="rosbag2 bags: record, play, info")
    bsub = p.add_subparsers(dest="bag_command", required=True, parser_class=Parser)
    b = bsub.add_parser("record", help="record topics into a new bag (MCAP)")
    b.add_argument("out", help="the new bag's folder")
    b.add_argument("topics", nargs="+", help="topics to record")
    b.add_argument(
        "--duration", type=float, default=None, help="seconds, > 0 (default: until Ctrl-C)"
    )
    b = bsub.add_parser("play", help="republish a bag with its original timing")
    b.add_argument("bag", help="the bag's folder")
    b.add_argument(
        "--rate", type=float, default=1.0, help="speed factor, in [0.001, 1000] (default 1)"
    )
    b.add_argument(
        "--start-offset",
        type=float,
        default=0.0,
        help="seconds into the bag (>= 0, before its end; default 0)",
    )
    b.add_argument("--topics", nargs="*", default=None, help="play only these (default: all)")
    b.add_argument("--loop", action="store_true", help="start again at the end")
    b.add_argument(
        "--wait-for-subscribers",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="wait up to this long (>= 0) for a subscriber on every topic first",
    )
    b.add_argument(
        "--paced",
        action="store_true",
        help="send each message once the engine node has finished with the ones "
        "before it (watching its status), keeping the recorded timing only "
        "within bursts (a SpaceMouse push); default: wall-clock timing",
    )
    b.add_argument(
        "--status-topic",
        default="/affordance_engine/status",
        help="with --paced: the node's JSON status topic",
    )
    b.add_argument(
        "--pace-timeout",
        type=float,
        default=60.0,
        metavar="SECONDS",
        help="with --paced: give up when the node takes longer than this (> 0 s, default 60)",
    )
    b = bsub.add_parser("info", help="topics, types, counts, duration")
    b.add_argument("bag", help="the bag's folder")
    p.set_defaults(func=command)


def subcommands(parser: argparse.ArgumentParser, prefix: tuple = ()):
    """``(words, parser, help)`` of every (sub)command below ``parser``, in the order declared;
    a command with commands of its own (``bag``) comes before them."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield (*prefix, name), sub, helps.get(name)
                yield from subcommands(sub, (*prefix, name))


def _arguments(action: argparse.Action) -> str:
    """What follows an option (or stands for a positional) in the reference: ``X Y Z``,
    ``{m,cm,mm}``, ``[TOPICS ...]``; empty for a flag."""
    if action.nargs == 0:
        return ""
    if action.metavar is not None:
        name = action.metavar
    elif action.choices is not None:
        name = "{" + ",".join(map(str, action.choices)) + "}"
    else:
        name = action.dest if not action.option_strings else action.dest.upper()
    if isinstance(name, tuple):
        return " ".join(name)
    if isinstance(action.nargs, int):
        return " ".join([name] * action.nargs)
    return {
        None: name,
        "?": f"[{name}]",
        "*": f"[{name} ...]",
        "+": f"{name} [{name} ...]",
    }.get(action.nargs, name)


def _options(sub: argparse.ArgumentParser) -> list:
    return [
        a
        for a in sub._actions
        if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
    ]


def reference(parser: argparse.ArgumentParser) -> str:
    """The markdown reference of every command and option of ``parser`` (docs/CLI.md): for each
    command its help, a synopsis and each option with its help text."""
    import textwrap

    def para(text: str, indent: str = "") -> str:
        return textwrap.fill(text, 99, subsequent_indent=indent, break_on_hyphens=False)

    prog = parser.prog
    lines = [
        "# Command line",
        "",
        para(
            f"`{prog}`: {parser.description} Every command and option, written from the parser "
            "(`affordance_registration/cli.py`) by `.venv/bin/python test/test_cli_reference.py "
            "--write`, which also checks that this file is what it writes. `--help` after any "
            "command says the same; a refused input is one line on stderr and exit status 2."
        ),
        "",
    ]
    for words, sub, text in subcommands(parser):
        command = f"{prog} {' '.join(words)}"
        lines += [f"## {' '.join(words)}", "", para(f"{text[:1].upper()}{text[1:]}."), ""]
        if any(isinstance(a, argparse._SubParsersAction) for a in sub._actions):
            names = [w for w, _, _ in subcommands(sub)]
            lines += [
                "Commands: " + ", ".join(f"`{' '.join(words + n)}`" for n in names) + ".",
                "",
            ]
            continue
        actions = _options(sub)
        shown = [_arguments(a) for a in actions if not a.option_strings]
        shown += [
            f"{a.option_strings[-1]} {_arguments(a)}".strip()
            for a in actions
            if a.option_strings and a.required
        ]
        if any(a.option_strings and not a.required for a in actions):
            shown.append("[options]")
        lines += ["```", " ".join([command, *shown]), "```", ""]
        exclusive = {
            id(a): [b for b in group._group_actions if b is not a]
            for group in sub._mutually_exclusive_groups
            for a in group._group_actions
        }
        for a in actions:
            if a.option_strings:
                head = f"`{' '.join(a.option_strings)} {_arguments(a)}`".replace(" `", "`")
            else:
                head = f"`{_arguments(a)}`"
            notes = ["required"] if a.option_strings and a.required else []
            notes += [f"not with {b.option_strings[-1]}" for b in exclusive.get(id(a), [])]
            extra = f" ({', '.join(notes)})" if notes else ""
            lines.append(para(f"- {head}{extra}: {a.help}", "  "))
        lines.append("")
    return "\n".join(lines)
