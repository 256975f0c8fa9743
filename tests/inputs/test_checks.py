"""Input checks and repairs on small synthetic sequences: one malformed input per check."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from synth import T0_NS, make_imu, make_poses, make_sequence

from pipeline.checks.options import CHECK_CODES, CheckOptions, Repair
from pipeline.checks.repairs import apply_repairs, parse_repairs
from pipeline.checks.run import STREAM_SUMMARY_KEYS, fatal_findings, run_checks, stream_summaries, verdict
from pipeline.errors import ConfigError
from pipeline.types import NS_PER_S, Finding, ImuSeries, Sequence, Severity, StateSeries, Verdict


def by_code(findings: list[Finding], code: str, stream: str | None = None) -> list[Finding]:
    return [f for f in findings if f.code == code and (stream is None or f.stream == stream)]


def one(findings: list[Finding], code: str, stream: str | None = None) -> Finding:
    hits = by_code(findings, code, stream)
    assert len(hits) == 1, (code, [f.to_dict() for f in findings])
    return hits[0]


def with_imu(seq: Sequence, **arrays) -> Sequence:
    imu = seq.imu
    assert imu is not None
    new = ImuSeries(arrays.get("t_ns", imu.t_ns), arrays.get("gyro", imu.gyro_radps), arrays.get("acc", imu.acc_mps2))
    return replace(seq, imu=new)


def with_pose(seq: Sequence, **arrays) -> Sequence:
    p = seq.poses["vicon0"]
    return replace(seq, poses={"vicon0": replace(p, **arrays)})


# ------------------------------------------------------------------------------------------ clean input


def test_clean_sequence_has_only_rate_info():
    findings = run_checks(make_sequence())
    assert [(f.code, f.stream) for f in findings] == [("RATE", "imu"), ("RATE", "poses/vicon0")]
    rate = findings[0].details
    assert rate["rate_hz"] == pytest.approx(200.0)
    assert rate["nominal_period_ms"] == pytest.approx(5.0)
    assert rate["dt_max_ms"] == pytest.approx(5.0)
    assert verdict(findings) is Verdict.PASS
    json.dumps([f.to_dict() for f in findings], allow_nan=False)  # details are plain JSON


def test_reader_findings_come_first_and_check_findings_are_not_repeated():
    seq = make_sequence()
    reader = Finding("PARSE_SKIPPED_LINES", Severity.WARNING, "imu", "skipped 7 lines", {"count": 7})
    stale = Finding("RATE", Severity.INFO, "imu", "from an earlier run", {})
    seq.findings = [reader, stale]
    findings = run_checks(seq)
    assert findings[0] == reader
    assert len(by_code(findings, "RATE", "imu")) == 1
    assert stale not in findings
    assert "PARSE_SKIPPED_LINES" not in CHECK_CODES


# ------------------------------------------------------------------------------------------ time stamps


def test_non_monotonic_reported_and_sorted():
    seq = make_sequence()
    t = seq.imu.t_ns.copy()
    gyro = seq.imu.gyro_radps.copy()
    t[[100, 101]] = t[[101, 100]]
    gyro[[100, 101]] = gyro[[101, 100]]
    t[[500, 502]] = t[[502, 500]]
    gyro[[500, 502]] = gyro[[502, 500]]
    bad = with_imu(seq, t_ns=t, gyro=gyro)
    f = one(run_checks(bad), "NON_MONOTONIC", "imu")
    assert f.severity is Severity.REPAIRABLE
    assert f.details["count"] == 3  # rows 101, 501 and 502 are earlier than their predecessors
    assert f.details["first_rows"] == [101, 501, 502]
    assert f.details["max_backward_s"] == pytest.approx(0.005)
    assert f.details["first_t_s"][0] == pytest.approx(0.5)  # row 101 holds the stamp of row 100: 0.5 s
    assert "--repair sort" in f.message
    assert verdict(run_checks(bad)) is Verdict.WARN
    fixed, changes = apply_repairs(bad, {Repair.SORT})
    np.testing.assert_array_equal(fixed.imu.t_ns, seq.imu.t_ns)
    np.testing.assert_array_equal(fixed.imu.gyro_radps, seq.imu.gyro_radps)
    assert changes == ["imu: sorted 2000 rows by time (3 backward steps)"]
    assert fixed.metadata["repairs"] == changes
    assert not by_code(run_checks(fixed), "NON_MONOTONIC")
    assert bad.imu.t_ns[100] != seq.imu.t_ns[100]  # the input is not modified


def test_duplicate_stamps_reported_and_first_kept():
    seq = make_sequence()
    imu = seq.imu
    idx = np.insert(np.arange(len(imu)), [10, 20, 20], [10, 20, 20])  # row 10 once more, row 20 twice more
    t = imu.t_ns[idx]
    gyro = imu.gyro_radps[idx].copy()
    gyro[11] += 1.0  # the repeated row differs: the first one must win
    bad = with_imu(seq, t_ns=t, gyro=gyro, acc=imu.acc_mps2[idx])
    f = one(run_checks(bad), "DUPLICATE_STAMPS", "imu")
    assert f.severity is Severity.REPAIRABLE
    assert f.details["count"] == 3
    assert f.details["first_t_s"] == pytest.approx([0.05, 0.1, 0.1])
    assert not by_code(run_checks(bad), "NON_MONOTONIC")
    fixed, changes = apply_repairs(bad, {"drop-duplicates"})
    np.testing.assert_array_equal(fixed.imu.t_ns, imu.t_ns)
    np.testing.assert_array_equal(fixed.imu.gyro_radps, imu.gyro_radps)
    assert changes == ["imu: dropped 3 rows with repeated stamps (kept the first)"]


def test_duplicates_without_sort_keep_first_occurrence_in_file_order():
    t = np.array([0, 10, 5, 10, 20], dtype=np.int64) * 1_000_000 + T0_NS
    imu = ImuSeries(t, np.arange(15.0).reshape(5, 3), np.tile([0, 0, 9.81], (5, 1)))
    seq = Sequence("x", imu=imu)
    fixed, _ = apply_repairs(seq, {Repair.DROP_DUPLICATES})
    np.testing.assert_array_equal(fixed.imu.t_ns - T0_NS, np.array([0, 10, 5, 20]) * 1_000_000)
    np.testing.assert_array_equal(fixed.imu.gyro_radps[:, 0], [0, 3, 6, 12])
    both, _ = apply_repairs(seq, {Repair.DROP_DUPLICATES, Repair.SORT})
    np.testing.assert_array_equal(both.imu.t_ns - T0_NS, np.array([0, 5, 10, 20]) * 1_000_000)
    np.testing.assert_array_equal(both.imu.gyro_radps[:, 0], [0, 6, 3, 12])


def test_gaps_listed_with_relative_start_and_duration():
    seq = make_sequence()
    keep = np.ones(len(seq.imu), dtype=bool)
    keep[400:600] = False  # 1 s missing after t = 1.995 s
    keep[1000:1002] = False  # 15 ms step: 3x the period
    bad = replace(seq, imu=seq.imu.take(keep))
    f = one(run_checks(bad), "GAPS", "imu")
    assert f.severity is Severity.WARNING
    assert f.details["count"] == 2
    assert f.details["nominal_period_ms"] == pytest.approx(5.0)
    g0, g1 = f.details["gaps"]
    assert g0["start_t_s"] == pytest.approx(1.995)
    assert g0["duration_s"] == pytest.approx(1.005)
    assert g0["start_t_ns"] == int(seq.imu.t_ns[399])
    assert g1["start_t_s"] == pytest.approx(4.995)
    assert g1["duration_s"] == pytest.approx(0.015)
    assert f.details["total_gap_s"] == pytest.approx(1.02)
    # a 10-ms step is exactly 2x: not a gap with the default factor, a gap with 1.5
    keep2 = np.ones(len(seq.imu), dtype=bool)
    keep2[300] = False
    small = replace(seq, imu=seq.imu.take(keep2))
    assert not by_code(run_checks(small), "GAPS")
    assert one(run_checks(small, CheckOptions(gap_factor=1.5)), "GAPS").details["count"] == 1


def test_rate_reports_nominal_rate_and_jitter():
    seq = make_sequence()
    rng = np.random.default_rng(1)
    t = seq.imu.t_ns + rng.integers(-100_000, 100_001, len(seq.imu))  # +-0.1 ms jitter
    f = one(run_checks(with_imu(seq, t_ns=t)), "RATE", "imu")
    assert f.severity is Severity.INFO
    assert f.details["rate_hz"] == pytest.approx(200.0, rel=1e-3)
    assert 0.05 < f.details["dt_std_ms"] < 0.1  # std of a difference of two U(-0.1, 0.1) ms: 0.0816
    assert 5.1 < f.details["dt_max_ms"] <= 5.2
    assert 4.8 <= f.details["dt_min_ms"] < 4.9


# ------------------------------------------------------------------------------------------ values


def test_nonfinite_rows_reported_and_dropped():
    seq = make_sequence()
    gyro = seq.imu.gyro_radps.copy()
    acc = seq.imu.acc_mps2.copy()
    gyro[5, 1] = np.nan
    acc[7, 2] = np.inf
    p = seq.poses["vicon0"]
    q = p.quat_wxyz.copy()
    q[3] = 0.0  # a zero quaternion is no rotation at all
    pos = p.p_m.copy()
    pos[8, 0] = np.nan
    bad = with_pose(with_imu(seq, gyro=gyro, acc=acc), quat_wxyz=q, p_m=pos)
    findings = run_checks(bad)
    fi = one(findings, "NONFINITE_ROWS", "imu")
    assert fi.severity is Severity.REPAIRABLE
    assert fi.details == {"count": 2, "first_rows": [5, 7]}
    fp = one(findings, "NONFINITE_ROWS", "poses/vicon0")
    assert fp.details == {"count": 2, "first_rows": [3, 8]}
    fixed, changes = apply_repairs(bad, {Repair.DROP_NONFINITE})
    assert len(fixed.imu) == len(seq.imu) - 2
    assert len(fixed.poses["vicon0"]) == len(p) - 2
    assert np.isfinite(fixed.imu.imu_6).all()
    assert 5 not in (fixed.imu.t_ns - T0_NS) // 5_000_000  # the row at 25 ms is gone
    assert changes[0] == "imu: dropped 2 rows with non-finite values or zero quaternions"
    assert not by_code(run_checks(fixed), "NONFINITE_ROWS")
    all_bad = with_imu(seq, gyro=np.full_like(gyro, np.nan))
    f = one(run_checks(all_bad), "NONFINITE_ROWS", "imu")
    assert f.severity is Severity.FATAL and f.details["count"] == 2000


def test_gyro_degps_pose_rule_and_repair():
    seq = make_sequence()
    bad = with_imu(seq, gyro=np.degrees(seq.imu.gyro_radps))
    f = one(run_checks(bad), "GYRO_DEGPS", "imu")
    assert f.severity is Severity.REPAIRABLE
    assert f.details["rule"] == "pose_rate_ratio"
    assert f.details["pose_stream"] == "poses/vicon0"
    assert 40 < f.details["ratio"] < 90
    fixed, changes = apply_repairs(bad, {Repair.GYRO_DEG_TO_RAD})
    np.testing.assert_allclose(fixed.imu.gyro_radps, seq.imu.gyro_radps, rtol=1e-12)
    assert changes == ["imu: scaled gyro by pi/180 (deg/s to rad/s, rule pose_rate_ratio; 2000 rows)"]
    assert not by_code(run_checks(fixed), "GYRO_DEGPS")


def test_gyro_degps_range_rule_without_poses():
    imu = make_imu()
    bad = Sequence("x", imu=ImuSeries(imu.t_ns, np.degrees(imu.gyro_radps), imu.acc_mps2))
    f = one(run_checks(bad), "GYRO_DEGPS")
    assert f.details["rule"] == "p99_magnitude"
    assert f.details["gyro_p99"] > 35
    assert not by_code(run_checks(Sequence("x", imu=imu)), "GYRO_DEGPS")


def test_gyro_degps_static_rule():
    rng = np.random.default_rng(3)
    n = 2000
    t = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    bias = np.array([0.02, -0.03, 0.04])  # rad/s: |b| = 0.054 rad/s = 3.1 deg/s
    gyro_rad = bias + rng.normal(0, 0.003, (n, 3))
    acc = np.array([0.1, 0.2, 9.8]) + rng.normal(0, 0.02, (n, 3))
    ok = Sequence("x", imu=ImuSeries(t, gyro_rad, acc))
    assert not by_code(run_checks(ok), "GYRO_DEGPS")
    bad = Sequence("x", imu=ImuSeries(t, np.degrees(gyro_rad), acc))
    f = one(run_checks(bad), "GYRO_DEGPS")
    assert f.details["rule"] == "static_magnitude"
    assert f.details["static_gyro_magnitude"] == pytest.approx(np.degrees(np.linalg.norm(bias)), rel=0.05)
    assert f.details["static_seconds"] == pytest.approx(10.0)


def test_pose_rule_overrides_range_rule():
    seq = make_sequence()
    # the same motion 40x faster: |gyro| beyond 35 rad/s, but the poses turn just as fast -> rad/s
    imu, poses = seq.imu, seq.poses["vicon0"]
    fast_imu = ImuSeries(T0_NS + (imu.t_ns - T0_NS) // 40, imu.gyro_radps * 40, imu.acc_mps2)
    fast_poses = replace(poses, t_ns=T0_NS + (poses.t_ns - T0_NS) // 40)
    assert np.percentile(np.linalg.norm(fast_imu.gyro_radps, axis=1), 99) > 35
    fast = Sequence("fast", imu=fast_imu, poses={"vicon0": fast_poses})
    assert not by_code(run_checks(fast), "GYRO_DEGPS")
    assert one(run_checks(Sequence("x", imu=fast_imu)), "GYRO_DEGPS").details["rule"] == "p99_magnitude"
    # a 40x gyro against poses that turn at ~1 rad/s is flagged by the pose rule
    slow_poses = Sequence("x", imu=ImuSeries(imu.t_ns, imu.gyro_radps * 40, imu.acc_mps2), poses={"vicon0": poses})
    assert one(run_checks(slow_poses), "GYRO_DEGPS").details["rule"] == "pose_rate_ratio"


def test_acc_in_g_reported_and_scaled():
    seq = make_sequence()
    bad = with_imu(seq, acc=seq.imu.acc_mps2 / 9.80665)
    f = one(run_checks(bad), "ACC_IN_G")
    assert f.severity is Severity.REPAIRABLE
    assert f.details["median_norm"] == pytest.approx(1.0, abs=0.05)
    assert not by_code(run_checks(bad), "ACC_SCALE_SUSPECT")
    fixed, changes = apply_repairs(bad, {Repair.ACC_G_TO_MPS2})
    np.testing.assert_allclose(fixed.imu.acc_mps2, seq.imu.acc_mps2, rtol=1e-12)
    assert changes == ["imu: scaled accelerometer by 9.80665 (g to m/s^2; 2000 rows)"]


def test_gravity_removed_acc_is_suspect_not_in_g():
    seq = make_sequence()
    lin = seq.imu.acc_mps2 - np.array([0, 0, 9.81])
    findings = run_checks(with_imu(seq, acc=lin))
    assert not by_code(findings, "ACC_IN_G")
    f = one(findings, "ACC_SCALE_SUSPECT")
    assert f.severity is Severity.WARNING
    assert f.details["median_norm"] < 1.0


def test_unit_repairs_leave_correct_data_alone():
    seq = make_sequence()
    fixed, changes = apply_repairs(seq, parse_repairs("all"))
    assert changes == []
    np.testing.assert_array_equal(fixed.imu.gyro_radps, seq.imu.gyro_radps)
    np.testing.assert_array_equal(fixed.imu.acc_mps2, seq.imu.acc_mps2)
    assert fixed.metadata["repairs"] == []


def test_saturation_flat_top_reported():
    seq = make_sequence()
    gyro = seq.imu.gyro_radps.copy()
    gyro[:, 0] = np.clip(gyro[:, 0], -0.5, 0.5)
    f = one(run_checks(with_imu(seq, gyro=gyro)), "SATURATION")
    assert f.severity is Severity.WARNING
    assert list(f.details["axes"]) == ["gyro_x"]
    ax = f.details["axes"]["gyro_x"]
    assert ax["value"] == pytest.approx(0.5)
    assert ax["count"] == int((np.abs(gyro[:, 0]) >= 0.5).sum())
    assert ax["count"] > 100


def test_saturation_not_flagged_on_smooth_or_quantised_signals():
    seq = make_sequence()
    assert not by_code(run_checks(seq), "SATURATION")
    # quantised static data: the top level is hit often, but so are the levels just below
    rng = np.random.default_rng(5)
    n = 4000
    t = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    lsb = 0.0007
    gyro = np.round(rng.normal(0, 0.0015, (n, 3)) / lsb) * lsb
    acc = np.round((np.array([0, 0, 9.81]) + rng.normal(0, 0.02, (n, 3))) / 0.0024) * 0.0024
    assert not by_code(run_checks(Sequence("q", imu=ImuSeries(t, gyro, acc))), "SATURATION")


# ------------------------------------------------------------------------------------------ quaternions


def test_quat_not_unit_reported_and_normalised():
    seq = make_sequence()
    q = seq.poses["vicon0"].quat_wxyz.copy()
    q[10:20] *= 1.01
    bad = with_pose(seq, quat_wxyz=q)
    f = one(run_checks(bad), "QUAT_NOT_UNIT", "poses/vicon0")
    assert f.severity is Severity.REPAIRABLE
    assert f.details["max_deviation"] == pytest.approx(0.01, rel=1e-6)
    assert f.details["count"] == 10
    fixed, changes = apply_repairs(bad, {Repair.NORMALISE_QUATERNIONS})
    np.testing.assert_allclose(fixed.poses["vicon0"].quat_wxyz, seq.poses["vicon0"].quat_wxyz, atol=1e-12)
    assert changes == ["poses/vicon0: normalised quaternions (max norm deviation 0.01; 10 rows beyond 0.001)"]
    # 6-decimal rounding is within tolerance
    rounded = with_pose(seq, quat_wxyz=np.round(seq.poses["vicon0"].quat_wxyz, 6))
    assert not by_code(run_checks(rounded), "QUAT_NOT_UNIT")


def test_quat_sign_flips_info_and_made_continuous():
    seq = make_sequence()
    q = seq.poses["vicon0"].quat_wxyz.copy()
    q[100:200] *= -1
    q[500:] *= -1
    bad = with_pose(seq, quat_wxyz=q)
    f = one(run_checks(bad), "QUAT_SIGN_FLIPS", "poses/vicon0")
    assert f.severity is Severity.INFO
    assert f.details["count"] == 3
    assert verdict(run_checks(bad)) is Verdict.PASS
    fixed, changes = apply_repairs(bad, {Repair.CONTINUOUS_QUATERNIONS})
    np.testing.assert_allclose(fixed.poses["vicon0"].quat_wxyz, seq.poses["vicon0"].quat_wxyz)
    assert changes == ["poses/vicon0: made quaternions continuous (3 sign flips)"]


def test_ground_truth_stream_is_checked_and_repaired():
    seq = make_sequence()
    p = seq.poses["vicon0"]
    n = len(p)
    q = p.quat_wxyz.copy()
    q[0] *= 1.1
    t = p.t_ns.copy()
    t[[4, 5]] = t[[5, 4]]
    gt = StateSeries(t, p.p_m, q, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)))
    seq = replace(seq, ground_truth=gt)
    findings = run_checks(seq)
    assert one(findings, "NON_MONOTONIC", "ground_truth").details["count"] == 1
    assert one(findings, "QUAT_NOT_UNIT", "ground_truth").details["max_deviation"] == pytest.approx(0.1)
    fixed, _ = apply_repairs(seq, {Repair.SORT, Repair.NORMALISE_QUATERNIONS})
    np.testing.assert_array_equal(fixed.ground_truth.t_ns, p.t_ns)
    np.testing.assert_allclose(np.linalg.norm(fixed.ground_truth.quat_wxyz, axis=1), 1.0)


# ------------------------------------------------------------------------------------------ cross-stream


def test_no_time_overlap_fatal_and_warning_when_another_stream_overlaps():
    late = make_poses(t0_ns=T0_NS + 100 * NS_PER_S)
    seq = Sequence("x", imu=make_imu(), poses={"late": late})
    f = one(run_checks(seq), "NO_TIME_OVERLAP", "poses/late")
    assert f.severity is Severity.FATAL
    assert f.details["offset_s"] == pytest.approx(100.0)
    assert f.details["overlap_s"] == 0
    assert verdict(run_checks(seq)) is Verdict.FAIL
    seq.poses["vicon0"] = make_poses()
    f2 = one(run_checks(seq), "NO_TIME_OVERLAP", "poses/late")
    assert f2.severity is Severity.WARNING
    assert not fatal_findings(run_checks(seq))


def test_clock_mismatch_fatal_for_boot_vs_epoch_and_warning_for_small_overlap():
    boot = make_poses(t0_ns=5 * NS_PER_S)  # seconds since boot
    seq = Sequence("x", imu=make_imu(), poses={"vicon0": boot})
    f = one(run_checks(seq), "CLOCK_MISMATCH", "poses/vicon0")
    assert f.severity is Severity.FATAL
    assert f.details["stream_t0_s"] == pytest.approx(5.0)
    assert "different clocks" in f.message
    assert not by_code(run_checks(seq), "NO_TIME_OVERLAP")
    shifted = make_poses(t0_ns=T0_NS + 7 * NS_PER_S)  # 3 s of 10 s overlap
    f2 = one(run_checks(Sequence("x", imu=make_imu(), poses={"vicon0": shifted})), "CLOCK_MISMATCH")
    assert f2.severity is Severity.WARNING
    assert f2.details["overlap_fraction"] == pytest.approx(0.3, abs=0.002)
    assert f2.details["overlap_s"] == pytest.approx(2.995)


def test_too_short_fatal_and_configurable():
    seq = make_sequence(duration_s=1.5)
    f = one(run_checks(seq), "TOO_SHORT", "imu")
    assert f.severity is Severity.FATAL
    assert f.details["duration_s"] == pytest.approx(1.495)
    assert not by_code(run_checks(seq, CheckOptions(min_duration_s=1.0)), "TOO_SHORT")


def test_no_imu_fatal_unless_pose_only_allowed():
    seq = Sequence("x", poses={"vicon0": make_poses()})
    f = one(run_checks(seq), "NO_IMU")
    assert f.severity is Severity.FATAL
    assert "--allow-pose-only" in f.message
    g = one(run_checks(seq, CheckOptions(allow_pose_only=True)), "NO_IMU")
    assert g.severity is Severity.INFO
    assert verdict(run_checks(seq, CheckOptions(allow_pose_only=True))) is Verdict.PASS


def test_no_poses_warning():
    f = one(run_checks(Sequence("x", imu=make_imu())), "NO_POSES")
    assert f.severity is Severity.WARNING


def test_empty_stream_fatal():
    empty_imu = ImuSeries(np.empty(0, np.int64), np.empty((0, 3)), np.empty((0, 3)))
    seq = Sequence("x", imu=empty_imu, poses={"vicon0": make_poses()})
    f = one(run_checks(seq), "EMPTY_STREAM", "imu")
    assert f.severity is Severity.FATAL
    assert f.details == {"count": 0}
    empty_pose = make_poses().take(slice(0, 1))
    only = Sequence("x", imu=make_imu(), poses={"vicon0": empty_pose})
    assert one(run_checks(only), "EMPTY_STREAM", "poses/vicon0").severity is Severity.FATAL
    two = Sequence("x", imu=make_imu(), poses={"vicon0": make_poses(), "empty": empty_pose})
    assert one(run_checks(two), "EMPTY_STREAM", "poses/empty").severity is Severity.WARNING


# ------------------------------------------------------------------------------------------ helpers


def test_ignore_demotes_non_fatal_findings_only():
    imu = make_imu()
    bad = Sequence("x", imu=ImuSeries(imu.t_ns[:200], np.degrees(imu.gyro_radps[:200]), imu.acc_mps2[:200]))
    findings = run_checks(bad, CheckOptions(ignore=frozenset({"gyro_degps", "TOO_SHORT"}), min_duration_s=2.0))
    g = one(findings, "GYRO_DEGPS")
    assert g.severity is Severity.INFO and g.details["ignored"] is True and g.details["severity"] == "repairable"
    assert one(findings, "TOO_SHORT").severity is Severity.FATAL
    fixed, changes = apply_repairs(bad, {Repair.GYRO_DEG_TO_RAD}, CheckOptions(ignore=frozenset({"GYRO_DEGPS"})))
    assert changes == []


def test_check_options_ignore_accepts_a_comma_string():
    assert CheckOptions(ignore="gyro_degps, SATURATION").ignore == frozenset({"GYRO_DEGPS", "SATURATION"})


def test_parse_repairs():
    assert parse_repairs("sort, drop-duplicates") == {Repair.SORT, Repair.DROP_DUPLICATES}
    assert parse_repairs("all") == set(Repair)
    assert parse_repairs("") == set() and parse_repairs(None) == set() and parse_repairs("none") == set()
    assert parse_repairs(["GYRO_DEG_TO_RAD", Repair.SORT]) == {Repair.GYRO_DEG_TO_RAD, Repair.SORT}
    with pytest.raises(ConfigError, match="unknown repair 'sorted'"):
        parse_repairs("sorted")


def test_check_options_validated():
    with pytest.raises(ConfigError):
        CheckOptions(gap_factor=1.0)
    with pytest.raises(ConfigError):
        CheckOptions(min_duration_s=-1)


def test_stream_summaries_keys_and_values():
    seq = make_sequence()
    rows = stream_summaries(seq)
    assert [r["stream"] for r in rows] == ["imu", "poses/vicon0"]
    for r in rows:
        assert tuple(r) == STREAM_SUMMARY_KEYS
    imu, pose = rows
    assert imu["kind"] == "imu" and imu["count"] == 2000
    assert imu["t0_ns"] == T0_NS and imu["t1_ns"] == T0_NS + 1999 * 5_000_000
    assert imu["duration_s"] == pytest.approx(9.995)
    assert imu["rate_hz"] == pytest.approx(200.0)
    assert imu["dt_std_ms"] == pytest.approx(0.0) and imu["dt_max_ms"] == pytest.approx(5.0)
    assert imu["frame"] is None and imu["has_orientation"] is False
    assert pose["kind"] == "poses" and pose["frame"] == "vicon_marker" and pose["source_kind"] == "mocap"
    assert pose["rate_hz"] == pytest.approx(100.0) and pose["has_orientation"] is True
    json.dumps(rows, allow_nan=False)


def test_all_repairs_together_give_a_clean_sequence():
    seq = make_sequence()
    imu = seq.imu
    idx = np.concatenate([np.arange(len(imu)), [7, 9]])
    rng = np.random.default_rng(0)
    idx = idx[rng.permutation(len(idx))]
    gyro = np.degrees(imu.gyro_radps[idx])
    acc = imu.acc_mps2[idx] / 9.80665
    gyro[idx == 50] = np.nan
    bad = with_imu(seq, t_ns=imu.t_ns[idx], gyro=gyro, acc=acc)
    codes = {f.code for f in run_checks(bad)}
    assert {"NON_MONOTONIC", "DUPLICATE_STAMPS", "NONFINITE_ROWS", "GYRO_DEGPS", "ACC_IN_G"} <= codes
    fixed, changes = apply_repairs(bad, {"all"})
    assert verdict(run_checks(fixed)) is Verdict.PASS
    expected = np.delete(np.arange(len(imu)), 50)
    np.testing.assert_array_equal(fixed.imu.t_ns, imu.t_ns[expected])
    np.testing.assert_allclose(fixed.imu.gyro_radps, imu.gyro_radps[expected], rtol=1e-12)
    np.testing.assert_allclose(fixed.imu.acc_mps2, imu.acc_mps2[expected], rtol=1e-12)
    assert len(changes) == 5


def test_checks_on_one_hour_at_200_hz():
    """One hour at 200 Hz passes the checks (their speed: benchmarks/pipeline/ingest.py)."""
    n = 720_000
    rng = np.random.default_rng(0)
    t = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    t_s = np.arange(n) / 200.0
    gyro = 0.5 * np.sin(np.outer(t_s, [0.3, 0.7, 1.1])) + rng.normal(0, 0.003, (n, 3))
    acc = np.array([0, 0, 9.81]) + 0.5 * np.cos(np.outer(t_s, [0.2, 0.5, 0.9])) + rng.normal(0, 0.03, (n, 3))
    poses = make_poses(duration_s=3600.0, rate_hz=100.0)
    seq = Sequence("hour", imu=ImuSeries(t, gyro, acc), poses={"vicon0": poses})
    findings = run_checks(seq)
    assert verdict(findings) is Verdict.PASS
    assert math.isfinite(one(findings, "RATE", "imu").details["rate_hz"])
