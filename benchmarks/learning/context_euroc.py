"""Learning beyond a constant on real EuRoC: the context model against train_mean, start_rest and sequence_mean.

Usage::

    biasgt run --config config/euroc.yaml --until windows --directory RUN    # the window dataset only
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/learning/context_euroc.py RUN/results/windows/dataset \\
        --base-dir RUN [--work DIR] [--steps N] [--seed S] [--variants NAME ...] [--grid] [--channel-oracles] \\
        [--labels dataset|state]

Writes the dataset's sequence records (``context/``, :func:`training.data.records.write_context`) when it
has none, evaluates the reference rows ``train_mean``, ``start_rest``, ``sequence_mean`` (oracle) and
``state_bias`` (EuRoC's own bias, oracle), ``bias_filter`` with config/euroc.yaml's protocol (nominal
gravity; ``--gravity recovered``: each sequence's recovered gravity), trains the context network
variants (the registered ``context_residual`` and ``context_diffusion`` with the variant's options,
by ``biasgt train``'s trainer into ``--work``; one seed, single thread) and evaluates them the same
way (``biasgt evaluate``'s function); a diffusion variant draws DIFFUSION_SAMPLES DDIM samples per
window and prints the metric over samples, then the sample mean and median as predictions.
``--labels state`` trains on a copy of the dataset whose labels are EuRoC's own bias where a
sequence has it (:func:`training.data.dataset.with_state_labels`). Prints, per row, PRMSE (m) / ROE
(deg) averaged over the test sequences and per sequence, the rests found in each test record, the
share of the gap from ``train_mean`` to ``sequence_mean`` each variant closes (PRMSE: the
accelerometer's part; ROE: the gyro's), and wall and CPU time. Exit code 0 (the figures are the output).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from training.config import EvaluationConfig  # noqa: E402
from training.data.records import has_context, open_context, write_context  # noqa: E402
from training.config import TrainConfig  # noqa: E402
from training.data.dataset import read_manifest, with_state_labels  # noqa: E402
from training.evaluation.evaluate import evaluate_reference, evaluate_run  # noqa: E402
from training.fit.train import train  # noqa: E402
from training.networks import get_network  # noqa: E402
from training.rows.sequence_mean import sequence_mean_bias  # noqa: E402
from training import references  # noqa: E402
from training.references import ReferenceRow  # noqa: E402

REFERENCES = ("train_mean", "start_rest", "bias_filter", "sequence_mean", "state_bias")


def variant(base: str, loss: str = "integration", *, diffusion: bool = False, **options) -> tuple[str, dict]:
    """``(method, model options)`` of a context variant: the registered network and its options."""
    return ("context_diffusion" if diffusion else "context_residual", {"base": base, "loss": loss, **options})


VARIANTS = {
    "rest_label": variant("rest", "label", history_s=()),
    "rest_integration": variant("rest", "integration", history_s=()),
    "rest_both": variant("rest", "both", history_s=()),
    "rest_history_label": variant("rest", "label"),
    "rest_history_integration": variant("rest", "integration"),
    "mean_history_label": variant("mean", "label"),
    "mean_history_integration": variant("mean", "integration"),
    "mean_history_both": variant("mean", "both"),
    "filter_history_integration": variant("filter", "integration"),
    "filter_history_both": variant("filter", "both"),
    "filter_history_label": variant("filter", "label"),
    # the residual drawn by a conditional diffusion model (training/context/diffusion.py): its noise
    # loss alone, or with the integration of its x0 estimate
    "filter_history_diffusion": variant("filter", "label", diffusion=True),
    "filter_history_diffusion_both": variant("filter", "both", diffusion=True),
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
GRID = {f"{c}_{t}_{b}": variant(b, t, **GRID_CONTEXT[c]) for c in GRID_CONTEXT for t in GRID_TARGET for b in GRID_BASE}


def train_variant(dataset: Path, method: str, options: dict, out: Path, *, steps: int, seed: int, lr: float = 1e-3,
                  use_temperature: bool = False) -> Path:
    """One context variant trained by the one trainer (``biasgt train``'s) into the run folder ``out``:
    AdamW (weight decay 1e-4), cosine learning rate without warm-up, the validation loss every 50 steps
    picking the kept weights."""
    config = TrainConfig(method=method, seed=seed, max_steps=steps, batch_size=64, lr=lr, weight_decay=1e-4,
                         warmup_steps=0, val_every=50, checkpoint_every=steps, use_temperature=use_temperature,
                         device="cpu", threads=1, model_overrides=options)
    shutil.rmtree(out, ignore_errors=True)
    return train(config, dataset, out)


def best_step(run: Path) -> int:
    """The step whose weights a run kept (its ``run.json``)."""
    return int(json.loads((run / "run.json").read_text())["best_step"])


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
    parser.add_argument("--work", type=Path, default=None, help="folder of the variants' runs (default: a temporary one)")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=[*VARIANTS, *GRID])
    parser.add_argument("--labels", choices=["dataset", "state"], default="dataset",
                        help="the label loss's target: the dataset's labels, or EuRoC's own bias where a sequence has it")
    parser.add_argument("--gravity", choices=["nominal", "recovered"], default="nominal",
                        help="the evaluation's gravity: nominal (0, 0, -9.81), the paper's protocol in EuRoC's state "
                             "frame; recovered: each sequence's own, for test records judged against a raw pose stream "
                             "(training integrates with each sequence's recovered gravity, as 'biasgt train')")
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
    work = args.work or Path(tempfile.mkdtemp(prefix="context_euroc_"))
    train_on = with_state_labels(args.dataset, work / "state_labels") if args.labels == "state" else args.dataset
    for name in list(GRID) if args.grid else args.variants:
        t, c = time.perf_counter(), time.process_time()
        method, options = {**VARIANTS, **GRID}[name]
        run = train_variant(train_on, method, options, work / name, steps=args.steps, seed=args.seed)
        sampled = get_network(method).is_diffusion
        summary = evaluate_run(run, args.dataset, None, sampled_cfg if sampled else cfg, method=method).summary
        print(_line(name, summary) + f"   [best step {best_step(run)}, {time.perf_counter() - t:.0f} s wall, "
              f"{time.process_time() - c:.0f} s CPU]", flush=True)
        for row in summary.rows:  # a diffusion variant: the metric over samples, then the sample mean and median
            if row.key:
                print(_line(f"  sample {row.key}", summary, row), flush=True)
            print(f"  {'':22s} {_closed(row.average, *ends)}", flush=True)
    print(f"\nwall {time.perf_counter() - wall0:.0f} s, CPU {time.process_time() - cpu0:.0f} s (this process, 1 thread)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
