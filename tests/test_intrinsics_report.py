"""What the recovery says of the IMU intrinsics (recovery.intrinsics_report) and the sigma of the terms it left out."""

from __future__ import annotations

import numpy as np

from recovery.intrinsics import TERM_PRIOR, ImuIntrinsics, IntrinsicsFit, intrinsics_bias_variance
from recovery.intrinsics_report import intrinsics_clause, term_table
from reports.quality_verdict import checked_and_not

GROUPS = ("gyro_scale_misalignment", "acc_scale_misalignment", "gyro_g_sensitivity")


def test_terms_left_out_are_covered_on_average():
    """A term the fit left out (not significant) is still in the readings: over terms drawn at the
    datasheet size and fit estimates drawn around them with the fit's sigma, the bias error it causes
    has, on average, the variance the function reports (NEES 1), whether the fit sees the term well
    (sigma << prior) or hardly (sigma >> prior)."""
    rng = np.random.default_rng(5)
    tau = TERM_PRIOR["gyro_g_sensitivity"]
    f = np.array([[0.3, -0.2, 9.81]])  # one keyframe: the G[z, z] term times f_z ~ g is a constant gyro z offset
    omega = np.zeros((1, 3))
    for sigma in (0.3 * tau, 3.0 * tau):
        cov = {"rotation": np.diag(np.r_[np.full(9, 1e-12), np.full(9, sigma**2)]), "velocity": np.eye(9) * 1e-12}
        fit = IntrinsicsFit(ImuIntrinsics.identity(), {}, {}, {}, GROUPS, None, cov)
        none = {g: np.zeros((3, 3), bool) for g in GROUPS}
        ratios = []
        for _ in range(1500):
            true = rng.normal(0.0, tau)
            left = {g: np.zeros((3, 3)) for g in GROUPS}
            left["gyro_g_sensitivity"][2, 2] = true + rng.normal(0.0, sigma)
            var = intrinsics_bias_variance(fit, none, omega, f, left=left)[0, 2]
            ratios.append((true * f[0, 2]) ** 2 / var)
        assert 0.85 < np.mean(ratios) < 1.15, (sigma, np.mean(ratios))


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
