"""The rig checks' pieces against independent computations: the FFT correlation against scipy.signal, the
per-lag Pearson correlation and least squares against numpy at single lags, the stamp-unit rule, the
placeholder rows; and the whole-overlap clock search on EuRoC's real Vicon and Leica streams against the
recovery's own fine search."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from pipeline.checks.rig import placeholder_rows
from pipeline.checks.rig_signals import full_correlation, lags, masked_lag_correlation, masked_lag_regression
from pipeline.checks.stamp_unit import stamp_unit
from pipeline.checks.streams import time_stats
from pipeline.types import PoseSeries, PoseSourceKind


@pytest.mark.parametrize("n", [1, 2, 7, 256, 1001])
def test_full_correlation_is_scipy_signals(n):
    rng = np.random.default_rng(n)
    x, y = rng.normal(size=n), rng.normal(size=n)
    np.testing.assert_allclose(full_correlation(y, x), scipy.signal.correlate(y, x, mode="full"), atol=1e-10)
    np.testing.assert_array_equal(lags(n), scipy.signal.correlation_lags(n, n, mode="full"))


def _masked(n: int, seed: int):
    rng = np.random.default_rng(seed)
    x, y = rng.normal(size=n), rng.normal(size=n)
    mx, my = rng.random(n) > 0.2, np.arange(n) > n // 4
    return x, mx, y, my


@pytest.mark.parametrize("k", [-37, -1, 0, 5, 60])
def test_masked_lag_correlation_is_pearson_over_the_overlap(k):
    n = 200
    x, mx, y, my = _masked(n, 3)
    r, count = masked_lag_correlation(x, mx, y, my)
    i = int(np.flatnonzero(lags(n) == k)[0])
    idx = np.arange(n)
    both = (idx + k >= 0) & (idx + k < n)
    idx = idx[both]
    use = mx[idx] & my[idx + k]
    assert count[i] == use.sum()
    assert r[i] == pytest.approx(np.corrcoef(x[idx][use], y[idx + k][use])[0, 1], abs=1e-9)


@pytest.mark.parametrize("k", [-20, 0, 33])
def test_masked_lag_regression_is_least_squares_over_the_overlap(k):
    n = 300
    rng = np.random.default_rng(7)
    features = np.column_stack([rng.normal(size=(n, 3)), np.ones(n)])
    _, mx, y, my = _masked(n, 5)
    r2, coef, count = masked_lag_regression(features, mx, y, my, ridge=0.0)
    i = int(np.flatnonzero(lags(n) == k)[0])
    idx = np.arange(n)
    idx = idx[(idx + k >= 0) & (idx + k < n)]
    use = mx[idx] & my[idx + k]
    X, z = features[idx][use], y[idx + k][use]
    expected, *_ = np.linalg.lstsq(X, z, rcond=None)
    np.testing.assert_allclose(coef[i], expected, atol=1e-8)
    assert r2[i] == pytest.approx(1 - np.sum((z - X @ expected) ** 2) / np.sum((z - z.mean()) ** 2), abs=1e-8)
    assert count[i] == use.sum()


EPOCH_NS = 1_400_000_000_000_000_000


@pytest.mark.parametrize(("t0", "step", "kind", "others", "expected"), [
    (EPOCH_NS // 10**6, 5, "imu", [EPOCH_NS], ("milliseconds", 1_000_000)),        # 200 Hz in ms
    (EPOCH_NS // 10**3, 5000, "imu", [], ("microseconds", 1_000)),                 # 200 Hz in us
    (EPOCH_NS, 5_000_000, "imu", [EPOCH_NS], None),                                # nanoseconds
    (EPOCH_NS // 10**6, 10, "poses", [EPOCH_NS], ("milliseconds", 1_000_000)),     # 100-Hz mocap in ms
    (EPOCH_NS // 10**9, 1, "poses", [EPOCH_NS], ("seconds", 1_000_000_000)),       # 1-Hz poses in s: also
    (EPOCH_NS // 10**6, 1, "poses", [EPOCH_NS], ("milliseconds", 1_000_000)),      # 1 kHz in ms; the start
])                                                                                  # tells them apart
def test_stamp_unit_rule(t0, step, kind, others, expected):
    t = t0 + np.arange(2000, dtype=np.int64) * step
    assert stamp_unit(kind, time_stats(t), others) == expected


def test_placeholders_are_exact_origin_identity_rows_of_a_stream_elsewhere():
    t = np.arange(10, dtype=np.int64)
    p = np.tile([1.0, 2.0, 0.5], (10, 1))
    q = np.tile([0.9, 0.1, 0.3, np.sqrt(1 - 0.91)], (10, 1))
    p[3:5], q[3], q[4] = 0.0, [1, 0, 0, 0], [0, 0, 0, 1]
    q[6], p[7] = [1, 0, 0, 0], 0.0  # identity alone, origin alone: real poses
    got = placeholder_rows(PoseSeries(t, p, q, "m", PoseSourceKind.MOCAP))
    assert np.flatnonzero(got).tolist() == [3, 4]
    at_origin = PoseSeries(t, np.zeros((10, 3)), np.tile([1.0, 0, 0, 0], (10, 1)), "m", PoseSourceKind.MOCAP)
    assert not placeholder_rows(at_origin).any()  # a stream that sits at the origin is not all placeholders


@pytest.mark.parametrize(("sequence", "stream"), [("V1_02_medium", "vicon0"), ("V2_01_easy", "vicon0"),
                                                  ("MH_01_easy", "leica0")])
def test_the_whole_overlap_search_agrees_with_the_fine_one_on_euroc(shared_data, sequence, stream):
    """EuRoC's raw streams (V2_01's Vicon 0.21 s off the IMU clock): the whole-overlap search, over +-50 s
    and more, peaks within 10 ms of the fine correlation's offset, trusted, and no rig finding fires."""
    from pipeline.checks.rig import fit_rig, rig_findings
    from pipeline.io import load_sequence
    from recovery.calibration_init import estimate_time_offset

    seq = load_sequence(shared_data / "euroc" / sequence)
    fit = fit_rig(seq.imu, seq.poses[stream])
    fine = estimate_time_offset(seq.imu, seq.poses[stream], max_offset_s=0.5)
    assert fit.offset.trusted and fit.offset.searched_s > 45.0
    assert abs(fit.offset.offset_s - fine.offset_s) < 0.01
    assert fit.position_factor == 1.0
    assert not rig_findings(seq)
