"""Tests of the quality report (reports/) and ``biasgt report``, on synthetic stage outputs made here."""

from __future__ import annotations

import functools
import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.cli import main as cli_main
from pipeline.errors import BiasgtError, DataError, InputFormatError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind
from reports.allan import allan_deviation, fit_noise_parameters, imu_allan, white_noise_upper_bound
from reports.quality import SECTIONS, build_quality_report, flagged_stretches, gravity_tilt_deg, pose_residuals, \
    stage_dirs, verdict_summary

SEQ = "simseq"
CLOCK_OFFSET_S = 0.012345  # the report must show 12.345 ms
GRAVITY = [0.3, -0.2, -9.80]
PRMSE_RECOVERED_M = 0.0041
PRMSE_CONSTANT_M = 0.0053
REPAIR_TEXT = "imu: sorted 6001 rows by time (3 backward steps)"


@functools.lru_cache(maxsize=1)
def _simulation(duration_s: float = 20.0):
    from pipeline.sim import PoseStreamConfig, SimConfig, simulate

    return simulate(SimConfig(duration_s=duration_s, seed=3, name=SEQ,
                              poses=PoseStreamConfig(clock_offset_s=CLOCK_OFFSET_S, extrinsic_rotation_deg=5.0,
                                                     extrinsic_translation_m=0.05)))


def write_stage_outputs(root: Path, *, recovery: bool = True, validation: bool = True) -> Path:
    """A results folder with ingest/recovery/validation outputs of one simulated sequence (the contracts)."""
    from pipeline.io.tum import write_tum
    from pipeline.store import write_store

    sim = _simulation()
    seq = sim.sequence
    seq = replace(seq, metadata={**seq.metadata, "repairs": [REPAIR_TEXT], "source_kind": "simulation"})
    results = root / "results"
    write_store(seq, results / "ingest" / SEQ)
    gt = seq.ground_truth
    k = np.arange(0, len(gt.t_ns), 10)  # 20 Hz keyframes
    t_kf = gt.t_ns[k]
    if recovery:
        rdir = results / "recovery" / SEQ
        rdir.mkdir(parents=True)
        bias = np.hstack([gt.bias_gyro_radps[k], gt.bias_acc_mps2[k]]) + 1e-5
        std = np.tile([2e-5, 2e-5, 2e-5, 3e-4, 3e-4, 3e-4], (len(k), 1))
        cols = ["bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z"]
        frame = pd.DataFrame(np.hstack([bias, std]), columns=cols + [c + "_std" for c in cols])
        frame.insert(0, "t_ns", t_kf)
        frame.to_csv(rdir / "bias.csv", index=False)
        T = sim.truth.T_imu_frame
        from scipy.spatial.transform import Rotation

        q = Rotation.from_matrix(T[:3, :3]).as_quat(scalar_first=True)
        report = {
            "sequence": SEQ, "pose_stream": "mocap0", "pose_source_kind": "mocap", "pose_frame": "mocap_marker",
            "pose_factor_mode": "absolute",
            "pose_time_offset_s": CLOCK_OFFSET_S, "pose_time_offset_std_s": 0.00021,
            "pose_time_offset_method": "correlation_gyro+graph_cost_parabola",
            "T_imu_pose": {"p_m": T[:3, 3].tolist(), "quat_wxyz": q.tolist()},
            "extrinsic": {"mode": "estimate", "source": "estimated", "rotation_std_deg": [0.05, 0.05, 0.07],
                          "translation_std_m": [0.001, 0.001, 0.002]},
            "gravity_world_mps2": GRAVITY, "gravity": {"estimated": True, "tilt_std_rad": 0.001},
            "noise": {"gyro_noise_density": 1.7e-4, "acc_noise_density": 2.0e-3, "gyro_random_walk": 3.9e-5,
                      "acc_random_walk": 6.0e-3, "position_sigma_m": 0.001, "rotation_sigma_rad": 0.002,
                      "gyro_random_walk_scale": 2.0, "acc_random_walk_scale": 2.0, "method": "evidence",
                      "pose_sigma_method": "within_bin_residuals"},
            "pose_fusion": {"enabled": True, "keyframe_rate_hz": 10.0, "samples_per_keyframe_mean": 9.98,
                            "samples_fused": 1996, "samples_rejected": 2, "within_bin_position_rms_m": 0.000501,
                            "within_bin_rotation_rms_rad": 0.000498},
            "accuracy_floor": {"gyro_radps": 0.00013, "acc_mps2": 0.00666},
            "residuals": {"pose_whitened_rms": 1.07, "imu_whitened_rms": 0.93},
            "outliers_rejected": 3, "outliers_t_ns": [int(t_kf[40]), int(t_kf[41]), int(t_kf[200])],
            "keyframes": int(len(k)), "segments": 1, "segment_seams": [],
            "duration_s": float((t_kf[-1] - t_kf[0]) / NS_PER_S), "runtime_s": 4.2,
            "warnings": ["gyro random-walk scale 100 is at the edge of random_walk_scales; widen the grid"],
        }
        (rdir / "recovery.json").write_text(json.dumps(report), encoding="utf-8")
        write_tum(rdir / "trajectory_tum.txt", PoseSeries(t_kf, gt.p_m[k], gt.quat_wxyz[k], "imu",
                                                          PoseSourceKind.GROUND_TRUTH))
    if validation:
        vdir = results / "validation" / SEQ
        vdir.mkdir(parents=True)
        rng = np.random.default_rng(0)
        t0 = gt.t_ns[0] + np.arange(38) * NS_PER_S // 2
        rows, sources = [], {}
        for name, kind, scale in (("recovered", "recovered", PRMSE_RECOVERED_M),
                                  ("constant_first_window", "constant_first_window", PRMSE_CONSTANT_M),
                                  ("zero", "zero", 0.02), ("dataset", "dataset", 0.0042)):
            pos = np.abs(rng.normal(0, scale, len(t0)))
            rot = np.abs(rng.normal(0, 0.01, len(t0)))
            flagged = np.zeros(len(t0), bool)
            if name == "recovered":
                flagged[[5, 17]] = True
            rows.append(pd.DataFrame({"t0_ns": t0, "source": name, "pos_err_m": pos, "rot_err_deg": rot,
                                      "flagged": flagged}))
            sources[name] = {"kind": kind, "prmse_m": scale, "roe_deg": 0.011 if name == "recovered" else 0.02,
                             "windows": len(t0),
                             "flagged": [{"t0_ns": int(t0[i]), "pos_err_m": float(pos[i]),
                                          "rot_err_deg": float(rot[i])} for i in np.flatnonzero(flagged)]}
        pd.concat(rows, ignore_index=True).to_parquet(vdir / "windows.parquet", index=False)
        doc = {"schema_version": 1, "sequence": SEQ, "verdict": "PASS", "reasons": [], "candidate": "recovered",
               "sources": sources, "windows_dropped": {"candidates": 40, "kept": 38, "dropped": 2, "fraction": 0.05}}
        (vdir / "validation.json").write_text(json.dumps(doc), encoding="utf-8")
    return results


@pytest.fixture(scope="module")
def results_dir(tmp_path_factory) -> Path:
    return write_stage_outputs(tmp_path_factory.mktemp("full"))


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
    assert len(imgs) == 7  # bias x2, pose residuals, error boxes, errors over time, Allan x2
    for img in imgs:
        assert re.search(r'src="data:image/png;base64,[A-Za-z0-9+/=]{100,}"', img), img[:80]
        assert 'alt="' in img


def test_report_sections_in_order_and_verdict_first(full_report):
    positions = [full_report.find(f"<h2>{title}</h2>") for _, title in SECTIONS]
    assert all(p > 0 for p in positions), positions
    assert positions == sorted(positions)
    verdict = full_report.find("The recovered bias integrates 23% better than a constant bias")
    assert 0 < verdict < full_report.find(SECTIONS[1][1])
    assert "usable for training." in full_report[:positions[1]]
    assert 'class="verdict v-pass"' in full_report


def test_report_shows_the_numbers(full_report):
    text = full_report
    assert "12.345 ms" in text  # clock offset
    assert "0.210 ms" in text  # its std
    assert "[0.3, -0.2, -9.8] m/s²" in text  # gravity
    tilt = gravity_tilt_deg(GRAVITY)
    assert f"{tilt:.3f} deg" in text
    assert "about axis" in text and "roll" in text
    assert "4.1" in text and "5.3" in text  # PRMSE in mm
    assert "Flagged windows" in text and text.count("<td class=\"num\">") > 20
    assert "Every flagged window (2)" in text
    assert REPAIR_TEXT in text
    assert "gyro random-walk scale 100 is at the edge" in text  # recovery warning
    assert "Per-keyframe residuals are not available" in text
    assert "Red lines: poses rejected as outliers." in text and "3 of 401 keyframes" in text
    assert "dataset&#x27;s own bias" in text  # ground truth overlaid
    assert "whole recording" in text  # simulated handheld motion: no rest
    assert "4,001" in text  # IMU samples (20 s at 200 Hz)
    assert "Pose fusion: 9.98 pose samples per 10-Hz keyframe" in text and "2 samples rejected" in text
    assert "pose sigmas from: within bin residuals" in text
    assert "Accuracy floor for this noise (optimal smoother, per axis): gyro 0.00013 rad/s" in text


def test_missing_stages_are_reported(tmp_path):
    results = write_stage_outputs(tmp_path, recovery=False, validation=False)
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


def test_renamed_stage_folders_and_residual_table(tmp_path, capsys):
    """results/recover + results/validate (the workflow's stage names), a per-keyframe residual table."""
    results = write_stage_outputs(tmp_path, validation=False)
    (results / "recovery").rename(results / "recover")
    rdir = results / "recover" / SEQ
    bias = pd.read_csv(rdir / "bias.csv")
    pd.DataFrame({"t_ns": bias["t_ns"], "pose_whitened": np.linspace(0.5, 1.5, len(bias)),
                  "imu_whitened": np.ones(len(bias))}).to_csv(rdir / "residuals.csv", index=False)
    found = stage_dirs(tmp_path, SEQ)  # the folder holding results/
    assert found["recovery"] == rdir and found["validation"] is None
    assert cli_main(["report", str(tmp_path), "--sequence", SEQ]) == 0
    out = Path(capsys.readouterr().out.strip())
    assert out == results / "report" / SEQ / "report.html"
    text = out.read_text(encoding="utf-8")
    assert "Residuals per keyframe, as written by the recovery" in text
    assert "Per-keyframe residuals are not available" not in text
    assert "NO VERDICT" in text and "no validation folder was given or found" in text
    assert len(re.findall(r"<img\b", text)) == 6  # bias x2, residual table, pose residuals, Allan x2


def test_partial_and_malformed_inputs(tmp_path):
    """Unreadable bias.csv, no trajectory, a minimal validation.json without windows.parquet: still a report."""
    results = write_stage_outputs(tmp_path)
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
    assert "windows.parquet" in text and "12.345 ms" in text
    assert len(re.findall(r"<img\b", text)) == 2  # Allan only


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
    monkeypatch.setattr(quality, "render_report", lambda inputs: "<!DOCTYPE html>")
    monkeypatch.setattr("pipeline.atomic.os.replace", boom)
    new = tmp_path / "sub" / "new.html"
    with pytest.raises(RuntimeError):
        build_quality_report(d["ingest"], recovery_dir=d["recovery"], validation_dir=d["validation"], out_path=new)
    assert not new.exists() and list(new.parent.iterdir()) == []


def test_cli_report(results_dir, tmp_path, capsys):
    out = tmp_path / "cli.html"
    assert cli_main(["report", str(results_dir), "--sequence", SEQ, "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert "12.345 ms" in out.read_text(encoding="utf-8")
    # explicit stage folders, no validation: still a report
    out2 = tmp_path / "cli2.html"
    assert cli_main(["report", "--ingest", str(results_dir / "ingest" / SEQ), "--recovery",
                     str(results_dir / "recovery" / SEQ), "--out", str(out2)]) == 0
    assert "NO VERDICT" in out2.read_text(encoding="utf-8")
    # a missing ingest store: exit 2 with one line
    assert cli_main(["report", str(results_dir), "--sequence", "nosuch", "--out", str(tmp_path / "x.html")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no ingest store" in err
    assert cli_main(["report", str(results_dir)]) == 2  # no --sequence
    assert isinstance(BiasgtError("x"), Exception)
