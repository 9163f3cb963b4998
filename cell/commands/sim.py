"""``weldcell sim up``: run every simulator of a simulated cell in the foreground until Ctrl-C or SIGTERM."""

from __future__ import annotations

import argparse
import logging
import sys

from cell.commands.stop_signals import StopSignals


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

    with StopSignals() as signals:  # ignored while the simulators start (see StopSignals)
        with start_simulators(config) as sims:
            signals.arm()
            for line in sims.devices():
                print(line.format(), flush=True)
            print(f"weldcell sim up: {config.source} running; Ctrl-C or SIGTERM stops it", flush=True)
            received = signals.wait()
            print(f"weldcell sim up: {received} received, stopping", flush=True)
        print("weldcell sim up: stopped", flush=True)
    return 0
