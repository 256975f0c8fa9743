"""The shortcuts of the noise evidence search and of the LM stopping rule (recovery.noise.evidence, recovery.solver.graph).

1. ``NoiseBasis``: the residual covariance re-weighted for other noise densities and random walks equals what
   GTSAM's own preintegration with those random walks gives (linearity of its propagation).
2. ``evidence_step``: the log evidence one Gauss-Newton step from a nearby candidate's optimum
   agrees with a full solve's, to a small fraction of the evidence differences between candidates.
3. The LM stopping rule (``REMAINING_DECREASE_TOL``): the solution is within 0.1 sigma of a solve
   iterated to GTSAM's tightest tolerance, and the rule itself on geometric cost sequences.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pipeline.sim import simulate
from pipeline.sim.config import SimConfig
from recovery.solver import graph
from recovery import recover as rr
from recovery.config import RecoveryConfig
from recovery.solver.factors import noise_basis
from recovery.solver.graph import evidence_step, solve_window
from recovery.solver.window import SolveOptions, WindowInit
from recovery.solver.preintegration import make_params, preintegrate


@pytest.fixture(scope="module")
def window():
    """A 20-s simulated mocap window (fused 10-Hz keyframes at the true calibration) and its options."""
    sim = simulate(SimConfig(duration_s=20.0, seed=3))
    inputs = rr._checked_inputs(sim.sequence, None, RecoveryConfig())
    problem = rr.Problem(inputs.imu, inputs.poses, inputs.pieces, fuse=inputs.fuse)
    problem.set_linearisation(T_imu_pose=sim.truth.T_imu_frame)
    a, b = inputs.pieces[0]
    samples, kf = problem.window(sim.truth.clock_offset_s, a, b, None)
    pose_cfg, imu_cfg = sim.config.poses, sim.config.imu
    opts = replace(inputs.opts, reject_outliers=False, position_sigma_m=pose_cfg.position_noise_m,
                   rotation_sigma_rad=pose_cfg.rotation_noise_rad)
    noise = replace(inputs.imu_noise, gyro_random_walk=imu_cfg.gyro_random_walk, acc_random_walk=imu_cfg.acc_random_walk)
    return samples, kf, noise, sim.truth.T_imu_frame.copy(), opts


def _scaled(noise, g: float, a: float):
    return replace(noise, gyro_random_walk=noise.gyro_random_walk * g, acc_random_walk=noise.acc_random_walk * a)


def test_noise_basis_equals_gtsam_preintegration(window):
    samples, _, noise, _, opts = window
    init = WindowInit(bias=np.array([0.01, -0.02, 0.005, 0.1, -0.2, 0.05]))
    basis = noise_basis(samples, noise, opts, init)
    for g, a, gn, an in ((3.0, 0.5, 1.0, 1.0), (0.3, 10.0, 1.0, 1.0), (1.0, 3.0, 2.0, 10.0), (10.0, 1.0, 0.5, 3.0)):
        target = replace(_scaled(noise, g, a), gyro_noise_density=noise.gyro_noise_density * gn,
                         acc_noise_density=noise.acc_noise_density * an)
        pims = preintegrate(samples, make_params(target, opts.gravity_mps2), init.bias)
        direct = np.array([p.residualCovariance() for p in pims])
        np.testing.assert_allclose(basis.covariances(target), direct, rtol=1e-9, atol=1e-12 * np.abs(direct).max())
    with pytest.raises(ValueError, match="integration sigma"):
        basis.covariances(replace(noise, integration_sigma=2 * noise.integration_sigma))


def test_evidence_step_matches_a_full_solve(window):
    samples, kf, noise, T, opts = window
    centre = solve_window(samples, kf, _scaled(noise, 10, 10), T, opts, want_evidence=True)
    start = WindowInit(gravity_unit=centre.gravity_unit, bias=centre.bias, values=centre.values)
    basis = noise_basis(samples, _scaled(noise, 10, 10), opts, start)
    like = None
    for g, a in ((3, 10), (30, 10), (10, 3), (10, 30)):
        candidate = _scaled(noise, g, a)
        solved = solve_window(samples, kf, candidate, T, opts, start, want_evidence=True)
        step = evidence_step(samples, kf, candidate, T, opts, start, basis)
        assert step is not None
        gap = abs(solved.log_evidence - centre.log_evidence)
        # well inside what separates the candidates: the choice (a parabola through three) moves < 1 %
        assert abs(step[0] - solved.log_evidence) < max(0.02 * gap, 0.5), (g, a, step[0], solved.log_evidence, gap)
        if like is not None:  # the graph of an earlier step, its IMU part re-weighted: the same step exactly
            shared = evidence_step(samples, kf, candidate, T, opts, start, basis, like)
            assert shared[0] == pytest.approx(step[0], rel=1e-12, abs=1e-9)
            assert shared[2].graph.size() == step[2].graph.size()
            assert shared[2].neg_log_const == pytest.approx(step[2].neg_log_const, rel=1e-12)
        like = step[2]


def test_lm_stop_is_within_a_tenth_of_sigma(window, monkeypatch):
    samples, kf, noise, T, opts = window
    o = replace(opts, compute_marginals=True, marginal_rate_hz=None)
    default = solve_window(samples, kf, noise, T, o)
    monkeypatch.setattr(graph, "REMAINING_DECREASE_TOL", 0.0)
    tight = solve_window(samples, kf, noise, T, replace(o, relative_error_tol=1e-12, max_iterations=60))
    assert tight.iterations >= default.iterations
    z = np.abs(default.bias - tight.bias) / tight.bias_std
    assert z.max() < 0.1, z.max()


def test_marginals_of_the_kept_linearisation_equal_gtsam_marginals_at_the_result(window):
    """The bias sigmas come from the optimiser's last Gauss-Newton linearisation, one step before the
    result: they equal gtsam.Marginals of the graph at the result."""
    import gtsam
    from gtsam.symbol_shorthand import B

    samples, kf, noise, T, opts = window
    o = replace(opts, compute_marginals=True, marginal_rate_hz=None)
    sol = solve_window(samples, kf, noise, T, o)
    built = graph.build_window(samples, kf, noise, T, o)
    result, iterations, lin = graph._optimize(built, o, keep_linearisation=True)
    assert lin is not None and iterations >= 2 and not lin.values.equals(result, 1e-12)
    np.testing.assert_allclose(sol.bias, [np.r_[result.atConstantBias(B(k)).gyroscope(),
                                                result.atConstantBias(B(k)).accelerometer()] for k in range(len(kf))],
                               rtol=0, atol=1e-12)
    marginals = gtsam.Marginals(built.graph, result)
    std = np.sqrt([np.diag(marginals.marginalCovariance(B(k))) for k in range(len(kf))])  # [acc, gyro]
    np.testing.assert_allclose(sol.bias_std, np.hstack([std[:, 3:], std[:, :3]]), rtol=1e-5)


def test_a_gauss_newton_step_that_raises_the_cost_hands_over_to_levenberg_marquardt(window, monkeypatch):
    """Every Gauss-Newton step counted as a failure (a negative tolerance): the solve goes on with
    damped steps, keeps no linearisation, and ends where Levenberg-Marquardt alone ends."""
    samples, kf, noise, T, opts = window
    o = replace(opts, compute_marginals=True, marginal_rate_hz=None)
    monkeypatch.setattr(graph, "REMAINING_DECREASE_TOL", -1e12)  # (the stopping rule: GTSAM's alone)
    damped, it_damped, none = graph._optimize(graph.build_window(samples, kf, noise, T, o), o)
    assert none is None
    handed, it_handed, lin = graph._optimize(graph.build_window(samples, kf, noise, T, o), o, keep_linearisation=True)
    assert lin is None and it_handed == it_damped
    assert handed.equals(damped, 1e-9)


@pytest.mark.parametrize("errors, stop", [
    ([1e6, 100.0], False),  # the first step says nothing about the rate
    ([1e6, 100.0, 100.0 - 1e-3], True),  # decrease below the tolerance
    ([1e6, 100.0, 99.0, 98.9], False),  # ratio 0.1: 0.1 * 0.1 / 0.9 = 0.011 still to come
    ([1e6, 100.0, 99.0, 98.9, 98.89], True),  # ratio 0.1: 0.0011 to come
    ([1e6, 100.0, 99.0, 98.5], False),  # ratio 0.5: 0.5 to come
    ([1e6, 100.0, 100.5], True),  # no decrease
])
def test_stopping_rule(errors, stop):
    assert graph._converged(errors, SolveOptions(relative_error_tol=1e-12)) is stop

