"""Sampling of the evaluation: per-window noise, windows x samples batched in chunks, and the backends.

The batched sampler is checked against a loop over single windows (the same noise: each window's own
generator), the chunked predictor against one call, and every backend that changes the arithmetic
against the float32 ``exact`` backend in distribution (per-channel mean and spread of many samples).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from pipeline.errors import ConfigError
from training.config import Draw, EvaluationConfig, ModelConfig, Preset, Sampler, SamplingBackend
from training.data.batch import WindowBatch
from training.data.normalizer import Normalizer
from training.evaluation.predictors import ModelPredictor
from training.models.backends import prepare_denoiser
from training.models.bias_model import build_model
from training.models.scheduler import WindowNoise
from training.networks import get_network, network_names

STATS = dict(imu_mean=[0.0] * 6, imu_std=[1.0] * 6, bias_mean=[0.01] * 6, bias_std=[0.02] * 6)
DIFFUSION = [n for n in network_names() if get_network(n).is_diffusion]
T = 21


def _model(method: str):
    torch.manual_seed(0)
    return build_model(ModelConfig.for_preset(method, Preset.TINY), Normalizer(STATS)).eval()


def _items(model, B: int, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    eye = torch.eye(3).expand(B, 3, 3)
    items = dict(imu=torch.randn(B, T, 6, generator=g), bias=torch.zeros(B, T, 6), bias_std=torch.ones(B, T, 6),
                 dt_s=torch.full((B, T - 1), 0.005), start_R=eye, start_v=torch.zeros(B, 3),
                 start_p=torch.zeros(B, 3), end_R=eye, end_v=torch.zeros(B, 3), end_p=torch.zeros(B, 3),
                 t0_ns=torch.arange(B, dtype=torch.int64) * 1_000_000_000 + 123)
    if getattr(model.net, "context_size", None):
        items["context"] = torch.randn(B, model.net.context_size, generator=g)
    return items


def test_window_noise_draws_each_window_from_its_own_generator():
    keys = [5, 17, 3]
    together = WindowNoise.seeded(7, keys).randn((6, 4), "cpu", torch.float32)
    for b, key in enumerate(keys):
        alone = WindowNoise.seeded(7, [key]).randn((2, 4), "cpu", torch.float32)
        assert torch.equal(together[2 * b:2 * b + 2], alone)
    with pytest.raises(ValueError, match="do not split"):
        WindowNoise.seeded(7, keys).randn((4, 4), "cpu", torch.float32)


@pytest.mark.parametrize("sampler", [Sampler.DDIM, Sampler.RELEASED, Sampler.DDPM])
@pytest.mark.parametrize("method", DIFFUSION)
def test_batched_windows_equal_the_per_window_loop(method, sampler):
    """All windows' K samples in one call equal each window sampled alone (same per-window noise)."""
    model = _model(method)
    items = _items(model, 4)
    batch = WindowBatch.from_items(items)
    keys = items["t0_ns"].tolist()
    together = model.sample(batch, 3, sampler=sampler, steps=5, generator=WindowNoise.seeded(1, keys))
    for b, key in enumerate(keys):
        alone = model.sample(batch.rows(b, b + 1), 3, sampler=sampler, steps=5, generator=WindowNoise.seeded(1, [key]))
        torch.testing.assert_close(together[b:b + 1], alone, rtol=1e-5, atol=1e-6)


def _predictor(model, method: str) -> ModelPredictor:
    run = SimpleNamespace(model=model, path=Path("run/best.pt"), config=SimpleNamespace(method=method), dataset={})
    return ModelPredictor(run)


@pytest.mark.parametrize("method", DIFFUSION)
def test_predictor_samples_do_not_depend_on_the_chunks(method):
    model = _model(method)
    items = _items(model, 5)
    one_call = _predictor(model, method).predict(items, "s", Draw(4, Sampler.DDIM, 5, 3, rows=4096))
    per_window = _predictor(model, method).predict(items, "s", Draw(4, Sampler.DDIM, 5, 3, rows=4))
    pairs = _predictor(model, method).predict(items, "s", Draw(4, Sampler.DDIM, 5, 3, rows=9))
    assert one_call.shape == (5, 4, T, 6)
    np.testing.assert_allclose(per_window, one_call, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(pairs, one_call, rtol=1e-5, atol=1e-6)
    other_seed = _predictor(model, method).predict(items, "s", Draw(4, Sampler.DDIM, 5, 4))
    assert not np.allclose(other_seed, one_call)


@pytest.mark.parametrize("backend", [b for b in SamplingBackend if b is not SamplingBackend.EXACT])
@pytest.mark.parametrize("method", DIFFUSION)
def test_backends_sample_the_exact_distribution(method, backend):
    """Per channel, the mean and spread of 200 samples per window match float32's (same noise)."""
    model = _model(method)
    items = _items(model, 2)
    exact = _predictor(model, method).predict(items, "s", Draw(200, Sampler.DDIM, 10, 0))
    # one window (200 rows) per call: the compiled backend pads them to 208
    other = _predictor(model, method).predict(items, "s", Draw(200, Sampler.DDIM, 10, 0, backend, rows=300))
    assert other.shape == exact.shape and np.isfinite(other).all()
    spread = exact.std(axis=(1, 2))  # [B, 6]
    assert np.all(np.abs(other.mean(axis=(1, 2)) - exact.mean(axis=(1, 2))) <= 0.05 * spread)
    np.testing.assert_allclose(other.std(axis=(1, 2)), spread, rtol=0.05)
    assert not np.array_equal(other, exact)  # the arithmetic did change


def test_exact_backend_is_the_networks_own_denoiser_and_unknown_ones_are_refused():
    assert prepare_denoiser(_model("diffusion_rnn").net, "exact") is None
    with pytest.raises(ConfigError, match="backend"):
        prepare_denoiser(_model("diffusion_rnn").net, "fp8")
    with pytest.raises(ConfigError, match="backend"):
        EvaluationConfig(backend="fp8")
    assert EvaluationConfig.from_mapping({"backend": "bf16"}).draws(True)[0].backend is SamplingBackend.BF16
