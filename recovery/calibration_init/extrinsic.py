"""Extrinsic between the tracked frame and the IMU: rotation and lever arm, closed form.

    * rotation: Kabsch/Wahba (``Rotation.align_vectors``) on centred rates, the exact joint
      least-squares solution for the rotation and a constant gyro bias; first per pose
      interval with 5-MAD rejection (drops pose glitches), then on window averages of the
      good intervals.
    * lever arm: linear least squares on second differences of positions,
      ``D2[p_pose] = D2[AA(R_wi f)] - D2[AA(R_wi) b_a] + D2[t^2/2] g + D2[R_wi] r``, where
      ``AA`` is the double time integral over the IMU samples and ``D2`` the second
      difference over +-h. This is the exact double integral of the rigid-body relation
      ``a_pose = a_imu + d^2/dt^2 (R_wi r)``, so neither angular acceleration nor a numerical
      second derivative of noisy positions is needed. Unknowns: r, g and a piecewise-linear
      accelerometer bias b_a(t). The same fit gives gravity (:mod:`.gravity`).

Conventions: :mod:`recovery.calibration_init.common`.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial.transform import Rotation, Slerp

from pipeline.errors import RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.calibration_init.common import (
    LeverArmEstimate,
    RotationEstimate,
    check_increasing,
    cumtrapz,
    interp_cols,
    overlap_span,
    pose_name,
    gyro_integral,
    pose_rotations,
)
from recovery.solver.rotations import relative_rotvecs

log = logging.getLogger(__name__)

#: Below this ratio of the smallest to largest eigenvalue of the rate covariance the
#: extrinsic rotation is reported unobservable (rate std ratio ~ 0.1).
MIN_ROTATION_CONDITION = 1e-2
#: The lever arm is reported unobservable when any axis std exceeds this.
MAX_LEVER_ARM_STD_M = 0.05


def _interval_increments(imu: ImuSeries, poses: PoseSeries, offset_s: float):
    """Per pose interval inside the overlap: pose rotation vector increment [M, 3] (tracked
    frame), gyro integral increment [M, 3] (IMU frame, bias included) and duration [M] (s)."""
    rot = pose_rotations(poses)
    check_increasing(imu.t_ns, "imu")
    check_increasing(poses.t_ns, pose_name(poses))
    a_ns, b_ns = overlap_span(imu, poses, offset_s, 0.0)
    t_ref = int(imu.t_ns[0])
    t_imu_s, G = gyro_integral(imu, t_ref)
    t_pose_s = (poses.t_ns - t_ref) / NS_PER_S + offset_s
    inside = (t_pose_s >= (a_ns - t_ref) / NS_PER_S) & (t_pose_s <= (b_ns - t_ref) / NS_PER_S)
    i = np.flatnonzero(inside)
    i0, i1 = i[0], i[-1] + 1
    t = t_pose_s[i0:i1]
    rv = relative_rotvecs(rot[i0:i1])
    dG = np.diff(interp_cols(t, t_imu_s, G), axis=0)
    return rv, dG, np.diff(t)


def kabsch_with_bias(w_imu: np.ndarray, w_pose: np.ndarray, n_iter: int = 3):
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
        raise RecoveryError(f"imu or {pose_name(poses)} does not rotate", field="quat_wxyz",
                            hint="the extrinsic rotation needs rotation about several axes; give it in the "
                            "calibration (T_imu_frames) instead")
    _, _, _, good = kabsch_with_bias(w_imu1, w_pose1)
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
    rot, bias, res, keep = kabsch_with_bias(w_imu, w_pose)
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


@dataclass(frozen=True)
class _SecondDifferences:
    """Rows of the second-difference least squares, one per window centre (M of them)."""

    y: np.ndarray  # [M, 3] D2[p_pose] - D2[AA(R_wi f)] (minus the known lever-arm term)
    J_r: np.ndarray | None  # [M, 3, 3] lever-arm Jacobian (None when the lever arm is known)
    J_g: np.ndarray  # [M] gravity Jacobian (times the identity)
    J_b: np.ndarray  # [M, 3, 3] accelerometer-bias Jacobian
    tm: np.ndarray  # [M] window centres, s from t_ref
    scale: np.ndarray  # [M] 1 / (h- h+): rows of different window length weigh alike (m/s^2)
    overlap: float  # windows overlapping one residual (2n / stride), for the covariance


def _second_differences(imu: ImuSeries, poses: PoseSeries, offset_s: float, R_imu_pose: np.ndarray,
                        half_window_s: float, p_imu_pose_m: np.ndarray | None) -> tuple[_SecondDifferences, int]:
    """The rows of the module docstring's relation at every pose window; returns them and t_ref."""
    check_increasing(imu.t_ns, "imu")
    check_increasing(poses.t_ns, pose_name(poses))
    a_ns, b_ns = overlap_span(imu, poses, offset_s, 0.0)
    t_ref = int(imu.t_ns[0])
    R_ip = np.asarray(R_imu_pose, float)
    sel_imu = (imu.t_ns >= a_ns - 0.1 * NS_PER_S) & (imu.t_ns <= b_ns + 0.1 * NS_PER_S)
    ti = (imu.t_ns[sel_imu] - t_ref) / NS_PER_S
    R_wi = _imu_rotations(imu, poses, offset_s, R_ip, ti, t_ref)  # [N, 3, 3]
    f_w = np.einsum("nij,nj->ni", R_wi, imu.acc_mps2[sel_imu])
    AA_f = cumtrapz(cumtrapz(f_w, ti, axis=0, initial=0), ti, axis=0, initial=0)
    AA_R = cumtrapz(cumtrapz(R_wi, ti, axis=0, initial=0), ti, axis=0, initial=0)

    tp = (poses.t_ns - t_ref) / NS_PER_S + offset_s
    inside = np.flatnonzero((tp >= ti[0]) & (tp <= ti[-1]))
    n = max(1, int(round(half_window_s / np.median(np.diff(tp[inside])))))
    if len(inside) < 2 * n + 10:
        raise RecoveryError(f"{pose_name(poses)} overlaps the imu for too short a time for the lever arm",
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
    y = d2(p[k0], p[km], p[k1]) - d2(*(interp_cols(t, ti, AA_f) for t in (t0, tm, t1)))  # [M, 3]
    J_b = -d2(*(interp_cols(t, ti, AA_R) for t in (t0, tm, t1)))  # [M, 3, 3]
    J_g = d2(0.5 * (t0 - tm) ** 2, np.zeros_like(tm), 0.5 * (t1 - tm) ** 2)  # [M]
    R_wi_p = pose_rotations(poses).as_matrix() @ R_ip.T
    J_r = d2(R_wi_p[k0], R_wi_p[km], R_wi_p[k1])  # [M, 3, 3]
    if p_imu_pose_m is not None:
        y = y - J_r @ np.asarray(p_imu_pose_m, float)
        J_r = None
    rows = _SecondDifferences(y, J_r, J_g, J_b, tm, 1.0 / (hm * hp), 2 * n / stride)
    return rows, t_ref


def _sparse_design(d: _SecondDifferences, bias_knot_s: float) -> tuple[sparse.csr_array, np.ndarray, np.ndarray]:
    """Scaled design [3M, nx] over [r (absent when known), g, b_a knots], right-hand side [3M], knots [K] (s).

    The accelerometer bias is piecewise linear in time (knots every ``bias_knot_s``),
    taken as constant over each +-h window (h << knot spacing). Sparse, because each row
    touches r, one g axis and two bias knots: the normal equations stay cheap and off
    multi-threaded BLAS for long sequences.
    """
    tm, scale = d.tm, d.scale
    n_r = 0 if d.J_r is None else 3
    n_knots = max(2, int(np.ceil((tm[-1] - tm[0]) / bias_knot_s)) + 1)
    knots = np.linspace(tm[0], tm[-1], n_knots)
    j = np.clip(np.searchsorted(knots, tm, side="right") - 1, 0, n_knots - 2)
    u = (tm - knots[j]) / (knots[j + 1] - knots[j])
    M = len(tm)
    rows = np.arange(3 * M).reshape(M, 3)
    blocks_r, blocks_c, blocks_v = [], [], []
    if n_r:
        blocks_r.append(np.repeat(rows[:, :, None], 3, axis=2))
        blocks_c.append(np.broadcast_to(np.arange(3), (M, 3, 3)))
        blocks_v.append(d.J_r * scale[:, None, None])
    blocks_r.append(rows[:, :, None])
    blocks_c.append(np.broadcast_to(n_r + np.arange(3)[None, :, None], (M, 3, 1)))
    blocks_v.append(np.broadcast_to((d.J_g * scale)[:, None, None], (M, 3, 1)))
    for knot, wk in ((j, 1.0 - u), (j + 1, u)):
        blocks_r.append(np.repeat(rows[:, :, None], 3, axis=2))
        blocks_c.append(np.broadcast_to((n_r + 3 + 3 * knot)[:, None, None] + np.arange(3)[None, None, :], (M, 3, 3)))
        blocks_v.append(d.J_b * (wk * scale)[:, None, None])
    A = sparse.csr_array((np.concatenate([v.ravel() for v in blocks_v]),
                          (np.concatenate([r.ravel() for r in blocks_r]),
                           np.concatenate([c.ravel() for c in blocks_c]))), shape=(3 * M, n_r + 3 + 3 * n_knots))
    return A, (d.y * scale[:, None]).reshape(-1), knots


def accelerometer_lstsq(imu: ImuSeries, poses: PoseSeries, offset_s: float, R_imu_pose: np.ndarray,
               half_window_s: float, bias_knot_s: float, p_imu_pose_m: np.ndarray | None) -> tuple[_AccFit, int]:
    """The second-difference least squares of the module docstring; returns the fit and t_ref.

    One pass, then a second without the rows beyond 6 MAD of the residual. The covariance is
    the least-squares one inflated by the number of windows that share a residual.
    """
    d, t_ref = _second_differences(imu, poses, offset_s, R_imu_pose, half_window_s, p_imu_pose_m)
    A, bvec, knots = _sparse_design(d, bias_knot_s)
    nx = A.shape[1]
    x = np.linalg.lstsq((A.T @ A).toarray(), A.T @ bvec, rcond=None)[0]
    res = bvec - A @ x
    keep = np.abs(res) < 6 * 1.4826 * np.median(np.abs(res)) + 1e-12
    Ak, bk = A[keep], bvec[keep]
    N = (Ak.T @ Ak).toarray()
    x = np.linalg.lstsq(N, Ak.T @ bk, rcond=None)[0]
    res = bk - Ak @ x
    sigma2 = float(res @ res) / max(keep.sum() - nx, 1)
    cov = sigma2 * np.linalg.pinv(N) * d.overlap
    # A column without excitation (e.g. the lever arm along the only rotation axis) has a
    # zero diagonal: pinv would report it as perfectly known.
    dead = np.diag(N) <= 1e-12 * np.max(np.diag(N))
    cov[dead, dead] = np.inf
    return _AccFit(x, cov, knots, 0 if d.J_r is None else 3), t_ref


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
    fit, t_ref = accelerometer_lstsq(imu, poses, offset_s, R_imu_pose, half_window_s, bias_knot_s, None)
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
