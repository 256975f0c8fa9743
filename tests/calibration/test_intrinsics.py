"""IMU intrinsics (recovery.intrinsics.estimate): the model, the fit against a known trajectory, the loop around recover."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import independent as ind
from pipeline.sim import SimConfig, simulate
from pipeline.sim.config import MotionConfig, PoseStreamConfig
from recovery.config import IntrinsicsMode, RecoveryConfig
from pipeline.types import ImuNoiseModel, ImuSeries, PoseSeries, PoseSourceKind
from recovery.intrinsics.estimate import ImuIntrinsics, IntrinsicsFit, drop_insignificant, fit_intrinsics, \
    intrinsics_bias_variance, raw_bias, recover_with_intrinsics
from recovery.recover import recover

_spec = importlib.util.spec_from_file_location(
    "benchmark_intrinsics", Path(__file__).resolve().parents[2] / "benchmarks" / "recovery" / "intrinsics.py")
_bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_bench)
bias_rmse, truth_intrinsics, with_intrinsics = _bench.bias_rmse, _bench.truth_intrinsics, _bench.with_intrinsics
full_intrinsics, nees = _bench.full_intrinsics, _bench.nees


@pytest.fixture(scope="module")
def drone_120s():
    return simulate(SimConfig(duration_s=120.0, seed=0, motion=MotionConfig(preset="aggressive_drone"),
                              poses=PoseStreamConfig(extrinsic_known=True)))


@pytest.fixture(scope="module")
def drone():
    return simulate(SimConfig(duration_s=60.0, seed=0, motion=MotionConfig(preset="aggressive_drone"),
                              poses=PoseStreamConfig(extrinsic_known=True)))


def test_correct_inverts_the_measurement_model(drone):
    M_g, M_a, G = truth_intrinsics()
    bad = with_intrinsics(drone, M_g, M_a, G).imu
    fixed = ImuIntrinsics(M_g, M_a, G).correct(bad, drone.truth.bias_acc_mps2)
    tr = drone.truth
    # corrected readings are w + M_g^-1 b_g and f + M_a^-1 b_a: remove those and compare with the clean ones
    w = fixed.gyro_radps - tr.bias_gyro_radps @ np.linalg.inv(M_g).T
    f = fixed.acc_mps2 - tr.bias_acc_mps2 @ np.linalg.inv(M_a).T
    np.testing.assert_allclose(w, drone.sequence.imu.gyro_radps - tr.bias_gyro_radps, atol=1e-12)
    np.testing.assert_allclose(f, drone.sequence.imu.acc_mps2 - tr.bias_acc_mps2, atol=1e-12)


def test_compose_and_raw_bias_closed_form():
    rng = np.random.default_rng(0)
    a = ImuIntrinsics(np.eye(3) + 1e-2 * rng.standard_normal((3, 3)), np.eye(3) + 1e-2 * rng.standard_normal((3, 3)),
                      1e-3 * rng.standard_normal((3, 3)))
    b = ImuIntrinsics(np.eye(3) + 1e-2 * rng.standard_normal((3, 3)), np.eye(3) + 1e-2 * rng.standard_normal((3, 3)),
                      1e-3 * rng.standard_normal((3, 3)))
    w, f = rng.standard_normal(3), rng.standard_normal(3)
    # raw = M_a (M_b w + G_b f) + G_a f  for gyro; raw = M_a M_b f for acc
    ab = a.compose(b)
    np.testing.assert_allclose(ab.gyro_matrix @ w + ab.gyro_g_sensitivity @ f,
                               a.gyro_matrix @ (b.gyro_matrix @ w + b.gyro_g_sensitivity @ f) + a.gyro_g_sensitivity @ f)
    np.testing.assert_allclose(ab.acc_matrix @ f, a.acc_matrix @ (b.acc_matrix @ f))
    bias = rng.standard_normal((4, 6))
    out, std = raw_bias(a, bias, np.zeros((4, 6)))
    np.testing.assert_allclose(out[:, :3], bias[:, :3] @ a.gyro_matrix.T)
    np.testing.assert_allclose(out[:, 3:], bias[:, 3:] @ a.acc_matrix.T)
    assert np.all(std == 0)


def test_terms_left_insignificant_by_the_composition_are_dropped():
    """A gyro misalignment zx times a real G xz fills G zz (``G = M_g G'``) although no fit applied it:
    in the raw convention it is 1.7 sigma, and dropped; the significant terms stay as they are."""
    M_g = np.eye(3)
    M_g[2, 0] = -8.7e-3
    step_g = np.zeros((3, 3))
    step_g[0, 2] = 1e-3
    total = ImuIntrinsics.identity().compose(ImuIntrinsics(M_g, np.eye(3), np.zeros((3, 3)))).compose(
        ImuIntrinsics(np.eye(3), np.diag([1.005, 1.0, 1.0]), step_g))
    assert total.gyro_g_sensitivity[2, 2] == pytest.approx(-8.7e-6)
    sigma = {"gyro_scale_misalignment": np.full((3, 3), 3e-5), "acc_scale_misalignment": np.full((3, 3), 2e-4),
             "gyro_g_sensitivity": np.full((3, 3), 5e-6)}
    fit = IntrinsicsFit(ImuIntrinsics.identity(), sigma, {k: np.ones((3, 3), bool) for k in sigma}, {})
    present = {k: np.zeros((3, 3), bool) for k in sigma}
    present["gyro_scale_misalignment"][2, 0] = present["gyro_g_sensitivity"][0, 2] = True
    present["acc_scale_misalignment"][0, 0] = True
    out, keep, dropped = drop_insignificant(total, fit, present)
    assert dropped == ["gyro_g_sensitivity[zz]"]
    expected = total.gyro_g_sensitivity.copy()
    expected[2, 2] = 0.0
    np.testing.assert_array_equal(out.gyro_g_sensitivity, expected)
    np.testing.assert_array_equal(out.gyro_matrix, total.gyro_matrix)
    np.testing.assert_array_equal(out.acc_matrix, total.acc_matrix)
    assert {k: v.sum() for k, v in keep.items()} == {k: v.sum() for k, v in present.items()}
    # the acc scale of 0.005 at 2e-4 sigma is 25 sigma: kept; at 2e-3 sigma it is not significant
    sigma["acc_scale_misalignment"] = np.full((3, 3), 2e-3)
    out, keep, dropped = drop_insignificant(total, fit, present)
    assert "acc_scale_misalignment[xx]" in dropped and not keep["acc_scale_misalignment"].any()
    np.testing.assert_array_equal(out.acc_matrix, np.eye(3))


def test_fit_recovers_injected_intrinsics_against_the_true_trajectory(drone_120s):
    """No GTSAM: the true trajectory and bias, readings rewritten with known intrinsics (the benchmark's case)."""
    drone = drone_120s
    M_g, M_a, G = truth_intrinsics()
    imu = with_intrinsics(drone, M_g, M_a, G).imu
    gt, tr = drone.sequence.ground_truth, drone.truth
    k = np.arange(0, len(gt.t_ns), 20)  # 10-Hz keyframes
    bias = np.hstack([tr.bias_gyro_radps, tr.bias_acc_mps2])
    cal = drone.sequence.calibration
    noise = dataclasses.replace(cal.noise_model(), gyro_random_walk=10 * cal.gyro_random_walk,
                                acc_random_walk=10 * cal.acc_random_walk)
    fit = fit_intrinsics(imu, gt.t_ns[k], gt.quat_wxyz[k], gt.v_mps[k],
                         lambda t: np.stack([np.interp(t, tr.t_ns, bias[:, c]) for c in range(6)], axis=1),
                         drone.truth.gravity_mps2, noise, g_sensitivity=True)
    for est, true, group in ((fit.step.gyro_matrix - np.eye(3), M_g - np.eye(3), "gyro_scale_misalignment"),
                             (fit.step.acc_matrix - np.eye(3), M_a - np.eye(3), "acc_scale_misalignment"),
                             (fit.step.gyro_g_sensitivity, G, "gyro_g_sensitivity")):
        sigma = fit.sigma[group]
        hit = true != 0
        assert np.all(np.abs(est - true)[hit] <= 3 * sigma[hit]), (group, est, true, sigma)
        assert np.all(np.abs(est - true)[hit] <= 0.1 * np.abs(true)[hit]), (group, est, true)
        assert np.all(fit.observable[group])


def test_present_terms_take_their_refinement_below_the_gate(drone_120s):
    """A term applied in an earlier round (``present``) takes the fit's estimate of what is left of it
    even when that is below the 3-sigma gate for new terms; a term not present stays zero."""
    drone = drone_120s
    M_a = np.diag([1.0, 1.0, 1.0004])  # what an earlier round left of a 0.5 % gravity-axis scale
    imu = with_intrinsics(drone, np.eye(3), M_a, np.zeros((3, 3))).imu
    gt, tr = drone.sequence.ground_truth, drone.truth
    k = np.arange(0, len(gt.t_ns), 20)
    bias = np.hstack([tr.bias_gyro_radps, tr.bias_acc_mps2])
    cal = drone.sequence.calibration
    noise = dataclasses.replace(cal.noise_model(), gyro_random_walk=10 * cal.gyro_random_walk,
                                acc_random_walk=10 * cal.acc_random_walk)

    def fit(present):
        return fit_intrinsics(imu, gt.t_ns[k], gt.quat_wxyz[k], gt.v_mps[k],
                              lambda t: np.stack([np.interp(t, tr.t_ns, bias[:, c]) for c in range(6)], axis=1),
                              drone.truth.gravity_mps2, noise, g_sensitivity=False, present=present)

    gated = fit(None)
    sigma = gated.sigma["acc_scale_misalignment"][2, 2]
    assert 0.0004 < 3 * sigma  # below the gate for a new term: not applied
    assert gated.step.acc_matrix[2, 2] == 1.0 and not gated.applied["acc_scale_misalignment"][2, 2]
    present = {"acc_scale_misalignment": np.zeros((3, 3), bool)}
    present["acc_scale_misalignment"][2, 2] = True
    refined = fit(present)
    assert refined.applied["acc_scale_misalignment"][2, 2]
    assert abs(refined.step.acc_matrix[2, 2] - 1.0004) <= 3 * sigma
    assert refined.moved(0.5) and not gated.moved(0.5)
    np.testing.assert_array_equal(refined.step.gyro_matrix, np.eye(3))


def test_accelerometer_fit_is_unbiased_under_noise_and_a_bias_walk():
    """Against the independent generator's true trajectory and bias, a calibrated IMU with white noise and a bias
    random walk (no intrinsic errors): over six seeds each accelerometer scale's estimate averages to zero within
    3 standard errors of the mean and its NEES is at most 2.5. A regressor built from the raw readings shares
    the interval's noise and the bias's within-block wander with the residual: the z scale then averaged +2.1
    sigma (NEES 5.0) on these seeds."""
    r = ind.REPORTED
    noise = ImuNoiseModel(r["gyro_noise_density"], 10 * r["gyro_random_walk"], r["acc_noise_density"],
                          10 * r["acc_random_walk"])
    z = []
    for seed in range(6):
        s = ind.make_sequence(60.0, seed=seed)
        k = np.arange(0, len(s.t_ns), int(s.rate_hz / 10))  # 10-Hz keyframes
        b = np.hstack([s.bias_gyro_radps, s.bias_acc_mps2])
        fit = fit_intrinsics(ImuSeries(s.t_ns, s.gyro_radps, s.acc_mps2), s.t_ns[k], s.quat_wxyz[k], s.v_mps[k],
                             lambda t: np.stack([np.interp(t, s.t_ns, b[:, c]) for c in range(6)], axis=1),
                             ind.GRAVITY_MPS2, noise, g_sensitivity=False)
        z.append(np.diag(fit.estimate["acc_scale_misalignment"]) / np.diag(fit.sigma["acc_scale_misalignment"]))
    z = np.array(z)
    assert np.all(np.abs(z.mean(0)) <= 3 / np.sqrt(len(z))), z
    assert np.all((z**2).mean(0) <= 2.5), z


@pytest.mark.parametrize("cutoff_hz", [1.0, 0.1])
def test_the_fit_low_pass_is_scipys_forward_backward_butterworth(cutoff_hz):
    """The fit's numpy low-pass (kept off ``scipy.signal``, which recovery processes do not load) against
    ``scipy.signal.sosfiltfilt`` of a 4th-order Butterworth with the same odd padding (the whole series): equal
    away from the ends (the IIR's start-up differs there, within 1 % of the signal's spread)."""
    from scipy.signal import butter, sosfiltfilt

    from recovery.intrinsics.estimate import zero_phase_low_pass

    rng = np.random.default_rng(0)
    n, rate_hz = 12001, 200.0
    t_ns = (np.arange(n) * 1e9 / rate_hz).astype(np.int64)
    x = (np.cumsum(rng.standard_normal((n, 3)), 0) * 0.01 + rng.standard_normal((n, 3)) * 0.1
         + np.sin(2 * np.pi * 0.3 * np.arange(n) / rate_hz)[:, None])
    ours = zero_phase_low_pass(t_ns, x, cutoff_hz)
    scipys = sosfiltfilt(butter(4, cutoff_hz, fs=rate_hz, output="sos"), x, axis=0, padtype="odd", padlen=n - 1)
    inner = slice(int(10 * rate_hz), -int(10 * rate_hz))
    assert np.abs(ours - scipys)[inner].max() <= 1e-4 * x.std()
    assert np.abs(ours - scipys).max() <= 1e-2 * x.std()


def test_intrinsics_uncertainty_in_the_bias_matches_sampling_the_model():
    """The first-order bias variance equals the variance of ``-(dS_g w + dG f)`` / ``-dS_a f`` over
    term errors drawn from the fit's covariance (the measurement model applied to matrices), and
    terms outside the model add nothing."""
    rng = np.random.default_rng(3)
    L_rot, L_vel = rng.normal(size=(18, 18)) * 1e-4, rng.normal(size=(9, 9)) * 1e-4
    cov = {"rotation": L_rot @ L_rot.T, "velocity": L_vel @ L_vel.T}
    groups = ("gyro_scale_misalignment", "acc_scale_misalignment", "gyro_g_sensitivity")
    fit = IntrinsicsFit(ImuIntrinsics.identity(), {}, {}, {}, groups, None, cov)
    terms = {g: rng.random((3, 3)) < 0.6 for g in groups}
    omega, f = rng.normal(size=(4, 3)), rng.normal(size=(4, 3)) + [0.0, 0.0, 9.81]
    var = intrinsics_bias_variance(fit, terms, omega, f)
    n = 40000
    x_rot = rng.multivariate_normal(np.zeros(18), cov["rotation"], n)
    x_vel = rng.multivariate_normal(np.zeros(9), cov["velocity"], n)
    dS_g = x_rot[:, :9].reshape(n, 3, 3) * terms["gyro_scale_misalignment"]
    dG = x_rot[:, 9:].reshape(n, 3, 3) * terms["gyro_g_sensitivity"]
    dS_a = x_vel.reshape(n, 3, 3) * terms["acc_scale_misalignment"]
    db_g = -(np.einsum("nij,kj->nki", dS_g, omega) + np.einsum("nij,kj->nki", dG, f))
    db_a = -np.einsum("nij,kj->nki", dS_a, f)
    sampled = np.concatenate([db_g.var(0), db_a.var(0)], axis=1)
    np.testing.assert_allclose(var, sampled, rtol=0.05)
    none = {g: np.zeros((3, 3), bool) for g in groups}
    assert np.all(intrinsics_bias_variance(fit, none, omega, f) == 0)


@pytest.mark.slow
def test_recover_with_intrinsics_on_a_simulated_drone(drone):
    M_g, M_a, G = truth_intrinsics()
    on = RecoveryConfig(intrinsics=IntrinsicsMode.WITH_G_SENSITIVITY)
    clean = recover(drone.sequence)
    fixed = recover(with_intrinsics(drone, M_g, M_a, G), config=on)
    rep = fixed.report["intrinsics"]
    np.testing.assert_allclose(np.diag(rep["gyro_matrix"]), np.diag(M_g), atol=0.1 * 0.01)
    np.testing.assert_allclose(np.array(rep["gyro_g_sensitivity"])[[0, 1], [2, 0]], [1e-3, -1e-3], atol=1e-4)
    # the gyro bias no longer absorbs 1 % of the rate: within 1.5x of the clean recovery on 60 s
    ratio = bias_rmse(fixed, drone.truth) / bias_rmse(clean, drone.truth)
    assert np.all(ratio[:3] < 1.5), ratio
    # on readings without intrinsic errors, nothing significant is found, nothing is applied; the matrices
    # reported carry only the posterior means of the terms left out (noise, far below the 1 % of the case)
    same = recover(drone.sequence, config=on).report["intrinsics"]
    assert not same["estimated"] and not same["dropped_at_end"]
    np.testing.assert_allclose(same["gyro_matrix"], np.eye(3), atol=5e-4)
    np.testing.assert_allclose(same["acc_matrix"], np.eye(3), atol=5e-3)
    # the terms' uncertainty widens the bias sigmas: those estimated, and with none estimated, those left
    # out (their datasheet prior where the fit cannot see them)
    assert min(rep["bias_std_inflation_mean"]) >= 1.0 and max(rep["bias_std_inflation_mean"]) > 1.0
    assert min(same["bias_std_inflation_mean"]) >= 1.0 and not same["estimated"]
    # a better IMU's datasheet (every prior 10x smaller) reaches the fit: the terms the fit sees well (the gyro's)
    # keep about the fit's sigma, those it hardly sees (the accelerometer's tilt terms) add far less
    better = on.replace(intrinsics_prior_scale_misalignment=5e-4, intrinsics_prior_g_sensitivity=2e-5,
                        intrinsics_prior_non_orthogonality=1e-4, intrinsics_prior_calibration_rotation_rad=5e-5)
    added, added_before = (np.array(r["bias_std_added_mean"]) for r in (
        recover(drone.sequence, config=better).report["intrinsics"], same))
    assert np.all(added <= added_before) and np.all(added[3:5] < 0.5 * added_before[3:5]), (added, added_before)


def test_a_report_record_answers_membership():
    """``"key" in report`` on a typed JSON record asks its data (the intrinsics benchmark does so)."""
    from recovery.outputs import RecoveryReport

    report = RecoveryReport.from_json({"intrinsics": {}, "noise": {}})
    assert "intrinsics" in report and "calibration_uncertainty" not in report


def test_position_only_stream_estimates_no_intrinsics(drone):
    """Positions alone do not pin the trajectory's orientation down (it is the gyro's own integration): the
    loop is skipped with a warning and the bias is the plain recovery's."""
    seq = drone.sequence
    name, poses = next(iter(seq.poses.items()))
    positions = PoseSeries(poses.t_ns, poses.p_m, None, poses.frame, PoseSourceKind.POSITION_TRACKER)
    seq = dataclasses.replace(seq, poses={name: positions}, ground_truth=None)
    calls = []

    def solve(s):
        calls.append(s)
        return recover(s, pose_stream=name)

    res = recover_with_intrinsics(seq, solve, g_sensitivity=True, block_s=10.0)
    assert len(calls) == 1 and calls[0] is seq
    assert res.report["intrinsics"]["method"] == "not estimated"
    np.testing.assert_array_equal(res.report["intrinsics"]["gyro_matrix"], np.eye(3))
    assert any("IMU intrinsics not estimated" in w and name in w for w in res.warnings)


def test_auto_estimates_only_where_the_gyro_shows_an_intrinsic_error(drone):
    """The default (AUTO): the clean drone's recovery is the plain one, with the decision recorded; a
    gyro with a 1 % scale and a 0.5-deg misalignment starts the loop (and gives what asking for it gives).
    The extrinsic is known here: estimated, its rotation absorbs the gyro triad's rotation relative to
    the accelerometer's (the part of a misalignment no solve can tell from the extrinsic)."""
    assert RecoveryConfig().intrinsics is IntrinsicsMode.AUTO
    known = RecoveryConfig(extrinsic_mode="known")
    off = recover(drone.sequence, config=known.replace(intrinsics=IntrinsicsMode.OFF))
    auto = recover(drone.sequence, config=known)
    assert auto.report["intrinsics_auto"]["estimated"] is False
    assert auto.report["intrinsics_auto"]["coupling"] == "none"
    assert "intrinsics" not in auto.report and auto.report["config"]["intrinsics"] == "off"
    np.testing.assert_array_equal(auto.bias_gyro_radps, off.bias_gyro_radps)
    M_g, _, _ = truth_intrinsics()
    bad = with_intrinsics(drone, M_g, np.eye(3), np.zeros((3, 3)))
    auto = recover(bad, config=known)
    assert auto.report["intrinsics_auto"]["estimated"] is True
    assert auto.report["intrinsics_auto"]["coupling"] == "intrinsic"
    assert auto.report["config"]["intrinsics"] == "with_g_sensitivity"  # what a re-recovery (crossval) runs
    np.testing.assert_allclose(np.array(auto.report["intrinsics"]["gyro_matrix"]), M_g, atol=1e-3)
    # position-only streams are not checked (their orientation is the gyro's own)
    pos = dataclasses.replace(drone.sequence, poses={k: PoseSeries(v.t_ns, v.p_m, None, v.frame,
                                                                   PoseSourceKind.POSITION_TRACKER)
                                                     for k, v in bad.poses.items()})
    assert "not checked" in recover(pos).report["intrinsics_auto"]["reason"]


@pytest.mark.parametrize("seed", [0, 1])
def test_bias_sigmas_cover_the_error_with_every_intrinsic_term(seed, drone_120s):
    """120 s with every term at once (gyro scales, 0.5 deg on every off-diagonal, accelerometer scales,
    a full 3x3 g-sensitivity), recovered with them estimated: per-axis NEES of the bias against the
    simulator's truth within [0.5, 2], and the gyro bias within 1.5x of the clean recovery's RMSE. Before
    the intrinsics are estimated, most pose factors of the first solve exceed the outlier threshold: they
    are kept (a noise model that is off), not rejected into a degenerate window."""
    sim = drone_120s if seed == 0 else simulate(SimConfig(
        duration_s=120.0, seed=seed, motion=MotionConfig(preset="aggressive_drone"), poses=PoseStreamConfig(extrinsic_known=True)))
    clean = recover(sim.sequence, config=RecoveryConfig(intrinsics=IntrinsicsMode.OFF))
    res = recover(with_intrinsics(sim, *full_intrinsics()), config=RecoveryConfig(intrinsics=IntrinsicsMode.WITH_G_SENSITIVITY))
    per_axis = nees(res, sim.truth)
    assert np.all((per_axis >= 0.5) & (per_axis <= 2.0)), per_axis
    ratio = bias_rmse(res, sim.truth) / bias_rmse(clean, sim.truth)
    assert np.all(ratio[:3] < 1.5), ratio
