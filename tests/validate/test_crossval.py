"""Cross-validation of a recovered bias by time blocks (validation.crossval.blocks, validation.crossval.heldout)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.errors import ValidationError
from pipeline.sim import SimConfig, simulate
from pipeline.sim.config import (
    EUROC_ACC_RANDOM_WALK,
    EUROC_GYRO_RANDOM_WALK,
    ImuNoiseConfig,
    MotionConfig,
    PoseStreamConfig,
    TemperatureConfig,
)
from recovery.recover import recover
from validation.config import ValidationConfig
from validation.crossval.blocks import BlockFolds, crossvalidate_recovery, fold_prediction, held_constant, without_fold
from validation.crossval.heldout import held_out_errors, held_out_windows
from validation.validate import plan_windows, reference_from_states

S = 1_000_000_000


def test_blocks_and_folds_closed_form():
    folds = BlockFolds(t0_ns=5 * S, block_s=10.0, n_folds=3)
    t = np.array([5, 14, 15, 25, 35, 45, 4], dtype=np.int64) * S + np.array([0, S - 1, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(folds.block(t), [0, 0, 1, 2, 3, 4, -1])
    np.testing.assert_array_equal(folds.fold(t), [0, 0, 1, 2, 0, 1, 2])
    with pytest.raises(ValidationError):
        BlockFolds(0, 10.0, 1)


@pytest.fixture(scope="module")
def handheld():
    """40 s handheld, the datasheet's bias random walk and no temperature term: a bias that a recovery
    can predict across a 5-s block without poses."""
    imu = ImuNoiseConfig(gyro_random_walk=EUROC_GYRO_RANDOM_WALK, acc_random_walk=EUROC_ACC_RANDOM_WALK,
                         temperature=TemperatureConfig(enabled=False))
    return simulate(SimConfig(duration_s=40.0, seed=4, imu=imu, motion=MotionConfig(preset="handheld"),
                              poses=PoseStreamConfig(extrinsic_known=True)))


def test_without_fold_drops_exactly_that_fold(handheld):
    name, poses = next(iter(handheld.sequence.poses.items()))
    folds = BlockFolds(int(handheld.sequence.imu.t_ns[0]), 5.0, 3)
    kept = [without_fold(poses, folds, k) for k in range(3)]
    for k, p in enumerate(kept):
        assert not np.any(folds.fold(p.t_ns) == k)
        assert len(p) == int(np.sum(folds.fold(poses.t_ns) != k))
    # each sample is left out by exactly one fold
    assert sum(len(p) for p in kept) == 2 * len(poses)


def test_held_out_windows_lie_inside_one_block(handheld):
    imu = handheld.sequence.imu
    plan = plan_windows(imu, ValidationConfig())
    folds = BlockFolds(int(imu.t_ns[0]), 10.0, 2)
    ref = reference_from_states(handheld.sequence.ground_truth, imu.t_ns)
    win = held_out_windows(imu, plan, folds, ref)
    # 200-Hz IMU, 1-s windows (samples s .. s + 200) every 100 samples, 10-s blocks of samples
    # [2000 b, 2000 b + 1999]: starts 2000 b + 0, 100, ..., 1700 fit, 18 per block, 4 blocks
    assert imu.rate_hz == pytest.approx(200.0) and plan.n == 200
    assert win.sum() == 4 * 18
    b = folds.block(imu.t_ns)
    assert np.all(b[plan.starts[win]] == b[plan.starts[win] + plan.n])


def test_each_sample_gets_the_bias_of_the_fold_that_left_it_out(handheld):
    seq = handheld.sequence
    name = next(iter(seq.poses))
    folds = BlockFolds(int(seq.imu.t_ns[0]), 5.0, 3)
    all_t = seq.poses[name].t_ns

    def fake_recover(s, stream):
        missing = set(folds.fold(np.setdiff1d(all_t, s.poses[stream].t_ns)).tolist())
        assert len(missing) == 1
        k = missing.pop()
        return SimpleNamespace(bias_at=lambda t: np.full((len(t), 6), float(k)),
                               std_at=lambda t: np.full((len(t), 6), 0.5 + k), report={})

    cv = crossvalidate_recovery(seq, name, folds, fake_recover)
    np.testing.assert_array_equal(cv.bias[:, 0], folds.fold(seq.imu.t_ns))
    np.testing.assert_array_equal(cv.raw_std[:, 5], 0.5 + folds.fold(seq.imu.t_ns))  # and that fold's sigma
    assert len(cv.recoveries) == 3


def test_an_edge_block_gets_the_end_value_with_the_random_walk_sigma():
    """Keyframes at 5-10 s (bias 0.1 + 0.01 t, sigma 0.02; random walks 0.03 and 0.2): beyond the span the
    bias random walk predicts the end value with variance sigma_end^2 + rw^2 |t - t_end| (closed form);
    inside, the keyframes' interpolation (the Brownian bridge adds nothing at a keyframe)."""
    kt = np.arange(5, 11) * S
    b = np.repeat((0.1 + 0.01 * np.arange(5, 11))[:, None], 3, 1)
    sd = np.full((6, 3), 0.02)
    res = SimpleNamespace(t_ns=kt, bias_gyro_radps=b, bias_acc_mps2=b, bias_gyro_std_radps=sd,
                          bias_acc_std_mps2=sd, report={"noise": {"gyro_random_walk": 0.03, "acc_random_walk": 0.2}})
    t = np.array([0, 3, 5, 7, 10, 14]) * S
    got = fold_prediction(res, t)
    np.testing.assert_allclose(got.bias[:, 0], [0.15, 0.15, 0.15, 0.17, 0.20, 0.20])
    np.testing.assert_allclose(got.std[:, 0], np.sqrt(0.02**2 + 0.03**2 * np.array([5, 2, 0, 0, 0, 4])))
    np.testing.assert_allclose(got.std[:, 3], np.sqrt(0.02**2 + 0.2**2 * np.array([5, 2, 0, 0, 0, 4])))
    np.testing.assert_array_equal(got.clamped, [True, True, False, False, False, True])


def test_crossvalidated_recovery_integrates_nearly_like_the_truth(handheld):
    """Held-out windows (5-s blocks, 2 folds): the cross-validated recovered bias integrates within 3x of the
    true bias (an independent reference; measured 4.5 vs 2.1 mm: a block without poses costs accuracy) and
    far better than no bias (58 mm)."""
    seq, truth = handheld.sequence, handheld.truth
    imu = seq.imu
    folds = BlockFolds(int(imu.t_ns[0]), 5.0, 2)
    cv = crossvalidate_recovery(seq, "mocap0", folds, lambda s, st: recover(s, pose_stream=st))
    plan = plan_windows(imu, ValidationConfig())
    ref = reference_from_states(seq.ground_truth, imu.t_ns)
    win = held_out_windows(imu, plan, folds, ref)
    g = np.asarray(truth.gravity_mps2)
    true_bias = np.hstack([truth.bias_gyro_radps, truth.bias_acc_mps2])
    e_cv = held_out_errors(cv.imu, cv.bias, ref, plan, win, g)
    e_true = held_out_errors(imu, true_bias, ref, plan, win, g)
    e_zero = held_out_errors(imu, np.zeros_like(true_bias), ref, plan, win, g)
    assert e_cv.prmse_m <= 3.0 * e_true.prmse_m, (e_cv.prmse_m, e_true.prmse_m)
    assert e_cv.roe_deg <= 1.2 * e_true.roe_deg, (e_cv.roe_deg, e_true.roe_deg)
    assert e_cv.prmse_m < 0.15 * e_zero.prmse_m


def test_held_constant_is_the_fold_mean_over_its_training_samples(handheld):
    seq = handheld.sequence
    folds = BlockFolds(int(seq.imu.t_ns[0]), 5.0, 2)
    ramp = (seq.imu.t_ns - seq.imu.t_ns[0]) / S  # a bias that grows 1 per second, the same in every fold

    def fake_recover(s, stream):
        return SimpleNamespace(bias_at=lambda t: np.repeat(((t - seq.imu.t_ns[0]) / S)[:, None], 6, 1),
                               std_at=lambda t: np.ones((len(t), 6)), report={})

    cv = held_constant(crossvalidate_recovery(seq, "mocap0", folds, fake_recover), seq.imu, folds)
    f = folds.fold(seq.imu.t_ns)
    for k in range(2):
        np.testing.assert_allclose(cv.bias[f == k, 3], ramp[f != k].mean())


def test_validate_inputs_adds_the_held_out_source(handheld, tmp_path):
    """validation.crossval.blocks on: the recovery is cross-validated with its own options and compared as
    'recovered_heldout' on the same windows; against the true state (an independent reference) it is compared,
    not judged: worse than the in-sample recovered bias but far better than none."""
    from recovery.recover import write_recovery
    from validation.validate import validate_inputs

    seq = handheld.sequence
    rec_dir = write_recovery(recover(seq, pose_stream="mocap0"), tmp_path / "rec")
    config = ValidationConfig(crossval="on", crossval_block_s=5.0, crossval_folds=2)
    res = validate_inputs(seq, recovery_dir=rec_dir, config=config)
    held, rec, zero = (res.sources[n] for n in ("recovered_heldout", "recovered", "zero"))
    assert res.candidate == "recovered" and held.kind.value == "file"
    assert held.windows == rec.windows and res.heldout["judged"] is False and res.heldout["dropped_folds"] == []
    assert rec.prmse_m <= held.prmse_m < 0.15 * zero.prmse_m
    with pytest.raises(ValidationError, match="cross-validation needs the recovery"):
        validate_inputs(seq, bias_files=[(None, rec_dir / "bias.csv")], config=config)
