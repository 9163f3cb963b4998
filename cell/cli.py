"""The one ``weldcell`` command line.

Exit codes: 0 success; 1 failure (a one-line reason on stderr); 2 bad input (bad capture, bad config,
bad arguments); 3 no seam found; 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from perception.errors import BadCapture, NoSeamFound, WeldcellError

# Subcommand modules, imported when the parser is built; each keeps heavy imports inside its handlers
# so that `weldcell --help` stays fast.
COMMAND_MODULES: tuple[str, ...] = (
    "cell.commands.simulate",
    "cell.commands.evaluate",
    "cell.commands.detect",
    "cell.commands.bench",
    "cell.commands.sim",
    "cell.commands.devices",
    "cell.commands.calibrate",
    "cell.commands.run",
    "cell.commands.serve",
    "cell.commands.schema",
    "cell.commands.export",
)

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_NO_SEAM = 3
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="weldcell",
        description="Robotic welding cell: seam detection from one RGB-D shot, calibration, cell control.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    parser.add_argument("--version", action="version", version=f"weldcell {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def version() -> str:
    """The installed distribution's version (pyproject.toml), or a note that weldcell is not installed."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("weldcell")
    except PackageNotFoundError:
        return "(not installed: run scripts/bootstrap.sh or pip install .)"


def exit_code_for(err: BaseException) -> int:
    """Map an error to the documented exit code."""
    from cell.errors import ConfigError

    if isinstance(err, NoSeamFound):
        return EXIT_NO_SEAM
    if isinstance(err, BadCapture | ConfigError):
        return EXIT_BAD_INPUT
    return EXIT_FAILURE


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        code = int(args.func(args))
    except KeyboardInterrupt:
        print("weldcell: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # the reader went away (`weldcell ... | head`): stop quietly, as command-line tools do
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except WeldcellError as err:
        print(f"weldcell {args.command}: {err}", file=sys.stderr)
        return exit_code_for(err)
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
