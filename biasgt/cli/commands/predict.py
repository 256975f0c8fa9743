"""``biasgt predict``: the bias of a recording from its IMU alone, with a trained model (adapter over training.deploy.predict)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biasgt.cli.commands._args import (
    add_check_arguments,
    add_reader_arguments,
    check_options_from_args,
    reader_kwargs_from_args,
)

DESCRIPTION = """\
Predict the IMU bias of a recording from its readings alone (no poses needed), with a model trained
by 'biasgt train' and rebuilt from its checkpoint. INPUT is anything 'biasgt inspect' reads (with an
IMU; the formats: --format below), checked as 'biasgt recover' checks it (an
accelerometer in g or a gyro in deg/s is refused unless repaired with --repair). The IMU is cut into
consecutive windows of
the model's length; a diffusion model draws K samples per window (--samples).

Writes OUT.csv and OUT.parquet (atomically): per IMU sample t_ns, the sample mean bg_x..ba_z
(rad/s, m/s^2), its spread bg_x_std..ba_z_std, the window it came from and the central 95% interval
(bg_x_q025.., bg_x_q975..). The first columns are those of a recovery's bias.csv, so the file can be
judged with 'biasgt validate INPUT --bias OUT.csv' where poses exist.
"""

EPILOG = """\
examples:
  biasgt predict --checkpoint results/training/diffusion_rnn/seed0 recordings/flight_07 --out flight_07_bias
  biasgt predict --checkpoint run/best.pt data.bag --samples 20 --out bias.csv
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    from training.config import SAMPLES, STEPS, Sampler

    p = subparsers.add_parser("predict", help="predict the bias of a recording from its IMU with a trained model",
                              description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", type=Path, metavar="INPUT", help="recording (any readable input) or canonical store")
    p.add_argument("--checkpoint", required=True, type=Path, metavar="RUN", help="run folder (best.pt) or .pt file")
    p.add_argument("--out", required=True, type=Path, metavar="FILE",
                   help="output path; FILE.csv and FILE.parquet are written")
    p.add_argument("--samples", type=int, default=SAMPLES, metavar="K", help=f"samples per window (default {SAMPLES})")
    p.add_argument("--sampler", default=Sampler.DDIM.value, choices=[s.value for s in Sampler],
                   help="sampler of a diffusion model (default ddim)")
    p.add_argument("--steps", type=int, default=STEPS, metavar="N", help=f"denoising steps (default {STEPS})")
    p.add_argument("--seed", type=int, default=0, help="seed of the sampling noise (default 0)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--resample-hz", type=float, default=None, metavar="HZ",
                   help="resample the IMU to HZ first (the model's rate), with an anti-alias filter; the output is "
                        "at the resampled stamps")
    add_reader_arguments(p)
    add_check_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from training.deploy.predict import predict_file

    paths = predict_file(args.checkpoint, args.input, args.out, samples=args.samples, sampler=args.sampler,
                         steps=args.steps, seed=args.seed, device=args.device,
                         reader_kwargs=reader_kwargs_from_args(args), repairs=args.repair,
                         check_options=check_options_from_args(args), resample_hz=args.resample_hz)
    print("wrote " + ", ".join(map(str, paths)))
    return 0
