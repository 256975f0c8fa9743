"""Records, constants and shared helpers of the closed-form initial estimates.

Conventions (shared by every module of :mod:`recovery.calibration_init`):
    * ``offset_s`` is the number of seconds to ADD to pose stamps to put them on the
      IMU clock: a pose stamped ``t`` was taken at IMU time ``t + offset_s``.
    * ``R_imu_pose`` [3, 3] maps vectors from the tracked (pose) frame to the IMU frame,
      so ``omega_imu = R_imu_pose @ omega_pose`` and ``R_world_imu = R_world_pose @ R_imu_pose.T``.
    * ``p_imu_pose_m`` [3] is the position of the tracked point in the IMU frame.
    * Gravity is the gravity *acceleration* vector in the pose world frame (it points down).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.fft import irfft, next_fast_len, rfft
from scipy.spatial.transform import Rotation

from pipeline.errors import DataError, RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.solver.rotations import relative_rotvecs

#: Shortest common span of IMU and poses worth estimating anything on.
MIN_OVERLAP_S = 5.0


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


def pose_name(poses: PoseSeries) -> str:
    return f"poses (frame '{poses.frame}', {poses.source_kind.value})"


def check_increasing(t_ns: np.ndarray, name: str, min_len: int = 3) -> None:
    if len(t_ns) < min_len:
        raise DataError(f"{name} has {len(t_ns)} samples, need at least {min_len}", field=name,
                        hint="give a longer recording")
    if np.any(np.diff(t_ns) <= 0):
        raise DataError(f"{name} stamps are not strictly increasing", field=name,
                        hint="run 'biasgt convert' so the input checks sort and deduplicate the stream")


def cumtrapz(y: np.ndarray, x: np.ndarray, axis: int = 0, initial: float = 0.0) -> np.ndarray:
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


def correlate_valid(a: np.ndarray, v: np.ndarray) -> np.ndarray:
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
        raise DataError(f"{pose_name(poses)} has no orientation", field="quat_wxyz",
                        hint="this estimate needs a 6-DoF pose stream (mocap, VIO or ground truth)")
    q = poses.quat_wxyz
    norms = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(norms)) or np.any(norms < 1e-6):
        raise DataError(f"{pose_name(poses)} has zero or non-finite quaternions", field="quat_wxyz",
                        hint="run 'biasgt convert' to drop invalid pose rows")
    return Rotation.from_quat(q, scalar_first=True)


def gyro_integral(imu: ImuSeries, t_ref_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Times [N] (s, relative to t_ref_ns) and the cumulative gyro integral [N, 3] (rad)."""
    t_s = (imu.t_ns - t_ref_ns) / NS_PER_S
    return t_s, cumtrapz(imu.gyro_radps, t_s, axis=0, initial=0.0)


def interp_cols(t: np.ndarray, tp: np.ndarray, fp: np.ndarray) -> np.ndarray:
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


def mean_gyro(t0_s: np.ndarray, t1_s: np.ndarray, t_imu_s: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Exact mean gyro rate over [t0, t1] (trapezoid model), [M, 3]."""
    return (interp_cols(t1_s, t_imu_s, G) - interp_cols(t0_s, t_imu_s, G)) / (t1_s - t0_s)[:, None]


def overlap_span(imu: ImuSeries, poses: PoseSeries, offset_s: float, margin_s: float) -> tuple[float, float]:
    """Common span on the IMU clock, shrunk by margin, in ns (floats); raises if too short."""
    p0 = poses.t_ns[0] + offset_s * NS_PER_S
    p1 = poses.t_ns[-1] + offset_s * NS_PER_S
    a = max(float(imu.t_ns[0]), float(p0)) + margin_s * NS_PER_S
    b = min(float(imu.t_ns[-1]), float(p1)) - margin_s * NS_PER_S
    if b - a < MIN_OVERLAP_S * NS_PER_S:
        raise RecoveryError(
            f"imu and {pose_name(poses)} overlap for only {max(b - a, 0) / NS_PER_S:.2f} s "
            f"(imu {imu.t_ns[0]}..{imu.t_ns[-1]} ns, poses {poses.t_ns[0]}..{poses.t_ns[-1]} ns, "
            f"offset {offset_s:+.3f} s, margin {margin_s:.2f} s; need {MIN_OVERLAP_S:.0f} s)",
            field="t_ns",
            hint="check that both streams are on the same clock epoch, or give --time-offset-s",
        )
    return a, b


def box_mean(x: np.ndarray, n: int) -> np.ndarray:
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
    check_increasing(poses.t_ns, pose_name(poses))
    dt_s = np.diff(poses.t_ns) / NS_PER_S
    omega = relative_rotvecs(rot) / dt_s[:, None]
    t_mid = poses.t_ns[:-1] + np.diff(poses.t_ns) // 2
    if smooth_s > 0:
        n = int(round(smooth_s / np.median(dt_s)))
        if n > 1:
            kernel = np.ones(n) / n
            omega = np.stack([np.convolve(omega[:, j], kernel, mode="same") for j in range(3)], axis=1)
    return t_mid.astype(np.int64), omega

def sliding_std(y: np.ndarray, n: int) -> np.ndarray:
    c1 = np.concatenate([[0.0], np.cumsum(y)])
    c2 = np.concatenate([[0.0], np.cumsum(y * y)])
    m = (c1[n:] - c1[:-n]) / n
    return np.sqrt(np.maximum((c2[n:] - c2[:-n]) / n - m * m, 0.0))
