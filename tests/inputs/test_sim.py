"""Tests of the simulator (pipeline.sim) and ``biasgt simulate``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy.spatial.transform import Rotation

from pipeline.errors import ConfigError, InputFormatError
from pipeline.geometry.integration import integrate
from pipeline.sim import (
    ImuNoiseConfig,
    MotionConfig,
    MotionPreset,
    PoseFormat,
    PoseStreamConfig,
    SimConfig,
    TemperatureConfig,
    read_simulation_yaml,
    simulate,
    write_simulation,
)
from pipeline.sim.motion import read_ground_truth_file
from pipeline.sim.simulator import BiasSource, MotionSource
from pipeline.sim.writer import GT_HEADER, IMU_HEADER, MOCAP_HEADER, POSITION_HEADER
from pipeline.types import PoseSourceKind

NS = 1_000_000_000
V102_GT = "euroc/V1_02_medium/mav0/state_groundtruth_estimate0/data.csv"
MH02_POSES = "euroc/MH_02_easy/ov_data/MH_02_easy.txt"  # EuRoC ground-truth poses only (TUM text)


def _rot(quat_wxyz: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.asarray(quat_wxyz)[..., [1, 2, 3, 0]])


def _one_second_errors(sim, window: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """End position [m] and rotation [deg] errors of integrating (IMU - true bias) over all 1-s windows."""
    imu, gt = sim.sequence.imu, sim.sequence.ground_truth
    starts = np.arange(0, len(imu) - window, window)
    idx = starts[:, None] + np.arange(window + 1)[None, :]
    gyro = torch.from_numpy(imu.gyro_radps[idx] - gt.bias_gyro_radps[idx])
    acc = torch.from_numpy(imu.acc_mps2[idx] - gt.bias_acc_mps2[idx])
    dt = torch.from_numpy(np.diff(imu.t_ns[idx], axis=1) / NS)
    R0 = torch.from_numpy(_rot(gt.quat_wxyz[starts]).as_matrix())
    res = integrate(
        gyro, acc, dt, R0, torch.from_numpy(gt.v_mps[starts]), torch.from_numpy(gt.p_m[starts]),
        gravity_mps2=sim.truth.gravity_mps2,
    )
    end = starts + window
    pos_err = np.linalg.norm(res.p.numpy() - gt.p_m[end], axis=1)
    rot_err = np.rad2deg((_rot(gt.quat_wxyz[end]).inv() * Rotation.from_matrix(res.R.numpy())).magnitude())
    return pos_err, rot_err


# ---------------------------------------------------------------------------------------------- config


def test_config_round_trip_and_unknown_keys(tmp_path: Path) -> None:
    cfg = SimConfig(
        duration_s=12.5, seed=7, name="x",
        imu=ImuNoiseConfig(rate_hz=400.0, temperature=TemperatureConfig(enabled=False)),
        motion=MotionConfig(preset=MotionPreset.SLOW_CART, position_amplitude_m=(1.0, 2.0, 0.0)),
        poses=PoseStreamConfig(format=PoseFormat.VIO, extrinsic_rotvec_deg=(1.0, 2.0, 3.0), dropouts=2),
    )
    d = cfg.to_dict()
    assert d["motion"]["preset"] == "slow_cart" and d["poses"]["format"] == "vio"
    assert SimConfig.from_dict(d) == cfg
    assert SimConfig.from_dict(yaml.safe_load(yaml.safe_dump(d))) == cfg
    assert SimConfig.from_dict({}) == SimConfig()

    with pytest.raises(ConfigError, match="unknown key.*imu.rate"):
        SimConfig.from_dict({"imu": {"rate": 100}})
    with pytest.raises(ConfigError, match="unknown key.*durationn"):
        SimConfig.from_dict({"durationn": 3})
    with pytest.raises(ConfigError, match="unknown value 'walking'"):
        SimConfig.from_dict({"motion": {"preset": "walking"}})
    with pytest.raises(ConfigError, match="must be a number"):
        SimConfig.from_dict({"poses": {"rate_hz": "fast"}})
    with pytest.raises(ConfigError, match="duration_s must be > 0"):
        SimConfig.from_dict({"duration_s": 0})
    with pytest.raises(ConfigError, match="seed must be >= 0"):
        SimConfig.from_dict({"seed": -1})
    with pytest.raises(ConfigError, match="duration_s is required"):
        SimConfig.from_dict({"duration_s": None})

    path = tmp_path / "c.yaml"
    path.write_text("seed: 3\nposes:\n  formatt: mocap\n")
    with pytest.raises(ConfigError) as err:
        SimConfig.from_yaml(path)
    assert str(path) in str(err.value) and "poses.formatt" in str(err.value)


# ---------------------------------------------------------------------------------------------- physics


def test_angular_rate_is_body_frame_and_acc_is_specific_force() -> None:
    cfg = SimConfig(duration_s=6.0, seed=2, imu=ImuNoiseConfig(
        white_noise=False, bias_random_walk=False, turn_on_bias=False, temperature=TemperatureConfig(enabled=False)))
    sim = simulate(cfg)
    assert np.all(sim.truth.bias_gyro_radps == 0) and np.all(sim.truth.bias_acc_mps2 == 0)
    traj, imu = sim.trajectory, sim.sequence.imu
    t = (imu.t_ns[100:1100:50] - imu.t_ns[0]) / NS
    h = 1e-5
    # body rate: R^T dR/dt by central differences
    Rp, Rm, R = traj.rotation(t + h).as_matrix(), traj.rotation(t - h).as_matrix(), traj.rotation(t).as_matrix()
    W = np.einsum("nji,njk->nik", R, (Rp - Rm) / (2 * h))
    w_fd = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(imu.gyro_radps[100:1100:50], w_fd, atol=1e-6)
    # specific force: R^T (d2p/dt2 - g) by central differences of the position (small h: the
    # acceleration of a cubic spline has kinks at the waypoints)
    h = 2e-5
    a_fd = (traj.position(t + h) - 2 * traj.position(t) + traj.position(t - h)) / h**2
    f_fd = np.einsum("nji,nj->ni", R, a_fd - np.array([0.0, 0.0, -9.81]))
    np.testing.assert_allclose(imu.acc_mps2[100:1100:50], f_fd, atol=1e-4)
    # ground truth velocity is the derivative of the position
    v_fd = (traj.position(t + h) - traj.position(t - h)) / (2 * h)
    np.testing.assert_allclose(sim.sequence.ground_truth.v_mps[100:1100:50], v_fd, atol=1e-5)


@pytest.mark.parametrize("preset", [MotionPreset.HANDHELD, MotionPreset.SLOW_CART])
def test_noise_free_imu_minus_bias_integrates_to_the_true_trajectory(preset: MotionPreset) -> None:
    sim = simulate(SimConfig(duration_s=30.0, seed=11, motion=MotionConfig(preset=preset)).noise_free())
    assert np.ptp(sim.truth.bias_acc_mps2, axis=0).max() > 1e-3  # the bias is really there and varies
    pos_err, rot_err = _one_second_errors(sim)
    assert len(pos_err) == 30
    assert pos_err.max() < 1e-4, pos_err.max()
    assert rot_err.max() < 1e-3, rot_err.max()


def test_integration_without_bias_correction_drifts() -> None:
    """The consistency test is sensitive: ignoring the bias gives large errors."""
    sim = simulate(SimConfig(duration_s=5.0, seed=11).noise_free())
    zero = dataclasses.replace(
        sim.sequence.ground_truth,
        bias_gyro_radps=np.zeros_like(sim.truth.bias_gyro_radps),
        bias_acc_mps2=np.zeros_like(sim.truth.bias_acc_mps2),
    )
    unbiased = dataclasses.replace(sim, sequence=dataclasses.replace(sim.sequence, ground_truth=zero))
    pos_err, _ = _one_second_errors(unbiased)
    assert pos_err.max() > 1e-2


# ---------------------------------------------------------------------------------------------- IMU model


def test_imu_noise_and_bias_statistics() -> None:
    base = SimConfig(duration_s=600.0, seed=5, imu=ImuNoiseConfig(temperature=TemperatureConfig(enabled=False)))
    noisy, clean = simulate(base), simulate(base.noise_free())
    # independent random streams: switching the white noise off keeps motion and bias
    np.testing.assert_array_equal(noisy.truth.bias_gyro_radps, clean.truth.bias_gyro_radps)
    np.testing.assert_array_equal(noisy.sequence.ground_truth.p_m, clean.sequence.ground_truth.p_m)
    cfg = base.imu
    sg = (noisy.sequence.imu.gyro_radps - clean.sequence.imu.gyro_radps).std(axis=0)
    sa = (noisy.sequence.imu.acc_mps2 - clean.sequence.imu.acc_mps2).std(axis=0)
    np.testing.assert_allclose(sg, cfg.gyro_noise_density * np.sqrt(cfg.rate_hz), rtol=0.05)
    np.testing.assert_allclose(sa, cfg.acc_noise_density * np.sqrt(cfg.rate_hz), rtol=0.05)
    # random walk increments: sigma * sqrt(dt); the first sample is the turn-on bias
    dt = 1.0 / cfg.rate_hz
    np.testing.assert_allclose(np.diff(noisy.truth.bias_gyro_radps, axis=0).std(axis=0),
                               cfg.gyro_random_walk * np.sqrt(dt), rtol=0.05)
    np.testing.assert_allclose(np.diff(noisy.truth.bias_acc_mps2, axis=0).std(axis=0),
                               cfg.acc_random_walk * np.sqrt(dt), rtol=0.05)
    np.testing.assert_array_equal(noisy.truth.bias_gyro_radps[0], noisy.truth.bias.turn_on_gyro_radps)
    # reported (datasheet) values differ from the true random walk
    assert noisy.sequence.calibration.gyro_random_walk == pytest.approx(cfg.gyro_random_walk / 10)


def test_temperature_term_and_sensor_matrices() -> None:
    imu = ImuNoiseConfig(white_noise=False, bias_random_walk=False, turn_on_bias=False,
                         temperature=TemperatureConfig(warmup_delta_degc=10.0, warmup_tau_s=10.0, sensor_tau_s=5.0,
                                                       oscillation_amp_degc=0.0),
                         gyro_scale_sigma=0.01, acc_misalignment_sigma=0.005, gyro_g_sensitivity_sigma=1e-4)
    sim = simulate(SimConfig(duration_s=120.0, seed=3, imu=imu))
    tr = sim.truth
    temp = sim.sequence.imu.temperature_degc
    assert temp[0] == pytest.approx(25.0) and temp[-1] == pytest.approx(35.0, abs=0.01)
    # after the lag has settled the bias is coefficient * temperature rise
    np.testing.assert_allclose(tr.bias_gyro_radps[-1], tr.bias.temp_coeff_gyro * 10.0, rtol=1e-3)
    np.testing.assert_allclose(tr.bias_acc_mps2[-1], tr.bias.temp_coeff_acc * 10.0, rtol=1e-3)
    np.testing.assert_allclose(tr.bias_gyro_radps[0], 0.0, atol=1e-12)
    M = tr.matrices
    assert not np.allclose(M.gyro_matrix, np.eye(3)) and np.allclose(M.gyro_matrix, np.diag(np.diag(M.gyro_matrix)))
    assert not np.allclose(M.acc_matrix, np.eye(3)) and np.allclose(np.diag(M.acc_matrix), 1.0)
    # the measurement model holds exactly
    t = (sim.sequence.imu.t_ns - sim.sequence.imu.t_ns[0]) / NS
    ms = sim.trajectory.sample(t)
    f = ms.specific_force(tr.gravity_mps2)
    expect = ms.omega_body_radps @ M.gyro_matrix.T + f @ M.gyro_g_sensitivity.T + tr.bias_gyro_radps
    np.testing.assert_allclose(sim.sequence.imu.gyro_radps, expect, atol=1e-12)
    np.testing.assert_allclose(sim.sequence.imu.acc_mps2, f @ M.acc_matrix.T + tr.bias_acc_mps2, atol=1e-12)


def test_one_imu_unit_in_every_sequence_and_a_temperature_reference() -> None:
    """Fixed coefficients and a reference temperature: the term is coeff * (T - reference) once settled."""
    coeff_g, coeff_a = (1e-4, -2e-4, 3e-4), (2e-3, -1e-3, 4e-3)
    temperature = TemperatureConfig(ambient_degc=18.0, warmup_delta_degc=6.0, warmup_tau_s=5.0, sensor_tau_s=2.0,
                                    oscillation_amp_degc=0.0, reference_degc=25.0,
                                    gyro_coeff_radps_per_degc=coeff_g, acc_coeff_mps2_per_degc=coeff_a)
    imu = ImuNoiseConfig(white_noise=False, bias_random_walk=False, turn_on_bias=False, temperature=temperature)
    for seed in (1, 2):
        sim = simulate(SimConfig(duration_s=60.0, seed=seed, imu=imu))
        tr = sim.truth
        np.testing.assert_array_equal(tr.bias.temp_coeff_gyro, coeff_g)
        temp = sim.sequence.imu.temperature_degc
        assert temp[0] == pytest.approx(18.0) and temp[-1] == pytest.approx(24.0, abs=1e-3)
        # starts at coeff * (18 - 25), ends (lag settled) at coeff * (24 - 25)
        np.testing.assert_allclose(tr.bias_gyro_radps[0], np.multiply(coeff_g, -7.0), rtol=1e-9)
        np.testing.assert_allclose(tr.bias_acc_mps2[-1], np.multiply(coeff_a, -1.0), rtol=1e-3)
    assert SimConfig.from_dict(SimConfig(imu=imu).to_dict()).imu.temperature == temperature



def test_one_imu_unit_repeats_its_turn_on_bias_with_a_small_spread() -> None:
    """The unit's turn-on mean in every run, plus each run's draw of the (small) sigmas: the runs' biases
    scatter about the mean by the sigmas, and without the mean about zero by the same draws."""
    mean_g, mean_a = (0.012, -0.008, 0.015), (0.08, -0.05, 0.12)
    quiet = dict(white_noise=False, bias_random_walk=False, temperature=TemperatureConfig(enabled=False),
                 gyro_turn_on_sigma=1e-3, acc_turn_on_sigma=1e-2)
    unit = ImuNoiseConfig(gyro_turn_on_mean_radps=mean_g, acc_turn_on_mean_mps2=mean_a, **quiet)
    bare = ImuNoiseConfig(**quiet)
    gyro = []
    for seed in range(8):
        a = simulate(SimConfig(duration_s=2.0, seed=seed, imu=unit)).truth
        b = simulate(SimConfig(duration_s=2.0, seed=seed, imu=bare)).truth
        np.testing.assert_allclose(a.bias_gyro_radps[0] - b.bias_gyro_radps[0], mean_g, atol=1e-12)
        np.testing.assert_allclose(a.bias_acc_mps2[0] - b.bias_acc_mps2[0], mean_a, atol=1e-12)
        gyro.append(a.bias_gyro_radps[0])
    assert np.abs(np.array(gyro) - mean_g).max() < 5e-3  # within 5 sigmas of the unit's mean
    assert SimConfig.from_dict(SimConfig(imu=unit).to_dict()).imu == unit


# ---------------------------------------------------------------------------------------------- poses


def test_pose_noise_statistics_match_the_config() -> None:
    cfg = SimConfig(duration_s=120.0, seed=9, poses=PoseStreamConfig(position_noise_m=2e-3, rotation_noise_rad=1e-3))
    sim = simulate(cfg)
    poses, pt = sim.sequence.poses["mocap0"], sim.truth.poses
    assert poses.source_kind is PoseSourceKind.MOCAP and poses.frame == "mocap_marker"
    np.testing.assert_allclose((poses.p_m - pt.p_true_m).std(axis=0), 2e-3, rtol=0.1)
    rotvec = (_rot(pt.quat_true_wxyz).inv() * _rot(poses.quat_wxyz)).as_rotvec()
    np.testing.assert_allclose(rotvec.std(axis=0), 1e-3, rtol=0.1)
    assert poses.rate_hz == pytest.approx(100.0)
    # own stamp grid, not aligned with the IMU's
    assert not np.isin(poses.t_ns, sim.sequence.imu.t_ns).all()


def test_dropouts_and_outliers() -> None:
    cfg = SimConfig(duration_s=60.0, seed=4, poses=PoseStreamConfig(dropouts=3, dropout_max_s=0.4, outliers=5))
    sim = simulate(cfg)
    poses, pt = sim.sequence.poses["mocap0"], sim.truth.poses
    gaps = np.diff(poses.t_ns)
    assert np.count_nonzero(gaps > 1.5 * NS / 100) == 3
    assert len(pt.dropout_intervals_ns) == 3
    for start, end in pt.dropout_intervals_ns:
        assert not np.any((poses.t_ns >= start) & (poses.t_ns < end))
        assert 0.2 * NS - 1 <= end - start <= 0.4 * NS + 1
    displacement = np.linalg.norm(poses.p_m - pt.p_true_m, axis=1)
    out = displacement > 0.05
    assert np.count_nonzero(out) == 5
    np.testing.assert_array_equal(poses.t_ns[out], pt.outlier_stamps_ns)
    np.testing.assert_allclose(displacement[out], 0.1, atol=5e-3)
    with pytest.raises(ConfigError, match="do not fit"):
        simulate(SimConfig(duration_s=5.0, poses=PoseStreamConfig(dropouts=10, dropout_max_s=1.0)))


def test_clock_offset_and_extrinsic_are_applied() -> None:
    poses_cfg = PoseStreamConfig(clock_offset_s=0.0237, extrinsic_rotation_deg=12.0, extrinsic_translation_m=0.15,
                                 position_noise_m=0.0, rotation_noise_rad=0.0)
    sim = simulate(SimConfig(duration_s=10.0, seed=6, poses=poses_cfg))
    poses, tr = sim.sequence.poses["mocap0"], sim.truth
    T = tr.T_imu_frame
    assert np.rad2deg(Rotation.from_matrix(T[:3, :3]).magnitude()) == pytest.approx(12.0)
    assert np.linalg.norm(T[:3, 3]) == pytest.approx(0.15)
    t0 = sim.sequence.imu.t_ns[0]
    t_imu = (poses.t_ns + tr.poses.clock_offset_ns - t0) / NS  # pose stamp + offset = IMU-clock time
    R = sim.trajectory.rotation(t_imu)
    expected_p = sim.trajectory.position(t_imu) + R.apply(T[:3, 3])
    np.testing.assert_allclose(poses.p_m, expected_p, atol=1e-9)
    expected_R = R * Rotation.from_matrix(T[:3, :3])
    assert (expected_R.inv() * _rot(poses.quat_wxyz)).magnitude().max() < 1e-9
    # the wrong sign of the offset does not fit
    t_wrong = (poses.t_ns - tr.poses.clock_offset_ns - t0) / NS
    t_wrong = t_wrong[t_wrong >= sim.trajectory.t_min_s]
    assert np.abs(sim.trajectory.position(t_wrong) - expected_p[-len(t_wrong):]).max() > 1e-3
    # with noise (default 0.5 mm): residual std matches
    noisy = simulate(SimConfig(duration_s=10.0, seed=6, poses=dataclasses.replace(
        poses_cfg, position_noise_m=0.5e-3)))
    np.testing.assert_allclose((noisy.sequence.poses["mocap0"].p_m - expected_p).std(), 0.5e-3, rtol=0.1)


def test_position_only_and_vio_streams() -> None:
    pos = simulate(SimConfig(duration_s=10.0, seed=1, poses=PoseStreamConfig(format=PoseFormat.POSITION, rate_hz=20)))
    leica = pos.sequence.poses["leica0"]
    assert leica.quat_wxyz is None and leica.source_kind is PoseSourceKind.POSITION_TRACKER
    assert leica.rate_hz == pytest.approx(20.0)
    vio_cfg = PoseStreamConfig(format=PoseFormat.VIO, vio_position_drift_m_per_sqrt_s=0.02,
                               vio_yaw_drift_rad_per_sqrt_s=0.01)
    vio = simulate(SimConfig(duration_s=100.0, seed=1, poses=vio_cfg))
    s, pt = vio.sequence.poses["vio"], vio.truth.poses
    assert s.source_kind is PoseSourceKind.VIO and s.world_frame == "vio_world"
    assert not np.any(np.einsum("ij,ij->i", s.quat_wxyz[1:], s.quat_wxyz[:-1]) < 0)  # continuous signs
    drift = np.linalg.norm(pt.vio_drift_p_m[-1])
    assert 0.01 < drift < 1.0
    np.testing.assert_allclose(np.diff(pt.vio_drift_yaw_rad).std(), 0.01 * np.sqrt(1 / 100), rtol=0.1)


# ---------------------------------------------------------------------------------------------- files


def test_write_is_deterministic_and_readable(tmp_path: Path) -> None:
    cfg = SimConfig(duration_s=8.0, seed=21, poses=PoseStreamConfig(
        clock_offset_s=-0.004, extrinsic_rotation_deg=5, extrinsic_translation_m=0.05, extrinsic_known=True,
        dropouts=1, outliers=2))
    a = write_simulation(simulate(cfg), tmp_path / "a")
    b = write_simulation(simulate(cfg), tmp_path / "b")
    c = write_simulation(simulate(dataclasses.replace(cfg, seed=22)), tmp_path / "c")
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert [str(f) for f in files] == [
        "mav0/imu0/data.csv", "mav0/imu0/sensor.yaml", "mav0/mocap0/data.csv", "mav0/mocap0/sensor.yaml",
        "mav0/state_groundtruth_estimate0/data.csv", "mav0/state_groundtruth_estimate0/sensor.yaml",
        "simulation.yaml",
    ]
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert (a / "mav0/imu0/data.csv").read_bytes() != (c / "mav0/imu0/data.csv").read_bytes()

    lines = (a / "mav0/imu0/data.csv").read_text().splitlines()
    assert lines[0] == f"{IMU_HEADER},temperature [degC]" and lines[1].startswith("1400000000123456789,")
    assert (a / "mav0/mocap0/data.csv").read_text().splitlines()[0] == MOCAP_HEADER
    assert (a / "mav0/state_groundtruth_estimate0/data.csv").read_text().splitlines()[0] == GT_HEADER

    meta = read_simulation_yaml(a)
    sim = simulate(cfg)
    assert meta["seed"] == 21 and SimConfig.from_dict(meta["config"]) == cfg
    assert meta["truth"]["pose_time_offset_s"] == -0.004
    np.testing.assert_array_equal(np.array(meta["truth"]["T_imu_mocap_marker"]), sim.truth.T_imu_frame)
    assert meta["truth"]["gravity_mps2"] == [0.0, 0.0, -9.81]
    assert len(meta["truth"]["dropout_intervals_ns"]) == 1 and len(meta["truth"]["outlier_stamps_ns"]) == 2

    from pipeline.io.asl import read_asl

    seq = read_asl(a)
    ref = sim.sequence
    np.testing.assert_array_equal(seq.imu.t_ns, ref.imu.t_ns)
    np.testing.assert_array_equal(seq.imu.gyro_radps, ref.imu.gyro_radps)
    np.testing.assert_array_equal(seq.imu.acc_mps2, ref.imu.acc_mps2)
    np.testing.assert_array_equal(seq.imu.temperature_degc, ref.imu.temperature_degc)  # lossless, 8th column
    for name in ("t_ns", "p_m", "quat_wxyz", "v_mps", "bias_gyro_radps", "bias_acc_mps2"):
        np.testing.assert_array_equal(getattr(seq.ground_truth, name), getattr(ref.ground_truth, name))
    mocap = seq.poses["mocap0"]
    np.testing.assert_array_equal(mocap.t_ns, ref.poses["mocap0"].t_ns)
    np.testing.assert_array_equal(mocap.p_m, ref.poses["mocap0"].p_m)
    np.testing.assert_array_equal(mocap.quat_wxyz, ref.poses["mocap0"].quat_wxyz)
    assert mocap.frame == "mocap_marker"
    np.testing.assert_allclose(seq.calibration.T_imu_frames["mocap_marker"], sim.truth.T_imu_frame, atol=1e-15)
    assert seq.calibration.gyro_random_walk == pytest.approx(1.9393e-5)
    assert seq.calibration.rate_hz == 200.0

    # extrinsic not known: no T_BS
    d = write_simulation(simulate(SimConfig(duration_s=3.0, seed=1)), tmp_path / "d")
    assert "T_BS" not in (d / "mav0/mocap0/sensor.yaml").read_text()
    assert read_asl(d).calibration.T_imu_frames == {}


def test_write_position_and_vio_formats(tmp_path: Path) -> None:
    from pipeline.io.asl import read_asl
    from pipeline.io.tum import read_tum

    cfg = SimConfig(duration_s=5.0, seed=2, poses=PoseStreamConfig(
        format=PoseFormat.POSITION, extrinsic_translation_m=0.1, extrinsic_rotation_deg=20, extrinsic_known=True))
    sim = simulate(cfg)
    out = write_simulation(sim, tmp_path / "leica")
    assert (out / "mav0/leica0/data.csv").read_text().splitlines()[0] == POSITION_HEADER
    seq = read_asl(out)
    np.testing.assert_array_equal(seq.poses["leica0"].p_m, sim.sequence.poses["leica0"].p_m)
    assert seq.poses["leica0"].quat_wxyz is None
    T = seq.calibration.T_imu_frames["leica_prism"]
    np.testing.assert_allclose(T[:3, 3], sim.truth.T_imu_frame[:3, 3], atol=1e-15)
    np.testing.assert_array_equal(T[:3, :3], np.eye(3))  # a prism has only a lever arm
    with pytest.raises(ConfigError, match="position-only"):
        write_simulation(sim, tmp_path / "bad", pose_format=PoseFormat.MOCAP)
    assert not (tmp_path / "bad").exists()  # nothing half-written

    vio = simulate(dataclasses.replace(cfg, poses=PoseStreamConfig(format=PoseFormat.VIO)))
    out = write_simulation(vio, tmp_path / "vio")
    assert not (out / "mav0/mocap0").exists()
    tum = read_tum(out / "vio_tum.txt")
    (stream,) = tum.poses.values()
    np.testing.assert_array_equal(stream.t_ns, vio.sequence.poses["vio"].t_ns)
    np.testing.assert_allclose(stream.p_m, vio.sequence.poses["vio"].p_m, atol=0)


def test_write_bag(tmp_path: Path) -> None:
    from pipeline.io.rosbag.reader import read_bag

    sim = simulate(SimConfig(duration_s=2.0, seed=3))
    out = write_simulation(sim, tmp_path / "s", bag="ros1")
    seq = read_bag(out / "sim.bag")
    np.testing.assert_array_equal(seq.imu.t_ns, sim.sequence.imu.t_ns)
    np.testing.assert_allclose(seq.imu.gyro_radps, sim.sequence.imu.gyro_radps, atol=0)


# ---------------------------------------------------------------------------------------------- semi-real


def _trajectory_errors(sim, reference) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and rotation (deg) errors of the simulated motion at a file's stamps inside the record."""
    imu_t = sim.sequence.imu.t_ns
    inside = (reference.t_ns >= imu_t[0]) & (reference.t_ns <= imu_t[-1])
    t_s = (reference.t_ns[inside] - imu_t[0]) / NS
    p_err = np.linalg.norm(sim.trajectory.position(t_s) - reference.p_m[inside], axis=1)
    r_err = np.rad2deg((sim.trajectory.rotation(t_s).inv() * _rot(reference.quat_wxyz[inside])).magnitude())
    return p_err, r_err


def test_semi_real_mode_reproduces_the_ground_truth_file(shared_data: Path) -> None:
    path = shared_data / V102_GT
    cfg = SimConfig(duration_s=30.0, seed=0, motion=MotionConfig(ground_truth_path=str(path))).noise_free()
    sim = simulate(cfg)
    gt_file = read_ground_truth_file(path)
    imu_t = sim.sequence.imu.t_ns
    assert imu_t[0] == gt_file.t_ns[0] + 500_000_000 and sim.config.duration_s == 30.0
    # bias: at IMU stamps that coincide (within 1 us) with file stamps, it is the file's bias
    j = np.searchsorted(gt_file.t_ns, imu_t).clip(1, len(gt_file.t_ns) - 1)
    j = np.where(np.abs(gt_file.t_ns[j - 1] - imu_t) < np.abs(gt_file.t_ns[j] - imu_t), j - 1, j)
    near = np.abs(gt_file.t_ns[j] - imu_t) < 1000
    assert near.mean() > 0.95
    np.testing.assert_allclose(sim.truth.bias_gyro_radps[near], gt_file.bias_gyro_radps[j[near]], atol=1e-9)
    np.testing.assert_allclose(sim.truth.bias_acc_mps2[near], gt_file.bias_acc_mps2[j[near]], atol=1e-9)
    # trajectory: within a few mm of the file's positions, a small fraction of a degree in rotation
    p_err, r_err = _trajectory_errors(sim, gt_file)
    assert p_err.max() < 3e-3 and np.sqrt(np.mean(p_err**2)) < 5e-4
    assert np.percentile(r_err, 95) < 0.1
    # the simulated IMU is consistent with the fitted motion. V1_02's real angular accelerations
    # make the 200-Hz midpoint integration error (O(h^2)) larger than for the random presets;
    # at 1 kHz it is 25x smaller and within the tight bounds.
    pos_err, rot_err = _one_second_errors(sim)
    assert pos_err.max() < 1e-3 and rot_err.max() < 1e-2 and np.median(pos_err) < 1e-4
    fast = simulate(dataclasses.replace(cfg, imu=dataclasses.replace(cfg.imu, rate_hz=1000.0)))
    pos_err, rot_err = _one_second_errors(fast, window=1000)
    assert pos_err.max() < 1e-4 and rot_err.max() < 1e-3
    # the derived IMU is smooth: 2nd differences far below the real sensor's white noise
    assert np.diff(sim.sequence.imu.acc_mps2, 2, axis=0).std() < 0.02
    # the whole file when duration_s is None
    whole = simulate(dataclasses.replace(cfg, duration_s=None))
    assert whole.config.duration_s == pytest.approx((gt_file.t_ns[-1] - gt_file.t_ns[0]) / NS - 1.0, abs=0.01)


def test_semi_real_from_poses_only_draws_the_bias_from_the_imu_model(shared_data: Path, tmp_path: Path) -> None:
    """A TUM pose file gives the motion; the bias is the IMU model's, labelled as simulated."""
    from pipeline.io.tum import read_tum_poses

    path = shared_data / MH02_POSES
    cfg = SimConfig(duration_s=20.0, seed=4, motion=MotionConfig(ground_truth_path=str(path)))
    sim = simulate(cfg)
    poses, _ = read_tum_poses(path)  # the file, read independently of the simulator's reader
    p_err, r_err = _trajectory_errors(sim, poses)
    assert p_err.max() < 5e-3 and np.sqrt(np.mean(p_err**2)) < 1e-3
    assert np.percentile(r_err, 95) < 0.1
    # the bias does not depend on where the motion came from: the same seed's random-motion
    # simulation of the same length draws the same bias (the IMU model's turn-on + random walk)
    random_motion = simulate(dataclasses.replace(cfg, motion=MotionConfig()))
    assert len(random_motion.truth.t_ns) == len(sim.truth.t_ns)
    np.testing.assert_array_equal(sim.truth.bias_gyro_radps, random_motion.truth.bias_gyro_radps)
    np.testing.assert_array_equal(sim.truth.bias_acc_mps2, random_motion.truth.bias_acc_mps2)
    assert np.ptp(sim.truth.bias_acc_mps2, axis=0).min() > 0  # a walk, not a constant
    assert (sim.truth.motion_source, sim.truth.bias_source) == (MotionSource.GROUND_TRUTH_POSES, BiasSource.SIMULATED)
    truth = yaml.safe_load((write_simulation(sim, tmp_path / "s") / "simulation.yaml").read_text())["truth"]
    assert (truth["motion_source"], truth["bias_source"]) == ("ground_truth_poses", "simulated")


def test_ground_truth_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        simulate(SimConfig(motion=MotionConfig(ground_truth_path=str(tmp_path / "missing.csv"))))
    bad = tmp_path / "bad.csv"
    bad.write_text("#timestamp,x,y\n" + "".join(f"{i},1,2\n" for i in range(20)))
    with pytest.raises(InputFormatError, match="not a"):
        simulate(SimConfig(motion=MotionConfig(ground_truth_path=str(bad))))


# ---------------------------------------------------------------------------------------------- CLI


def test_cli_simulate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from biasgt.cli.app import main

    out = tmp_path / "cli"
    rc = main(["simulate", str(out), "--duration", "4", "--seed", "3", "--preset", "slow_cart",
               "--pose-format", "mocap", "--pose-rate", "50", "--clock-offset-ms", "12.5",
               "--extrinsic-deg", "3", "--extrinsic-m", "0.02", "--dropouts", "1", "--outliers", "2", "--noise-free"])
    assert rc == 0
    assert capsys.readouterr().out.strip() == str(out)
    meta = read_simulation_yaml(out)
    c = meta["config"]
    assert c["duration_s"] == 4.0 and c["seed"] == 3 and c["motion"]["preset"] == "slow_cart"
    assert c["poses"]["rate_hz"] == 50.0 and c["poses"]["position_noise_m"] == 0.0
    assert c["imu"]["white_noise"] is False
    assert meta["truth"]["pose_time_offset_s"] == pytest.approx(0.0125)
    assert meta["truth"]["pose_time_offset_ns"] == 12_500_000

    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("seed: 5\nimu: {rate_hz: 100.0}\nposes: {format: position}\n")
    rc = main(["simulate", str(tmp_path / "cli2"), "--config", str(cfg_file), "--duration", "2", "--seed", "6"])
    assert rc == 0
    meta = read_simulation_yaml(tmp_path / "cli2")
    assert meta["seed"] == 6 and meta["config"]["imu"]["rate_hz"] == 100.0
    assert (tmp_path / "cli2/mav0/leica0/data.csv").is_file()

    cfg_file.write_text("imu: {noise: 1}\n")
    assert main(["simulate", str(tmp_path / "cli3"), "--config", str(cfg_file)]) == 2
    assert "unknown key 'imu.noise'" in capsys.readouterr().err
    assert not (tmp_path / "cli3").exists()
