"""Speed of the learning stage on CPU threads, and Table I of a results folder.

Prints:

1. Training throughput (windows/s) per method at a preset (default ``small``): optimiser steps
   (loss, backward, clipping, AdamW) on synthetic 201-sample windows
   (:func:`training.deploy.speed.training_throughput`; data loading excluded; ``run.json`` of a real
   run holds the figure with loading).
2. Latency of DDIM-25 (eta 0) for ONE window of 201 samples: one sample, and 50 samples
   batched, for the paper-size RNN (2,192,710 parameters) and U-Net (42,814,022), in PyTorch
   eager, TorchScript (``torch.jit.trace`` of :class:`training.deploy.export.ExportedSampler`) and
   onnxruntime (the ONNX export of the same module), with ``--threads`` (default 2) intra-op
   threads; and, for reference, eager with PyTorch's dynamic int8 quantisation of the GRU and
   Linear layers (``torch.ao.quantization.quantize_dynamic``), printed with its largest sample
   difference from float32 for the same noise (a deployment option, not what ``export`` writes). Weights are freshly initialised (latency does not depend on their values). Each
   figure is the median of ``--repeats`` runs after one warm-up run; runs longer than 20 s
   are timed once (no warm-up), and stated so.
3. With ``--results DIR``: Table I from ``DIR/evaluation`` (the workflow's results folder).

Wall-clock time: on a shared machine the figures are pessimistic. The paper's goals, for
comparison: RNN 145 ms (one sample, DDIM-25, Jetson AGX Orin GPU); 50 samples within 1 s.

Run: ``.venv/bin/python benchmarks/learning/training.py [--threads 2] [--train-steps 20] [--skip-train]
[--skip-latency] [--methods diffusion_rnn ...] [--latency-samples 1 50] [--latency-methods diffusion_rnn
diffusion_unet] [--results results]``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from training.config import Preset, Sampler  # noqa: E402
from training.networks import network_names  # noqa: E402
from training.deploy.export import ExportedSampler, ExportFormat, example_inputs, onnx_session, write_export  # noqa: E402,E501
from training.models.bias_model import count_parameters  # noqa: E402
from training.deploy.speed import probe_model, training_throughput  # noqa: E402

T = 201
STEPS = 25
#: A run longer than this (s) is timed once, without a warm-up run.
LONG_S = 20.0


def train_throughput(methods: list[str], preset: Preset, steps: int, batch: int, threads: int) -> None:
    torch.set_num_threads(threads)
    print(f"training throughput ({preset.value} preset, batch {batch}, {steps} steps after 2 warm-up steps, "
          f"{threads} threads; loss, backward, clipping, AdamW on synthetic windows):")
    for method in methods:
        rate = training_throughput(method, preset, batch_size=batch, steps=steps)
        params = count_parameters(probe_model(method, preset))
        print(f"  {method.value:<16} {rate:8.1f} windows/s ({params:,} parameters)")


def _time(fn, repeats: int) -> tuple[float, str]:
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    if first > LONG_S:
        return first, " (one run, no warm-up)"
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs), ""


def latency(threads: int, repeats: int, samples: tuple[int, ...] = (1, 50),
            methods: tuple[str, ...] = ("diffusion_rnn", "diffusion_unet")) -> None:
    torch.set_num_threads(threads)
    print(f"DDIM-{STEPS} latency, one window of {T} samples, paper-size models, {threads} threads:")
    for method in methods:
        model = probe_model(method, Preset.PAPER).eval()
        module = ExportedSampler(model, Sampler.DDIM, STEPS).eval()
        imu = torch.randn(1, T, 6)
        with tempfile.TemporaryDirectory() as tmp, torch.no_grad():
            example = example_inputs(module, T)
            write_export(module, example, Path(tmp) / "m.pt", ExportFormat.TORCHSCRIPT)
            write_export(module, example, Path(tmp) / "m.onnx", ExportFormat.ONNX)
            ts = torch.jit.load(str(Path(tmp) / "m.pt"))
            sess = onnx_session(Path(tmp) / "m.onnx", threads)
            int8 = _dynamic_int8(module)
            print(f"  {method.value} ({count_parameters(model):,} parameters)")
            for k in samples:
                noise = torch.randn(k, T, 6)
                feeds = {"imu": imu.numpy(), "noise": noise.numpy()}
                for name, fn in (("eager", lambda: module(imu, noise)), ("torchscript", lambda: ts(imu, noise)),
                                 ("onnxruntime", lambda: sess.run(None, feeds)),
                                 ("eager int8", lambda: int8(imu, noise))):
                    sec, note = _time(fn, repeats)
                    print(f"    {k:>2} sample(s)  {name:<12} {1000 * sec:10.1f} ms{note}")
                diff = (module(imu, noise) - int8(imu, noise)).abs().amax(dim=(0, 1, 2))
                print(f"    {k:>2} sample(s)  int8 - float32, largest |difference| per channel: "
                      + " ".join(f"{v:.1e}" for v in diff.tolist()) + " (rad/s x3, m/s^2 x3)")


def _dynamic_int8(module: torch.nn.Module) -> torch.nn.Module:
    """``module`` with int8 weights in its GRU and Linear layers (activations quantised on the fly)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch.ao.quantization announces its move to torchao
        return torch.ao.quantization.quantize_dynamic(module, {torch.nn.GRU, torch.nn.Linear}, dtype=torch.qint8)


def print_table(results: Path) -> None:
    from training.evaluation.outputs import SUMMARY_JSON, read_summary
    from training.evaluation.table import format_markdown, table_columns

    paths = sorted((results / "evaluation").glob(f"**/{SUMMARY_JSON}"))
    if not paths:
        print(f"no evaluation summaries under {results / 'evaluation'}")
        return
    print(format_markdown(table_columns(read_summary(p) for p in paths)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--preset", default="small", choices=[p.value for p in Preset])
    parser.add_argument("--train-steps", type=int, default=20)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--methods", nargs="*", default=list(network_names()), choices=network_names())
    parser.add_argument("--skip-train", action="store_true")
    parser.add_argument("--skip-latency", action="store_true")
    parser.add_argument("--latency-samples", type=int, nargs="+", default=[1, 50])
    parser.add_argument("--latency-methods", nargs="+", default=["diffusion_rnn", "diffusion_unet"],
                        choices=["diffusion_rnn", "diffusion_unet"])
    parser.add_argument("--results", type=Path, help="a workflow results folder: print its Table I")
    args = parser.parse_args()
    if not args.skip_train:
        train_throughput(list(args.methods), Preset(args.preset), args.train_steps, args.batch,
                         args.threads)
    if not args.skip_latency:
        latency(args.threads, args.repeats, tuple(args.latency_samples), tuple(args.latency_methods))
    if args.results is not None:
        print_table(args.results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
