"""biasgt predict: windows cover every IMU sample once; values are the model's samples; the output is a bias file."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

from pipeline.bias_table import CSV_HEADER
from biasgt.cli.app import main
from pipeline.errors import DataError
from pipeline.store import read_store
from training.fit.checkpoint import load_run
from training.deploy.predict import predict_batch, predict_sequence, window_starts
from validation.validate import read_bias_file, validate_inputs
from window_data import make_window_dataset, train_tiny



@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("predict")
    data = make_window_dataset(root, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    for m in ("regression_rnn", "diffusion_rnn"):
        train_tiny(data, root / m, m)
    return root


@pytest.mark.parametrize("n, T, expected", [(10, 4, [0, 4, 6]), (8, 4, [0, 4]), (3, 4, []), (4, 4, [0])])
def test_window_starts(n, T, expected):
    assert window_starts(n, T).tolist() == expected


def test_regression_prediction_is_the_models_output(runs):
    run = load_run(runs / "regression_rnn")
    seq = read_store(runs / "stores" / "test0")
    frame = predict_sequence(run, seq, samples=3)
    assert list(frame.columns[:13]) == list(CSV_HEADER) and len(frame) == len(seq.imu)
    assert np.array_equal(frame["t_ns"].to_numpy(), seq.imu.t_ns)
    T = int(run.dataset["window_samples"])
    starts = window_starts(len(seq.imu), T)
    last = starts[-1]
    with torch.no_grad():
        windows = np.stack([seq.imu.imu_6[:T], seq.imu.imu_6[last:last + T]])
        direct = run.model.sample(predict_batch(windows, None, torch.float32), num_samples=1).double().numpy()[:, 0]
    cols = ["bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z"]
    np.testing.assert_allclose(frame[cols].to_numpy()[:T], direct[0], rtol=1e-6, atol=1e-9)
    tail = frame[frame["window"] == len(starts) - 1]  # only the samples no earlier window covers
    np.testing.assert_allclose(tail[cols].to_numpy(), direct[1][T - len(tail):], rtol=1e-6, atol=1e-9)
    assert (frame[[c + "_std" for c in cols]].to_numpy() == 0).all()  # one deterministic prediction


def test_cli_predict_diffusion_writes_a_bias_file(runs, tmp_path, capsys):
    out = tmp_path / "pred"
    assert main(["predict", str(runs / "stores" / "test0"), "--checkpoint", str(runs / "diffusion_rnn"),
                 "--samples", "4", "--steps", "3", "--out", str(out)]) == 0
    assert "pred.parquet" in capsys.readouterr().out
    csv, parquet = pd.read_csv(out.with_suffix(".csv")), pd.read_parquet(out.with_suffix(".parquet"))
    np.testing.assert_allclose(csv["bg_x"], parquet["bg_x"], rtol=1e-8)
    assert (parquet["bg_x_std"] > 0).all() and (parquet["ba_z_q025"] <= parquet["ba_z_q975"]).all()
    track = read_bias_file(out.with_suffix(".csv"))  # a bias file biasgt validate accepts
    assert len(track.t_ns) == len(parquet)
    res = validate_inputs(read_store(runs / "stores" / "test0"), bias_files=[(None, out.with_suffix(".csv"))])
    assert res.sources["recovered"].windows > 0


def test_predict_refuses_another_rate(runs, tmp_path):
    from pipeline.sim import ImuNoiseConfig, SimConfig, simulate

    sim = simulate(SimConfig(duration_s=3.0, seed=9, name="r100", imu=ImuNoiseConfig(rate_hz=100.0)))
    with pytest.raises(DataError, match="IMU rate 100 Hz, the model was trained at 200 Hz"):
        predict_sequence(load_run(runs / "regression_rnn"), sim.sequence)
