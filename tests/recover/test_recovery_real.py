"""Bias recovery on real EuRoC data (skips without the shared data folder).

Cheap versions of the acceptance checks in ``benchmarks/recovery/recovery.py``: shorter
spans and decimated keyframes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from pipeline.types import PoseSourceKind
from recovery.config import RecoveryConfig
from recovery.recover import agreement_z, recover


def _v101(shared_data, duration_s: float):
    from pipeline.io import load_sequence
    from pipeline.io.tum import read_tum_poses

    seq = load_sequence(shared_data / "euroc/V1_01_easy")
    poses, _ = read_tum_poses(shared_data / "euroc/V1_01_easy/ov_data/V1_01_easy_original.txt",
                              source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
    poses = poses.take(poses.t_ns < poses.t_ns[0] + int(duration_s * 1e9))
    seq.poses = {"euroc_gt": poses}
    return seq


def _static_start_check(shared_data):
    """benchmarks/recovery/v101_bias_consistency.static_start_check (the benchmarks folder is not a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "recovery" / "v101_bias_consistency.py"
    spec = importlib.util.spec_from_file_location("v101_bias_consistency", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.static_start_check(shared_data / "euroc")


def test_v101_gt_poses_vs_euroc_bias_first_5s(shared_data):
    """EuRoC GT poses (IMU frame, IMU clock), whole sequence, default settings: over the first 5 s
    the gyro bias and acc x/z agree with EuRoC's own estimate (targets: 2e-3 rad/s, 0.08 m/s^2).
    Acc y misses by ~0.002 because EuRoC's value (a sequence constant) contradicts its own static
    start by 0.06 m/s^2; the recovered bias agrees with what the static data say."""
    seq = _v101(shared_data, 1e6)
    res = recover(seq, pose_stream="euroc_gt")
    rep = res.report
    assert rep["pose_time_offset_method"] == "fixed" and rep["pose_time_offset_s"] == 0.0
    assert rep["extrinsic"]["source"] == "calibration"  # frame 'imu': identity
    fusion = rep["pose_fusion"]
    assert fusion["enabled"] and fusion["samples_per_keyframe_mean"] > 19.8  # 200-Hz GT into 10-Hz keyframes
    assert fusion["samples_rejected"] < 0.005 * fusion["samples_fused"]  # smooth GT: (almost) nothing rejected
    ref = pd.read_csv(shared_data / "euroc/V1_01_easy_proto_excerpt/mav0/state_groundtruth_estimate0/data.csv")
    ref = ref.to_numpy()
    t_ref = ref[:, 0].astype(np.int64)
    sel = (res.t_ns >= t_ref[0]) & (res.t_ns <= t_ref[-1])
    assert sel.sum() >= 45  # 10-Hz keyframes over the 5-s excerpt
    ours = np.hstack([res.bias_gyro_radps, res.bias_acc_mps2])[sel]
    theirs = np.stack([np.interp(res.t_ns[sel], t_ref, ref[:, c]) for c in range(11, 17)], 1)
    diff = np.abs((ours - theirs).mean(axis=0))
    assert (diff[:3] < 2e-3).all(), diff
    assert diff[3] < 0.08 and diff[5] < 0.08, diff
    # acc y: EuRoC's own static start (motors on, < 3 mm motion) says ~0.487, EuRoC's file 0.548
    check = _static_start_check(shared_data)
    assert check["gt_motion_m"] < 3e-3
    assert check["ba_euroc"][1] - check["ba_static_local"][1] > 0.05
    static = (res.t_ns >= int(check["t0_ns"]) + 300_000_000) & (res.t_ns < int(check["t0_ns"]) + 3_300_000_000)
    assert abs(res.bias_acc_mps2[static, 1].mean() - check["ba_static_local"][1]) < 0.03
    # the sigmas are finite and of a sane size
    assert np.isfinite(res.bias_gyro_std_radps).all() and (res.bias_gyro_std_radps < 5e-3).all()
    assert rep["residuals"]["pose_whitened_rms"] < 3.0


def test_v101_random_walk_bound_is_kept_and_reported(shared_data):
    """EuRoC GT poses have artefacts (jumps every 10 samples) that pull the evidence search to
    ~100x the datasheet gyro random walk; a bounded random_walk_scales keeps it at the bound and
    recovery.json says so."""
    seq = _v101(shared_data, 25.0)
    cfg = RecoveryConfig(keyframe_rate_hz=50.0, random_walk_scales=[0.5, 1.0, 3.0, 10.0, 30.0])
    res = recover(seq, pose_stream="euroc_gt", config=cfg)
    noise = res.report["noise"]
    assert noise["gyro_random_walk_scale"] <= 30.0 and noise["acc_random_walk_scale"] <= 30.0
    assert any(w.startswith("gyro random walk: the evidence search hit its bound") for w in res.warnings), res.warnings


@pytest.mark.slow
def test_mh01_leica_agrees_with_gt_recovery(shared_data):
    """Raw Leica positions (lever arm from sensor.yaml, clock offset estimated) vs the GT-pose recovery."""
    from pipeline.io import load_sequence
    from pipeline.io.tum import read_tum_poses

    seq = load_sequence(shared_data / "euroc/MH_01_easy")
    assert "leica0" in seq.poses
    ra = recover(seq, pose_stream="leica0", config=RecoveryConfig())
    assert ra.report["pose_source_kind"] == "position_tracker"
    # the lever arm is estimated with sensor.yaml's as its prior, and stays within centimetres of it
    assert ra.report["extrinsic"]["mode"] == "prior"
    assert ra.report["T_imu_pose"]["p_m"] == pytest.approx([0.0748903, -0.0184772, -0.120209], abs=0.02)
    gt, _ = read_tum_poses(shared_data / "euroc/MH_01_easy/ov_data/MH_01_easy.txt",
                           source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
    seq.poses["euroc_gt"] = gt
    rb = recover(seq, pose_stream="euroc_gt", config=RecoveryConfig(keyframe_rate_hz=20.0))
    # position-only: noise evidence and segments over the whole recording (position_only_window_s)
    assert ra.report["flags"]["noise_window_s"] > 150 and ra.report["segments"] == 1
    assert ra.report["noise"]["gyro_random_walk_scale"] > 2.0  # the 60-s window said ~0.7x
    frac = (agreement_z(ra, rb) < 3).mean(axis=0)
    # Acceptance target: >= 95% of keyframes within the combined 3 sigma, every axis
    assert (frac >= 0.95).all(), frac
    # the gyro bias itself agrees to ~1e-3 rad/s on average
    sel = (ra.t_ns >= rb.t_ns[0]) & (ra.t_ns <= rb.t_ns[-1])
    gyro_diff = np.abs(ra.bias_gyro_radps[sel] - rb.bias_at(ra.t_ns[sel])[:, :3])
    assert (gyro_diff.mean(axis=0) < 2e-3).all()


@pytest.mark.slow
def test_mh01_leica_agrees_with_gt_recovery_with_intrinsics_on(shared_data):
    """With the IMU intrinsics on, the Leica and GT-pose recoveries still agree within 3 sigma, in the readings'
    convention (the GT recovery's bias with the terms' posterior means put back; without them acc x agrees on 54 % of
    the keyframes: the fit's x scale, the gravity axis, 0.008 +- 0.003, narrows its prior to a mean of 0.0077, and
    0.0077 g leaves the bias). From the Leica positions nothing is estimated (position-only stream);
    before that rule the fit's 6.7 % accelerometer scale left gyro y at 0 % agreement."""
    from pipeline.io import load_sequence
    from pipeline.io.tum import read_tum_poses
    from recovery.config import IntrinsicsMode

    on = RecoveryConfig(intrinsics=IntrinsicsMode.WITH_G_SENSITIVITY)
    seq = load_sequence(shared_data / "euroc/MH_01_easy")
    ra = recover(seq, pose_stream="leica0", config=on)
    assert ra.report["intrinsics"]["method"] == "not estimated"
    gt, _ = read_tum_poses(shared_data / "euroc/MH_01_easy/ov_data/MH_01_easy.txt",
                           source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu")
    seq.poses["euroc_gt"] = gt
    rb = recover(seq, pose_stream="euroc_gt", config=on)  # the default keyframes, as the benchmark
    assert rb.report["intrinsics"]["rounds"] >= 1
    # the GT recovery's bias is in the raw readings' convention, the terms' posterior means taken out of it
    # (the accelerometer's x scale, its gravity axis, ~0.8 % here); the Leica recovery's bias still holds
    # them: compare the two in the readings' convention, the means times the 10-s block force put back
    left = np.array(rb.report["intrinsics"]["left_out_posterior_means"]["acc_scale_misalignment"])
    force = np.stack([np.interp(rb.t_ns, seq.imu.t_ns, seq.imu.acc_mps2[:, c]) for c in range(3)], axis=1)
    force -= rb.bias_acc_mps2
    block = ((rb.t_ns - rb.t_ns[0]) // 10_000_000_000).astype(int)
    counts = np.bincount(block)
    block_force = np.stack([np.bincount(block, force[:, c]) / counts for c in range(3)], axis=1)[block]
    readings_convention = dataclasses.replace(rb, bias_acc_mps2=rb.bias_acc_mps2 + block_force @ left.T)
    frac = (agreement_z(ra, readings_convention) < 3).mean(axis=0)
    assert (frac >= 0.99).all(), frac
