"""``biasgt evaluate``: PRMSE / ROE of a trained run or a reference row on the test split (adapter over training.evaluate)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.atomic import OutputKind

DESCRIPTION = """\
Evaluate a bias predictor on the TEST split of a window dataset, as the paper (after AirIMU) does:
non-overlapping 1-s windows (every other window of the dataset's 50%-overlap ones), each integrated
from the reference start state with the predicted bias subtracted from the readings; end-point PRMSE
(m) and ROE (deg) per test sequence and their mean over sequences (Average).

A trained run (--checkpoint RUN: a 'biasgt train' folder or a .pt file) is rebuilt from its checkpoint
alone. A diffusion model draws K samples per window (--samples, default 50) with each --sampler
(correct DDIM, and 'released': the released code's sampler, for the ablation); the figures are
averaged over the samples (the paper), and the sample mean and median are evaluated as predictions
too. The spread is checked for calibration: per channel, the fraction of ground-truth bias inside the
central 68% / 95% (and other levels) of the K samples.

--reference NAME evaluates a row that needs no training: zero, train_mean (the train split's mean
bias), ground_truth (the recovered bias itself), state_bias (the dataset's own ground-truth-state
bias), random_walk_oracle (ground-truth bias at each window start plus 50 random walks with the
evaluation's random-walk strengths, the best chosen with the ground-truth end pose: an oracle upper
bound, not a usable method) or random_walk_paper (the same with the walks the paper's column implies).

Writes OUT atomically: summary.json, windows.parquet (errors per window and sample),
predictions.parquet (every window's predicted bias: per time step the samples' mean, std, median
and quantiles), examples.parquet (a few test windows: truth, the dataset's own bias, sample mean, quantiles and a
few samples).
"""

EPILOG = """\
examples:
  biasgt evaluate --checkpoint results/training/diffusion_rnn --dataset results/windows --out ev/diffusion_rnn
  biasgt evaluate --checkpoint run --dataset ds --samples 50 --sampler ddim --sampler released --out ev
  biasgt evaluate --reference random_walk_oracle --dataset ds --out ev/random_walk_oracle
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    from training.config import Baseline, EvalGravity, Method, OracleWalk, Sampler

    p = subparsers.add_parser("evaluate", help="PRMSE / ROE of a trained model or a reference on the test split",
                              description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", type=Path, metavar="RUN", help="run folder (best.pt) or checkpoint file")
    src.add_argument("--reference", choices=[b.value for b in Baseline], help="a reference row (no training)")
    p.add_argument("--dataset", required=True, type=Path, metavar="DIR", help="window dataset ('biasgt windows')")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (written atomically)")
    p.add_argument("--samples", type=int, default=50, metavar="K", help="samples per window (default 50)")
    p.add_argument("--sampler", action="append", choices=[Sampler.DDIM.value, Sampler.RELEASED.value],
                   help="sampler of a diffusion model (repeatable; default ddim)")
    p.add_argument("--steps", type=int, default=25, metavar="N", help="denoising steps (default 25)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sampling noise (default 0)")
    p.add_argument("--gravity", choices=[g.value for g in EvalGravity], default=EvalGravity.RECOVERED.value,
                   help="gravity of the integration: nominal (0, 0, -9.81), as the paper, or each sequence's "
                        "recovered one (default recovered)")
    p.add_argument("--oracle-random-walk", choices=[w.value for w in OracleWalk], default=OracleWalk.RECOVERY.value,
                   help="random walks of the random-walk oracle: the sensor's calibration (sensor.yaml), as the "
                        "paper, or the recovery's (default recovery)")
    p.add_argument("--method", choices=[m.value for m in Method],
                   help="refuse a checkpoint of another method")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def run(args: argparse.Namespace) -> int:
    from training.evaluate import EvaluationConfig, evaluate_reference, evaluate_run

    config = EvaluationConfig(samples=args.samples, samplers=tuple(args.sampler or ("ddim",)), steps=args.steps,
                              seed=args.seed, gravity=args.gravity, oracle_random_walk=args.oracle_random_walk)
    if args.reference:
        result = evaluate_reference(args.reference, args.dataset, args.out, config)
    else:
        result = evaluate_run(args.checkpoint, args.dataset, args.out, config, method=args.method,
                              device=args.device)
    s = result.summary
    print(f"{s.label}: {s.windows} test windows, {s.samples} sample(s) per window -> {args.out}")
    for row in s.rows:
        name = row.key or ("samples" if s.samples > 1 else "prediction")
        print(f"  {name:<16} average PRMSE {row.average.prmse_m:.4f} m  ROE {row.average.roe_deg:.4f} deg")
    for cal in s.calibration:
        c68, c95 = cal.at(0.68), cal.at(0.95)
        print(f"  calibration ({cal.sampler.value}): inside 68%: " + " ".join(f"{x:.2f}" for x in c68)
              + "; inside 95%: " + " ".join(f"{x:.2f}" for x in c95))
    for clip in s.clip:
        print(f"  x0 clip ({clip.sampler}): samples on the bound per channel: "
              + " ".join(f"{x:.1%}" for x in clip.on_bound))
    return 0
