# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ``affordance-registration`` command's argument parsing: its parser class (one-line usage
errors), the path option type, stdout's last flush, and the ``bag`` subcommand's options (each
checked by :func:`.cli.cmd_bag` before a node starts or a file is made)."""

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
