"""Pose fusion (recovery.solver.fusion): samples between keyframes moved through the IMU and fused.

Checked against the simulator's truth: exact on noise-free poses (to the IMU's own
noise), the fused sigmas match the scatter of the errors, the within-bin residuals
estimate the pose noise, glitches are rejected, and a recovery from fused keyframes
equals one that makes every pose sample a keyframe.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.spatial.transform import Rotation, Slerp

from pipeline.sim import simulate
from pipeline.sim.config import PoseStreamConfig, SimConfig
from recovery.config import RecoveryConfig
from recovery.solver.fusion import WithinBinStats, fuse_poses, relative_motion
from recovery.recover import recover


def _sim(noise: float, outliers: int = 0, seed: int = 1, duration_s: float = 30.0):
    return simulate(SimConfig(duration_s=duration_s, seed=seed, poses=PoseStreamConfig(
        position_noise_m=noise, rotation_noise_rad=noise, extrinsic_rotation_deg=15.0,
        extrinsic_translation_m=0.1, outliers=outliers, outlier_offset_m=0.1)))


def _fuse(sim, rate_hz=20.0, true_bias=True):
    seq, tr = sim.sequence, sim.truth
    ps = next(iter(seq.poses.values()))
    t = ps.t_ns + int(round(tr.clock_offset_s * 1e9))
    sel = (t > seq.imu.t_ns[0] + 50_000_000) & (t < seq.imu.t_ns[-1] - 50_000_000)
    t = t[sel]
    bias = None
    if true_bias:
        bias = np.hstack([np.stack([np.interp(t, tr.t_ns, tr.bias_gyro_radps[:, c]) for c in range(3)], 1),
                          np.stack([np.interp(t, tr.t_ns, tr.bias_acc_mps2[:, c]) for c in range(3)], 1)])
    fused = fuse_poses(t, ps.p_m[sel], ps.quat_wxyz[sel], seq.imu.t_ns, seq.imu.imu_6, rate_hz,
                       int(seq.imu.t_ns[0]), tr.T_imu_frame, tr.gravity_mps2, bias)
    return fused, sel.sum()


def _truth_at(sim, t_ns):
    """True tracked-frame pose and IMU velocity at ``t_ns`` (from the 200-Hz ground truth)."""
    gt, T = sim.sequence.ground_truth, sim.truth.T_imu_frame
    x = (gt.t_ns - gt.t_ns[0]).astype(float)
    xq = (t_ns - gt.t_ns[0]).astype(float)
    p_imu = np.stack([np.interp(xq, x, gt.p_m[:, c]) for c in range(3)], 1)
    q = gt.quat_wxyz
    R_imu = Slerp(x, Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]]))(xq)
    v = np.stack([np.interp(xq, x, gt.v_mps[:, c]) for c in range(3)], 1)
    return p_imu + R_imu.apply(T[:3, 3]), R_imu * Rotation.from_matrix(T[:3, :3]), v


def _rot(q_wxyz):
    return Rotation.from_quat(np.c_[q_wxyz[:, 1:], q_wxyz[:, :1]])


def test_relative_motion_closed_form():
    """Constant rate about z and constant specific force: dR = Rz(w dt), dp = double integral, both directions."""
    t = np.arange(0, 2001) * 1_000_000  # 1 kHz, 2 s
    w, f = 0.7, np.array([0.3, -0.2, 9.81])
    imu_6 = np.tile(np.r_[0.0, 0.0, w, f], (len(t), 1))
    t_from = np.array([1_000_000_000, 1_000_000_000])
    t_to = np.array([1_040_000_000, 960_000_000])  # +-40 ms
    dR, dp = relative_motion(t, imu_6, t_from, t_to, np.zeros(6))
    for i, dt in enumerate((0.04, -0.04)):
        np.testing.assert_allclose(dR[i], Rotation.from_rotvec([0, 0, w * dt]).as_matrix(), atol=1e-12)
        # p(dt) = int_0^dt int_0^s Rz(w u) f du ds (closed form in the plane, z trivially 1/2 f_z dt^2)
        fx, fy = f[0], f[1]
        ax = lambda s: fx * np.cos(w * s) - fy * np.sin(w * s)  # noqa: E731
        ay = lambda s: fx * np.sin(w * s) + fy * np.cos(w * s)  # noqa: E731
        ex = quad(lambda s: quad(ax, 0, s)[0], 0, dt)[0]
        ey = quad(lambda s: quad(ay, 0, s)[0], 0, dt)[0]
        np.testing.assert_allclose(dp[i], [ex, ey, 0.5 * f[2] * dt**2], atol=3e-8)  # midpoint rule, 5-ms steps


def test_noise_free_fusion_matches_the_truth():
    sim = _sim(0.0)
    fused, n_samples = _fuse(sim)
    assert fused.count.sum() == n_samples and len(fused.rejected_t_ns) == 0
    p_true, R_true, v_true = _truth_at(sim, fused.t_ns)
    # the IMU moves samples by <= 25 ms: its own noise (~1e-5 rad, ~3e-6 m) and the ground
    # truth's linear interpolation at 200 Hz (~1e-5 m) are all that is left
    assert np.abs(fused.p_m - p_true).max() < 3e-5
    assert (R_true.inv() * _rot(fused.quat_wxyz)).magnitude().max() < 6e-5
    has_v = fused.dt2_s2 > 0
    assert np.abs(fused.v_mps[has_v] - v_true[has_v]).max() < 2e-3
    assert np.all(np.diff(fused.t_ns) > 0)


def test_fused_sigmas_and_within_bin_noise_estimate():
    sigma = 0.5e-3
    sim = _sim(sigma, seed=3, duration_s=60.0)
    fused, _ = _fuse(sim)
    p_true, R_true, v_true = _truth_at(sim, fused.t_ns)
    n = fused.count[:, None]
    z_p = (fused.p_m - p_true) / (sigma / np.sqrt(n))
    z_r = (R_true.inv() * _rot(fused.quat_wxyz)).as_rotvec() / (sigma / np.sqrt(n))
    has_v = fused.dt2_s2 > 0
    z_v = (fused.v_mps[has_v] - v_true[has_v]) / (sigma / np.sqrt(fused.dt2_s2[has_v]))[:, None]
    for z in (z_p, z_r, z_v):  # ~3500 values each: the std of a unit normal within a few %
        assert 0.9 < z.std() < 1.1 and abs(z.mean()) < 0.1
    pb = fused.per_bin
    assert np.sqrt(pb.pos_sq.sum() / pb.pos_dof.sum()) == pytest.approx(sigma, rel=0.03)
    assert np.sqrt(pb.rot_sq.sum() / pb.rot_dof.sum()) == pytest.approx(sigma, rel=0.03)
    # the log-likelihood of the scatter peaks at the true sigma
    w = WithinBinStats(float(pb.pos_sq.sum()), int(pb.pos_dof.sum()), float(pb.rot_sq.sum()), int(pb.rot_dof.sum()))
    ll = [w.log_likelihood(s, s) for s in (0.8 * sigma, sigma, 1.25 * sigma)]
    assert ll[1] > ll[0] and ll[1] > ll[2]


def test_outliers_are_rejected_inside_their_bin():
    sim = _sim(0.5e-3, outliers=20, seed=5)
    fused, n_samples = _fuse(sim)
    truth = sim.truth.poses.outlier_stamps_ns + int(round(sim.truth.clock_offset_s * 1e9))
    assert np.isin(truth, fused.rejected_t_ns).all()  # all 20 found
    assert len(fused.rejected_t_ns) <= 22  # and at most a couple of genuine samples with them
    p_true, _, _ = _truth_at(sim, fused.t_ns)
    assert np.abs(fused.p_m - p_true).max() < 1.5e-3  # no bin pulled by a 10-cm glitch


def test_fusion_after_rejection_equals_fusion_of_the_kept_samples():
    """The refits after a rejection integrate again only the bins whose keyframe stamp moved: the
    result equals fusing the kept samples from scratch."""
    sim = _sim(0.5e-3, outliers=20, seed=5)
    seq, tr = sim.sequence, sim.truth
    ps = next(iter(seq.poses.values()))
    t = ps.t_ns + int(round(tr.clock_offset_s * 1e9))
    sel = (t > seq.imu.t_ns[0] + 50_000_000) & (t < seq.imu.t_ns[-1] - 50_000_000)
    args = (seq.imu.t_ns, seq.imu.imu_6, 20.0, int(seq.imu.t_ns[0]), tr.T_imu_frame, tr.gravity_mps2)
    bias = np.array([0.01, -0.02, 0.005, 0.1, -0.05, 0.2])
    full = fuse_poses(t[sel], ps.p_m[sel], ps.quat_wxyz[sel], *args, bias)
    assert len(full.rejected_t_ns) >= 20
    kept = sel & ~np.isin(t, full.rejected_t_ns)
    clean = fuse_poses(t[kept], ps.p_m[kept], ps.quat_wxyz[kept], *args, bias)
    assert len(clean.rejected_t_ns) == 0
    np.testing.assert_array_equal(full.t_ns, clean.t_ns)
    np.testing.assert_array_equal(full.count, clean.count)
    for a, b in ((full.p_m, clean.p_m), (full.quat_wxyz, clean.quat_wxyz), (full.v_mps, clean.v_mps)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_gyro_bias_error_of_the_linearisation_is_absorbed():
    """Zero linearisation bias (sim gyro bias ~0.01 rad/s): the rate term keeps the fused rotation exact."""
    sim = _sim(0.0)
    fused, _ = _fuse(sim, true_bias=False)
    _, R_true, _ = _truth_at(sim, fused.t_ns)
    assert (R_true.inv() * _rot(fused.quat_wxyz)).magnitude().max() < 6e-5


def test_fused_recovery_equals_every_sample_recovery():
    """Fused 10-Hz keyframes carry the information of all 100-Hz samples: same bias and sigmas
    as the graph with every sample a keyframe, at a tenth of the keyframes."""
    sim = simulate(SimConfig(duration_s=30.0, seed=7, poses=PoseStreamConfig(extrinsic_known=True)))
    common = dict(noise_estimation="fixed", gyro_random_walk=10 * 1.9393e-5, acc_random_walk=10 * 3.0e-3,
                  position_sigma_m=0.5e-3, rotation_sigma_rad=0.5e-3, time_offset_mode="fixed",
                  marginal_rate_hz=None)
    fused = recover(sim.sequence, config=RecoveryConfig(**common))
    every = recover(sim.sequence, config=RecoveryConfig(**common, pose_fusion=False))
    assert fused.report["pose_fusion"]["enabled"] and not every.report["pose_fusion"]["enabled"]
    assert every.report["keyframes"] > 9 * fused.report["keyframes"]
    b_e = every.bias_at(fused.t_ns)
    s_e = every.std_at(fused.t_ns)
    b_f = np.hstack([fused.bias_gyro_radps, fused.bias_acc_mps2])
    s_f = np.hstack([fused.bias_gyro_std_radps, fused.bias_acc_std_mps2])
    inner = slice(20, -20)  # away from the ends, where keyframe spacing differs most
    assert np.median(np.abs(b_f - b_e)[inner] / s_e[inner], axis=0).max() < 0.25
    np.testing.assert_allclose(np.median(s_f[inner] / s_e[inner], axis=0), 1.0, atol=0.1)


def test_single_sample_bins_carry_no_velocity():
    """A bin with one sample (sparse stream, dropout edge) gives a pose but no velocity measurement."""
    sim = _sim(0.0, duration_s=10.0)
    seq, tr = sim.sequence, sim.truth
    ps = next(iter(seq.poses.values()))
    t = ps.t_ns + int(round(tr.clock_offset_s * 1e9))
    sel = np.nonzero((t > seq.imu.t_ns[0] + 50_000_000) & (t < seq.imu.t_ns[-1] - 50_000_000))[0]
    sel = np.r_[sel[: len(sel) // 2 : 5], sel[len(sel) // 2:]]  # 20 Hz then 100 Hz
    fused = fuse_poses(t[sel], ps.p_m[sel], ps.quat_wxyz[sel], seq.imu.t_ns, seq.imu.imu_6, 20.0,
                       int(seq.imu.t_ns[0]), tr.T_imu_frame, tr.gravity_mps2)
    single = fused.count == 1
    assert single.sum() > 50 and (fused.count[~single] >= 4).all()
    assert (fused.dt2_s2[single] == 0).all() and (fused.v_mps[single] == 0).all()
    assert (fused.per_bin.pos_dof[single] == 0).all()
    p_true, _, _ = _truth_at(sim, fused.t_ns)
    assert np.abs(fused.p_m[single] - p_true[single]).max() < 2e-5
