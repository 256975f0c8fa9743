"""biasgt export: TorchScript and ONNX (run with onnxruntime) reproduce PyTorch's samples for the same noise."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biasgt.cli.app import main
from pipeline.errors import ConfigError
from training.fit.checkpoint import load_run
from training.config import Sampler
from training.deploy.export import export_run, onnx_session
from training.deploy.predict import predict_batch
from window_data import make_window_dataset, train_tiny



@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    data = make_window_dataset(root, splits={"train": 1, "val": 1}, duration_s=4.0)
    for m in ("diffusion_rnn", "regression_rnn"):
        train_tiny(data, root / m, m)
    return root


def _reference(run, imu: torch.Tensor, k: int, sampler: Sampler, seed: int) -> tuple[np.ndarray, torch.Tensor]:
    """PyTorch's samples and the initial noise they start from (the generator's first draw)."""
    with torch.no_grad():
        ref = run.model.sample(predict_batch(imu.numpy(), None, torch.float32), k, sampler=sampler, steps=4,
                               generator=torch.Generator().manual_seed(seed)).numpy()
    noise = torch.randn((imu.shape[0] * k, imu.shape[1], 6), generator=torch.Generator().manual_seed(seed))
    return ref, noise


@pytest.mark.parametrize("sampler", [Sampler.DDIM, Sampler.RELEASED])
def test_onnx_and_torchscript_reproduce_pytorch_samples(runs, tmp_path, sampler):
    run = load_run(runs / "diffusion_rnn")
    T = int(run.dataset["window_samples"])
    imu = torch.as_tensor(np.random.default_rng(0).normal(0, 0.5, (3, T, 6)), dtype=torch.float32)
    ref, noise = _reference(run, imu, 5, sampler, seed=11)  # 3 windows x 5 samples (export traced 2 x 3)
    onnx_file = export_run(runs / "diffusion_rnn", tmp_path / "m.onnx", "onnx", sampler=sampler, steps=4)
    out = onnx_session(onnx_file, threads=1).run(None, {"imu": imu.numpy(), "noise": noise.numpy()})[0]
    assert out.shape == (3, 5, T, 6)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5 * max(1.0, float(np.abs(ref).max())))
    ts = export_run(runs / "diffusion_rnn", tmp_path / "m.pt", "torchscript", sampler=sampler, steps=4)
    with torch.no_grad():
        np.testing.assert_allclose(torch.jit.load(str(ts))(imu, noise).numpy(), ref, rtol=0, atol=1e-6)


def test_regression_export_and_cli(runs, tmp_path, capsys):
    run = load_run(runs / "regression_rnn")
    T = int(run.dataset["window_samples"])
    imu = torch.as_tensor(np.random.default_rng(1).normal(0, 0.5, (2, T, 6)), dtype=torch.float32)
    ref, _ = _reference(run, imu, 1, Sampler.DDIM, seed=0)
    assert main(["export", "--checkpoint", str(runs / "regression_rnn"), "--format", "onnx",
                 "--out", str(tmp_path / "r.onnx")]) == 0
    assert "r.onnx" in capsys.readouterr().out
    out = onnx_session(tmp_path / "r.onnx").run(None, {"imu": imu.numpy()})[0]
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-6)
    with pytest.raises(ConfigError, match="DDPM"):
        export_run(runs / "diffusion_rnn", tmp_path / "x.onnx", "onnx", sampler=Sampler.DDPM)
    assert not (tmp_path / "x.onnx").exists()
