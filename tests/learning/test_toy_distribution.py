"""Acceptance: the diffusion model learns a conditional distribution, regression only its mean.

Toy window datasets (written in the real format, :mod:`toy_windows`) whose bias given the IMU
condition ``c`` is known: ``b = 0.5 c + m`` with ``m = +0.6`` (30 %) or ``-0.6`` (70 %) in the
bimodal case, ``b = 0.5 c + 0.2 z`` in the Gaussian case. Samples are judged per IMU sample
(every timestep and channel of every sample of every test window) against that truth, with the
shipped sampler (DDIM, 25 steps, eta 0). Tiny preset, fixed seeds, one thread: deterministic.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from training.data.batch import WindowBatch
from training.fit.checkpoint import load_run
from training.config import Preset, TrainConfig
from training.data.dataset import Split, WindowDataset
from training.fit.train import train

sys.path.insert(0, str(Path(__file__).parents[1]))
from toy_windows import Kind, Toy, one_torch_thread, write_toy_dataset  # noqa: E402,F401 (a fixture)

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_torch_thread")]
SAMPLES = 20  # K per test window


def _residuals(tmp: Path, toy: Toy, method: str, steps: int) -> np.ndarray:
    """Samples minus the known conditional part ``a c``: [windows, K, T, 6]."""
    ds = tmp / f"ds_{toy.kind.value}"
    if not ds.exists():
        write_toy_dataset(ds, toy, train=2048, val=128, test=100, seed=11)
    config = TrainConfig(method=method, preset=Preset.TINY, seed=0, max_steps=steps, batch_size=128, lr=5e-3,
                         warmup_steps=20, ema_decay=0.99, val_every=steps, checkpoint_every=steps)
    run = load_run(train(config, ds, tmp / f"{toy.kind.value}_{method}"))
    test = WindowDataset(ds, Split.TEST)
    batch = WindowBatch.from_items(torch.utils.data.default_collate(test.__getitems__(list(range(len(test))))))
    s = run.model.sample(batch, SAMPLES, generator=torch.Generator().manual_seed(0)).numpy()
    c = np.asarray(test.manifest["sequences"]["toy_test"]["info"]["condition"])
    return s - toy.slope * c[:, None, None, None]


def test_bimodal_diffusion_keeps_both_modes_where_regression_collapses(tmp_path):
    toy = Toy(kind=Kind.BIMODAL, samples=4)
    d = _residuals(tmp_path, toy, "diffusion_rnn", 1000)
    share_plus = float((d > 0).mean())
    near_mode = float((np.abs(np.abs(d) - toy.offset) < 0.25).mean())
    assert abs(share_plus - toy.p_plus) < 0.10, share_plus
    assert near_mode > 0.8, near_mode  # the samples sit on the modes, not between them

    r = _residuals(tmp_path, toy, "regression_rnn", 300)
    mean = toy.offset * toy.p_plus - toy.offset * (1 - toy.p_plus)  # -0.24: between the modes
    assert abs(float(np.median(r)) - mean) < 0.05
    assert float((np.abs(np.abs(r) - toy.offset) < 0.25).mean()) < 0.05  # no prediction near a mode
    assert abs(float((r > 0).mean()) - toy.p_plus) > 0.25  # the mode shares are lost


def test_gaussian_diffusion_matches_mean_and_std(tmp_path):
    toy = Toy(kind=Kind.GAUSSIAN, samples=4)
    d = _residuals(tmp_path, toy, "diffusion_rnn", 1000)
    assert abs(float(d.mean())) < 0.1 * toy.std, d.mean()
    assert abs(float(d.std()) / toy.std - 1) < 0.15, d.std()
