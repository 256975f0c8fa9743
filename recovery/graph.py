"""The factor graph of one recovery window and its solution.

Variables per keyframe k (GTSAM ``symbol_shorthand``): ``X(k)`` pose of the IMU in
the pose world frame, ``V(k)`` velocity, ``B(k)`` bias (GTSAM ``ConstantBias``,
tangent order [acc, gyro]). Shared: ``G(0)`` gravity direction (Unit3) when
estimated, ``E(0)`` extrinsic ``T_imu_pose`` (Pose3) or ``L(0)`` lever arm
(Point3, position trackers) when estimated.

Factors: ``CombinedImuFactor`` (or ``CombinedImuFactorWithGravityDirection``)
between consecutive keyframes, carrying the bias random walk; pose factors per
source kind (absolute Pose3 prior, GPS-like position with lever arm, relative
BetweenFactorPose3 for VIO), each wrapped in a robust loss.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, E, G, L, V, X
from scipy.special import chdtri
from scipy.spatial.transform import Rotation

from pipeline.errors import RecoveryError
from pipeline.types import GRAVITY_MPS2, NS_PER_S, PoseSourceKind
from recovery.calibration_uncertainty import BACKSUBSTITUTION_MAX_RANK, OFFSET_INDEX, CalibrationCovariance, \
    KeyframeKinematics, added_bias_variance, measurement_columns, parameter_slope_and_information
from recovery.config import PoseFactorMode, RobustLoss
from recovery.fusion import FusedPoses, PerBin, WithinBinStats
from recovery.gaps import bridge_gaps, gap_keyframe_stamps
from recovery.pose_error import PoseErrorModel, add_error_states, error_key, imu_pose_factor, tracked_pose_factor, \
    velocity_fit_variance
from recovery.preintegration import ImuNoise, MidpointSamples, NoiseBasis, make_params, preintegrate
from recovery.rotations import matrix_to_quat_wxyz

log = logging.getLogger(__name__)

# Weak prior on the first bias: keeps the problem well posed without pulling it.
RELATIVE_ANCHOR_SIGMAS = (1.0, 1.0)  # rad, m: weak absolute priors in RELATIVE mode (conditioning only)
BIAS_PRIOR_SIGMAS = np.array([1.0, 1.0, 1.0, 0.2, 0.2, 0.2])  # [acc m/s^2, gyro rad/s]


@dataclass(frozen=True)
class KeyframePoses:
    """Pose measurements at the keyframes, stamps already on the IMU clock.

    Attributes:
        t_ns: Keyframe stamps (IMU clock), int64 [K], strictly increasing.
        p_m: Measured position of the tracked frame, [K, 3].
        quat_wxyz: Measured orientation of the tracked frame, [K, 4] or None.
        source_kind: The pose source.
        count: Pose samples fused into each keyframe, int [K] (None: one sample each); the pose
            factor's covariance is divided by it.
        v_mps: Fused IMU velocity, [K, 3]; dt2_s2: its information per unit position variance
            (``sum dt^2`` of the bin), [K] (0: no velocity measurement).
        per_bin: Within-bin residual sums of the fused samples (for the noise evidence).
        rejected_t_ns: Pose samples rejected while fusing (outliers), int64 [R].
        measured: Whether each keyframe has a pose measurement, bool [K] (None: all have). The
            others sit inside pose gaps (:mod:`recovery.gaps`): no pose factor, their ``p_m`` and
            ``quat_wxyz`` only placeholders (interpolated, held).
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray | None
    source_kind: PoseSourceKind
    count: np.ndarray | None = None
    v_mps: np.ndarray | None = None
    dt2_s2: np.ndarray | None = None
    per_bin: PerBin | None = None
    rejected_t_ns: np.ndarray | None = None
    measured: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def unmeasured(self) -> np.ndarray:
        """Indices of the keyframes without a pose measurement, int [U]."""
        return np.zeros(0, dtype=int) if self.measured is None else np.nonzero(~self.measured)[0]

    def with_gap_keyframes(self) -> "KeyframePoses":
        """These keyframes plus unmeasured ones inside the pose gaps (:func:`recovery.gaps.gap_keyframe_stamps`)."""
        t_ns, measured = gap_keyframe_stamps(self.t_ns)
        if measured.all():
            return self
        src = np.cumsum(measured) - 1  # the measured keyframe at or before each
        t_s, t_meas = t_ns / NS_PER_S, self.t_ns / NS_PER_S
        p_m = np.column_stack([np.interp(t_s, t_meas, self.p_m[:, i]) for i in range(3)])
        q = None if self.quat_wxyz is None else self.quat_wxyz[src]
        if self.count is None:
            return replace(self, t_ns=t_ns, p_m=p_m, quat_wxyz=q, measured=measured)

        def put(x: np.ndarray, fill: float) -> np.ndarray:
            out = np.full((len(t_ns), *x.shape[1:]), fill, dtype=x.dtype)
            out[measured] = x
            return out

        pb = self.per_bin
        return replace(self, t_ns=t_ns, p_m=p_m, quat_wxyz=q, count=put(self.count, 1), v_mps=put(self.v_mps, 0.0),
                       dt2_s2=put(self.dt2_s2, 0.0), measured=measured,
                       per_bin=PerBin(put(pb.pos_sq, 0.0), put(pb.pos_dof, 0), put(pb.rot_sq, 0.0), put(pb.rot_dof, 0)))

    @classmethod
    def from_fused(cls, fused: FusedPoses, source_kind: PoseSourceKind) -> "KeyframePoses":
        """Keyframes carrying the fused samples of their bins (:mod:`recovery.fusion`)."""
        return cls(fused.t_ns, fused.p_m, fused.quat_wxyz, source_kind, fused.count, fused.v_mps,
                   fused.dt2_s2, fused.per_bin, fused.rejected_t_ns)

    def within_bin(self) -> WithinBinStats | None:
        """Residual sums of the fused samples about their keyframes (None when not fused)."""
        return None if self.per_bin is None else self.per_bin.total()

    def take(self, index: np.ndarray | slice) -> "KeyframePoses":
        q = None if self.quat_wxyz is None else self.quat_wxyz[index]
        measured = None if self.measured is None else self.measured[index]
        if self.count is None:
            return KeyframePoses(self.t_ns[index], self.p_m[index], q, self.source_kind, measured=measured)
        pb = self.per_bin
        return KeyframePoses(self.t_ns[index], self.p_m[index], q, self.source_kind, self.count[index],
                             self.v_mps[index], self.dt2_s2[index],
                             PerBin(pb.pos_sq[index], pb.pos_dof[index], pb.rot_sq[index], pb.rot_dof[index]),
                             self.rejected_t_ns, measured)


@dataclass
class SolveOptions:
    """How one window is built and solved (derived from RecoveryConfig)."""

    pose_mode: PoseFactorMode = PoseFactorMode.ABSOLUTE
    relative_horizon: int = 5
    position_sigma_m: float = 1e-3
    rotation_sigma_rad: float = 1e-3
    robust_loss: RobustLoss = RobustLoss.HUBER
    robust_k: float = 3.0
    outlier_threshold: float = 5.0
    reject_outliers: bool = True
    estimate_gravity: bool = True
    gravity_mps2: float = GRAVITY_MPS2
    estimate_extrinsic: bool = False
    estimate_lever_arm: bool = False  # 6-DoF sources: rotation of T_imu_pose fixed, lever arm L(0) free (native factors)
    max_iterations: int = 30
    relative_error_tol: float = 1e-6
    compute_marginals: bool = False
    marginal_extras: bool = False  # gravity / extrinsic covariances
    marginal_rate_hz: float | None = 20.0  # bias marginals at this rate (+ ends, gap edges), interpolated
    gravity_prior_cov: np.ndarray | None = None  # [2, 2] Unit3-tangent prior on G(0) around init.gravity_unit
    # the calibration held fixed and its covariance: propagated into the bias marginals
    # (recovery.calibration_uncertainty; 6-DoF absolute pose factors only)
    calibration_cov: CalibrationCovariance | None = None
    residuals: bool = True  # the whitened residuals per keyframe and their RMS (NaN without)
    # the cost's slope and information in the clock offset into extras (offset_slope,
    # offset_information; 6-DoF absolute pose factors only): recovery.calibration_uncertainty
    offset_sensitivity: bool = False
    # the stream's time-correlated error as graph states (6-DoF absolute pose factors;
    # recovery.pose_error); None or inactive: white pose noise only
    pose_error: PoseErrorModel | None = None
    # with estimate_extrinsic: a prior on E(0), (T_imu_pose [4, 4], sigmas [6]: rotation rad, translation m)
    extrinsic_prior: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def correlated_error(self) -> PoseErrorModel | None:
        """The active time-correlated pose error model, else None."""
        return self.pose_error if self.pose_error is not None and self.pose_error.active else None


@dataclass
class WindowInit:
    """Optional initial values for a window (e.g. from a previous solve)."""

    gravity_unit: np.ndarray | None = None
    bias: np.ndarray | None = None  # [6] gyro, acc or [K, 6]
    rot_wxyz: np.ndarray | None = None  # [K, 4] IMU orientation (position trackers)
    velocity: np.ndarray | None = None  # [K, 3] velocity guess (else from the positions)
    values: Any = None  # gtsam.Values: an optimum of the same window; every variable starts there


@dataclass
class WindowSolution:
    """Result of :func:`solve_window`.

    Attributes:
        t_ns: Keyframe stamps, int64 [K].
        p_m: IMU positions, [K, 3]. quat_wxyz: IMU orientations, [K, 4]. v_mps: [K, 3].
        bias: [K, 6] gyro xyz then acc xyz. bias_std: [K, 6] (NaN without marginals).
        gravity_unit: [3] gravity direction in the world frame.
        T_imu_pose: 4x4 extrinsic used / estimated.
        cost: Final graph error (0.5 * sum of squared whitened residuals, robust).
        pose_whitened_rms / imu_whitened_rms: Per-DoF RMS of the whitened residuals.
        outliers: Indices of rejected pose keyframes.
        iterations: LM iterations (of the last solve).
        extras: Covariances of shared variables when asked for.
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    bias: np.ndarray
    bias_std: np.ndarray
    gravity_unit: np.ndarray
    T_imu_pose: np.ndarray
    cost: float
    pose_whitened_rms: float
    imu_whitened_rms: float
    outliers: np.ndarray
    iterations: int
    log_evidence: float = float("nan")
    extras: dict[str, Any] = field(default_factory=dict)
    pose_residual: np.ndarray | None = None  # [K] whitened RMS of each keyframe's pose factor(s), NaN if none
    imu_residual: np.ndarray | None = None  # [K] whitened RMS of the IMU factor ending at each keyframe
    values: Any = None  # the optimum as gtsam.Values (with want_evidence: the evidence search starts from it)


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


def _robust(base: gtsam.noiseModel.Base, loss: RobustLoss, k: float) -> gtsam.noiseModel.Base:
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
class _Built:
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    pose_factors: list[tuple[int, Any, Any]]  # (keyframe index, factor, gaussian model)
    imu_factors: list[Any]
    neg_log_const: float  # sum of the Gaussian normalisers (for the evidence)
    pose_index: list[int] = field(default_factory=list)  # graph index of each pose_factors entry
    imu_part: tuple[int, float] = (0, 0.0)  # the leading factors from _add_imu_factors: count, normalisers


def _savgol(y: np.ndarray, win: int, dt: float, deriv: int) -> np.ndarray:
    """First or second derivative of a local quadratic least-squares fit (Savitzky-Golay), [K, C].

    Same values as ``scipy.signal.savgol_filter(y, win, 2, deriv=deriv, delta=dt, axis=0,
    mode="interp")`` without importing scipy.signal (~0.5 s and ~25 MB in every recovery process):
    inside, the centred fit's slope is ``sum_j j y_{k+j} / sum_j j^2`` and its second derivative
    ``2 sum_j (j^2 - mean j^2) y_{k+j} / sum_j (j^2 - mean j^2)^2``; at the ends the quadratic
    fit to the first / last ``win`` samples is differentiated.
    """
    K = len(y)
    m = win // 2
    j = np.arange(-m, m + 1, dtype=float)
    if deriv == 1:
        c = j / (np.sum(j**2) * dt)
    elif deriv == 2:
        q = j**2 - np.mean(j**2)
        c = 2.0 * q / (np.sum(q**2) * dt**2)
    else:
        raise ValueError(f"deriv must be 1 or 2, got {deriv}")
    out = np.empty_like(y, dtype=float)
    for col in range(y.shape[1]):
        out[m:K - m, col] = np.convolve(y[:, col], c[::-1], mode="valid")
    x = np.arange(win, dtype=float) * dt
    for head in (True, False):
        coef = np.polyfit(x, y[:win] if head else y[K - win:], 2)  # [3, C]: quadratic fit per column
        xs = x[:m] if head else x[win - m:]
        if deriv == 1:
            vals = 2.0 * coef[0][None, :] * xs[:, None] + coef[1][None, :]
        else:
            vals = np.broadcast_to(2.0 * coef[0][None, :], (len(xs), y.shape[1]))
        if head:
            out[:m] = vals
        else:
            out[K - m:] = vals
    return out


def initial_velocity(t_s: np.ndarray, p_m: np.ndarray, window_s: float = 0.3) -> np.ndarray:
    """Velocity guess [K, 3]: local quadratic fits (Savitzky-Golay) over ~``window_s``.

    Plain differences of noisy poses (5 mm at 30 Hz: 0.15 m/s) start LM thousands
    of sigmas away from the IMU factors and cost many iterations.
    """
    K = len(t_s)
    if K < 2:
        return np.zeros((K, 3))
    if K < 7:
        return np.gradient(p_m, t_s, axis=0)
    dt = float(np.median(np.diff(t_s)))
    win = int(round(window_s / max(dt, 1e-4))) | 1
    win = max(5, min(win, K if K % 2 else K - 1))
    vel = _savgol(np.asarray(p_m, dtype=float), win, dt, deriv=1)
    # irregular stamps (dropouts): fall back to differences where the grid assumption breaks
    irregular = np.abs(np.diff(t_s) - dt) > 0.5 * dt
    if irregular.any():
        bad = np.zeros(K, dtype=bool)
        for i in np.nonzero(irregular)[0]:
            bad[max(0, i - win // 2):min(K, i + win // 2 + 2)] = True
        vel[bad] = np.gradient(p_m, t_s, axis=0)[bad]
    return vel


def propagate_orientations(
    samples: MidpointSamples,
    q_wxyz: np.ndarray,
    known: np.ndarray,
    bias_gyro: np.ndarray,
) -> np.ndarray:
    """Fill unknown keyframe orientations by gyro integration from the last known one (rows
    before the first known one: backwards from it).

    Args:
        samples: The window's midpoint samples.
        q_wxyz: Orientations [K, 4]; rows where ``known`` is False are overwritten.
        known: Mask [K]; at least one row must be known.
        bias_gyro: Gyro bias subtracted while integrating, [3].

    Returns:
        Orientations [K, 4] (wxyz).
    """
    out = np.array(q_wxyz, dtype=float, copy=True)
    known = np.asarray(known, dtype=bool)
    if not known.any():
        return out
    last = np.maximum.accumulate(np.where(known, np.arange(len(out)), -1))  # last known row at or before
    last[last < 0] = int(np.argmax(known))
    fill = np.nonzero(~known)[0]
    if len(fill):
        gyro = gyro_keyframe_rotations(samples, bias_gyro)
        src = last[fill]
        R_known = Rotation.from_quat(out[src][:, [1, 2, 3, 0]])
        out[fill] = (R_known * gyro[src].inv() * gyro[fill]).as_quat(scalar_first=True)
    return out


def gyro_keyframe_rotations(samples: MidpointSamples, bias_gyro: np.ndarray | None = None) -> Rotation:
    """The gyro's orientation at each keyframe relative to the first (``bias_gyro`` [3] subtracted;
    zero if None), [K].

    The sub-interval rotations ``Exp(omega_j dt_j)`` composed in order: vectorised over the
    keyframe intervals within them, then interval by interval (one rotation per sample through
    scipy costs ~40 us: seconds per solve of a 20-Hz position stream).
    """
    start = np.asarray(samples.start)
    K = len(start)
    n = np.diff(start)
    rel = np.broadcast_to(np.eye(3), (max(K - 1, 0), 3, 3)).copy()
    gyro = samples.gyro_radps if bias_gyro is None else samples.gyro_radps - np.asarray(bias_gyro, dtype=float)
    steps = gyro * samples.dt_s[:, None]
    for j in range(int(n.max()) if K > 1 else 0):
        act = np.nonzero(n > j)[0]
        rel[act] = rel[act] @ Rotation.from_rotvec(steps[start[act] + j]).as_matrix()
    out = np.empty((K, 3, 3))
    out[0] = np.eye(3)
    for i in range(K - 1):
        out[i + 1] = out[i] @ rel[i]
    return Rotation.from_matrix(out)


def initial_orientations(
    samples: MidpointSamples,
    kf: KeyframePoses,
    gravity_mps2: float,
    window_s: float = 8.0,
) -> np.ndarray:
    """Orientation guess for position-only sources, [K, 4] wxyz.

    Integrates the gyro (zero bias) and, per window of ``window_s``, solves
    Wahba's problem between world accelerations (second differences of the
    positions plus gravity) and the gyro-propagated specific force.
    """
    K = len(kf)
    # Gyro-propagated relative orientations at keyframes and specific force at keyframes.
    rel = gyro_keyframe_rotations(samples)
    f_kf = np.zeros((K, 3))
    if K > 1:
        f_kf[:-1] = samples.acc_mps2[np.minimum(samples.start[:-1], len(samples.dt_s) - 1)]
        f_kf[-1] = f_kf[-2]
    t = (kf.t_ns - kf.t_ns[0]) / NS_PER_S
    # world acceleration by smoothed differences
    if K >= 9:
        dt = float(np.median(np.diff(t))) if K > 1 else 0.05
        win = max(5, int(round(0.5 / max(dt, 1e-3))) | 1)
        win = min(win, K - (1 - K % 2))
        acc_w = _savgol(kf.p_m, win, dt, deriv=2)
    else:
        acc_w = np.zeros((K, 3))
    g = np.array([0.0, 0.0, -gravity_mps2])
    out = np.zeros((K, 4))
    edges = np.arange(0.0, t[-1] + window_s, window_s)
    prev = None
    measured = np.ones(K, dtype=bool) if kf.measured is None else kf.measured
    for w0 in edges:
        idx = np.nonzero((t >= w0) & (t < w0 + window_s))[0]
        if len(idx) == 0:
            continue
        m = idx[measured[idx]]  # keyframes in pose gaps have no measured acceleration
        a_vec = acc_w[m] - g  # = R f
        b_vec = rel[m].apply(f_kf[m])  # = R_rel f ; world = R0 R_rel f
        try:
            R0, _ = Rotation.align_vectors(a_vec, b_vec)
        except Exception:  # degenerate window (or no measured keyframe in it)
            R0 = prev if prev is not None else Rotation.identity()
        prev = R0
        q = (R0 * rel[idx]).as_quat()
        out[idx] = np.c_[q[:, 3], q[:, :3]]
    return out


_BIAS_POOL: list[gtsam.Values] = []  # one Values of zero biases B(0..n-1), grown on demand


def _bias_values(bias: np.ndarray, K: int) -> gtsam.Values:
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
) -> _Built:
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
    built = _Built(gtsam.NonlinearFactorGraph(), _bias_values(bias0, len(kf)), [], [], 0.0)
    vel = _initial_velocities(kf, Xs, init)
    if kf.measured is not None and init.values is None:
        Xs, vel = bridge_gaps(pims, Xs, vel, kf.t_ns, kf.measured)
    for k in range(len(kf)):
        built.values.insert(X(k), Xs[k])
        built.values.insert(V(k), vel[k])
    _add_imu_factors(built, pims, opts, init, bias0, models)
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


def _add_imu_factors(built: _Built, pims: list[Any], opts: SolveOptions, init: WindowInit, bias0: np.ndarray,
                     models: list[Any] | None = None) -> None:
    """The IMU factors between consecutive keyframes (gravity direction as a variable when estimated,
    with its prior) and the prior on the first bias. ``models``: noise models replacing the
    preintegrated covariances (:class:`recovery.preintegration.NoiseBasis`)."""
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


def _add_pose(built: _Built, k: int, factor: Any, base: Any) -> None:
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
            self.cache[(kind, n)] = (base, _robust(base, self.opts.robust_loss, self.opts.robust_k))
        return self.cache[(kind, n)]


def _add_pose_factors(built: _Built, kf: KeyframePoses, Xs: list[Any], Z: list[Any] | None, T_imu_pose: np.ndarray,
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


def _add_position_factors(built: _Built, kf: KeyframePoses, T_imu_pose: np.ndarray, opts: SolveOptions,
                          skip: set[int]) -> None:
    """Position-only streams: the tracked point at the lever arm (a variable with ``estimate_extrinsic``)."""
    base = gtsam.noiseModel.Isotropic.Sigma(3, opts.position_sigma_m)
    model = _robust(base, opts.robust_loss, opts.robust_k)
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


def _add_lever_arm_factors(built: _Built, kf: KeyframePoses, Z: list[Any], T_imu_pose: np.ndarray,
                           opts: SolveOptions, skip: set[int]) -> None:
    """z = X E with R_E fixed: rotation prior on X (R_z R_E^T, isotropic noise stays isotropic) and a
    position-with-lever-arm factor on (X, L) -- both native GTSAM factors, cheap at any rate."""
    sr, sp = opts.rotation_sigma_rad, opts.position_sigma_m
    models = _FusedModels(kf, opts)
    built.values.insert(L(0), np.asarray(T_imu_pose, dtype=float)[:3, 3].copy())
    _add_lever_arm_prior(built, opts)
    R_Et = _pose3(T_imu_pose).rotation().inverse()
    for k in range(len(kf)):
        if k in skip:
            continue
        base_r, model_r = models.get("r", k, lambda n: gtsam.noiseModel.Isotropic.Sigma(3, sr / math.sqrt(n)))
        base_p, model_p = models.get("p", k, lambda n: gtsam.noiseModel.Isotropic.Sigma(3, sp / math.sqrt(n)))
        _add_pose(built, k, gtsam.PoseRotationPrior3D(X(k), Z[k].rotation().compose(R_Et), model_r), base_r)
        _add_pose(built, k, gtsam.GPSFactorArmCalib(X(k), L(0), kf.p_m[k], model_p), base_p)


def _add_lever_arm_prior(built: _Built, opts: SolveOptions) -> None:
    """The calibration's lever arm as a prior on ``L(0)`` (with ``extrinsic_prior``)."""
    if opts.extrinsic_prior is None:
        return
    T_prior, sigmas = opts.extrinsic_prior
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float)[3:])
    built.graph.add(gtsam.PriorFactorPoint3(L(0), np.asarray(T_prior, dtype=float)[:3, 3], prior))
    built.neg_log_const += prior.negLogConstant()


def _add_relative_factors(built: _Built, Xs: list[Any], T_imu_pose: np.ndarray, opts: SolveOptions,
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
    model = _robust(base, opts.robust_loss, opts.robust_k)
    for k in range(K):
        if k in skip:
            continue
        for j in range(k + 1, min(K, k + h + 1)):
            if j not in skip:
                _add_pose(built, j, gtsam.BetweenFactorPose3(X(k), X(j), Xs[k].between(Xs[j]), model), base)


def _add_absolute_factors(built: _Built, kf: KeyframePoses, Xs: list[Any], Z: list[Any], T_imu_pose: np.ndarray,
                          opts: SolveOptions, skip: set[int]) -> None:
    """6-DoF absolute poses: a prior on each IMU pose, or (extrinsic estimated) z = X E with E a variable;
    with a correlated error model, its states ``N(k)`` enter each factor (:mod:`recovery.pose_error`)."""
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


def _add_velocity_priors(built: _Built, kf: KeyframePoses, opts: SolveOptions, skip: set[int]) -> None:
    """The fused keyframes' velocities (the bins' line fits): std sigma_p / sqrt(sum dt^2), decoupled
    from the position because the keyframe sits at the bin's mean sample time, and widened by the
    slope a correlated position error puts into the fit (:func:`recovery.pose_error.velocity_fit_variance`).
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
        f = gtsam.PriorFactorVector(V(k), kf.v_mps[k], _robust(base, opts.robust_loss, opts.robust_k))
        _add_pose(built, k, f, base)


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


def _lm(built: _Built, values: gtsam.Values, order: gtsam.Ordering) -> Any:
    params = gtsam.LevenbergMarquardtParams()
    params.setOrdering(order)
    return gtsam.LevenbergMarquardtOptimizer(built.graph, values, params)


def _optimize(built: _Built, opts: SolveOptions, keep_linearisation: bool = False
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
                _refuse_unconverged(built, optimizer.values(), order, errors[-1])
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


def _refuse_unconverged(built: _Built, values: gtsam.Values, order: gtsam.Ordering, cost: float) -> None:
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


def log_evidence(built: _Built, values: gtsam.Values) -> float:
    """Laplace approximation of log p(measurements | noise model), up to a constant.

    ``-E(x*) - sum_f negLogConstant_f - 0.5 log det H``; the constant ``n/2 log 2 pi``
    is the same for every noise hypothesis on the same graph.
    """
    gfg = built.graph.linearize(values)
    bn = gfg.eliminateSequential(elimination_order(values))
    return -built.graph.error(values) - built.neg_log_const - bn.logDeterminant()


def _reweighted(prev: _Built, basis: NoiseBasis, imu_noise: ImuNoise, opts: SolveOptions,
                init: WindowInit) -> _Built:
    """``prev`` (a window built on ``basis``) with its IMU part built again for ``imu_noise`` and
    ``init`` (the IMU factors' noise models, the bias and gravity priors' centres) and every other
    factor shared, starting at ``init.values``: what :func:`build_window` would build, without
    building the pose factors and initial values again."""
    bias0 = np.zeros(6) if init.bias is None else np.asarray(init.bias, dtype=float)
    built = _Built(gtsam.NonlinearFactorGraph(), gtsam.Values(), prev.pose_factors, [], 0.0)
    _add_imu_factors(built, basis.pims, opts, init,
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
    like: _Built | None = None,
) -> tuple[float, WindowInit, _Built] | None:
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
    built = build_window(samples, kf, imu_noise, T_imu_pose, opts, init, basis=basis)
    want_marginals = opts.compute_marginals or opts.marginal_extras or opts.offset_sensitivity
    result, iters, lin = _optimize(built, opts, keep_linearisation=want_marginals)
    outliers = np.zeros(0, dtype=int)
    pose_norms = None
    if opts.reject_outliers and built.pose_factors:
        norms = _whitened_norms(built.pose_factors, result)
        bad = norms > opts.outlier_threshold
        pose_norms = norms  # still valid unless the window is solved again below
        if bad.any():
            pose_norms = None
            outliers = np.unique([built.pose_factors[i][0] for i in np.nonzero(bad)[0]])
            if len(outliers) > 0.2 * K:
                log.warning("%d of %d pose factors exceed %.1f sigma: the pose noise may be underestimated",
                            len(outliers), K, opts.outlier_threshold)
            init2 = _init_from(result, K, opts, init)
            built = build_window(samples, kf, imu_noise, T_imu_pose, opts, init2, skip=outliers, basis=basis)
            built.values = result_subset(result, built.values)
            result, iters, lin = _optimize(built, opts, keep_linearisation=want_marginals)
    cost = float(built.graph.error(result))
    if not math.isfinite(cost):
        raise RecoveryError("the optimisation diverged (non-finite cost)",
                            hint="check the pose stream, its clock offset and the extrinsic")
    if pose_norms is None:
        pose_norms = (_whitened_norms(built.pose_factors, result) if built.pose_factors and opts.residuals
                      else np.zeros(0))
    pose_rms = float(np.sqrt(np.mean(pose_norms**2))) if len(pose_norms) else float("nan")
    imu_sq = []
    for f in built.imu_factors if opts.residuals else []:
        r = f.whitenedError(result)
        imu_sq.append(float(r @ r) / len(r))
    imu_rms = float(np.sqrt(np.mean(imu_sq))) if imu_sq else float("nan")
    # Per keyframe, for plots over time: the whitened RMS of its pose factor(s) and of the IMU
    # factor that ends at it (factor k links keyframes k and k+1).
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

    P, Q, Vv = _keyframe_states(result, K)
    bias = _keyframe_biases(result, K)
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


def _marginals(built: _Built, result: gtsam.Values, samples: MidpointSamples, kf: KeyframePoses,
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


def _linearised_at_optimum(built: _Built, result: gtsam.Values, lin: _Linearised | None
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


def _calibration_columns(built: _Built, samples: MidpointSamples, kf: KeyframePoses,
                         state: tuple[np.ndarray, np.ndarray, np.ndarray], T_imu_pose: np.ndarray, opts: SolveOptions
                         ) -> tuple[list[tuple[int, int, str]], tuple[np.ndarray, np.ndarray]] | None:
    """The pose and velocity factors ``(graph index, keyframe, kind)`` and their measurement columns
    in the calibration (:func:`recovery.calibration_uncertainty.measurement_columns`) at the optimum
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


def _calibration_variance(gfg: gtsam.GaussianFactorGraph, tree: gtsam.GaussianBayesTree | None, built: _Built,
                          result: gtsam.Values, samples: MidpointSamples,
                          kf: KeyframePoses, state: tuple[np.ndarray, np.ndarray, np.ndarray],
                          T_imu_pose: np.ndarray, opts: SolveOptions, idx: np.ndarray) -> np.ndarray | None:
    """Bias variance [len(idx), 6] (gyro, acc) added by the uncertainty of the fixed calibration
    (:mod:`recovery.calibration_uncertainty`; ``tree``: ``gfg`` eliminated, or None); None when
    there is none or the factors are not 6-DoF absolute."""
    cols = None if opts.calibration_cov is None else _calibration_columns(built, samples, kf, state, T_imu_pose, opts)
    if cols is None:
        return None
    return added_bias_variance(gfg, cols[0], cols[1], opts.calibration_cov, [B(int(k)) for k in idx],
                               elimination_order(result) if tree is None else None, tree=tree,
                               zero=None if tree is None else result.zeroVectors())


def _offset_sensitivity(built: _Built, result: gtsam.Values, samples: MidpointSamples, kf: KeyframePoses,
                        state: tuple[np.ndarray, np.ndarray, np.ndarray], T_imu_pose: np.ndarray, opts: SolveOptions,
                        extras: dict[str, Any], lin: _Linearised | None) -> None:
    """``extras["offset_slope"]`` / ``["offset_information"]``: the cost's slope and information in
    the clock offset (:func:`recovery.calibration_uncertainty.parameter_slope_and_information`),
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
