"""Can the context model learn a bias that its input determines? The simulated check at full size.

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/learning/context_learning.py [--out DIR] [--steps N] [--seed S]

The variants' runs are written beside the dataset (``DIR/../runs``).

Writes the simulated dataset of :mod:`training.data.sim_context` (24 train, 4 validation, 8 test
sequences of 60 s at 100 Hz: a start rest showing a per-sequence turn-on bias, a temperature-driven
bias with one unit's coefficients) to ``DIR`` (default: a temporary folder), evaluates the reference
rows (train mean, start_rest, sequence_mean, the true bias) and trains the registered context network
(``context_residual``, by ``biasgt train``'s trainer) in several variants, each evaluated with Table
I's protocol. Prints
PRMSE (m) and ROE (deg) and the share of the gap from the train mean to the true bias each row
closes (the goal: >= 80 % for the learned row), with wall and CPU time. Exit code 0 (the figures
are the output).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402
from context_euroc import train_variant, variant  # noqa: E402

from training.config import EvaluationConfig  # noqa: E402
from training.data.sim_context import RestSim, write_rest_sim_dataset  # noqa: E402
from training.evaluation.evaluate import evaluate_reference, evaluate_run  # noqa: E402

#: name -> (method, options, condition on the temperature)
VARIANTS = {
    "start_rest + residual (temperature, label loss)": (*variant("rest", "label", history_s=()), True),
    "train_mean + residual (temperature, label loss)": (*variant("mean", "label", history_s=()), True),
    "start_rest + residual (temperature, integration loss)": (*variant("rest", "integration", history_s=()), True),
    "start_rest + residual (temperature, 5/30 s history, label)": (*variant("rest", "label"), True),
    "1-s model, no context, no temperature (label loss)": (*variant("mean", "label", use_context=False,
                                                                    history_s=()), False),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="dataset folder (default: a temporary one)")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    out = args.out or Path(tempfile.mkdtemp(prefix="context_learning_")) / "dataset"
    root = write_rest_sim_dataset(out, RestSim(), train=24, val=4, test=8, seed=args.seed)
    cfg = EvaluationConfig(samples=1, gravity="recovered")
    rows = {}
    for ref in ("train_mean", "start_rest", "sequence_mean", "ground_truth"):
        rows[ref] = evaluate_reference(ref, root, None, cfg).summary.rows[0].average
    for i, (name, (method, options, temperature)) in enumerate(VARIANTS.items()):
        t = time.perf_counter()
        run = train_variant(root, method, options, root.parent / "runs" / f"variant{i}", steps=args.steps,
                            seed=args.seed, lr=3e-3, use_temperature=temperature)
        rows[name] = evaluate_run(run, root, None, cfg, method=method).summary.rows[0].average
        print(f"  trained {name}: {time.perf_counter() - t:.0f} s wall", flush=True)
    tm, gt = rows["train_mean"], rows["ground_truth"]
    print(f"\nsimulated test split ({root}): PRMSE m / ROE deg, gap closed from train mean to the true bias")
    for name, a in rows.items():
        cp = (tm.prmse_m - a.prmse_m) / (tm.prmse_m - gt.prmse_m)
        cr = (tm.roe_deg - a.roe_deg) / (tm.roe_deg - gt.roe_deg)
        print(f"  {name:<60s} {a.prmse_m:.4f} / {a.roe_deg:.4f}   closed {cp:6.1%} / {cr:6.1%}")
    print(f"\nwall {time.perf_counter() - wall0:.0f} s, CPU {time.process_time() - cpu0:.0f} s (this process)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
