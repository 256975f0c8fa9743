"""The pipeline on sequences generated independently of ``pipeline.sim`` (tests/independent.py).

1. readers: an EuRoC folder, a TUM text and a ROS1 bag written by our own code read back
   exactly; ``biasgt inspect --json`` says ok, and corrupted copies get the right codes;
2. the integration engine reproduces independent 1-s end poses;
3. the project's simulator is checked by an independent RK4 integrator (and GTSAM's scenario
   runner is checked against our closed-form generator's conventions);
4. recovery on independent 60-s sequences (clean and hard) meets loose versions of the
   benchmark's targets (the full 120-s figures: ``benchmarks/recovery/independent.py``).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import independent as ind
from biasgt.cli.app import main as cli_main
from pipeline.geometry.integration import IntegrationScheme, integrate
from pipeline.io import load_sequence
from pipeline.types import PoseSourceKind
from recovery_sim import FAST


@pytest.fixture(scope="module")
def short_seq() -> ind.IndependentSequence:
    return ind.make_sequence(12.0, seed=3)


@pytest.fixture(scope="module")
def euroc_dir(tmp_path_factory, short_seq):
    return ind.write_euroc(short_seq, tmp_path_factory.mktemp("indep") / "indep_seq")


# ----------------------------------------------------------------------------- 0. the generator itself


def test_generator_rates_match_finite_differences():
    """Analytic body rate / velocity / acceleration of the closed-form motion vs central differences."""
    m = ind.LissajousMotion()
    t = np.linspace(0.0, 60.0, 601)
    st, e = m.state(t), 1e-6
    after, before = m.state(t + e), m.state(t - e)
    w_fd = (before.rotation.inv() * after.rotation).as_rotvec() / (2 * e)
    assert np.abs(w_fd - st.omega_body_radps).max() < 1e-7
    assert np.abs((after.p_m - before.p_m) / (2 * e) - st.v_mps).max() < 1e-7
    assert np.abs((after.v_mps - before.v_mps) / (2 * e) - st.a_mps2).max() < 1e-7
    assert 0.5 < np.abs(st.omega_body_radps).max() < 2.0  # enough excitation, no singularity


def test_generator_specific_force_matches_gtsam_scenario_runner():
    """Our f = R^T (a - g) equals gtsam.ScenarioRunner.actualSpecificForce on GTSAM's own scenarios."""
    t = np.linspace(0.0, 5.0, 21)
    for kind in ("twist", "accelerating"):
        g = ind.gtsam_scenario_motion(kind)
        st = g.state(t)
        np.testing.assert_allclose(st.specific_force(), g.specific_force_gtsam(t), atol=1e-12)


def test_generator_rig_imperfections():
    """A tilted gravity enters the specific force as ``R^T (a - g)``; the Gauss-Markov attitude error has the
    stationary sigma and the lag-one correlation ``exp(-dt / tau)`` asked for; a dropout leaves no mocap sample
    in its span."""
    g = np.array([0.0857, 0.0, -9.8096])
    base = ind.make_sequence(10.0, seed=1, noise=False)
    tilted = ind.make_sequence(10.0, seed=1, noise=False, gravity_mps2=g)
    rot = Rotation.from_quat(base.quat_wxyz[:, [1, 2, 3, 0]])
    np.testing.assert_allclose(tilted.acc_true_mps2 - base.acc_true_mps2, rot.inv().apply(ind.GRAVITY_MPS2 - g),
                               atol=1e-12)
    x = ind.gauss_markov_rotvec(np.arange(200_000) * 0.01, 0.5, np.random.default_rng(0))
    assert np.std(x) == pytest.approx(1.0, rel=0.03)
    assert np.mean(x[1:] * x[:-1]) == pytest.approx(np.exp(-0.01 / 0.5), abs=0.02)
    seq = ind.make_sequence(20.0, seed=2, noise=False, correlated_rotation_noise_rad=4e-3, dropouts_s=((5.0, 1.0),))
    rel_s = (seq.pose_t_ns - seq.t_ns[0]) / 1e9
    assert not np.any((rel_s >= 5.0) & (rel_s < 6.0)) and np.any(rel_s < 5.0) and np.any(rel_s >= 6.0)
    level = ind.make_sequence(20.0, seed=2, noise=False)
    kept = np.isin(level.pose_t_ns, seq.pose_t_ns)
    err = (Rotation.from_quat(level.pose_quat_wxyz[kept][:, [1, 2, 3, 0]]).inv()
           * Rotation.from_quat(seq.pose_quat_wxyz[:, [1, 2, 3, 0]])).as_rotvec()
    assert 2e-3 < float(np.sqrt(np.mean(err**2))) < 8e-3  # 4 mrad per axis, over ~20 correlation times


def test_gtsam_scenario_runner_noise_and_sequence():
    """A sequence on GTSAM's ConstantTwistScenario with GTSAM-sampled white noise: noise level and truth."""
    dens_g, dens_a = ind.REPORTED["gyro_noise_density"], ind.REPORTED["acc_noise_density"]
    g = ind.gtsam_scenario_motion("twist", dt_s=0.005, gyro_noise_density=dens_g, acc_noise_density=dens_a)
    s = ind.make_sequence(20.0, seed=2, motion=g, gtsam_noise=True)
    ng = s.gyro_radps - s.gyro_true_radps - s.bias_gyro_radps
    na = s.acc_mps2 - s.acc_true_mps2 - s.bias_acc_mps2
    # discrete sigma = density * sqrt(rate): 2.4e-3 rad/s and 2.83e-2 m/s^2 (4001 samples: +-3.4 % at 3 sigma)
    np.testing.assert_allclose(ng.std(0), dens_g * np.sqrt(200.0), rtol=0.04)
    np.testing.assert_allclose(na.std(0), dens_a * np.sqrt(200.0), rtol=0.04)
    assert np.abs(ng.mean(0)).max() < 4 * dens_g * np.sqrt(200.0) / np.sqrt(len(ng))
    # the truth is GTSAM's: the scenario's own specific force at the stamps
    t_s = (s.t_ns[:50] - s.t_ns[0]) / 1e9
    np.testing.assert_allclose(s.acc_true_mps2[:50], g.specific_force_gtsam(t_s), atol=1e-12)


def _gtsam_end_errors(rate_hz: float) -> np.ndarray:
    """GTSAM preintegration of our noise-free IMU (minus the true bias) over 1 s: end errors [3 windows, 3]."""
    import gtsam

    s = ind.make_sequence(4.0, seed=5, noise=False, rate_hz=rate_hz)
    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setGyroscopeCovariance(1e-8 * np.eye(3))
    params.setAccelerometerCovariance(1e-6 * np.eye(3))
    params.setIntegrationCovariance(1e-8 * np.eye(3))
    w_true, a_true = s.gyro_radps - s.bias_gyro_radps, s.acc_mps2 - s.bias_acc_mps2
    n = int(rate_hz)
    out = []
    for start_s in (0.0, 1.5, 2.5):
        i0 = int(round(start_s * rate_hz))
        pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
        for k in range(i0, i0 + n):
            pim.integrateMeasurement(a_true[k], w_true[k], 1.0 / rate_hz)
        R0 = Rotation.from_quat(s.quat_wxyz[i0][[1, 2, 3, 0]]).as_matrix()
        pred = pim.predict(gtsam.NavState(gtsam.Rot3(R0), s.p_m[i0], s.v_mps[i0]), gtsam.imuBias.ConstantBias())
        i1 = i0 + n
        R1 = Rotation.from_quat(s.quat_wxyz[i1][[1, 2, 3, 0]])
        out.append((np.linalg.norm(pred.position() - s.p_m[i1]), np.linalg.norm(pred.velocity() - s.v_mps[i1]),
                    np.degrees((R1.inv() * Rotation.from_matrix(pred.attitude().matrix())).magnitude())))
    return np.array(out)


def test_gtsam_preintegration_reproduces_generator_poses():
    """GTSAM's preintegration of our IMU predicts our 1-s end states, converging at first order.

    GTSAM holds each sample over its interval (rectangle rule), a first-order scheme: at
    200 Hz the 1-s error is ~5 mm / ~0.13 deg on this motion, and 5x the rate must cut it 5x.
    A convention error (frames, gravity sign, quaternion order) would not shrink with the step.
    """
    e200, e1000 = _gtsam_end_errors(200.0), _gtsam_end_errors(1000.0)
    assert e1000[:, 0].max() < 1.5e-3 and e1000[:, 1].max() < 4e-3 and e1000[:, 2].max() < 0.05
    ratio = e200.max(0) / e1000.max(0)
    assert ((ratio > 4.5) & (ratio < 5.5)).all(), ratio


# ----------------------------------------------------------------------------- 1. readers


def test_euroc_folder_reads_exactly(euroc_dir, short_seq):
    s = short_seq
    seq = load_sequence(euroc_dir)
    assert seq.imu.t_ns.dtype == np.int64
    np.testing.assert_array_equal(seq.imu.t_ns, s.t_ns)
    np.testing.assert_array_equal(seq.imu.gyro_radps, s.gyro_radps)
    np.testing.assert_array_equal(seq.imu.acc_mps2, s.acc_mps2)
    vic = seq.poses["vicon0"]
    assert vic.source_kind is PoseSourceKind.MOCAP and vic.t_ns.dtype == np.int64
    np.testing.assert_array_equal(vic.t_ns, s.pose_t_ns)
    np.testing.assert_array_equal(vic.p_m, s.pose_p_m)
    np.testing.assert_array_equal(vic.quat_wxyz, s.pose_quat_wxyz)
    gt = seq.ground_truth
    np.testing.assert_array_equal(gt.t_ns, s.t_ns)
    np.testing.assert_array_equal(gt.quat_wxyz, s.quat_wxyz)
    np.testing.assert_array_equal(gt.v_mps, s.v_mps)
    np.testing.assert_array_equal(gt.bias_gyro_radps, s.bias_gyro_radps)
    np.testing.assert_array_equal(gt.bias_acc_mps2, s.bias_acc_mps2)
    cal = seq.calibration
    assert cal.gyro_noise_density == ind.REPORTED["gyro_noise_density"]
    assert cal.acc_random_walk == ind.REPORTED["acc_random_walk"] and cal.rate_hz == 200.0
    np.testing.assert_array_equal(cal.T_imu_frames[vic.frame], s.T_imu_marker)
    assert not [f for f in seq.findings if f.severity.value in ("fatal", "repairable")]


def test_tum_text_reads_exactly(tmp_path, short_seq):
    s = short_seq
    path = ind.write_tum_text(tmp_path / "mocap.txt", s.pose_t_ns, s.pose_p_m, s.pose_quat_wxyz)
    seq = load_sequence(path)
    poses = seq.poses["mocap"]
    np.testing.assert_array_equal(poses.t_ns, s.pose_t_ns)  # 1.5e18 ns: exact only via decimal text
    np.testing.assert_array_equal(poses.p_m, s.pose_p_m)
    np.testing.assert_array_equal(poses.quat_wxyz, s.pose_quat_wxyz)


def test_ros1_bag_reads_exactly(tmp_path):
    s = ind.make_sequence(3.0, seed=4)
    path = ind.write_ros1_bag(s, tmp_path / "indep.bag")
    seq = load_sequence(path)
    np.testing.assert_array_equal(seq.imu.t_ns, s.t_ns)  # header stamps, not receive times (+3 ms)
    np.testing.assert_array_equal(seq.imu.gyro_radps, s.gyro_radps)
    np.testing.assert_array_equal(seq.imu.acc_mps2, s.acc_mps2)
    (name, poses), = seq.poses.items()
    np.testing.assert_array_equal(poses.t_ns, s.pose_t_ns)
    np.testing.assert_array_equal(poses.p_m, s.pose_p_m)
    np.testing.assert_array_equal(poses.quat_wxyz, s.pose_quat_wxyz)


def _inspect_json(path, capsys) -> tuple[int, dict]:
    capsys.readouterr()
    rc = cli_main(["-q", "inspect", str(path), "--json"])
    return rc, json.loads(capsys.readouterr().out)


def test_inspect_ok_on_independent_folder(euroc_dir, capsys):
    rc, rep = _inspect_json(euroc_dir, capsys)
    assert rc == 0 and rep["verdict"] == "ok", rep["findings"]
    codes = {f["code"] for f in rep["findings"]}
    assert not codes & {"NON_MONOTONIC", "DUPLICATE_STAMPS", "GYRO_DEGPS", "ACC_IN_G", "CLOCK_MISMATCH"}
    imu = next(st for st in rep["streams"] if st["stream"] == "imu")
    assert imu["count"] == 12 * 200 + 1 and imu["rate_hz"] == pytest.approx(200.0)


@pytest.mark.parametrize("corruption, code", [
    ("unsorted", "NON_MONOTONIC"), ("duplicate", "DUPLICATE_STAMPS"), ("degps", "GYRO_DEGPS"),
])
def test_inspect_flags_corrupted_copy(euroc_dir, tmp_path, capsys, corruption, code):
    bad = tmp_path / "bad"
    shutil.copytree(euroc_dir, bad)
    csv = bad / "mav0" / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    header, rows = lines[0], lines[1:]
    if corruption == "unsorted":
        rows[100], rows[101] = rows[101], rows[100]
    elif corruption == "duplicate":
        rows.insert(501, rows[500])
    else:
        vals = np.array([[float(x) for x in r.split(",")[1:]] for r in rows])
        vals[:, :3] = np.degrees(vals[:, :3])
        rows = [r.split(",")[0] + "," + ",".join(repr(float(x)) for x in v) for r, v in zip(rows, vals)]
    csv.write_text("\n".join([header, *rows]) + "\n")
    rc, rep = _inspect_json(bad, capsys)
    found = [f for f in rep["findings"] if f["code"] == code]
    assert found and found[0]["stream"] == "imu" and found[0]["severity"] == "repairable"
    assert rep["verdict"] == "repairable" and rc == 0
    others = {"NON_MONOTONIC", "DUPLICATE_STAMPS", "GYRO_DEGPS"} - {code}
    assert not {f["code"] for f in rep["findings"]} & others
    if code == "NON_MONOTONIC":
        assert found[0]["details"]["count"] == 1 and found[0]["details"]["first_rows"] == [101]
    if code == "DUPLICATE_STAMPS":
        assert found[0]["details"]["count"] == 1


# ----------------------------------------------------------------------------- 2. integration engine


def _one_second_windows(s: ind.IndependentSequence, starts: np.ndarray, n: int):
    idx = starts[:, None] + np.arange(n)[None]
    w = (s.gyro_radps - s.bias_gyro_radps)[idx]
    a = (s.acc_mps2 - s.bias_acc_mps2)[idx]
    dt = np.diff(s.t_ns[idx], axis=1) / 1e9
    R0 = Rotation.from_quat(s.quat_wxyz[starts][:, [1, 2, 3, 0]]).as_matrix()
    res = integrate(torch.from_numpy(w), torch.from_numpy(a), torch.from_numpy(dt), torch.from_numpy(R0),
                    torch.from_numpy(s.v_mps[starts]), torch.from_numpy(s.p_m[starts]),
                    gravity_mps2=ind.GRAVITY_MPS2, scheme=IntegrationScheme.MIDPOINT)
    end = starts + n - 1
    p_err = np.linalg.norm(res.p.numpy() - s.p_m[end], axis=1)
    R_end = Rotation.from_quat(s.quat_wxyz[end][:, [1, 2, 3, 0]])
    rot_err = np.degrees((R_end.inv() * Rotation.from_matrix(res.R.numpy())).magnitude())
    return p_err, rot_err


def test_integration_engine_reproduces_independent_end_poses():
    """MIDPOINT on our noise-free IMU minus the true bias gives our true 1-s end poses.

    Tolerance: MIDPOINT is second order, so its error at 200 Hz on this motion (|w| <= 0.93
    rad/s, |a| <= 1.25 m/s^2) is ~1e-5 m and ~1e-4 deg, and halving the step must cut it ~4x;
    a convention error (frame, sign, gravity, quaternion order) would give >= 1e-2 m / 0.1 deg
    and would not shrink with the step. So: < 1e-4 m, < 1e-3 deg, and a 3..5x drop at 400 Hz.
    """
    s200 = ind.make_sequence(30.0, seed=2, noise=False, rate_hz=200.0)
    s400 = ind.make_sequence(30.0, seed=2, noise=False, rate_hz=400.0)
    starts = np.arange(0, 28) * 200
    p200, r200 = _one_second_windows(s200, starts, 201)
    p400, r400 = _one_second_windows(s400, starts * 2, 401)
    assert p200.max() < 1e-4 and r200.max() < 1e-3
    assert 3.0 < np.sqrt((p200**2).mean() / (p400**2).mean()) < 5.0
    assert 3.0 < np.sqrt((r200**2).mean() / (r400**2).mean()) < 5.0


def test_integration_engine_on_gtsam_scenario():
    """The same on GTSAM's AcceleratingScenario (truth from GTSAM, not from our formulas)."""
    g = ind.gtsam_scenario_motion("accelerating")
    s = ind.make_sequence(6.0, seed=1, noise=False, motion=g)
    p_err, rot_err = _one_second_windows(s, np.array([0, 400, 900]), 201)
    assert p_err.max() < 1e-4 and rot_err.max() < 1e-3


# ----------------------------------------------------------------------------- 3. simulator cross-check


def test_independent_rk4_checks_our_generator():
    s = ind.make_sequence(10.0, seed=1, noise=False)
    starts = np.arange(0, 9) * 200
    idx = starts[:, None] + np.arange(201)[None]
    q, v, p = ind.rk4_integrate((s.gyro_radps - s.bias_gyro_radps)[idx], (s.acc_mps2 - s.bias_acc_mps2)[idx],
                                0.005, s.quat_wxyz[starts], s.v_mps[starts], s.p_m[starts])
    end = starts + 200
    assert np.abs(p - s.p_m[end]).max() < 1e-7 and np.abs(v - s.v_mps[end]).max() < 1e-7
    assert ind.rotation_error_deg(q, s.quat_wxyz[end]).max() < 1e-6


def test_project_simulator_is_consistent_under_independent_rk4():
    """pipeline.sim's noise-free IMU minus its true bias, integrated by OUR RK4, lands on its ground truth.

    RK4 (4th order) with a 10-ms step: on the simulator's smooth splines the 1-s error is
    ~1e-5 m / ~1e-4 deg or less. A convention mismatch (world vs body rate, f = R^T(a - g)
    vs R^T(a + g), quaternion order) gives centimetres and degrees.
    """
    from pipeline.sim import simulate
    from pipeline.sim.config import ImuNoiseConfig, PoseStreamConfig, SimConfig

    sim = simulate(SimConfig(duration_s=12.0, seed=7, imu=ImuNoiseConfig(white_noise=False),
                             poses=PoseStreamConfig(extrinsic_known=True)))
    gt, imu = sim.sequence.ground_truth, sim.sequence.imu
    np.testing.assert_array_equal(gt.t_ns, imu.t_ns)
    h = float(np.diff(imu.t_ns).mean()) / 1e9
    assert np.ptp(np.diff(imu.t_ns)) <= 1  # uniform (ns rounding)
    starts = np.arange(0, 11) * 200
    idx = starts[:, None] + np.arange(201)[None]
    w = (imu.gyro_radps - gt.bias_gyro_radps)[idx]
    a = (imu.acc_mps2 - gt.bias_acc_mps2)[idx]
    q, v, p = ind.rk4_integrate(w, a, h, gt.quat_wxyz[starts], gt.v_mps[starts], gt.p_m[starts],
                                gravity_mps2=np.asarray(sim.truth.gravity_mps2))
    end = starts + 200
    assert np.linalg.norm(p - gt.p_m[end], axis=1).max() < 1e-4
    assert np.linalg.norm(v - gt.v_mps[end], axis=1).max() < 2e-4
    assert ind.rotation_error_deg(q, gt.quat_wxyz[end]).max() < 1e-3
    # and a wrong convention would be caught: the same RK4 with gravity's sign flipped is far off
    _, _, p_bad = ind.rk4_integrate(w, a, h, gt.quat_wxyz[starts], gt.v_mps[starts], gt.p_m[starts],
                                    gravity_mps2=-np.asarray(sim.truth.gravity_mps2))
    assert np.linalg.norm(p_bad - gt.p_m[end], axis=1).min() > 1.0


def test_project_simulator_pose_stream_convention():
    """The simulator's mocap = T_world_imu(t_stamp + offset) @ T_imu_marker, checked with scipy only."""
    from pipeline.sim import simulate
    from pipeline.sim.config import PoseStreamConfig, SimConfig

    sim = simulate(SimConfig(duration_s=5.0, seed=2, poses=PoseStreamConfig(
        extrinsic_rotation_deg=15.0, extrinsic_translation_m=0.1, clock_offset_s=0.012,
        position_noise_m=0.0, rotation_noise_rad=0.0)))
    (name, poses), = sim.sequence.poses.items()
    gt, T = sim.sequence.ground_truth, sim.truth.T_imu_frame
    # true instants on the IMU clock, as seconds from the first IMU stamp (the trajectory's time)
    t_true_s = (poses.t_ns + int(round(sim.truth.clock_offset_s * 1e9)) - gt.t_ns[0]) / 1e9
    R = sim.trajectory.rotation(t_true_s)
    np.testing.assert_allclose(poses.p_m, sim.trajectory.position(t_true_s) + R.apply(T[:3, 3]), atol=1e-9)
    R_m = Rotation.from_quat(poses.quat_wxyz[:, [1, 2, 3, 0]])
    # the trajectory agrees with the written ground truth at the IMU stamps
    j = np.arange(0, len(gt.t_ns), 97)
    R_gt = Rotation.from_quat(gt.quat_wxyz[j][:, [1, 2, 3, 0]])
    t_gt_s = (gt.t_ns[j] - gt.t_ns[0]) / 1e9
    assert np.degrees((R_gt.inv() * sim.trajectory.rotation(t_gt_s)).magnitude()).max() < 1e-9
    np.testing.assert_allclose(sim.trajectory.position(t_gt_s), gt.p_m[j], atol=1e-12)
    # a wrong offset sign would be visible: 24 ms of motion is far above 1e-9
    wrong = sim.trajectory.position(t_true_s - 2 * sim.truth.clock_offset_s) + R.apply(T[:3, 3])
    assert np.abs(wrong - poses.p_m).max() > 1e-3
    assert np.degrees(((R * Rotation.from_matrix(T[:3, :3])).inv() * R_m).magnitude()).max() < 1e-7


# ----------------------------------------------------------------------------- 4. recovery


@pytest.fixture(scope="module")
def clean_recovery(tmp_path_factory):
    from recovery.config import RecoveryConfig
    from recovery.recover import recover

    s = ind.make_sequence(60.0, seed=11)
    root = ind.write_euroc(s, tmp_path_factory.mktemp("rec") / "clean60")
    res = recover(load_sequence(root), config=RecoveryConfig(**FAST))
    return s, root, res


def test_recovery_clean_independent(clean_recovery):
    """Default pipeline (gravity direction estimated, or kept level when its tilt does not stand out):
    loose versions of the 120-s targets; the sigmas honest (per-axis NEES within 0.5-2)."""
    s, _, res = clean_recovery
    fig = ind.recovery_figures(res, s)
    assert (fig.gyro_rmse_radps < 3e-4).all(), fig.lines("clean60")
    assert (fig.acc_rmse_mps2 < 2e-2).all(), fig.lines("clean60")
    assert ((0.5 < fig.nees_per_axis) & (fig.nees_per_axis < 2.0)).all(), fig.lines("clean60")
    assert abs(fig.offset_error_s) < 1e-3
    # estimated with sensor.yaml's (the truth) as its prior
    assert fig.extrinsic_rot_error_deg < 0.05 and fig.extrinsic_trans_error_m < 0.01
    assert not res.report["extrinsic"]["difference_from_calibration"]["exceeds"]
    assert res.report["pose_stream"] == "vicon0" and not res.warnings


def test_recovery_clean_known_gravity(clean_recovery):
    """With the (true, z-up) gravity direction fixed, the acc sigmas are honest: NEES in [0.5, 2].

    The acc RMSE is then at the optimal-smoother level (~7e-3 m/s^2 for 0.03 m/s^3/sqrt(Hz)
    random walk and 0.5-mm mocap, see benchmarks/recovery/independent.py 'bound').
    """
    from recovery.config import RecoveryConfig
    from recovery.recover import recover

    s, root, _ = clean_recovery
    res = recover(load_sequence(root), config=RecoveryConfig(**FAST, estimate_gravity=False))
    fig = ind.recovery_figures(res, s)
    assert (fig.gyro_rmse_radps < 2.5e-4).all(), fig.lines("clean60-g")
    assert (fig.acc_rmse_mps2 < 1.1e-2).all(), fig.lines("clean60-g")
    assert 0.5 < fig.nees_gyro < 2.0 and 0.5 < fig.nees_acc < 2.0, fig.lines("clean60-g")


def test_recover_cli_on_independent_folder(clean_recovery, tmp_path, capsys):
    """``biasgt recover INPUT --out DIR`` on the independent folder writes the same result files."""
    import pandas as pd

    from pipeline.bias_table import CSV_HEADER

    s, root, res = clean_recovery
    cfg = tmp_path / "fast.yaml"
    cfg.write_text("recovery:\n" + "".join(f"  {k}: {v}\n" for k, v in FAST.items()))
    out = tmp_path / "rec"
    assert cli_main(["-q", "recover", str(root), "--out", str(out), "--config", str(cfg)]) == 0
    bias = pd.read_csv(out / "bias.csv")
    assert tuple(bias.columns) == CSV_HEADER and bias["t_ns"].dtype == np.int64
    np.testing.assert_array_equal(bias["t_ns"].to_numpy(), res.t_ns)
    np.testing.assert_allclose(bias[["bg_x", "bg_y", "bg_z"]].to_numpy(), res.bias_gyro_radps, rtol=1e-6, atol=1e-9)
    rep = json.loads((out / "recovery.json").read_text())
    assert rep["pose_stream"] == "vicon0" and abs(rep["pose_time_offset_s"]) < 1e-3
    assert (out / "trajectory_tum.txt").is_file()


def test_recovery_hard_independent(tmp_path):
    """12-ms clock offset and an unknown 15-deg / 10-cm marker extrinsic (no vicon0/sensor.yaml)."""
    from recovery.config import RecoveryConfig
    from recovery.recover import recover

    s = ind.make_sequence(60.0, seed=12, clock_offset_s=0.012, T_imu_marker=ind.HARD_EXTRINSIC)
    root = ind.write_euroc(s, tmp_path / "hard60", extrinsic_known=False)
    res = recover(load_sequence(root), config=RecoveryConfig(**FAST))
    fig = ind.recovery_figures(res, s)
    assert res.report["extrinsic"]["mode"] == "estimate"
    assert abs(fig.offset_error_s) < 1e-3, fig.lines("hard60")
    assert fig.extrinsic_rot_error_deg < 0.5 and fig.extrinsic_trans_error_m < 0.01, fig.lines("hard60")
    assert (fig.gyro_rmse_radps < 4.5e-4).all() and (fig.acc_rmse_mps2 < 2.5e-2).all(), fig.lines("hard60")
    # the calibration's uncertainty (offset, extrinsic, lever arm) reaches the bias sigmas: NEES as if known
    assert ((0.5 < fig.nees_per_axis) & (fig.nees_per_axis < 2.0)).all(), fig.lines("hard60")


def test_recovery_of_a_gauss_markov_mocap_attitude_error_is_honest(tmp_path):
    """A unit with no bias, its 113-Hz mocap attitude off by a Gauss-Markov error (5.3 mrad, 1.4 s) with three
    dropouts, the extrinsic from the calibration file (estimated with it as a prior), defaults: the extrinsic
    and the lever arm are solved with the correlated error the evidence chose, so the extrinsic stays within
    its sigma of the file's and the horizontal accelerometer sigmas cover the truth (white, the lever-arm
    refinement put the error's slow part into the lever arm at 19 sigma: acc-y NEES 91)."""
    from recovery.recover import recover

    s = ind.make_sequence(60.0, seed=1, gyro_turn_on_sigma=0.0, acc_turn_on_sigma=0.0, gyro_random_walk=0.0,
                          acc_random_walk=0.0, pose_rate_hz=112.9, correlated_rotation_noise_rad=5.3e-3,
                          correlated_noise_tau_s=1.37, dropouts_s=((9.0, 0.7), (31.0, 0.9), (50.0, 0.6)))
    res = recover(load_sequence(ind.write_euroc(s, tmp_path / "gm60", extrinsic_known=True, with_ground_truth=False)))
    fig = ind.recovery_figures(res, s)
    assert res.report["noise"]["pose_error"]["rotation_sigma_rad"] > 1e-3, res.report["noise"]
    difference = res.report["extrinsic"]["difference_from_calibration"]
    assert difference["rotation_sigmas"] < 3.0, difference
    assert (fig.nees_per_axis < 4.0).all(), fig.lines("gm60")
    assert (fig.acc_rmse_mps2[:2] < 5e-3).all(), fig.lines("gm60")
