"""The ``biasgt`` command line: a thin layer over the importable stages.

Each subcommand lives in ``biasgt/cli/commands/<name>.py`` and exposes
``register(subparsers)`` which adds its parser and sets ``func(args) -> int``.
Known errors (:class:`pipeline.errors.BiasgtError`) print one line and exit 2.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline import __version__
from pipeline.files.atomic import check_output_location, no_space_error
from biasgt.cli.commands import (
    convert,
    evaluate,
    export,
    inspect,
    interpolate,
    predict,
    recover,
    report,
    run,
    simulate,
    train,
    validate,
    windows,
)
from pipeline.errors import BiasgtError

log = logging.getLogger("biasgt")

#: Every command, in the order of the help text (the workflow's order). A command is a module of
#: biasgt/cli/commands with ``register(subparsers)``; add one by importing it above and listing it here.
COMMANDS = (inspect, convert, simulate, recover, interpolate, validate, windows, train, evaluate, predict, export,
            report, run)


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
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output: debug messages too (the default shows progress: info)")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.register(sub)
    return parser


def log_level(verbose: int, quiet: bool) -> int:
    """The log level of ``-v`` (count) / ``-q``: DEBUG, WARNING, else INFO."""
    if quiet:
        return logging.WARNING
    return logging.DEBUG if verbose > 0 else logging.INFO


def _setup_logging(verbose: int, quiet: bool) -> None:
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    logging.getLogger().setLevel(log_level(verbose, quiet))  # also when a host application set up logging


class Terminated(BaseException):
    """SIGTERM received: unwinds like Ctrl-C, so every temporary output is removed on the way out."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated()


def _terminated(command: str) -> int:
    print(f"biasgt {command}: terminated (SIGTERM); nothing half-written was left", file=sys.stderr)
    return 128 + signal.SIGTERM


def _caused_by_termination(exc: BaseException) -> bool:
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, Terminated):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


def main(argv: Sequence[str] | None = None) -> int:
    try:
        parser = build_parser()
    except BiasgtError as exc:  # a registry's plugin that cannot load: named on one line
        print(f"biasgt: error: {exc}", file=sys.stderr)
        return exc.exit_code
    args = parser.parse_args(argv)
    _setup_logging(args.verbose, args.quiet)
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        if getattr(args, "out", None) is not None:  # every writing command names its output --out/OUT
            check_output_location(args.out, getattr(args, "out_kind", None))
        rc = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return rc
    except BiasgtError as exc:
        print(f"biasgt {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"biasgt {args.command}: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        return _terminated(args.command)
    except BrokenPipeError:
        # Output piped into e.g. `head`, which closed early: not an error of ours.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        # a full disk outside the atomic writers (which say so themselves): the same one line
        full = no_space_error(exc, getattr(args, "out", None) or Path.cwd() / "-")
        if full is None:
            if _caused_by_termination(exc):
                return _terminated(args.command)
            raise
        print(f"biasgt {args.command}: error: {full}", file=sys.stderr)
        return full.exit_code
    except Exception as exc:
        # SIGTERM inside an extension module's code (e.g. while gtsam initialises) surfaces as
        # that module's error, caused by Terminated: still a termination, not a crash.
        if _caused_by_termination(exc):
            return _terminated(args.command)
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
