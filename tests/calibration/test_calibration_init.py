"""Tests of recovery.calibration_init on simulated sequences (pipeline.sim), analytic
signals and the real EuRoC V1_01 IMU + ground-truth poses."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from pipeline.errors import DataError, RecoveryError
from pipeline.sim import MotionConfig, MotionPreset, PoseFormat, PoseStreamConfig, SimConfig, simulate
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind
from recovery.calibration_init import (
    GravityEstimate,
    LeverArmEstimate,
    RestTest,
    RotationEstimate,
    TimeOffsetEstimate,
    estimate_extrinsic_rotation,
    estimate_gravity,
    estimate_gravity_direction,
    estimate_lever_arm,
    estimate_time_offset,
    find_static_segments,
    pose_angular_rates,
)

T0_NS = 1_400_000_000_000_000_000


@functools.lru_cache(maxsize=None)
def _sim(offset_s: float = 0.012, seed: int = 3, fmt: PoseFormat = PoseFormat.MOCAP,
         preset: MotionPreset = MotionPreset.HANDHELD, rate_hz: float = 100.0):
    """60 s, IMU 200 Hz with EuRoC-like noise and drifting bias, poses with a 15 deg / 10 cm extrinsic."""
    cfg = SimConfig(
        duration_s=60.0, seed=seed, motion=MotionConfig(preset=preset),
        poses=PoseStreamConfig(format=fmt, rate_hz=rate_hz, clock_offset_s=offset_s,
                               extrinsic_rotation_deg=15.0, extrinsic_translation_m=0.10),
    )
    sim = simulate(cfg)
    (poses,) = sim.sequence.poses.values()
    return sim, sim.sequence.imu, poses


def _single_axis(duration_s: float = 60.0) -> tuple[ImuSeries, PoseSeries]:
    """Analytic yaw-only motion (rotation about one axis), IMU 200 Hz, poses 100 Hz."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, duration_s, 0.005)
    yaw = 0.8 * np.sin(2 * np.pi * 0.2 * t) + 0.3 * np.sin(2 * np.pi * 0.53 * t)
    rate = 0.8 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t) + 0.3 * 2 * np.pi * 0.53 * np.cos(2 * np.pi * 0.53 * t)
    gyro = np.zeros((len(t), 3))
    gyro[:, 2] = rate
    gyro += 0.01 + 2e-3 * rng.standard_normal(gyro.shape)
    p = np.stack([np.sin(0.3 * t), np.cos(0.4 * t), 0.1 * np.sin(t)], axis=1)
    acc = Rotation.from_euler("z", yaw[:, None]).inv().apply(
        np.stack([-0.09 * np.sin(0.3 * t), -0.16 * np.cos(0.4 * t), -0.1 * np.sin(t) + 9.81], axis=1)
    ) + 0.03 * rng.standard_normal((len(t), 3))
    imu = ImuSeries(T0_NS + np.round(t * NS_PER_S).astype(np.int64), gyro, acc)
    k = slice(0, None, 2)
    quat = Rotation.from_euler("z", yaw[k, None]).as_quat(scalar_first=True)
    poses = PoseSeries(imu.t_ns[k], p[k], quat, "marker", PoseSourceKind.MOCAP)
    return imu, poses


def _angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(R_a @ R_b.T).magnitude()))


# ----------------------------------------------------------------------------- rates


def test_pose_angular_rates_constant_rate_with_sign_flips() -> None:
    omega = np.array([0.3, -0.5, 1.2])
    t_ns = T0_NS + np.arange(500, dtype=np.int64) * 10_000_000
    t_s = (t_ns - T0_NS) / NS_PER_S
    quat = (Rotation.from_rotvec([0.1, 0.2, 0.3]) * Rotation.from_rotvec(t_s[:, None] * omega)).as_quat(
        scalar_first=True)
    quat[1::3] *= -1.0  # q and -q are the same rotation
    poses = PoseSeries(t_ns, np.zeros((500, 3)), quat, "body", PoseSourceKind.MOCAP)
    t_mid, w = pose_angular_rates(poses)
    assert t_mid.dtype == np.int64 and len(t_mid) == 499
    assert t_mid[0] == T0_NS + 5_000_000
    np.testing.assert_allclose(w, np.broadcast_to(omega, w.shape), atol=1e-9)
    _, w_s = pose_angular_rates(poses, smooth_s=0.05)
    np.testing.assert_allclose(w_s[10:-10], np.broadcast_to(omega, w_s[10:-10].shape), atol=1e-9)


def test_pose_angular_rates_needs_orientation() -> None:
    poses = PoseSeries(np.arange(10, dtype=np.int64), np.zeros((10, 3)), None, "prism",
                       PoseSourceKind.POSITION_TRACKER)
    with pytest.raises(DataError, match="prism.*no orientation"):
        pose_angular_rates(poses)


# ----------------------------------------------------------------------------- time offset


@pytest.mark.parametrize("offset_s", [0.0, 0.012, -0.137])
def test_time_offset_recovered_from_mocap(offset_s: float) -> None:
    sim, imu, poses = _sim(offset_s)
    assert sim.truth.clock_offset_s == pytest.approx(offset_s)
    est = estimate_time_offset(imu, poses)
    assert isinstance(est, TimeOffsetEstimate)
    assert est.method == "rotation"
    assert abs(est.offset_s - sim.truth.clock_offset_s) < 1e-3
    assert 0.0 < est.std_s < 1e-3
    assert est.correlation > 0.9


@pytest.mark.parametrize(("preset", "tol_s"), [(MotionPreset.AGGRESSIVE_DRONE, 2e-3), (MotionPreset.HANDHELD, 30e-3)])
def test_time_offset_position_only(preset: MotionPreset, tol_s: float) -> None:
    """Leica-like 20 Hz positions: the |f|^2 gravity fit gives a coarse offset with an honest std."""
    sim, imu, poses = _sim(-0.137, seed=4, fmt=PoseFormat.POSITION, preset=preset, rate_hz=20.0)
    assert not poses.has_orientation
    est = estimate_time_offset(imu, poses)
    err = abs(est.offset_s - sim.truth.clock_offset_s)
    assert est.method == "position"
    assert err < tol_s
    assert err < 3 * est.std_s + 1e-3


def test_time_offset_no_overlap_raises() -> None:
    _, imu, poses = _sim()
    shifted = replace(poses, t_ns=poses.t_ns + 1000 * NS_PER_S)
    with pytest.raises(RecoveryError, match=r"imu and poses \(frame .*overlap for only.*--time-offset-s"):
        estimate_time_offset(imu, shifted)


def test_time_offset_constant_orientation_raises() -> None:
    _, imu, poses = _sim()
    still = replace(poses, quat_wxyz=np.tile([1.0, 0.0, 0.0, 0.0], (len(poses), 1)))
    with pytest.raises(RecoveryError, match="does not rotate.*--time-offset-s"):
        estimate_time_offset(imu, still)


def test_time_offset_unrelated_streams_raise() -> None:
    _, imu, _ = _sim(seed=3)
    _, _, other = _sim(seed=5)
    with pytest.raises(RecoveryError, match=r"poses \(frame .*(correlate only|search boundary).*time-offset-s"):
        estimate_time_offset(imu, other)


def test_time_offset_peak_beyond_search_range_raises() -> None:
    sim, imu, poses = _sim(-0.137)
    with pytest.raises(RecoveryError, match="search boundary.*increase max_offset_s"):
        estimate_time_offset(imu, poses, max_offset_s=0.05)


def test_non_increasing_stamps_raise_data_error() -> None:
    _, imu, poses = _sim()
    t = poses.t_ns.copy()
    t[100] = t[99]
    with pytest.raises(DataError, match="not strictly increasing"):
        estimate_time_offset(imu, replace(poses, t_ns=t))


# ----------------------------------------------------------------------------- extrinsic rotation


def test_extrinsic_rotation_recovered() -> None:
    sim, imu, poses = _sim(0.012)
    off = estimate_time_offset(imu, poses).offset_s
    est = estimate_extrinsic_rotation(imu, poses, off)
    assert isinstance(est, RotationEstimate)
    R_true = sim.truth.poses.T_imu_frame[:3, :3]
    assert _angle_deg(R_true, np.eye(3)) == pytest.approx(15.0, abs=1e-6)
    assert _angle_deg(est.R_imu_pose, R_true) < 0.3
    assert est.observable and est.condition > 0.05
    # The jointly solved constant gyro bias matches the (slowly drifting) true bias.
    np.testing.assert_allclose(est.gyro_bias_radps, sim.truth.bias_gyro_radps.mean(axis=0), atol=1e-3)


def test_extrinsic_rotation_single_axis_unobservable() -> None:
    imu, poses = _single_axis()
    est = estimate_extrinsic_rotation(imu, poses, 0.0)
    assert not est.observable
    assert est.condition < 1e-3
    la = estimate_lever_arm(imu, poses, 0.0, np.eye(3))
    assert not la.observable


def test_extrinsic_rotation_position_only_raises() -> None:
    _, imu, poses = _sim(fmt=PoseFormat.POSITION, rate_hz=20.0)
    with pytest.raises(DataError, match="no orientation"):
        estimate_extrinsic_rotation(imu, poses, 0.0)


# ----------------------------------------------------------------------------- lever arm, gravity


def test_lever_arm_recovered() -> None:
    sim, imu, poses = _sim(0.012)
    off = estimate_time_offset(imu, poses).offset_s
    rot = estimate_extrinsic_rotation(imu, poses, off)
    est = estimate_lever_arm(imu, poses, off, rot.R_imu_pose)
    assert isinstance(est, LeverArmEstimate)
    r_true = sim.truth.poses.T_imu_frame[:3, 3]
    assert np.linalg.norm(r_true) == pytest.approx(0.10)
    assert np.linalg.norm(est.p_imu_pose_m - r_true) < 0.02
    assert est.observable and np.all(est.std_m < 0.03)
    # Bias knots follow the drifting true accelerometer bias.
    true_b = sim.truth.bias_acc_mps2[np.searchsorted(sim.truth.t_ns, est.acc_bias_t_ns).clip(0, len(imu) - 1)]
    assert np.median(np.abs(est.acc_bias_knots_mps2 - true_b)) < 0.05


def test_gravity_direction() -> None:
    sim, imu, poses = _sim(0.012)
    R = sim.truth.poses.T_imu_frame[:3, :3]
    g_true = sim.truth.gravity_mps2 / np.linalg.norm(sim.truth.gravity_mps2)
    est = estimate_gravity(imu, poses, 0.012, R)
    assert isinstance(est, GravityEstimate)
    assert np.degrees(np.arccos(np.clip(est.direction @ g_true, -1, 1))) < 0.2
    assert 0 < est.std_rad < np.radians(0.2)
    d = estimate_gravity_direction(imu, poses, 0.012, R)
    assert d.shape == (3,) and np.linalg.norm(d) == pytest.approx(1.0)
    np.testing.assert_allclose(d, est.direction)


# ----------------------------------------------------------------------------- static segments


def test_static_segments_two_known_intervals() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 40.0, 0.005)
    moving = ~(((t >= 8.0) & (t < 12.0)) | ((t >= 25.0) & (t < 31.5)))
    gyro = np.array([0.01, -0.02, 0.005]) + 3e-3 * rng.standard_normal((len(t), 3))
    acc = np.array([0.0, 0.0, 9.81]) + 0.03 * rng.standard_normal((len(t), 3))
    gyro[moving] += 0.6 * np.stack([np.sin(2.1 * t), np.cos(1.3 * t), np.sin(0.7 * t + 1)], 1)[moving]
    acc[moving] += 1.5 * np.stack([np.sin(3.0 * t), np.cos(2.2 * t), np.sin(1.7 * t)], 1)[moving]
    imu = ImuSeries(T0_NS + np.round(t * NS_PER_S).astype(np.int64), gyro, acc)
    segs = find_static_segments(imu, min_duration_s=1.0)
    assert len(segs) == 2
    (a0, a1), (b0, b1) = [((s - T0_NS) / NS_PER_S, (e - T0_NS) / NS_PER_S) for s, e in segs]
    assert all(isinstance(v, int) for seg in segs for v in seg)
    assert 8.0 <= a0 < 8.4 and 11.6 < a1 < 12.0
    assert 25.0 <= b0 < 25.4 and 31.1 < b1 < 31.5
    assert find_static_segments(imu, min_duration_s=5.0) == [segs[1]]


def test_static_segments_by_variation_ignore_the_bias_but_not_a_turn() -> None:
    """A unit at rest with a 0.08 rad/s turn-on gyro bias, then a slow turn about a tilted axis at a
    constant 0.2 rad/s (below the mean-rate cap, so only the accelerometer can show it), then a
    fast constant turn about gravity (0.5 rad/s: the cap), then rest again."""
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 40.0, 0.005)
    bias = np.array([0.05, -0.06, 0.02])  # |b| = 0.081 rad/s
    omega = np.zeros((len(t), 3))
    tilted = (t >= 10.0) & (t < 20.0)
    yaw = (t >= 20.0) & (t < 28.0)
    omega[tilted] = 0.2 * np.array([1.0, 0.0, 0.0])
    omega[yaw] = [0.0, 0.0, 0.5]
    angle = np.cumsum(np.where(tilted, 0.2, 0.0)) * 0.005  # roll angle about x, held after the turn
    g_body = 9.81 * np.stack([np.zeros_like(t), np.sin(angle), np.cos(angle)], 1)
    gyro = omega + bias + 2e-3 * rng.standard_normal((len(t), 3))
    acc = g_body + 0.03 * rng.standard_normal((len(t), 3))
    imu = ImuSeries(T0_NS + np.round(t * NS_PER_S).astype(np.int64), gyro, acc)
    assert find_static_segments(imu, min_duration_s=1.0) == []  # the bias alone fails the calibrated-IMU test
    segs = find_static_segments(imu, min_duration_s=1.0, test=RestTest.VARIATION)
    spans = [((s - T0_NS) / NS_PER_S, (e - T0_NS) / NS_PER_S) for s, e in segs]
    assert len(spans) == 2, spans
    assert spans[0][0] < 0.3 and 9.6 < spans[0][1] <= 10.0
    assert 28.0 <= spans[1][0] < 28.4 and spans[1][1] > 39.6


# ----------------------------------------------------------------------------- real data


@pytest.fixture(scope="module")
def euroc_v101(shared_data) -> tuple[ImuSeries, PoseSeries]:
    base = shared_data / "euroc" / "V1_01_easy"
    imu_df = pd.read_csv(base / "mav0" / "imu0" / "data.csv")
    imu = ImuSeries(imu_df.iloc[:, 0].to_numpy(np.int64), imu_df.iloc[:, 1:4].to_numpy(float),
                    imu_df.iloc[:, 4:7].to_numpy(float))
    # TUM text "t[s] x y z qx qy qz qw"; stamps are rounded to 10 us.
    gt = pd.read_csv(base / "ov_data" / "V1_01_easy_original.txt", sep=r"\s+", comment="#", header=None)
    t_ns = np.round(gt[0].to_numpy() * 1e5).astype(np.int64) * 10_000
    poses = PoseSeries(t_ns, gt[[1, 2, 3]].to_numpy(), gt[[7, 4, 5, 6]].to_numpy(), "imu",
                       PoseSourceKind.GROUND_TRUTH)
    return imu, poses


def test_euroc_v101_offset_and_rotation(euroc_v101) -> None:
    """EuRoC's ground truth is the IMU (body) frame on the IMU clock."""
    imu, poses = euroc_v101
    off = estimate_time_offset(imu, poses)
    assert abs(off.offset_s) < 5e-3
    assert off.correlation > 0.9
    rot = estimate_extrinsic_rotation(imu, poses, off.offset_s)
    assert _angle_deg(rot.R_imu_pose, np.eye(3)) < 1.0
    assert rot.observable
    la = estimate_lever_arm(imu, poses, off.offset_s, rot.R_imu_pose)
    assert np.linalg.norm(la.p_imu_pose_m) < 0.05
    g = estimate_gravity_direction(imu, poses, off.offset_s, rot.R_imu_pose)
    assert np.degrees(np.arccos(-g[2])) < 1.0  # EuRoC's world frame is gravity-aligned
