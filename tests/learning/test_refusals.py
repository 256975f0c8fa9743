"""Refusals of the learning commands: each is one error line naming the culprit and the fix, exit 2, no
traceback and no output left behind (a test split the model saw, another IMU rate, a full disk, a
run folder in use by another training)."""

from __future__ import annotations

from pathlib import Path

import pytest

from biasgt.cli.app import main
from training.data.windows import WindowConfig, WindowSource, build_window_dataset
from window_data import make_window_dataset, train_tiny


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A tiny 200-Hz window dataset (train0 / val0 / test0) and a regression run trained on it."""
    root = tmp_path_factory.mktemp("refusals")
    data = make_window_dataset(root, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    train_tiny(data, root / "run", "regression_rnn")
    return root


def _first_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err and len(lines) == 1, err
    return lines[0]


def test_evaluate_refuses_a_test_split_holding_a_sequence_the_model_trained_on(trained, tmp_path, capsys):
    """A dataset whose test split holds train0 (the model's train sequence): refused naming it; the
    explicit flag evaluates it anyway."""
    src = [WindowSource("val0", "train", trained / "stores" / "val0", trained / "rec" / "val0"),
           WindowSource("train0", "test", trained / "stores" / "train0", trained / "rec" / "train0")]
    build_window_dataset(src, tmp_path / "leaked", WindowConfig(window_s=1.0, overlap=0.5))
    argv = ["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(tmp_path / "leaked"),
            "--out", str(tmp_path / "ev")]
    assert main(argv) == 2
    line = _first_error(capsys)
    assert line.startswith(f"biasgt evaluate: error: {trained / 'run' / 'best.pt'}: the test split of "
                           f"{tmp_path / 'leaked'} holds 1 sequence(s) the model trained on: train0"), line
    assert "--allow-train-overlap" in line and not (tmp_path / "ev").exists()
    assert main([*argv, "--allow-train-overlap"]) == 0
    assert (tmp_path / "ev" / "summary.json").is_file()


def test_evaluate_on_another_rate_names_the_rate(trained, tmp_path, capsys):
    """A 200-Hz model on a real 100-Hz dataset (whose 1-s windows have 101 samples, not 201): the rate is named."""
    slow = make_window_dataset(tmp_path, splits={"train": 1, "test": 1}, duration_s=5.0, rate_hz=100.0)
    assert main(["evaluate", "--checkpoint", str(trained / "run"), "--dataset", str(slow),
                 "--out", str(tmp_path / "ev")]) == 2
    line = _first_error(capsys)
    assert line.startswith(f"biasgt evaluate: error: {slow}: IMU rate 100 Hz, the checkpoint was trained at "
                           "200 Hz; re-create the dataset with --resample-hz 200"), line
    assert not (tmp_path / "ev").exists()
