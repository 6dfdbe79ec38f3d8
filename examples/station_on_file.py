# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The browser operator station on your own scan file: ``affordance-registration station --scene
FILE`` starts an engine node, publishes the file and serves the station; this prints the page's
URL and keeps them running until Ctrl-C.

    python examples/station_on_file.py [SCAN [--units mm]] [--port 8080]

Without a scan it writes a simulated one first (``affordance-registration simulate``). Open the
URL in a browser: click an object in the cloud, correct it, Accept, Save (the registrations go
to station_output/registrations.yaml, or ``--out``).
"""

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scan", nargs="?", help="a PLY, PCD or organized .npy scan")
    parser.add_argument("--units", default="m", choices=("m", "cm", "mm"))
    parser.add_argument("--port", type=int, default=8080)
    parser.add_argument("--out", default="station_output", help="registrations and node logs")
    args = parser.parse_args()
    command = os.path.join(os.path.dirname(sys.executable), "affordance-registration")

    with tempfile.TemporaryDirectory() as tmp:
        scan = args.scan
        if scan is None:
            subprocess.run(
                [command, "simulate", "--out", tmp], check=True, stdout=subprocess.DEVNULL
            )
            scan = os.path.join(tmp, "scene.ply")
        station = subprocess.Popen(
            [command, "station", "--scene", scan, "--units", args.units]
            + ["--port", str(args.port), "--out", args.out],
            stdout=subprocess.PIPE,
            text=True,
        )
        for stop in (signal.SIGINT, signal.SIGTERM):  # both stop it as Ctrl-C does
            signal.signal(stop, signal.default_int_handler)
        try:
            for line in station.stdout:  # the station says where it serves once it is up
                found = re.search(r"https?://\S+", line)
                if found:
                    print(f"open {found.group(0)}  (Ctrl-C stops the station)", flush=True)
                    break
                print(line, end="")
            else:
                return f"the station stopped: see {args.out}/station_scene.log"
            for line in station.stdout:  # whatever else it says, until it stops
                print(line, end="")
            return station.wait()
        except KeyboardInterrupt:
            station.send_signal(signal.SIGINT)  # it stops its engine and nodes, then exits
            return station.wait()


if __name__ == "__main__":
    sys.exit(main())
