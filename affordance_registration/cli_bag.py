# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""``affordance-registration bag``: record, play and inspect rosbag2 bags (the CLI's part of
:mod:`.ros.standins.bag`). Every option is checked before a node starts or a file is made."""
from __future__ import annotations

import sys
import time


def cmd_bag(args) -> int:
    from .ros.standins.bag import RATE_LIMITS, BagError, bag_info, check_number, topic_name
    if args.bag_command == "info":
        info = bag_info(args.bag)
        print(f"bag {info['path']}: {info['messages']} messages, {info['duration_s']:.2f} s")
        for t in info["topics"]:
            print(f"  {t['topic']:<32} {t['type']:<36} {t['count']:>6}")
        return 0
    # every option checked before a node starts or a file is made
    if args.bag_command == "record":
        if args.duration is not None:
            check_number("--duration", args.duration, positive=True)
        for topic in args.topics:
            topic_name(topic)
    else:
        check_number("--rate", args.rate, positive=True, limits=RATE_LIMITS)
        check_number("--start-offset", args.start_offset)
        check_number("--wait-for-subscribers", args.wait_for_subscribers)
        check_number("--pace-timeout", args.pace_timeout, positive=True)
        topic_name(args.status_topic)
    import signal
    import threading

    from .ros.standins.spin import background_node
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    with background_node("affordance_bag") as node:
        if args.bag_command == "record":
            from .ros.standins.bag import Recorder
            recorder = Recorder(node, args.out, args.topics)
            try:
                t0 = time.monotonic()
                while not stop.is_set() and recorder.error is None and (
                        args.duration is None or time.monotonic() - t0 < args.duration):
                    time.sleep(0.05)
            except BaseException:
                recorder.abort()
                raise
            counts = recorder.close()
            if recorder.error is not None:
                raise BagError(f"{recorder.error}; recording stopped" + (
                    f", the {sum(counts.values())} messages recorded before are in {args.out}"
                    if recorder.kept else f", {args.out} removed"))
            print(f"recorded {sum(counts.values())} messages into {args.out}: {counts}")
        else:
            from .ros.standins.bag import Player, StatusPacer
            pace = StatusPacer(node, args.status_topic, args.pace_timeout) if args.paced \
                else None
            player = Player(node, args.bag, rate=args.rate, start_offset=args.start_offset,
                            topics=args.topics or None, loop=args.loop, pace=pace)
            if args.wait_for_subscribers and not player.wait_for_subscribers(
                    args.wait_for_subscribers, stop) and not stop.is_set():
                print("not every topic has a subscriber; playing anyway", file=sys.stderr)
            n = player.play(stop)
            print(f"played {n} messages from {args.bag}")
    return 0


def add_bag_parser(sub, parser_class) -> None:
    """The ``bag`` subcommand and its own subcommands (their parsers of ``parser_class``)."""
    p = sub.add_parser("bag", help="rosbag2 bags: record, play, info")
    bsub = p.add_subparsers(dest="bag_command", required=True, parser_class=parser_class)
    b = bsub.add_parser("record", help="record topics into a new bag (MCAP)")
    b.add_argument("out", help="the new bag's folder")
    b.add_argument("topics", nargs="+", help="topics to record")
    b.add_argument("--duration", type=float, default=None,
                   help="seconds, > 0 (default: until Ctrl-C)")
    b = bsub.add_parser("play", help="republish a bag with its original timing")
    b.add_argument("bag", help="the bag's folder")
    b.add_argument("--rate", type=float, default=1.0, help="speed factor, in [0.001, 1000] (default 1)")
    b.add_argument("--start-offset", type=float, default=0.0,
                   help="seconds into the bag (>= 0, before its end; default 0)")
    b.add_argument("--topics", nargs="*", default=None, help="play only these (default: all)")
    b.add_argument("--loop", action="store_true", help="start again at the end")
    b.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="SECONDS",
                   help="wait up to this long (>= 0) for a subscriber on every topic first")
    b.add_argument("--paced", action="store_true",
                   help="send each message once the engine node has finished with the ones "
                        "before it (watching its status), keeping the recorded timing only "
                        "within bursts (a SpaceMouse push); default: wall-clock timing")
    b.add_argument("--status-topic", default="/affordance_engine/status",
                   help="with --paced: the node's JSON status topic")
    b.add_argument("--pace-timeout", type=float, default=60.0, metavar="SECONDS",
                   help="with --paced: give up when the node takes longer than this (> 0 s, "
                        "default 60)")
    b = bsub.add_parser("info", help="topics, types, counts, duration")
    b.add_argument("bag", help="the bag's folder")
    p.set_defaults(func=cmd_bag)
