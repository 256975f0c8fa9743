"""Gravity in the pose world frame, and the IMU's static segments.

Gravity comes from the second-difference least squares of :mod:`.extrinsic`; on a level
platform the vertical accelerometer bias and ``|g|`` are confounded, so the direction is
the reliable part. Conventions: :mod:`recovery.calibration_init.common`.
"""

from __future__ import annotations

import logging

import numpy as np

from pipeline.errors import RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.calibration_init.common import (
    GravityEstimate,
    box_mean,
    check_increasing,
    sliding_std,
)
from recovery.calibration_init.extrinsic import accelerometer_lstsq

log = logging.getLogger(__name__)


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
    check_increasing(imu.t_ns, "imu")
    n = len(imu)
    w = max(3, int(round(window_s * imu.rate_hz)) | 1)
    if n < w:
        return []
    g2 = np.sum(imu.gyro_radps**2, axis=1)
    an = np.linalg.norm(imu.acc_mps2, axis=1)
    g_rms = np.sqrt(box_mean(g2, w))
    a_std = sliding_std(an, w)
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
    fit, _ = accelerometer_lstsq(imu, poses, offset_s, R_imu_pose, half_window_s, bias_knot_s, p_imu_pose_m)
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
