"""Keyframes inside pose gaps (recovery.solver.gaps): where they go, how they start, and a recovery across a 10-s gap."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.sim import simulate
from pipeline.sim.config import PoseStreamConfig, SimConfig
from pipeline.types import NS_PER_S
from recovery.config import RecoveryConfig
from recovery.solver.gaps import GAP_KEYFRAME_PERIOD_S, bridge_gaps, gap_keyframe_stamps
from recovery.solver.preintegration import ImuNoise, make_params, midpoint_samples, preintegrate
from recovery.recover import recover


def test_a_pause_gets_evenly_spaced_keyframes_a_short_one_none():
    t = np.arange(0, 101) * 50_000_000  # 20 Hz over 5 s
    t_gap = np.concatenate([t[:21], t[60:]])  # 1.0 s to 3.0 s missing: a 2.0-s pause
    out, measured = gap_keyframe_stamps(t_gap)
    np.testing.assert_array_equal(out[measured], t_gap)
    added = out[~measured]
    # GAP_KEYFRAME_PERIOD_S = 0.5: ceil(2.0 / 0.5) - 1 = 3 stamps, evenly 0.5 s apart, strictly inside
    assert GAP_KEYFRAME_PERIOD_S == 0.5 and len(added) == 3
    np.testing.assert_allclose(np.diff(out[20:25]), 0.5 * NS_PER_S, atol=1)
    short = np.concatenate([t[:21], t[25:]])  # a 0.25-s pause: under GAP_MIN_S
    assert gap_keyframe_stamps(short)[1].all() and gap_keyframe_stamps(t)[1].all()
    slow = np.arange(0, 30) * 800_000_000  # a 1.25 Hz stream's own spacing is kept, not refined
    out, m = gap_keyframe_stamps(np.concatenate([slow[:10], slow[20:]]))
    assert (~m).sum() == 10 and np.diff(out).max() <= 0.8 * NS_PER_S  # 8.8 s in 11 steps of 0.8 s


def _circle(t_s: np.ndarray, g_world: np.ndarray) -> tuple[np.ndarray, ...]:
    """A body yawing at 0.8 rad/s on a 2-m circle while climbing at 0.2 m/s^2: positions, velocities,
    orientations and its ideal IMU readings (gyro, specific force) in closed form."""
    w, r, az = 0.8, 2.0, 0.2
    c, s = np.cos(w * t_s), np.sin(w * t_s)
    p = np.c_[r * c, r * s, 0.5 * az * t_s**2]
    v = np.c_[-r * w * s, r * w * c, az * t_s]
    a = np.c_[-r * w**2 * c, -r * w**2 * s, np.full_like(t_s, az)]
    R = Rotation.from_rotvec(np.c_[np.zeros_like(t_s), np.zeros_like(t_s), w * t_s])
    f = R.inv().apply(a - g_world)
    return p, v, R, np.c_[np.tile([0.0, 0.0, w], (len(t_s), 1)), f]


def test_bridged_states_follow_the_true_motion_across_a_pause_despite_a_wrong_gravity():
    """The IMU integrated across a 3-s pause with a gravity 0.2 deg off (a constant world acceleration
    error, 3.4 cm/s^2) misses the true motion by centimetres; the bridged states, closed onto the state
    after the pause, follow the closed-form truth within 0.1 mm and 0.01 mrad."""
    g_true = np.array([0.0, 0.0, -9.81])
    imu_t = np.arange(0, 6.0 + 1e-9, 0.005)
    _, _, _, imu_6 = _circle(imu_t, g_true)
    kf_t = np.round(np.arange(0, 6.0 + 1e-9, 0.1) * NS_PER_S).astype(np.int64)
    measured = (kf_t < 1.5 * NS_PER_S) | (kf_t > 4.5 * NS_PER_S)
    p, v, R, _ = _circle(kf_t / NS_PER_S, g_true)
    samples = midpoint_samples(np.round(imu_t * NS_PER_S).astype(np.int64), imu_6, kf_t)
    tilted = Rotation.from_rotvec([np.radians(0.2), 0.0, 0.0]).apply([0.0, 0.0, -1.0])
    params = make_params(ImuNoise(gyro_noise_density=1e-4, acc_noise_density=1e-3, gyro_random_walk=1e-5,
                                   acc_random_walk=1e-4), 9.81, tilted)
    pims = preintegrate(samples, params, np.zeros(6))
    truth = [gtsam.Pose3(gtsam.Rot3(R[k].as_matrix()), p[k]) for k in range(len(kf_t))]
    start = [x if m else gtsam.Pose3() for x, m in zip(truth, measured)]
    Xs, vel = bridge_gaps(pims, start, np.where(measured[:, None], v, 0.0), kf_t, measured)
    gap = np.nonzero(~measured)[0]
    pos_err = np.array([np.linalg.norm(Xs[k].translation() - p[k]) for k in gap])
    rot_err = np.array([np.linalg.norm(gtsam.Rot3.Logmap(Xs[k].rotation().between(truth[k].rotation())))
                        for k in gap])
    assert pos_err.max() < 1e-4 and rot_err.max() < 1e-5 and np.abs(vel[gap] - v[gap]).max() < 1e-4
    # the forward integration alone drifts by centimetres in the same pause
    state, drift = gtsam.NavState(truth[gap[0] - 1], v[gap[0] - 1]), []
    for k in range(gap[0] - 1, gap[-1]):
        state = pims[k].predict(state, pims[k].biasHat())
        drift.append(np.linalg.norm(state.position() - p[k + 1]))
    assert max(drift) > 100 * pos_err.max()


def test_recovery_across_a_ten_second_pose_gap_tracks_the_true_bias_and_motion():
    """40 s of simulated Vicon with the poses of 15-25 s removed (what a cross-validation fold leaves):
    the keyframes inside the gap carry the bias (within 3 of their sigmas of the simulator's truth, at
    the gap's middle) and an IMU-only trajectory within 15 cm of the true one (the simulator's accelerometer
    random walk, 10x EuRoC's, moves its bias by ~0.07 m/s^2 in 5 s: ~10 cm of drift at the gap's middle)."""
    sim = simulate(SimConfig(duration_s=40.0, seed=5, poses=PoseStreamConfig(extrinsic_known=True)))
    seq = sim.sequence
    stream = next(iter(seq.poses))
    poses = seq.poses[stream]
    t_rel = (poses.t_ns - seq.imu.t_ns[0]) / NS_PER_S
    seq = dataclasses.replace(seq, poses={stream: poses.take((t_rel < 15.0) | (t_rel >= 25.0))})
    res = recover(seq, pose_stream=stream, config=RecoveryConfig(
        keyframe_rate_hz=20.0, noise_estimation="fixed", gyro_random_walk=10 * 1.9393e-5,
        acc_random_walk=10 * 3.0e-3, position_sigma_m=0.5e-3, rotation_sigma_rad=0.5e-3, extrinsic_mode="known"))
    k_rel = (res.t_ns - seq.imu.t_ns[0]) / NS_PER_S
    inside = (k_rel > 15.2) & (k_rel < 24.8)
    assert inside.sum() >= 18  # keyframes every 0.5 s in the gap
    mid = inside & (np.abs(k_rel - 20.0) < 2.0)
    truth = sim.truth
    for got, std, true in ((res.bias_gyro_radps, res.bias_gyro_std_radps, truth.bias_gyro_radps),
                           (res.bias_acc_mps2, res.bias_acc_std_mps2, truth.bias_acc_mps2)):
        want = np.stack([np.interp(res.t_ns[mid], truth.t_ns, true[:, c]) for c in range(3)], 1)
        z = np.abs(got[mid] - want) / std[mid]
        assert np.median(z) < 3.0, np.median(z, axis=0)
    gt = sim.sequence.ground_truth
    p_true = np.stack([np.interp(res.t_ns[inside], gt.t_ns, gt.p_m[:, c]) for c in range(3)], 1)
    assert np.linalg.norm(res.p_m[inside] - p_true, axis=1).max() < 0.15


def _true_solution(gt, idx: np.ndarray):
    """A WindowSolution holding the simulator's true state at ground-truth rows ``idx``."""
    from recovery.solver.window import WindowSolution

    bias = np.hstack([gt.bias_gyro_radps[idx], gt.bias_acc_mps2[idx]])
    return WindowSolution(gt.t_ns[idx], gt.p_m[idx], gt.quat_wxyz[idx], gt.v_mps[idx], bias, np.full_like(bias, np.nan),
                          np.array([0.0, 0.0, -1.0]), np.eye(4), 0.0, np.nan, np.nan, np.zeros(0, dtype=int), 0)


def test_a_position_only_segment_starts_from_another_solution_inside_it_or_across_a_pose_gap():
    """The orientation guess of a position-only segment (recovery.problem._continue_from) from a solution that
    covers only its middle (filled forwards and backwards with the gyro) or that ends before it, with no
    keyframe in common (carried across the gap with the IMU): within 0.2 deg of the simulator's truth at every
    keyframe, where the closed-form guess would be used otherwise."""
    from recovery.solver.window import KeyframePoses
    from recovery.problem import continue_from
    from pipeline.types import PoseSourceKind

    sim = simulate(SimConfig(duration_s=30.0, seed=2, poses=PoseStreamConfig(extrinsic_known=True)))
    imu, gt = sim.sequence.imu, sim.sequence.ground_truth
    t_rel = (gt.t_ns - gt.t_ns[0]) / NS_PER_S
    kf_idx = np.nonzero((t_rel >= 12.0) & (t_rel <= 28.0))[0][::20]  # keyframes at 10 Hz in 12-28 s
    kf = KeyframePoses(gt.t_ns[kf_idx], gt.p_m[kf_idx], None, PoseSourceKind.POSITION_TRACKER)
    w = (midpoint_samples(imu.t_ns, imu.imu_6, kf.t_ns), kf)
    truth = Rotation.from_quat(gt.quat_wxyz[kf_idx], scalar_first=True)
    middle = _true_solution(gt, np.nonzero((t_rel >= 17.0) & (t_rel <= 22.0))[0][::7])
    before = _true_solution(gt, np.nonzero((t_rel >= 2.0) & (t_rel <= 8.0))[0][::7])
    for prev in (middle, before):
        init = continue_from(prev, w, np.array([0.0, 0.0, -1.0]), (imu.t_ns, imu.imu_6))
        got = Rotation.from_quat(init.rot_wxyz, scalar_first=True)
        assert np.degrees((got.inv() * truth).magnitude()).max() < 0.2
    assert continue_from(before, w, np.array([0.0, 0.0, -1.0])).rot_wxyz is None  # no IMU: the closed-form guess
