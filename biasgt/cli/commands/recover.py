"""``biasgt recover``: bias ground truth from IMU + poses by joint optimisation (GTSAM).

Thin adapter over :func:`recovery.recover.recover` and :func:`recovery.outputs.write_recovery`.
"""

from __future__ import annotations

import argparse
import enum
import logging
from pathlib import Path

from pipeline.files.atomic import OutputKind
from biasgt.cli.commands._args import (
    add_check_arguments,
    add_reader_arguments,
    check_options_from_args,
    reader_kwargs_from_args,
)
from pipeline.ingest import load_checked
from pipeline.io.registry import readers_in_words
from pipeline.types import Sequence, Severity
from recovery.config import (
    ExtrinsicMode,
    NoiseEstimation,
    PoseFactorMode,
    RecoveryConfig,
    RobustLoss,
    TimeOffsetMode,
)

log = logging.getLogger(__name__)

#: Input findings that ``recover`` repeats before its solve: they change what the result is worth.
SAID_BEFORE_THE_SOLVE = ("IMU_RATE_MISMATCH",)


def _values(kind: type[enum.Enum]) -> list[str]:
    return [m.value for m in kind]


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "recover",
        help="recover the IMU bias trajectory (with marginal std) from IMU + poses",
        description=(
            "Jointly optimise the IMU readings of INPUT with one of its pose streams (mocap, position tracker, "
            "VIO or a dataset's ground truth) in a GTSAM factor graph and write, atomically, DIR/bias.csv "
            "(bias per keyframe with marginal std), DIR/recovery.json (clock offset, extrinsic, gravity, noise "
            "used, residuals, outliers, warnings) and DIR/trajectory_tum.txt. The clock offset, the extrinsic "
            "T_imu_pose (when not in the calibration), the gravity direction and the bias random walks are "
            "estimated from the data unless fixed by options or --config. Example (EuRoC IMU + its GT poses as "
            "TUM text): biasgt recover mav0_folder --add-poses gt.txt:ground_truth --poses gt --out rec"
        ),
    )
    p.add_argument("input", metavar="INPUT",
                   help=f"{readers_in_words()} (see --format; more pose files: --add-poses)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (replaced atomically)")
    p.add_argument("--poses", metavar="STREAM", default=None,
                   help="pose stream to use (default: vicon0 > mocap0 > leica0 > other mocap > ... > ground truth)")
    p.add_argument("--name", default=None, help="sequence name (default: from the input)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE.yaml",
                   help="recovery options (YAML mapping; see recovery.config.RecoveryConfig)")
    p.add_argument("--keyframe-rate", type=float, default=None, metavar="HZ",
                   help="keyframes per second (default: every pose sample's information -- 10-Hz keyframes "
                        "fusing the samples between them for 6-DoF streams, one keyframe per sample otherwise)")
    p.add_argument("--time-offset-s", type=float, default=None, metavar="X",
                   help="seconds to add to pose stamps to put them on the IMU clock (fixes the offset)")
    p.add_argument("--estimate-time-offset", dest="estimate_time_offset", action=argparse.BooleanOptionalAction,
                   default=None, help="estimate the clock offset (default: yes, except for ground-truth poses)")
    p.add_argument("--extrinsic", choices=_values(ExtrinsicMode), default=None,
                   help="T_imu_pose from the calibration (known) or from the data (estimate); "
                        "default auto: known when the calibration has it")
    p.add_argument("--pose-factors", choices=_values(PoseFactorMode), default=None,
                   help="absolute pose priors or relative (VIO) constraints; default by source kind")
    p.add_argument("--robust", choices=_values(RobustLoss), default=None, help="robust loss on pose factors")
    p.add_argument("--noise", choices=_values(NoiseEstimation), default=None,
                   help="bias random walks / pose sigma by maximum evidence (default) or as given")
    p.add_argument("--no-marginals", action="store_true", help="skip the bias std columns (faster; NaN)")
    p.add_argument("--no-pose-fusion", action="store_true",
                   help="keyframes are single pose samples (with --keyframe-rate, the samples between them are "
                        "dropped; without, every sample is a keyframe: ~5-10x slower on 100-Hz mocap)")
    p.add_argument("--keep-frame-disagreement", action="store_true",
                   help="write a result whose IMU and pose stream disagree about the body frame (an implausible "
                        "bias), with a warning, instead of refusing it: 'biasgt validate' then FAILs it")
    add_reader_arguments(p)
    add_check_arguments(p)
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def config_from_args(args: argparse.Namespace):
    """RecoveryConfig from ``--config`` plus command-line overrides."""

    cfg = RecoveryConfig.from_yaml(args.config) if args.config is not None else RecoveryConfig()
    changes = {}
    if args.keyframe_rate is not None:
        changes["keyframe_rate_hz"] = args.keyframe_rate
    if args.time_offset_s is not None:
        changes["time_offset_s"] = args.time_offset_s
        changes["time_offset_mode"] = TimeOffsetMode.ESTIMATE if args.estimate_time_offset else TimeOffsetMode.FIXED
    elif args.estimate_time_offset is not None:
        changes["time_offset_mode"] = TimeOffsetMode.ESTIMATE if args.estimate_time_offset else TimeOffsetMode.FIXED
    if args.extrinsic is not None:
        changes["extrinsic_mode"] = args.extrinsic
    if args.pose_factors is not None:
        changes["pose_factor_mode"] = args.pose_factors
    if args.robust is not None:
        changes["robust_loss"] = args.robust
    if args.noise is not None:
        changes["noise_estimation"] = args.noise
    if args.no_pose_fusion:
        changes["pose_fusion"] = False
    if args.no_marginals:
        changes["compute_marginals"] = False
    if args.keep_frame_disagreement:
        changes["keep_frame_disagreement"] = True
    if changes:
        merged = cfg.to_dict()
        merged.update(changes)
        cfg = RecoveryConfig.from_dict(merged, path=args.config)
    return cfg


def run(args: argparse.Namespace) -> int:
    from recovery.recover import recover, write_recovery  # gtsam: off the CLI start-up path

    config = config_from_args(args)
    seq = load_checked(args.input, reader_kwargs_from_args(args), repairs=args.repair,
                       check_options=check_options_from_args(args), action="recover")
    stream = args.poses
    if stream is None:
        print(chosen_stream_sentence(seq))
    for f in seq.findings:
        if f.code in SAID_BEFORE_THE_SOLVE and f.severity is Severity.WARNING:
            print(f"  warning: {f.code}: {f.message}")
    result = recover(seq, pose_stream=stream, config=config)
    write_recovery(result, args.out)
    r = result.report
    print(f"wrote {args.out} ({r['keyframes']} keyframes over {r['duration_s']:.1f} s from '{r['pose_stream']}', "
          f"offset {r['pose_time_offset_s'] * 1e3:+.3f} ms, {outlier_counts(r)}, "
          f"{r['runtime_s']:.1f} s)")
    for w in result.warnings:
        print(f"  warning: {w}")
    return 0


def chosen_stream_sentence(seq: Sequence) -> str:
    """Which pose stream the default order chose, why, and the others (said before the solve)."""
    from pipeline.io import ADDED_POSE_STREAMS_KEY, list_pose_streams, select_pose_stream

    name, poses = select_pose_stream(seq)
    added = seq.metadata.get(ADDED_POSE_STREAMS_KEY) or ()
    why = ("given with --add-poses" if name in added
           else f"{poses.source_kind.value}, first in the default order")
    others = [s for s in list_pose_streams(seq) if s != name]
    return (f"pose stream: '{name}' ({why})" + (f"; also in the input: {', '.join(others)} (choose with --poses NAME)"
                                                 if others else ""))


def outlier_counts(report: dict) -> str:
    """Which poses were rejected: keyframe poses (the solve's robust loss), with pose fusion pose samples
    (before fusing them into keyframes), and placeholder frames; ``outliers_rejected`` is their sum."""
    samples = int((report.get("pose_fusion") or {}).get("samples_rejected") or 0)
    placeholders = int(report.get("placeholders_rejected") or 0)
    keyframes = int(report["outliers_rejected"]) - samples - placeholders
    return (f"outliers rejected: {keyframes} of {report['keyframes']} keyframe poses"
            + (f", {samples} pose samples before fusion" if samples else "")
            + (f", {placeholders} placeholder frames" if placeholders else ""))
