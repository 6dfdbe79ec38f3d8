# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The real engine node with a slow fitter: every click's fit takes SECONDS longer, to show that
operator input stays in order behind a slow fit. Started as its own process by the tests
(``ros_helpers.engine_process(..., slow_fit_s=SECONDS)``)::

    python test/slow_engine_node.py SECONDS --ros-args -p name:=value ...
"""

from __future__ import annotations

import sys
import time

from affordance_registration.core.engine import AffordanceEngine
from affordance_registration.ros.nodes import engine_node


class SlowEngine(AffordanceEngine):
    """The engine, its clicks' fits ``delay`` seconds slower."""

    delay = 0.0

    def click(self, *args, **kwargs):
        time.sleep(self.delay)
        return super().click(*args, **kwargs)


def main() -> int:
    SlowEngine.delay = float(sys.argv.pop(1))
    engine_node.AffordanceEngine = SlowEngine  # the node builds its engine from this name
    return engine_node.main()


if __name__ == "__main__":
    raise SystemExit(main())
