"""Bias recovery under a clock offset, an unknown extrinsic, outliers and dropouts, and split into
overlapping segments (simulated data)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.sim.config import PoseFormat
from pipeline.types import ImuSeries, PoseSeries, PoseSourceKind
from recovery.config import RecoveryConfig
from recovery.recover import recover
from recovery.solver.segments import plan_segments
from recovery_sim import FAST, bias_errors, sim_sequence


# ----------------------------------------------------------------------------- clock offset, extrinsic and outliers


def test_coarse_offset_uses_the_most_rotating_span_of_long_recordings():
    from recovery.clock.offset import coarse_offset_inputs
    from recovery.recover import COARSE_OFFSET_SPAN_S

    t_s = np.arange(0.0, 2000.0, 0.05)
    gyro = np.zeros((len(t_s), 3))
    gyro[(t_s > 1200) & (t_s < 1500), 2] = 1.0  # the motion is here
    imu = ImuSeries((t_s * 1e9).astype(np.int64), gyro, np.tile([0, 0, 9.81], (len(t_s), 1)))
    tp = (t_s[::2] * 1e9).astype(np.int64)
    poses = PoseSeries(tp, np.zeros((len(tp), 3)), np.tile([1.0, 0, 0, 0], (len(tp), 1)), "m", PoseSourceKind.MOCAP)
    pieces = [(int(imu.t_ns[0]), int(imu.t_ns[-1]))]
    imu_c, poses_c = coarse_offset_inputs(imu, poses, pieces, 0.5)
    span = (poses_c.t_ns[-1] - poses_c.t_ns[0]) / 1e9
    assert COARSE_OFFSET_SPAN_S - 1 <= span <= COARSE_OFFSET_SPAN_S
    assert poses_c.t_ns[0] <= 1200e9 and poses_c.t_ns[-1] >= 1500e9
    # the IMU reaches past the poses by more than the largest offset searched
    assert imu_c.t_ns[0] <= poses_c.t_ns[0] - 1.5e9 and imu_c.t_ns[-1] >= poses_c.t_ns[-1] + 1.4e9
    short = imu.take(slice(0, 4000))
    assert coarse_offset_inputs(short, poses, pieces, 0.5)[0] is short


@pytest.mark.slow
def test_hard_offset_extrinsic_outliers_dropouts():
    sim = sim_sequence(40.0, seed=2, extrinsic_known=False, extrinsic_rotation_deg=15.0, extrinsic_translation_m=0.10,
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
    eg, ea = bias_errors(res, sim.truth)
    assert (np.sqrt((eg**2).mean(0)) < 4e-4).all()
    assert rep["extrinsic_rotation_observable"] is True


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_newton_clock_offset_equals_the_cost_parabola(seed, monkeypatch):
    """The Newton refinement (analytic slope and curvature of the cost in the offset) lands where
    the parabola through three re-solved costs puts the vertex (within 0.1 sigma, same curvature sigma to 3 %),
    from a coarse value ~0.1 ms off, in one solve; both near the truth."""
    from recovery.clock import offset as ro

    sim = sim_sequence(40.0, seed=seed, clock_offset_s=0.012, dropouts=1, outliers=4, outlier_offset_m=0.1)
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
    sim = sim_sequence(40.0, seed=5, format=PoseFormat.POSITION, rate_hz=20.0, extrinsic_known=True,
               extrinsic_translation_xyz_m=(0.07, -0.02, -0.12), position_noise_m=1e-3, clock_offset_s=0.005)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None, "position_sigma_m": 1e-3}, intrinsics="off")
    rep = recover(sim.sequence, config=cfg).report
    assert rep["pose_time_offset_method"].endswith("+graph_cost_parabola")
    assert abs(rep["pose_time_offset_s"] - 0.005) < 4 * rep["pose_time_offset_std_s"]


def test_outliers_do_not_move_the_bias():
    sim_clean = sim_sequence(30.0, seed=4)
    sim_bad = sim_sequence(30.0, seed=4, outliers=15, outlier_offset_m=0.1)
    cfg = RecoveryConfig(**{**FAST, "keyframe_rate_hz": None}, time_offset_mode="fixed", compute_marginals=False)
    a = recover(sim_clean.sequence, config=cfg)
    b = recover(sim_bad.sequence, config=cfg)
    assert a.report["outliers_rejected"] == 0
    assert 15 <= b.report["outliers_rejected"] <= 17
    common, ia, ib = np.intersect1d(a.t_ns, b.t_ns, return_indices=True)
    assert len(common) > 0.9 * len(a.t_ns)
    assert np.abs(a.bias_gyro_radps[ia] - b.bias_gyro_radps[ib]).max() < 2e-4
    assert np.abs(a.bias_acc_mps2[ia] - b.bias_acc_mps2[ib]).max() < 1e-2


# ----------------------------------------------------------------------------- segments


def test_plan_segments_cover_with_overlap():
    s = plan_segments(0, int(200e9), 60.0, 10.0)
    assert s[0][0] == 0 and s[-1][1] == int(200e9)
    for (a0, b0), (a1, b1) in zip(s[:-1], s[1:]):
        assert b0 - a1 >= int(10e9) - 1 and a1 > a0
    assert plan_segments(0, int(80e9), 60.0, 10.0) == [(0, int(80e9))]


def test_segment_seams_within_sigma():
    sim = sim_sequence(50.0, seed=7)
    cfg = RecoveryConfig(**FAST, time_offset_mode="fixed", segment_s=20.0, segment_overlap_s=6.0)
    res = recover(sim.sequence, config=cfg)
    seams = res.report["segment_seams"]
    assert len(seams) >= 2
    assert max(s["max_abs_diff_over_sigma"] for s in seams) < 1.0
    # no step in the stitched output either: neighbour differences are small vs sigma
    step = np.abs(np.diff(res.bias_gyro_radps, axis=0)) / res.bias_gyro_std_radps[1:]
    assert step.max() < 1.0
    assert (np.diff(res.t_ns) > 0).all()
