"""``biasgt evaluate``: PRMSE / ROE of a trained run or a reference row on the test split (adapter over training.evaluation.evaluate)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.files.atomic import OutputKind

DESCRIPTION = """\
Evaluate a bias predictor on the TEST split of a window dataset, as the paper (after AirIMU) does:
non-overlapping 1-s windows (every other window of the dataset's 50%-overlap ones), each integrated
from the reference start state with the predicted bias subtracted from the readings; end-point PRMSE
(m) and ROE (deg) per test sequence and their mean over sequences (Average).

A trained run (--checkpoint RUN: a 'biasgt train' folder or a .pt file) is rebuilt from its checkpoint
alone. A diffusion model draws K samples per window (--samples) with each --sampler
(correct DDIM, and 'released': the released code's sampler, for the ablation); the figures are
averaged over the samples (the paper), and the sample mean and median are evaluated as predictions
too. The spread is checked for calibration: per channel, the fraction of ground-truth bias inside the
central 68% / 95% (and other levels) of the K samples.

--reference NAME evaluates a row that needs no training (the registered rows, training.references;
an oracle reads the ground truth at test time: an upper bound, not a usable method):
{references}

Writes OUT atomically: summary.json, windows.parquet (errors per window and sample),
predictions.parquet (every window's predicted bias: per time step the samples' mean, std, median
and quantiles), examples.parquet (a few test windows: truth, the dataset's own bias, sample mean, quantiles and a
few samples).
"""

EPILOG = """\
examples:
  biasgt evaluate --checkpoint results/training/{m}/seed0 --dataset results/windows --out ev/{m}
  biasgt evaluate --checkpoint run --dataset ds --samples 50 --sampler ddim --sampler released --out ev
  biasgt evaluate --reference {r} --dataset ds --out ev/{r}
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    from training.config import EvalGravity, EvaluationConfig, OracleWalk, Sampler, SamplingBackend
    from training.networks import network_names
    from training.references import get_reference, reference_names

    d = EvaluationConfig()
    rows = reference_names()
    listing = "\n".join(f"  {r}: {get_reference(r).help}{' (oracle)' if get_reference(r).oracle else ''}"
                         for r in rows)
    p = subparsers.add_parser("evaluate", help="PRMSE / ROE of a trained model or a reference on the test split",
                              description=DESCRIPTION.format(references=listing),
                              epilog=EPILOG.format(m=network_names()[0], r=rows[-1] if rows else "NAME"),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", type=Path, metavar="RUN", help="run folder (best.pt) or checkpoint file")
    src.add_argument("--reference", choices=rows, metavar="NAME",
                     help=f"a reference row (no training): {', '.join(rows)}")
    p.add_argument("--dataset", required=True, type=Path, metavar="DIR", help="window dataset ('biasgt windows')")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (written atomically)")
    p.add_argument("--samples", type=int, default=d.samples, metavar="K",
                   help=f"samples per window (default {d.samples})")
    p.add_argument("--sampler", action="append", choices=[Sampler.DDIM.value, Sampler.RELEASED.value],
                   help="sampler of a diffusion model (repeatable; default "
                        f"{' and '.join(s.value for s in d.samplers)})")
    p.add_argument("--steps", type=int, default=d.steps, metavar="N", help=f"denoising steps (default {d.steps})")
    p.add_argument("--seed", type=int, default=d.seed, help=f"seed of the sampling noise (default {d.seed})")
    p.add_argument("--backend", choices=[b.value for b in SamplingBackend], default=d.backend.value,
                   help="how a diffusion model's denoiser runs: exact (float32, the reference), or bf16 (compiled "
                        f"bfloat16, faster, samples equal in distribution only) (default {d.backend.value})")
    p.add_argument("--gravity", choices=[g.value for g in EvalGravity], default=d.gravity.value,
                   help="gravity of the integration: nominal (0, 0, -9.81), as the paper, or each sequence's "
                        f"recovered one (default {d.gravity.value})")
    p.add_argument("--oracle-random-walk", choices=[w.value for w in OracleWalk], default=d.oracle_random_walk.value,
                   help="random walks of the random-walk oracle: the sensor's calibration (sensor.yaml), as the "
                        f"paper, or the recovery's (default {d.oracle_random_walk.value})")
    p.add_argument("--method", choices=network_names(), metavar="METHOD",
                   help=f"refuse a checkpoint of another method ({', '.join(network_names())})")
    p.add_argument("--allow-train-overlap", action="store_true",
                   help="evaluate even when the test split holds sequences the model trained or was validated on "
                        "(refused by default: such figures are no test result)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.set_defaults(func=run, out_kind=OutputKind.FOLDER)


def run(args: argparse.Namespace) -> int:
    from training.evaluation.evaluate import EvaluationConfig, evaluate_reference, evaluate_run

    defaults = EvaluationConfig()
    config = EvaluationConfig(samples=args.samples, samplers=tuple(args.sampler or defaults.samplers),
                              steps=args.steps, seed=args.seed, backend=args.backend, gravity=args.gravity,
                              oracle_random_walk=args.oracle_random_walk)
    if args.reference:
        result = evaluate_reference(args.reference, args.dataset, args.out, config)
    else:
        result = evaluate_run(args.checkpoint, args.dataset, args.out, config, method=args.method,
                              device=args.device, allow_train_overlap=args.allow_train_overlap)
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
