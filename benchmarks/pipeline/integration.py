"""Throughput of the IMU integration engine (pipeline.geometry.integration.integrate).

Integrates batches of one-second, 200-Hz windows (T = 201 samples, 200 intervals of 5 ms,
MIDPOINT scheme, random gyro/acc, per-window [B, 3] biases) on the CPU with
``torch.set_num_threads(2)``, after a warm-up, and prints the median of several runs as
windows per second, for float32 and float64, forward only (and, with ``--backward``,
forward + backward: the training-loss use). Wall-clock time; on a shared machine the figures are pessimistic.

Run: ``.venv/bin/python benchmarks/pipeline/integration.py [--threads N] [--repeats N] [--backward]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from pipeline.geometry.integration import IntegrationScheme, integrate
from pipeline.geometry.so3_torch import so3_exp

RATE_HZ = 200.0
T = 201  # one second: 200 intervals
GRAVITY_MPS2 = (0.0, 0.0, -9.81)


def _inputs(B: int, dtype: torch.dtype, requires_grad: bool) -> dict:
    gen = torch.Generator().manual_seed(0)
    gyro = 0.5 * torch.randn(B, T, 3, generator=gen, dtype=dtype)
    acc = torch.randn(B, T, 3, generator=gen, dtype=dtype) + torch.tensor([0.0, 0.0, 9.81], dtype=dtype)
    bg = (0.01 * torch.randn(B, 3, generator=gen, dtype=dtype)).requires_grad_(requires_grad)
    ba = (0.1 * torch.randn(B, 3, generator=gen, dtype=dtype)).requires_grad_(requires_grad)
    return dict(
        gyro_radps=gyro,
        acc_mps2=acc,
        dt_s=1.0 / RATE_HZ,
        R0=so3_exp(torch.randn(B, 3, generator=gen, dtype=dtype)),
        v0=torch.randn(B, 3, generator=gen, dtype=dtype),
        p0=torch.randn(B, 3, generator=gen, dtype=dtype),
        gravity_mps2=GRAVITY_MPS2,
        bias_gyro_radps=bg,
        bias_acc_mps2=ba,
        scheme=IntegrationScheme.MIDPOINT,
    )


def _time_once(kw: dict, backward: bool) -> float:
    start = time.perf_counter()
    if backward:
        res = integrate(**kw)
        loss = res.p.square().sum() + res.v.square().sum() + res.R.square().sum()
        loss.backward()
    else:
        with torch.no_grad():
            integrate(**kw)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads (default 2)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per case (median reported)")
    parser.add_argument("--backward", action="store_true", help="also time forward + backward (training use)")
    parser.add_argument("--batches", type=int, nargs="+", default=[1024, 8192], help="windows per call")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, T={T} samples ({(T - 1) / RATE_HZ:.0f} s "
          f"at {RATE_HZ:.0f} Hz), MIDPOINT, wall-clock median of {args.repeats} runs after warm-up")
    print(f"{'dtype':8s} {'B':>6s} {'pass':>9s} {'median_ms':>10s} {'min_ms':>8s} {'windows/s':>10s}")
    for dtype in (torch.float32, torch.float64):
        for B in args.batches:
            for backward in (False, True) if args.backward else (False,):
                kw = _inputs(B, dtype, backward)
                for _ in range(2):  # warm-up (allocator, thread pool)
                    _time_once(kw, backward)
                times = [_time_once(kw, backward) for _ in range(args.repeats)]
                med = statistics.median(times)
                name = "fwd+bwd" if backward else "forward"
                print(f"{str(dtype).removeprefix('torch.'):8s} {B:6d} {name:>9s} {med * 1e3:10.1f} "
                      f"{min(times) * 1e3:8.1f} {B / med:10.0f}", flush=True)


if __name__ == "__main__":
    main()
