# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The QoS profiles of the package's topics, in one place.

``LATCHED``: the last message is kept for late subscribers (transient local, reliable) -- the
status, markers, a published scan, static TF. ``INPUT``: operator input and TF streams, reliable
with a deep queue so a burst is not dropped. ``SERVICES``: a service storm is queued, not lost.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["LATCHED", "INPUT", "SERVICES", "latched", "cloud"]


def latched(depth: int = 1) -> QoSProfile:
    """Reliable and transient local: the last ``depth`` messages reach late subscribers."""
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def cloud(reliable: bool) -> QoSProfile:
    """Point clouds: only the newest matters; best effort for drivers using SensorDataQoS."""
    return QoSProfile(
        depth=1,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
    )


LATCHED = latched()
INPUT = QoSProfile(
    depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE
)
SERVICES = QoSProfile(
    depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE
)
