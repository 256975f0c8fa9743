"""``biasgt convert``: read an input, check it, apply the allowed repairs, write the canonical store.

Refuses (exit 2, one line naming the ``--repair`` flag that would help, nothing
written) while a fatal or an unrepaired repairable problem remains.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.files.atomic import OutputKind
from pipeline.checks.repairs import parse_repairs
from biasgt.cli.commands._args import (
    add_check_arguments,
    add_reader_arguments,
    check_options_from_args,
    reader_kwargs_from_args,
)
from pipeline.ingest import ingest
from pipeline.types import Severity


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "convert",
        help="check an input, apply allowed repairs, and write the canonical Parquet store",
        description=(
            "Read INPUT, run the input checks (see 'biasgt inspect'), apply only the repairs named in --repair, "
            "check again, and write the canonical store to --out (atomically). Refuses, writing nothing, while a "
            "fatal or an unrepaired repairable problem remains. Findings and repairs are recorded in the store's "
            "sequence.yaml."
        ),
    )
    p.add_argument("input", metavar="INPUT", help="file or folder to convert")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="store folder to write")
    p.add_argument("--name", default=None, help="sequence name (default: from the input)")
    p.add_argument("--resample-hz", type=float, default=None, metavar="HZ",
                   help="resample the IMU to HZ (e.g. a model's or the calibration's rate) with an anti-alias "
                        "filter; the store's calibration rate becomes HZ")
    add_reader_arguments(p)
    add_check_arguments(p)
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def run(args: argparse.Namespace) -> int:

    repairs = parse_repairs(args.repair)
    seq = ingest(args.input, args.out, repairs=repairs, reader_kwargs=reader_kwargs_from_args(args),
                 check_options=check_options_from_args(args), resample_hz=args.resample_hz)
    parts = []
    if seq.imu is not None:
        parts.append(f"imu {len(seq.imu)} rows, {seq.imu.duration_s:.1f} s")
    parts += [f"poses/{k} {len(v)} rows" for k, v in seq.poses.items()]
    if seq.ground_truth is not None:
        parts.append(f"ground_truth {len(seq.ground_truth)} rows")
    print(f"wrote {args.out} ({seq.name}: {'; '.join(parts)})")
    for change in seq.metadata.get("repairs", []):
        print(f"  repaired: {change}")
    for f in seq.findings:
        if f.severity == Severity.WARNING:
            print(f"  warning: {f.code} ({f.stream}): {f.message}")
    return 0
