"""Bias models: paper sizes, causality of the condition encoder, shapes, normaliser, temperature."""

from __future__ import annotations

import pytest
import torch

from pipeline.errors import DataError, InputFormatError
from training.data.batch import WindowBatch
from training.networks import get_network, network_names
from training.config import ModelConfig, Preset, Sampler, TrainConfig
from training.models.bias_model import build_model, count_parameters
from training.models.layers import TcnEncoder
from training.data.normalizer import Normalizer

STATS = dict(imu_mean=[0.0] * 6, imu_std=[1.0] * 6, bias_mean=[0.01] * 6, bias_std=[0.02] * 6)


def _batch(B: int = 3, T: int = 21, seed: int = 0, temperature: bool = False) -> WindowBatch:
    g = torch.Generator().manual_seed(seed)
    eye = torch.eye(3).expand(B, 3, 3)
    items = dict(imu=torch.randn(B, T, 6, generator=g), bias=0.02 * torch.randn(B, T, 6, generator=g),
                 bias_std=torch.ones(B, T, 6), dt_s=torch.full((B, T - 1), 0.005), start_R=eye,
                 start_v=torch.zeros(B, 3), start_p=torch.zeros(B, 3), end_R=eye, end_v=torch.zeros(B, 3),
                 end_p=torch.zeros(B, 3))
    if temperature:
        items["temperature_degc"] = 20 + torch.randn(B, T, generator=g)
    return WindowBatch.from_items(items)


def test_paper_sizes_match_the_released_models():
    """The released code's parameter counts (the paper's 2.2M and 42.8M)."""
    counts = {m: count_parameters(build_model(ModelConfig.for_preset(m, Preset.PAPER), Normalizer(STATS)))
              for m in ("diffusion_rnn", "diffusion_unet")}
    assert counts["diffusion_rnn"] == 2_192_710
    assert counts["diffusion_unet"] == 42_814_022


def test_tcn_receptive_field_is_255_and_causal():
    config = ModelConfig.for_preset("diffusion_rnn", Preset.PAPER)
    enc = TcnEncoder(6, config.tcn_channels, config.tcn_kernel, 0.0, config.cond_dim).eval()
    assert enc.receptive_field == 255
    x = torch.randn(1, 300, 6)
    base = enc(x)
    y = x.clone()
    y[:, : 300 - 255] += 10.0  # outside the receptive field of the last output
    assert torch.equal(enc(y), base)
    y[:, 300 - 255] += 10.0  # the oldest sample inside it
    assert not torch.equal(enc(y), base)


@pytest.mark.parametrize("method", network_names())
def test_every_method_samples_raw_units_and_rebuilds_from_state_dict(method):
    torch.manual_seed(0)
    model = build_model(ModelConfig.for_preset(method, Preset.TINY), Normalizer(STATS)).eval()
    batch = _batch(T=21)  # an odd length: the U-Net pads and crops
    if get_network(method).context:  # the window's context vector from its sequence's record
        batch.context = torch.randn(len(batch), model.net.context_size, generator=torch.Generator().manual_seed(2))
    loss = model.loss(batch, torch.Generator().manual_seed(0))
    assert loss.dim() == 0 and torch.isfinite(loss)
    s = model.sample(batch, 4, steps=5, generator=torch.Generator().manual_seed(1))
    assert s.shape == (3, 4, 21, 6)
    if not get_network(method).is_diffusion:
        assert torch.equal(s[:, 0], s[:, 3])
    state = model.state_dict()
    assert torch.equal(state["normalizer.bias_std"], torch.tensor(STATS["bias_std"]))
    twin = build_model(ModelConfig.for_preset(method, Preset.TINY), Normalizer(dict(STATS, bias_std=[1.0] * 6)))
    twin.load_state_dict(state)
    twin.eval()
    assert torch.equal(twin.sample(batch, 4, steps=5, generator=torch.Generator().manual_seed(1)), s)


def test_released_sampler_clips_in_raw_units():
    torch.manual_seed(0)
    wide = dict(STATS, bias_mean=[0.0] * 6, bias_std=[5.0] * 6)  # normalised +-1 would be +-5 raw
    model = build_model(ModelConfig.for_preset("diffusion_rnn", Preset.TINY), Normalizer(wide)).eval()
    s = model.sample(_batch(), 8, sampler=Sampler.RELEASED, steps=25, generator=torch.Generator().manual_seed(0))
    assert s.abs().max() <= 1.0 + 1e-6
    assert (s.abs() > 0.999).any()  # an untrained model's x0 estimate hits the clip


def test_indirect_loss_is_zero_at_the_true_bias():
    """The integration loss, independent of labels: windows integrated from consistent states."""
    from pipeline.geometry.integration import integrate

    torch.manual_seed(0)
    batch = _batch(B=4, T=41)
    batch.imu[..., 5] += 9.81
    res = integrate(batch.imu[..., :3].double(), batch.imu[..., 3:].double(), batch.dt_s.double(),
                    batch.start_R, batch.start_v, batch.start_p, gravity_mps2=(0.0, 0.0, -9.81),
                    bias_gyro_radps=batch.bias[..., :3].double(), bias_acc_mps2=batch.bias[..., 3:].double())
    batch.end_R, batch.end_v, batch.end_p = res.R.float(), res.v.float(), res.p.float()
    model = build_model(ModelConfig.for_preset("indirect_rnn", Preset.TINY), Normalizer(STATS))
    assert float(model._integration_loss(batch, batch.bias)) < 1e-10
    assert float(model._integration_loss(batch, torch.zeros_like(batch.bias))) > 1e-6


def test_temperature_is_a_seventh_condition_channel():
    config = TrainConfig(method="diffusion_rnn", preset=Preset.TINY, use_temperature=True).model_config()
    assert config.condition_channels == 7
    torch.manual_seed(0)
    model = build_model(config, Normalizer(STATS, temperature_degc=(20.0, 1.0))).eval()
    batch = _batch(temperature=True)
    a = model.sample(batch, 2, steps=5, generator=torch.Generator().manual_seed(0))
    batch.temperature_degc = batch.temperature_degc + 5.0
    b = model.sample(batch, 2, steps=5, generator=torch.Generator().manual_seed(0))
    assert not torch.allclose(a, b)
    batch.temperature_degc = None
    with pytest.raises(DataError, match="temperature_degc"):
        model.loss(batch)


def test_normalizer_rejects_missing_statistics():
    with pytest.raises(InputFormatError, match="bias_std"):
        Normalizer({k: v for k, v in STATS.items() if k != "bias_std"}, path="ds/manifest.json")
    with pytest.raises(InputFormatError, match="normaliser"):
        Normalizer.from_manifest({}, path="ds/manifest.json")
