"""Solving one recovery window (:mod:`recovery.solver.factors` builds its graph): Gauss-Newton and
Levenberg-Marquardt steps to convergence, outlier rejection, the log evidence the noise search
compares, and the bias marginals with the fixed calibration's uncertainty.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, E, G, L, V, X
from scipy.spatial.transform import Rotation

from pipeline.errors import RecoveryError
from pipeline.types import NS_PER_S, PoseSourceKind
from recovery.solver.calibration_uncertainty import BACKSUBSTITUTION_MAX_RANK, OFFSET_INDEX, KeyframeKinematics, added_bias_variance, measurement_columns, parameter_slope_and_information
from recovery.config import PoseFactorMode
from recovery.solver.pose_error import error_key
from recovery.solver.preintegration import ImuNoise, MidpointSamples, NoiseBasis
from recovery.solver.rotations import matrix_to_quat_wxyz
from recovery.solver.factors import add_imu_factors, BuiltWindow, build_window, result_subset
from recovery.solver.initial import initial_orientations
from recovery.solver.window import KeyframePoses, SolveOptions, WindowInit, WindowSolution

log = logging.getLogger(__name__)

def marginal_keyframes(t_ns: np.ndarray, rate_hz: float | None) -> np.ndarray:
    """Keyframes whose bias marginal is computed: a ``rate_hz`` grid, both ends, both sides of gaps.

    The bias std changes on the time scale of the bias random walk and of pose
    dropouts, so between these keyframes it is interpolated linearly.
    """
    K = len(t_ns)
    if rate_hz is None or K < 3:
        return np.arange(K)
    period = NS_PER_S / rate_hz
    bins = np.floor((t_ns - t_ns[0]) / period).astype(np.int64)
    _, first = np.unique(bins, return_index=True)
    dt = np.diff(t_ns)
    gap = np.nonzero(dt > 3 * np.median(dt))[0]
    return np.unique(np.concatenate([first, gap, gap + 1, [0, K - 1]])).astype(int)


# LM stops when the cost decrease still to come is below this (GTSAM cost = 0.5 chi^2). Near the
# optimum a Gauss-Newton step that lowers the cost by d moves the state by a Mahalanobis length
# sqrt(2 d), so no estimate moves by more than sqrt(2 * 0.005) = 0.1 of its sigma any more.
REMAINING_DECREASE_TOL = 0.005


def _converged(errors: list[float], opts: SolveOptions) -> bool:
    """Whether LM may stop after the costs ``errors`` (initial, then one per iteration).

    GTSAM's rules (no decrease, relative decrease below ``relative_error_tol``), plus the
    remaining decrease predicted from the last two (robust losses make the tail of the
    iterations converge linearly: IRLS): with ratio ``r = d_k / d_{k-1}`` of consecutive
    decreases, the rest is ``d_k r / (1 - r)``; the first step, from the initial values,
    does not count towards ``r``.
    """
    d = errors[-2] - errors[-1]
    if not math.isfinite(errors[-1]) or d <= 0 or d <= opts.relative_error_tol * errors[-2]:
        return True
    if d <= REMAINING_DECREASE_TOL:
        return True
    if len(errors) >= 4:
        r = d / (errors[-3] - errors[-2])
        return r < 1.0 and d * r / (1.0 - r) <= REMAINING_DECREASE_TOL
    return False


def elimination_order(values: gtsam.Values) -> gtsam.Ordering:
    """Keyframe variables in time order (``B(k), V(k), [N(k),] X(k)``), then the shared ones (``G``, ``E``, ``L``).

    The graph is a chain in time plus the shared variables: eliminating along the chain gives
    cliques as small as COLAMD's, without computing COLAMD for every elimination.
    """
    ordering = gtsam.Ordering()
    k = 0
    correlated = values.exists(error_key(0))
    while values.exists(X(k)):
        ordering.push_back(B(k))
        ordering.push_back(V(k))
        if correlated:
            ordering.push_back(error_key(k))
        ordering.push_back(X(k))
        k += 1
    for key in (G(0), E(0), L(0)):
        if values.exists(key):
            ordering.push_back(key)
    return ordering


@dataclass
class _Linearised:
    """A graph linearised at ``values`` and its Bayes tree (eliminated by :func:`elimination_order`)."""

    values: gtsam.Values
    gfg: gtsam.GaussianFactorGraph
    tree: gtsam.GaussianBayesTree | None


_LAMBDA_UPPER_BOUND = gtsam.LevenbergMarquardtParams().getlambdaUpperBound()  # LM gives up beyond


def _lm(built: BuiltWindow, values: gtsam.Values, order: gtsam.Ordering) -> Any:
    params = gtsam.LevenbergMarquardtParams()
    params.setOrdering(order)
    return gtsam.LevenbergMarquardtOptimizer(built.graph, values, params)


def _optimize(built: BuiltWindow, opts: SolveOptions, keep_linearisation: bool = False
              ) -> tuple[gtsam.Values, int, _Linearised | None]:
    """Gauss-Newton steps from ``built.values`` until :func:`_converged`, Levenberg-Marquardt where
    they do not descend.

    The steps go through a Bayes tree eliminated here; with ``keep_linearisation`` (solves whose
    marginals follow) the last one's linearisation is returned with the result: the marginals come
    from it instead of linearising and eliminating once more. It lies one step before the result,
    a step the convergence rule bounds to a cost decrease of ~0.005 (a Mahalanobis length of ~0.1);
    the bias variances of the benchmark's 180 s differ from those at the result by ~1e-8 relative.
    GTSAM's Levenberg-Marquardt starts at a damping of 1e-5, a Gauss-Newton step in all but name,
    plus the damped system, a copy of the graph and an error evaluation per damping tried (costly
    with the correlated pose error's Python factors). A step that raises the cost by more than the
    tolerance hands over to Levenberg-Marquardt from where it started (no linearisation kept).

    Returns:
        The result, the iterations, and the kept linearisation (None if none).
    """
    order = elimination_order(built.values)
    optimizer = None
    errors = [float(built.graph.error(built.values))]
    values = built.values  # the Gauss-Newton iterate (None: LM steps)
    lin = None
    while len(errors) - 1 < opts.max_iterations:
        if values is not None:
            # the previous step's linearisation and tree are not needed any more: release every
            # reference before the next ones are built (peak memory: one of each)
            lin = gfg = tree = None
            gfg = built.graph.linearize(values)
            tree = gfg.eliminateMultifrontal(order)
            new = values.retract(tree.optimize())
            err = float(built.graph.error(new))
            if not math.isfinite(err) or err > errors[-1] + REMAINING_DECREASE_TOL:
                optimizer = _lm(built, values, order)  # not quadratic enough here: damped steps from now on
                values, lin, gfg, tree = None, None, None, None
                continue
            if keep_linearisation:
                lin = _Linearised(values, gfg, tree)
            if err > errors[-1]:  # no decrease: converged where the step started (GTSAM's rule)
                errors.append(errors[-1])
                break
            values = new
            errors.append(err)
        else:
            optimizer.iterate()
            errors.append(float(optimizer.error()))
            if optimizer.lambda_() >= _LAMBDA_UPPER_BOUND:
                refuse_unconverged(built, optimizer.values(), order, errors[-1])
                break
        if _converged(errors, opts):
            break
    if values is None:
        values = optimizer.values()
    if log.isEnabledFor(logging.DEBUG):
        log.debug("LM: %d keys, %d iterations, error %.6g -> %.6g", built.values.size(), len(errors) - 1,
                  errors[0], errors[-1])
    return values, len(errors) - 1, lin


#: Levenberg-Marquardt that gave up where its linear model still promises more than this share of the cost
#: (plus ``REMAINING_DECREASE_TOL``) stopped far from an optimum (e.g. a poor start across a long pose gap).
UNCONVERGED_PREDICTED_SHARE = 1e-3


def refuse_unconverged(built: BuiltWindow, values: gtsam.Values, order: gtsam.Ordering, cost: float) -> None:
    """Raise where LM stopped at its damping bound though a Gauss-Newton step from there predicts a
    decrease beyond ``UNCONVERGED_PREDICTED_SHARE`` of the cost: its result is no optimum.

    Raises:
        RecoveryError: naming the cost and the predicted decrease.
    """
    gfg = built.graph.linearize(values)
    delta = gfg.eliminateMultifrontal(order).optimize()
    predicted = float(gfg.error(delta.Zero(delta))) - float(gfg.error(delta))
    if predicted > UNCONVERGED_PREDICTED_SHARE * cost + REMAINING_DECREASE_TOL:
        raise RecoveryError(
            f"the optimisation did not converge (stopped at cost {cost:.6g}, its linear model still predicting "
            f"a decrease of {predicted:.6g})",
            hint="check the pose stream for long gaps, the clock offset and the extrinsic")


def _whitened_norms(factors: list[tuple[int, Any, Any]], values: gtsam.Values) -> np.ndarray:
    out = np.empty(len(factors))
    for i, (_, f, base) in enumerate(factors):
        r = base.whiten(f.unwhitenedError(values))
        out[i] = math.sqrt(float(r @ r) / len(r))
    return out


def log_evidence(built: BuiltWindow, values: gtsam.Values) -> float:
    """Laplace approximation of log p(measurements | noise model), up to a constant.

    ``-E(x*) - sum_f negLogConstant_f - 0.5 log det H``; the constant ``n/2 log 2 pi``
    is the same for every noise hypothesis on the same graph.
    """
    gfg = built.graph.linearize(values)
    bn = gfg.eliminateSequential(elimination_order(values))
    return -built.graph.error(values) - built.neg_log_const - bn.logDeterminant()


def _reweighted(prev: BuiltWindow, basis: NoiseBasis, imu_noise: ImuNoise, opts: SolveOptions,
                init: WindowInit) -> BuiltWindow:
    """``prev`` (a window built on ``basis``) with its IMU part built again for ``imu_noise`` and
    ``init`` (the IMU factors' noise models, the bias and gravity priors' centres) and every other
    factor shared, starting at ``init.values``: what :func:`build_window` would build, without
    building the pose factors and initial values again."""
    bias0 = np.zeros(6) if init.bias is None else np.asarray(init.bias, dtype=float)
    built = BuiltWindow(gtsam.NonlinearFactorGraph(), gtsam.Values(), prev.pose_factors, [], 0.0)
    add_imu_factors(built, basis.pims, opts, init,
                     bias0, [gtsam.noiseModel.Gaussian.Covariance(c) for c in basis.covariances(imu_noise)])
    size, nlc = int(built.graph.size()), built.neg_log_const
    for i in range(prev.imu_part[0], int(prev.graph.size())):
        built.graph.add(prev.graph.at(i))
    built.pose_index = [i - prev.imu_part[0] + size for i in prev.pose_index]
    built.neg_log_const = prev.neg_log_const - prev.imu_part[1] + nlc
    built.imu_part = (size, nlc)
    built.values = result_subset(init.values, prev.values)
    return built


def evidence_step(
    samples: MidpointSamples,
    kf: KeyframePoses,
    imu_noise: ImuNoise,
    T_imu_pose: np.ndarray,
    opts: SolveOptions,
    init: WindowInit,
    basis: NoiseBasis | None = None,
    like: BuiltWindow | None = None,
) -> tuple[float, WindowInit, BuiltWindow] | None:
    """Log evidence (:func:`log_evidence`) one Gauss-Newton step from ``init.values``, the optimum
    under a nearby noise model, where the step ends (the start of a next candidate), and the graph
    (``like`` of a next step with the same pose noise: its pose factors are shared, see
    :func:`_reweighted`).

    The cost is evaluated where the step lands, the log determinant where it starts. From the
    optimum of random walks 3x apart, the result differs from a full solve's log evidence by
    0.1-1.6 on the benchmark's 180-s mocap (0.03-0.17 on the test's 20-s window), against
    differences of 60-800 between such candidates. None when the step does not lower the cost
    (then solve).
    """
    if like is not None and basis is not None:
        built = _reweighted(like, basis, imu_noise, opts, init)
    else:
        built = build_window(samples, kf, imu_noise, T_imu_pose, opts, init, basis=basis)
    start = built.graph.error(built.values)
    bn = built.graph.linearize(built.values).eliminateSequential(elimination_order(built.values))
    values = built.values.retract(bn.optimize())
    cost = built.graph.error(values)
    if not math.isfinite(cost) or cost > start:
        return None
    ev = -cost - built.neg_log_const - bn.logDeterminant()
    return ev, replace(_init_from(values, len(kf), opts, init), values=values), built


#: A window whose pose factors exceed the outlier threshold in more than this fraction of its keyframes
#: keeps them all: so many outliers say that the noise model, not the poses, is wrong.
MAX_OUTLIER_FRACTION = 0.2


def _solve_rejecting(samples: MidpointSamples, kf: KeyframePoses, imu_noise: ImuNoise, T_imu_pose: np.ndarray,
                     opts: SolveOptions, init: WindowInit | None, basis: NoiseBasis | None, want_marginals: bool):
    """Solve once; with ``opts.reject_outliers``, drop the keyframes whose pose factor exceeds the
    threshold and solve again from the first optimum (unless more than :data:`MAX_OUTLIER_FRACTION`
    of them do).

    Returns:
        ``(built, result, iterations, linearisation, outliers [n], pose_norms)``; ``pose_norms``
        is None when the window was solved again (the first solve's norms no longer apply).
    """
    built = build_window(samples, kf, imu_noise, T_imu_pose, opts, init, basis=basis)
    result, iters, lin = _optimize(built, opts, keep_linearisation=want_marginals)
    outliers = np.zeros(0, dtype=int)
    if not (opts.reject_outliers and built.pose_factors):
        return built, result, iters, lin, outliers, None
    norms = _whitened_norms(built.pose_factors, result)
    bad = norms > opts.outlier_threshold
    if not bad.any():
        return built, result, iters, lin, outliers, norms
    K = len(kf)
    outliers = np.unique([built.pose_factors[i][0] for i in np.nonzero(bad)[0]])
    if len(outliers) > MAX_OUTLIER_FRACTION * K:
        # most of the stream cannot be outliers: the noise model is off (e.g. readings with intrinsic
        # errors under the calibration's noise), and dropping them would leave the window degenerate
        log.warning("%d of %d pose factors exceed %.1f sigma: the pose noise is underestimated, none is "
                    "rejected", len(outliers), K, opts.outlier_threshold)
        return built, result, iters, lin, np.zeros(0, dtype=int), norms
    init2 = _init_from(result, K, opts, init)
    built = build_window(samples, kf, imu_noise, T_imu_pose, opts, init2, skip=outliers, basis=basis)
    built.values = result_subset(result, built.values)
    result, iters, lin = _optimize(built, opts, keep_linearisation=want_marginals)
    return built, result, iters, lin, outliers, None


def _residual_summary(built: BuiltWindow, result: gtsam.Values, K: int, opts: SolveOptions,
                      pose_norms: np.ndarray | None) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Whitened RMS of the pose and IMU factors, overall and per keyframe [K] (NaN where none).

    Per keyframe, for plots over time: its pose factor(s), and the IMU factor that ends at it
    (factor k links keyframes k and k+1).
    """
    if pose_norms is None:
        pose_norms = (_whitened_norms(built.pose_factors, result) if built.pose_factors and opts.residuals
                      else np.zeros(0))
    pose_rms = float(np.sqrt(np.mean(pose_norms**2))) if len(pose_norms) else float("nan")
    imu_sq = []
    for f in built.imu_factors if opts.residuals else []:
        r = f.whitenedError(result)
        imu_sq.append(float(r @ r) / len(r))
    imu_rms = float(np.sqrt(np.mean(imu_sq))) if imu_sq else float("nan")
    pose_res = np.full(K, np.nan)
    if len(pose_norms):
        sq = np.zeros(K)
        cnt = np.zeros(K)
        idx = np.array([k for k, _, _ in built.pose_factors], dtype=int)
        np.add.at(sq, idx, pose_norms**2)
        np.add.at(cnt, idx, 1.0)
        has = cnt > 0
        pose_res[has] = np.sqrt(sq[has] / cnt[has])
    imu_res = np.full(K, np.nan)
    if imu_sq and len(imu_sq) == K - 1:
        imu_res[1:] = np.sqrt(imu_sq)
    return pose_rms, imu_rms, pose_res, imu_res


def _solved_frame(result: gtsam.Values, opts: SolveOptions, init: WindowInit | None,
                  T_imu_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The gravity unit vector [3] and T_imu_pose [4, 4] the window used: estimated where it estimated them."""
    if opts.estimate_gravity:
        gu = result.atUnit3(G(0)).unitVector()
    elif init is not None and init.gravity_unit is not None:
        gu = np.asarray(init.gravity_unit, dtype=float) / np.linalg.norm(init.gravity_unit)
    else:
        gu = np.array([0.0, 0.0, -1.0])
    T_used = np.asarray(T_imu_pose, dtype=float).copy()
    if result.exists(E(0)):
        T_used = result.atPose3(E(0)).matrix()
    elif result.exists(L(0)):
        T_used[:3, 3] = result.atPoint3(L(0))
    return gu, T_used


def solve_window(
    samples: MidpointSamples,
    kf: KeyframePoses,
    imu_noise: ImuNoise,
    T_imu_pose: np.ndarray,
    opts: SolveOptions,
    init: WindowInit | None = None,
    want_evidence: bool = False,
    basis: NoiseBasis | None = None,
) -> WindowSolution:
    """Build, solve (with outlier rejection) and summarise one window (``basis``: see :func:`build_window`).

    A position-only window with no attitude to start from is solved from each of the closed-form
    guesses of :data:`ATTITUDE_GUESS_WINDOWS_S` and the lowest cost kept.

    Raises:
        RecoveryError: if the optimiser diverges (non-finite cost).
    """
    K = len(kf)
    if K < 3:
        raise RecoveryError(f"a recovery window needs >= 3 keyframes, got {K}")
    position_only = kf.source_kind == PoseSourceKind.POSITION_TRACKER or kf.quat_wxyz is None
    if position_only and (init is None or (init.rot_wxyz is None and init.values is None)):
        return _best_attitude_start(samples, kf, imu_noise, T_imu_pose, opts, init, want_evidence, basis)
    want_marginals = opts.compute_marginals or opts.marginal_extras or opts.offset_sensitivity
    built, result, iters, lin, outliers, pose_norms = _solve_rejecting(
        samples, kf, imu_noise, T_imu_pose, opts, init, basis, want_marginals)
    cost = float(built.graph.error(result))
    if not math.isfinite(cost):
        raise RecoveryError("the optimisation diverged (non-finite cost)",
                            hint="check the pose stream, its clock offset and the extrinsic")
    pose_rms, imu_rms, pose_res, imu_res = _residual_summary(built, result, K, opts, pose_norms)
    P, Q, Vv = _keyframe_states(result, K)
    bias = _keyframe_biases(result, K)
    gu, T_used = _solved_frame(result, opts, init, T_imu_pose)
    bias_std = np.full((K, 6), np.nan)
    extras: dict[str, Any] = {}
    if opts.offset_sensitivity:
        _offset_sensitivity(built, result, samples, kf, (Q, Vv, bias), T_used, opts, extras, lin)
    if opts.compute_marginals or opts.marginal_extras:
        bias_std = _marginals(built, result, samples, kf, (Q, Vv, bias), T_used, opts, extras, lin)
    ev = log_evidence(built, result) if want_evidence else float("nan")
    return WindowSolution(
        t_ns=kf.t_ns.copy(), p_m=P, quat_wxyz=Q, v_mps=Vv, bias=bias, bias_std=bias_std, gravity_unit=gu,
        T_imu_pose=T_used, cost=cost, pose_whitened_rms=pose_rms, imu_whitened_rms=imu_rms,
        outliers=outliers, iterations=iters, log_evidence=ev, extras=extras,
        pose_residual=pose_res, imu_residual=imu_res, values=result if want_evidence else None,
    )


#: Wahba windows of the closed-form attitude guesses a position-only solve starts from (the first is
#: the default of :func:`initial_orientations`). From positions alone a poor start settles in a wrong
#: minimum, a tilted attitude explained by a gyro bias of ~0.1 rad/s, at several times the cost of
#: the right one; which guess is good depends on the motion and on the gyro bias the guess ignores.
ATTITUDE_GUESS_WINDOWS_S = (8.0, 16.0, 4.0)


def _best_attitude_start(samples: MidpointSamples, kf: KeyframePoses, imu_noise: ImuNoise, T_imu_pose: np.ndarray,
                         opts: SolveOptions, init: WindowInit | None, want_evidence: bool,
                         basis: NoiseBasis | None) -> WindowSolution:
    """:func:`solve_window` from each attitude guess; the solution of lowest cost (the last error
    raised when every start fails)."""
    best, error = None, None
    for window_s in ATTITUDE_GUESS_WINDOWS_S:
        rot = initial_orientations(samples, kf, opts.gravity_mps2, window_s=window_s)
        try:
            sol = solve_window(samples, kf, imu_noise, T_imu_pose, opts, replace(init or WindowInit(), rot_wxyz=rot),
                               want_evidence, basis)
        except RecoveryError as exc:
            error = exc
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:
        raise error
    return best


def _marginals(built: BuiltWindow, result: gtsam.Values, samples: MidpointSamples, kf: KeyframePoses,
               state: tuple[np.ndarray, np.ndarray, np.ndarray], T_imu_pose: np.ndarray, opts: SolveOptions,
               extras: dict[str, Any], lin: _Linearised | None = None) -> np.ndarray:
    """Bias 1-sigma [K, 6] (NaN without ``compute_marginals``; including the fixed calibration's
    uncertainty with ``calibration_cov``; ``state``: the optimum's quat_wxyz [K, 4], v_mps [K, 3] and
    bias [K, 6]) and the shared variables' covariances into ``extras``
    (``marginal_extras``), from one linearisation at the optimum (``lin``: the optimiser's last one,
    a step before it, when it kept one)."""
    K = len(kf)
    bias_std = np.full((K, 6), np.nan)
    gfg, marg, _ = _linearised_at_optimum(built, result, lin)
    if lin is not None:
        lin.tree = None  # freed with ``marg`` below
    if opts.marginal_extras:
        if opts.estimate_gravity:
            extras["gravity_cov_tangent"] = marg.marginalCovariance(G(0))
        if result.exists(E(0)):
            extras["extrinsic_cov"] = marg.marginalCovariance(E(0))
        if result.exists(L(0)):
            extras["lever_arm_cov"] = marg.marginalCovariance(L(0))
    if not opts.compute_marginals:
        return bias_std
    idx = marginal_keyframes(kf.t_ns, opts.marginal_rate_hz)
    var = np.array([np.diag(marg.marginalCovariance(B(int(k)))) for k in idx])  # [acc, gyro]
    var = np.hstack([var[:, 3:], var[:, :3]])
    cal = opts.calibration_cov
    if cal is not None and cal.sqrt_columns().shape[1] > BACKSUBSTITUTION_MAX_RANK:
        marg = None  # the propagation eliminates again: one tree at a time (peak memory)
    added = _calibration_variance(gfg, marg, built, result, samples, kf, state, T_imu_pose, opts, idx)
    del marg
    if added is not None:
        extras["calibration_std_ratio"] = np.sqrt((var + added) / var)  # [len(idx), 6]
        var = var + added
    bias_std[idx] = np.sqrt(var)
    if len(idx) < K:
        x = kf.t_ns - kf.t_ns[0]
        for c in range(6):
            bias_std[:, c] = np.interp(x, x[idx], bias_std[idx, c])
    return bias_std


def _linearised_at_optimum(built: BuiltWindow, result: gtsam.Values, lin: _Linearised | None
                           ) -> tuple[gtsam.GaussianFactorGraph, gtsam.GaussianBayesTree, gtsam.Values]:
    """The linearisation the marginals and the calibration's sensitivities come from, its Bayes tree
    and where it was taken: the optimiser's last one (``lin``, a step before the result) when it
    kept one, else ``result``'s."""
    if lin is not None and lin.tree is not None:
        return lin.gfg, lin.tree, lin.values
    gfg = built.graph.linearize(result)
    # the Bayes tree of the chain in time order: the same marginals as gtsam.Marginals' COLAMD tree
    # (1e-14 apart), 25 % less CPU with its queries on the benchmark's 180 s
    return gfg, gfg.eliminateMultifrontal(elimination_order(result)), result


def _calibration_columns(built: BuiltWindow, samples: MidpointSamples, kf: KeyframePoses,
                         state: tuple[np.ndarray, np.ndarray, np.ndarray], T_imu_pose: np.ndarray, opts: SolveOptions
                         ) -> tuple[list[tuple[int, int, str]], tuple[np.ndarray, np.ndarray]] | None:
    """The pose and velocity factors ``(graph index, keyframe, kind)`` and their measurement columns
    in the calibration (:func:`recovery.solver.calibration_uncertainty.measurement_columns`) at the optimum
    ``state``; None unless the factors are 6-DoF absolute with the calibration held fixed."""
    if (opts.pose_mode != PoseFactorMode.ABSOLUTE or opts.estimate_extrinsic or opts.estimate_lever_arm
            or kf.quat_wxyz is None or not built.pose_index):
        return None
    q, v, bias = state
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    first = np.minimum(samples.start, len(samples.dt_s) - 1)  # the sub-interval after each keyframe
    kin = KeyframeKinematics(R, v, samples.gyro_radps[first] - bias[:, :3],
                             np.gradient(v, (kf.t_ns - kf.t_ns[0]) / NS_PER_S, axis=0))
    factors = [(i, k, chr(gtsam.Symbol(f.keys()[0]).chr()))
               for i, (k, f, _) in zip(built.pose_index, built.pose_factors)]
    return [f for f in factors if f[2] in ("x", "v")], measurement_columns(kin, T_imu_pose)


def _calibration_variance(gfg: gtsam.GaussianFactorGraph, tree: gtsam.GaussianBayesTree | None, built: BuiltWindow,
                          result: gtsam.Values, samples: MidpointSamples,
                          kf: KeyframePoses, state: tuple[np.ndarray, np.ndarray, np.ndarray],
                          T_imu_pose: np.ndarray, opts: SolveOptions, idx: np.ndarray) -> np.ndarray | None:
    """Bias variance [len(idx), 6] (gyro, acc) added by the uncertainty of the fixed calibration
    (:mod:`recovery.solver.calibration_uncertainty`; ``tree``: ``gfg`` eliminated, or None); None when
    there is none or the factors are not 6-DoF absolute."""
    cols = None if opts.calibration_cov is None else _calibration_columns(built, samples, kf, state, T_imu_pose, opts)
    if cols is None:
        return None
    return added_bias_variance(gfg, cols[0], cols[1], opts.calibration_cov, [B(int(k)) for k in idx],
                               elimination_order(result) if tree is None else None, tree=tree,
                               zero=None if tree is None else result.zeroVectors())


def _offset_sensitivity(built: BuiltWindow, result: gtsam.Values, samples: MidpointSamples, kf: KeyframePoses,
                        state: tuple[np.ndarray, np.ndarray, np.ndarray], T_imu_pose: np.ndarray, opts: SolveOptions,
                        extras: dict[str, Any], lin: _Linearised | None) -> None:
    """``extras["offset_slope"]`` / ``["offset_information"]``: the cost's slope and information in
    the clock offset (:func:`recovery.solver.calibration_uncertainty.parameter_slope_and_information`),
    from the optimiser's last linearisation (its tree stays for the marginals); nothing when the
    factors are not 6-DoF absolute."""
    cols = _calibration_columns(built, samples, kf, state, T_imu_pose, opts)
    if cols is None:
        return
    gfg, tree, at = _linearised_at_optimum(built, result, lin)
    sensitivity = parameter_slope_and_information(gfg, tree, cols[0], cols[1], at.zeroVectors(), OFFSET_INDEX)
    if sensitivity is not None:
        extras["offset_slope"], extras["offset_information"] = sensitivity


def _keyframe_states(result: gtsam.Values, K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions [K, 3], quat_wxyz [K, 4] and velocities [K, 3] of ``X(k)``, ``V(k)``, k < K.

    Extracted in C++ by GTSAM's utilities (a loop over keys costs ~6 us per keyframe), which
    return every value of a type in key order: the only other pose, ``E(0)``, sorts first.
    """
    M = gtsam.utilities.extractPose3(result)
    Vv = gtsam.utilities.extractVectors(result, "v")
    if len(M) != K + int(result.exists(E(0))) or len(Vv) != K:
        raise RecoveryError(f"internal: expected {K} keyframe poses and velocities, found {len(M)} and {len(Vv)}")
    M = M[len(M) - K:]
    return M[:, 9:].copy(), matrix_to_quat_wxyz(M[:, :9].reshape(K, 3, 3)), np.asarray(Vv, dtype=float)


def _keyframe_biases(result: gtsam.Values, K: int) -> np.ndarray:
    """Biases [K, 6] (gyro, acc) of ``B(k)``, k < K."""
    tangent = np.array([result.atConstantBias(B(k)).vector() for k in range(K)])  # [acc, gyro]
    return np.ascontiguousarray(np.hstack([tangent[:, 3:], tangent[:, :3]]))


def _init_from(result: gtsam.Values, K: int, opts: SolveOptions, init: WindowInit | None) -> WindowInit:
    gu = result.atUnit3(G(0)).unitVector() if opts.estimate_gravity else (None if init is None else init.gravity_unit)
    return WindowInit(gravity_unit=gu, bias=_keyframe_biases(result, K), rot_wxyz=_keyframe_states(result, K)[1])
