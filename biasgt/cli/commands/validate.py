"""``biasgt validate``: judge a bias trajectory by 1-s integration error (adapter over validation.validate)."""

from __future__ import annotations

import argparse
from functools import partial
import logging
from pathlib import Path
from typing import Any

from pipeline.files.atomic import OutputKind
from biasgt.cli.commands._args import (
    add_check_arguments,
    add_reader_arguments,
    add_window_arguments,
    check_options_from_args,
    reader_kwargs_from_args,
)
from pipeline.errors import ValidationError
from pipeline.ingest import load_checked
from pipeline.types import Verdict
from validation.config import CrossvalMode, ValidationConfig

log = logging.getLogger(__name__)

DESCRIPTION = """\
Validate bias trajectories the way AirIMU evaluates IMU models: cut the IMU into WINDOW_S windows
(overlapping by OVERLAP), integrate each from the reference position, velocity and orientation with
'imu - bias' and gravity, and compare the end state with the reference:
  PRMSE = sqrt(mean |p_end - p_ref|^2) [m],   ROE = mean |Log(R_ref^T R_end)| [deg].

Sources compared on the same windows: zero bias, a constant bias (the candidate's mean over the first
window), the dataset's own ground-truth bias (when the input has one), the bias under test
(--recovery DIR's bias.csv, else the first unnamed --bias), and every --bias NAME=FILE.

Reference: the input's ground-truth state when it has one, else (or with --poses STREAM) a pose stream
moved to the IMU frame and clock with the recovery's T_imu_pose and pose_time_offset_s (identity and 0
without --recovery, which is right only for poses of the IMU on its clock).

Writes OUT/validation.json and OUT/windows.parquet atomically.
"""

EPILOG = """\
exit status: 0 PASS or WARN, 1 FAIL, 2 bad input (one-line error, nothing written).

examples:
  biasgt validate data/V1_01_store --recovery out/V1_01/recovery --out out/V1_01/validation
  biasgt validate sim01 --bias out/sim01/bias.csv --bias openvins=V1_01_easy.csv --out out/val
  biasgt validate MH_01 --add-poses MH_01/ov_data/MH_01_easy.txt:ground_truth --poses MH_01_easy \
      --recovery out/MH_01 --window-s 2 --overlap 0 --out out/val2   (Leica recovery, GT reference)
"""


#: The options' defaults, shown by the parser (validation.config is light: no torch at start-up).
DEFAULTS = ValidationConfig()


def description() -> str:
    """The help text: :data:`DESCRIPTION` and the verdict's rules, from their registry (validation.rules)."""
    from validation.rules import rules_text

    return (DESCRIPTION + "\nVerdict: FAIL when a FAIL rule fires, WARN when only WARN rules do, PASS otherwise. "
            "validation.json\nlists each reason with its rule's code (reason_codes). The rules, in reason order "
            "(CODE (LEVEL): what):\n" + rules_text())


def _format_help_with_rules(parser: argparse.ArgumentParser) -> str:
    """``validate --help``: the parser's help with :func:`description` (the rules) as its description."""
    parser.description = description()
    return argparse.ArgumentParser.format_help(parser)


def register(subparsers: argparse._SubParsersAction) -> None:
    d = DEFAULTS
    p = subparsers.add_parser(
        "validate",
        help="judge a bias trajectory by 1-s integration error (PRMSE, ROE) with a PASS/WARN/FAIL verdict",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.format_help = partial(_format_help_with_rules, p)  # the rules' registry loads only when help is asked
    p.add_argument("sequence", metavar="SEQUENCE", help="input with IMU (store folder, ASL/EuRoC folder, bag, ...)")
    p.add_argument("--bias", action="append", default=[], metavar="[NAME=]FILE",
                   help="bias file: bias.csv / interpolated .csv/.parquet, or a EuRoC/OpenVINS state CSV; the "
                        "first unnamed one is the bias under test unless --recovery is given (repeatable)")
    p.add_argument("--recovery", type=Path, metavar="DIR",
                   help="recovery output folder: its bias.csv is the bias under test; recovery.json gives the clock "
                        "offset, T_imu_pose, gravity and the random walks")
    p.add_argument("--poses", metavar="STREAM", help="use this pose stream as reference (default: ground-truth "
                                                     "state, else the default pose stream)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (written atomically)")
    add_window_arguments(p, d.window_s, d.overlap)
    p.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"),
                   help="gravity in the reference world frame for every row, m/s^2 (default: 0 0 -|g| for each "
                        "row, the recovery's own gravity for the recovered bias against the stream it was fitted "
                        "to)")
    p.add_argument("--margin", type=float, default=d.margin, metavar="F",
                   help=f"relative margin of the FAIL rule (default {d.margin:g})")
    p.add_argument("--flag-k", type=float, default=d.flag_k, metavar="K",
                   help=f"flag windows whose error exceeds K x the median (default {d.flag_k:g})")
    p.add_argument("--velocity-cutoff-hz", type=float, default=d.velocity_cutoff_hz, metavar="HZ",
                   help="smoothing cutoff for pose-derived velocity (default: chosen from the pose noise)")
    p.add_argument("--crossval", choices=[m.value for m in CrossvalMode], default=d.crossval.value,
                   help="cross-validate the recovery by time blocks: recover again without the poses of each fold "
                        "of blocks ('recovered_heldout'); auto: when the reference is the stream the bias was "
                        "fitted to, where the held-out blocks judge the verdict (default %(default)s)")
    p.add_argument("--crossval-block-s", type=float, default=d.crossval_block_s, metavar="S",
                   help=f"block length of the cross-validation (default {d.crossval_block_s:g})")
    p.add_argument("--crossval-folds", type=int, default=d.crossval_folds, metavar="N",
                   help=f"folds of --crossval-block-s (default {d.crossval_folds})")
    add_reader_arguments(p)
    add_check_arguments(p)
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def _split_bias_arg(value: str) -> tuple[str | None, Path]:
    """``NAME=FILE`` or ``FILE`` (a value naming an existing file is never split)."""
    if Path(value).exists() or "=" not in value:
        return None, Path(value)
    name, _, path = value.partition("=")
    return (name.strip() or None), Path(path)


def _format_table(result: Any) -> str:
    rows = [("source", "kind", "PRMSE [m]", "ROE [deg]", "windows", "flagged")]
    for name, m in result.sources.items():
        mark = " *" if name == result.candidate else ""
        rows.append((name + mark, m.kind.value, f"{m.prmse_m:.4f}", f"{m.roe_deg:.4f}", str(m.windows),
                     str(int(m.flagged.sum()))))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))) for r in rows]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from validation.validate import validate_inputs, write_validation  # torch: off the CLI start-up path

    if not args.bias and args.recovery is None:
        raise ValidationError("nothing to validate", field="--bias",
                              hint="give --recovery DIR or --bias FILE")
    config = ValidationConfig(window_s=args.window_s, overlap=args.overlap, margin=args.margin,
                              flag_k=args.flag_k, velocity_cutoff_hz=args.velocity_cutoff_hz,
                              crossval=args.crossval, crossval_block_s=args.crossval_block_s,
                              crossval_folds=args.crossval_folds)
    seq = load_checked(args.sequence, reader_kwargs_from_args(args), repairs=args.repair,
                       check_options=check_options_from_args(args), action="validate")
    if seq.imu is None:
        raise ValidationError(f"'{args.sequence}' has no IMU to integrate", path=args.sequence,
                              hint="give an input with IMU readings")
    result = validate_inputs(seq, recovery_dir=args.recovery, bias_files=[_split_bias_arg(v) for v in args.bias],
                             pose_stream=args.poses, gravity_mps2=args.gravity, config=config)
    write_validation(result, args.out)

    print(f"{result.sequence}: {result.windows_dropped['kept']} of {result.windows_dropped['candidates']} "
          f"{config.window_s:g}-s windows ({result.reference['kind']} reference)")
    print(_format_table(result))
    print(f"verdict: {result.verdict.value} (* = bias under test)")
    for reason, code in zip(result.reasons, result.reason_codes):
        print(f"  - {reason} [{code}]")
    for step in result.next_steps:
        print(f"  next: {step}")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"wrote {args.out}")
    return 1 if result.verdict is Verdict.FAIL else 0
