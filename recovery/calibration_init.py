"""Initial estimates that bias recovery needs before its factor graph.

Everything here is a closed-form or one-dimensional-search estimator that needs no
initial guess; the GTSAM graph (:mod:`recovery.graph`) refines the results.

Conventions:
    * ``offset_s`` is the number of seconds to ADD to pose stamps to put them on the
      IMU clock: a pose stamped ``t`` was taken at IMU time ``t + offset_s``.
    * ``R_imu_pose`` [3, 3] maps vectors from the tracked (pose) frame to the IMU frame,
      so ``omega_imu = R_imu_pose @ omega_pose`` and ``R_world_imu = R_world_pose @ R_imu_pose.T``.
    * ``p_imu_pose_m`` [3] is the position of the tracked point in the IMU frame
      (``T_imu_pose[:3, 3]``): ``p_pose_world = p_imu_world + R_world_imu @ p_imu_pose_m``.
    * Gravity is the gravity *acceleration* vector in the pose world frame (it points
      down: ``[0, 0, -9.81]`` in a z-up world); the accelerometer measures the specific
      force ``f = R_imu_world @ (a - g) + b_a``.

Methods, with their accuracy measured on ``pipeline.sim`` (60 s, handheld preset, IMU
200 Hz with EuRoC noise and a drifting bias, mocap 100 Hz with 0.5 mm / 0.5 mrad noise,
15 deg / 10 cm extrinsic; see ``tests/test_calibration_init.py``):
    * time offset (method ``"rotation"``): FFT cross-correlation of ``|omega|`` from the gyro
      and from the poses (rotation invariant, so no extrinsic is needed), both mean rates over
      ``CORRELATION_WINDOW_S`` (a rate from one pair of 100-Hz mocap attitudes is mostly noise),
      on a uniform grid with a parabolic sub-sample step. The gyro bias skews ``|omega_imu|`` (2-9 ms error
      on handheld motion), so a joint (R, b_g) fit at that offset gives the bias and the
      correlation is repeated on bias-free rates; finally a continuous 1-D search (+-3 grid
      steps) minimises the residual of the full vector fit ``omega_imu = R omega_pose + b_g``
      (closed-form Kabsch cost per offset) between 50-ms window-averaged pose rates and the
      exact mean gyro rate over the shifted windows (cumulative gyro integral). Error
      < 0.1 ms (handheld, drone); 4-26 ms on the near-planar slow cart preset, whose
      rotation is flagged unobservable. Std: scatter of 6 per-chunk estimates / sqrt(6).
    * time offset, position-only streams (method ``"position"``): ``|f|^2`` from the IMU is
      rotation invariant and equals ``|a_world - g|^2``. For each lag a 4-parameter linear
      least-squares fit ``|f|^2 - |a|^2 = -2 a.g + |g|^2`` (unknown world gravity) is scored
      by its R^2, all lags at once through FFT correlations; accelerations are 50-ms
      Gaussian second derivatives of the positions and ``|f|^2`` is smoothed by the same
      kernel. Error (20 Hz Leica-like positions, 10 cm lever arm): < 1 ms for the drone,
      2-18 ms for handheld motion, within 3 std. Coarse: the graph must refine it.
    * extrinsic rotation: Kabsch/Wahba (``Rotation.align_vectors``) on centred rates, the
      exact joint least-squares solution for the rotation and a constant gyro bias; first
      per pose interval with 5-MAD rejection (drops pose glitches such as the 20-Hz
      correction jumps in EuRoC's ground truth), then on 50-ms averages of the good
      intervals. Error 0.002-0.03 deg; gyro bias to 5e-5 rad/s.
    * lever arm: linear least squares on second differences of positions,
      ``D2[p_pose] = D2[AA(R_wi f)] - D2[AA(R_wi) b_a] + D2[t^2/2] g + D2[R_wi] r``, where
      ``AA`` is the double time integral over the IMU samples and ``D2`` the second difference
      over +-h (0.3 s). This is the exact double integral of the rigid-body relation
      ``a_pose = a_imu + d^2/dt^2 (R_wi r)``, so no angular acceleration and no numerical
      second derivative of noisy positions are needed. Unknowns: r, g and a piecewise-linear
      accelerometer bias b_a(t) (knots every 5 s; with a constant bias the simulated warm-up
      drift gave 3-6 cm errors). Error 0.6-1.4 cm (0.04-0.1 cm without bias drift).
    * gravity: from the same least squares (optionally with the lever arm fixed); the
      direction is what is reliable (a vertical bias is confounded with ``|g|`` when level).
      Direction error 0.03-0.09 deg.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.fft import irfft, next_fast_len, rfft
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation, Slerp

from pipeline.errors import DataError, RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.rotations import relative_rotvecs

log = logging.getLogger(__name__)

__all__ = [
    "TimeOffsetEstimate",
    "RotationEstimate",
    "LeverArmEstimate",
    "GravityEstimate",
    "pose_angular_rates",
    "estimate_time_offset",
    "estimate_extrinsic_rotation",
    "estimate_lever_arm",
    "find_static_segments",
    "estimate_gravity",
    "estimate_gravity_direction",
]

#: Below this correlation the time-offset peak is not trusted.
MIN_CORRELATION = 0.5
#: The |omega| correlation compares mean rates over windows of this length.
CORRELATION_WINDOW_S = 0.1
#: Below this ratio of the smallest to largest eigenvalue of the rate covariance the
#: extrinsic rotation is reported unobservable (rate std ratio ~ 0.1).
MIN_ROTATION_CONDITION = 1e-2
#: The lever arm is reported unobservable when any axis std exceeds this.
MAX_LEVER_ARM_STD_M = 0.05
#: Shortest common span of IMU and poses worth estimating anything on.
MIN_OVERLAP_S = 5.0
_N_CHUNKS = 6


@dataclass(frozen=True)
class TimeOffsetEstimate:
    """Clock offset between a pose stream and the IMU.

    Attributes:
        offset_s: Seconds to ADD to pose stamps to put them on the IMU clock.
        std_s: 1-sigma uncertainty (scatter of independent per-chunk estimates / sqrt(n)).
        correlation: Peak normalised correlation (``"rotation"``) or sqrt(R^2) of the
            gravity fit (``"position"``), in [0, 1].
        method: ``"rotation"`` (|omega| correlation) or ``"position"`` (|f| vs positions).
    """

    offset_s: float
    std_s: float
    correlation: float
    method: str


@dataclass(frozen=True)
class RotationEstimate:
    """Extrinsic rotation between the tracked frame and the IMU.

    Attributes:
        R_imu_pose: Rotation from the tracked frame to the IMU frame, [3, 3].
        residual_deg: RMS residual of the rate fit, in deg/s (window-averaged rates; not
            an angle error).
        observable: False when the rotation excitation is degenerate.
        condition: Smallest / largest eigenvalue of the covariance of the gyro rates.
        gyro_bias_radps: The constant gyro bias solved jointly, [3].
    """

    R_imu_pose: np.ndarray
    residual_deg: float
    observable: bool
    condition: float
    gyro_bias_radps: np.ndarray | None = None


@dataclass(frozen=True)
class LeverArmEstimate:
    """Position of the tracked point in the IMU frame.

    Attributes:
        p_imu_pose_m: The lever arm, [3].
        std_m: 1-sigma per axis (least-squares covariance, inflated for window overlap), [3].
        observable: False when the rotational excitation does not fix it (std > 5 cm).
        gravity_world_mps2: Gravity vector in the pose world frame solved jointly, [3].
        acc_bias_mps2: Mean of the accelerometer bias solved jointly, [3].
        acc_bias_t_ns: IMU-clock stamps of the bias knots, int64 [K].
        acc_bias_knots_mps2: Accelerometer bias at the knots (linear in between), [K, 3].
    """

    p_imu_pose_m: np.ndarray
    std_m: np.ndarray
    observable: bool
    gravity_world_mps2: np.ndarray | None = None
    acc_bias_mps2: np.ndarray | None = None
    acc_bias_t_ns: np.ndarray | None = None
    acc_bias_knots_mps2: np.ndarray | None = None


@dataclass(frozen=True)
class GravityEstimate:
    """Gravity in the pose world frame.

    Attributes:
        direction: Unit vector of the gravity acceleration (points down), [3].
        magnitude_mps2: Its norm.
        std_rad: 1-sigma angular uncertainty of ``direction``.
        method: ``"acc_lstsq"`` (the second-difference least squares).
    """

    direction: np.ndarray
    magnitude_mps2: float
    std_rad: float
    method: str


# ----------------------------------------------------------------------------- helpers


def _pose_name(poses: PoseSeries) -> str:
    return f"poses (frame '{poses.frame}', {poses.source_kind.value})"


def _check_increasing(t_ns: np.ndarray, name: str, min_len: int = 3) -> None:
    if len(t_ns) < min_len:
        raise DataError(f"{name} has {len(t_ns)} samples, need at least {min_len}", field=name,
                        hint="give a longer recording")
    if np.any(np.diff(t_ns) <= 0):
        raise DataError(f"{name} stamps are not strictly increasing", field=name,
                        hint="run 'biasgt convert' so the input checks sort and deduplicate the stream")


def _cumtrapz(y: np.ndarray, x: np.ndarray, axis: int = 0, initial: float = 0.0) -> np.ndarray:
    """``scipy.integrate.cumulative_trapezoid(y, x, axis=0, initial=0)`` in numpy (axis 0 only).

    Kept local: scipy.integrate and scipy.signal add ~50 MB of RSS to every recovery run.
    """
    if axis != 0:
        raise ValueError("axis must be 0")
    y = np.asarray(y, dtype=float)
    dx = np.diff(np.asarray(x, dtype=float)).reshape((-1,) + (1,) * (y.ndim - 1))
    out = np.empty_like(y)
    out[0] = initial
    np.cumsum(0.5 * dx * (y[1:] + y[:-1]), axis=0, out=out[1:])
    if initial != 0.0:
        out[1:] += initial
    return out


def _correlate_valid(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``scipy.signal.correlate(a, v)`` for real 1-D, len(a) >= len(v):
    ``out[k] = sum_l a[l + k] v[l]``, [len(a) - len(v) + 1]."""
    n, m = len(a), len(v)
    size = next_fast_len(n + m - 1, real=True)
    full = irfft(rfft(a, size) * np.conj(rfft(v, size)), size)
    return full[: n - m + 1]


def pose_rotations(poses: PoseSeries) -> Rotation:
    """The stream's orientations ``R_world_<frame>`` [N].

    Raises:
        DataError: the stream has no orientation, or a zero or non-finite quaternion.
    """
    if poses.quat_wxyz is None:
        raise DataError(f"{_pose_name(poses)} has no orientation", field="quat_wxyz",
                        hint="this estimate needs a 6-DoF pose stream (mocap, VIO or ground truth)")
    q = poses.quat_wxyz
    norms = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(norms)) or np.any(norms < 1e-6):
        raise DataError(f"{_pose_name(poses)} has zero or non-finite quaternions", field="quat_wxyz",
                        hint="run 'biasgt convert' to drop invalid pose rows")
    return Rotation.from_quat(q, scalar_first=True)


def gyro_integral(imu: ImuSeries, t_ref_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Times [N] (s, relative to t_ref_ns) and the cumulative gyro integral [N, 3] (rad)."""
    t_s = (imu.t_ns - t_ref_ns) / NS_PER_S
    return t_s, _cumtrapz(imu.gyro_radps, t_s, axis=0, initial=0.0)


def _interp_cols(t: np.ndarray, tp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Linear interpolation of fp [N, ...] (rows at increasing tp [N]) at t [M] -> [M, ...].

    np.interp (clamped at the ends) column by column: its search starts from the previous
    query's interval, a third faster on sorted queries than one searchsorted and two gathers.
    """
    fp = np.asarray(fp, dtype=float)
    flat = fp.reshape(len(fp), -1)
    out = np.empty((len(t), flat.shape[1]))
    for c in range(flat.shape[1]):
        out[:, c] = np.interp(t, tp, flat[:, c])
    return out.reshape((len(t),) + fp.shape[1:])


def _mean_gyro(t0_s: np.ndarray, t1_s: np.ndarray, t_imu_s: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Exact mean gyro rate over [t0, t1] (trapezoid model), [M, 3]."""
    return (_interp_cols(t1_s, t_imu_s, G) - _interp_cols(t0_s, t_imu_s, G)) / (t1_s - t0_s)[:, None]


def _overlap(imu: ImuSeries, poses: PoseSeries, offset_s: float, margin_s: float) -> tuple[float, float]:
    """Common span on the IMU clock, shrunk by margin, in ns (floats); raises if too short."""
    p0 = poses.t_ns[0] + offset_s * NS_PER_S
    p1 = poses.t_ns[-1] + offset_s * NS_PER_S
    a = max(float(imu.t_ns[0]), float(p0)) + margin_s * NS_PER_S
    b = min(float(imu.t_ns[-1]), float(p1)) - margin_s * NS_PER_S
    if b - a < MIN_OVERLAP_S * NS_PER_S:
        raise RecoveryError(
            f"imu and {_pose_name(poses)} overlap for only {max(b - a, 0) / NS_PER_S:.2f} s "
            f"(imu {imu.t_ns[0]}..{imu.t_ns[-1]} ns, poses {poses.t_ns[0]}..{poses.t_ns[-1]} ns, "
            f"offset {offset_s:+.3f} s, margin {margin_s:.2f} s; need {MIN_OVERLAP_S:.0f} s)",
            field="t_ns",
            hint="check that both streams are on the same clock epoch, or give --time-offset-s",
        )
    return a, b


def _box_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over n samples along axis 0 ('valid' part)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    return (c[n:] - c[:-n]) / n


# ----------------------------------------------------------------------------- rates


def pose_angular_rates(poses: PoseSeries, *, smooth_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame angular rate of the tracked frame from its orientations.

    ``omega_k = Log(R_k^T R_{k+1}) / (t_{k+1} - t_k)`` at the interval mid-times, which is
    the mean body rate over the interval to second order; quaternion sign flips do not
    matter because the relative rotation is formed as a rotation.

    Args:
        poses: A 6-DoF pose stream with strictly increasing stamps.
        smooth_s: Optional centred moving-average width in seconds (0: none).

    Returns:
        ``t_ns`` int64 [M] (interval mid-times on the pose clock) and ``omega_body_radps`` [M, 3].

    Raises:
        DataError: No orientation, fewer than 3 poses, or non-increasing stamps.
    """
    rot = pose_rotations(poses)
    _check_increasing(poses.t_ns, _pose_name(poses))
    dt_s = np.diff(poses.t_ns) / NS_PER_S
    omega = relative_rotvecs(rot) / dt_s[:, None]
    t_mid = poses.t_ns[:-1] + np.diff(poses.t_ns) // 2
    if smooth_s > 0:
        n = int(round(smooth_s / np.median(dt_s)))
        if n > 1:
            kernel = np.ones(n) / n
            omega = np.stack([np.convolve(omega[:, j], kernel, mode="same") for j in range(3)], axis=1)
    return t_mid.astype(np.int64), omega


# ----------------------------------------------------------------------------- time offset


def _parabolic(y: np.ndarray, k: int) -> float:
    """Sub-sample peak position around index k (0 < k < len-1)."""
    a, b, c = y[k - 1], y[k], y[k + 1]
    den = a - 2 * b + c
    return 0.0 if den == 0 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))


def _sliding_std(y: np.ndarray, n: int) -> np.ndarray:
    c1 = np.concatenate([[0.0], np.cumsum(y)])
    c2 = np.concatenate([[0.0], np.cumsum(y * y)])
    m = (c1[n:] - c1[:-n]) / n
    return np.sqrt(np.maximum((c2[n:] - c2[:-n]) / n - m * m, 0.0))


def _lag_correlation(x: np.ndarray, y_ext: np.ndarray) -> np.ndarray:
    """Pearson correlation of x [N] with every length-N window of y_ext [N + 2K] -> [2K + 1]."""
    n = len(x)
    xc = x - x.mean()
    sx = xc.std()
    sy = _sliding_std(y_ext, n)
    c = _correlate_valid(y_ext, xc)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = c / (n * sx * sy)
    return np.nan_to_num(r, nan=-1.0)


def _kabsch_cost(X: np.ndarray, Y: np.ndarray) -> float:
    """min over R, b of sum |Y - R X - b|^2 (closed form via the SVD of the 3x3 cross-covariance)."""
    Xc, Yc = X - X.mean(0), Y - Y.mean(0)
    U, S, Vt = np.linalg.svd(Yc.T @ Xc)
    d = np.sign(np.linalg.det(U @ Vt))
    return float(np.sum(Xc * Xc) + np.sum(Yc * Yc) - 2 * (S[0] + S[1] + d * S[2]))


def _rotation_offset(imu: ImuSeries, poses: PoseSeries, max_offset_s: float, resample_hz: float | None,
                     min_correlation: float, window_s: float = 0.05) -> TimeOffsetEstimate:
    t_ref = int(imu.t_ns[0])
    t_imu_s, G = gyro_integral(imu, t_ref)
    t_pose_s = (poses.t_ns - t_ref) / NS_PER_S
    rot = pose_rotations(poses)
    dt_p = np.diff(t_pose_s)
    rv = relative_rotvecs(rot)
    x_native = np.linalg.norm(rv / dt_p[:, None], axis=1)
    if np.std(x_native) < 1e-6:
        raise RecoveryError(f"{_pose_name(poses)} does not rotate (constant orientation)", field="quat_wxyz",
                            hint="the clock offset cannot be found without motion; give --time-offset-s")
    if np.std(np.linalg.norm(imu.gyro_radps, axis=1)) < 1e-6:
        raise RecoveryError("imu gyro signal is constant", field="gyro_radps",
                            hint="check the IMU stream (units, saturation) or give --time-offset-s")

    a_ns, b_ns = _overlap(imu, poses, 0.0, max_offset_s)
    rate = float(resample_hz) if resample_hz else float(np.clip(poses.rate_hz, 20.0, 400.0))
    dt = 1.0 / rate
    K = int(np.ceil(max_offset_s / dt))
    tg = np.arange((a_ns - t_ref) / NS_PER_S, (b_ns - t_ref) / NS_PER_S, dt)
    h = float(np.median(dt_p))
    crv = np.concatenate([np.zeros((1, 3)), np.cumsum(rv, axis=0)])
    # |omega| over CORRELATION_WINDOW_S: a rate differenced from one pair of mocap attitudes carries
    # their noise over one interval (EuRoC's 100-Hz Vicon: ~0.4 rad/s, a correlation of 0.3)
    nc = max(1, int(round(CORRELATION_WINDOW_S / h)))
    hc = nc * h
    x_window = np.linalg.norm(crv[nc:] - crv[:-nc], axis=1) / (t_pose_s[nc:] - t_pose_s[:-nc])
    x = np.interp(tg, 0.5 * (t_pose_s[nc:] + t_pose_s[:-nc]), x_window)
    tg_ext = tg[0] + dt * np.arange(-K, len(tg) + K)
    # Pose intervals inside the overlap, and window sums over n of them (pose side is fixed).
    idx = np.flatnonzero((t_pose_s[:-1] >= tg[0]) & (t_pose_s[1:] <= tg[-1]))
    n = max(1, int(round(window_s / h)))
    j0 = idx[: len(idx) - n + 1]  # windows [t_j, t_{j+n}], all inside
    w_pose = (crv[j0 + n] - crv[j0]) / (t_pose_s[j0 + n] - t_pose_s[j0])[:, None]

    def w_imu(tau: float, sel: np.ndarray, Gb: np.ndarray) -> np.ndarray:
        return _mean_gyro(t_pose_s[j0[sel]] + tau, t_pose_s[j0[sel] + n] + tau, t_imu_s, Gb)

    def coarse(Gb: np.ndarray) -> tuple[float, float, int]:
        y_ext = np.linalg.norm(_mean_gyro(tg_ext - hc / 2, tg_ext + hc / 2, t_imu_s, Gb), axis=1)
        r = _lag_correlation(x, y_ext)
        k = int(np.argmax(r))
        if k <= 1 or k >= len(r) - 2:
            raise RecoveryError(
                f"time-offset peak between imu and {_pose_name(poses)} is at the search boundary "
                f"({(k - K) * dt:+.3f} s of +-{max_offset_s:.3f} s, correlation {r[k]:.2f})",
                field="t_ns", hint="increase max_offset_s, or give --time-offset-s")
        return (k - K + _parabolic(r, k)) * dt, float(r[k]), k

    # Pass 1: |omega| correlation; the gyro bias skews |omega_imu| (by b . omega_hat).
    tau0, _, _ = coarse(G)
    # Joint R, b at tau0 (b barely depends on the offset), then pass 2 without the bias.
    all_sel = np.arange(len(j0))
    _, bias, _, _ = _kabsch_with_bias(w_imu(tau0, all_sel, G), w_pose)
    Gb = G - np.outer(t_imu_s, bias)
    tau1, corr, _ = coarse(Gb)
    if corr < min_correlation:
        raise RecoveryError(
            f"|omega| of imu and {_pose_name(poses)} correlate only {corr:.2f} (< {min_correlation})",
            field="t_ns", hint="check that the streams belong to the same rigid body and overlap in time, "
            "or give --time-offset-s")

    # Pass 3: full vector fit omega_imu = R omega_pose + b, continuous in tau.
    def refine(sel: np.ndarray, centre: float, half: float, xatol: float) -> float:
        res = minimize_scalar(lambda tau: _kabsch_cost(w_pose[sel], w_imu(tau, sel, G)),
                              bounds=(centre - half, centre + half), method="bounded",
                              options={"xatol": xatol})
        return float(res.x)

    tau = refine(all_sel, tau1, 3 * dt, 1e-6)
    chunks = [c for c in np.array_split(all_sel, _N_CHUNKS) if len(c) > 10]
    est = np.array([refine(c, tau, 3 * dt, 1e-5) for c in chunks])
    std = float(np.std(est, ddof=1) / np.sqrt(len(est))) if len(est) > 1 else dt
    log.info("time offset (rotation) %+.6f s +- %.6f s (|omega| pass %+.6f s), correlation %.3f",
             tau, std, tau1, corr)
    return TimeOffsetEstimate(tau, std, corr, "rotation")


def _position_r2(acc: np.ndarray, u: np.ndarray) -> np.ndarray:
    """R^2 per lag of ``u[n + k] - |acc_n|^2 = -2 acc_n . g + c`` (g, c fitted per lag), [len(u) - N + 1]."""
    n = len(acc)
    a2 = np.sum(acc**2, axis=1)
    D = np.column_stack([-2 * acc, np.ones(n)])
    Minv = np.linalg.pinv(D.T @ D)
    Dz = np.stack([_correlate_valid(u, D[:, j]) for j in range(4)], axis=1)
    Dz -= (D.T @ a2)[None, :]
    c1 = np.concatenate([[0.0], np.cumsum(u)])
    c2 = np.concatenate([[0.0], np.cumsum(u * u)])
    su, suu = c1[n:] - c1[:-n], c2[n:] - c2[:-n]
    sua = _correlate_valid(u, a2)
    zz = suu - 2 * sua + np.sum(a2**2)
    zsum = su - a2.sum()
    tss = zz - zsum**2 / n
    rss = zz - np.einsum("ki,ij,kj->k", Dz, Minv, Dz)
    return np.clip(1 - rss / np.maximum(tss, 1e-300), 0.0, 1.0)


def _position_offset(imu: ImuSeries, poses: PoseSeries, max_offset_s: float, resample_hz: float | None,
                     min_correlation: float) -> TimeOffsetEstimate:
    t_ref = int(imu.t_ns[0])
    t_imu_s = (imu.t_ns - t_ref) / NS_PER_S
    t_pose_s = (poses.t_ns - t_ref) / NS_PER_S
    if np.all(np.std(poses.p_m, axis=0) < 1e-6):
        raise RecoveryError(f"{_pose_name(poses)} does not move (constant position)", field="p_m",
                            hint="the clock offset cannot be found without motion; give --time-offset-s")
    a_ns, b_ns = _overlap(imu, poses, 0.0, max_offset_s)
    rate = float(resample_hz) if resample_hz else 100.0
    dt = 1.0 / rate
    K = int(np.ceil(max_offset_s / dt))
    sigma = 0.05 / dt  # 50 ms Gaussian on both sides
    tg = np.arange((a_ns - t_ref) / NS_PER_S, (b_ns - t_ref) / NS_PER_S, dt)
    pad = int(4 * sigma) + 1
    tg_pad = tg[0] + dt * np.arange(-pad, len(tg) + pad)
    p = _interp_cols(tg_pad, t_pose_s, poses.p_m)
    acc = gaussian_filter1d(p, sigma, axis=0, order=2)[pad:-pad] / dt**2  # [N, 3]
    tg_ext = tg[0] + dt * np.arange(-K - pad, len(tg) + K + pad)
    f2 = np.sum(_interp_cols(tg_ext, t_imu_s, imu.acc_mps2) ** 2, axis=1)
    u = gaussian_filter1d(f2, sigma)[pad:-pad]  # [N + 2K]
    if np.std(u) < 1e-9:
        raise RecoveryError("imu accelerometer signal is constant", field="acc_mps2",
                            hint="check the IMU stream or give --time-offset-s")
    r2 = _position_r2(acc, u)
    k = int(np.argmax(r2))
    if k <= 1 or k >= len(r2) - 2:
        raise RecoveryError(
            f"time-offset peak between imu and {_pose_name(poses)} is at the search boundary "
            f"({(k - K) * dt:+.3f} s of +-{max_offset_s:.3f} s)", field="t_ns",
            hint="increase max_offset_s, or give --time-offset-s")
    tau = (k - K + _parabolic(r2, k)) * dt
    corr = float(np.sqrt(r2[k]))
    if corr < min_correlation:
        raise RecoveryError(
            f"accelerations of imu and {_pose_name(poses)} fit only with R = {corr:.2f} (< {min_correlation})",
            field="t_ns", hint="check that the streams belong to the same rigid body, or give --time-offset-s")
    # Per-chunk peaks (searched within +-5 grid steps of the global one) for the std.
    est = []
    n = len(acc)
    for idx in np.array_split(np.arange(n), _N_CHUNKS):
        rc = _position_r2(acc[idx], u[idx[0]: idx[-1] + 1 + 2 * K])
        lo, hi = max(k - 5, 1), min(k + 6, len(rc) - 1)
        kc = lo + int(np.argmax(rc[lo:hi]))
        est.append((kc - K + _parabolic(rc, kc)) * dt)
    std = float(np.std(est, ddof=1) / np.sqrt(len(est)))
    log.info("time offset (position) %+.6f s +- %.6f s, R %.3f", tau, std, corr)
    return TimeOffsetEstimate(tau, std, corr, "position")


def estimate_time_offset(
    imu: ImuSeries,
    poses: PoseSeries,
    *,
    max_offset_s: float = 0.5,
    resample_hz: float | None = None,
    min_correlation: float = MIN_CORRELATION,
) -> TimeOffsetEstimate:
    """Clock offset of a pose stream relative to the IMU.

    6-DoF streams use the ``|omega|`` correlation (method ``"rotation"``); position-only
    streams the gravity-fit of ``|f|^2`` (method ``"position"``), see the module docstring.

    Args:
        imu: IMU readings.
        poses: The pose stream.
        max_offset_s: Search range +-, seconds.
        resample_hz: Rate of the coarse uniform grid (default: pose rate for rotation,
            100 Hz for position).
        min_correlation: Below this the result is rejected.

    Returns:
        The offset to ADD to pose stamps to put them on the IMU clock.

    Raises:
        DataError: Too few samples or non-increasing stamps.
        RecoveryError: No overlap, no motion, low correlation or a peak at the boundary.
    """
    _check_increasing(imu.t_ns, "imu")
    _check_increasing(poses.t_ns, _pose_name(poses))
    if poses.has_orientation:
        return _rotation_offset(imu, poses, max_offset_s, resample_hz, min_correlation)
    return _position_offset(imu, poses, max_offset_s, resample_hz, min_correlation)


# ----------------------------------------------------------------------------- rotation


def _interval_increments(imu: ImuSeries, poses: PoseSeries, offset_s: float):
    """Per pose interval inside the overlap: pose rotation vector increment [M, 3] (tracked
    frame), gyro integral increment [M, 3] (IMU frame, bias included) and duration [M] (s)."""
    rot = pose_rotations(poses)
    _check_increasing(imu.t_ns, "imu")
    _check_increasing(poses.t_ns, _pose_name(poses))
    a_ns, b_ns = _overlap(imu, poses, offset_s, 0.0)
    t_ref = int(imu.t_ns[0])
    t_imu_s, G = gyro_integral(imu, t_ref)
    t_pose_s = (poses.t_ns - t_ref) / NS_PER_S + offset_s
    inside = (t_pose_s >= (a_ns - t_ref) / NS_PER_S) & (t_pose_s <= (b_ns - t_ref) / NS_PER_S)
    i = np.flatnonzero(inside)
    i0, i1 = i[0], i[-1] + 1
    t = t_pose_s[i0:i1]
    rv = relative_rotvecs(rot[i0:i1])
    dG = np.diff(_interp_cols(t, t_imu_s, G), axis=0)
    return rv, dG, np.diff(t)


def _kabsch_with_bias(w_imu: np.ndarray, w_pose: np.ndarray, n_iter: int = 3):
    """Robust joint fit of ``w_imu = R w_pose + b``: Kabsch on centred rates, 5-MAD rejection."""
    keep = np.ones(len(w_pose), bool)
    for _ in range(n_iter):
        mp, mi = w_pose[keep].mean(0), w_imu[keep].mean(0)
        with warnings.catch_warnings():  # degenerate excitation is reported via `condition`
            warnings.simplefilter("ignore", UserWarning)
            rot, _ = Rotation.align_vectors(w_imu[keep] - mi, w_pose[keep] - mp)
        bias = mi - rot.apply(mp)
        res = np.linalg.norm(w_imu - rot.apply(w_pose) - bias, axis=1)
        med = np.median(res[keep])
        mad = np.median(np.abs(res[keep] - med)) + 1e-12
        keep = res < med + 5 * 1.4826 * mad
    return rot, bias, res, keep


def estimate_extrinsic_rotation(
    imu: ImuSeries,
    poses: PoseSeries,
    offset_s: float,
    *,
    window_s: float = 0.05,
    min_condition: float = MIN_ROTATION_CONDITION,
) -> RotationEstimate:
    """Rotation from the tracked frame to the IMU frame, with a constant gyro bias.

    Solves ``omega_imu = R_imu_pose @ omega_pose + b_g`` in least squares: centring both
    rate sets removes ``b_g`` exactly, Kabsch (``Rotation.align_vectors``) gives R, then
    ``b_g = mean(omega_imu) - R mean(omega_pose)``. First per pose interval with 5-MAD
    rejection of bad intervals (pose glitches, e.g. the 20-Hz correction jumps of the EuRoC
    ground truth), then on ``window_s`` averages of the good intervals (pose rate noise
    averages down while the relation stays exact, both sides being linear in the rates).

    Args:
        imu: IMU readings.
        poses: 6-DoF pose stream.
        offset_s: Seconds to add to pose stamps (from :func:`estimate_time_offset`).
        window_s: Averaging window for both rate sets.
        min_condition: Threshold on :attr:`RotationEstimate.condition`.

    Returns:
        The estimate; ``observable`` is False for (near) single-axis rotation.

    Raises:
        DataError: Position-only stream, too few samples.
        RecoveryError: No overlap, or the streams do not rotate.
    """
    rv, dG, dt = _interval_increments(imu, poses, offset_s)
    w_pose1, w_imu1 = rv / dt[:, None], dG / dt[:, None]
    if np.max(np.std(w_pose1, axis=0)) < 1e-6 or np.max(np.std(w_imu1, axis=0)) < 1e-6:
        raise RecoveryError(f"imu or {_pose_name(poses)} does not rotate", field="quat_wxyz",
                            hint="the extrinsic rotation needs rotation about several axes; give it in the "
                            "calibration (T_imu_frames) instead")
    _, _, _, good = _kabsch_with_bias(w_imu1, w_pose1)
    n = max(1, int(round(window_s / np.median(dt))))
    if n > 1:
        def wsum(x: np.ndarray) -> np.ndarray:
            c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
            return c[n:] - c[:-n]

        T = wsum(dt * good)
        ok = T > 0.5 * n * np.median(dt)
        w_pose = wsum(rv * good[:, None])[ok] / T[ok, None]
        w_imu = wsum(dG * good[:, None])[ok] / T[ok, None]
    else:
        w_pose, w_imu = w_pose1[good], w_imu1[good]
    rot, bias, res, keep = _kabsch_with_bias(w_imu, w_pose)
    res_rms = float(np.sqrt(np.mean(res[keep] ** 2)))
    ev = np.linalg.eigvalsh(np.cov(w_imu[keep].T))
    condition = float(max(ev[0], 0.0) / ev[-1]) if ev[-1] > 0 else 0.0
    observable = condition >= min_condition
    if not observable:
        log.warning("extrinsic rotation is not observable: rate covariance condition %.2e < %.0e "
                    "(rotation about fewer than 3 axes)", condition, min_condition)
    return RotationEstimate(rot.as_matrix(), float(np.degrees(res_rms)), bool(observable), condition, bias)


# ----------------------------------------------------------------------------- lever arm


def _imu_rotations(imu: ImuSeries, poses: PoseSeries, offset_s: float, R_imu_pose: np.ndarray,
                   t_s: np.ndarray, t_ref: int) -> np.ndarray:
    """R_world_imu [N, 3, 3] at IMU-clock times t_s (relative to t_ref), by Slerp of the poses."""
    rot = pose_rotations(poses)
    tp = (poses.t_ns - t_ref) / NS_PER_S + offset_s
    R_wp = Slerp(tp, rot)(np.clip(t_s, tp[0], tp[-1])).as_matrix()
    return R_wp @ np.asarray(R_imu_pose, float).T


@dataclass(frozen=True)
class _AccFit:
    x: np.ndarray  # [r (3, absent when fixed), g (3), b_a knots (3K)]
    cov: np.ndarray
    knots_s: np.ndarray
    n_r: int


def _acc_lstsq(imu: ImuSeries, poses: PoseSeries, offset_s: float, R_imu_pose: np.ndarray,
               half_window_s: float, bias_knot_s: float, p_imu_pose_m: np.ndarray | None) -> tuple[_AccFit, int]:
    """The second-difference least squares of the module docstring; returns the fit and t_ref."""
    _check_increasing(imu.t_ns, "imu")
    _check_increasing(poses.t_ns, _pose_name(poses))
    a_ns, b_ns = _overlap(imu, poses, offset_s, 0.0)
    t_ref = int(imu.t_ns[0])
    R_ip = np.asarray(R_imu_pose, float)
    sel_imu = (imu.t_ns >= a_ns - 0.1 * NS_PER_S) & (imu.t_ns <= b_ns + 0.1 * NS_PER_S)
    ti = (imu.t_ns[sel_imu] - t_ref) / NS_PER_S
    R_wi = _imu_rotations(imu, poses, offset_s, R_ip, ti, t_ref)  # [N, 3, 3]
    f_w = np.einsum("nij,nj->ni", R_wi, imu.acc_mps2[sel_imu])
    AA_f = _cumtrapz(_cumtrapz(f_w, ti, axis=0, initial=0), ti, axis=0, initial=0)
    AA_R = _cumtrapz(_cumtrapz(R_wi, ti, axis=0, initial=0), ti, axis=0, initial=0)

    tp = (poses.t_ns - t_ref) / NS_PER_S + offset_s
    inside = np.flatnonzero((tp >= ti[0]) & (tp <= ti[-1]))
    n = max(1, int(round(half_window_s / np.median(np.diff(tp[inside])))))
    if len(inside) < 2 * n + 10:
        raise RecoveryError(f"{_pose_name(poses)} overlaps the imu too briefly for the lever arm",
                            hint="give a longer recording or a smaller half_window_s")
    stride = max(1, n // 10)  # neighbouring windows overlap almost fully: thin them out
    km = inside[n:-n:stride]
    k0, k1 = km - n, km + n
    t0, tm, t1 = tp[k0], tp[km], tp[k1]
    hm, hp = tm - t0, t1 - tm
    w0, wm, w1 = hp, -(hp + hm), hm  # second-difference weights (kill constants and linear terms)

    def d2(v0, vm, v1):
        shape = (-1,) + (1,) * (v0.ndim - 1)
        return w0.reshape(shape) * v0 + wm.reshape(shape) * vm + w1.reshape(shape) * v1

    p = poses.p_m
    y = d2(p[k0], p[km], p[k1]) - d2(*(_interp_cols(t, ti, AA_f) for t in (t0, tm, t1)))  # [M, 3]
    J_b = -d2(*(_interp_cols(t, ti, AA_R) for t in (t0, tm, t1)))  # [M, 3, 3]
    J_g = d2(0.5 * (t0 - tm) ** 2, np.zeros_like(tm), 0.5 * (t1 - tm) ** 2)  # [M]
    R_wi_p = pose_rotations(poses).as_matrix() @ R_ip.T
    J_r = d2(R_wi_p[k0], R_wi_p[km], R_wi_p[k1])  # [M, 3, 3]
    n_r = 3
    if p_imu_pose_m is not None:
        y = y - J_r @ np.asarray(p_imu_pose_m, float)
        n_r = 0
    # Accelerometer bias: piecewise linear in time (knots every bias_knot_s), taken as
    # constant over each +-h window (h << knot spacing).
    n_knots = max(2, int(np.ceil((tm[-1] - tm[0]) / bias_knot_s)) + 1)
    knots = np.linspace(tm[0], tm[-1], n_knots)
    j = np.clip(np.searchsorted(knots, tm, side="right") - 1, 0, n_knots - 2)
    u = (tm - knots[j]) / (knots[j + 1] - knots[j])
    M = len(tm)
    nx = n_r + 3 + 3 * n_knots
    # Sparse design (each row touches r, one g axis and two bias knots): keeps the normal
    # equations cheap and off multi-threaded BLAS for long sequences.
    scale = 1.0 / (hm * hp)  # rows of different window length weigh alike (units: m/s^2)
    rows = np.arange(3 * M).reshape(M, 3)
    blocks_r, blocks_c, blocks_v = [], [], []
    if n_r:
        blocks_r.append(np.repeat(rows[:, :, None], 3, axis=2))
        blocks_c.append(np.broadcast_to(np.arange(3), (M, 3, 3)))
        blocks_v.append(J_r * scale[:, None, None])
    blocks_r.append(rows[:, :, None])
    blocks_c.append(np.broadcast_to(n_r + np.arange(3)[None, :, None], (M, 3, 1)))
    blocks_v.append(np.broadcast_to((J_g * scale)[:, None, None], (M, 3, 1)))
    for knot, wk in ((j, 1.0 - u), (j + 1, u)):
        blocks_r.append(np.repeat(rows[:, :, None], 3, axis=2))
        blocks_c.append(np.broadcast_to((n_r + 3 + 3 * knot)[:, None, None] + np.arange(3)[None, None, :], (M, 3, 3)))
        blocks_v.append(J_b * (wk * scale)[:, None, None])
    A = sparse.csr_array((np.concatenate([v.ravel() for v in blocks_v]),
                          (np.concatenate([r.ravel() for r in blocks_r]),
                           np.concatenate([c.ravel() for c in blocks_c]))), shape=(3 * M, nx))
    bvec = (y * scale[:, None]).reshape(-1)
    x = np.linalg.lstsq((A.T @ A).toarray(), A.T @ bvec, rcond=None)[0]
    res = bvec - A @ x
    keep = np.abs(res) < 6 * 1.4826 * np.median(np.abs(res)) + 1e-12
    Ak, bk = A[keep], bvec[keep]
    N = (Ak.T @ Ak).toarray()
    x = np.linalg.lstsq(N, Ak.T @ bk, rcond=None)[0]
    res = bk - Ak @ x
    sigma2 = float(res @ res) / max(keep.sum() - nx, 1)
    # Residuals of windows closer than 2h are correlated: inflate by the overlap count.
    cov = sigma2 * np.linalg.pinv(N) * (2 * n / stride)
    # A column without excitation (e.g. the lever arm along the only rotation axis) has a
    # zero diagonal: pinv would report it as perfectly known.
    dead = np.diag(N) <= 1e-12 * np.max(np.diag(N))
    cov[dead, dead] = np.inf
    return _AccFit(x, cov, knots, n_r), t_ref


def estimate_lever_arm(
    imu: ImuSeries,
    poses: PoseSeries,
    offset_s: float,
    R_imu_pose: np.ndarray,
    *,
    half_window_s: float = 0.3,
    bias_knot_s: float = 5.0,
    max_std_m: float = MAX_LEVER_ARM_STD_M,
) -> LeverArmEstimate:
    """Lever arm from the IMU to the tracked point, by linear least squares.

    Second differences (step ``half_window_s``) of the tracked positions are matched with
    the double integral of the rigid-body acceleration model; unknowns are the lever arm,
    the world gravity vector and a piecewise-linear accelerometer bias (module docstring).

    Args:
        imu: IMU readings.
        poses: 6-DoF pose stream.
        offset_s: Seconds to add to pose stamps.
        R_imu_pose: Extrinsic rotation, [3, 3].
        half_window_s: Second-difference step h; larger averages more position noise.
        bias_knot_s: Knot spacing of the piecewise-linear accelerometer bias (the bias of
            real and simulated IMUs drifts by tenths of m/s^2 per minute while warming up,
            which a constant bias would push into the lever arm).
        max_std_m: ``observable`` is False when any axis std exceeds this.

    Returns:
        The estimate with per-axis std (least-squares covariance inflated by the number of
        overlapping windows, an allowance for their correlation).

    Raises:
        DataError: Position-only stream, too few samples.
        RecoveryError: No overlap.
    """
    fit, t_ref = _acc_lstsq(imu, poses, offset_s, R_imu_pose, half_window_s, bias_knot_s, None)
    x = fit.x
    std = np.sqrt(np.clip(np.diag(fit.cov)[0:3], 0, None))
    observable = bool(np.all(std < max_std_m))
    if not observable:
        log.warning("lever arm is not observable (std %s m); rotate the rig about several axes", std)
    b_knots = x[6:].reshape(-1, 3)
    return LeverArmEstimate(
        x[0:3].copy(), std, observable, x[3:6].copy(), b_knots.mean(axis=0),
        t_ref + np.round(fit.knots_s * NS_PER_S).astype(np.int64), b_knots,
    )


# ----------------------------------------------------------------------------- static segments


def find_static_segments(
    imu: ImuSeries,
    *,
    min_duration_s: float = 1.0,
    gyro_thresh_radps: float = 0.05,
    acc_std_thresh_mps2: float = 0.15,
    window_s: float = 0.5,
) -> list[tuple[int, int]]:
    """Intervals where the IMU is at rest.

    A sample is static when, over a centred window of ``window_s``, the RMS gyro norm is
    below ``gyro_thresh_radps`` (so it includes the gyro bias) and the std of the
    accelerometer norm is below ``acc_std_thresh_mps2``. Runs shorter than
    ``min_duration_s`` are dropped. Edges shrink by up to half a window.

    Args:
        imu: IMU readings with increasing stamps.
        min_duration_s: Shortest segment kept.
        gyro_thresh_radps: RMS angular-rate threshold.
        acc_std_thresh_mps2: Accelerometer-norm std threshold.
        window_s: Detector window.

    Returns:
        ``[(t0_ns, t1_ns), ...]`` in time order (Python ints, inclusive IMU stamps).
    """
    _check_increasing(imu.t_ns, "imu")
    n = len(imu)
    w = max(3, int(round(window_s * imu.rate_hz)) | 1)
    if n < w:
        return []
    g2 = np.sum(imu.gyro_radps**2, axis=1)
    an = np.linalg.norm(imu.acc_mps2, axis=1)
    g_rms = np.sqrt(_box_mean(g2, w))
    a_std = _sliding_std(an, w)
    ok_valid = (g_rms < gyro_thresh_radps) & (a_std < acc_std_thresh_mps2)
    ok = np.zeros(n, bool)
    ok[w // 2: w // 2 + len(ok_valid)] = ok_valid
    edges = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    out = []
    for s, e in zip(starts, ends):
        if (imu.t_ns[e] - imu.t_ns[s]) >= min_duration_s * NS_PER_S:
            out.append((int(imu.t_ns[s]), int(imu.t_ns[e])))
    return out


# ----------------------------------------------------------------------------- gravity


def estimate_gravity(
    imu: ImuSeries,
    poses: PoseSeries,
    offset_s: float,
    R_imu_pose: np.ndarray,
    *,
    p_imu_pose_m: np.ndarray | None = None,
    half_window_s: float = 0.3,
    bias_knot_s: float = 5.0,
) -> GravityEstimate:
    """Gravity vector in the pose world frame.

    The same second-difference least squares as :func:`estimate_lever_arm` (gravity, a
    piecewise-linear accelerometer bias and, unless ``p_imu_pose_m`` is given, the lever
    arm). On a level platform the vertical bias and ``|g|`` are confounded, so only the
    direction is reliable; ``magnitude_mps2`` is the fitted norm.

    Args:
        imu: IMU readings.
        poses: 6-DoF pose stream.
        offset_s: Seconds to add to pose stamps.
        R_imu_pose: Extrinsic rotation, [3, 3].
        p_imu_pose_m: Known lever arm, [3] (None: solved jointly).
        half_window_s: Second-difference step.
        bias_knot_s: Knot spacing of the accelerometer bias.

    Returns:
        The estimate (direction points down) with the LS angular std.

    Raises:
        DataError: Position-only stream, too few samples.
        RecoveryError: No overlap, zero gravity fit.
    """
    fit, _ = _acc_lstsq(imu, poses, offset_s, R_imu_pose, half_window_s, bias_knot_s, p_imu_pose_m)
    g = fit.x[fit.n_r:fit.n_r + 3]
    cov = fit.cov[fit.n_r:fit.n_r + 3, fit.n_r:fit.n_r + 3]
    mag = float(np.linalg.norm(g))
    if mag < 1e-6:
        raise RecoveryError("gravity estimate is zero", field="acc_mps2",
                            hint="check the accelerometer units (m/s^2)")
    d = g / mag
    P = np.eye(3) - np.outer(d, d)
    std = float(np.sqrt(max(np.trace(P @ cov @ P), 0.0) / 2) / mag)
    log.info("gravity %s m/s^2 (|g| %.3f), std %.4f deg", g, mag, np.degrees(std))
    return GravityEstimate(d, mag, std, "acc_lstsq")


def estimate_gravity_direction(imu: ImuSeries, poses: PoseSeries, offset_s: float,
                               R_imu_pose: np.ndarray) -> np.ndarray:
    """Unit gravity direction (points down) in the pose world frame, [3].

    See :func:`estimate_gravity` for the method and its std.
    """
    return estimate_gravity(imu, poses, offset_s, R_imu_pose).direction
