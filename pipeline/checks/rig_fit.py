"""What the poses imply against what the IMU measures, at a known clock offset: the positions' unit and the
agreement of the two streams' body frames. Closed-form fits on a 20-Hz grid over the whole overlap, cheap
enough for ``biasgt inspect``.

* :func:`position_scale`: the factor ``s`` that turns the positions into metres, from the linear fit
  ``|f|^2 = s^2 |a|^2 - 2 s a.g + |g|^2`` of the accelerometer's ``|f|^2`` on the positions' second
  derivative ``a`` (rotation invariant: no attitude or extrinsic needed): ``s = |coefficient of a| / 2 g``.
* :func:`frame_agreement` (6-DoF streams): the robust fit ``omega_imu = R omega_pose + b_g`` (Kabsch with a
  bias) and, with that ``R``, ``f = R R_world_pose^T (a - g) + b_a`` (gravity and bias fitted). A gyro or
  accelerometer with two axes swapped or a sign flipped (a reflection), or quaternions read in another order,
  leaves residuals that no rotation removes; a correct rig leaves the pose noise, the lever arm and the
  IMU noise.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.checks.clock import ACC_SMOOTH_S, GRID_DT_S, MIN_OVERLAP_S, RATE_WINDOW_S, position_features
from pipeline.checks.rig_signals import (
    Grid,
    gyro_rate,
    pose_acceleration,
    pose_attitude,
    pose_rate,
    specific_force,
    specific_force_sq,
)
from pipeline.types import NS_PER_S, STANDARD_GRAVITY_MPS2, ImuSeries, PoseSeries

#: Units positions are exported in, by their factor to metres.
POSITION_UNITS = {1.0: "metres", 1e-2: "centimetres", 1e-3: "millimetres"}


def on_pose_clock(imu: ImuSeries, poses: PoseSeries, offset_s: float, dt_s: float = GRID_DT_S
                  ) -> tuple[ImuSeries, Grid] | None:
    """``imu`` with its stamps moved onto the pose clock (``t_imu = t_pose + offset_s``), and the grid over the
    two streams' overlap there; None below :data:`MIN_OVERLAP_S`."""
    imu_p = ImuSeries(imu.t_ns - int(round(offset_s * NS_PER_S)), imu.gyro_radps, imu.acc_mps2)
    a, b = max(int(imu_p.t_ns[0]), int(poses.t_ns[0])), min(int(imu_p.t_ns[-1]), int(poses.t_ns[-1]))
    if (b - a) / NS_PER_S < MIN_OVERLAP_S:
        return None
    return imu_p, Grid(a, 0.0, dt_s, int((b - a) / NS_PER_S / dt_s) + 1)


@dataclass(frozen=True)
class PositionScale:
    """The positions' factor to metres.

    Attributes:
        scale: ``s`` from the gravity term (1: metres, 1e-3: millimetres).
        r2: The fit's R^2 (how much of ``|f|^2`` the motion explains).
        unit: The unit in :data:`POSITION_UNITS` within a factor 2 of ``scale`` (None: none is).
    """

    scale: float
    r2: float
    unit: str | None


def position_scale(imu: ImuSeries, poses: PoseSeries, offset_s: float) -> PositionScale | None:
    """The factor that turns ``poses``' positions into metres (see the module docstring); None without a
    usable overlap."""
    aligned = on_pose_clock(imu, poses, offset_s)
    if aligned is None:
        return None
    imu_p, grid = aligned
    a, ma = pose_acceleration(poses, grid, ACC_SMOOTH_S)
    f2, mf = specific_force_sq(imu_p, grid, ACC_SMOOTH_S)
    m = ma & mf
    if m.sum() < 20:
        return None
    rms = float(np.sqrt(np.mean(a[m] ** 2)))
    if not rms > 0:
        return None
    X, y = position_features(a[m]), f2[m]
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    tss = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum((y - X @ coef) ** 2)) / tss if tss > 0 else 0.0
    scale = float(np.linalg.norm(coef[1:4]) / rms / (2.0 * STANDARD_GRAVITY_MPS2))
    unit = None
    if scale > 0:
        nearest = min(POSITION_UNITS, key=lambda u: abs(np.log10(scale / u)))
        unit = POSITION_UNITS[nearest] if abs(np.log10(scale / nearest)) < np.log10(2.0) else None
    return PositionScale(scale, r2, unit)


@dataclass(frozen=True)
class FrameAgreement:
    """How well the IMU and a 6-DoF pose stream agree about the body frame.

    Attributes:
        gyro_residual: RMS of ``omega_imu - R omega_pose - b_g`` over the RMS of the centred ``omega_imu``
            (0: exact; 1: the pose rates explain nothing).
        gyro_bias_radps: The norm of the fitted gyro bias.
        acc_residual_mps2: RMS of the specific-force residual (m/s^2).
        acc_bias_mps2: The norm of the fitted accelerometer bias.
        rate_rms_radps: RMS of the centred gyro rate (how much the rig rotated).
        attitude_spread_deg: RMS angle of the attitudes from their mean (what the accelerometer
            check can see: a level rig that never tilts cannot tell a swapped axis from a tilted world).
        R_imu_pose: The fitted rotation from the tracked frame to the IMU frame, [3, 3].
    """

    gyro_residual: float
    gyro_bias_radps: float
    acc_residual_mps2: float
    acc_bias_mps2: float
    rate_rms_radps: float
    attitude_spread_deg: float
    R_imu_pose: np.ndarray


def _robust_kabsch(w_imu: np.ndarray, w_pose: np.ndarray, n_iter: int = 3) -> tuple[Rotation, np.ndarray, np.ndarray]:
    """``(R, b, kept)`` of ``w_imu = R w_pose + b`` ([n, 3] each), rows beyond 5 MAD of the residual dropped."""
    keep = np.ones(len(w_pose), bool)
    for _ in range(n_iter):
        mp, mi = w_pose[keep].mean(0), w_imu[keep].mean(0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            rot, _ = Rotation.align_vectors(w_imu[keep] - mi, w_pose[keep] - mp)
        bias = mi - rot.apply(mp)
        res = np.linalg.norm(w_imu - rot.apply(w_pose) - bias, axis=1)
        med = np.median(res[keep])
        keep = res < med + 5 * 1.4826 * (np.median(np.abs(res[keep] - med)) + 1e-12)
    return rot, bias, keep


def _acc_fit(f: np.ndarray, a_w: np.ndarray, world_to_imu: Rotation, gravity_mps2: float = STANDARD_GRAVITY_MPS2,
             n_iter: int = 30) -> tuple[float, np.ndarray]:
    """``(RMS residual, b)`` of ``f = M (a_w - g) + b`` with ``M = world_to_imu``, ``|g|`` fixed at
    ``gravity_mps2`` (its direction and the bias ``b`` [3] fitted, alternately; [n, 3] each), rows beyond
    5 MAD of the residual dropped. With ``|g|`` free, a vertical bias and the gravity's magnitude trade
    wherever the rig turns about the vertical alone."""
    M = world_to_imu.as_matrix()  # [n, 3, 3]
    y = np.einsum("nji,nj->ni", M, f) - a_w  # = -g + M^T b
    keep = np.ones(len(f), bool)
    b = np.zeros(3)
    for i in range(n_iter):
        bw = np.einsum("nji,j->ni", M, b)  # M^T b
        g = -np.mean((y - bw)[keep], axis=0)
        g *= gravity_mps2 / max(float(np.linalg.norm(g)), 1e-12)
        A = np.transpose(M[keep], (0, 2, 1)).reshape(-1, 3)
        b, *_ = np.linalg.lstsq(A, (y[keep] + g).reshape(-1), rcond=None)
        if i % 10 == 9:
            res = np.linalg.norm(y + g - np.einsum("nji,j->ni", M, b), axis=1)
            med = np.median(res[keep])
            keep = res < med + 5 * 1.4826 * (np.median(np.abs(res[keep] - med)) + 1e-12)
    res = np.linalg.norm(y + g - np.einsum("nji,j->ni", M, b), axis=1)
    return float(np.sqrt(np.mean(res[keep] ** 2))), b


def frame_agreement(imu: ImuSeries, poses: PoseSeries, offset_s: float, position_scale_m: float = 1.0
                    ) -> FrameAgreement | None:
    """The fits of the module docstring at ``offset_s`` (positions times ``position_scale_m`` in metres);
    None for a position-only stream or without a usable overlap."""
    if poses.quat_wxyz is None:
        return None
    aligned = on_pose_clock(imu, poses, offset_s)
    if aligned is None:
        return None
    imu_p, grid = aligned
    wi, mi = gyro_rate(imu_p, grid, RATE_WINDOW_S)
    wp, mp = pose_rate(poses, grid, RATE_WINDOW_S)
    a_w, ma = pose_acceleration(poses, grid, ACC_SMOOTH_S)
    m = mi & mp & ma
    if m.sum() < 20:
        return None
    wi, wp = wi[m], wp[m]
    rot, bias, keep = _robust_kabsch(wi, wp)
    centred = wi[keep] - wi[keep].mean(0)
    rate_rms = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    res = wi[keep] - rot.apply(wp[keep]) - bias
    gyro_residual = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) / max(rate_rms, 1e-12)
    attitude = pose_attitude(poses, grid)[np.flatnonzero(m)]
    spread = float(np.degrees(np.sqrt(np.mean((attitude.mean().inv() * attitude).magnitude() ** 2))))
    acc_res, acc_bias = _acc_fit(specific_force(imu_p, grid, ACC_SMOOTH_S)[m], a_w[m] * position_scale_m,
                                 rot * attitude.inv())
    return FrameAgreement(gyro_residual, float(np.linalg.norm(bias)), acc_res, float(np.linalg.norm(acc_bias)),
                          rate_rms, spread, rot.as_matrix())
