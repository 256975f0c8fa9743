"""Bias recovery on simulated data: its config, accuracy and honesty of the sigmas, outputs and CLI.

Short sequences and reduced keyframe rates keep this file fast; the full
acceptance runs (120 s, full rate) are in ``benchmarks/recovery/recovery.py``.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
import yaml

from pipeline.errors import ConfigError
from pipeline.sim.config import PoseFormat
from recovery.config import ExtrinsicMode, PoseFactorMode, RecoveryConfig, RobustLoss
from pipeline.bias_table import read_bias_csv
from pipeline.files.atomic import umask
from pipeline.bias_table import CSV_HEADER
from recovery.recover import write_recovery
from recovery.recover import recover
from recovery_sim import FAST, bias_errors, sim_sequence


# ----------------------------------------------------------------------------- config


def test_config_rejects_unknown_key_and_bad_enum():
    with pytest.raises(ConfigError, match="keyframe_rate"):
        RecoveryConfig.from_dict({"keyframe_rate": 10})
    with pytest.raises(ConfigError, match="robust_loss"):
        RecoveryConfig.from_dict({"robust_loss": "tukey"})
    with pytest.raises(ConfigError, match="segment_overlap_s"):
        RecoveryConfig(segment_s=10, segment_overlap_s=6)
    cfg = RecoveryConfig.from_dict({"robust_loss": "cauchy", "keyframe_rate_hz": 25})
    assert cfg.robust_loss is RobustLoss.CAUCHY
    again = RecoveryConfig.from_dict(cfg.to_dict())
    assert again == cfg
    assert json.loads(json.dumps(cfg.to_dict()))["robust_loss"] == "cauchy"


def test_command_line_assignments_become_config_fields():
    from pipeline.configs import assignments_to_mapping

    got = assignments_to_mapping(["random_walk_scales=[0.01, 0.1, 10]", "robust_loss=cauchy", "keyframe_rate_hz=25",
                                  "position_sigma_m=null"])
    assert got == {"random_walk_scales": [0.01, 0.1, 10], "robust_loss": "cauchy", "keyframe_rate_hz": 25,
                   "position_sigma_m": None}
    cfg = RecoveryConfig.from_dict(got)
    assert cfg.random_walk_scales == [0.01, 0.1, 10.0] and cfg.robust_loss is RobustLoss.CAUCHY
    # YAML 1.1 reads 1e-7 as text: a number on a command line; in a config file, an error saying how to write it
    assert assignments_to_mapping(["intrinsics_prior_g_sensitivity=1e-7", "random_walk_scales=[1e-2, 1]"]) == {
        "intrinsics_prior_g_sensitivity": 1e-7, "random_walk_scales": [0.01, 1]}
    with pytest.raises(ConfigError, match="write it with a point and a signed exponent, 1.0e-7"):
        RecoveryConfig.from_dict({"intrinsics_prior_g_sensitivity": "1e-7"})
    with pytest.raises(ConfigError, match="1.5e\\+3"):
        RecoveryConfig.from_dict({"outlier_threshold": "1.5e3"})
    assert yaml.safe_load("1.0e-7") == 1e-7 and yaml.safe_load("1.5e+3") == 1500.0  # the forms the hint writes
    with pytest.raises(ConfigError, match="'robust_loss' is not KEY=VALUE.*--set.*KEY=VALUE"):
        assignments_to_mapping(["robust_loss"])
    with pytest.raises(ConfigError, match="not YAML.*quote"):
        assignments_to_mapping(["random_walk_scales=[0.1, 1"])


def test_config_auto_rates_and_segments():
    cfg = RecoveryConfig()
    assert cfg.calibration_rate_hz("noise", fused=True) == 5.0 and cfg.calibration_rate_hz("noise", fused=False) == 10.0
    assert RecoveryConfig(noise_keyframe_rate_hz=7.0).calibration_rate_hz("noise", fused=True) == 7.0
    assert cfg.segment_plan(20.0) == (300.0, 50.0)  # 6000 keyframes, capped at 300 s
    assert cfg.segment_plan(100.0) == (60.0, 10.0)
    assert cfg.segment_plan(1000.0) == (30.0, 5.0)  # floor
    assert RecoveryConfig(segment_s=90.0, segment_overlap_s=20.0).segment_plan(20.0) == (90.0, 20.0)
    with pytest.raises(ConfigError, match="segment_overlap_s"):
        RecoveryConfig(segment_overlap_s=40.0).segment_plan(100.0)  # auto 60 s: 40 is too long
    with pytest.raises(ConfigError, match="segment_overlap_s"):
        RecoveryConfig(segment_s=60.0, segment_overlap_s=30.0)


def test_config_yaml(tmp_path):
    p = tmp_path / "rec.yaml"
    p.write_text("recovery:\n  extrinsic_mode: estimate\n  keyframe_rate_hz: 50\n")
    cfg = RecoveryConfig.from_yaml(p)
    assert cfg.extrinsic_mode is ExtrinsicMode.ESTIMATE and cfg.keyframe_rate_hz == 50
    p.write_text("recovery:\n  bogus: 1\n")
    with pytest.raises(ConfigError, match="bogus"):
        RecoveryConfig.from_yaml(p)


# ----------------------------------------------------------------------------- accuracy and honesty


@pytest.fixture(scope="module")
def clean_run():
    sim = sim_sequence(40.0, seed=1)
    res = recover(sim.sequence, config=RecoveryConfig(**FAST, time_offset_mode="fixed"))
    return sim, res


def test_clean_bias_accuracy_and_nees(clean_run):
    sim, res = clean_run
    eg, ea = bias_errors(res, sim.truth)
    assert (np.sqrt((eg**2).mean(0)) < 3e-4).all()
    assert (np.sqrt((ea**2).mean(0)) < 2e-2).all()
    nees = np.concatenate([(eg / res.bias_gyro_std_radps) ** 2, (ea / res.bias_acc_std_mps2) ** 2], 1).mean()
    assert 0.3 < nees < 3.0
    # the calibration's extrinsic (the simulator's truth) is the estimate's prior; the data agree with it
    ext = res.report["extrinsic"]
    assert ext["mode"] == "prior" and ext["source"] == "estimated"
    assert not ext["difference_from_calibration"]["exceeds"] and not res.warnings
    assert np.isfinite(res.bias_gyro_std_radps).all()


def test_accuracy_floor_is_reported_and_not_beaten(clean_run):
    """recovery.json states the optimal smoother's RMSE for the noise used; the recovery sits above it
    and, on a short clean run, within a small factor of it."""
    sim, res = clean_run
    floor = res.report["accuracy_floor"]
    # FAST fixes the noise at the simulator's truth: 10x EuRoC walks, 0.5 mm / 0.5 mrad at 100 Hz; the values
    # are recovery.noise.bounds' for that noise (regression values there, checked against an RTS smoother)
    assert floor["acc_mps2"] == pytest.approx(6.66e-3, rel=0.02)
    assert floor["gyro_radps"] == pytest.approx(1.304e-4, rel=0.02)
    eg, ea = bias_errors(res, sim.truth)
    rg, ra = np.sqrt((eg**2).mean(0)), np.sqrt((ea**2).mean(0))
    assert (rg > 0.6 * floor["gyro_radps"]).all() and (rg < 2.5 * floor["gyro_radps"]).all()  # 40 s: noisy RMSE
    assert (ra > 0.6 * floor["acc_mps2"]).all() and (ra < 2.5 * floor["acc_mps2"]).all()


def test_gravity_of_a_level_frame_and_as_a_variable_per_segment(clean_run):
    """The simulator's world is level: the estimated tilt lies within 3 sigma and the frame is kept level
    (solved with gravity -z). Asked to estimate it, gravity is a variable of the full-rate solve, so its
    uncertainty reaches the accelerometer-bias marginals; it stays close to its first estimate."""
    sim, res = clean_run
    grav = res.report["gravity"]
    assert grav["level_test"]["level"] and not grav["estimated"] and "per_segment" not in grav
    assert grav["level_test"]["tilt_deg"] < 3 * grav["level_test"]["tilt_std_deg"]
    assert res.report["gravity_world_mps2"] == [0.0, 0.0, -9.81]
    est = recover(sim.sequence, config=RecoveryConfig(**FAST, time_offset_mode="fixed", estimate_gravity=True))
    grav = est.report["gravity"]
    assert grav["estimated"] and grav["per_segment"] and "level_test" not in grav
    assert 0.0 <= grav["segment_max_tilt_change_rad"] < 5 * grav["tilt_std_rad"]


def test_a_tilted_mocap_frame_keeps_its_tilt():
    """The same motion seen from a world frame tilted by 2 deg about x: the tilt stands out of its sigma and
    is kept, within a few of its sigmas of the truth."""
    from scipy.spatial.transform import Rotation

    sim = sim_sequence(40.0, seed=1)
    tilt = Rotation.from_rotvec([np.radians(2.0), 0.0, 0.0])
    poses = {k: dataclasses.replace(v, p_m=tilt.apply(v.p_m), quat_wxyz=(tilt * Rotation.from_quat(
        v.quat_wxyz, scalar_first=True)).as_quat(scalar_first=True)) for k, v in sim.sequence.poses.items()}
    seq = dataclasses.replace(sim.sequence, poses=poses)
    res = recover(seq, config=RecoveryConfig(**FAST, time_offset_mode="fixed"))
    test = res.report["gravity"]["level_test"]
    assert not test["level"] and res.report["gravity"]["estimated"]
    g_true = tilt.apply([0.0, 0.0, -9.81])
    err_deg = np.degrees(np.arccos(np.dot(res.report["gravity_world_mps2"], g_true) / 9.81 ** 2))
    assert err_deg < 3 * test["tilt_std_deg"]


def test_acc_nees_honest_with_gravity_uncertainty():
    """Full-rate 60 s: the x/y accelerometer-bias std includes the gravity-direction uncertainty
    (held fixed, the per-axis NEES was ~2 on x/y)."""
    sim = sim_sequence(60.0, seed=0)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None}, time_offset_mode="fixed")
    res = recover(sim.sequence, config=cfg)
    _, ea = bias_errors(res, sim.truth)
    nees_axes = ((ea / res.bias_acc_std_mps2) ** 2).mean(axis=0)
    assert (nees_axes < 1.6).all(), nees_axes


def test_a_walk_at_either_bound_says_what_that_bound_means():
    """At the upper bound the bias may be absorbing pose artefacts; at the lower one the bias is steadier than
    the datasheet's walk (an upper limit), which is no reason to distrust it."""
    from pipeline.types import PoseSourceKind
    from recovery.noise.evidence import NoiseChoice
    from recovery.solver.preintegration import ImuNoise
    from recovery.recover import grid_edge_warnings

    cfg = RecoveryConfig(random_walk_scales=[0.3, 1.0, 300.0])
    choice = NoiseChoice(ImuNoise(gyro_noise_density=1e-4, acc_noise_density=1e-3, gyro_random_walk=1e-5,
                                  acc_random_walk=1e-4), 1e-3, 1e-3, gyro_rw_scale=0.3, acc_rw_scale=300.0)
    gyro, acc = grid_edge_warnings(choice, PoseSourceKind.MOCAP, cfg)
    assert gyro.startswith("gyro random walk: the evidence search hit its bound (0.3x") and "steadier" in gyro
    assert acc.startswith("acc random walk: the evidence search hit its bound (300x") and "artefacts" in acc
    assert "artefacts" not in gyro and "steadier" not in acc


def test_random_walk_bound_is_reported():
    """The evidence search stays inside random_walk_scales and says so when it hits a bound
    (the simulated random walk is 10x the calibration, above this 0.5x-3x range)."""
    sim = sim_sequence(20.0, seed=2)
    fast = {k: v for k, v in FAST.items() if k not in ("noise_estimation", "gyro_random_walk", "acc_random_walk")}
    cfg = RecoveryConfig(**fast, time_offset_mode="fixed", random_walk_scales=[0.5, 1.0, 3.0],
                         noise_keyframe_rate_hz=5.0)
    res = recover(sim.sequence, config=cfg)
    noise = res.report["noise"]
    assert noise["gyro_random_walk_scale"] <= 3.0 and noise["acc_random_walk_scale"] <= 3.0
    assert any("hit its bound" in w and "0.5x-3x" in w for w in res.warnings), res.warnings
    # the bracketing search evaluates fewer candidates than its coordinates' grids hold (two passes over
    # the densities, the correlated pose error's sigmas and times and the walks, after the pose sigma)
    per_pass = 2 * (len(cfg.noise_density_scales) + len(cfg.pose_error_sigma_scales) + len(cfg.pose_error_taus_s)
                    + len(cfg.random_walk_scales))
    assert len(noise["candidates"]) < len(cfg.pose_sigma_scales) + 2 * per_pass


# ----------------------------------------------------------------------------- other pose streams


def test_position_tracker_with_lever_arm():
    sim = sim_sequence(40.0, seed=5, format=PoseFormat.POSITION, rate_hz=20.0, extrinsic_known=True,
               extrinsic_translation_xyz_m=(0.07, -0.02, -0.12), position_noise_m=1e-3)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": 1e-3}, time_offset_mode="fixed")
    res = recover(sim.sequence, config=cfg)
    eg, ea = bias_errors(res, sim.truth)
    assert res.report["pose_source_kind"] == "position_tracker"
    assert (np.sqrt((eg**2).mean(0)) < 2e-3).all()
    assert (np.sqrt((ea**2).mean(0)) < 0.1).all()
    # the lever arm is estimated with the calibration's (the truth) as its prior: within its sigmas
    diff = res.report["extrinsic"]["difference_from_calibration"]
    assert np.allclose(res.report["T_imu_pose"]["p_m"], [0.07, -0.02, -0.12], atol=0.02)
    assert diff["translation_sigmas"] < 3.0 and not diff["exceeds"]


def test_vio_relative_factors():
    sim = sim_sequence(30.0, seed=6, format=PoseFormat.VIO, rate_hz=30.0, extrinsic_known=True)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": None, "rotation_sigma_rad": None},
                         time_offset_mode="fixed")
    res = recover(sim.sequence, config=cfg)
    assert res.report["pose_factor_mode"] == PoseFactorMode.RELATIVE.value
    eg, _ = bias_errors(res, sim.truth)
    assert (np.sqrt((eg**2).mean(0)) < 2e-3).all()


# ----------------------------------------------------------------------------- outputs


def test_write_recovery_files(clean_run, tmp_path):
    _, res = clean_run
    out = tmp_path / "rec"
    out.mkdir()
    (out / "bias_imu.parquet").write_text("another stage's output")
    (out / "bias.csv").write_text("old")
    write_recovery(res, out)
    assert (out / "bias_imu.parquet").read_text() == "another stage's output"  # only its own files replaced
    header = (out / "bias.csv").read_text().splitlines()[0]
    assert header == ",".join(CSV_HEADER)
    track = read_bias_csv(out / "bias.csv")
    assert track.t_ns.dtype == np.int64 and len(track) == len(res.t_ns)
    np.testing.assert_allclose(track.bias[:, 0], res.bias_gyro_radps[:, 0], rtol=1e-8)
    mode = (out / "bias.csv").stat().st_mode & 0o777
    assert mode == 0o666 & ~umask() and (out.stat().st_mode & 0o777) == 0o777 & ~umask()
    rep = json.loads((out / "recovery.json").read_text())
    for key in ("pose_time_offset_s", "T_imu_pose", "gravity_world_mps2", "noise", "residuals",
                "outliers_rejected", "keyframes", "duration_s", "runtime_s", "warnings",
                "extrinsic_rotation_observable", "pose_stream", "pose_source_kind"):
        assert key in rep
    assert set(rep["T_imu_pose"]) == {"p_m", "quat_wxyz"}
    res = pd.read_csv(out / "residuals.csv")
    assert list(res.columns) == ["t_ns", "pose_whitened_rms", "imu_whitened_rms", "outlier"]
    np.testing.assert_array_equal(res["t_ns"].to_numpy(), track.t_ns)
    # Whitened residuals of a consistent fit are O(1); every keyframe after the first has an IMU factor.
    assert np.isfinite(res["imu_whitened_rms"].to_numpy()[1:]).all()
    assert 0.2 < np.nanmedian(res["pose_whitened_rms"]) < 3.0 and 0.05 < np.nanmedian(res["imu_whitened_rms"]) < 3.0
    tum = (out / "trajectory_tum.txt").read_text().split("\n")
    assert len([ln for ln in tum if ln and not ln.startswith("#")]) == len(res.t_ns)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_write_failure_leaves_nothing(clean_run, tmp_path):
    _, res = clean_run
    broken = dataclasses.replace(res, bias_gyro_radps=res.bias_gyro_radps[:-1])  # wrong shape -> fails
    with pytest.raises(Exception):
        write_recovery(broken, tmp_path / "rec")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- CLI


def test_cli_recover_on_store(tmp_path, clean_run, capsys):
    from biasgt.cli.app import main
    from pipeline.store import write_store

    sim, _ = clean_run
    store = tmp_path / "store"
    write_store(sim.sequence, store)
    cfg = tmp_path / "rec.yaml"
    cfg.write_text("noise_estimation: fixed\ngyro_random_walk: 1.9393e-4\nacc_random_walk: 0.03\n"
                   "position_sigma_m: 0.0005\nrotation_sigma_rad: 0.0005\ngravity_keyframe_rate_hz: 5\n")
    out = tmp_path / "rec"
    rc = main(["recover", str(store), "--out", str(out), "--config", str(cfg), "--keyframe-rate", "10",
               "--no-estimate-time-offset"])
    assert rc == 0
    frame = pd.read_csv(out / "bias.csv")
    assert list(frame.columns) == list(CSV_HEADER)
    assert 350 <= len(frame) <= 410
    assert "wrote" in capsys.readouterr().out
    assert json.loads((out / "recovery.json").read_text())["pose_fusion"]["enabled"] is True
    rc = main(["recover", str(store), "--out", str(tmp_path / "rec_nf"), "--config", str(cfg), "--keyframe-rate", "10",
               "--no-estimate-time-offset", "--no-pose-fusion"])
    assert rc == 0
    rep = json.loads((tmp_path / "rec_nf" / "recovery.json").read_text())
    assert rep["pose_fusion"] == {"enabled": False} and rep["config"]["pose_fusion"] is False
    capsys.readouterr()
    bad = tmp_path / "bad.yaml"
    bad.write_text("keyframe_rate: 3\n")
    rc = main(["recover", str(store), "--out", str(tmp_path / "rec2"), "--config", str(bad)])
    assert rc == 2
    assert not (tmp_path / "rec2").exists()
    assert "keyframe_rate" in capsys.readouterr().err


def test_agreement_z_is_zero_for_identical_and_scales_with_sigma(clean_run):
    import dataclasses

    from recovery.recover import agreement_z

    _, res = clean_run
    z = agreement_z(res, res)
    assert z.shape == (len(res.t_ns), 6) and np.allclose(z, 0.0)
    shifted = dataclasses.replace(res, bias_gyro_radps=res.bias_gyro_radps + 3e-4)
    z = agreement_z(shifted, res)
    expected = 3e-4 / np.sqrt(2 * res.bias_gyro_std_radps**2)
    np.testing.assert_allclose(z[:, :3], expected, rtol=1e-9)
