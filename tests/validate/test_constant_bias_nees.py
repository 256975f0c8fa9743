"""The NEES of a constant bias under a random-walk smoother (benchmarks/recovery/constant_bias_nees.py),
against GTSAM's smoother of the same chain and its closed form."""

import importlib.util
from pathlib import Path

import gtsam
import numpy as np
import pytest

SPEC = importlib.util.spec_from_file_location(
    "constant_bias_nees", Path(__file__).resolve().parents[2] / "benchmarks" / "recovery" / "constant_bias_nees.py")
bench = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(bench)


def _gtsam_smoother_nees(density: float, walk: float, duration_s: float, dt_s: float, draws: int,
                         rng: np.random.Generator) -> tuple[float, float, float]:
    """``(mean NEES, its standard error, RMS sigma)`` over ``draws`` recordings of a constant (zero) bias seen
    through white noise, each smoothed by a GTSAM batch of a scalar random-walk chain."""
    n = int(round(duration_s / dt_s)) + 1
    walk_noise = gtsam.noiseModel.Isotropic.Sigma(1, walk * np.sqrt(dt_s))
    read_noise = gtsam.noiseModel.Isotropic.Sigma(1, density / np.sqrt(dt_s))
    nees, sigma = [], None
    for _ in range(draws):
        graph, init = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for k, y in enumerate(rng.normal(0.0, density / np.sqrt(dt_s), n)):
            graph.add(gtsam.PriorFactorDouble(k, float(y), read_noise))
            if k:
                graph.add(gtsam.BetweenFactorDouble(k - 1, k, 0.0, walk_noise))
            init.insert(k, 0.0)
        est = gtsam.GaussNewtonOptimizer(graph, init).optimize()
        if sigma is None:  # the posterior does not depend on the readings
            marg = gtsam.Marginals(graph, est)
            sigma = np.sqrt([marg.marginalCovariance(k)[0, 0] for k in range(n)])
        err = np.array([est.atDouble(k) for k in range(n)])
        nees.append(np.mean((err / sigma) ** 2))
    return float(np.mean(nees)), float(np.std(nees) / np.sqrt(draws)), float(np.sqrt(np.mean(sigma**2)))


def test_the_expected_nees_of_a_constant_bias_matches_gtsams_smoother():
    density, walk, duration, dt = 1.0, 0.5, 30.0, 0.1  # tau = 2 s
    expected, sigma = bench.constant_bias_nees(density, walk, duration, dt)
    drawn, se, gtsam_sigma = _gtsam_smoother_nees(density, walk, duration, dt, 300, np.random.default_rng(3))
    assert sigma == pytest.approx(gtsam_sigma, rel=1e-6)
    assert abs(drawn - expected) < 4 * se
    assert se < 0.03  # the draws tell 1/2 from 1


def test_in_steady_state_a_constant_bias_has_half_the_nees():
    # the smoother's impulse response exp(-|t|/tau) / (2 tau) passes density^2 / (4 tau) of the noise while its
    # posterior variance is density^2 / (2 tau): a ratio of 1/2, whatever the walk's strength
    nees, _ = bench.constant_bias_nees(1.0, 1.0, 60.0, 0.05)  # tau = 1 s: 60 tau long, keyframes tau / 20 apart
    assert nees == pytest.approx(0.5, abs=0.01)


def test_a_walk_much_slower_than_the_recording_gives_the_constant_models_nees_of_one():
    # walk -> 0: the estimate is the readings' mean, its error variance and its posterior variance both r / n
    nees, sigma = bench.constant_bias_nees(1.0, 1e-4, 30.0, 0.1)  # tau = 1e4 s
    assert nees == pytest.approx(1.0, abs=1e-3)
    assert sigma == pytest.approx(1.0 / np.sqrt(30.1), rel=1e-3)  # density / sqrt(n dt), n = 301 readings
