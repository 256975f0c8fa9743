"""recovery.intrinsics.gyro_consistency: the likelihood against the exact Gaussian density, walk fits on
simulated increments with known noise, rate coupling on a rotation with a known misalignment."""

from __future__ import annotations

import html
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import butter, filtfilt
from scipy.spatial.transform import Rotation
from scipy.stats import multivariate_normal

from pipeline.errors import RecoveryError
from pipeline.types import ImuSeries, PoseSeries, PoseSourceKind
from recovery.intrinsics.gyro_consistency import CouplingKind, attitude_increments, fit_walk, rate_coupling, walk_log_likelihood

DT = 0.1
ND = 1.7e-4  # gyro white noise density, rad/s/sqrt(Hz)


def _exact_log_likelihood(y: np.ndarray, nd: float, rw: float, white: float, gm_sigma: float, gm_tau: float) -> float:
    """The same state-space model's density of the summed increments, from its dense covariance."""
    a = np.exp(-DT / gm_tau) if gm_sigma > 0 else 0.0
    F = np.array([[1.0, DT, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, a]])
    Q = np.diag([nd**2 * DT, rw**2 * DT, gm_sigma**2 * (1 - a * a)])
    H = np.array([1.0, 0.0, 1.0])
    z = np.concatenate([[0.0], np.cumsum(y)])
    n = len(z)
    m = np.array([0.0, np.mean(y[:20]) / DT, 0.0])
    P = np.diag([1.0, 1e-2, gm_sigma**2])
    means, covs = [], []
    for _ in range(n):
        means.append(m)
        covs.append(P)
        m, P = F @ m, F @ P @ F.T + Q
    C = np.zeros((n, n))
    for k in range(n):
        Fk = np.eye(3)
        for j in range(k, n):  # Cov(x_j, x_k) = F^(j-k) P_k
            C[j, k] = C[k, j] = H @ Fk @ covs[k] @ H
            Fk = F @ Fk
    C += white**2 * np.eye(n)
    return float(multivariate_normal(np.array([H @ mm for mm in means]), C).logpdf(z))


@pytest.mark.parametrize("gm_sigma", [0.0, 2e-3])
def test_kalman_likelihood_equals_the_dense_gaussian_density(gm_sigma):
    y = np.random.default_rng(0).normal(0.002, 1e-3, 40)
    kf = walk_log_likelihood(y, DT, ND, 3e-3, 2e-4, gm_sigma, 0.7)
    # 8 significant digits: the diffuse first variance (1 rad^2) against 1e-8-sized ones costs the rest
    assert kf == pytest.approx(_exact_log_likelihood(y, ND, 3e-3, 2e-4, gm_sigma, 0.7), rel=1e-7)


def _simulated_increments(n: int, rw: float, white: float, gm_sigma: float, gm_tau: float, seed: int) -> np.ndarray:
    """Increments of gyro attitude error against a reference with white and Gauss-Markov attitude error."""
    rng = np.random.default_rng(seed)
    b = 0.02 + np.cumsum(rng.normal(0, rw * np.sqrt(DT), n))
    p = np.concatenate([[0.0], np.cumsum(b * DT + rng.normal(0, ND * np.sqrt(DT), n))])
    a = np.exp(-DT / gm_tau)
    g = np.zeros(n + 1)
    g[0] = rng.normal(0, gm_sigma)
    for k in range(n):
        g[k + 1] = a * g[k] + rng.normal(0, gm_sigma * np.sqrt(1 - a * a))
    phi = p + g + rng.normal(0, white, n + 1)
    return np.diff(phi)


def test_fit_walk_recovers_a_known_random_walk():
    rw = 2e-3  # ~100x a MEMS datasheet value
    fits = [fit_walk(_simulated_increments(1500, rw, 1e-4, 0.0, 1.0, seed), DT, ND) for seed in range(3)]
    ratios = [f.random_walk / rw for f in fits]
    assert all(0.7 < r < 1.4 for r in ratios), ratios


def test_a_gauss_markov_reference_error_is_told_from_the_walk():
    rw, sigma, tau = 2e-4, 3e-3, 1.0
    y = _simulated_increments(3000, rw, 5e-5, sigma, tau, seed=4)
    white_only = fit_walk(y, DT, ND)
    gm = fit_walk(y, DT, ND, gauss_markov=True)
    # modelled as white, the time-correlated error inflates the walk; modelled, it is found
    assert white_only.random_walk > 3 * rw
    assert gm.log_likelihood > white_only.log_likelihood + 10
    assert 0.5 < gm.gm_tau_s / tau < 2.0 and 0.7 < gm.gm_sigma_rad / sigma < 1.4
    assert gm.random_walk < 2.5 * rw


def _rotation_sequence(misalign: np.ndarray, low_pass_hz: float | None) -> tuple[ImuSeries, PoseSeries]:
    """200 s of multi-sine rotation; the gyro reads ``omega + S omega`` (or ``S LP(omega)``)."""
    rate_hz, n = 200.0, 40000
    t = np.arange(n) / rate_hz
    # two tones per band of DEFAULT_BANDS_HZ, shifted per axis (tones shared by the axes would
    # put the reference's second-order cross terms at the rate's own frequencies)
    freqs = np.array([0.02, 0.04, 0.08, 0.15, 0.4, 0.7, 1.5, 2.3, 4.1, 6.7])
    rng = np.random.default_rng(1)
    omega = np.stack([sum(0.06 * np.sin(2 * np.pi * f * shift * t + rng.uniform(0, 6.3)) for f in freqs)
                      for shift in (1.0, 1.07, 1.15)], 1)
    rots = [Rotation.identity()]
    for k in range(n - 1):  # the reference: the true rate integrated (midpoint)
        rots.append(rots[-1] * Rotation.from_rotvec(0.5 * (omega[k] + omega[k + 1]) / rate_hz))
    quat = Rotation.concatenate(rots).as_quat()[:, [3, 0, 1, 2]]
    coupled = omega
    if low_pass_hz is not None:
        bb, aa = butter(2, low_pass_hz / (rate_hz / 2))
        coupled = filtfilt(bb, aa, omega, axis=0)
    gyro = omega + coupled @ misalign.T
    t_ns = (t * 1e9).astype(np.int64) + 10**18
    imu = ImuSeries(t_ns, gyro, np.tile([0.0, 0.0, 9.81], (n, 1)))
    poses = PoseSeries(t_ns[::2], np.zeros((n // 2, 3)), quat[::2], "body", PoseSourceKind.GROUND_TRUTH)
    return imu, poses


def test_rate_coupling_of_a_misalignment_is_flat_across_bands():
    S = np.zeros((3, 3))
    S[1, 0], S[2, 1], S[0, 0] = 0.01, -0.004, 0.005  # two misalignments and a scale error
    imu, poses = _rotation_sequence(S, None)
    rc = rate_coupling(imu, poses)
    np.testing.assert_allclose(rc.gain[:3], np.broadcast_to(S, (3, 3, 3)), atol=1e-4)  # 0-1 Hz
    np.testing.assert_allclose(rc.gain[3], S, atol=1.5e-3)  # 1-3 Hz: the 100-Hz poses' interpolation shows
    assert np.all(rc.coherence[:3] > 0.9) and np.all(rc.coherence[3] > 0.7)
    assert rc.kind() is CouplingKind.INTRINSIC and rc.strongest()[1:] == (1, 0)


def test_rate_coupling_of_a_slow_process_shows_in_the_low_bands_only():
    S = np.zeros((3, 3))
    S[1, 0] = 0.03
    imu, poses = _rotation_sequence(S, low_pass_hz=0.1)
    rc = rate_coupling(imu, poses)
    assert rc.gain[0, 1, 0] == pytest.approx(0.03, abs=2e-3)  # 0-0.05 Hz: all of it
    assert rc.gain[1, 1, 0] > 0.01  # 0.05-0.2 Hz: the low pass passes the 0.08-Hz tone
    assert np.all(np.abs(rc.gain[2:, 1, 0]) < 5e-4)  # 0.2-3 Hz: (almost) none
    assert rc.kind() is CouplingKind.SLOW and rc.strongest()[1:] == (1, 0)


def test_increments_vanish_for_a_consistent_gyro_and_errors_are_clear():
    imu, poses = _rotation_sequence(np.zeros((3, 3)), None)
    inc = attitude_increments(imu, poses, interval_s=0.1)
    assert np.abs(inc).max() < 1e-5
    # a repeated pose stamp (a stream not cleaned by ingest) gives finite rates, not a division by zero
    t = poses.t_ns.copy()
    t[100] = t[99]
    assert np.all(np.isfinite(rate_coupling(imu, replace(poses, t_ns=t)).gain))
    with pytest.raises(RecoveryError, match="positions only"):
        rate_coupling(imu, PoseSeries(poses.t_ns, poses.p_m, None, "prism", PoseSourceKind.POSITION_TRACKER))
    short = PoseSeries(poses.t_ns[:2000], poses.p_m[:2000], poses.quat_wxyz[:2000], "body", PoseSourceKind.GROUND_TRUTH)
    with pytest.raises(RecoveryError, match="overlap"):
        rate_coupling(imu, short)


def test_coupling_sentences():
    S = np.zeros((3, 3))
    S[1, 0] = 0.01
    assert "misalignment error" in rate_coupling(*_rotation_sequence(S, None)).sentence()
    S[1, 0] = 0.03
    assert "not an IMU scale or misalignment" in rate_coupling(*_rotation_sequence(S, low_pass_hz=0.1)).sentence()
    none = rate_coupling(*_rotation_sequence(np.zeros((3, 3)), None))
    assert none.kind() is CouplingKind.NONE and "follows the pose stream's rotation" in none.sentence()


def test_chance_coherence_of_unrelated_signals_does_not_count():
    """d made of a random walk unrelated to the rate: the lowest band's few averages give it a high
    coherence by chance now and then; the threshold from Beta(3, n - 3) keeps it from counting."""
    imu, poses = _rotation_sequence(np.zeros((3, 3)), None)
    kinds = []
    for seed in range(10):
        walk = np.cumsum(np.random.default_rng(seed).normal(0, 2e-4, imu.gyro_radps.shape), axis=0)
        kinds.append(rate_coupling(replace(imu, gyro_radps=imu.gyro_radps + walk), poses).kind())
    assert kinds.count(CouplingKind.NONE) == 10, kinds


def test_a_band_of_three_averages_never_counts_even_at_coherence_rounded_above_one():
    """Three inputs and n <= 3 independent averages give a multiple coherence of exactly 1 for any
    signals; rounding may put it a hair above 1, which must not pass for a coupling."""
    from recovery.intrinsics.gyro_consistency import RateCoupling

    gain = np.zeros((2, 3, 3))
    gain[0, 1, 0] = 0.01
    rc = RateCoupling(np.array([[0.0, 0.05], [0.2, 1.0]]), gain, np.array([[0.3, 1.0 + 1e-12, 0.3], [0.1] * 3]),
                      np.array([np.inf, 0.6]))
    assert rc.kind() is CouplingKind.NONE and "too few independent averages" in rc.sentence()
    imu, poses = _rotation_sequence(np.zeros((3, 3)), None)
    n = 60 * 200
    one_minute = rate_coupling(ImuSeries(imu.t_ns[:n], imu.gyro_radps[:n], imu.acc_mps2[:n]),
                               PoseSeries(poses.t_ns[:n // 2], poses.p_m[:n // 2], poses.quat_wxyz[:n // 2], "body",
                                          PoseSourceKind.GROUND_TRUTH))
    assert np.isinf(one_minute.coherence_needed[0])  # 0-0.05 Hz over two 30-s segments: 2 averages
    assert one_minute.kind() is CouplingKind.NONE


def test_quality_report_note_uses_the_recovered_offset_and_extrinsic(tmp_path):
    from pipeline.types import Sequence
    from recovery.outputs import RecoveryReport
    from reports.quality import ReportInputs, gyro_consistency_note

    imu, body = _rotation_sequence(np.zeros((3, 3)), None)
    R_imu_pose = Rotation.from_euler("xyz", [3.0, -2.0, 10.0], degrees=True)
    offset_s = 0.02  # pose stamps + offset = IMU clock
    q = (Rotation.from_quat(body.quat_wxyz[:, [1, 2, 3, 0]]) * R_imu_pose).as_quat()[:, [3, 0, 1, 2]]
    poses = PoseSeries(body.t_ns - int(offset_s * 1e9), body.p_m, q, "marker", PoseSourceKind.MOCAP)
    seq = Sequence("s", imu, {"mocap": poses})

    def note(T: np.ndarray, off: float) -> str:
        rec = RecoveryReport.from_json({"pose_stream": "mocap", "T_imu_pose": T.tolist(), "pose_time_offset_s": off})
        return html.unescape(str(gyro_consistency_note(ReportInputs(ingest_dir=tmp_path, sequence=seq, recovery=rec))))

    T = np.eye(4)
    T[:3, :3] = R_imu_pose.as_matrix()
    assert "follows the pose stream's rotation" in note(T, offset_s)
    assert "recovery.intrinsics.estimate" in note(np.eye(4), offset_s)  # a 10-deg rotation left in reads like a misalignment
    no_rotation = Sequence("s", imu, {"mocap": PoseSeries(poses.t_ns, poses.p_m, None, "prism",
                                                          PoseSourceKind.POSITION_TRACKER)})
    rec = RecoveryReport.from_json({"pose_stream": "mocap", "T_imu_pose": T.tolist(), "pose_time_offset_s": offset_s})
    assert gyro_consistency_note(ReportInputs(ingest_dir=tmp_path, sequence=no_rotation, recovery=rec)) is None


def test_quality_report_note_takes_the_sentence_auto_decided_on(tmp_path):
    """A recovery whose ``intrinsics: auto`` checked the coupling: the report shows that sentence (the
    one the decision was made on) and says what the recovery did."""
    from pipeline.types import Sequence
    from recovery.outputs import RecoveryReport
    from reports.quality import ReportInputs, gyro_consistency_note

    imu, poses = _rotation_sequence(np.zeros((3, 3)), None)
    rec = RecoveryReport.from_json({"pose_stream": "body", "intrinsics_auto": {
        "estimated": False, "coupling": "slow", "reason": "The sentence the decision was made on."}})
    note = html.unescape(str(gyro_consistency_note(
        ReportInputs(ingest_dir=tmp_path, sequence=Sequence("s", imu, {"body": poses}), recovery=rec))))
    assert "The sentence the decision was made on." in note and "(intrinsics: auto)" in note


@pytest.mark.parametrize("nperseg", [64, 65])
def test_cross_spectra_and_chance_level_equal_scipy(nperseg):
    """The numpy Welch cross spectra and the Beta quantile that keep scipy.signal / scipy.stats out
    of every recovery process."""
    from scipy.signal import csd
    from scipy.special import betaincinv
    from scipy.stats import beta

    from recovery.intrinsics.gyro_consistency import cross_spectra

    x = np.random.default_rng(4).normal(size=(517, 4)).cumsum(0)
    f, S = cross_spectra(x, 15.0, nperseg)
    f_ref, S_ref = csd(x[:, :, None], x[:, None, :], fs=15.0, nperseg=nperseg, axis=0)
    np.testing.assert_allclose(f, f_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(S, S_ref, rtol=1e-10, atol=1e-12 * np.abs(S_ref).max())
    for n in (4, 9, 40, 400):
        assert betaincinv(3, n - 3, 0.999) == pytest.approx(beta.ppf(0.999, 3, n - 3), rel=1e-10)


def test_rate_coupling_of_a_rotation_about_one_axis_counts_no_band():
    """Rotation about z only: the rate cross-spectrum of every band is singular (no rate about x or y), so
    no coupling can be told from it; every band is left out (never counts), where solving it raised."""
    rate_hz, n = 200.0, 12000
    t = np.arange(n) / rate_hz
    omega = np.zeros((n, 3))
    omega[:, 2] = sum(0.3 * np.sin(2 * np.pi * f * t) for f in (0.03, 0.1, 0.5, 1.7))
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:, 2] + omega[:-1, 2]) / rate_hz)])
    quat = Rotation.from_rotvec(np.column_stack([np.zeros(n), np.zeros(n), yaw])).as_quat()[:, [3, 0, 1, 2]]
    t_ns = (t * 1e9).astype(np.int64) + 10**18
    imu = ImuSeries(t_ns, omega, np.tile([0.0, 0.0, 9.81], (n, 1)))
    poses = PoseSeries(t_ns[::2], np.zeros((n // 2, 3)), quat[::2], "body", PoseSourceKind.GROUND_TRUTH)
    rc = rate_coupling(imu, poses)
    assert np.all(rc.gain == 0.0) and np.all(rc.coherence == 0.0)
    assert rc.kind() is CouplingKind.NONE
