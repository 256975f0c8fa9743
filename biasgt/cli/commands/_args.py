"""Command-line flags shared by several commands, defined once."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml

from pipeline.checks.options import CheckOptions, Repair
from pipeline.errors import ConfigError
from pipeline.io.registry import format_help


def add_window_arguments(parser: argparse.ArgumentParser, window_s: float, overlap: float) -> None:
    """``--window-s`` and ``--overlap`` (1-s windows with 50 % overlap by default: the callers' configs)."""
    parser.add_argument("--window-s", type=float, default=window_s, metavar="S",
                        help=f"window length in seconds (default {window_s:g})")
    parser.add_argument("--overlap", type=float, default=overlap, metavar="F",
                        help=f"overlap of consecutive windows, in [0, 1) (default {overlap:g})")


def add_reader_arguments(parser: argparse.ArgumentParser) -> None:
    """Options that choose how an input is read (passed to :func:`pipeline.io.load_sequence`)."""
    g = parser.add_argument_group("reader options")
    g.add_argument("--format", dest="fmt", metavar="FMT", default=None, help=format_help())
    g.add_argument("--imu-topic", metavar="TOPIC", help="bag topic with sensor_msgs/Imu (when there are several)")
    g.add_argument("--pose-topic", metavar="TOPIC", help="bag topic with the poses (PoseStamped, Odometry, ...)")
    g.add_argument("--tf-parent", metavar="FRAME", help="take poses from /tf: parent (world) frame")
    g.add_argument("--tf-child", metavar="FRAME", help="take poses from /tf: child (tracked) frame")
    g.add_argument("--csv-mapping", metavar="FILE", type=Path,
                   help="YAML file mapping a generic CSV's columns to biasgt fields")
    g.add_argument("--add-poses", dest="extra_poses", metavar="PATH[:KIND]", action="append", default=[],
                   help="merge poses from another input (TUM text, ASL pose or ground-truth CSV, bag), e.g. "
                        "'gt.txt:ground_truth' or 'vio.txt:vio'; repeatable. KIND: mocap, position_tracker, "
                        "vio, ground_truth")


def reader_kwargs_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """Reader keyword arguments from parsed options (loads ``--csv-mapping``)."""
    mapping = None
    path = getattr(args, "csv_mapping", None)
    if path is not None:
        try:
            mapping = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f"cannot read CSV mapping ({exc.strerror})", path=path,
                              hint="give an existing YAML file to --csv-mapping") from exc
        except yaml.YAMLError as exc:
            raise ConfigError(f"CSV mapping is not valid YAML ({exc})", path=path) from exc
        if not isinstance(mapping, dict):
            raise ConfigError("CSV mapping must be a YAML mapping of field: column", path=path)
    return {
        "fmt": getattr(args, "fmt", None),
        "name": getattr(args, "name", None),
        "csv_mapping": mapping,
        "imu_topic": getattr(args, "imu_topic", None),
        "pose_topic": getattr(args, "pose_topic", None),
        "tf_parent": getattr(args, "tf_parent", None),
        "tf_child": getattr(args, "tf_child", None),
        "extra_poses": list(getattr(args, "extra_poses", None) or []),
    }


def add_check_arguments(parser: argparse.ArgumentParser, *, repairs: bool = True) -> None:
    """Options that tune the input checks (and, with ``repairs``, the repairs allowed)."""
    g = parser.add_argument_group("check options")
    d = CheckOptions()
    if repairs:
        names = ", ".join(r.value for r in Repair)
        g.add_argument("--repair", default="", metavar="LIST",
                       help=f"comma list of allowed repairs ({names}) or 'all'; unit repairs touch only data "
                            "whose check fires")
    g.add_argument("--min-duration", type=float, default=d.min_duration_s, metavar="S",
                   help=f"shortest acceptable IMU span in seconds (default {d.min_duration_s:g})")
    g.add_argument("--gap-factor", type=float, default=d.gap_factor, metavar="X",
                   help=f"report steps longer than X times the median step as gaps (default {d.gap_factor:g})")
    g.add_argument("--allow-pose-only", action="store_true",
                   help="accept an input without IMU (NO_IMU becomes info)")
    g.add_argument("--ignore", default="", metavar="CODES",
                   help="comma list of non-fatal finding codes that are false positives (e.g. GYRO_DEGPS)")


def check_options_from_args(args: argparse.Namespace) -> CheckOptions:
    """:class:`CheckOptions` from parsed options."""
    return CheckOptions(
        min_duration_s=args.min_duration,
        gap_factor=args.gap_factor,
        allow_pose_only=args.allow_pose_only,
        ignore=frozenset(c for c in str(args.ignore or "").split(",") if c.strip()),
    )
