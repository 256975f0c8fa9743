"""Bias recovery on simulated data: accuracy, honesty of the sigmas, bad input, outputs.

Short sequences and reduced keyframe rates keep this file fast; the full
acceptance runs (120 s, full rate) are in ``benchmarks/recovery.py``.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import ConfigError, RecoveryError
from pipeline.sim import simulate
from pipeline.sim.config import PoseFormat, PoseStreamConfig, SimConfig
from pipeline.types import ImuSeries, PoseSeries, PoseSourceKind, Sequence
from recovery.config import ExtrinsicMode, PoseFactorMode, RecoveryConfig, RobustLoss
from pipeline.bias_table import read_bias_csv
from pipeline.atomic import _umask
from pipeline.bias_table import CSV_HEADER
from recovery.recover import write_recovery
from recovery.preintegration import midpoint_samples
from recovery.recover import recover
from recovery.segments import plan_segments

# Fast settings: noise fixed to the simulator's truth, decimated keyframes.
FAST = dict(keyframe_rate_hz=20.0, noise_estimation="fixed", gyro_random_walk=10 * 1.9393e-5,
            acc_random_walk=10 * 3.0e-3, position_sigma_m=0.5e-3, rotation_sigma_rad=0.5e-3,
            offset_refine_keyframe_rate_hz=10.0, extrinsic_keyframe_rate_hz=10.0, gravity_keyframe_rate_hz=5.0)


def _sim(duration_s: float = 30.0, seed: int = 0, **poses) -> object:
    poses.setdefault("extrinsic_known", True)
    return simulate(SimConfig(duration_s=duration_s, seed=seed, poses=PoseStreamConfig(**poses)))


def _errors(res, truth) -> tuple[np.ndarray, np.ndarray]:
    tb = np.stack([np.interp(res.t_ns, truth.t_ns, truth.bias_gyro_radps[:, c]) for c in range(3)], 1)
    ta = np.stack([np.interp(res.t_ns, truth.t_ns, truth.bias_acc_mps2[:, c]) for c in range(3)], 1)
    return res.bias_gyro_radps - tb, res.bias_acc_mps2 - ta


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


# ----------------------------------------------------------------------------- preintegration


def test_midpoint_samples_integrate_linear_signal_exactly():
    t_imu = np.arange(0, 1_000_000_001, 5_000_000, dtype=np.int64)  # 200 Hz
    sig = np.stack([np.linspace(0, 1, len(t_imu))] * 6, 1) * np.arange(1, 7)
    kf = np.array([12_345_678, 333_333_333, 500_000_000, 987_654_321], dtype=np.int64)
    s = midpoint_samples(t_imu, sig, kf)
    assert len(s.start) == len(kf) and s.start[-1] == len(s.dt_s)
    for i in range(len(kf) - 1):
        a, b = s.start[i], s.start[i + 1]
        assert s.dt_s[a:b].sum() == pytest.approx((kf[i + 1] - kf[i]) / 1e9, abs=1e-12)
        # exact integral of the gyro channel (linear in t): mean value * span
        t0, t1 = kf[i] / 1e9, kf[i + 1] / 1e9
        exact = 0.5 * (t0 + t1) * (t1 - t0)  # integral of t dt; channel 0 == t (span 1 s -> 0..1)
        got = float((s.gyro_radps[a:b, 0] * s.dt_s[a:b]).sum())
        assert got == pytest.approx(exact, rel=1e-9)


def test_noise_free_recovery_has_no_integration_bias():
    """Midpoint + half-step rotation: a noise-free run with constant bias recovers it almost exactly.

    GTSAM's plain left-rectangle rule would leave ~1e-3..1e-2 of motion-dependent error here.
    """
    from pipeline.sim.config import ImuNoiseConfig, TemperatureConfig

    imu = ImuNoiseConfig(bias_random_walk=False, temperature=TemperatureConfig(enabled=False))
    sim = simulate(SimConfig(duration_s=20.0, seed=3, imu=imu, poses=PoseStreamConfig(extrinsic_known=True)).noise_free())
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": 1e-4, "rotation_sigma_rad": 1e-4,
                            "gyro_random_walk": 1.9393e-5, "acc_random_walk": 3e-3, "estimate_gravity": False,
                            "time_offset_mode": "fixed", "compute_marginals": False})
    res = recover(sim.sequence, config=cfg)
    eg, ea = _errors(res, sim.truth)
    core = slice(len(eg) // 10, -len(eg) // 10)
    assert np.sqrt((eg[core] ** 2).mean()) < 2e-5
    assert np.sqrt((ea[core] ** 2).mean()) < 2e-3


# ----------------------------------------------------------------------------- accuracy and honesty


@pytest.fixture(scope="module")
def clean_run():
    sim = _sim(40.0, seed=1)
    res = recover(sim.sequence, config=RecoveryConfig(**FAST, time_offset_mode="fixed"))
    return sim, res


def test_clean_bias_accuracy_and_nees(clean_run):
    sim, res = clean_run
    eg, ea = _errors(res, sim.truth)
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
    # are recovery.bounds' for that noise (regression values there, checked against an RTS smoother)
    assert floor["acc_mps2"] == pytest.approx(6.66e-3, rel=0.02)
    assert floor["gyro_radps"] == pytest.approx(1.304e-4, rel=0.02)
    eg, ea = _errors(res, sim.truth)
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

    sim = _sim(40.0, seed=1)
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
    sim = _sim(60.0, seed=0)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None}, time_offset_mode="fixed")
    res = recover(sim.sequence, config=cfg)
    _, ea = _errors(res, sim.truth)
    nees_axes = ((ea / res.bias_acc_std_mps2) ** 2).mean(axis=0)
    assert (nees_axes < 1.6).all(), nees_axes


def test_a_walk_at_either_bound_says_what_that_bound_means():
    """At the upper bound the bias may be absorbing pose artefacts; at the lower one the bias is steadier than
    the datasheet's walk (an upper limit), which is no reason to distrust it."""
    from pipeline.types import PoseSourceKind
    from recovery.noise import NoiseChoice
    from recovery.preintegration import ImuNoise
    from recovery.recover import _grid_edge_warnings

    cfg = RecoveryConfig(random_walk_scales=[0.3, 1.0, 300.0])
    choice = NoiseChoice(ImuNoise(1e-4, 1e-3, 1e-5, 1e-4), 1e-3, 1e-3, gyro_rw_scale=0.3, acc_rw_scale=300.0)
    gyro, acc = _grid_edge_warnings(choice, PoseSourceKind.MOCAP, cfg)
    assert gyro.startswith("gyro random walk: the evidence search hit its bound (0.3x") and "steadier" in gyro
    assert acc.startswith("acc random walk: the evidence search hit its bound (300x") and "artefacts" in acc
    assert "artefacts" not in gyro and "steadier" not in acc


def test_random_walk_bound_is_reported():
    """The evidence search stays inside random_walk_scales and says so when it hits a bound
    (the simulated random walk is 10x the calibration, above this 0.5x-3x range)."""
    sim = _sim(20.0, seed=2)
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


def test_numpy_replacements_match_scipy():
    """The numpy versions that keep scipy.signal / scipy.integrate off the recovery path."""
    from scipy import signal
    from scipy.integrate import cumulative_trapezoid

    from recovery.calibration_init.common import _correlate_valid, _cumtrapz
    from recovery.initial import _savgol

    rng = np.random.default_rng(0)
    a, v = rng.normal(size=500), rng.normal(size=380)
    np.testing.assert_allclose(_correlate_valid(a, v), signal.correlate(a, v, mode="valid", method="fft"),
                               atol=1e-9)
    x, y = np.sort(rng.uniform(size=40)), rng.normal(size=(40, 3, 3))
    np.testing.assert_allclose(_cumtrapz(y, x), cumulative_trapezoid(y, x, axis=0, initial=0), atol=1e-12)
    for K, win in ((100, 31), (7, 7), (8, 7), (50, 5)):
        p = rng.normal(size=(K, 3)).cumsum(0)
        for deriv in (1, 2):
            np.testing.assert_allclose(_savgol(p, win, 0.01, deriv),
                                       signal.savgol_filter(p, win, 2, deriv=deriv, delta=0.01, axis=0),
                                       rtol=1e-9, atol=1e-8 * 100.0**deriv)


def test_bias_values_pool_round_trip():
    """Bias initial values built from the cached zero pool carry the requested values, any K."""
    from gtsam.symbol_shorthand import B

    from recovery.factors import _bias_values

    rng = np.random.default_rng(3)
    for K in (5, 12, 7):
        b = rng.normal(size=(K, 6))
        vals = _bias_values(b, K)
        assert vals.size() == K
        for k in (0, K - 1):
            cb = vals.atConstantBias(B(k))
            np.testing.assert_allclose(np.r_[cb.gyroscope(), cb.accelerometer()], b[k], atol=1e-12)
    assert _bias_values(np.zeros(6), 4).size() == 4


def test_coarse_offset_uses_the_most_rotating_span_of_long_recordings():
    from recovery.recover import COARSE_OFFSET_SPAN_S, _coarse_offset_inputs

    t_s = np.arange(0.0, 2000.0, 0.05)
    gyro = np.zeros((len(t_s), 3))
    gyro[(t_s > 1200) & (t_s < 1500), 2] = 1.0  # the motion is here
    imu = ImuSeries((t_s * 1e9).astype(np.int64), gyro, np.tile([0, 0, 9.81], (len(t_s), 1)))
    tp = (t_s[::2] * 1e9).astype(np.int64)
    poses = PoseSeries(tp, np.zeros((len(tp), 3)), np.tile([1.0, 0, 0, 0], (len(tp), 1)), "m", PoseSourceKind.MOCAP)
    pieces = [(int(imu.t_ns[0]), int(imu.t_ns[-1]))]
    imu_c, poses_c = _coarse_offset_inputs(imu, poses, pieces, 0.5)
    span = (poses_c.t_ns[-1] - poses_c.t_ns[0]) / 1e9
    assert COARSE_OFFSET_SPAN_S - 1 <= span <= COARSE_OFFSET_SPAN_S
    assert poses_c.t_ns[0] <= 1200e9 and poses_c.t_ns[-1] >= 1500e9
    # the IMU reaches past the poses by more than the largest offset searched
    assert imu_c.t_ns[0] <= poses_c.t_ns[0] - 1.5e9 and imu_c.t_ns[-1] >= poses_c.t_ns[-1] + 1.4e9
    short = imu.take(slice(0, 4000))
    assert _coarse_offset_inputs(short, poses, pieces, 0.5)[0] is short


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
    assert mode == 0o666 & ~_umask() and (out.stat().st_mode & 0o777) == 0o777 & ~_umask()
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


@pytest.mark.slow
def test_hard_offset_extrinsic_outliers_dropouts():
    sim = _sim(40.0, seed=2, extrinsic_known=False, extrinsic_rotation_deg=15.0, extrinsic_translation_m=0.10,
               clock_offset_s=0.012, dropouts=2, dropout_max_s=1.5, outliers=8, outlier_offset_m=0.1)
    res = recover(sim.sequence, config=RecoveryConfig(**FAST))
    rep = res.report
    assert abs(rep["pose_time_offset_s"] - 0.012) < 1e-3
    T_true = sim.truth.T_imu_frame
    from scipy.spatial.transform import Rotation

    q = rep["T_imu_pose"]["quat_wxyz"]
    ang = (Rotation.from_quat([q[1], q[2], q[3], q[0]]).inv() * Rotation.from_matrix(T_true[:3, :3])).magnitude()
    assert np.degrees(ang) < 0.5
    # 40 s only: the lever arm is good to ~4 mm (1 sigma) here; the 1-cm target is checked on 120 s by the benchmark
    lever_err = np.array(rep["T_imu_pose"]["p_m"]) - T_true[:3, 3]
    assert np.linalg.norm(lever_err) < 0.02
    assert (np.abs(lever_err) < 4 * np.array(rep["extrinsic"]["translation_std_m"])).all()
    # fused keyframes (default) use every sample: each injected outlier is found inside its bin
    n_out = len(sim.truth.poses.outlier_stamps_ns)
    assert n_out == 8
    assert rep["pose_fusion"]["enabled"] and rep["pose_fusion"]["samples_rejected"] >= n_out
    assert n_out <= rep["outliers_rejected"] <= n_out + 2
    eg, ea = _errors(res, sim.truth)
    assert (np.sqrt((eg**2).mean(0)) < 4e-4).all()
    assert rep["extrinsic_rotation_observable"] is True


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_newton_clock_offset_equals_the_cost_parabola(seed, monkeypatch):
    """The Newton refinement (analytic slope and curvature of the cost in the offset) lands where
    the parabola through three re-solved costs puts the vertex (within 0.1 sigma, same curvature sigma to 3 %),
    from a coarse value ~0.1 ms off, in one solve; both near the truth."""
    from recovery import offset as ro

    sim = _sim(40.0, seed=seed, clock_offset_s=0.012, dropouts=1, outliers=4, outlier_offset_m=0.1)
    cfg = RecoveryConfig(**FAST, intrinsics="off")
    newton = recover(sim.sequence, config=cfg).report
    monkeypatch.setattr(ro, "_newton_offset", lambda *a, **k: None)
    parabola = recover(sim.sequence, config=cfg).report
    assert newton["pose_time_offset_method"].endswith("+graph_cost_newton")
    assert parabola["pose_time_offset_method"].endswith("+graph_cost_parabola")
    assert len(newton["pose_time_offset_search"]) == 1 and len(parabola["pose_time_offset_search"]) >= 3
    std = parabola["pose_time_offset_curvature_std_s"]
    assert abs(newton["pose_time_offset_s"] - parabola["pose_time_offset_s"]) < 0.1 * std
    assert newton["pose_time_offset_curvature_std_s"] == pytest.approx(std, rel=0.03)
    assert abs(newton["pose_time_offset_s"] - 0.012) < 4 * std


def test_position_only_clock_offset_uses_the_cost_parabola():
    """No 6-DoF pose factors, no analytic slope: the offset comes from the parabola."""
    sim = _sim(40.0, seed=5, format=PoseFormat.POSITION, rate_hz=20.0, extrinsic_known=True,
               extrinsic_translation_xyz_m=(0.07, -0.02, -0.12), position_noise_m=1e-3, clock_offset_s=0.005)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": 1e-3}, intrinsics="off")
    rep = recover(sim.sequence, config=cfg).report
    assert rep["pose_time_offset_method"].endswith("+graph_cost_parabola")
    assert abs(rep["pose_time_offset_s"] - 0.005) < 4 * rep["pose_time_offset_std_s"]


def test_outliers_do_not_move_the_bias():
    sim_clean = _sim(30.0, seed=4)
    sim_bad = _sim(30.0, seed=4, outliers=15, outlier_offset_m=0.1)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None}, time_offset_mode="fixed", compute_marginals=False)
    a = recover(sim_clean.sequence, config=cfg)
    b = recover(sim_bad.sequence, config=cfg)
    assert a.report["outliers_rejected"] == 0
    assert 15 <= b.report["outliers_rejected"] <= 17
    common, ia, ib = np.intersect1d(a.t_ns, b.t_ns, return_indices=True)
    assert len(common) > 0.9 * len(a.t_ns)
    assert np.abs(a.bias_gyro_radps[ia] - b.bias_gyro_radps[ib]).max() < 2e-4
    assert np.abs(a.bias_acc_mps2[ia] - b.bias_acc_mps2[ib]).max() < 1e-2


def test_position_tracker_with_lever_arm():
    sim = _sim(40.0, seed=5, format=PoseFormat.POSITION, rate_hz=20.0, extrinsic_known=True,
               extrinsic_translation_xyz_m=(0.07, -0.02, -0.12), position_noise_m=1e-3)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": 1e-3}, time_offset_mode="fixed")
    res = recover(sim.sequence, config=cfg)
    eg, ea = _errors(res, sim.truth)
    assert res.report["pose_source_kind"] == "position_tracker"
    assert (np.sqrt((eg**2).mean(0)) < 2e-3).all()
    assert (np.sqrt((ea**2).mean(0)) < 0.1).all()
    # the lever arm is estimated with the calibration's (the truth) as its prior: within its sigmas
    diff = res.report["extrinsic"]["difference_from_calibration"]
    assert np.allclose(res.report["T_imu_pose"]["p_m"], [0.07, -0.02, -0.12], atol=0.02)
    assert diff["translation_sigmas"] < 3.0 and not diff["exceeds"]


def test_vio_relative_factors():
    sim = _sim(30.0, seed=6, format=PoseFormat.VIO, rate_hz=30.0, extrinsic_known=True)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": None, "rotation_sigma_rad": None},
                         time_offset_mode="fixed")
    res = recover(sim.sequence, config=cfg)
    assert res.report["pose_factor_mode"] == PoseFactorMode.RELATIVE.value
    eg, _ = _errors(res, sim.truth)
    assert (np.sqrt((eg**2).mean(0)) < 2e-3).all()


# ----------------------------------------------------------------------------- segments


def test_plan_segments_cover_with_overlap():
    s = plan_segments(0, int(200e9), 60.0, 10.0)
    assert s[0][0] == 0 and s[-1][1] == int(200e9)
    for (a0, b0), (a1, b1) in zip(s[:-1], s[1:]):
        assert b0 - a1 >= int(10e9) - 1 and a1 > a0
    assert plan_segments(0, int(80e9), 60.0, 10.0) == [(0, int(80e9))]


def test_segment_seams_within_sigma():
    sim = _sim(50.0, seed=7)
    cfg = RecoveryConfig(**FAST, time_offset_mode="fixed", segment_s=20.0, segment_overlap_s=6.0)
    res = recover(sim.sequence, config=cfg)
    seams = res.report["segment_seams"]
    assert len(seams) >= 2
    assert max(s["max_abs_diff_over_sigma"] for s in seams) < 1.0
    # no step in the stitched output either: neighbour differences are small vs sigma
    step = np.abs(np.diff(res.bias_gyro_radps, axis=0)) / res.bias_gyro_std_radps[1:]
    assert step.max() < 1.0
    assert (np.diff(res.t_ns) > 0).all()


# ----------------------------------------------------------------------------- bad input


def _tiny_sequence(imu_t_s, pose_t_s, quat=None) -> Sequence:
    imu_t = (np.asarray(imu_t_s) * 1e9).astype(np.int64) + 10**18
    pose_t = (np.asarray(pose_t_s) * 1e9).astype(np.int64) + 10**18
    n = len(imu_t)
    imu = ImuSeries(imu_t, np.zeros((n, 3)), np.tile([0, 0, 9.81], (n, 1)))
    q = np.tile([1.0, 0, 0, 0], (len(pose_t), 1)) if quat is None else quat
    poses = PoseSeries(pose_t, np.zeros((len(pose_t), 3)), q, "marker", PoseSourceKind.MOCAP)
    return Sequence("tiny", imu=imu, poses={"mocap0": poses})


def test_no_overlap_is_a_recovery_error():
    seq = _tiny_sequence(np.arange(0, 10, 0.005), np.arange(100, 110, 0.01))
    with pytest.raises(RecoveryError, match="overlap"):
        recover(seq, config=RecoveryConfig(time_offset_mode="fixed"))


def test_too_few_poses():
    seq = _tiny_sequence(np.arange(0, 10, 0.005), np.arange(1, 1.1, 0.01))
    with pytest.raises(RecoveryError, match="min_poses"):
        recover(seq, config=RecoveryConfig(time_offset_mode="fixed"))


def test_missing_stream_and_missing_imu():
    seq = _tiny_sequence(np.arange(0, 10, 0.005), np.arange(1, 9, 0.01))
    with pytest.raises(Exception, match="nope"):
        recover(seq, pose_stream="nope")
    seq.imu = None
    with pytest.raises(RecoveryError, match="IMU"):
        recover(seq)


def test_imu_gap_refuse_and_split():
    sim = _sim(30.0, seed=8)
    seq = sim.sequence
    t = seq.imu.t_ns
    keep = (t < t[0] + int(12e9)) | (t > t[0] + int(13e9))
    seq_gap = dataclasses.replace(seq, imu=seq.imu.take(keep))
    with pytest.raises(RecoveryError, match="gap"):
        recover(seq_gap, config=RecoveryConfig(**FAST, time_offset_mode="fixed", imu_gap_policy="refuse"))
    res = recover(seq_gap, config=RecoveryConfig(**FAST, time_offset_mode="fixed", compute_marginals=False))
    assert res.report["imu_pieces"] == 2
    assert any("gap" in w for w in res.warnings)
    inside = (res.t_ns > t[0] + int(12e9)) & (res.t_ns < t[0] + int(13e9))
    assert not inside.any()


def test_no_rotation_excitation_flags_extrinsic_unobservable():
    """Translation-only motion: the extrinsic rotation cannot be estimated -> warn and fall back."""
    sim = _sim(25.0, seed=9, extrinsic_known=False)
    seq = sim.sequence
    ps = seq.poses["mocap0"]
    # the same positions with a constant orientation: IMU gyro = bias + noise only, f = a - g + bias
    t_s = (ps.t_ns - ps.t_ns[0]) / 1e9
    acc_w = np.stack([np.gradient(np.gradient(ps.p_m[:, c], t_s), t_s) for c in range(3)], 1)
    imu_t = seq.imu.t_ns
    tt = (imu_t - ps.t_ns[0]) / 1e9
    acc_i = np.stack([np.interp(tt, t_s, acc_w[:, c]) for c in range(3)], 1) + [0, 0, 9.81]
    rng = np.random.default_rng(0)
    gyro = 0.01 + rng.normal(0, 2e-3, (len(imu_t), 3))
    acc = acc_i + [0.1, -0.1, 0.05] + rng.normal(0, 2e-2, acc_i.shape)
    flat = PoseSeries(ps.t_ns, ps.p_m, np.tile([1.0, 0, 0, 0], (len(ps), 1)), ps.frame, ps.source_kind)
    seq2 = Sequence("flat", imu=ImuSeries(imu_t, gyro, acc), poses={"mocap0": flat})
    res = recover(seq2, config=RecoveryConfig(**FAST, time_offset_mode="fixed", extrinsic_mode="estimate",
                                               compute_marginals=False))
    assert res.report["extrinsic_rotation_observable"] is False
    assert any("unobservable" in w for w in res.warnings)
    assert res.report["T_imu_pose"]["quat_wxyz"] == [1.0, 0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------- CLI


def test_cli_recover_on_store(tmp_path, clean_run, capsys):
    from pipeline.cli.app import main
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


def test_degenerate_problem_is_a_recovery_error(monkeypatch):
    """GTSAM's bare RuntimeError for an indeterminant system becomes a one-line RecoveryError."""
    import recovery.recover as rr
    from pipeline.errors import RecoveryError
    from pipeline.types import Sequence

    def boom(*a, **k):
        raise RuntimeError("\nIndeterminant linear system detected while working near variable\n"
                           "8070450532247928832 (Symbol: p0).\n")

    monkeypatch.setattr(rr, "_recover", boom)
    with pytest.raises(RecoveryError, match=r"degenerate \(Indeterminant linear system detected") as info:
        rr.recover(Sequence(name="flat"))
    assert "\n" not in str(info.value) and "--extrinsic known" in str(info.value)
    assert "--keyframe-rate" not in str(info.value)  # no odometry stream to thin out
    monkeypatch.setattr(rr, "_recover", lambda *a, **k: (_ for _ in ()).throw(RuntimeError("other bug")))
    with pytest.raises(RuntimeError, match="other bug"):
        rr.recover(Sequence(name="x"))


@pytest.mark.parametrize(("rate_hz", "changes", "expected", "absent"), [
    (50.0, {}, ["--keyframe-rate 10", "--extrinsic known", "--time-offset-s"], []),
    (10.0, {}, ["--extrinsic known", "--time-offset-s"], ["--keyframe-rate"]),  # 10-Hz odometry: already 10 Hz
    (10.0, {"extrinsic_mode": "known", "time_offset_mode": "fixed"}, ["varied motion", "motion capture"],
     ["--keyframe-rate", "--extrinsic known", "--time-offset-s"]),
])
def test_degenerate_hint_suggests_only_fixes_that_apply(rate_hz, changes, expected, absent) -> None:
    from pipeline.types import PoseSeries, PoseSourceKind, Sequence
    from recovery.config import RecoveryConfig
    from recovery.recover import degenerate_hint

    n = 50
    t_ns = 1_000_000_000 + np.arange(n, dtype=np.int64) * int(1e9 / rate_hz)
    odom = PoseSeries(t_ns, np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), "base_link", PoseSourceKind.VIO)
    hint = degenerate_hint(Sequence(name="odom", poses={"/odom": odom}), None, RecoveryConfig(**changes))
    for text in expected:
        assert text in hint, hint
    for text in absent:
        assert text not in hint, hint


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


def test_robust_threshold_has_the_one_dimensional_tail_in_every_dimension():
    """A clean factor of any dimension is down-weighted as often as a 1-D one beyond k sigmas."""
    import math

    import gtsam

    from recovery.factors import _robust, robust_norm_threshold

    k = 3.0
    p = math.erfc(k / math.sqrt(2.0))  # P(|z| > 3) = 0.0027
    assert robust_norm_threshold(k, 1) == k
    # 2-D: the norm is Rayleigh, P(|r| > t) = exp(-t^2 / 2)
    assert math.isclose(robust_norm_threshold(k, 2), math.sqrt(-2.0 * math.log(p)), rel_tol=1e-9)
    rng = np.random.default_rng(0)
    for d in (3, 6):
        r = np.linalg.norm(rng.normal(size=(400_000, d)), axis=1)
        assert abs(np.mean(r > robust_norm_threshold(k, d)) - p) < 4 * math.sqrt(p / 400_000)
    # the GTSAM model: a 6-D whitened error of norm 4 (beyond 3, inside 4.48) keeps its full weight
    base = gtsam.noiseModel.Isotropic.Sigma(6, 1.0)
    e = np.full(6, 4.0 / math.sqrt(6.0))
    f = gtsam.PriorFactorVector(0, np.zeros(6), _robust(base, RobustLoss.HUBER, k))
    vals = gtsam.Values()
    vals.insert(0, e)
    assert math.isclose(f.error(vals), 0.5 * 16.0, rel_tol=1e-9)
    vals.update(0, 2.0 * e)  # norm 8: Huber's linear branch at t = 4.48
    t = robust_norm_threshold(k, 6)
    assert math.isclose(f.error(vals), t * 8.0 - 0.5 * t * t, rel_tol=1e-9)
    assert _robust(base, RobustLoss.NONE, k) is base


def test_a_recovery_process_loads_neither_scipy_signal_nor_scipy_stats(tmp_path):
    """scipy.signal (and the scipy.stats it pulls in) would add ~0.5 s and ~25 MB to every recovery
    process: a whole default recovery, the intrinsics check included, runs on the numpy versions."""
    import subprocess
    import sys
    from pathlib import Path

    from pipeline.store import write_store

    write_store(_sim(60.0, seed=2).sequence, tmp_path / "store")
    code = ("import json, sys\n"
            "from pipeline.store import read_store\n"
            "from recovery.recover import recover\n"
            f"res = recover(read_store({str(tmp_path / 'store')!r}))\n"
            "print(json.dumps({'coupling': res.report['intrinsics_auto']['coupling'],\n"
            "                  'loaded': [m for m in ('scipy.signal', 'scipy.stats') if m in sys.modules]}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["coupling"] == "none"  # the intrinsics check ran (on a 6-DoF stream)
    assert got["loaded"] == []


def test_gyro_keyframe_rotations_equal_composing_every_sample():
    """The vectorised gyro integration of the position-only orientation guess equals composing the
    sub-interval rotations one by one with scipy."""
    from scipy.spatial.transform import Rotation

    from recovery.initial import gyro_keyframe_rotations

    sim = _sim(6.0, seed=3)
    imu = sim.sequence.imu
    kf = imu.t_ns[5:-5:37]  # keyframes off the IMU grid's phase: split sub-intervals
    kf = np.unique(np.concatenate([kf, kf[:-1] + 2_500_000]))
    samples = midpoint_samples(imu.t_ns, imu.imu_6, kf)
    got = gyro_keyframe_rotations(samples)
    cur, want = Rotation.identity(), [Rotation.identity()]
    for i in range(len(kf) - 1):
        for j in range(samples.start[i], samples.start[i + 1]):
            cur = cur * Rotation.from_rotvec(samples.gyro_radps[j] * samples.dt_s[j])
        want.append(cur)
    err = (Rotation.concatenate(want).inv() * got).magnitude()
    assert len(got) == len(kf) and err.max() < 1e-10, err.max()


def test_propagated_orientations_equal_composing_every_sample_from_the_last_known():
    from scipy.spatial.transform import Rotation

    from recovery.initial import propagate_orientations

    sim = _sim(6.0, seed=3)
    imu = sim.sequence.imu
    kf = imu.t_ns[5:-5:37]
    samples = midpoint_samples(imu.t_ns, imu.imu_6, kf)
    K, bias = len(kf), np.array([0.01, -0.02, 0.03])
    q = Rotation.random(K, random_state=1).as_quat(scalar_first=True)
    known = np.zeros(K, dtype=bool)
    known[[0, 3, 4, 10, K - 2]] = True
    got = propagate_orientations(samples, q, known, bias)
    cur, want = None, q.copy()
    for k in range(K):  # the definition: from the last known orientation, sample by sample
        if known[k]:
            cur = Rotation.from_quat(q[k], scalar_first=True)
            continue
        for j in range(samples.start[k - 1], samples.start[k]):
            cur = cur * Rotation.from_rotvec((samples.gyro_radps[j] - bias) * samples.dt_s[j])
        want[k] = cur.as_quat(scalar_first=True)
    err = (Rotation.from_quat(want, scalar_first=True).inv() * Rotation.from_quat(got, scalar_first=True)).magnitude()
    assert err.max() < 1e-10, err.max()
    np.testing.assert_array_equal(got[known], q[known])


def test_an_optimiser_that_gives_up_far_from_an_optimum_is_refused():
    """Levenberg-Marquardt stopped where a Gauss-Newton step still predicts a large decrease is no optimum:
    refused with the cost and the decrease; at the optimum of the same graph (a prior's own value, whose
    cost is 0 in closed form) nothing is raised."""
    import gtsam

    from gtsam.symbol_shorthand import X

    from recovery.factors import BuiltWindow
    from recovery.graph import _refuse_unconverged

    graph = gtsam.NonlinearFactorGraph()
    target = gtsam.Pose3(gtsam.Rot3.Rz(0.3), gtsam.Point3(1.0, 2.0, 3.0))
    graph.add(gtsam.PriorFactorPose3(X(0), target, gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    far = gtsam.Values()
    far.insert(X(0), gtsam.Pose3())
    built = BuiltWindow(graph, far, [], [], 0.0)
    order = gtsam.Ordering()
    order.push_back(X(0))
    with pytest.raises(RecoveryError, match="did not converge"):
        _refuse_unconverged(built, far, order, graph.error(far))
    at = gtsam.Values()
    at.insert(X(0), target)
    assert graph.error(at) == pytest.approx(0.0, abs=1e-12)
    _refuse_unconverged(built, at, order, graph.error(at))
