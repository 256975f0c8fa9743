"""Sampling throughput of every registered diffusion network: windows x samples per CPU-second.

For each diffusion network (:mod:`training.networks`) at ``--preset`` (default ``small``, the
workflow's), on the same synthetic windows (``--windows`` of 201 samples) and the same freshly
initialised weights, one run prints side by side:

* ``released``: the released code's sampler (ShenghaoZhou/ioo_diffusion, ``scheduler/ddim.py``
  ``generate`` with ``model.py`` ``sample``), reimplemented: one call per sample, each a batch of
  all windows; every one of the 25 steps runs the whole network (step embedding of the scalar step,
  the condition encoder on the window, the denoiser) under ``torch.no_grad``, then its DDIM step
  (x0 estimate clipped, ``alpha_bar_prev`` of ``t - 1000 // 25``).
* ``before``: this project's previous evaluation path: the condition encoded once per window,
  32 windows x K samples per sampler call, float32.
* one row per sampling backend (:class:`training.config.SamplingBackend`): every window's K samples
  in one call (chunked to at most ``--rows`` rows), the condition encoded once, under
  ``torch.inference_mode`` (:meth:`training.models.bias_model.BiasModel.sample`).

Columns: CPU seconds (``time.process_time``, after one warm-up call; a backend's preparation,
with a 2-step warm-up run on the same shapes: the ONNX export, the bf16 compilation, is timed apart), windows x samples per CPU-second, the speed-up over
``before`` and over ``released``, and the ratio to the compute floor. The floor is the FLOPs of one
denoising step of one sample (``torch.utils.flop_counter``: matrix products and convolutions) x
steps x samples, divided by a float32 matrix product's GFLOP/s measured on this core at the start.

Run on one core: ``OMP_NUM_THREADS=1 .venv/bin/python benchmarks/learning/sampling.py [--preset small]
[--windows 16] [--samples 10] [--steps 25] [--methods ...] [--backends ...] [--rows 2048]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from training.config import Preset, Sampler, SamplingBackend  # noqa: E402
from training.deploy.speed import probe_model, synthetic_batch  # noqa: E402
from training.models.backends import prepare_denoiser  # noqa: E402
from training.models.bias_model import BiasModel  # noqa: E402
from training.models.scheduler import WindowNoise  # noqa: E402
from training.networks import get_network, network_names  # noqa: E402

T = 201
#: Windows per sampler call of the previous evaluation path.
BEFORE_WINDOWS = 32


def matmul_gflops(n: int = 1024, repeats: int = 5) -> float:
    """Float32 GFLOP/s of an ``n x n`` matrix product on the current threads (best of ``repeats``)."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    a @ b
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        a @ b
        best = min(best, time.process_time() - t0)
    return 2.0 * n**3 / best / 1e9


def step_flops(model: BiasModel, batch) -> float:
    """FLOPs of one denoising step of one sample (``torch.utils.flop_counter``)."""
    from torch.utils.flop_counter import FlopCounterMode

    with torch.inference_mode():
        code = model.net.encode(model._condition(batch.rows(0, 1)), *model._context(batch.rows(0, 1), batch.imu))
        x = torch.zeros(1, *model.state_shape(T))
        counter = FlopCounterMode(display=False)
        with counter:
            model.net.denoise(x, torch.full((1,), 500, dtype=torch.int64), code)
    return float(counter.get_total_flops())


def released_sampler(model: BiasModel, batch, samples: int, steps: int) -> torch.Tensor:
    """The released code's sampling loop (module docstring): [K, B, ...] samples, normalised units."""
    sched = model.scheduler
    B = len(batch)
    out = []
    with torch.no_grad():
        for _ in range(samples):  # model.sample -> generate(batch_size=B): one sample of every window
            image = torch.randn(B, *model.state_shape(T))
            timesteps = torch.arange(steps - 1, -1, -1)  # 'leading' with the step ratio S // S = 1
            for t in timesteps:
                tt = t.expand(B)
                cond = model._condition(batch)
                code = model.net.encode(cond, *model._context(batch, cond))  # the condition encoder, every step
                eps = model.net.denoise(image, tt, code)
                prev = int(t) - sched.train_timesteps // steps
                ab_t = sched.alphas_cumprod[t]
                ab_prev = sched.alphas_cumprod[prev] if prev >= 0 else torch.tensor(1.0)
                x0 = ((image - (1 - ab_t) ** 0.5 * eps) / ab_t**0.5).clamp(-1.0, 1.0)
                variance = (1 - ab_prev) / (1 - ab_t) * (1 - ab_t / ab_prev)
                std = 0.0 * variance**0.5
                image = ab_prev**0.5 * x0 + (1 - ab_prev - std**2) ** 0.5 * eps
            out.append(image)
    return torch.stack(out)


def _cpu_seconds(fn: Callable[[], object]) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def _chunked(model: BiasModel, batch, samples: int, steps: int, per_call: int, denoise, noise_seed: int) -> None:
    keys = list(range(len(batch)))
    noise = WindowNoise.seeded(noise_seed, keys)
    for i in range(0, len(batch), per_call):
        model.sample(batch.rows(i, i + per_call), samples, sampler=Sampler.DDIM, steps=steps,
                     generator=noise.subset(i, i + per_call), denoise=denoise)


def bench_network(method: str, preset: Preset, windows: int, samples: int, steps: int, rows: int,
                  backends: list[SamplingBackend], gflops: float) -> None:
    model = probe_model(method, preset).eval()
    net = get_network(method)
    batch = synthetic_batch(windows, T, context_size=getattr(model.net, "context_size", None))
    floor_s = step_flops(model, batch) * steps * windows * samples / (gflops * 1e9)
    print(f"{net.name} ({preset.value}, {windows} windows x {samples} samples, DDIM-{steps}; "
          f"floor {floor_s:.3f} s at {gflops:.0f} GFLOP/s):")
    print(f"  {'sampler / backend':<22} {'prepare s':>9} {'CPU s':>8} {'w x s / CPU-s':>14} {'x before':>9} "
          f"{'x released':>11} {'CPU / floor':>12}")
    runs: list[tuple[str, float, float]] = []
    small = batch.rows(0, 1)
    released_sampler(model, small, 1, 2)
    runs.append(("released", 0.0, _cpu_seconds(lambda: released_sampler(model, batch, samples, steps))))
    _chunked(model, small, 1, 2, 1, None, 0)
    runs.append(("before (32 windows)", 0.0,
                 _cpu_seconds(lambda: _chunked(model, batch, samples, steps, BEFORE_WINDOWS, None, 0))))
    per_call = max(1, rows // samples)
    for backend in backends:
        prep = [None]
        prep_s = _cpu_seconds(lambda: prep.__setitem__(0, prepare_denoiser(model.net, backend)))
        # warm-up on the timed run's shapes (ONNX: the export; bf16: the compilation)
        prep_s += _cpu_seconds(lambda: _chunked(model, batch, samples, 2, per_call, prep[0], 0))
        sec = _cpu_seconds(lambda: _chunked(model, batch, samples, steps, per_call, prep[0], 0))
        runs.append((backend.value, prep_s, sec))
    before, released = runs[1][2], runs[0][2]
    for name, prep_s, sec in runs:
        print(f"  {name:<22} {prep_s:9.2f} {sec:8.2f} {windows * samples / sec:14.1f} {before / sec:9.2f} "
              f"{released / sec:11.2f} {sec / floor_s:12.1f}", flush=True)


def main() -> int:
    diffusion = [n for n in network_names() if get_network(n).is_diffusion]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="small", choices=[p.value for p in Preset])
    parser.add_argument("--windows", type=int, default=16)
    parser.add_argument("--samples", type=int, default=10)
    parser.add_argument("--steps", type=int, default=25)
    parser.add_argument("--rows", type=int, default=2048, help="rows (windows x samples) per sampler call")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--methods", nargs="+", default=diffusion, choices=diffusion)
    parser.add_argument("--backends", nargs="+", default=[b.value for b in SamplingBackend],
                        choices=[b.value for b in SamplingBackend])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    gflops = matmul_gflops()
    print(f"float32 matrix product: {gflops:.0f} GFLOP/s on {args.threads} thread(s)")
    for method in args.methods:
        bench_network(method, Preset(args.preset), args.windows, args.samples, args.steps, args.rows,
                      [SamplingBackend(b) for b in args.backends], gflops)
    return 0


if __name__ == "__main__":
    sys.exit(main())
