"""The ``biasgt`` command line: a thin layer over the importable stages.

Each subcommand lives in ``pipeline/commands/<name>.py`` and exposes
``register(subparsers)`` which adds its parser and sets ``func(args) -> int``.
Known errors (:class:`pipeline.errors.BiasgtError`) print one line and exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from pipeline import __version__
from pipeline.errors import BiasgtError

log = logging.getLogger("biasgt")

# Order is the order of the help text: the workflow's order.
COMMANDS = (
    "inspect",
    "convert",
    "simulate",
    "recover",
    "interpolate",
    "validate",
    "windows",
    "train",
    "evaluate",
    "predict",
    "export",
    "report",
    "run",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="biasgt",
        description=(
            "Extract ground-truth IMU bias from recorded IMU + pose data, check its quality, "
            "and train models that predict bias from IMU readings alone."
        ),
        epilog="Run 'biasgt COMMAND --help' for the options of one command.",
    )
    parser.add_argument("--version", action="version", version=f"biasgt {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"pipeline.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"pipeline.commands.{name}":
                continue  # command not available in this build
            raise
        module.register(sub)
    return parser


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.INFO if verbose <= 1 else logging.DEBUG)
    if verbose == 0 and not quiet:
        level = logging.INFO
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args.verbose, args.quiet)
    try:
        return int(args.func(args) or 0)
    except BiasgtError as exc:
        print(f"biasgt {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"biasgt {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Output piped into e.g. `head`, which closed early: not an error of ours.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
