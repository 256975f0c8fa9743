"""Clock offset between a pose stream and the IMU, found without an initial guess.

Two methods, chosen by what the stream carries:
    * ``"rotation"`` (6-DoF streams): FFT cross-correlation of ``|omega|`` from the gyro and
      from the poses (rotation invariant, so no extrinsic is needed), both as mean rates over
      ``CORRELATION_WINDOW_S``, on a uniform grid with a parabolic sub-sample step. A joint
      (R, b_g) fit at that offset removes the gyro bias, which skews ``|omega_imu|``, and the
      correlation is repeated; a continuous 1-D search (+-3 grid steps) then minimises the
      closed-form Kabsch cost of ``omega_imu = R omega_pose + b_g`` between window-averaged
      pose rates and the exact mean gyro rate over the shifted windows.
    * ``"position"`` (position-only streams): ``|f|^2`` from the IMU equals
      ``|a_world - g|^2``; per lag, a 4-parameter linear fit
      ``|f|^2 - |a|^2 = -2 a.g + |g|^2`` (unknown world gravity) is scored by its R^2, all
      lags at once through FFT correlations. Coarse: the factor graph refines it.

The std of either is the scatter of per-chunk estimates over sqrt(number of chunks).
Conventions: :mod:`recovery.calibration_init.common`.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import minimize_scalar

from pipeline.errors import RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.calibration_init.common import (
    TimeOffsetEstimate,
    check_increasing,
    correlate_valid,
    interp_cols,
    mean_gyro,
    overlap_span,
    pose_name,
    sliding_std,
    gyro_integral,
    pose_rotations,
)
from recovery.calibration_init.extrinsic import kabsch_with_bias
from recovery.solver.rotations import relative_rotvecs

log = logging.getLogger(__name__)

#: Below this correlation the time-offset peak is not trusted.
MIN_CORRELATION = 0.5
#: The |omega| correlation compares mean rates over windows of this length.
CORRELATION_WINDOW_S = 0.1
_N_CHUNKS = 6


def _parabolic(y: np.ndarray, k: int) -> float:
    """Sub-sample peak position around index k (0 < k < len-1)."""
    a, b, c = y[k - 1], y[k], y[k + 1]
    den = a - 2 * b + c
    return 0.0 if den == 0 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))



def _lag_correlation(x: np.ndarray, y_ext: np.ndarray) -> np.ndarray:
    """Pearson correlation of x [N] with every length-N window of y_ext [N + 2K] -> [2K + 1]."""
    n = len(x)
    xc = x - x.mean()
    sx = xc.std()
    sy = sliding_std(y_ext, n)
    c = correlate_valid(y_ext, xc)
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
        raise RecoveryError(f"{pose_name(poses)} does not rotate (constant orientation)", field="quat_wxyz",
                            hint="the clock offset cannot be found without motion; give --time-offset-s")
    if np.std(np.linalg.norm(imu.gyro_radps, axis=1)) < 1e-6:
        raise RecoveryError("imu gyro signal is constant", field="gyro_radps",
                            hint="check the IMU stream (units, saturation) or give --time-offset-s")

    a_ns, b_ns = overlap_span(imu, poses, 0.0, max_offset_s)
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
        return mean_gyro(t_pose_s[j0[sel]] + tau, t_pose_s[j0[sel] + n] + tau, t_imu_s, Gb)

    def coarse(Gb: np.ndarray) -> tuple[float, float, int]:
        y_ext = np.linalg.norm(mean_gyro(tg_ext - hc / 2, tg_ext + hc / 2, t_imu_s, Gb), axis=1)
        r = _lag_correlation(x, y_ext)
        k = int(np.argmax(r))
        if k <= 1 or k >= len(r) - 2:
            raise RecoveryError(
                f"time-offset peak between imu and {pose_name(poses)} is at the search boundary "
                f"({(k - K) * dt:+.3f} s of +-{max_offset_s:.3f} s, correlation {r[k]:.2f})",
                field="t_ns", hint="increase max_offset_s, or give --time-offset-s")
        return (k - K + _parabolic(r, k)) * dt, float(r[k]), k

    # Pass 1: |omega| correlation; the gyro bias skews |omega_imu| (by b . omega_hat).
    tau0, _, _ = coarse(G)
    # Joint R, b at tau0 (b barely depends on the offset), then pass 2 without the bias.
    all_sel = np.arange(len(j0))
    _, bias, _, _ = kabsch_with_bias(w_imu(tau0, all_sel, G), w_pose)
    Gb = G - np.outer(t_imu_s, bias)
    tau1, corr, _ = coarse(Gb)
    if corr < min_correlation:
        raise RecoveryError(
            f"|omega| of imu and {pose_name(poses)} correlate only {corr:.2f} (< {min_correlation})",
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
    Dz = np.stack([correlate_valid(u, D[:, j]) for j in range(4)], axis=1)
    Dz -= (D.T @ a2)[None, :]
    c1 = np.concatenate([[0.0], np.cumsum(u)])
    c2 = np.concatenate([[0.0], np.cumsum(u * u)])
    su, suu = c1[n:] - c1[:-n], c2[n:] - c2[:-n]
    sua = correlate_valid(u, a2)
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
        raise RecoveryError(f"{pose_name(poses)} does not move (constant position)", field="p_m",
                            hint="the clock offset cannot be found without motion; give --time-offset-s")
    a_ns, b_ns = overlap_span(imu, poses, 0.0, max_offset_s)
    rate = float(resample_hz) if resample_hz else 100.0
    dt = 1.0 / rate
    K = int(np.ceil(max_offset_s / dt))
    sigma = 0.05 / dt  # 50 ms Gaussian on both sides
    tg = np.arange((a_ns - t_ref) / NS_PER_S, (b_ns - t_ref) / NS_PER_S, dt)
    pad = int(4 * sigma) + 1
    tg_pad = tg[0] + dt * np.arange(-pad, len(tg) + pad)
    p = interp_cols(tg_pad, t_pose_s, poses.p_m)
    acc = gaussian_filter1d(p, sigma, axis=0, order=2)[pad:-pad] / dt**2  # [N, 3]
    tg_ext = tg[0] + dt * np.arange(-K - pad, len(tg) + K + pad)
    f2 = np.sum(interp_cols(tg_ext, t_imu_s, imu.acc_mps2) ** 2, axis=1)
    u = gaussian_filter1d(f2, sigma)[pad:-pad]  # [N + 2K]
    if np.std(u) < 1e-9:
        raise RecoveryError("imu accelerometer signal is constant", field="acc_mps2",
                            hint="check the IMU stream or give --time-offset-s")
    r2 = _position_r2(acc, u)
    k = int(np.argmax(r2))
    if k <= 1 or k >= len(r2) - 2:
        raise RecoveryError(
            f"time-offset peak between imu and {pose_name(poses)} is at the search boundary "
            f"({(k - K) * dt:+.3f} s of +-{max_offset_s:.3f} s)", field="t_ns",
            hint="increase max_offset_s, or give --time-offset-s")
    tau = (k - K + _parabolic(r2, k)) * dt
    corr = float(np.sqrt(r2[k]))
    if corr < min_correlation:
        raise RecoveryError(
            f"accelerations of imu and {pose_name(poses)} fit only with R = {corr:.2f} (< {min_correlation})",
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
    check_increasing(imu.t_ns, "imu")
    check_increasing(poses.t_ns, pose_name(poses))
    if poses.has_orientation:
        return _rotation_offset(imu, poses, max_offset_s, resample_hz, min_correlation)
    return _position_offset(imu, poses, max_offset_s, resample_hz, min_correlation)
