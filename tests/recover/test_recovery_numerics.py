"""The recovery's numerical building blocks: preintegration samples, orientation propagation, robust
thresholds, GTSAM value pools, and the numpy replacements that keep scipy.signal off the recovery path."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.sim import simulate
from pipeline.sim.config import PoseStreamConfig, SimConfig
from recovery.config import RecoveryConfig, RobustLoss
from recovery.solver.preintegration import midpoint_samples
from recovery.recover import recover
from recovery_sim import FAST, bias_errors, sim_sequence


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
    eg, ea = bias_errors(res, sim.truth)
    core = slice(len(eg) // 10, -len(eg) // 10)
    assert np.sqrt((eg[core] ** 2).mean()) < 2e-5
    assert np.sqrt((ea[core] ** 2).mean()) < 2e-3


# ----------------------------------------------------------------------------- numpy replacements and GTSAM values


def test_numpy_replacements_match_scipy():
    """The numpy versions that keep scipy.signal / scipy.integrate off the recovery path."""
    from scipy import signal
    from scipy.integrate import cumulative_trapezoid

    from recovery.calibration_init.common import correlate_valid, cumtrapz
    from recovery.solver.initial import savgol

    rng = np.random.default_rng(0)
    a, v = rng.normal(size=500), rng.normal(size=380)
    np.testing.assert_allclose(correlate_valid(a, v), signal.correlate(a, v, mode="valid", method="fft"),
                               atol=1e-9)
    x, y = np.sort(rng.uniform(size=40)), rng.normal(size=(40, 3, 3))
    np.testing.assert_allclose(cumtrapz(y, x), cumulative_trapezoid(y, x, axis=0, initial=0), atol=1e-12)
    for K, win in ((100, 31), (7, 7), (8, 7), (50, 5)):
        p = rng.normal(size=(K, 3)).cumsum(0)
        for deriv in (1, 2):
            np.testing.assert_allclose(savgol(p, win, 0.01, deriv),
                                       signal.savgol_filter(p, win, 2, deriv=deriv, delta=0.01, axis=0),
                                       rtol=1e-9, atol=1e-8 * 100.0**deriv)


def test_bias_values_pool_round_trip():
    """Bias initial values built from the cached zero pool carry the requested values, any K."""
    from gtsam.symbol_shorthand import B

    from recovery.solver.factors import bias_values

    rng = np.random.default_rng(3)
    for K in (5, 12, 7):
        b = rng.normal(size=(K, 6))
        vals = bias_values(b, K)
        assert vals.size() == K
        for k in (0, K - 1):
            cb = vals.atConstantBias(B(k))
            np.testing.assert_allclose(np.r_[cb.gyroscope(), cb.accelerometer()], b[k], atol=1e-12)
    assert bias_values(np.zeros(6), 4).size() == 4


# ----------------------------------------------------------------------------- robust loss


def test_robust_threshold_has_the_one_dimensional_tail_in_every_dimension():
    """A clean factor of any dimension is down-weighted as often as a 1-D one beyond k sigmas."""
    import math

    import gtsam

    from recovery.solver.factors import robust_noise, robust_norm_threshold

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
    f = gtsam.PriorFactorVector(0, np.zeros(6), robust_noise(base, RobustLoss.HUBER, k))
    vals = gtsam.Values()
    vals.insert(0, e)
    assert math.isclose(f.error(vals), 0.5 * 16.0, rel_tol=1e-9)
    vals.update(0, 2.0 * e)  # norm 8: Huber's linear branch at t = 4.48
    t = robust_norm_threshold(k, 6)
    assert math.isclose(f.error(vals), t * 8.0 - 0.5 * t * t, rel_tol=1e-9)
    assert robust_noise(base, RobustLoss.NONE, k) is base


# ----------------------------------------------------------------------------- scipy-free recovery process


def test_a_recovery_process_loads_neither_scipy_signal_nor_scipy_stats(tmp_path):
    """scipy.signal (and the scipy.stats it pulls in) would add ~0.5 s and ~25 MB to every recovery
    process: a whole default recovery, the intrinsics check included, runs on the numpy versions."""
    import subprocess
    import sys
    from pathlib import Path

    from pipeline.store import write_store

    write_store(sim_sequence(60.0, seed=2).sequence, tmp_path / "store")
    code = ("import json, sys\n"
            "from pipeline.store import read_store\n"
            "from recovery.recover import recover\n"
            f"res = recover(read_store({str(tmp_path / 'store')!r}))\n"
            "print(json.dumps({'coupling': res.report['intrinsics_auto']['coupling'],\n"
            "                  'loaded': [m for m in ('scipy.signal', 'scipy.stats') if m in sys.modules]}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["coupling"] == "none"  # the intrinsics check ran (on a 6-DoF stream)
    assert got["loaded"] == []


# ----------------------------------------------------------------------------- orientations from the gyro


def test_gyro_keyframe_rotations_equal_composing_every_sample():
    """The vectorised gyro integration of the position-only orientation guess equals composing the
    sub-interval rotations one by one with scipy."""
    from scipy.spatial.transform import Rotation

    from recovery.solver.initial import gyro_keyframe_rotations

    sim = sim_sequence(6.0, seed=3)
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

    from recovery.solver.initial import propagate_orientations

    sim = sim_sequence(6.0, seed=3)
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
