"""What the recovery says of the IMU intrinsics (recovery.intrinsics.report) and the sigma of the terms it left out."""

from __future__ import annotations

import numpy as np
import pytest

from recovery.intrinsics.estimate import ImuIntrinsics, IntrinsicsFit, intrinsics_bias_variance, left_out_shift
from recovery.intrinsics.report import intrinsics_clause, term_table
from reports.quality_verdict import checked_and_not

GROUPS = ("gyro_scale_misalignment", "acc_scale_misalignment", "gyro_g_sensitivity")


def test_terms_left_out_are_covered_on_average():
    """A term the fit left out (not significant) is still in the readings: over terms drawn at the
    datasheet size and fit estimates drawn around them with the fit's sigma, the bias error it causes
    has, on average, the variance the function reports (NEES 1), whether the fit sees the term well
    (sigma << prior) or hardly (sigma >> prior). With the bias corrected by the term's posterior mean
    (``left_out_shift``), the error left has, on average, the variance reported for the corrected bias."""
    rng = np.random.default_rng(5)
    tau = 2e-4  # the datasheet prior of a g-sensitivity term
    f = np.array([[0.3, -0.2, 9.81]])  # one keyframe: the G[z, z] term times f_z ~ g is a constant gyro z offset
    omega = np.zeros((1, 3))
    for sigma in (0.3 * tau, 3.0 * tau):
        cov = {"rotation": np.diag(np.r_[np.full(9, 1e-12), np.full(9, sigma**2)]), "velocity": np.eye(9) * 1e-12}
        fit = IntrinsicsFit(ImuIntrinsics.identity(), {}, {}, {}, GROUPS, None, cov)
        none = {g: np.zeros((3, 3), bool) for g in GROUPS}
        ratios, corrected = [], []
        for _ in range(1500):
            true = rng.normal(0.0, tau)
            left = {g: np.zeros((3, 3)) for g in GROUPS}
            left["gyro_g_sensitivity"][2, 2] = true + rng.normal(0.0, sigma)
            var = intrinsics_bias_variance(fit, none, omega, f, left=left)[0, 2]
            ratios.append((true * f[0, 2]) ** 2 / var)  # the bias absorbed G f
            shift = left_out_shift(fit, none, omega, f, left)[0, 2]
            var_c = intrinsics_bias_variance(fit, none, omega, f, left=left, corrected=True)[0, 2]
            corrected.append((true * f[0, 2] - shift) ** 2 / var_c)
        assert 0.85 < np.mean(ratios) < 1.15, (sigma, np.mean(ratios))
        assert 0.85 < np.mean(corrected) < 1.15, (sigma, np.mean(corrected))


def test_a_term_too_weak_to_correct_for_still_narrows_its_prior():
    """Closed form of the posterior: a left-out term whose fit sigma is 3x the prior's (above the fit's limit for
    correcting the readings) adds ``(1 / sigma^2 + 1 / tau^2)^-1 f^2`` to the bias variance, its posterior mean
    ``tau^2 / (tau^2 + sigma^2) x`` times the force leaves the bias; past ``BLIND_SIGMA_RATIO`` prior sigmas the
    prior ``tau^2 f^2`` stands and the estimate is ignored."""
    from recovery.intrinsics.posterior import BLIND_SIGMA_RATIO
    tau, x = 5e-3, 4e-3  # the accelerometer scale's datasheet prior; the fit's estimate of S_a[z, z]
    f, omega = np.array([[0.2, -0.1, 9.81]]), np.zeros((1, 3))
    none = {g: np.zeros((3, 3), bool) for g in GROUPS}
    left = {g: np.zeros((3, 3)) for g in GROUPS}
    left["acc_scale_misalignment"][2, 2] = x
    for sigma, var_term, mean in ((3 * tau, 1 / (1 / (3 * tau) ** 2 + 1 / tau**2), x / 10),
                                  (1.01 * BLIND_SIGMA_RATIO * tau, tau**2, 0.0)):
        vel = np.eye(9) * 1e-14
        vel[8, 8] = sigma**2
        fit = IntrinsicsFit(ImuIntrinsics.identity(), {}, {}, {}, GROUPS, None,
                            {"rotation": np.eye(18) * 1e-14, "velocity": vel})
        var = intrinsics_bias_variance(fit, none, omega, f, left=left, corrected=True)[0, 5]
        assert var == pytest.approx(var_term * f[0, 2] ** 2, rel=1e-6)
        assert left_out_shift(fit, none, omega, f, left)[0, 5] == pytest.approx(mean * f[0, 2], rel=1e-6, abs=1e-15)


def test_a_blind_tilt_term_keeps_the_configured_prior():
    """A left-out accelerometer tilt term the fit cannot see (``S_a[x, z]`` times ``f_z ~ g``) adds its prior
    ``tau^2 f_z^2`` to the x bias variance, with ``tau`` from the recovery's ``intrinsics_prior_*`` options:
    the triad's non-orthogonality where the frame is held, the scale/misalignment size where it is not."""
    from recovery.config import RecoveryConfig

    f, omega = np.array([[0.3, -0.2, 9.81]]), np.zeros((1, 3))
    none = {g: np.zeros((3, 3), bool) for g in GROUPS}
    left = {g: np.zeros((3, 3)) for g in GROUPS}
    vel = np.eye(9) * 1e-14
    vel[2, 2] = 1.0  # S_a[x, z]: blind
    fit = IntrinsicsFit(ImuIntrinsics.identity(), {}, {}, {}, GROUPS, None,
                        {"rotation": np.eye(18) * 1e-14, "velocity": vel})
    config = RecoveryConfig.from_dict({"intrinsics_prior_non_orthogonality": 2e-4,
                                       "intrinsics_prior_scale_misalignment": 3e-3})
    for frame_held, tau in ((True, 2e-4), (False, 3e-3)):
        sigmas = config.intrinsics_prior().term_sigmas(frame_held)
        var = intrinsics_bias_variance(fit, none, omega, f, left=left, prior=sigmas, corrected=True)[0, 3]
        assert var == pytest.approx(tau**2 * f[0, 2] ** 2 + 1e-14 * (f[0, 0] ** 2 + f[0, 1] ** 2), rel=1e-6)
    assert RecoveryConfig().intrinsics_prior() == type(config.intrinsics_prior())()  # the defaults: one source


def test_term_table_and_the_report_clause():
    sigma = {g: np.full((3, 3), 1e-4) for g in GROUPS}
    observable = {g: np.ones((3, 3), bool) for g in GROUPS}
    observable["acc_scale_misalignment"][2, 2] = False
    in_model = {g: np.zeros((3, 3), bool) for g in GROUPS}
    in_model["gyro_scale_misalignment"][0, 0] = in_model["gyro_g_sensitivity"][0, 2] = True
    values = {g: np.zeros((3, 3)) for g in GROUPS}
    values["gyro_scale_misalignment"][0, 0] = 0.01
    left = {g: np.full((3, 3), 2e-5) for g in GROUPS}
    table = term_table(values, sigma, observable, in_model, left, ["gyro_g_sensitivity[zz]"], GROUPS)
    assert [e["term"] for e in table["estimated"]] == ["gyro_scale_misalignment[xx]", "gyro_g_sensitivity[xz]"]
    assert table["estimated"][0] == {"term": "gyro_scale_misalignment[xx]", "value": 0.01, "sigma": 1e-4}
    why = {e["term"]: e["why"] for e in table["absorbed_by_bias"]}
    assert len(why) == 25 and why["acc_scale_misalignment[zz]"].startswith("not observable")
    assert why["gyro_g_sensitivity[zz]"].startswith("dropped") and why["gyro_g_sensitivity[zx]"].startswith("not signif")
    clause = intrinsics_clause({"intrinsics": {"method": "alternating", **table}})
    assert "2 terms estimated (1 gyro scale/misalignment, 1 gyro g-sensitivity" in clause
    assert "25 terms could not be told from the bias" in clause and "acc_scale_misalignment[zz]" in clause
    assert "its sigma includes them" in clause


def test_the_report_says_which_path_ran():
    validation = {"reference": {"kind": "state"}, "config": {"window_s": 1.0}, "windows_dropped": {"kept": 10}}
    off = checked_and_not(validation, {"intrinsics_auto": {"estimated": False, "coupling": "none",
                                                          "reason": "no axis of the gyro follows another's rate"}})[-1]
    assert "not estimated: no axis of the gyro follows another's rate; any the IMU has, the bias absorbs" in off
    assert "not modelled" not in off
    assert "turned off" in checked_and_not(validation, {})[-1]
    assert "unknown" in checked_and_not(validation)[-1]
    positions = {"intrinsics": {"method": "not estimated", "reason": "pose stream 'x' has positions only"}}
    assert "not estimated: pose stream 'x' has positions only" in checked_and_not(validation, positions)[-1]
    none_left = {"intrinsics": {"method": "alternating", "estimated": [{"term": "acc_scale_misalignment[yy]"}],
                                "absorbed_by_bias": []}}
    assert "none was left to the bias" in checked_and_not(validation, none_left)[-1]


def test_calibration_agreement_of_the_accelerometer_rotation():
    """The antisymmetric part of ``S_a`` is the rotation from the solve's IMU frame to the accelerometer's:
    with the solve's extrinsic turned by ``dtheta`` from the file's, an accelerometer rotation of
    ``-R dtheta`` (within its sigma) agrees with the file; one 1 deg away does not; no file, no answer."""
    from scipy.spatial.transform import Rotation

    from recovery.intrinsics.frame import calibration_agreement

    R = Rotation.from_rotvec([0.1, -0.2, 0.3])
    dtheta_deg = np.array([0.3, -0.2, 0.1])
    report = {"extrinsic": {"mode": "prior", "difference_from_calibration": {"rotation_vector_deg": dtheta_deg.tolist()}},
              "T_imu_pose": {"quat_wxyz": np.roll(R.as_quat(), 1).tolist()}}
    phi = -R.as_matrix() @ np.radians(dtheta_deg)
    S = np.array([[0.004, -phi[2], phi[1]], [phi[2], -0.002, -phi[0]], [-phi[1], phi[0], 0.001]])  # scale + [phi]x
    cov = np.eye(9) * (1.5e-3) ** 2
    noise = np.array([[0, 1e-3, -5e-4], [0, 0, 1e-3], [5e-4, 0, 0]])
    held = calibration_agreement(S + noise, cov, report)
    assert held["agrees"] and held["mahalanobis_sq"] < 3
    np.testing.assert_allclose(held["calibration_rotation_rad"], phi)
    off = S.copy()
    off[0, 2] += np.radians(1.0)  # 1 deg more about y (half of it in the antisymmetric part)
    off[2, 0] -= np.radians(1.0)
    assert not calibration_agreement(off, cov, report)["agrees"]
    assert calibration_agreement(S, cov, {**report, "extrinsic": {"mode": "known"}}) is None


def test_chi2_quantile_is_scipy_stats_chi2_ppf() -> None:
    from scipy.stats import chi2

    from recovery.intrinsics.frame import chi2_quantile

    for q, dof in ((0.997, 3), (0.5, 1), (0.95, 6)):
        assert chi2_quantile(q, dof) == pytest.approx(chi2.ppf(q, dof), rel=1e-10)
