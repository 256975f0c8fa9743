"""The estimated calibration's uncertainty in the bias sigmas (recovery.solver.calibration_uncertainty).

1. The first-order sensitivity the module propagates (from the linearised solve) equals what
   re-solving the whole nonlinear problem -- pose fusion included -- with the calibration moved
   by that amount gives: extrinsic rotation, translation and clock offset. Its two ways (through
   the solve's own Bayes tree, or one elimination of the augmented system) agree.
2. On the hard simulated case (unknown 15 deg / 10 cm extrinsic, 12 ms clock offset, dropouts,
   outliers), three seeds: per-axis NEES of the reported sigmas within [0.5, 2], and
   recovery.json says the sigmas include the calibration's uncertainty (inflation >= 1).
The 120-s figures over more seeds: ``benchmarks/recovery/recovery.py --only hard``.
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from pipeline.sim import simulate
from pipeline.sim.config import PoseStreamConfig, SimConfig
from recovery.solver import calibration_uncertainty as cu
from recovery.solver import graph
from recovery import recover as rr
from recovery.solver.calibration_uncertainty import CALIBRATION_DIM, OFFSET_INDEX, CalibrationCovariance
from recovery.config import RecoveryConfig
from recovery.solver.graph import solve_window
from recovery.solver.window import WindowInit

HARD = dict(extrinsic_rotation_deg=15.0, extrinsic_translation_m=0.10, clock_offset_s=0.012, dropouts=4,
            dropout_max_s=1.5, outliers=20, outlier_offset_m=0.1)


def _truth_bias(sim):
    table = np.hstack([sim.truth.bias_gyro_radps, sim.truth.bias_acc_mps2])
    return lambda t: np.stack([np.interp(t, sim.truth.t_ns, table[:, c]) for c in range(6)], 1)


@pytest.fixture(scope="module")
def window_solver():
    """Solves the whole of a 20-s simulated mocap sequence at a given extrinsic / clock offset (the
    fused keyframes rebuilt for each), with the noise of the simulation."""
    sim = simulate(SimConfig(duration_s=20.0, seed=1, poses=PoseStreamConfig(extrinsic_rotation_deg=15.0,
                                                                             extrinsic_translation_m=0.10)))
    inputs = rr._checked_inputs(sim.sequence, None, RecoveryConfig())
    problem = rr.Problem(inputs.imu, inputs.poses, inputs.pieces, fuse=inputs.fuse)
    truth_bias = _truth_bias(sim)
    problem.set_linearisation(bias=truth_bias)
    a, b = inputs.pieces[0]
    pose_cfg, imu_cfg = sim.config.poses, sim.config.imu
    opts = replace(inputs.opts, compute_marginals=True, estimate_gravity=False,
                   position_sigma_m=pose_cfg.position_noise_m, rotation_sigma_rad=pose_cfg.rotation_noise_rad)
    noise = replace(inputs.imu_noise, gyro_random_walk=imu_cfg.gyro_random_walk, acc_random_walk=imu_cfg.acc_random_walk)

    def solve(T: np.ndarray, offset_s: float, cal: CalibrationCovariance | None = None):
        problem.set_linearisation(T_imu_pose=T)
        samples, kf = problem.window(offset_s, a, b, None)
        init = WindowInit(gravity_unit=np.array([0.0, 0.0, -1.0]), bias=truth_bias(kf.t_ns))
        return solve_window(samples, kf, noise, T, replace(opts, calibration_cov=cal), init)

    return solve, sim.truth.T_imu_frame.copy(), sim.truth.clock_offset_s


@pytest.mark.parametrize("index, step", [(0, 1e-3), (2, 1e-3), (4, 5e-3), (OFFSET_INDEX, 2e-4)],
                         ids=["rotation_x", "rotation_z", "translation_y", "clock_offset"])
def test_propagated_sensitivity_matches_nonlinear_resolve(window_solver, index, step):
    """The bias std added for a calibration std ``step`` equals |bias change| of a re-solve with the
    calibration moved by ``step`` (RMS over the keyframes, per axis; 3 % where the change matters)."""
    solve, T, offset_s = window_solver
    base = solve(T, offset_s)
    cov = np.zeros((CALIBRATION_DIM, CALIBRATION_DIM))
    cov[index, index] = step**2
    inflated = solve(T, offset_s, CalibrationCovariance(cov, ("test",)))
    added = np.sqrt(np.maximum(inflated.bias_std**2 - base.bias_std**2, 0.0))
    xi = np.zeros(6)
    if index < 6:
        xi[index] = step
    moved = solve((gtsam.Pose3(T) * gtsam.Pose3.Expmap(xi)).matrix(), offset_s + (step if index == OFFSET_INDEX else 0.0))
    inner = np.arange(5, len(base.t_ns) - 5)
    moved_bias = np.stack([np.interp(base.t_ns[inner], moved.t_ns, moved.bias[:, c]) for c in range(6)], 1)
    change_rms = np.sqrt(((moved_bias - base.bias[inner]) ** 2).mean(0))
    added_rms = np.sqrt((added[inner] ** 2).mean(0))
    matters = change_rms > 0.1 * base.bias_std[inner].mean(0)  # axes the calibration moves noticeably
    assert matters.any()
    np.testing.assert_allclose(added_rms[matters], change_rms[matters], rtol=0.03)
    assert np.all(inflated.bias_std >= base.bias_std - 1e-15)


@pytest.mark.parametrize("rank", [1, 2, 7])
def test_backsubstitution_through_the_tree_equals_the_augmented_elimination(window_solver, monkeypatch, rank):
    """Both ways to ``J`` give the same sigmas, for a covariance of rank 1, 2 and 7 (each forced)."""
    solve, T, offset_s = window_solver
    rng = np.random.default_rng(rank)
    F = rng.normal(size=(CALIBRATION_DIM, rank)) * np.array([1e-3] * 3 + [5e-3] * 3 + [2e-4])[:, None]
    cal = CalibrationCovariance(F @ F.T, ("test",))
    assert cal.sqrt_columns().shape[1] == rank
    stds = {}
    for route, max_rank in (("tree", CALIBRATION_DIM), ("elimination", 0)):
        monkeypatch.setattr(cu, "BACKSUBSTITUTION_MAX_RANK", max_rank)
        monkeypatch.setattr(graph, "BACKSUBSTITUTION_MAX_RANK", max_rank)
        stds[route] = solve(T, offset_s, cal).bias_std
    base = solve(T, offset_s).bias_std
    assert np.all(stds["tree"] >= base * (1 - 1e-12)) and (stds["tree"] / base).mean() > 1.01  # it adds
    np.testing.assert_allclose(stds["tree"], stds["elimination"], rtol=1e-9)


def test_hard_case_nees_per_axis_over_seeds():
    """Hard case, 3 seeds x 60 s: pooled per-axis NEES of the bias against the truth in [0.5, 2]
    (errors every 0.5 s: 360 samples per axis), and the report says how much the sigmas grew."""
    sq_err, inflation = [], []
    for seed in range(3):
        sim = simulate(SimConfig(duration_s=60.0, seed=seed, poses=PoseStreamConfig(**HARD)))
        res = rr.recover(sim.sequence)
        pick = np.searchsorted(res.t_ns, np.arange(res.t_ns[0], res.t_ns[-1], 500_000_000))
        err = res.bias_at(res.t_ns[pick]) - _truth_bias(sim)(res.t_ns[pick])
        sq_err.append((err / res.std_at(res.t_ns[pick])) ** 2)
        report = res.report["calibration_uncertainty"]
        assert report["included_in_bias_std"]
        assert set(report["parameters"]) == {"extrinsic_rotation", "extrinsic_translation", "clock_offset"}
        inflation.append(report["std_inflation_mean"])
    nees = np.concatenate(sq_err).mean(0)
    assert np.all((nees >= 0.5) & (nees <= 2.0)), nees
    inflation = np.array(inflation)
    assert np.all(inflation >= 1.0) and np.all(inflation.mean(0) > 1.001)


def test_known_calibration_adds_nothing():
    """Nothing estimated (extrinsic known, clock offset fixed): no calibration covariance at all."""
    assert CalibrationCovariance.assemble() is None
    cal = CalibrationCovariance.assemble(offset_std_s=1e-4)
    assert cal.parameters == ("clock_offset",)
    L = cal.sqrt_columns()
    np.testing.assert_allclose(L @ L.T, cal.cov, atol=1e-20)
