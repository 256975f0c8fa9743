"""Gravity in the pose world frame, and the IMU's static segments.

Gravity comes from the second-difference least squares of :mod:`.extrinsic`; on a level
platform the vertical accelerometer bias and ``|g|`` are confounded, so the direction is
the reliable part. Conventions: :mod:`recovery.calibration_init.common`.
"""

from __future__ import annotations

import logging
from enum import Enum

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

#: Largest mean angular rate a window may show under :attr:`RestTest.VARIATION` (rad/s): far
#: above any gyro bias, far below a deliberate turn.
MAX_REST_MEAN_RATE_RADPS = 0.3


class RestTest(str, Enum):
    """How :func:`find_static_segments` judges the gyro and accelerometer at rest.

    ``RATE``: the gyro's RMS norm (bias included) and the accelerometer norm's std, for a
    calibrated IMU whose bias is small. ``VARIATION``: each sensor's spread about its window
    mean (RMS over the axes; the bias excluded, so an uncalibrated unit with a large turn-on
    bias still shows its rest), the accelerometer taken per axis so that a slow turn shows, and
    the mean rate capped at :data:`MAX_REST_MEAN_RATE_RADPS`.
    """

    RATE = "rate"
    VARIATION = "variation"


def _spread(x: np.ndarray, w: int) -> np.ndarray:
    """Root of the mean per-axis variance of x [N, 3] over a centred window of w samples ('valid'), [N - w + 1]."""
    return np.sqrt(np.mean([sliding_std(x[:, k], w) ** 2 for k in range(x.shape[1])], axis=0))


def find_static_segments(
    imu: ImuSeries,
    *,
    min_duration_s: float = 1.0,
    gyro_thresh_radps: float = 0.05,
    acc_std_thresh_mps2: float = 0.15,
    window_s: float = 0.5,
    test: RestTest = RestTest.RATE,
) -> list[tuple[int, int]]:
    """Intervals where the IMU is at rest.

    A sample is static when, over a centred window of ``window_s``, the gyro passes
    ``gyro_thresh_radps`` and the accelerometer ``acc_std_thresh_mps2`` under ``test``
    (:class:`RestTest`: by default the RMS gyro norm, bias included, and the std of the
    accelerometer norm). Runs shorter than ``min_duration_s`` are dropped. Edges shrink by
    up to half a window.

    Args:
        imu: IMU readings with increasing stamps.
        min_duration_s: Shortest segment kept.
        gyro_thresh_radps: Angular-rate threshold (RMS norm, or spread about the mean).
        acc_std_thresh_mps2: Accelerometer threshold (std of the norm, or spread about the mean).
        window_s: Detector window.
        test: What the thresholds apply to.

    Returns:
        ``[(t0_ns, t1_ns), ...]`` in time order (Python ints, inclusive IMU stamps).
    """
    check_increasing(imu.t_ns, "imu")
    n = len(imu)
    w = max(3, int(round(window_s * imu.rate_hz)) | 1)
    if n < w:
        return []
    if RestTest(test) is RestTest.VARIATION:
        mean_rate = np.linalg.norm(box_mean(imu.gyro_radps, w), axis=1)
        ok_valid = ((_spread(imu.gyro_radps, w) < gyro_thresh_radps) & (mean_rate < MAX_REST_MEAN_RATE_RADPS)
                    & (_spread(imu.acc_mps2, w) < acc_std_thresh_mps2))
    else:
        g_rms = np.sqrt(box_mean(np.sum(imu.gyro_radps**2, axis=1), w))
        a_std = sliding_std(np.linalg.norm(imu.acc_mps2, axis=1), w)
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
