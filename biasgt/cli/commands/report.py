"""``biasgt report``: the per-sequence dataset quality report (one self-contained HTML file).

Thin adapter over :func:`reports.quality.build_quality_report`.
"""

from __future__ import annotations

import argparse
import logging
import textwrap
from pathlib import Path

from pipeline.files.atomic import OutputKind
from biasgt.cli.commands._args import (
    add_check_arguments,
    add_reader_arguments,
    check_options_from_args,
    reader_kwargs_from_args,
)
from pipeline.errors import ConfigError
from pipeline.ingest import load_checked

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "report",
        help="write the quality report of one sequence, or the dataset page over all (self-contained HTML)",
        description=textwrap.fill(
            "Write one self-contained HTML page (figures embedded, no network needed) that says whether a "
            "sequence's recovered bias is usable and why: the validation verdict in plain words, the streams and "
            "input checks, the estimated calibration (clock offset, extrinsic, gravity, noise), the recovered bias "
            "with its uncertainty, residuals, the integration error per bias source, and the IMU's Allan deviation. "
            "Give a results folder and --sequence NAME (reads results/ingest|recovery|validation/NAME), or the "
            "input and the stage folders with --ingest/--recovery/--validation; the input may be a canonical store "
            "or any input that recover and validate read (an ASL folder, a bag, ...), with the same reader options "
            "(--add-poses, --format, ...). Missing recovery or validation outputs are "
            "reported in the page; a missing ingest store is an error. Prints the path of the written file. "
            "A results folder without --sequence gives the dataset page over every sequence instead "
            "(RESULTS_DIR/report/index.html: verdicts, windows per split and what was left out, one sortable row "
            "per sequence linking its report, Table I's averages, every recovered bias in one figure)."
        ),
        epilog=("examples:\n  biasgt report results --sequence MH_01_easy --out MH_01_easy.html\n"
                "  biasgt report results                   the dataset page: results/report/index.html\n"
                "  biasgt report --ingest data/V1_01_easy --add-poses data/V1_01_easy/ov_data/V1_01_easy_original.txt"
                ":ground_truth \\\n      --recovery out/V1_01 --validation out/V1_01/validation --out out/V1_01/quality.html"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("results", metavar="RESULTS_DIR", nargs="?", type=Path, default=None,
                   help="the workflow's results/ folder (or the folder holding it)")
    p.add_argument("--sequence", metavar="NAME", default=None, help="sequence name (with RESULTS_DIR)")
    p.add_argument("--ingest", metavar="INPUT", type=Path, default=None,
                   help="the sequence: its canonical store or any input recover reads (overrides "
                        "RESULTS_DIR/ingest/NAME)")
    p.add_argument("--recovery", metavar="DIR", type=Path, default=None,
                   help="the recovery output folder (bias.csv, recovery.json; overrides RESULTS_DIR/recovery/NAME)")
    p.add_argument("--validation", metavar="DIR", type=Path, default=None,
                   help="the validation output folder (validation.json, windows.parquet; overrides "
                        "RESULTS_DIR/validation/NAME)")
    p.add_argument("--out", metavar="FILE.html", type=Path, default=None,
                   help="the HTML file to write (default with RESULTS_DIR: RESULTS_DIR/report/NAME/report.html)")
    add_reader_arguments(p)
    add_check_arguments(p)
    p.set_defaults(func=run, out_kind=OutputKind.FILE)


def resolve_inputs(args: argparse.Namespace) -> tuple[Path, Path | None, Path | None, Path]:
    """``(ingest, recovery, validation, out)`` from the command-line arguments.

    Raises:
        ConfigError: Neither RESULTS_DIR with --sequence nor --ingest given, or no --out.
    """
    from reports.quality import stage_dirs  # matplotlib: off the CLI start-up path

    ingest, recovery, validation, out = args.ingest, args.recovery, args.validation, args.out
    if args.results is not None:
        if not args.sequence:
            raise ConfigError("RESULTS_DIR with --ingest needs --sequence NAME", field="--sequence",
                              hint="name the sequence, e.g. --sequence MH_01_easy (RESULTS_DIR alone: the dataset page)")
        found = stage_dirs(args.results, args.sequence)
        ingest = ingest or found["ingest"]
        recovery = recovery or found["recovery"]
        validation = validation or found["validation"]
        if out is None:
            root = found["ingest"].parent.parent if found["ingest"] is not None else args.results
            out = root / "report" / args.sequence / "report.html"
    if ingest is None:
        raise ConfigError("no input given", field="--ingest",
                          hint="give RESULTS_DIR --sequence NAME, or --ingest DIR (and --recovery/--validation)")
    if out is None:
        raise ConfigError("no output file given", field="--out", hint="add --out FILE.html")
    return ingest, recovery, validation, out


def run(args: argparse.Namespace) -> int:
    from pipeline.store import is_store

    if args.results is not None and not args.sequence and args.ingest is None:
        from reports.dataset import build_dataset_report  # matplotlib: off the CLI start-up path

        print(build_dataset_report(args.results, args.out))
        return 0
    from reports.quality import build_quality_report  # matplotlib: off the CLI start-up path

    ingest, recovery, validation, out = resolve_inputs(args)
    sequence = None
    if Path(ingest).exists() and (not is_store(ingest) or args.extra_poses or args.fmt):
        sequence = load_checked(ingest, reader_kwargs_from_args(args), repairs=args.repair,
                                check_options=check_options_from_args(args), action="report")
    path = build_quality_report(ingest, recovery_dir=recovery, validation_dir=validation, out_path=out,
                                sequence=sequence)
    print(path)
    return 0
