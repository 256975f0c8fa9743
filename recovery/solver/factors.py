"""The factor graph of one recovery window: its variables, initial values and factors.

Variables per keyframe k (GTSAM ``symbol_shorthand``): ``X(k)`` pose of the IMU in
the pose world frame, ``V(k)`` velocity, ``B(k)`` bias (GTSAM ``ConstantBias``,
tangent order [acc, gyro]). Shared: ``G(0)`` gravity direction (Unit3) when
estimated, ``E(0)`` extrinsic ``T_imu_pose`` (Pose3) or ``L(0)`` lever arm
(Point3, position trackers) when estimated.

Factors: ``CombinedImuFactor`` (or ``CombinedImuFactorWithGravityDirection``)
between consecutive keyframes, carrying the bias random walk; pose factors per
source kind (absolute Pose3 prior, GPS-like position with lever arm, relative
BetweenFactorPose3 for VIO), each wrapped in a robust loss. Keyframes inside pose
gaps have no pose factor (:mod:`recovery.solver.gaps`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, E, G, L, V, X
from scipy.special import chdtri

from pipeline.types import NS_PER_S, PoseSourceKind
from recovery.config import PoseFactorMode, RobustLoss
from recovery.solver.gaps import bridge_gaps
from recovery.solver.pose_error import add_error_states, error_key, imu_pose_factor, lever_position_factor, \
    rotation_factor, tracked_pose_factor, velocity_fit_variance
from recovery.solver.preintegration import ImuNoise, MidpointSamples, NoiseBasis, make_params, preintegrate
from recovery.solver.initial import initial_orientations, initial_velocity
from recovery.solver.window import KeyframePoses, SolveOptions, WindowInit

# Weak prior on the first bias: keeps the problem well posed without pulling it.
RELATIVE_ANCHOR_SIGMAS = (1.0, 1.0)  # rad, m: weak absolute priors in RELATIVE mode (conditioning only)
BIAS_PRIOR_SIGMAS = np.array([1.0, 1.0, 1.0, 0.2, 0.2, 0.2])  # [acc m/s^2, gyro rad/s]

def _pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, dtype=float))


def _quat_to_rot3(q: np.ndarray) -> gtsam.Rot3:
    return gtsam.Rot3.Quaternion(float(q[0]), float(q[1]), float(q[2]), float(q[3]))


@functools.lru_cache(maxsize=64)
def robust_norm_threshold(k: float, dim: int) -> float:
    """The whitened-norm threshold of a ``dim``-dimensional factor equivalent to ``k`` sigmas.

    GTSAM's robust models weight a factor by the norm of its whole whitened error. A clean
    ``dim``-dimensional error has a chi(dim) norm, so one threshold ``k`` for every dimension
    would down-weight 17 % of clean 6-DoF pose factors at ``k = 3`` (0.27 % of 1-D ones). The
    threshold here has the 1-D tail probability of ``k``: ``P(chi2(dim) > t^2) = P(|z| > k)``
    (3.76 for 3-D, 4.48 for 6-D at ``k = 3``).
    """
    if dim <= 1:
        return float(k)
    return float(math.sqrt(chdtri(dim, math.erfc(k / math.sqrt(2.0)))))  # P(|z| > k) = erfc(k / sqrt 2)


def robust_noise(base: gtsam.noiseModel.Base, loss: RobustLoss, k: float) -> gtsam.noiseModel.Base:
    """``base`` wrapped in the M-estimator ``loss`` at ``k`` sigmas (:func:`robust_norm_threshold`)."""
    if loss == RobustLoss.NONE:
        return base
    t = robust_norm_threshold(k, int(base.dim()))
    if loss == RobustLoss.HUBER:
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(t), base)
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(t), base)


def _pose_cov_in_imu(E_pose: gtsam.Pose3, sig_r: float, sig_p: float) -> np.ndarray:
    """Covariance of a Pose3 prior on the IMU pose given noise on the tracked-frame pose.

    ``X_meas = Z E^-1 = X_true Exp(Ad_E n)``: the noise n (tangent of the tracked
    frame, [rot, trans]) maps through the adjoint of ``E = T_imu_pose``.
    """
    Sf = np.diag([sig_r**2] * 3 + [sig_p**2] * 3)
    Ad = E_pose.AdjointMap()
    S = Ad @ Sf @ Ad.T
    return 0.5 * (S + S.T)


def _extrinsic_error(z: gtsam.Pose3):
    """CustomFactor error ``Logmap(z^-1 X E)`` with Jacobians wrt X and E."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        x = values.atPose3(this.keys()[0])
        e = values.atPose3(this.keys()[1])
        Hx = np.zeros((6, 6), order="F")
        He = np.zeros((6, 6), order="F")
        pred = x.compose(e, Hx, He)
        Hb = np.zeros((6, 6), order="F")
        Hz = np.zeros((6, 6), order="F")
        d = z.between(pred, Hz, Hb)
        Hl = np.zeros((6, 6), order="F")
        r = gtsam.Pose3.Logmap(d, Hl)
        if H is not None:
            H[0] = Hl @ Hb @ Hx
            H[1] = Hl @ Hb @ He
        return r

    return error


@dataclass
class BuiltWindow:
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    pose_factors: list[tuple[int, Any, Any]]  # (keyframe index, factor, gaussian model)
    imu_factors: list[Any]
    neg_log_const: float  # sum of the Gaussian normalisers (for the evidence)
    pose_index: list[int] = field(default_factory=list)  # graph index of each pose_factors entry
    imu_part: tuple[int, float] = (0, 0.0)  # the leading factors from add_imu_factors: count, normalisers


_BIAS_POOL: list[gtsam.Values] = []  # one Values of zero biases B(0..n-1), grown on demand


def bias_values(bias: np.ndarray, K: int) -> gtsam.Values:
    """A Values holding ``B(k) = bias[k]`` for k < K (``bias`` [6] or [K, 6], gyro then acc).

    ``Values.insert(key, ConstantBias)`` costs ~0.1 ms in the Python binding (pybind tries
    ~44 overloads first): 0.6 s per 6000-keyframe segment. A cached pool of zero biases
    is copied and trimmed in C++ instead and moved to ``bias`` by one ``retract``.
    """
    if not _BIAS_POOL or _BIAS_POOL[0].size() < K:
        pool = _BIAS_POOL[0] if _BIAS_POOL else gtsam.Values()
        zero = gtsam.imuBias.ConstantBias()
        for k in range(pool.size(), K):
            pool.insert(B(k), zero)
        if not _BIAS_POOL:
            _BIAS_POOL.append(pool)
    vals = gtsam.Values(_BIAS_POOL[0])
    for k in range(K, vals.size()):
        vals.erase(B(k))
    b = np.asarray(bias, dtype=float)
    if not np.any(b):
        return vals
    b = np.broadcast_to(b, (K, 6))
    delta = gtsam.VectorValues()
    tangent = np.ascontiguousarray(np.hstack([b[:, 3:], b[:, :3]]))  # ConstantBias tangent: [acc, gyro]
    for k in range(K):
        delta.insert(B(k), tangent[k])
    return vals.retract(delta)


def build_window(
    samples: MidpointSamples,
    kf: KeyframePoses,
    imu_noise: ImuNoise,
    T_imu_pose: np.ndarray,
    opts: SolveOptions,
    init: WindowInit | None = None,
    skip: np.ndarray | None = None,
    basis: NoiseBasis | None = None,
) -> BuiltWindow:
    """Build the factor graph and initial values of one window.

    In order: the initial states, the IMU factors (with the gravity direction when estimated)
    and the bias prior, the pose factors of the stream's kind (:func:`_add_pose_factors`), and
    the fused keyframes' velocity priors. ``skip``: keyframes whose pose factors are left out.
    ``basis``: this window's preintegration (:func:`noise_basis`), re-weighted for
    ``imu_noise`` instead of integrating again.
    """
    init = init or WindowInit()
    bias0 = np.zeros(6) if init.bias is None else np.asarray(init.bias, dtype=float)
    models = None
    if basis is None:
        pims = preintegrate(samples, _params(imu_noise, opts, init), bias0 if bias0.ndim == 1 else bias0[:-1])
    else:
        pims = basis.pims
        models = [gtsam.noiseModel.Gaussian.Covariance(c) for c in basis.covariances(imu_noise)]
    Xs, Z = _initial_poses(samples, kf, T_imu_pose, opts, init)
    built = BuiltWindow(gtsam.NonlinearFactorGraph(), bias_values(bias0, len(kf)), [], [], 0.0)
    vel = _initial_velocities(kf, Xs, init)
    if kf.measured is not None and init.values is None:
        Xs, vel = bridge_gaps(pims, Xs, vel, kf.t_ns, kf.measured)
    for k in range(len(kf)):
        built.values.insert(X(k), Xs[k])
        built.values.insert(V(k), vel[k])
    add_imu_factors(built, pims, opts, init, bias0, models)
    built.imu_part = (int(built.graph.size()), built.neg_log_const)
    skip_set = set() if skip is None else set(int(i) for i in skip)
    skip_set.update(int(i) for i in kf.unmeasured)
    _add_pose_factors(built, kf, Xs, Z, T_imu_pose, opts, skip_set)
    position_only = kf.source_kind == PoseSourceKind.POSITION_TRACKER or kf.quat_wxyz is None
    if (kf.v_mps is not None and not position_only and opts.pose_mode != PoseFactorMode.RELATIVE
            and not opts.estimate_extrinsic and not opts.estimate_lever_arm):
        _add_velocity_priors(built, kf, opts, skip_set)
    if init.values is not None:
        built.values = result_subset(init.values, built.values)
    return built


def _initial_poses(samples: MidpointSamples, kf: KeyframePoses, T_imu_pose: np.ndarray, opts: SolveOptions,
                   init: WindowInit) -> tuple[list[Any], list[Any] | None]:
    """Initial IMU poses ``Xs`` [K] and the measured poses ``Z`` [K] (None for position-only streams,
    whose orientations come from ``init`` or :func:`initial_orientations`)."""
    if kf.quat_wxyz is not None:
        Z = [gtsam.Pose3(_quat_to_rot3(kf.quat_wxyz[k]), kf.p_m[k]) for k in range(len(kf))]
        Einv = _pose3(T_imu_pose).inverse()
        return [z.compose(Einv) for z in Z], Z
    rq = init.rot_wxyz if init.rot_wxyz is not None else initial_orientations(samples, kf, opts.gravity_mps2)
    lever = np.asarray(T_imu_pose, dtype=float)[:3, 3]
    Xs = []
    for k in range(len(kf)):
        R = _quat_to_rot3(rq[k])
        Xs.append(gtsam.Pose3(R, kf.p_m[k] - R.rotate(lever)))
    return Xs, None


def _initial_velocities(kf: KeyframePoses, Xs: list[Any], init: WindowInit) -> np.ndarray:
    """Initial velocities [K, 3]: ``init``'s, else from the positions (fused keyframes: measured)."""
    if init.velocity is not None:
        return np.ascontiguousarray(init.velocity, dtype=float)
    t = (kf.t_ns - kf.t_ns[0]) / NS_PER_S
    pos = np.array([x.translation() for x in Xs])
    if kf.measured is None:
        vel = initial_velocity(t, pos)
    else:  # per run of measured keyframes; the pauses' keyframes are bridged by the IMU later
        vel = np.zeros_like(pos)
        idx = np.nonzero(kf.measured)[0]
        for run in np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1):
            vel[run] = initial_velocity(t[run], pos[run])
    if kf.v_mps is not None:  # fused keyframes measured their velocity: a better start for LM
        vel[kf.dt2_s2 > 0] = kf.v_mps[kf.dt2_s2 > 0]
    return np.ascontiguousarray(vel, dtype=float)


def _params(imu_noise: ImuNoise, opts: SolveOptions, init: WindowInit) -> gtsam.PreintegrationCombinedParams:
    """The preintegration parameters of a window (gravity fixed to ``init``'s unless estimated)."""
    return make_params(imu_noise, opts.gravity_mps2, None if opts.estimate_gravity else init.gravity_unit)


def noise_basis(samples: MidpointSamples, imu_noise: ImuNoise, opts: SolveOptions,
                      init: WindowInit | None = None) -> NoiseBasis:
    """One window's preintegration at ``init``'s bias, for :func:`build_window` with other random walks."""
    init = init or WindowInit()
    bias0 = np.zeros(6) if init.bias is None else np.asarray(init.bias, dtype=float)
    return NoiseBasis.build(samples, imu_noise, lambda n: _params(n, opts, init),
                                 bias0 if bias0.ndim == 1 else bias0[:-1])


def add_imu_factors(built: BuiltWindow, pims: list[Any], opts: SolveOptions, init: WindowInit, bias0: np.ndarray,
                     models: list[Any] | None = None) -> None:
    """The IMU factors between consecutive keyframes (gravity direction as a variable when estimated,
    with its prior) and the prior on the first bias. ``models``: noise models replacing the
    preintegrated covariances (:class:`recovery.solver.preintegration.NoiseBasis`)."""
    graph, values = built.graph, built.values
    if opts.estimate_gravity:
        gu = np.array([0.0, 0.0, -1.0]) if init.gravity_unit is None else np.asarray(init.gravity_unit, float)
        values.insert(G(0), gtsam.Unit3(gu / np.linalg.norm(gu)))
        if opts.gravity_prior_cov is not None:
            prior_g = gtsam.noiseModel.Gaussian.Covariance(np.asarray(opts.gravity_prior_cov, dtype=float))
            graph.add(gtsam.PriorFactorUnit3(G(0), gtsam.Unit3(gu / np.linalg.norm(gu)), prior_g))
            built.neg_log_const += prior_g.negLogConstant()
    for k in range(len(pims)):
        if opts.estimate_gravity:
            f = gtsam.CombinedImuFactorWithGravityDirection(
                X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), G(0), pims[k], opts.gravity_mps2
            )
        else:
            f = gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pims[k])
        if models is not None:
            f = f.cloneWithNewNoiseModel(models[k])
        graph.add(f)
        built.imu_factors.append(f)
        built.neg_log_const += f.noiseModel().negLogConstant()
    prior_b = gtsam.noiseModel.Diagonal.Sigmas(BIAS_PRIOR_SIGMAS)
    b0 = bias0 if bias0.ndim == 1 else bias0[0]
    graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(b0[3:], b0[:3]), prior_b))


def _add_pose(built: BuiltWindow, k: int, factor: Any, base: Any) -> None:
    """Add keyframe ``k``'s pose factor (``base``: its Gaussian model, for residuals and the evidence)."""
    built.pose_index.append(int(built.graph.size()))
    built.graph.add(factor)
    built.pose_factors.append((k, factor, base))
    built.neg_log_const += base.negLogConstant()


class _FusedModels:
    """(base, robust) noise models per factor kind and number of fused samples (one model per
    distinct count: fused keyframes carry the information of ``n`` samples)."""

    def __init__(self, kf: KeyframePoses, opts: SolveOptions) -> None:
        self.kf, self.opts = kf, opts
        self.cache: dict[tuple[str, int], tuple[Any, Any]] = {}

    def get(self, kind: str, k: int, make: Any) -> tuple[Any, Any]:
        """``make(n)`` builds the base model of keyframe ``k``'s factor ``kind`` for ``n`` samples."""
        n = 1 if self.kf.count is None else int(self.kf.count[k])
        if (kind, n) not in self.cache:
            base = make(n)
            self.cache[(kind, n)] = (base, robust_noise(base, self.opts.robust_loss, self.opts.robust_k))
        return self.cache[(kind, n)]


def _add_pose_factors(built: BuiltWindow, kf: KeyframePoses, Xs: list[Any], Z: list[Any] | None, T_imu_pose: np.ndarray,
                      opts: SolveOptions, skip: set[int]) -> None:
    """The pose factors: position-only, lever arm only, relative (VIO), or absolute 6-DoF."""
    position_only = kf.source_kind == PoseSourceKind.POSITION_TRACKER or kf.quat_wxyz is None
    if position_only:
        _add_position_factors(built, kf, T_imu_pose, opts, skip)
    elif opts.estimate_lever_arm and not opts.estimate_extrinsic:
        _add_lever_arm_factors(built, kf, Z, T_imu_pose, opts, skip)
    elif opts.pose_mode == PoseFactorMode.RELATIVE:
        _add_relative_factors(built, Xs, T_imu_pose, opts, skip)
    else:
        _add_absolute_factors(built, kf, Xs, Z, T_imu_pose, opts, skip)


def _add_position_factors(built: BuiltWindow, kf: KeyframePoses, T_imu_pose: np.ndarray, opts: SolveOptions,
                          skip: set[int]) -> None:
    """Position-only streams: the tracked point at the lever arm (a variable with ``estimate_extrinsic``)."""
    base = gtsam.noiseModel.Isotropic.Sigma(3, opts.position_sigma_m)
    model = robust_noise(base, opts.robust_loss, opts.robust_k)
    lever = np.asarray(T_imu_pose, dtype=float)[:3, 3]
    if opts.estimate_extrinsic:
        built.values.insert(L(0), lever.copy())
        _add_lever_arm_prior(built, opts)
    for k in range(len(kf)):
        if k in skip:
            continue
        if opts.estimate_extrinsic:
            f = gtsam.GPSFactorArmCalib(X(k), L(0), kf.p_m[k], model)
        else:
            f = gtsam.GPSFactorArm(X(k), kf.p_m[k], lever, model)
        _add_pose(built, k, f, base)


def _add_lever_arm_factors(built: BuiltWindow, kf: KeyframePoses, Z: list[Any], T_imu_pose: np.ndarray,
                           opts: SolveOptions, skip: set[int]) -> None:
    """z = X E with R_E fixed: rotation prior on X (R_z R_E^T, isotropic noise stays isotropic) and a
    position-with-lever-arm factor on (X, L) -- both native GTSAM factors, cheap at any rate."""
    sr, sp = opts.rotation_sigma_rad, opts.position_sigma_m
    models = _FusedModels(kf, opts)
    built.values.insert(L(0), np.asarray(T_imu_pose, dtype=float)[:3, 3].copy())
    _add_lever_arm_prior(built, opts)
    R_Et = _pose3(T_imu_pose).rotation().inverse()
    gm = opts.correlated_error
    if gm is not None:  # the correlated error's states enter both factors (pose_error)
        built.neg_log_const += add_error_states(built.graph, built.values, kf.t_ns, gm)
        S, R_E = gm.selection(), np.asarray(T_imu_pose, dtype=float)[:3, :3]
    for k in range(len(kf)):
        if k in skip:
            continue
        base_r, model_r = models.get("r", k, lambda n: gtsam.noiseModel.Isotropic.Sigma(3, sr / math.sqrt(n)))
        base_p, model_p = models.get("p", k, lambda n: gtsam.noiseModel.Isotropic.Sigma(3, sp / math.sqrt(n)))
        Rm = Z[k].rotation().compose(R_Et)
        rot = (rotation_factor(Rm, R_E, S[:3], model_r, X(k), error_key(k)) if gm is not None
               else gtsam.PoseRotationPrior3D(X(k), Rm, model_r))
        pos = (lever_position_factor(kf.p_m[k], R_E, S[3:], model_p, X(k), L(0), error_key(k))
               if gm is not None and gm.position_active else gtsam.GPSFactorArmCalib(X(k), L(0), kf.p_m[k], model_p))
        _add_pose(built, k, rot, base_r)
        _add_pose(built, k, pos, base_p)


def _add_lever_arm_prior(built: BuiltWindow, opts: SolveOptions) -> None:
    """The calibration's lever arm as a prior on ``L(0)`` (with ``extrinsic_prior``)."""
    if opts.extrinsic_prior is None:
        return
    T_prior, sigmas = opts.extrinsic_prior
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float)[3:])
    built.graph.add(gtsam.PriorFactorPoint3(L(0), np.asarray(T_prior, dtype=float)[:3, 3], prior))
    built.neg_log_const += prior.negLogConstant()


def _add_relative_factors(built: BuiltWindow, Xs: list[Any], T_imu_pose: np.ndarray, opts: SolveOptions,
                          skip: set[int]) -> None:
    """VIO: BetweenFactors from every keyframe to the next ``relative_horizon`` ones, weakly anchored."""
    K = len(Xs)
    cov = _pose_cov_in_imu(_pose3(T_imu_pose), opts.rotation_sigma_rad, opts.position_sigma_m)
    built.graph.add(gtsam.PriorFactorPose3(X(0), Xs[0], gtsam.noiseModel.Gaussian.Covariance(cov)))
    # Weak absolute anchors (1 rad, 1 m): relative factors fix the trajectory only up to a
    # random walk from X(0); against the IMU factors' information (1e10 on position over
    # 30 ms) the Hessian is then numerically singular (LM needs huge damping, Marginals
    # fail). At 1 m the anchors carry ~1e-4 of a relative factor's weight: no drift leaks in.
    weak = gtsam.noiseModel.Diagonal.Sigmas(np.array([RELATIVE_ANCHOR_SIGMAS[0]] * 3 + [RELATIVE_ANCHOR_SIGMAS[1]] * 3))
    for k in range(1, K):
        built.graph.add(gtsam.PriorFactorPose3(X(k), Xs[k], weak))
        built.neg_log_const += weak.negLogConstant()
    h = opts.relative_horizon
    # Each pose enters up to 2h factors; inflate so the information is not counted 2h times.
    base = gtsam.noiseModel.Gaussian.Covariance(cov * 2.0 * h)
    model = robust_noise(base, opts.robust_loss, opts.robust_k)
    for k in range(K):
        if k in skip:
            continue
        for j in range(k + 1, min(K, k + h + 1)):
            if j not in skip:
                _add_pose(built, j, gtsam.BetweenFactorPose3(X(k), X(j), Xs[k].between(Xs[j]), model), base)


def _add_absolute_factors(built: BuiltWindow, kf: KeyframePoses, Xs: list[Any], Z: list[Any], T_imu_pose: np.ndarray,
                          opts: SolveOptions, skip: set[int]) -> None:
    """6-DoF absolute poses: a prior on each IMU pose, or (extrinsic estimated) z = X E with E a variable;
    with a correlated error model, its states ``N(k)`` enter each factor (:mod:`recovery.solver.pose_error`)."""
    sr, sp = opts.rotation_sigma_rad, opts.position_sigma_m
    models = _FusedModels(kf, opts)
    Ep = _pose3(T_imu_pose)
    if opts.estimate_extrinsic:
        built.values.insert(E(0), Ep)
        if opts.extrinsic_prior is not None:
            T_prior, sigmas = opts.extrinsic_prior
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))
            built.graph.add(gtsam.PriorFactorPose3(E(0), _pose3(T_prior), prior))
            built.neg_log_const += prior.negLogConstant()
    gm = opts.correlated_error
    if gm is not None:
        built.neg_log_const += add_error_states(built.graph, built.values, kf.t_ns, gm)
        S, Ad = gm.selection(), Ep.AdjointMap()
    cov = _pose_cov_in_imu(Ep, sr, sp)
    for k in range(len(kf)):
        if k in skip:
            continue
        if opts.estimate_extrinsic:
            base, model = models.get("e", k, lambda n: gtsam.noiseModel.Diagonal.Sigmas(
                np.array([sr] * 3 + [sp] * 3) / math.sqrt(n)))
            f = (tracked_pose_factor(Z[k], S, model, X(k), E(0), error_key(k)) if gm is not None
                 else gtsam.CustomFactor(model, [X(k), E(0)], _extrinsic_error(Z[k])))
        else:
            base, model = models.get("x", k, lambda n: gtsam.noiseModel.Gaussian.Covariance(cov / n))
            f = (imu_pose_factor(Xs[k], Ad, S, model, X(k), error_key(k)) if gm is not None
                 else gtsam.PriorFactorPose3(X(k), Xs[k], model))
        _add_pose(built, k, f, base)


def _add_velocity_priors(built: BuiltWindow, kf: KeyframePoses, opts: SolveOptions, skip: set[int]) -> None:
    """The fused keyframes' velocities (the bins' line fits): std sigma_p / sqrt(sum dt^2), decoupled
    from the position because the keyframe sits at the bin's mean sample time, and widened by the
    slope a correlated position error puts into the fit (:func:`recovery.solver.pose_error.velocity_fit_variance`).
    Not while the lever arm is a variable: the fused velocity was computed with a fixed one (omega x lever)."""
    gm = opts.correlated_error
    for k in range(len(kf)):
        if k in skip or kf.dt2_s2[k] <= 0.0:
            continue
        var = opts.position_sigma_m**2 / float(kf.dt2_s2[k])
        if gm is not None and gm.position_active:
            n = 1 if kf.count is None else int(kf.count[k])
            # n samples evenly over T have sum dt^2 = n T^2 (n + 1) / (12 (n - 1))
            span = math.sqrt(12.0 * float(kf.dt2_s2[k]) * (n - 1) / (n * (n + 1))) if n > 1 else 0.0
            var += velocity_fit_variance(gm, span, n)
        base = gtsam.noiseModel.Isotropic.Sigma(3, math.sqrt(var))
        f = gtsam.PriorFactorVector(V(k), kf.v_mps[k], robust_noise(base, opts.robust_loss, opts.robust_k))
        _add_pose(built, k, f, base)


def result_subset(result: gtsam.Values, template: gtsam.Values) -> gtsam.Values:
    """The values of ``result`` for the keys of ``template`` (warm start).

    Copied and trimmed in C++ (a per-key ``insert`` of a bias costs ~0.1 ms in the binding);
    keys of ``template`` missing from ``result`` take the template's value.
    """
    out = gtsam.Values(result)
    wanted = set(template.keys())
    n0 = error_key(0)
    if out.exists(n0) and template.exists(n0) and len(out.atVector(n0)) != len(template.atVector(n0)):
        wanted = {key for key in wanted if chr(gtsam.Symbol(key).chr()) != "n"}  # another error model: restart it
    for key in list(out.keys()):
        if key not in wanted:
            out.erase(key)
    for key in template.keys():
        if not out.exists(key):
            out.insert(key, _value_at(template, key, template))
    return out


def _value_at(result: gtsam.Values, key: int, template: gtsam.Values) -> Any:
    ch = chr(gtsam.Symbol(key).chr())
    if ch == "x" or ch == "e":
        return result.atPose3(key)
    if ch == "v" or ch == "n":
        return result.atVector(key)
    if ch == "b":
        return result.atConstantBias(key)
    if ch == "g":
        return result.atUnit3(key)
    if ch == "l":
        return result.atPoint3(key)
    raise KeyError(ch)
