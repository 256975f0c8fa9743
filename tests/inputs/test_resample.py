"""IMU resampling with an anti-alias filter (convert / predict --resample-hz) and the rate finding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.signal import resample_poly

from biasgt.cli.app import main
from pipeline.resample import resample_imu_filtered
from pipeline.types import ImuSeries

T0_NS = 1_400_000_000_000_000_000


def _imu(rate_hz: float, duration_s: float, tone_hz: float) -> ImuSeries:
    t_ns = T0_NS + np.round(np.arange(int(duration_s * rate_hz)) * 1e9 / rate_hz).astype(np.int64)
    t_s = (t_ns - T0_NS) / 1e9
    wave = np.sin(2 * np.pi * tone_hz * t_s)
    gyro = np.column_stack([wave, 0.5 * wave, 0.01 * t_s])
    acc = np.column_stack([wave, np.zeros_like(wave), 9.81 + 0 * wave])
    return ImuSeries(t_ns, gyro, acc)


def test_downsampling_is_scipys_polyphase_resampler_on_the_stated_grid() -> None:
    imu = _imu(200.0, 10.0, 3.0)
    out = resample_imu_filtered(imu, 100.0)
    expected = resample_poly(np.hstack([imu.gyro_radps, imu.acc_mps2]), 1, 2, axis=0, padtype="line")
    np.testing.assert_allclose(np.hstack([out.gyro_radps, out.acc_mps2]), expected[:len(out.t_ns)], atol=1e-12)
    np.testing.assert_array_equal(out.t_ns, T0_NS + np.arange(len(out.t_ns)) * 10_000_000)


def test_anti_alias_filter_removes_a_tone_above_the_new_nyquist_and_keeps_one_below() -> None:
    fast = resample_imu_filtered(_imu(200.0, 20.0, 70.0), 100.0)  # 70 Hz would alias to 30 Hz
    inner = slice(50, -50)
    assert np.sqrt(np.mean(fast.acc_mps2[inner, 0] ** 2)) < 0.01  # of an amplitude-1 tone (RMS 0.71)
    naive = _imu(200.0, 20.0, 70.0).acc_mps2[::2, 0]  # decimation without a filter
    assert np.sqrt(np.mean(naive ** 2)) > 0.5
    slow = resample_imu_filtered(_imu(200.0, 20.0, 5.0), 100.0)
    t_s = (slow.t_ns - T0_NS) / 1e9
    np.testing.assert_allclose(slow.acc_mps2[inner, 0], np.sin(2 * np.pi * 5.0 * t_s)[inner], atol=0.01)
    np.testing.assert_allclose(slow.acc_mps2[:, 2], 9.81, atol=1e-6)  # gravity's offset does not ring at the ends
    up = resample_imu_filtered(_imu(100.0, 20.0, 5.0), 200.0)
    t_s = (up.t_ns - T0_NS) / 1e9
    np.testing.assert_allclose(up.acc_mps2[100:-100, 0], np.sin(2 * np.pi * 5.0 * t_s)[100:-100], atol=0.01)


def test_a_gap_stays_a_gap() -> None:
    imu = _imu(200.0, 10.0, 2.0)
    keep = np.ones(len(imu.t_ns), bool)
    keep[800:1000] = False  # a 1-s gap
    gapped = ImuSeries(imu.t_ns[keep], imu.gyro_radps[keep], imu.acc_mps2[keep])
    out = resample_imu_filtered(gapped, 100.0)
    dt = np.diff(out.t_ns)
    assert (dt > 20_000_000).sum() == 1 and dt.max() > 900_000_000
    assert not ((out.t_ns > imu.t_ns[800]) & (out.t_ns < imu.t_ns[999])).any()


@pytest.fixture(scope="module")
def copy_100hz(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated ASL recording with every other IMU row dropped: 100 Hz, its sensor.yaml still says 200."""
    root = tmp_path_factory.mktemp("r100")
    sim = root / "sim"
    assert main(["-q", "simulate", "--duration", "12", "--seed", "2", str(sim)]) == 0
    csv = sim / "mav0" / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0], *lines[1::2]]) + "\n")
    return sim


def test_a_rate_far_from_the_calibration_is_a_finding_and_convert_resamples_it(copy_100hz: Path, tmp_path: Path,
                                                                            capsys) -> None:
    from pipeline.checks.run import run_checks
    from pipeline.io import load_sequence
    from pipeline.store import read_store

    (finding,) = [f for f in run_checks(load_sequence(copy_100hz)) if f.code == "IMU_RATE_MISMATCH"]
    assert "runs at 100 Hz but its calibration" in finding.message and "--resample-hz 200" in finding.message
    assert main(["convert", str(copy_100hz), "--out", str(tmp_path / "store"), "--resample-hz", "200"]) == 0
    store = read_store(tmp_path / "store")
    assert np.median(np.diff(store.imu.t_ns)) == 5_000_000 and store.calibration.rate_hz == 200.0
    assert store.metadata["resampled_from_hz"] == pytest.approx(100.0)
    assert not [f for f in run_checks(store) if f.code == "IMU_RATE_MISMATCH"]
    capsys.readouterr()
    assert main(["recover", str(copy_100hz), "--out", str(tmp_path / "rec"), "--noise", "fixed"]) == 0
    assert "warning: IMU_RATE_MISMATCH: imu runs at 100 Hz" in capsys.readouterr().out
    assert main(["validate", str(copy_100hz), "--recovery", str(tmp_path / "rec"), "--crossval", "off",
                 "--out", str(tmp_path / "val")]) in (0, 1)
    out = capsys.readouterr().out
    assert "verdict: PASS" not in out and "input: imu runs at 100 Hz" in out


def test_predict_resamples_a_100_hz_recording_for_a_200_hz_model(copy_100hz: Path, tmp_path: Path, capsys) -> None:
    from window_data import make_window_dataset, train_tiny

    data = make_window_dataset(tmp_path, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    train_tiny(data, tmp_path / "run", "regression_rnn")
    out = tmp_path / "pred"
    assert main(["predict", str(copy_100hz), "--checkpoint", str(tmp_path / "run"), "--out", str(out)]) == 2
    assert "--resample-hz 200" in capsys.readouterr().err
    assert main(["predict", str(copy_100hz), "--checkpoint", str(tmp_path / "run"), "--resample-hz", "200",
                 "--out", str(out)]) == 0
    frame = pd.read_parquet(out.with_suffix(".parquet"))
    assert np.median(np.diff(frame["t_ns"])) == 5_000_000 and np.isfinite(frame["bg_x"]).all()
