# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Running rclpy nodes the way these wheels need it: no rclpy signal handlers (a node blocked in
``rclpy.spin()`` has been seen to ignore SIGINT), our own SIGINT/SIGTERM handler, and a
``spin_once`` loop that logs a failing callback instead of dying."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from ...core.errors import AffordanceError

__all__ = ["run_node", "background_node"]


def run_node(factory, name: str, args=None, shutdown=None) -> int:
    """Create the node with ``factory()`` and spin it until SIGINT/SIGTERM. A node that cannot
    start (bad parameters) prints one line and returns 2. ``shutdown(node)`` runs before the
    node is destroyed."""
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    node, code = None, 0
    executor = SingleThreadedExecutor()
    try:
        node = factory()
        executor.add_node(node)  # one executor for the node's life: its futures wake it
        while not stop.is_set() and rclpy.ok():
            try:
                executor.spin_once(timeout_sec=0.1)
            except Exception as exc:  # a failing callback must not take the node down
                node.get_logger().error(f"internal error in a callback: {exc!r}")
    except (AffordanceError, ParameterException, ValueError, ImportError) as exc:
        sys.stderr.write(f"{name}: cannot start: {exc}\n")
        code = 2
    except Exception as exc:  # a bug: one line, not a traceback
        sys.stderr.write(
            f"{name}: cannot start: internal error: {exc.__class__.__name__}: {exc}\n"
        )
        code = 2
    finally:
        if node is not None:
            node.get_logger().info("shutting down")
            if shutdown is not None:
                shutdown(node)
            executor.remove_node(node)
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


@contextlib.contextmanager
def background_node(name: str):
    """A node spun by a background thread (initialising rclpy if nobody has); yields the node."""
    own = not rclpy.ok()
    if own:
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(name)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=spin, name=f"{name}-spin", daemon=True)
    thread.start()
    try:
        yield node
    finally:
        stop.set()
        thread.join(timeout=2)
        executor.remove_node(node)
        node.destroy_node()
        if own and rclpy.ok():
            rclpy.shutdown()
