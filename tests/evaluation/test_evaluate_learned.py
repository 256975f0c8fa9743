"""Learned rows end to end at the tiny preset: train -> evaluate -> table through the workflow steps; bad inputs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

from biasgt.cli.app import main
from pipeline.errors import ConfigError, InputFormatError
from biasgt.workflow.learning import TrainingPlan, evaluate_step, table_step
from training.config import Sampler
from training.data.dataset import STATE_BIAS
from training.evaluation.evaluate import CALIBRATION_LEVELS, CHANNELS, EvaluationConfig, evaluate_run, load_test_windows
from training.evaluation.outputs import Aggregation, read_summary
from training.evaluation.table import TABLE_MD
from window_data import make_window_dataset, train_tiny

METHODS = ("diffusion_rnn", "regression_rnn")
EVAL = {"samples": 4, "steps": 3, "samplers": ["ddim", "released"], "examples": 2}


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("learned")
    data = make_window_dataset(root, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    for method in METHODS:
        train_tiny(data, root / "training" / method, method, steps=6)
        evaluate_step(data, root / "evaluation" / method, EVAL, run_dir=root / "training" / method, method=method)
    for ref in ("zero", "ground_truth"):
        evaluate_step(data, root / "evaluation" / ref, EVAL, reference=ref)
    return root


def test_diffusion_summary_rows_and_calibration(trained):
    s = read_summary(trained / "evaluation" / "diffusion_rnn")
    assert s.kind == "learned" and s.samples == 4 and s.steps == 3
    assert [(r.sampler, r.aggregation) for r in s.rows] == [
        (smp, agg) for smp in (Sampler.DDIM, Sampler.RELEASED) for agg in Aggregation]
    assert s.checkpoint["method"] == "diffusion_rnn" and s.checkpoint["parameters"] > 0
    frame = pd.read_parquet(trained / "evaluation" / "diffusion_rnn" / "windows.parquet")
    w = load_test_windows(trained / "dataset")
    samples = frame[(frame["aggregation"] == "samples") & (frame["sampler"] == "ddim")]
    assert len(samples) == 4 * len(w)
    # the headline figure is the mean over samples of the per-sample PRMSE (closed form from the frame)
    per_sample = samples.groupby("sample")["pos_err_m"].apply(lambda e: np.sqrt(np.mean(e**2)))
    assert s.row(Sampler.DDIM).average.prmse_m == pytest.approx(per_sample.mean(), rel=1e-12)
    assert s.row(Sampler.DDIM).average.prmse_std_m == pytest.approx(per_sample.std(ddof=0), rel=1e-9)
    for cal in s.calibration:
        cov = np.asarray(cal.coverage)
        assert cov.shape == (len(CALIBRATION_LEVELS), 6) and np.all((0 <= cov) & (cov <= 1))
        assert np.all(np.diff(cov, axis=0) >= 0)  # wider intervals cover at least as much
    # how often each sampler's clip bound, per channel, with its range; no prediction leaves the range
    assert [c.sampler for c in s.clip] == ["ddim", "released"]
    pred = pd.read_parquet(trained / "evaluation" / "diffusion_rnn" / "predictions.parquet")
    for c in s.clip:
        assert np.all(np.asarray(c.lo) < np.asarray(c.hi))
        assert all(0 <= b <= a <= 1 for b, a in zip(c.on_bound, c.any_step, strict=True))
        mine = pred[pred["sampler"] == c.sampler]
        for ch, lo, hi in zip(CHANNELS, c.lo, c.hi, strict=True):
            assert lo - 1e-6 <= mine[f"q0.025_{ch}"].min() and mine[f"q0.975_{ch}"].max() <= hi + 1e-6
    assert not read_summary(trained / "evaluation" / "regression_rnn").clip
    ex = pd.read_parquet(trained / "evaluation" / "diffusion_rnn" / "examples.parquet")
    assert ex["window"].nunique() == 2 and set(ex["sampler"]) == {"ddim", "released"}
    assert np.all(ex["q0.025"] <= ex["q0.975"])
    # the paper's Fig. 3: a few samples and the dataset's own bias beside the label, in the windows' layout
    from training.evaluation.evaluate import EXAMPLE_SAMPLES

    kept = [c for c in ex.columns if c.startswith("sample") and c[6:].isdigit()]
    assert kept == [f"sample{j}" for j in range(min(EXAMPLE_SAMPLES, EVAL["samples"]))]
    tw = load_test_windows(trained / "dataset")
    for (window, ch), part in ex[ex["sampler"] == "ddim"].groupby(["window", "channel"]):
        np.testing.assert_allclose(part["dataset"].to_numpy(), tw.arrays[STATE_BIAS][window][:, CHANNELS.index(ch)], atol=1e-12)


def _midpoint_end_states(imu: np.ndarray, bias: np.ndarray, dt_s: np.ndarray, R0: np.ndarray, v0: np.ndarray,
                         p0: np.ndarray, gravity: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """End orientation and position of windows [B, T, 6] integrated with ``imu - bias``, written here with scipy:
    rotation by the mid-point rate, velocity by the trapezoid, position by the exact double integral of a
    linearly interpolated world acceleration."""
    w, a = (imu - bias)[..., :3], (imu - bias)[..., 3:]
    R, v, p = Rotation.from_matrix(R0), v0.copy(), p0.copy()
    f = gravity + R.apply(a[:, 0])
    for k in range(imu.shape[1] - 1):
        h = dt_s[:, k, None]
        R = R * Rotation.from_rotvec(0.5 * (w[:, k] + w[:, k + 1]) * h)
        f_next = gravity + R.apply(a[:, k + 1])
        p = p + v * h + (2.0 * f + f_next) * h**2 / 6.0
        v = v + 0.5 * (f + f_next) * h
        f = f_next
    return R, p


def _rows_from_predictions(folder: Path, dataset: Path, stat: str, sampler: str) -> dict[str, tuple[float, float]]:
    """Sequence -> (PRMSE m, ROE deg) recomputed from predictions.parquet and the dataset's test arrays alone."""
    from training.data.dataset import Split, WindowDataset
    from training.evaluation.predictions import PREDICTIONS_PARQUET, prediction_array

    frame = pd.read_parquet(folder / PREDICTIONS_PARQUET)
    windows, bias = prediction_array(frame, stat, sampler)
    first = frame[frame["sampler"] == sampler].drop_duplicates("window").set_index("window").loc[windows]
    ds = WindowDataset(dataset, Split.TEST, dtype=torch.float64)
    out = {}
    for name in first["sequence"].unique():
        arrays = {k: np.asarray(v) for k, v in ds.arrays(name).items()}
        sel = (first["sequence"] == name).to_numpy()
        at = np.searchsorted(arrays["t_ns"][:, 0], first["t0_ns"].to_numpy()[sel])
        assert np.array_equal(arrays["t_ns"][at, 0], first["t0_ns"].to_numpy()[sel])
        g = ds.manifest["sequences"][name].get("info", {}).get("gravity_mps2") or (0.0, 0.0, -9.81)
        R, p = _midpoint_end_states(arrays["imu"][at], bias[sel], np.diff(arrays["t_ns"][at], axis=1) * 1e-9,
                                    arrays["start_R"][at], arrays["start_v"][at], arrays["start_p"][at],
                                    np.asarray(g, dtype=np.float64))
        pos = np.linalg.norm(p - arrays["end_p"][at], axis=1)
        rot = np.rad2deg((Rotation.from_matrix(arrays["end_R"][at]).inv() * R).magnitude())
        out[name] = (float(np.sqrt(np.mean(pos**2))), float(np.mean(rot)))
    return out


def test_learned_rows_recompute_from_the_kept_predictions(trained):
    """The mean and median rows of the diffusion model and the regression row, from predictions.parquet, the
    dataset and an integration written in this test."""
    data = trained / "dataset"
    cases = [("diffusion_rnn", "mean", Sampler.DDIM, Aggregation.MEAN),
             ("diffusion_rnn", "median", Sampler.RELEASED, Aggregation.MEDIAN),
             ("regression_rnn", "mean", None, Aggregation.SAMPLES)]
    for method, stat, sampler, aggregation in cases:
        folder = trained / "evaluation" / method
        row = read_summary(folder).row(sampler, aggregation)
        got = _rows_from_predictions(folder, data, stat, "" if sampler is None else sampler.value)
        assert set(got) == set(row.sequences)
        for name, (prmse, roe) in got.items():
            # float32 storage of the bias (~3e-10 here); the two integrations agree to ~1e-14
            assert prmse == pytest.approx(row.sequences[name].prmse_m, rel=1e-7), (method, stat, name)
            assert roe == pytest.approx(row.sequences[name].roe_deg, rel=1e-7), (method, stat, name)
    frame = pd.read_parquet(trained / "evaluation" / "diffusion_rnn" / "predictions.parquet")
    w = load_test_windows(data)
    T = int(json.loads((data / "manifest.json").read_text())["window_samples"])
    assert len(frame) == 2 * len(w) * T  # two samplers, every window, every time step
    assert np.all(frame["q0.025_gyro_x"] <= frame["median_gyro_x"]) and np.all(frame["std_acc_z"] >= 0)


def test_regression_is_deterministic_one_row(trained):
    s = read_summary(trained / "evaluation" / "regression_rnn")
    assert s.samples == 1 and len(s.rows) == 1 and s.rows[0].sampler is None and not s.calibration


def test_table_has_every_column(trained):
    dirs = [trained / "evaluation" / n for n in ("diffusion_rnn", "regression_rnn", "zero", "ground_truth")]
    table_step(dirs, trained / "evaluation")
    md = (trained / "evaluation" / TABLE_MD).read_text()
    rows = [[c.strip() for c in line.split("|")[1:3]] for line in md.splitlines()[4:] if line.startswith("| ")]
    labels, group = set(), ""
    for method, variant in rows:  # a variant row leaves its method cell empty (grouped under the one above)
        group = method or group
        labels.add(f"{group} {variant}".strip())
    for col in ("diffusion_rnn", "diffusion_rnn mean", "diffusion_rnn median", "diffusion_rnn released",
                "regression_rnn", "Zero bias", "Recovered GT bias (oracle)"):
        assert col in labels, (col, labels)


def test_cli_evaluate_and_bad_inputs(trained, tmp_path, capsys):
    data = trained / "dataset"
    run = trained / "training" / "regression_rnn"
    assert main(["evaluate", "--checkpoint", str(run), "--dataset", str(data), "--out", str(tmp_path / "ev")]) == 0
    assert "regression_rnn" in capsys.readouterr().out and (tmp_path / "ev" / "summary.json").is_file()
    assert main(["evaluate", "--checkpoint", str(trained / "training" / "diffusion_rnn"), "--dataset", str(data),
                 "--out", str(tmp_path / "ev_diffusion"), "--samples", "2", "--steps", "2"]) == 0
    out = capsys.readouterr().out
    assert "x0 clip (ddim): samples on the bound per channel:" in out
    # checkpoint of another method
    with pytest.raises(ConfigError, match="holds a regression_rnn model, not diffusion_rnn"):
        evaluate_run(run, data, tmp_path / "x", method="diffusion_rnn")
    assert main(["evaluate", "--checkpoint", str(run), "--dataset", str(data), "--method", "diffusion_rnn",
                 "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "best.pt" in err and not (tmp_path / "x").exists()
    # an evaluation dataset with another rate
    other = tmp_path / "rate"
    shutil.copytree(data, other)
    m = json.loads((other / "manifest.json").read_text())
    (other / "manifest.json").write_text(json.dumps({**m, "rate_hz": 100.0}))
    with pytest.raises(InputFormatError, match="IMU rate 100 Hz, the checkpoint was trained at 200 Hz"):
        evaluate_run(run, other, tmp_path / "x")
    # another window length (a real 2-s dataset)
    two = make_window_dataset(tmp_path / "two", splits={"train": 1, "test": 1}, duration_s=5.0, window_s=2.0)
    with pytest.raises(InputFormatError, match="windows of 401 samples at 200 Hz, the checkpoint was trained on 201"):
        evaluate_run(run, two, tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_training_plan_rejects_bad_sections():
    with pytest.raises(ConfigError, match="unknown key 'method'"):
        TrainingPlan.from_mapping({"method": "diffusion_rnn"})
    with pytest.raises(ConfigError, match="options sets seed"):
        TrainingPlan.from_mapping({"options": {"seed": 3}})
    with pytest.raises(ConfigError, match="max_steps"):
        TrainingPlan.from_mapping({"options": {"max_steps": 0}})
    with pytest.raises(ConfigError, match="training.threads must be >= 1"):
        TrainingPlan.from_mapping({"threads": 0})
    with pytest.raises(ConfigError, match="clip_x0_sigmas must be positive or null"):
        TrainingPlan.from_mapping({"options": {"model_overrides": {"clip_x0_sigmas": -1}}})
    with pytest.raises(ConfigError, match=r"unknown key 'sampler' \(did you mean 'samplers'"):
        EvaluationConfig.from_mapping({"sampler": "ddim"})


def test_job_parameters_change_only_with_the_run():
    """A train job's parameters are its resolved TrainConfig: adding seeds or methods leaves them alone;
    an evaluate job's exclude the list of references."""
    from biasgt.workflow.learning import evaluation_settings
    from training.config import TrainConfig

    one = TrainingPlan.from_mapping({"methods": ["diffusion_rnn"], "seeds": [0]})
    more = TrainingPlan.from_mapping({"methods": ["diffusion_rnn", "regression_rnn"], "seeds": [0, 1]})
    assert one.run_settings("diffusion_rnn", "0") == more.run_settings("diffusion_rnn", 0)
    assert one.run_settings("diffusion_rnn", 0) != more.run_settings("diffusion_rnn", 1)
    # threads per job is how the job runs, not what it trains: changing it retrains nothing
    assert TrainingPlan.from_mapping({"threads": 1}).run_settings("diffusion_rnn", 0) == one.run_settings("diffusion_rnn", 0)
    assert TrainConfig.from_mapping(more.run_settings("regression_rnn", 1)) == more.train_config("regression_rnn", 1)
    assert evaluation_settings({"samples": 8, "references": ["zero"]}) == {"samples": 8}
