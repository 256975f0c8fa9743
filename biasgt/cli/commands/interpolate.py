"""``biasgt interpolate``: recovered keyframe bias -> bias at every IMU stamp, with sigma."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from interpolation.config import InterpolationConfig, InterpolationMethod
from pipeline.files.atomic import OutputKind
from biasgt.cli.commands._args import add_reader_arguments, reader_kwargs_from_args

log = logging.getLogger(__name__)
_DEFAULTS = InterpolationConfig()

DESCRIPTION = """\
Interpolate a recovery's keyframe bias (RECOVERY_DIR/bias.csv) to every IMU stamp of INPUT, with its
standard deviation. Default 'linear': for a random-walk bias this is the mean of the Brownian bridge
between keyframes; the sigma adds the bridge variance (random-walk strengths from recovery.json) to the
keyframe marginals (see interpolation/bias.py). 'cubic' gives a smooth (Akima) curve with the same sigma.
Stamps outside the recovered span get the end values, flagged and counted, their sigma growing with the
random walk (the IMU usually starts before and ends after the poses); --no-clamp refuses them instead.

Writes OUT (.parquet or .csv, by suffix) with the columns of bias.csv:
  t_ns,bg_x,bg_y,bg_z,ba_x,ba_y,ba_z,bg_x_std,...,ba_z_std
and, for a .parquet OUT, the same table as CSV next to it (unless --no-csv). Written atomically.
"""

EPILOG = """\
examples:
  biasgt interpolate out/V1_01/recovery --imu data/V1_01_easy --out out/V1_01/bias_imu.parquet
  biasgt interpolate results/recovery/sim01 --imu results/ingest/sim01 --method cubic --out bias.csv
"""


def register(subparsers: argparse._SubParsersAction) -> None:

    p = subparsers.add_parser(
        "interpolate",
        help="bias at every IMU stamp (with sigma) from a recovery's keyframes",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("recovery", metavar="RECOVERY_DIR", type=Path, help="folder written by 'biasgt recover'")
    p.add_argument("--imu", required=True, metavar="INPUT",
                   help="input whose IMU stamps to interpolate to (store, ASL folder, bag, ...)")
    p.add_argument("--out", required=True, type=Path, metavar="FILE", help="output .parquet or .csv")
    p.add_argument("--method", choices=[m.value for m in InterpolationMethod], default=_DEFAULTS.method.value,
                   help=f"interpolation of the mean (default {_DEFAULTS.method.value}; linear = Brownian-bridge mean)")
    p.add_argument("--clamp", action=argparse.BooleanOptionalAction, default=_DEFAULTS.clamp,
                   help="hold the end values beyond the recovered span, flagged (--no-clamp: refuse such stamps)")
    p.add_argument("--no-csv", action="store_false", dest="write_csv", default=_DEFAULTS.write_csv,
                   help="with a .parquet OUT, do not also write the CSV twin")
    add_reader_arguments(p)
    p.set_defaults(func=run, out_kind=OutputKind.FILE)


def run(args: argparse.Namespace) -> int:
    from interpolation.interpolate import interpolate_recovery  # pandas/pyarrow: off the CLI start-up path

    written = interpolate_recovery(
        args.recovery,
        args.imu,
        args.out,
        InterpolationConfig(method=InterpolationMethod(args.method), clamp=args.clamp, write_csv=args.write_csv),
        reader_kwargs=reader_kwargs_from_args(args),
    )
    for path in written:
        print(path)
    return 0
