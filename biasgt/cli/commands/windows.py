"""``biasgt windows``: cut recovered sequences into a versioned training dataset (adapter over training.data.windows)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from pipeline.files.atomic import OutputKind
from biasgt.cli.commands._args import add_window_arguments
from pipeline.errors import ConfigError
from pipeline.types import Split
from training.data.windows_config import WindowConfig

log = logging.getLogger(__name__)

SPLITS = tuple(s.value for s in Split)

DESCRIPTION = """\
Cut sequences into fixed-length IMU windows for training, exactly as 'biasgt validate' cuts them
(WINDOW_S long, overlapping by OVERLAP). Each window holds the IMU [T, 6], the recovered bias
interpolated to the IMU stamps [T, 6] with its sigma, the reference start and end states (the
ground-truth state when the input has one, else the pose stream moved with the recovery's clock
offset and T_imu_pose), its stamps and the sequence name. Windows crossing an IMU gap, outside the
recovered bias span or without a reference are dropped and counted.

Sequences come from --seq NAME SPLIT STORE RECOVERY_DIR (repeatable), and/or from --splits FILE.yaml
({train: [NAME, ...], val: [...], test: [...], none: [...]}; split none: not windowed) with
--results DIR, which takes each NAME's store from DIR/ingest/NAME and its recovery from
DIR/recovery/NAME (the workflow layout). A sequence belongs to exactly one split; naming it twice is an error. Normalisation statistics
come from the train split only.

All sequences must share one uniform IMU rate; --resample-hz HZ resamples those that do not
(linear interpolation onto a uniform grid, gaps kept). Writes OUT atomically:
  OUT/manifest.json             sequences, splits, window counts, drops, config + hash, code version,
                                normalisation statistics (train split)
  OUT/sequences/NAME/*.npy      arrays, memory-mapped by training.data.dataset.WindowDataset
"""

EPILOG = """\
examples:
  biasgt windows --seq MH_01 train stores/MH_01 rec/MH_01 --seq MH_02 test stores/MH_02 rec/MH_02 --out ds
  biasgt windows --splits config/euroc_splits.yaml --results results --out results/windows
  biasgt windows --splits splits.yaml --results results --window-s 2 --overlap 0 --resample-hz 200 --out ds2
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "windows",
        help="cut recovered sequences into a versioned training dataset (IMU, bias, sigma, states)",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--seq", nargs=4, action="append", default=[], metavar=("NAME", "SPLIT", "STORE", "RECOVERY_DIR"),
                   help=f"a sequence: its name, split ({'/'.join(SPLITS)}), store folder and recovery folder "
                        "(repeatable)")
    p.add_argument("--splits", type=Path, metavar="FILE.yaml",
                   help="split -> sequence names (train/val/test/none); needs --results")
    p.add_argument("--results", type=Path, metavar="DIR",
                   help="workflow results folder holding ingest/NAME and recovery/NAME (with --splits)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="dataset folder (written atomically)")
    d = WindowConfig()  # the defaults, defined once
    add_window_arguments(p, d.window_s, d.overlap)
    p.add_argument("--resample-hz", type=float, default=d.resample_hz, metavar="HZ",
                   help="resample IMU streams not at HZ onto a uniform HZ grid (default: refuse other rates)")
    p.add_argument("--gap-factor", type=float, default=d.gap_factor, metavar="K",
                   help=f"an IMU interval longer than K x the nominal one is a gap (default {d.gap_factor:g})")
    p.add_argument("--validation", action="append", default=[], metavar="NAME=DIR",
                   help="the 'biasgt validate' folder of a --seq sequence: its verdict decides whether the "
                        "sequence enters the dataset (PASS; WARN with --accept-warn; never FAIL); repeatable. "
                        "With --results, results/validation/NAME is used; a sequence without a validation is refused "
                        "unless --allow-unvalidated")
    p.add_argument("--reference", action="append", default=[], metavar="NAME=STREAM",
                   help="the pose stream a --seq sequence's windows take their start and end states from, as "
                        "'biasgt validate --poses' (default: the ground-truth state, else the recovery's stream; "
                        "needed when the recovery fitted positions only, e.g. Leica); repeatable")
    p.add_argument("--accept-warn", action="store_true", default=d.accept_warn,
                   help="take sequences whose verdict is WARN too")
    p.add_argument("--allow-unvalidated", action="store_true",
                   help="take sequences without a validation (no --validation, no results/validation/NAME) as "
                        "they are; without it they are refused")
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def run(args: argparse.Namespace) -> int:
    from training.data.records import write_window_dataset
    from training.data.windows import (  # torch: off the CLI start-up path
        WindowSource,
        format_summary,
        read_splits_file,
        sources_from_results,
    )

    config = WindowConfig(window_s=args.window_s, overlap=args.overlap, resample_hz=args.resample_hz,
                          gap_factor=args.gap_factor, accept_warn=args.accept_warn)
    validations = {name: Path(folder) for name, folder in (_name_value(v, "--validation") for v in args.validation)}
    references = dict(_name_value(v, "--reference") for v in args.reference)
    for option, given in (("--validation", validations), ("--reference", references)):
        unknown = sorted(set(given) - {name for name, *_ in args.seq})
        if unknown:
            raise ConfigError(f"{option} names '{unknown[0]}', which no --seq gives", field=option,
                              hint="write NAME=VALUE with the NAME of a --seq sequence")
    sources = []
    for name, split, store, recovery in args.seq:
        if split not in SPLITS:
            raise ConfigError(f"unknown split '{split}' for sequence '{name}'", field="--seq",
                              hint=f"use one of {', '.join(SPLITS)}")
        sources.append(WindowSource(name, split, Path(store), Path(recovery), validations.get(name),
                                    references.get(name)))
    if (args.splits is None) != (args.results is None):
        raise ConfigError("--splits and --results go together", field="--splits" if args.results is None
                          else "--results", hint="give both, e.g. --splits splits.yaml --results results")
    if args.splits is not None:
        sources += sources_from_results(read_splits_file(args.splits), args.results)
    if not sources:
        raise ConfigError("no sequence given", field="--seq",
                          hint="give --seq NAME SPLIT STORE RECOVERY_DIR or --splits FILE --results DIR")
    if not args.allow_unvalidated:
        _refuse_unvalidated(sources, args.results)
    manifest = write_window_dataset(sources, args.out, config)  # with its sequence records, as one
    print(f"{len(manifest.sequences)} sequences, {manifest.window_samples} samples per window "
          f"({config.window_s:g} s at {manifest.rate_hz:g} Hz, overlap {config.overlap:g}), "
          f"config {manifest.config_hash}")
    print(format_summary(manifest))
    print(f"wrote {args.out}")
    return 0


def _name_value(value: str, option: str) -> tuple[str, str]:
    name, sep, rest = value.partition("=")
    if not sep or not name or not rest:
        raise ConfigError(f"{option} {value!r} is not NAME=VALUE", field=option,
                          hint=f"e.g. {option} rec01=" + ("out/rec01/validation" if option == "--validation"
                                                           else "groundtruth_poses"))
    return name, rest


def _refuse_unvalidated(sources: list, results: Path | None) -> None:
    """Refuse the windowed sequences without a validation folder (their verdict cannot gate them)."""
    missing = [src for src in sources if src.validation_dir is None and src.split.windowed]
    if not missing:
        return
    names = ", ".join(f"'{src.name}'" for src in missing)
    where = (f"no folder {results / 'validation' / missing[0].name}" if results is not None
             and _from_results(missing[0], results) else "no --validation NAME=DIR")
    raise ConfigError(f"{len(missing)} sequence(s) not validated: {names} ({where}); an unvalidated sequence "
                      "may be a recording that 'biasgt validate' FAILs", field="--allow-unvalidated",
                      hint="run 'biasgt validate' for it (the workflow's validate stage) and give its folder, or "
                           "pass --allow-unvalidated to take it unchecked")


def _from_results(src, results: Path) -> bool:
    """Whether ``src`` was taken from the --results layout (its store is results/ingest/NAME)."""
    return Path(src.store_dir) == Path(results) / "ingest" / src.name
