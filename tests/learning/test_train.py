"""Training infrastructure: resume after SIGKILL, determinism, validation-chosen best, bad input."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.errors import BiasgtError, DataError, InputFormatError
from training.fit.checkpoint import BEST, LAST, CheckpointError, load_checkpoint, load_run, weights_hash
from training.config import Preset, TrainConfig
from training.data.dataset import Split, WindowDataset
from training.fit.train import TrainingError, train

sys.path.insert(0, str(Path(__file__).parents[1]))
from toy_windows import Kind, Toy, one_torch_thread, write_toy_dataset  # noqa: E402,F401 (a fixture)

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.usefixtures("one_torch_thread")
TINY = dict(preset=Preset.TINY, batch_size=16, lr=3e-3, warmup_steps=5, val_every=10, checkpoint_every=10)


@pytest.fixture(scope="module")
def toy_ds(tmp_path_factory) -> Path:
    return write_toy_dataset(tmp_path_factory.mktemp("toy") / "ds", Toy(kind=Kind.LINEAR, samples=16),
                             train=96, val=32, test=32)


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "biasgt.cli", "-q", "train", *args]


def test_resume_after_sigkill_gives_bit_identical_weights(toy_ds, tmp_path):
    args = ["--dataset", str(toy_ds), "--method", "diffusion_rnn", "--preset", "tiny", "--max-steps", "120",
            "--config", str(tmp_path / "c.yaml")]
    (tmp_path / "c.yaml").write_text("batch_size: 16\nval_every: 25\ncheckpoint_every: 5\nlr: 0.003\n"
                                     "model_overrides: {tcn_dropout: 0.2}\n")  # dropout draws from torch's RNG
    subprocess.run(_cli(*args, "--out", str(tmp_path / "whole")), env=_env(), check=True)

    cut = tmp_path / "cut"
    proc = subprocess.Popen(_cli(*args, "--out", str(cut)), env=_env())
    deadline = time.monotonic() + 120
    while not (cut / LAST).exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "training ended before it could be killed"
    killed_at = load_checkpoint(cut / LAST)["step"]
    assert 0 < killed_at < 120
    assert not (cut / "run.json").exists()

    subprocess.run(_cli(*args, "--out", str(cut), "--resume"), env=_env(), check=True)
    whole, resumed = load_checkpoint(tmp_path / "whole" / LAST), load_checkpoint(cut / LAST)
    assert resumed["step"] == whole["step"] == 120
    assert weights_hash(resumed["model"]) == weights_hash(whole["model"])
    assert weights_hash(resumed["ema"]["model"]) == weights_hash(whole["ema"]["model"])
    assert weights_hash(load_checkpoint(cut / BEST)["model"]) == weights_hash(load_checkpoint(tmp_path / "whole" / BEST)["model"])
    rows = [[r[k] for k in ("step", "train_loss", "val_loss", "lr")] for r in csv.DictReader(open(cut / "metrics.csv"))]
    assert rows == [[r[k] for k in ("step", "train_loss", "val_loss", "lr")]
                    for r in csv.DictReader(open(tmp_path / "whole" / "metrics.csv"))]


class _Stop(Exception):
    """Stands for a kill between two steps (after the checkpoint of the last one)."""


def _assert_bit_identical(a, b, where: str = "") -> None:
    """Nested checkpoint values equal bit for bit (tensors and arrays elementwise, others with ==)."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _assert_bit_identical(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_bit_identical(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b), where
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), where
    else:
        assert a == b, where


def test_resume_with_dropout_is_bit_identical(toy_ds, tmp_path, monkeypatch):
    """Dropout draws from torch's global RNG: nothing else may draw from it between the restore and the
    first resumed step (a DataLoader iterator without its own generator does)."""
    import training.fit.train as train_module

    config = TrainConfig(method="diffusion_rnn", max_steps=20, model_overrides={"tcn_dropout": 0.3},
                         **{**TINY, "checkpoint_every": 5})
    train(config, toy_ds, tmp_path / "whole")

    real_step = train_module._Trainer.train_step

    def stop_after_15(self, batch):
        if self.run.step == 15:
            raise _Stop
        return real_step(self, batch)

    monkeypatch.setattr(train_module._Trainer, "train_step", stop_after_15)
    with pytest.raises(_Stop):
        train(config, toy_ds, tmp_path / "cut")
    assert load_checkpoint(tmp_path / "cut" / LAST)["step"] == 15
    monkeypatch.setattr(train_module._Trainer, "train_step", real_step)
    torch.manual_seed(12345)  # whatever the global RNG holds before the resume
    train(config, toy_ds, tmp_path / "cut", resume=True)

    whole, resumed = load_checkpoint(tmp_path / "whole" / LAST), load_checkpoint(tmp_path / "cut" / LAST)
    assert resumed["step"] == whole["step"] == 20
    for key in ("model", "ema", "optimizer", "lr_schedule", "rng"):
        _assert_bit_identical(whole[key], resumed[key], key)
    timeless = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    _assert_bit_identical(timeless(whole["metrics"]), timeless(resumed["metrics"]), "metrics")


def test_same_seed_same_hashes_other_seed_differs(toy_ds, tmp_path):
    hashes = []
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        train(TrainConfig(method="regression_rnn", seed=seed, max_steps=20, **TINY), toy_ds, tmp_path / name)
        hashes.append(weights_hash(load_checkpoint(tmp_path / name / LAST)["model"]))
    assert hashes[0] == hashes[1] != hashes[2]


def test_checkpoint_holds_everything_to_rebuild_and_best_is_the_lowest_validation_loss(toy_ds, tmp_path, monkeypatch):
    opened: list[Split] = []
    real_init = WindowDataset.__init__

    def spy(self, root, split=Split.TRAIN, dtype=None):
        opened.append(Split(split))
        real_init(self, root, split, dtype)

    monkeypatch.setattr(WindowDataset, "__init__", spy)
    out = train(TrainConfig(method="diffusion_rnn", max_steps=40, **TINY), toy_ds, tmp_path / "run")
    assert Split.TEST not in opened  # the test split is read only by evaluation

    state = load_checkpoint(out / LAST)
    assert {"model", "ema", "optimizer", "lr_schedule", "rng", "step", "config", "model_config", "normalizer",
            "dataset"} <= set(state)
    assert {"torch", "numpy", "python", "noise"} <= set(state["rng"])
    manifest = json.loads((toy_ds / "manifest.json").read_text())
    assert state["dataset"]["format_version"] == manifest["format_version"]
    assert state["normalizer"]["bias_std"] == pytest.approx(manifest["normalization"]["bias_std"], rel=1e-6)

    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert [int(r["step"]) for r in rows] == [10, 20, 30, 40]
    best_row = min(rows, key=lambda r: float(r["val_loss"]))
    best = load_checkpoint(out / BEST)
    assert best["step"] == int(best_row["step"])
    summary = json.loads((out / "run.json").read_text())
    assert summary["best_step"] == best["step"] and summary["windows_per_s"] > 0

    run = load_run(out, "best")  # EMA weights, eval mode, rebuilt from the checkpoint alone
    assert not run.model.training
    assert weights_hash(run.model.state_dict()) == weights_hash(best["ema"]["model"])


def test_non_finite_loss_names_the_step_and_keeps_the_last_good_checkpoint(toy_ds, tmp_path, monkeypatch):
    from training.models.bias_model import BiasModel

    real_loss, calls = BiasModel.loss, {"n": 0}

    def flaky(self, batch, generator=None):
        loss = real_loss(self, batch, generator)
        if self.training:
            calls["n"] += 1
            if calls["n"] == 17:
                return loss * float("nan")
        return loss

    monkeypatch.setattr(BiasModel, "loss", flaky)
    with pytest.raises(TrainingError, match="at step 17"):
        train(TrainConfig(method="regression_rnn", max_steps=40, **TINY), toy_ds, tmp_path / "run")
    assert load_checkpoint(tmp_path / "run" / LAST)["step"] == 10
    assert not (tmp_path / "run" / "run.json").exists()


def _edit_manifest(src: Path, dst: Path, edit) -> Path:
    import shutil

    shutil.copytree(src, dst)
    manifest = json.loads((dst / "manifest.json").read_text())
    edit(manifest)
    (dst / "manifest.json").write_text(json.dumps(manifest))
    return dst


def test_bad_datasets_fail_with_one_line_and_write_nothing(toy_ds, tmp_path):
    config = TrainConfig(method="regression_rnn", max_steps=5, **TINY)
    no_val = write_toy_dataset(tmp_path / "noval", Toy(), train=32, val=0, test=8)
    other = _edit_manifest(toy_ds, tmp_path / "v99", lambda m: m.update(format_version=99))
    no_norm = _edit_manifest(toy_ds, tmp_path / "nonorm", lambda m: m.pop("normalization"))
    cases = [(no_val, DataError, "validation split has no windows"),
             (other, InputFormatError, "unsupported dataset format 99"),
             (no_norm, InputFormatError, "normaliser statistics")]
    for ds, kind, text in cases:
        out = tmp_path / f"run_{ds.name}"
        with pytest.raises(kind, match=text) as info:
            train(config, ds, out)
        assert "manifest.json" in str(info.value) and "\n" not in str(info.value)
        assert not out.exists()
    with pytest.raises(DataError, match="temperature_degc"):
        train(config.replace(use_temperature=True), toy_ds, tmp_path / "run_temp")
    assert not (tmp_path / "run_temp").exists()

    proc = subprocess.run(_cli("--dataset", str(other), "--method", "regression_rnn", "--out", str(tmp_path / "x")),
                          env=_env(), capture_output=True, text=True)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr


def test_an_existing_run_is_not_overwritten_and_resume_checks_options(toy_ds, tmp_path):
    config = TrainConfig(method="regression_rnn", max_steps=10, **TINY)
    train(config, toy_ds, tmp_path / "run")
    with pytest.raises(TrainingError, match="--resume"):
        train(config, toy_ds, tmp_path / "run")
    with pytest.raises(TrainingError, match="lr"):
        train(config.replace(lr=1e-2), toy_ds, tmp_path / "run", resume=True)
    with pytest.raises(CheckpointError, match="not found"):
        load_run(tmp_path / "nothing")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="cannot read"):
        load_run(tmp_path / "junk.pt")
    assert issubclass(CheckpointError, BiasgtError)


def test_batched_item_reads_equal_single_reads(toy_ds):
    ds = WindowDataset(toy_ds, Split.TRAIN)
    idx = [5, 1, 77, 1, 40]
    for a, b in zip(ds.__getitems__(idx), [ds[i] for i in idx], strict=True):
        assert a.keys() == b.keys()
        for k in a:
            assert (torch.equal(a[k], b[k]) if isinstance(a[k], torch.Tensor) else a[k] == b[k]), k


def test_temperature_conditioning_trains_from_a_dataset_with_temperature(tmp_path, monkeypatch):
    """A dataset whose windows carry ``temperature_degc`` [T] trains a 7-channel model."""
    import training.data.dataset as dataset_module

    ds = write_toy_dataset(tmp_path / "ds", Toy(), train=48, val=16, test=0, temperature=True)
    if "temperature_degc" not in WindowDataset(ds, Split.TRAIN)[0]:
        # this dataset writer predates the optional temperature array: add it as the windows stage will
        from toy_windows import toy_sequence

        for i, (split, n) in enumerate(((Split.TRAIN, 48), (Split.VAL, 16))):
            seq = toy_sequence(Toy(), f"toy_{split.value}", split, n, i, temperature=True)
            np.save(ds / "sequences" / seq.name / "temperature_degc.npy", seq.arrays["temperature_degc"])
        monkeypatch.setattr(dataset_module, "ARRAYS", (*dataset_module.ARRAYS, "temperature_degc"))
    out = train(TrainConfig(method="diffusion_rnn", max_steps=10, use_temperature=True, **TINY), ds,
                tmp_path / "run")
    run = load_run(out)
    assert run.model.config.condition_channels == 7
    t_mean, t_std = load_checkpoint(out / LAST)["normalizer"]["temperature_degc"]
    c = np.concatenate([json.loads((ds / "manifest.json").read_text())["sequences"]["toy_train"]["info"]["condition"]])
    assert t_mean == pytest.approx(np.mean(20 + 5 * c), rel=1e-5)
    assert t_std == pytest.approx(np.std(20 + 5 * c), rel=1e-3)
