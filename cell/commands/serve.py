"""``weldcell serve --config cell.toml``: the cell's HTTP service (cell.daemon) in the foreground.

SIGTERM or Ctrl-C stops it safely: a running job's motion is stopped and the arc switched off first (the job ends
in fault with that reason), queued jobs are cancelled, the arc output is read back (the last line says whether it
reads off; exit code 1 if it still reads on), then the devices and the journal are closed, and any child process
still running (a simulator, a driver's worker) is ended within a bound. SIGUSR1 prints every thread's stack to
stderr.

``--sim-faults`` (tests and soaks only) serves ``/sim/faults`` to switch faults of the simulators on and off; it is
refused unless every device of the config is a simulator started by this process (see cell.daemon).
"""

from __future__ import annotations

import argparse
import faulthandler
import logging
import signal
import sys

from cell.commands.stop_signals import StopSignals, end_child_processes

logger = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve",
        help="run the cell as an HTTP service",
        description="Serve the cell of --config over HTTP ([daemon] host, default 127.0.0.1, and port; a bearer "
        "token is required when the host is not a loopback address): POST /jobs, GET /jobs, GET /jobs/{id}, "
        "POST /jobs/{id}/approve|reject, POST /acknowledge, GET /status, GET / (status page), GET /metrics. Jobs run "
        "one at a time; SIGTERM stops the motion and the arc before exiting.",
    )
    p.add_argument("--config", required=True, help="cell config file (TOML)")
    p.add_argument(
        "--no-sims",
        action="store_true",
        help="connect to simulators already running ('weldcell sim up') instead of starting the config's fakes",
    )
    p.add_argument("--port", type=int, default=None, help="override [daemon] port (0: a free port, printed)")
    p.add_argument(
        "--sim-faults",
        action="store_true",
        help="test only: serve /sim/faults to inject faults into the simulators this process starts (refused "
        "unless every device is simulated, and with --no-sims)",
    )
    p.set_defaults(func=run_serve)


def _register_stack_dump() -> None:
    """`kill -USR1 <pid>` prints every thread's stack to stderr (a daemon that does not stop can say where it
    waits); to the process's own stderr when ``sys.stderr`` is not a file (a caller that captures it)."""
    stream = sys.stderr
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError and a ValueError
        stream = sys.__stderr__
    try:
        faulthandler.register(signal.SIGUSR1, file=stream, all_threads=True)
    except (AttributeError, OSError, ValueError, RuntimeError) as e:  # no SIGUSR1 here, or no stderr at all
        logger.warning("no stack dump on SIGUSR1: %s", e)


def run_serve(args: argparse.Namespace) -> int:
    from cell.config import load_config
    from cell.daemon import Daemon
    from cell.runner import safety_limits

    if args.verbose < 2:
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    _register_stack_dump()
    config = load_config(args.config)
    safety_limits(config)  # refuse a config without [safety] before starting anything
    if args.port is not None:
        config = config.model_copy(update={"daemon": config.daemon.model_copy(update={"port": args.port})})
    on: bool | None = None
    with StopSignals() as signals:  # ignored while the devices start (the fake UR runs in a child process)
        daemon = Daemon(config, start_simulators=not args.no_sims, sim_faults=args.sim_faults)
        received = "error"
        try:
            signals.arm()
            daemon.start()
            host, port = daemon.address
            _say(f"weldcell serve: listening on http://{host}:{port} (journal {daemon.journal.path})")
            for record in daemon.interrupted:
                _say(f"weldcell serve: job {record.id} ({record.job_file}) was interrupted: not resumed")
            received = signals.wait()
            _say(f"weldcell serve: {received} received, stopping safely")
        finally:  # whatever ended the wait, the motion stops and the arc goes off before the process ends
            try:
                daemon.shutdown(received)
                on = daemon.arc_on_at_exit
                said = "could not be read back" if on is None else ("STILL READS ON" if on else "reads off")
                _say(f"weldcell serve: stopped; arc output {daemon.runner.arc_output} {said}")
            finally:
                end_child_processes()
    return 1 if on else 0


def _say(line: str) -> None:
    """Print a status line for whoever started the daemon. A reader that went away (a closed pipe) must not keep
    the daemon from stopping safely: the line goes to the log instead."""
    try:
        print(line, flush=True)
    except (OSError, ValueError):
        logger.warning("%s (stdout is closed)", line)
