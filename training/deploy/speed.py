"""Speed probes of the models (used by ``benchmarks/learning/training.py``): training throughput and
sampling latency on synthetic windows of the right shape, so no dataset is needed.
"""

from __future__ import annotations

import statistics
import time

import torch

from pipeline.types import GRAVITY_MPS2
from training.data.batch import WindowBatch
from training.config import IMU_CHANNELS, STEPS, ModelConfig, Preset, Sampler
from training.models.bias_model import BiasModel, build_model
from training.data.normalizer import Normalizer

__all__ = ["synthetic_batch", "probe_model", "training_throughput", "sampling_latency"]


def synthetic_batch(batch_size: int, window_samples: int, rate_hz: float = 200.0, seed: int = 0,
                    context_size: int | None = None) -> WindowBatch:
    """Random windows [B, T, 6] with level start/end states (shapes and dtypes as a real batch), and a random
    context [B, context_size] for a network that reads one."""
    g = torch.Generator().manual_seed(seed)
    B, T = batch_size, window_samples
    eye = torch.eye(3).expand(B, 3, 3).clone()
    imu = torch.randn(B, T, IMU_CHANNELS, generator=g)
    imu[..., 5] += GRAVITY_MPS2
    return WindowBatch(imu=imu, bias=0.01 * torch.randn(B, T, IMU_CHANNELS, generator=g),
                       bias_std=torch.full((B, T, IMU_CHANNELS), 1e-3), dt_s=torch.full((B, T - 1), 1.0 / rate_hz),
                       start_R=eye, start_v=torch.zeros(B, 3), start_p=torch.zeros(B, 3), end_R=eye.clone(),
                       end_v=torch.zeros(B, 3), end_p=torch.zeros(B, 3),
                       context=None if context_size is None else torch.randn(B, context_size, generator=g))


def probe_model(method: str, preset: Preset, seed: int = 0) -> BiasModel:
    """A freshly initialised model with unit normaliser statistics."""
    torch.manual_seed(seed)
    stats = {"imu_mean": [0.0] * 6, "imu_std": [1.0] * 6, "bias_mean": [0.0] * 6, "bias_std": [0.01] * 6}
    return build_model(ModelConfig.for_preset(method, preset), Normalizer(stats))


def training_throughput(method: str, preset: Preset = Preset.SMALL, *, window_samples: int = 201,
                        batch_size: int = 64, steps: int = 10, warmup: int = 2, device: str = "cpu") -> float:
    """Windows per second of optimiser steps (loss, backward, clip, AdamW), data loading excluded."""
    model = probe_model(method, preset).to(device).train()
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    batch = synthetic_batch(batch_size, window_samples, context_size=getattr(model.net, "context_size", None)).to(device)
    g = torch.Generator().manual_seed(0)

    def step() -> None:
        loss = model.loss(batch, g)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    for _ in range(warmup):
        step()
    _sync(device)
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    _sync(device)
    return steps * batch_size / (time.perf_counter() - t0)


def sampling_latency(method: str, preset: Preset = Preset.PAPER, *, num_samples: int = 1,
                     window_samples: int = 200, sampler: Sampler = Sampler.DDIM, steps: int = STEPS, repeats: int = 5,
                     device: str = "cpu") -> float:
    """Median seconds to draw ``num_samples`` samples for one window (one batched call)."""
    model = probe_model(method, preset).to(device).eval()
    batch = synthetic_batch(1, window_samples, context_size=getattr(model.net, "context_size", None)).to(device)
    times = []
    for i in range(repeats + 1):
        _sync(device)
        t0 = time.perf_counter()
        model.sample(batch, num_samples, sampler=sampler, steps=steps)
        _sync(device)
        if i:  # the first call warms up
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _sync(device: str) -> None:
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()
