"""Bias interpolation: Brownian-bridge mean and variance, clamping, file round trips."""

from __future__ import annotations

import numpy as np
import pytest

from interpolation.bias import interpolate_bias
from interpolation.config import InterpolationMethod
from pipeline.bias_table import CSV_HEADER, BiasTrack, read_bias_csv, write_bias_table
from pipeline.errors import DataError, InputFormatError
from synth import write_recovery_folder


def _keyframes(t_s: np.ndarray, bias: np.ndarray, std: float = 0.0) -> BiasTrack:
    t_ns = (np.asarray(t_s) * 1e9).round().astype(np.int64) + 1_400_000_000_000_000_000
    return BiasTrack(t_ns, bias, np.full_like(bias, std))


def test_linear_is_exact_at_keyframes_and_midpoints():
    bias = np.array([[0.0] * 6, [1.0, 2, 3, 4, 5, 6], [0.0] * 6])
    kf = _keyframes(np.array([0.0, 1.0, 2.0]), bias, std=0.1)
    q_t = kf.t_ns[[0, 1, 2]]
    out = interpolate_bias(kf, np.concatenate([q_t, [kf.t_ns[0] + 500_000_000]]), random_walk=np.zeros(6))
    np.testing.assert_allclose(out.bias[:3], bias)
    np.testing.assert_allclose(out.bias[3], 0.5 * bias[1])
    np.testing.assert_allclose(out.std[:3], 0.1)
    assert not out.clamped.any()


def test_bridge_variance_matches_monte_carlo():
    """Random walks seen only at keyframes: the interpolation error has the bridge variance."""
    rng = np.random.default_rng(0)
    sigma_rw, dt, n_steps, n_runs = 0.3, 0.01, 100, 4000
    # Random walk on a fine grid; keyframes at both ends (1 s apart), query in between.
    steps = rng.normal(0.0, sigma_rw * np.sqrt(dt), size=(n_runs, n_steps))
    walk = np.concatenate([np.zeros((n_runs, 1)), np.cumsum(steps, axis=1)], axis=1)
    k = 30  # query at t = 0.3 s
    errors = []
    for run in range(200):
        kf = _keyframes(np.array([0.0, 1.0]), np.repeat(walk[run, [0, -1]][:, None], 6, axis=1))
        out = interpolate_bias(kf, kf.t_ns[:1] + int(k * dt * 1e9), random_walk=np.full(6, sigma_rw))
        errors.append(out.bias[0, 0] - walk[run, k])
    # Mean of the interpolated values over all runs vs empirical error variance.
    t, t1 = k * dt, 1.0
    expected_var = sigma_rw**2 * t * (t1 - t) / t1
    kf = _keyframes(np.array([0.0, 1.0]), np.zeros((2, 6)))
    out = interpolate_bias(kf, kf.t_ns[:1] + int(k * dt * 1e9), random_walk=np.full(6, sigma_rw))
    assert out.std[0, 0] ** 2 == pytest.approx(expected_var, rel=1e-9)
    empirical = np.var(
        (1 - t) * walk[:, 0] + t * walk[:, -1] - walk[:, k]
    )
    assert empirical == pytest.approx(expected_var, rel=0.08)
    assert np.var(errors) == pytest.approx(expected_var, rel=0.3)


def test_outside_span_refused_or_clamped():
    kf = _keyframes(np.array([0.0, 1.0]), np.array([[1.0] * 6, [2.0] * 6]), std=0.01)
    query = np.array([kf.t_ns[0] - 100_000_000, kf.t_ns[1] + 200_000_000])
    with pytest.raises(DataError, match="outside the recovered bias span"):
        interpolate_bias(kf, query, random_walk=np.ones(6))
    out = interpolate_bias(kf, query, random_walk=np.ones(6), clamp=True)
    np.testing.assert_allclose(out.bias[0], 1.0)
    np.testing.assert_allclose(out.bias[1], 2.0)
    assert out.clamped.tolist() == [True, True]
    np.testing.assert_allclose(out.std[1], np.sqrt(0.01**2 + 0.2))


def test_cubic_passes_through_keyframes_and_is_smooth():
    t = np.linspace(0, 2, 21)
    bias = np.column_stack([np.sin(t)] * 6)
    kf = _keyframes(t, bias, std=0.001)
    query = kf.t_ns[0] + (np.linspace(0, 2, 401) * 1e9).astype(np.int64)
    out = interpolate_bias(kf, query, random_walk=np.zeros(6), method=InterpolationMethod.CUBIC)
    np.testing.assert_allclose(out.bias[::20, 0], np.sin(t), atol=1e-12)
    np.testing.assert_allclose(out.bias[:, 0], np.sin(np.linspace(0, 2, 401)), atol=2e-4)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip(tmp_path, suffix):
    rng = np.random.default_rng(1)
    track = _keyframes(np.arange(5) * 0.005, rng.normal(size=(5, 6)) * 1e-3, std=1e-4)
    path = write_bias_table(track, tmp_path / f"bias{suffix}")
    back = read_bias_csv(path)
    np.testing.assert_array_equal(back.t_ns, track.t_ns)
    np.testing.assert_allclose(back.bias, track.bias, rtol=1e-9)
    if suffix == ".csv":
        assert path.read_text().splitlines()[0] == ",".join(CSV_HEADER)


def test_malformed_bias_files(tmp_path):
    with pytest.raises(InputFormatError, match="does not exist"):
        read_bias_csv(tmp_path / "nope.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("t_ns,bg_x\n1,2\n")
    with pytest.raises(InputFormatError, match="missing columns"):
        read_bias_csv(bad)
    unsorted = tmp_path / "unsorted.csv"
    rows = [",".join(CSV_HEADER), "2," + ",".join(["0"] * 12), "1," + ",".join(["0"] * 12)]
    unsorted.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"unsorted.csv:3: bias stamps are not strictly increasing"):
        read_bias_csv(unsorted)


# --- the stage and its CLI ----------------------------------------------------------------------


def _known_recovery(tmp_path, imu_t_ns, *, margin_ns=0):
    """A recovery folder holding a bias linear in time (known, so interpolation is exact)."""
    t0, t1 = int(imu_t_ns[0]) - margin_ns, int(imu_t_ns[-1]) + margin_ns
    t = np.array([t0 + (t1 - t0) * i // 10 for i in range(11)], dtype=np.int64)
    bias = np.column_stack([np.linspace(0, 1e-3, 11)] * 3 + [np.linspace(0.1, 0.2, 11)] * 3)
    rec = write_recovery_folder(tmp_path / "recovery", BiasTrack(t, bias, np.full_like(bias, 1e-5)),
                                {"noise": {"gyro_random_walk": 2e-5, "acc_random_walk": 3e-3}})
    return rec, t, bias


def test_interpolate_cli_writes_parquet_and_csv(tmp_path):
    from biasgt.cli.app import main
    from pipeline.sim import SimConfig, simulate
    from pipeline.store import write_store

    sim = simulate(SimConfig(duration_s=3.0, seed=2))
    store = write_store(sim.sequence, tmp_path / "store")
    rec, t, bias = _known_recovery(tmp_path, sim.sequence.imu.t_ns)
    out = tmp_path / "bias_imu.parquet"
    assert main(["interpolate", str(rec), "--imu", str(store), "--out", str(out)]) == 0
    back = read_bias_csv(out)
    twin = read_bias_csv(out.with_suffix(".csv"))
    np.testing.assert_array_equal(back.t_ns, sim.sequence.imu.t_ns)
    np.testing.assert_array_equal(twin.t_ns, back.t_ns)
    # Linear in time between keyframes, and the keyframe values are linear too: exact line.
    frac = (back.t_ns - t[0]) / (t[-1] - t[0])
    np.testing.assert_allclose(back.bias[:, 3], 0.1 + 0.1 * frac, atol=1e-12)
    assert np.all(back.std >= 1e-5 - 1e-15)


def test_interpolate_cli_refuses_uncovered_span(tmp_path, capsys):
    from biasgt.cli.app import main
    from pipeline.sim import SimConfig, simulate
    from pipeline.store import write_store

    sim = simulate(SimConfig(duration_s=3.0, seed=2))
    store = write_store(sim.sequence, tmp_path / "store")
    rec, t, bias = _known_recovery(tmp_path, sim.sequence.imu.t_ns, margin_ns=-500_000_000)
    out = tmp_path / "bias_imu.parquet"
    assert main(["interpolate", str(rec), "--imu", str(store), "--out", str(out), "--no-clamp"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside the recovered bias span" in err[0] and "--clamp" in err[0]
    assert not out.exists() and not out.with_suffix(".csv").exists()
    # the default (like --clamp, and the workflow) holds the end values, flagged
    assert main(["interpolate", str(rec), "--imu", str(store), "--out", str(out)]) == 0
    assert out.exists()
    held = read_bias_csv(out.with_suffix(".csv"))
    outside = (held.t_ns < t[0]) | (held.t_ns > t[-1])
    assert outside.any()
    np.testing.assert_allclose(held.bias[held.t_ns < t[0]], np.tile(bias[0], (int((held.t_ns < t[0]).sum()), 1)))
