"""Learning beyond a constant on real EuRoC: the context model against train_mean, start_rest and sequence_mean.

Usage::

    biasgt run --config config/euroc.yaml --until windows --directory RUN    # the window dataset only
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/context_euroc.py RUN/results/windows/dataset \\
        --base-dir RUN [--steps N] [--seed S] [--variants NAME ...]

Writes the dataset's sequence records (``context/``, :func:`training.context.write_context`) when it
has none, evaluates the reference rows ``train_mean``, ``start_rest``, ``sequence_mean`` (oracle) and
``state_bias`` (EuRoC's own bias, oracle) with config/euroc.yaml's protocol (nominal gravity), trains
the context model variants (one seed, single thread) and evaluates them the same way. Prints, per
row, PRMSE (m) / ROE (deg) averaged over the test sequences and per sequence, the rests found in
each test record, and wall and CPU time. Exit code 0 (the figures are the output).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from training.config import EvaluationConfig  # noqa: E402
from training.context import has_context, open_context, write_context  # noqa: E402
from training.context_train import ContextTrainConfig, evaluate_context, train_context  # noqa: E402
from training.dataset import read_manifest  # noqa: E402
from training.evaluate import evaluate_reference  # noqa: E402

REFERENCES = ("train_mean", "start_rest", "sequence_mean", "state_bias")
VARIANTS = {
    "rest_label": dict(model=dict(base="rest", history_s=()), loss="label"),
    "rest_integration": dict(model=dict(base="rest", history_s=()), loss="integration"),
    "rest_both": dict(model=dict(base="rest", history_s=()), loss="both"),
    "rest_history_label": dict(model=dict(base="rest"), loss="label"),
    "rest_history_integration": dict(model=dict(base="rest"), loss="integration"),
    "mean_history_label": dict(model=dict(base="mean"), loss="label"),
    "mean_history_integration": dict(model=dict(base="mean"), loss="integration"),
    "mean_history_both": dict(model=dict(base="mean"), loss="both"),
}


def _line(name: str, summary) -> str:
    row = summary.rows[0]
    per = "  ".join(f"{s[:5]} {m.prmse_m:.4f}/{m.roe_deg:.4f}" for s, m in row.sequences.items())
    return f"  {name:<22s} {row.average.prmse_m:.4f} / {row.average.roe_deg:.4f}   {per}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--base-dir", type=Path, default=None, help="the workflow's folder (store paths start there)")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--no-references", action="store_true", help="train and evaluate the variants only")
    args = parser.parse_args()
    torch.set_num_threads(1)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    if not has_context(args.dataset):
        write_context(args.dataset, args.base_dir)
    manifest = read_manifest(args.dataset)
    print("rests in the test records (start s, length s; first window at s):")
    for name in manifest.names("test"):
        ctx = open_context(args.dataset, name)
        t_first = np.load(args.dataset / manifest.sequences[name].path / "t_ns.npy", mmap_mode="r")[0, 0]
        rests = [(round(a / ctx.rate_hz, 1), round((b - a) / ctx.rate_hz, 1)) for a, b in ctx.rests[:4]]
        print(f"  {name}: {rests} (of {len(ctx.rests)}); first window {(t_first - ctx.t_ns[0]) * 1e-9:.1f}")
    cfg = EvaluationConfig(samples=1, gravity="nominal")
    print("\nrow                    PRMSE m / ROE deg (average; per sequence)")
    for ref in () if args.no_references else REFERENCES:
        print(_line(ref, evaluate_reference(ref, args.dataset, None, cfg).summary), flush=True)
    for name in args.variants:
        t, c = time.perf_counter(), time.process_time()
        model = train_context(args.dataset, ContextTrainConfig(steps=args.steps, seed=args.seed, val_every=50,
                                                               **VARIANTS[name]))
        summary = evaluate_context(model, args.dataset, cfg, name=name).summary
        print(_line(name, summary) + f"   [best step {model.info['best_step']}, {time.perf_counter() - t:.0f} s wall, "
              f"{time.process_time() - c:.0f} s CPU]", flush=True)
    print(f"\nwall {time.perf_counter() - wall0:.0f} s, CPU {time.process_time() - cpu0:.0f} s (this process, 1 thread)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
