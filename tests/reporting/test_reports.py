"""Tests of the quality report (reports/) and ``biasgt report``, on stage outputs the stages write from a simulation."""

from __future__ import annotations

import functools
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from biasgt.cli.app import main as cli_main
from pipeline.errors import DataError, InputFormatError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind
from reports.html import fmt
from recovery.noise.allan import allan_deviation, fit_noise_parameters, imu_allan, white_noise_upper_bound
from reports.quality import SECTIONS, build_quality_report, mm_pair, flagged_stretches, gravity_tilt_deg, pose_residuals, \
    other_estimates_sentence, stage_dirs, verdict_summary

SEQ = "simseq"
CLOCK_OFFSET_S = 0.012345
OUTLIERS = 3  # pose samples displaced by 10 cm


@functools.lru_cache(maxsize=1)
def _simulation(duration_s: float = 20.0):
    from pipeline.sim import PoseStreamConfig, SimConfig, simulate

    return simulate(SimConfig(duration_s=duration_s, seed=3, name=SEQ,
                              poses=PoseStreamConfig(clock_offset_s=CLOCK_OFFSET_S, extrinsic_rotation_deg=5.0,
                                                     extrinsic_translation_m=0.05, outliers=OUTLIERS)))


def _run_stages(root: Path) -> Path:
    """``root/results`` written by the stages themselves from one simulated sequence: the simulator's
    EuRoC folder (two IMU rows swapped) -> ingest with the sort repair -> recover -> validate (flag
    threshold 1.5 x the median error, so that the flagged-window table has rows)."""
    from pipeline.ingest import ingest
    from pipeline.sim import write_simulation
    from recovery.recover import recover, write_recovery
    from validation.validate import ValidationConfig, validate_inputs, write_validation

    raw = write_simulation(_simulation(), root / "raw")
    imu_csv = next(raw.rglob("imu0/data.csv"))
    lines = imu_csv.read_text(encoding="utf-8").splitlines(keepends=True)
    lines[10], lines[11] = lines[11], lines[10]
    imu_csv.write_text("".join(lines), encoding="utf-8")
    results = root / "results"
    seq = ingest(raw, results / "ingest" / SEQ, repairs=["sort"], reader_kwargs={"name": SEQ})
    write_recovery(recover(seq), results / "recovery" / SEQ)
    validation = validate_inputs(seq, recovery_dir=results / "recovery" / SEQ, config=ValidationConfig(flag_k=1.5))
    write_validation(validation, results / "validation" / SEQ)
    return results


@pytest.fixture(scope="module")
def stage_outputs(tmp_path_factory) -> Path:
    return _run_stages(tmp_path_factory.mktemp("stages"))


def write_stage_outputs(src: Path, root: Path, *, recovery: bool = True, validation: bool = True) -> Path:
    """A copy of the stage outputs ``src`` under ``root/results`` (without recovery / validation if asked)."""
    results = root / "results"
    shutil.copytree(src / "ingest", results / "ingest")
    for stage, keep in (("recovery", recovery), ("validation", validation)):
        if keep:
            shutil.copytree(src / stage, results / stage)
    return results


@pytest.fixture(scope="module")
def results_dir(stage_outputs) -> Path:
    return stage_outputs


@pytest.fixture(scope="module")
def recovery_json(results_dir) -> dict:
    return json.loads((results_dir / "recovery" / SEQ / "recovery.json").read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def validation_json(results_dir) -> dict:
    return json.loads((results_dir / "validation" / SEQ / "validation.json").read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def full_report(results_dir) -> str:
    d = stage_dirs(results_dir, SEQ)
    out = build_quality_report(d["ingest"], recovery_dir=d["recovery"], validation_dir=d["validation"],
                               out_path=results_dir / "report" / f"{SEQ}.html")
    return out.read_text(encoding="utf-8")


# ----------------------------------------------------------------------------- Allan deviation


def test_allan_recovers_white_noise_and_random_walk():
    rate, n_density, k_rw = 50.0, 2e-3, 2e-3
    rng = np.random.default_rng(1)
    n = int(3600 * rate)
    x = rng.normal(0, n_density * np.sqrt(rate), (n, 3)) + np.cumsum(rng.normal(0, k_rw / np.sqrt(rate), (n, 3)), 0)
    taus, adev = allan_deviation(x, rate)
    assert adev.shape == (len(taus), 3) and np.all(np.diff(taus) > 0)
    for i in range(3):
        white, rw = fit_noise_parameters(taus, adev[:, i], max_tau_s=360.0)
        assert white == pytest.approx(n_density, rel=0.05)
        assert rw == pytest.approx(k_rw, rel=0.10)


def test_allan_white_noise_curve_and_no_random_walk():
    rate, density = 100.0, 1e-3
    x = np.random.default_rng(2).normal(0, density * np.sqrt(rate), 60_000)
    taus, adev = allan_deviation(x, rate, taus=[0.01, 0.1, 1.0, 10.0])
    np.testing.assert_allclose(taus, [0.01, 0.1, 1.0, 10.0])
    np.testing.assert_allclose(adev, density / np.sqrt(taus), rtol=0.08)  # adev = N / sqrt(tau)
    white, rw = fit_noise_parameters(*allan_deviation(x, rate))
    assert white == pytest.approx(density, rel=0.03)
    assert np.isnan(rw)  # pure white noise: the curve never rises


def test_allan_pools_segments_and_ignores_constants():
    rate = 100.0
    rng = np.random.default_rng(3)
    x = rng.normal(0, 0.01, 20_000)
    x[10_000:] += 5.0  # a different constant (e.g. gravity projection) in the second segment
    taus, pooled = allan_deviation(x, rate, segments=[(0, 10_000), (10_000, 20_000)])
    _, whole = allan_deviation(x, rate)
    assert taus[-1] <= 50.0  # limited by the longest segment (100 s / 2)
    assert pooled[0] == pytest.approx(0.01, rel=0.05)
    assert whole[-1] > 10 * pooled[-1]  # the step dominates when not split
    with pytest.raises(DataError):
        allan_deviation(np.ones((5, 2, 2)), rate)
    with pytest.raises(DataError):
        allan_deviation(np.array([1.0, np.nan, 2.0, 3.0]), rate)


def test_imu_allan_uses_static_segments():
    rate, n = 200.0, 24_000  # 120 s: static, 20 s of rotation, static
    rng = np.random.default_rng(4)
    t = (np.arange(n) * NS_PER_S / rate).astype(np.int64)
    gyro = rng.normal(0, 1e-4 * np.sqrt(rate), (n, 3))
    acc = rng.normal(0, 2e-3 * np.sqrt(rate), (n, 3)) + [0, 0, 9.81]
    moving = slice(10_000, 14_000)
    gyro[moving] += 1.5 * np.sin(np.linspace(0, 40, 4000))[:, None]
    res = imu_allan(ImuSeries(t, gyro, acc))
    assert res.static and len(res.segments_s) == 2
    assert 90 < res.used_s < 100.5
    np.testing.assert_allclose(res.gyro_white, 1e-4, rtol=0.1)
    np.testing.assert_allclose(res.acc_white, 2e-3, rtol=0.1)
    moving_only = imu_allan(ImuSeries(t[moving], gyro[moving], acc[moving]))
    assert not moving_only.static and "no stretch at rest" in " ".join(moving_only.notes)
    assert np.all(moving_only.gyro_white >= 1e-4) and np.all(np.isnan(moving_only.gyro_rw))  # bounds only
    np.testing.assert_allclose(moving_only.acc_white, 2e-3, rtol=0.15)  # acc noise is not hidden by rotation


def test_white_noise_upper_bound_holds_under_motion():
    rate, density = 100.0, 1e-3
    t_s = np.arange(30_000) / rate
    x = np.random.default_rng(5).normal(0, density * np.sqrt(rate), len(t_s)) + 0.5 * np.sin(2 * np.pi * 0.3 * t_s)
    taus, adev = allan_deviation(x, rate)
    bound = white_noise_upper_bound(taus, adev, max_tau_s=30.0)
    assert density <= bound < 1.2 * density  # the shortest cluster times still see mostly white noise


# ----------------------------------------------------------------------------- helpers


def test_gravity_tilt_and_verdict_sentence():
    assert gravity_tilt_deg([0, 0, -9.81]) == pytest.approx(0.0)
    assert gravity_tilt_deg([9.81, 0, 0]) == pytest.approx(90.0)
    v = {"verdict": "PASS", "candidate": "rec", "sources": {
        "rec": {"kind": "recovered", "prmse_m": 0.0077, "roe_deg": 0.01},
        "const": {"kind": "constant_first_window", "prmse_m": 0.01, "roe_deg": 0.02}}}
    word, sentence = verdict_summary(v)
    assert word == "PASS"
    assert sentence.startswith("The recovered bias integrates 23% better than a constant bias")
    assert sentence.endswith("usable for training.")
    v["verdict"], v["sources"]["rec"]["prmse_m"] = "FAIL", 0.0125
    assert "25% worse than a constant bias" in verdict_summary(v)[1]
    assert verdict_summary(None)[0] == "NO VERDICT"


def test_other_estimates_sentence():
    v = {"candidate": "recovered", "gravity_mps2": [0.0, 0.0, -9.81], "sources": {
        "recovered": {"kind": "recovered", "prmse_m": 0.05, "mean_bias": [0, 0, 0, -0.01, 0.55, 0.07]},
        "constant": {"kind": "constant_first_window", "prmse_m": 0.06},
        "openvins": {"kind": "file", "prmse_m": 0.2, "mean_bias": [0, 0, 0, -0.02, 0.15, 0.07]}}}
    text = other_estimates_sentence(v)
    assert "'openvins' integrates to 200 mm, 4x the judged bias's 50 mm" in text
    # |(-0.01, -0.4, 0)| = 0.4001 m/s^2 = 0.04079 rad of a 9.81 m/s^2 gravity
    assert "differs by (-0.010, -0.400, +0.000) m/s^2, what a 2.34-deg tilt" in text
    v["sources"]["recovered_heldout"] = {"kind": "file", "prmse_m": 0.054}
    text = other_estimates_sentence(v)
    assert "'recovered_heldout', the recovery cross-validated by time blocks" in text
    assert "integrates to 54 mm, 1.1x the judged bias's 50 mm: what the recovery is worth on poses" in text
    del v["sources"]["openvins"]
    assert "attitudes agree" not in other_estimates_sentence(v)
    del v["sources"]["recovered_heldout"]
    assert other_estimates_sentence(v) is None


def test_flagged_stretches_merge_consecutive_windows():
    t0 = 1_000_000_000_000
    flagged = [{"t0_ns": t0 + int(k * 0.5e9), "pos_err_m": 0.01 * k, "rot_err_deg": 0.1} for k in (0, 1, 2, 10, 11)]
    flagged.append({"t0_ns": t0 + 30 * NS_PER_S, "pos_err_m": 0.5, "rot_err_deg": 2.0})
    out = flagged_stretches(flagged[::-1], stride_s=0.5)
    assert out == [(t0, t0 + NS_PER_S, 3, 0.02, 0.1), (t0 + 5 * NS_PER_S, t0 + int(5.5e9), 2, 0.11, 0.1),
                   (t0 + 30 * NS_PER_S, t0 + 30 * NS_PER_S, 1, 0.5, 2.0)]


def test_pose_residuals_zero_for_consistent_streams():
    from scipy.spatial.transform import Rotation

    t = (np.arange(200) * NS_PER_S // 100).astype(np.int64)
    rot = Rotation.from_rotvec(np.column_stack([0.3 * np.sin(t / 1e9), 0.2 * np.cos(t / 1e9), t / 1e9]))
    p_wi = np.column_stack([np.sin(t / 1e9), np.cos(t / 1e9), 0.1 * t / 1e9])
    T_ip = np.eye(4)
    T_ip[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    T_ip[:3, 3] = [0.05, -0.02, 0.1]
    # T_world_pose = T_world_imu @ T_imu_pose; pose stamps are 5 ms behind the IMU clock
    R_wp = rot * Rotation.from_matrix(T_ip[:3, :3])
    p_wp = p_wi + rot.apply(T_ip[:3, 3])
    traj = PoseSeries(t, p_wi, rot.as_quat(scalar_first=True), "imu", PoseSourceKind.GROUND_TRUTH)
    poses = PoseSeries(t - 5_000_000, p_wp, R_wp.as_quat(scalar_first=True), "marker", PoseSourceKind.MOCAP)
    tq, pos, ang = pose_residuals(traj, poses, T_ip, 0.005)
    assert len(tq) == 200
    assert np.max(pos) < 1e-9 and np.max(ang) < 1e-6
    leica = PoseSeries(t - 5_000_000, p_wp, None, "prism", PoseSourceKind.POSITION_TRACKER)
    _, pos2, ang2 = pose_residuals(traj, leica, T_ip, 0.005)
    assert ang2 is None and np.max(pos2) < 1e-9


# ----------------------------------------------------------------------------- full report


def test_report_is_self_contained(full_report):
    assert full_report.startswith("<!DOCTYPE html>")
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", full_report, re.I)
    assert "<link" not in full_report and "@import" not in full_report and "url(" not in full_report
    imgs = re.findall(r"<img\b[^>]*>", full_report)
    # bias x2, residual table, pose residuals, error boxes, errors over time, Allan x2
    assert len(imgs) == 8
    for img in imgs:
        assert re.search(r'src="data:image/png;base64,[A-Za-z0-9+/=]{100,}"', img), img[:80]
        assert 'alt="' in img


def test_report_sections_in_order_and_verdict_first(full_report, validation_json):
    positions = [full_report.find(f"<h2>{title}</h2>") for _, title in SECTIONS]
    assert all(p > 0 for p in positions), positions
    assert positions == sorted(positions)
    src = validation_json["sources"]
    better = 1.0 - src["recovered"]["prmse_m"] / src["constant"]["prmse_m"]
    verdict = full_report.find(f"The recovered bias integrates {better:.0%} better than a constant bias")
    assert 0 < verdict < full_report.find(SECTIONS[1][1])
    word = validation_json["verdict"]
    assert f'class="verdict v-{word.lower()}"' in full_report
    assert {"PASS": "usable for training.", "WARN": "usable with care"}[word] in full_report[:positions[1]]


def test_recovery_finds_the_injected_outliers_and_the_report_shows_them(full_report, recovery_json):
    """The outliers of a real recovery (sim with 3 displaced pose samples) reach the report."""
    truth = _simulation().truth
    expect_ns = truth.poses.outlier_stamps_ns + round(truth.clock_offset_s * NS_PER_S)  # on the IMU clock
    found = np.asarray(recovery_json["outlier_t_ns"], dtype=np.int64)
    assert len(found) == OUTLIERS == recovery_json["outliers_rejected"]
    assert np.max(np.abs(np.sort(found) - np.sort(expect_ns))) < 1_000_000  # within 1 ms (offset estimate)
    assert "Red lines: poses rejected as outliers." in full_report
    samples = int(recovery_json["pose_fusion"].get("samples_rejected") or 0)  # rejected before fusion
    assert f"{OUTLIERS - samples} of {recovery_json['keyframes']} keyframes" in full_report
    assert not samples or "pose samples rejected before fusion into keyframes" in full_report
    assert f"{OUTLIERS} samples rejected as outliers" in full_report  # pose fusion rejected them


def _offset_text(offset_s: float) -> str:
    """The clock offset as the calibration table shows it: three decimals of a millisecond."""
    return f"{offset_s * 1e3:.3f} ms"


def test_report_shows_the_numbers(full_report, recovery_json, validation_json, results_dir):
    text, rec = full_report, recovery_json
    offset_s = rec["pose_time_offset_s"]
    assert abs(offset_s - CLOCK_OFFSET_S) < 5e-4  # the estimate is near the truth
    assert _offset_text(offset_s) in text  # clock offset
    assert f"{fmt(rec['pose_time_offset_std_s'] * 1e3, 2)} ms" in text  # its std
    tilt = gravity_tilt_deg(rec["gravity_world_mps2"])
    assert tilt < 0.5 and f"{tilt:.3f} deg" in text  # the simulated world is z-up
    level = rec["gravity"]["level_test"]  # z-up by construction: kept level, its measured tilt within 3 sigma of 0
    assert level["level"] and level["tilt_deg"] < 3 * level["tilt_std_deg"]
    assert "Tilt the data measured (frame kept level)" in text and f"{level['tilt_deg']:.3f} deg" in text
    assert "about axis" in text and "roll" in text
    src = validation_json["sources"]
    a, b = mm_pair(src["recovered"]["prmse_m"], src["constant"]["prmse_m"])  # one format for both
    assert f"PRMSE {a} mm vs {b} mm" in text
    flagged = src["recovered"]["flagged"]
    assert flagged and "Flagged windows" in text and f"Every flagged window ({len(flagged)})" in text
    assert "imu: sorted 4001 rows by time (1 backward steps)" in text  # the one swapped pair, 20 s at 200 Hz
    assert "Warnings of the recovery" in text
    assert "Residuals per keyframe, as written by the recovery" in text
    assert "dataset&#x27;s own bias" in text  # ground truth overlaid
    assert "whole recording" in text  # simulated handheld motion: no rest
    assert "4,001" in text  # IMU samples (20 s at 200 Hz)
    fusion = rec["pose_fusion"]
    assert f"Pose fusion: {fmt(fusion['samples_per_keyframe_mean'], 3)} pose samples per 10-Hz keyframe" in text
    assert "pose sigmas from: within bin residuals" in text
    floor = rec["accuracy_floor"]["gyro_radps"]
    assert f"Accuracy floor for this noise (optimal smoother, per axis): gyro {fmt(floor, 3)} rad/s" in text
    # the bias table in the plots' units: the gyro x mean of bias.csv, in mrad/s
    import pandas as pd

    bias = pd.read_csv(results_dir / "recovery" / SEQ / "bias.csv")
    assert f"<td class=\"num\">{fmt(1e3 * bias['bg_x'].mean(), 4)}</td>" in text
    assert "<td>mrad/s</td>" in text and "<td>10⁻³ m/s²</td>" in text
    cu = rec["calibration_uncertainty"]  # offset and extrinsic estimated: their uncertainty is in the sigmas
    assert cu["included_in_bias_std"] and "extrinsic_rotation" in cu["parameters"]
    assert f"(gyro x, y, z, acc x, y, z) by {(cu['std_inflation_mean'][0] - 1) * 100:.1f} %" in text


def test_report_states_the_extrinsic_difference_and_the_correlated_pose_error(stage_outputs, tmp_path):
    """recovery.json's extrinsic difference from the calibration file (a warning box beyond its threshold)
    and the noise search's correlated pose error and white-noise scales, as written."""
    results = write_stage_outputs(stage_outputs, tmp_path)
    rdir = results / "recovery" / SEQ
    rec = json.loads((rdir / "recovery.json").read_text())
    rec.setdefault("extrinsic", {})["difference_from_calibration"] = {
        "rotation_deg": 1.52, "rotation_sigmas": 30.4, "translation_m": 0.004, "translation_sigmas": 1.1,
        "max_sigmas": 3.0, "exceeds": True}
    rec["noise"]["pose_error"] = {"rotation_sigma_rad": 0.002, "rotation_tau_s": 1.0, "position_sigma_m": 0.001,
                                  "position_tau_s": 3.0}
    rec["noise"]["gyro_density_scale"] = 3.0
    (rdir / "recovery.json").write_text(json.dumps(rec), encoding="utf-8")
    text = build_quality_report(results / "ingest" / SEQ, recovery_dir=rdir, validation_dir=None,
                                out_path=tmp_path / "r.html").read_text(encoding="utf-8")
    assert ('<div class="warnbox">Estimated extrinsic against the calibration file&#x27;s: 1.52 deg (30.4 σ) in '
            "rotation, 0.40 cm (1.1 σ) in translation; beyond 3 σ") in text
    assert "correlated pose error (Gauss-Markov): 0.002 rad over 1 s, 0.001 m over 3 s" in text
    assert "gyro white noise: 3× the calibration&#x27;s (as calibrated)" in text


def test_missing_stages_are_reported(stage_outputs, tmp_path):
    results = write_stage_outputs(stage_outputs, tmp_path, recovery=False, validation=False)
    out = build_quality_report(results / "ingest" / SEQ, recovery_dir=results / "recovery" / SEQ,
                               validation_dir=None, out_path=tmp_path / "r.html")
    text = out.read_text(encoding="utf-8")
    assert "NO VERDICT" in text and 'class="verdict v-none"' in text
    assert "the recovery stage has not run" in text
    assert "no validation folder was given" in text
    assert text.count('class="missing"') >= 4
    for _, title in SECTIONS:
        assert f"<h2>{title}</h2>" in text
    assert "Gyroscope Allan deviation" in text  # the IMU part is still shown


def test_renamed_stage_folders(stage_outputs, tmp_path, capsys):
    """results/recover + results/validate (the workflow's rule names)."""
    results = write_stage_outputs(stage_outputs, tmp_path, validation=False)
    (results / "recovery").rename(results / "recover")
    rdir = results / "recover" / SEQ
    found = stage_dirs(tmp_path, SEQ)  # the folder holding results/
    assert found["recovery"] == rdir and found["validation"] is None
    assert cli_main(["report", str(tmp_path), "--sequence", SEQ]) == 0
    out = Path(capsys.readouterr().out.strip())
    assert out == results / "report" / SEQ / "report.html"
    text = out.read_text(encoding="utf-8")
    assert "Residuals per keyframe, as written by the recovery" in text
    assert "NO VERDICT" in text and "no validation folder was given or found" in text
    assert len(re.findall(r"<img\b", text)) == 6  # bias x2, residual table, pose residuals, Allan x2
    (rdir / "residuals.csv").unlink()
    assert cli_main(["report", str(tmp_path), "--sequence", SEQ]) == 0
    assert "Per-keyframe residuals are not available" in out.read_text(encoding="utf-8")


def test_partial_and_malformed_inputs(stage_outputs, recovery_json, tmp_path):
    """Unreadable bias.csv, no trajectory, a minimal validation.json without windows.parquet: still a report."""
    results = write_stage_outputs(stage_outputs, tmp_path)
    rdir, vdir = results / "recovery" / SEQ, results / "validation" / SEQ
    (rdir / "bias.csv").write_text("t_ns,foo\n1,2\n", encoding="utf-8")
    (rdir / "trajectory_tum.txt").unlink()
    (vdir / "windows.parquet").unlink()
    doc = {"schema_version": 1, "sequence": SEQ, "verdict": "WARN", "reasons": ["3 of 38 windows <flagged>"],
           "sources": {"rec": {"kind": "recovered", "prmse_m": 0.005, "roe_deg": 0.01, "windows": 38, "flagged": []},
                       "const": {"kind": "constant_first_window", "prmse_m": 0.005, "roe_deg": 0.01, "windows": 38,
                                 "flagged": []}},
           "windows_dropped": 2}
    (vdir / "validation.json").write_text(json.dumps(doc), encoding="utf-8")
    text = build_quality_report(results / "ingest" / SEQ, recovery_dir=rdir, validation_dir=vdir,
                                out_path=tmp_path / "r.html").read_text(encoding="utf-8")
    assert 'class="verdict v-warn"' in text
    assert "The recovered bias integrates as well as a constant bias" in text
    assert "usable with care" in text
    assert "3 of 38 windows &lt;flagged&gt;" in text  # data is escaped
    assert "missing columns" in text  # the bias.csv reader's message, shown in the page
    assert "bias.csv is missing or could not be read" in text
    assert "windows.parquet" in text and _offset_text(recovery_json["pose_time_offset_s"]) in text
    assert len(re.findall(r"<img\b", text)) == 3  # residual table, Allan x2


def test_missing_ingest_is_one_line_error(tmp_path):
    with pytest.raises(InputFormatError) as exc:
        build_quality_report(tmp_path / "nope", out_path=tmp_path / "r.html")
    assert "\n" not in str(exc.value) and "ingest" in str(exc.value)
    assert not (tmp_path / "r.html").exists()


def test_failure_leaves_no_file(results_dir, tmp_path, monkeypatch):
    import reports.quality as quality

    out = tmp_path / "report.html"
    out.write_text("previous", encoding="utf-8")

    def boom(*a, **k):
        raise RuntimeError("plot failed")

    monkeypatch.setattr(quality.plots, "allan_figure", boom)
    d = stage_dirs(results_dir, SEQ)
    with pytest.raises(RuntimeError):
        build_quality_report(d["ingest"], recovery_dir=d["recovery"], validation_dir=d["validation"],
                             out_path=out)
    assert out.read_text(encoding="utf-8") == "previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]  # no temporary left behind
    # a failure while writing (after the temporary file exists): no file, no temporary
    monkeypatch.setattr(quality, "render_report", lambda inputs, *_: "<!DOCTYPE html>")
    monkeypatch.setattr("pipeline.files.atomic.os.replace", boom)
    new = tmp_path / "sub" / "new.html"
    with pytest.raises(RuntimeError):
        build_quality_report(d["ingest"], recovery_dir=d["recovery"], validation_dir=d["validation"], out_path=new)
    assert not new.exists() and list(new.parent.iterdir()) == []


def test_cli_report(results_dir, recovery_json, tmp_path, capsys):
    offset_text = _offset_text(recovery_json["pose_time_offset_s"])
    out = tmp_path / "cli.html"
    assert cli_main(["report", str(results_dir), "--sequence", SEQ, "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert offset_text in out.read_text(encoding="utf-8")
    # explicit stage folders, no validation: still a report
    out2 = tmp_path / "cli2.html"
    assert cli_main(["report", "--ingest", str(results_dir / "ingest" / SEQ), "--recovery",
                     str(results_dir / "recovery" / SEQ), "--out", str(out2)]) == 0
    assert "NO VERDICT" in out2.read_text(encoding="utf-8")
    # a missing ingest store: exit 2 with one line
    assert cli_main(["report", str(results_dir), "--sequence", "nosuch", "--out", str(tmp_path / "x.html")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no ingest store" in err
    # no --sequence: the dataset page over every sequence of the results folder
    assert cli_main(["report", str(results_dir), "--out", str(tmp_path / "index.html")]) == 0
    assert f'<tr data-sequence="{SEQ}">' in (tmp_path / "index.html").read_text(encoding="utf-8")


def test_report_at_the_workflow_place_links_back_and_names_the_sequence(results_dir, tmp_path):
    from reports.quality import dataset_page_href

    assert dataset_page_href(tmp_path / "results" / "report" / SEQ / "report.html") == "../index.html"
    assert dataset_page_href(tmp_path / "elsewhere.html") is None
    d = stage_dirs(results_dir, SEQ)
    out = build_quality_report(d["ingest"], recovery_dir=d["recovery"], validation_dir=d["validation"],
                               out_path=tmp_path / "report" / SEQ / "report.html")
    html = out.read_text(encoding="utf-8")
    assert re.search(r'<nav class="back"><a href="\.\./index\.html">', html)
    assert f"<h1>Sequence quality report: {SEQ}</h1>" in html and "Dataset quality report" not in html
    assert "Reference: the " in html and "Reference: state" not in html
    assert "start t_ns" not in html  # no 19-digit stamps on the page
