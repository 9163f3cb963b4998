"""``weldcell sim up``: run every simulator of a simulated cell in the foreground until Ctrl-C or SIGTERM."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from types import FrameType


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim",
        help="run the simulated cell's devices",
        description="Simulated cell devices: 'up' starts the fake robot controller and fake track drive of a "
        "config (kind = fake-*) in the foreground, prints one line per device (role, kind, address), and "
        "stops them all on Ctrl-C or SIGTERM. The fake camera is an in-process renderer that each client "
        "builds for itself.",
    )
    actions = p.add_subparsers(dest="sim_action", metavar="ACTION")
    actions.required = True
    up = actions.add_parser("up", help="start every simulator of the config and wait for Ctrl-C / SIGTERM")
    up.add_argument("--config", required=True, help="cell config file (TOML), e.g. examples/sim-cell.toml")
    up.set_defaults(func=run_up)


def run_up(args: argparse.Namespace) -> int:
    from cell.config import load_config
    from cell.factory import start_simulators

    if args.verbose < 2:  # pymodbus logs a refused bind at WARNING; the one-line reason says it already
        logging.getLogger("pymodbus").setLevel(logging.ERROR)
    config = load_config(args.config)
    if not config.robot.kind.startswith("fake-") and config.track.kind != "fake" and config.camera.kind != "fake":
        print(f"weldcell sim up: {args.config} has no simulated device (kind = fake-* / fake)", file=sys.stderr)
        return 2

    stop = threading.Event()
    received: list[str] = []

    def on_signal(signum: int, frame: FrameType | None) -> None:
        received.append(signal.Signals(signum).name)
        stop.set()

    signals = (signal.SIGINT, signal.SIGTERM)
    # Ignored while the simulators start: a fake that runs in its own process (the UR) inherits an *ignored*
    # signal across exec, so a Ctrl-C sent to the whole process group reaches only this process, which then
    # stops every fake in order instead of each child dying with its own traceback.
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in signals}
    try:
        with start_simulators(config) as sims:
            for sig in signals:
                signal.signal(sig, on_signal)
            for line in sims.devices():
                print(line.format(), flush=True)
            print(f"weldcell sim up: {config.source} running; Ctrl-C or SIGTERM stops it", flush=True)
            while not stop.wait(0.25):
                pass
            print(f"weldcell sim up: {received[0] if received else 'stop'} received, stopping", flush=True)
        print("weldcell sim up: stopped", flush=True)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
