"""The diffusion samplers' x0 clip: its range from the train and validation biases, and a bias far outside
the training range reachable when the validation split shows one."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import default_collate

from pipeline.errors import ConfigError, DataError
from training.data.batch import WindowBatch
from training.fit.checkpoint import load_run
from training.models.clip import clip_bounds
from training.config import ClipRange, ModelConfig, Preset, Sampler, TrainConfig
from training.data.dataset import Split, WindowDataset, write_dataset
from training.models.scheduler import ClipCount
from training.fit.train import train

sys.path.insert(0, str(Path(__file__).parents[1]))
from toy_windows import Kind, Toy, one_torch_thread, toy_sequence  # noqa: E402,F401 (a fixture)

pytestmark = pytest.mark.usefixtures("one_torch_thread")
FAR_BIAS = 3.0  # the validation sequence's bias offset: the train biases lie within +-0.5 (std ~0.29)


@pytest.fixture(scope="module")
def far_val(tmp_path_factory) -> Path:
    """Train biases 0.5 c (c uniform in [-1, 1]); validation biases 0.5 c + 3, about 10 train sigmas out."""
    seqs = [toy_sequence(Toy(), "toy_train", Split.TRAIN, 96, 0),
            toy_sequence(Toy(kind=Kind.BIMODAL, offset=FAR_BIAS, p_plus=1.0), "toy_val", Split.VAL, 32, 1),
            toy_sequence(Toy(), "toy_test", Split.TEST, 16, 2)]
    out = tmp_path_factory.mktemp("clip") / "ds"
    write_dataset(seqs, out, config={"toy": "far validation"}, extra={"rate_hz": 100.0})
    return out


def _biases(root: Path, split: Split) -> np.ndarray:
    ds = WindowDataset(root, split)
    return np.concatenate([np.asarray(ds.arrays(n)["bias"]).reshape(-1, 6) for n in ds.sequences])


def test_bounds_of_each_range(far_val):
    train_b, val_b = _biases(far_val, Split.TRAIN), _biases(far_val, Split.VAL)
    mean, std = train_b.mean(axis=0), train_b.std(axis=0)
    cfg = ModelConfig.for_preset("diffusion_rnn", Preset.TINY)
    assert cfg.clip_x0_range is ClipRange.EVIDENCE  # the default
    half = np.abs(np.concatenate([train_b, val_b]) - mean).max(axis=0) + 3.0 * std
    lo, hi = clip_bounds(cfg, mean, std, [train_b, val_b])
    np.testing.assert_allclose(lo, mean - half, rtol=1e-12)
    np.testing.assert_allclose(hi, mean + half, rtol=1e-12)
    assert np.all(np.asarray(hi) > val_b.max(axis=0))  # the validation biases are inside
    lo, hi = clip_bounds(ModelConfig.for_preset("diffusion_rnn", Preset.TINY, clip_x0_range="train"),
                         mean, std, [train_b, val_b])
    np.testing.assert_allclose(hi, mean + 3.0 * std, rtol=1e-12)
    sensor = ModelConfig.for_preset("diffusion_rnn", Preset.TINY, clip_x0_range="sensor",
                                    clip_x0_bias_range=[0.1] * 3 + [5.0] * 3)
    assert clip_bounds(sensor, np.zeros(6), std, []) == ((-0.1,) * 3 + (-5.0,) * 3, (0.1,) * 3 + (5.0,) * 3)
    with pytest.raises(DataError, match="outside clip_x0_bias_range"):
        clip_bounds(sensor, np.full(6, 0.2), std, [])
    with pytest.raises(ConfigError, match="needs clip_x0_bias_range"):
        ModelConfig.for_preset("diffusion_rnn", Preset.TINY, clip_x0_range="sensor")
    with pytest.raises(ConfigError, match="unknown clip_x0_range 'wide'"):
        ModelConfig.for_preset("diffusion_rnn", Preset.TINY, clip_x0_range="wide")
    assert clip_bounds(ModelConfig.for_preset("diffusion_rnn", Preset.TINY, clip_x0_sigmas=None),
                       mean, std, []) is None


def _oracle_samples(model, root: Path, target_raw: float, sampler: Sampler) -> tuple[torch.Tensor, ClipCount]:
    """Samples of a denoiser that knows the answer: every x0 estimate is ``target_raw`` on every channel."""
    z_star = model.normalizer.bias(torch.full((6,), target_raw))
    ab_all = model.scheduler.alphas_cumprod

    def oracle(x, t, code):
        ab = ab_all[t].to(x).reshape(-1, 1, 1)
        return (x - ab.sqrt() * z_star) / (1.0 - ab).sqrt()

    model.net.denoise = oracle
    ds = WindowDataset(root, Split.TEST)
    batch = WindowBatch.from_items(default_collate([ds[0], ds[1]]))
    count = ClipCount()
    out = model.sample(batch, num_samples=3, sampler=sampler, steps=10, generator=torch.Generator().manual_seed(0),
                       clip_count=count)
    return out, count


def test_a_bias_far_outside_the_training_range_is_reached_when_the_validation_split_shows_one(far_val, tmp_path):
    target = FAR_BIAS + 0.2  # ~11 train sigmas from the train mean, inside the validation evidence
    tiny = dict(preset=Preset.TINY, batch_size=16, max_steps=2, warmup_steps=1, val_every=2, checkpoint_every=2)
    runs = {}
    for name, clip in (("evidence", {}), ("train", {"clip_x0_range": "train"})):
        train(TrainConfig(method="diffusion_rnn", model_overrides=clip, **tiny), far_val, tmp_path / name)
        runs[name] = load_run(tmp_path / name)
    std = float(runs["train"].model.normalizer.bias_std[0])
    assert (target - float(runs["train"].model.normalizer.bias_mean[0])) / std > 10

    for sampler in (Sampler.DDIM, Sampler.DDPM):
        reached, count = _oracle_samples(runs["evidence"].model, far_val, target, sampler)
        np.testing.assert_allclose(reached.numpy(), target, rtol=1e-5)
        on_bound, any_step = count.fractions()
        assert count.values == 2 * 3 * 16 and on_bound == [0.0] * 6 and any_step == [0.0] * 6

        capped, count = _oracle_samples(runs["train"].model, far_val, target, sampler)
        hi = np.asarray(runs["train"].model.config.clip_x0_bounds[1])
        np.testing.assert_allclose(capped.numpy(), np.broadcast_to(hi, capped.shape), rtol=1e-5)
        assert count.fractions() == ([1.0] * 6, [1.0] * 6)  # every value ends on the bound
