"""Learning beyond a constant on real EuRoC: the context model against train_mean, start_rest and sequence_mean.

Usage::

    biasgt run --config config/euroc.yaml --until windows --directory RUN    # the window dataset only
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/context_euroc.py RUN/results/windows/dataset \\
        --base-dir RUN [--steps N] [--seed S] [--variants NAME ...] [--grid] [--channel-oracles] [--labels dataset|state]

Writes the dataset's sequence records (``context/``, :func:`training.data.records.write_context`) when it
has none, evaluates the reference rows ``train_mean``, ``start_rest``, ``sequence_mean`` (oracle) and
``state_bias`` (EuRoC's own bias, oracle), ``bias_filter`` with config/euroc.yaml's protocol (nominal
gravity; ``--gravity recovered``: each sequence's recovered gravity), trains the context model
variants (one seed, single thread) and evaluates them the same way; a diffusion variant draws
DIFFUSION_SAMPLES DDIM samples per window and prints the metric over samples, then the sample mean
and median as predictions. Prints, per row, PRMSE (m) / ROE (deg) averaged over the test sequences
and per sequence, the rests found in each test record, the share of the gap from ``train_mean`` to
``sequence_mean`` each variant closes (PRMSE: the accelerometer's part; ROE: the gyro's), and wall
and CPU time. Exit code 0 (the figures are the output).
"""

from __future__ import annotations

import argparse
import functools
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
from training.data.records import has_context, open_context, write_context  # noqa: E402
from training.context.train import ContextTrainConfig, evaluate_context, train_context  # noqa: E402
from training.data.dataset import read_manifest  # noqa: E402
from training.evaluation.evaluate import evaluate_reference  # noqa: E402
from training.rows.sequence_mean import sequence_mean_bias  # noqa: E402
from training import references  # noqa: E402
from training.references import ReferenceRow  # noqa: E402

REFERENCES = ("train_mean", "start_rest", "bias_filter", "sequence_mean", "state_bias")
VARIANTS = {
    "rest_label": dict(model=dict(base="rest", history_s=()), loss="label"),
    "rest_integration": dict(model=dict(base="rest", history_s=()), loss="integration"),
    "rest_both": dict(model=dict(base="rest", history_s=()), loss="both"),
    "rest_history_label": dict(model=dict(base="rest"), loss="label"),
    "rest_history_integration": dict(model=dict(base="rest"), loss="integration"),
    "mean_history_label": dict(model=dict(base="mean"), loss="label"),
    "mean_history_integration": dict(model=dict(base="mean"), loss="integration"),
    "mean_history_both": dict(model=dict(base="mean"), loss="both"),
    "filter_history_integration": dict(model=dict(base="filter"), loss="integration"),
    "filter_history_both": dict(model=dict(base="filter"), loss="both"),
    "filter_history_label": dict(model=dict(base="filter"), loss="label"),
    # the residual drawn by a conditional diffusion model (training/context/diffusion.py): its noise
    # loss alone, or with the integration of its x0 estimate
    "filter_history_diffusion": dict(model=dict(base="filter", diffusion=True), loss="label"),
    "filter_history_diffusion_both": dict(model=dict(base="filter", diffusion=True), loss="both"),
}
#: Samples per window of the diffusion variants (DDIM), as config/euroc.yaml's diffusion rows.
DIFFUSION_SAMPLES = 10
#: The ablation grid (``--grid``): context x target x base, named ``<context>_<target>_<base>``. Context
#: ``1s`` is the window alone (no context vector); the others add the start rest's summary and one
#: history mean (5 s, 30 s before the window, or since the record's start).
GRID_CONTEXT = {"1s": dict(use_context=False, history_s=()), "5s": dict(history_s=(5.0,), since_start=False),
                "30s": dict(history_s=(30.0,), since_start=False), "start": dict(history_s=(), since_start=True)}
GRID_TARGET = ("label", "integration", "both")
GRID_BASE = ("none", "mean", "rest")
GRID = {f"{c}_{t}_{b}": dict(model=dict(base=b, **GRID_CONTEXT[c]), loss=t)
        for c in GRID_CONTEXT for t in GRID_TARGET for b in GRID_BASE}


def _channel_oracle(items: dict, *, sequence_dir: Path, bias_mean: np.ndarray, context, part: str) -> np.ndarray:
    """``sequence_mean`` (oracle) on one part of the bias, the train mean on the rest: ``gyro``, ``acc``,
    ``acc_along`` / ``acc_across`` (the accelerometer bias along / across the record's mean specific
    force, i.e. gravity in the body frame)."""
    B, T, _ = np.shape(items["imu"])
    seq, out = sequence_mean_bias(sequence_dir), np.asarray(bias_mean, dtype=np.float64).copy()
    u = np.asarray(context.imu, dtype=np.float64)[:, 3:].mean(axis=0)
    u /= np.linalg.norm(u)
    d = seq[3:] - out[3:]
    if part == "gyro":
        out[:3] = seq[:3]
    elif part == "acc":
        out[3:] = seq[3:]
    else:
        along = (d @ u) * u
        out[3:] += along if part == "acc_along" else d - along
    return np.broadcast_to(out, (B, 1, T, 6)).copy()


def _channel_rows() -> list[str]:
    """Registers the four :func:`_channel_oracle` rows; their names."""
    names = []
    for part in ("gyro", "acc", "acc_along", "acc_across"):
        name = f"sequence_mean_{part}"
        references.register(ReferenceRow(name, f"Sequence mean on {part} (oracle)", "", functools.partial(
            _channel_oracle, part=part), oracle=True, needs=("sequence_dir", "bias_mean", "context"), default=False))
        names.append(name)
    return names


def _closed(row, train_mean, sequence_mean) -> str:
    """The share of the gap from ``train_mean`` to ``sequence_mean`` (averages) that ``row`` closes: in
    PRMSE (the accelerometer's part) and in ROE (the gyro's part)."""
    p = (train_mean.prmse_m - row.prmse_m) / (train_mean.prmse_m - sequence_mean.prmse_m)
    r = (train_mean.roe_deg - row.roe_deg) / (train_mean.roe_deg - sequence_mean.roe_deg)
    return f"gap from train_mean to sequence_mean closed: PRMSE {100 * p:.0f} %, ROE {100 * r:.0f} %"


def _line(name: str, summary, row=None) -> str:
    row = summary.rows[0] if row is None else row
    per = "  ".join(f"{s[:5]} {m.prmse_m:.4f}/{m.roe_deg:.4f}" for s, m in row.sequences.items())
    return f"  {name:<22s} {row.average.prmse_m:.4f} / {row.average.roe_deg:.4f}   {per}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--base-dir", type=Path, default=None, help="the workflow's folder (store paths start there)")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=[*VARIANTS, *GRID])
    parser.add_argument("--labels", choices=["dataset", "state"], default="dataset",
                        help="the label loss's target: the dataset's labels, or EuRoC's own bias where a sequence has it")
    parser.add_argument("--gravity", choices=["nominal", "recovered"], default="nominal",
                        help="the integration's gravity: nominal (0, 0, -9.81), the paper's protocol in EuRoC's state "
                             "frame; recovered: each sequence's own, for test records judged against a raw pose stream")
    parser.add_argument("--grid", action="store_true", help="train the whole ablation grid (GRID) instead")
    parser.add_argument("--no-references", action="store_true", help="train and evaluate the variants only")
    parser.add_argument("--channel-oracles", action="store_true",
                        help="also the sequence_mean oracle on the gyro, the accelerometer, and the accelerometer "
                             "along and across gravity alone (the train mean elsewhere): where the headroom lies")
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
    cfg = EvaluationConfig(samples=1, gravity=args.gravity)
    sampled_cfg = EvaluationConfig(samples=DIFFUSION_SAMPLES, samplers=["ddim"], gravity=args.gravity)
    print("\nrow                    PRMSE m / ROE deg (average; per sequence)")
    refs = () if args.no_references else REFERENCES
    for ref in (*refs, *(_channel_rows() if args.channel_oracles else ())):
        print(_line(ref, evaluate_reference(ref, args.dataset, None, cfg).summary), flush=True)
    ends = [evaluate_reference(r, args.dataset, None, cfg).summary.rows[0].average for r in ("train_mean", "sequence_mean")]
    for name in list(GRID) if args.grid else args.variants:
        t, c = time.perf_counter(), time.process_time()
        model = train_context(args.dataset, ContextTrainConfig(steps=args.steps, seed=args.seed, val_every=50,
                                                               labels=args.labels, **{**VARIANTS, **GRID}[name]))
        sampled = getattr(model, "stochastic", False)
        summary = evaluate_context(model, args.dataset, sampled_cfg if sampled else cfg, name=name).summary
        print(_line(name, summary) + f"   [best step {model.info['best_step']}, {time.perf_counter() - t:.0f} s wall, "
              f"{time.process_time() - c:.0f} s CPU]", flush=True)
        for row in summary.rows:  # a diffusion variant: the metric over samples, then the sample mean and median
            if row.key:
                print(_line(f"  sample {row.key}", summary, row), flush=True)
            print(f"  {'':22s} {_closed(row.average, *ends)}", flush=True)
    print(f"\nwall {time.perf_counter() - wall0:.0f} s, CPU {time.process_time() - cpu0:.0f} s (this process, 1 thread)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
