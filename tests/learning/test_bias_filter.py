"""The causal bias filter (training.rows.bias_filter): its bias against the truth of the independent
generator (tests/independent.py, written from the equations), its causality, and its reference row.
"""

from __future__ import annotations

import numpy as np
import pytest

from independent import REPORTED, LissajousMotion, RestThenMotion, make_sequence
from training.rows.bias_filter import run_bias_filter, track_of
from training.config import EvaluationConfig
from training.data.records import SequenceContext, detect_rests, open_context
from training.evaluation.evaluate import evaluate_reference
from training.references import get_reference
from training.data.sim_context import RestSim, write_rest_sim_dataset

#: The prior a train split would give: zero mean, a sigma of the generator's turn-on sizes.
PRIOR_STD = np.r_[np.full(3, 0.02), np.full(3, 0.1)]


def _independent(seed: int, duration_s: float = 90.0):
    """A 5-s rest, then hand-held Lissajous motion; the datasheet's random walks."""
    seq = make_sequence(duration_s, seed=seed, motion=RestThenMotion(LissajousMotion(), rest_s=5.0),
                        gyro_random_walk=REPORTED["gyro_random_walk"], acc_random_walk=REPORTED["acc_random_walk"])
    imu = np.hstack([seq.gyro_radps, seq.acc_mps2])
    return seq, imu, np.hstack([seq.bias_gyro_radps, seq.bias_acc_mps2])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_filter_finds_the_gyro_bias_and_narrows_the_accelerometer_bias(seed):
    seq, imu, truth = _independent(seed)
    track = run_bias_filter(imu, seq.t_ns, detect_rests(imu, seq.rate_hz), np.zeros(6), PRIOR_STD, 9.81)
    late = slice(len(imu) // 2, None)  # the second half: after the rest and 40 s of motion
    err = np.sqrt(np.mean((track.bias[late] - truth[late]) ** 2, axis=0))
    prior_err = np.sqrt(np.mean(truth[late] ** 2, axis=0))
    # gyro: within 1 mrad/s of the truth on every axis, its sigma covering the error
    assert np.all(err[:3] < 1e-3), err
    assert np.all(np.abs(track.bias[late, :3] - truth[late, :3]) < 4 * track.std[late, :3] + 1e-4)
    # accelerometer: only partly observable from bounded motion; the error at least 30 % below the prior's
    assert np.linalg.norm(err[3:]) < 0.7 * np.linalg.norm(prior_err[3:]), (err, prior_err)


def test_filter_is_causal():
    seq, imu, _ = _independent(0, duration_s=20.0)
    rests = detect_rests(imu, seq.rate_hz)
    before = run_bias_filter(imu, seq.t_ns, rests, np.zeros(6), PRIOR_STD, 9.81)
    k = 2500
    changed = imu.copy()
    changed[k + 1:] += 0.5  # every reading after sample k
    after = run_bias_filter(changed, seq.t_ns, rests, np.zeros(6), PRIOR_STD, 9.81)
    np.testing.assert_array_equal(before.bias[: k + 1], after.bias[: k + 1])
    assert not np.allclose(before.bias[-1], after.bias[-1])


def test_bias_filter_row_holds_the_track_at_each_window_end(tmp_path):
    sim = RestSim(duration_s=20.0, rate_hz=50.0)
    dataset = write_rest_sim_dataset(tmp_path / "ds", sim, train=4, val=1, test=2, seed=3)
    row = get_reference("bias_filter")
    assert not row.oracle and "context" in row.needs  # a usable row, from the IMU record alone
    summary = evaluate_reference("bias_filter", dataset, None, EvaluationConfig(samples=1, gravity="recovered"))
    result = summary.summary.rows[0]
    assert np.isfinite(result.average.prmse_m) and np.isfinite(result.average.roe_deg)
    ctx: SequenceContext = open_context(dataset, "rest_test_00")
    assert any(key[0] == "bias_filter" for key in ctx.derived)  # computed once, kept with the record
    track = next(v for key, v in ctx.derived.items() if key[0] == "bias_filter")
    assert track.bias.shape == (len(ctx.t_ns), 6) and np.all(np.isfinite(track.std))
    fresh = track_of(ctx, *next((np.array(k[1]), np.array(k[2]), k[3]) for k in ctx.derived if k[0] == "bias_filter"))
    assert fresh is track


def test_filter_base_and_context_block(tmp_path):
    from training.context.model import Base, ContextModelConfig, Stats, context_features

    sim = RestSim(duration_s=20.0, rate_hz=50.0)
    dataset = write_rest_sim_dataset(tmp_path / "ds", sim, train=2, val=1, test=1, seed=5)
    ctx = open_context(dataset, "rest_test_00")
    stats = Stats(np.zeros(6), np.ones(6), np.r_[0.01, -0.02, 0.03, 0.1, -0.1, 0.2], PRIOR_STD)
    config = ContextModelConfig(base="filter", history_s=())
    assert config.base is Base.FILTER and config.filter  # the filter base brings its block
    T = 50
    t0 = ctx.t_ns[[0, 300, 600]]
    feats, base = context_features(ctx, t0, T, stats, config, 9.81)
    assert feats.shape == (3, config.features())
    track = track_of(ctx, stats.bias_mean, stats.bias_std, 9.81)
    last = ctx.index(t0) + T - 1
    np.testing.assert_array_equal(base[:, :3], track.bias[last, :3])  # the filter's gyro at the window's end
    np.testing.assert_array_equal(base[:, 3:], np.tile(stats.bias_mean[3:], (3, 1)))  # the train mean's acc
    np.testing.assert_allclose(feats[:, -12:-6], (track.bias[last] - stats.bias_mean) / stats.bias_std)
    np.testing.assert_allclose(feats[:, -6:], track.std[last] / stats.bias_std)


def test_state_labels_are_the_state_bias_where_a_sequence_has_one(tmp_path):
    from pipeline.types import Split
    from training.data.dataset import STATE_BIAS, WindowDataset, with_state_labels

    sim = RestSim(duration_s=20.0, rate_hz=50.0)
    dataset = write_rest_sim_dataset(tmp_path / "ds", sim, train=2, val=1, test=1, seed=7)
    ds = WindowDataset(dataset, Split.TRAIN)
    first, second = ds.sequences[:2]
    folder = dataset / ds.manifest["sequences"][first]["path"]
    labels = np.load(folder / "bias.npy")
    state = labels + np.r_[0.0, 0.0, 0.0, 0.5, 0.5, 0.5]  # a state bias that differs from the labels
    np.save(folder / f"{STATE_BIAS}.npy", state)
    taken = WindowDataset(with_state_labels(dataset, tmp_path / "state"), Split.TRAIN)
    np.testing.assert_array_equal(np.asarray(taken.arrays(first)["bias"]), state)
    # the other sequence has no state: its labels stay; everything else is the dataset's own
    np.testing.assert_array_equal(np.asarray(taken.arrays(second)["bias"]), np.asarray(ds.arrays(second)["bias"]))
    np.testing.assert_array_equal(np.asarray(taken.arrays(first)["imu"]), np.asarray(ds.arrays(first)["imu"]))
    assert taken.manifest["normalization"] == ds.manifest["normalization"]
    assert np.array_equal(np.load(folder / "bias.npy"), labels)  # the source untouched


def test_bias_filter_row_has_a_table_i_footnote_only_when_present():
    from types import SimpleNamespace

    row = get_reference("bias_filter")
    assert "error-state Kalman filter" in row.footnote([SimpleNamespace(method="bias_filter")])
    assert row.footnote([SimpleNamespace(method="train_mean")]) is None


def test_registered_network_with_the_filter_base_starts_at_the_filter_gyro(tmp_path):
    """The context the feeder gives ends with the base (the filter's gyro, the train mean's accelerometer,
    normalised), and the untrained network is that base."""
    import torch

    from training.config import ModelConfig
    from training.context.model import ContextFeeder, ContextNet
    from training.data.normalizer import Normalizer

    sim = RestSim(duration_s=20.0, rate_hz=50.0)
    dataset = write_rest_sim_dataset(tmp_path / "ds", sim, train=2, val=1, test=1, seed=5)
    config = ModelConfig.for_preset("context_residual", "tiny", base="filter", history_s=())
    mean, std = np.r_[0.01, -0.02, 0.03, 0.1, -0.1, 0.2], PRIOR_STD
    normalizer = Normalizer({"imu_mean": np.zeros(6), "imu_std": np.ones(6), "bias_mean": mean, "bias_std": std})
    feeder = ContextFeeder.for_model(dataset, config, normalizer)
    net = ContextNet(config)
    F = net.features
    assert F == 8 + 12  # the rest summary, then the filter block
    ctx = open_context(dataset, "rest_test_00")
    t0, T = ctx.t_ns[[0, 300, 600]], 50
    context = feeder(["rest_test_00"] * 3, t0, T)
    assert context.shape == (3, F + 6)
    track = track_of(ctx, normalizer.bias_mean.double().numpy(), normalizer.bias_std.double().numpy(), 9.81)
    last = ctx.index(t0) + T - 1
    f32 = normalizer.bias_std.double().numpy()
    np.testing.assert_allclose(context[:, F:F + 3].numpy(), (track.bias[last, :3] - mean[:3]) / f32[:3], rtol=1e-6)
    np.testing.assert_array_equal(context[:, F + 3:].numpy(), 0.0)  # the train mean's accelerometer
    out = net(torch.zeros(3, 40, 6), context)  # untrained: the residual's last layers are zero
    assert out.shape == (3, 40, 6)
    torch.testing.assert_close(out[:, 0], context[:, F:].float())
