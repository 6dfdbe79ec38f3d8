# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""Rate-limited log lines: a stream of bad messages gives one line per kind of problem every few
seconds, not one per message (and not one per distinct text: a storm of client ids or frame
names counts once)."""

from __future__ import annotations

import math
import time
from typing import Callable, Hashable

__all__ = ["Throttle"]


class Throttle:
    """At most one line per key every ``every_s`` seconds of ``clock()`` (s, monotonic)."""

    def __init__(self, every_s: float, clock: Callable[[], float] = time.monotonic):
        self.every_s = float(every_s)
        self.clock = clock
        self._last: dict[Hashable, float] = {}

    def due(self, key: Hashable = None) -> bool:
        """True when a line of ``key`` may be written now (and counts it as written)."""
        now = self.clock()
        if now - self._last.get(key, -math.inf) < self.every_s:
            return False
        self._last[key] = now
        return True
