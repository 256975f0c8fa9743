"""IMU and pose signals on one uniform grid, and their comparison at every clock offset at once.

The rig checks (:mod:`pipeline.checks.rig`) and the recovery's coarse clock offset compare what the
IMU measures with what the poses imply, over the whole recording and at offsets of up to minutes.
Both streams are put on one grid of step ``dt_s`` (seconds from a reference stamp, each stream on
its own clock) with a validity mask (outside a stream's span, in its gaps); a comparison at offset
``tau`` pairs pose grid point ``n`` with IMU grid point ``n + k``, ``tau = k dt_s``
(``t_imu = t_pose + tau``, the recovery's convention).

* :func:`gyro_rate_norm` / :func:`pose_rate_norm`: ``|omega|`` as the mean rate over a short window
  (rotation invariant, so no extrinsic is needed);
* :func:`pose_acceleration` / :func:`specific_force_sq`: the poses' second derivative and the
  accelerometer's ``|f|^2``, both Gaussian-smoothed;
* :func:`masked_lag_correlation`: the Pearson correlation over the overlap at every lag
  (FFT, as ``scipy.signal.correlate``);
* :func:`masked_lag_regression`: the R^2 of a linear fit of one signal on several at every lag.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.fft import irfft, next_fast_len, rfft
from scipy.spatial.transform import Rotation, Slerp

from pipeline.types import NS_PER_S, ImuSeries, PoseSeries


@dataclass(frozen=True)
class Grid:
    """A uniform grid: ``t_s = start_s + dt_s * arange(n)``, seconds after ``t_ref_ns`` (int64 ns)."""

    t_ref_ns: int
    start_s: float
    dt_s: float
    n: int

    @property
    def t_s(self) -> np.ndarray:
        return self.start_s + self.dt_s * np.arange(self.n)

    @classmethod
    def spanning(cls, spans_ns: list[tuple[int, int]], dt_s: float) -> "Grid":
        """The grid covering every ``(t0_ns, t1_ns)`` of ``spans_ns``, starting at the earliest."""
        t0 = min(a for a, _ in spans_ns)
        t1 = max(b for _, b in spans_ns)
        return cls(int(t0), 0.0, float(dt_s), int((t1 - t0) / NS_PER_S / dt_s) + 1)


def sorted_valid_imu(imu: ImuSeries) -> ImuSeries | None:
    """``imu`` without non-finite rows, in increasing unique stamps; None with fewer than 10 rows."""
    ok = np.isfinite(imu.gyro_radps).all(axis=1) & np.isfinite(imu.acc_mps2).all(axis=1)
    t = imu.t_ns[ok]
    _, first = np.unique(t, return_index=True)
    idx = np.flatnonzero(ok)[first]
    return imu.take(idx) if len(idx) >= 10 else None


def sorted_valid_poses(poses: PoseSeries) -> PoseSeries | None:
    """``poses`` without non-finite (or zero-quaternion) rows, in increasing unique stamps; None with fewer
    than 10 rows."""
    ok = np.isfinite(poses.p_m).all(axis=1)
    if poses.quat_wxyz is not None:
        q = poses.quat_wxyz
        ok &= np.isfinite(q).all(axis=1) & (np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1) > 0.5)
    _, first = np.unique(poses.t_ns[ok], return_index=True)
    idx = np.flatnonzero(ok)[first]
    return poses.take(idx) if len(idx) >= 10 else None


def _grid_s(grid: Grid, t_ns: np.ndarray) -> np.ndarray:
    return (np.asarray(t_ns, dtype=np.int64) - grid.t_ref_ns) / NS_PER_S


def _inside(grid: Grid, t_s: np.ndarray, half_s: float, max_gap_s: float) -> np.ndarray:
    """Grid points whose +-``half_s`` lies inside the samples' span and no longer gap than ``max_gap_s``."""
    g = grid.t_s
    ok = (g - half_s >= t_s[0]) & (g + half_s <= t_s[-1])
    gaps = np.flatnonzero(np.diff(t_s) > max_gap_s)
    for i in gaps:
        ok &= ~((g + half_s > t_s[i]) & (g - half_s < t_s[i + 1]))
    return ok


def _window_means(t: np.ndarray, cumulative: np.ndarray, grid: Grid, window_s: float) -> np.ndarray:
    """``(C(g + w/2) - C(g - w/2)) / w`` of a cumulative ``C`` [N, 3] sampled at ``t`` [N], at the grid points."""
    g, h = grid.t_s, 0.5 * window_s
    lo = np.column_stack([np.interp(g - h, t, cumulative[:, c]) for c in range(3)])
    hi = np.column_stack([np.interp(g + h, t, cumulative[:, c]) for c in range(3)])
    return (hi - lo) / window_s


def gyro_rate(imu: ImuSeries, grid: Grid, window_s: float, max_gap_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The mean gyro reading over ``window_s`` centred on each grid point ``[n, 3]``, and its validity ``[n]``."""
    t = _grid_s(grid, imu.t_ns)
    dt = np.diff(t)
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (imu.gyro_radps[1:] + imu.gyro_radps[:-1])
                                                          * dt[:, None], axis=0)])
    valid = _inside(grid, t, 0.5 * window_s, max_gap_s)
    return np.where(valid[:, None], _window_means(t, integral, grid, window_s), 0.0), valid


def pose_rate(poses: PoseSeries, grid: Grid, window_s: float, max_gap_s: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """The pose orientations' mean angular rate in their own (body) frame over ``window_s`` centred on each
    grid point ``[n, 3]`` (the sum of the relative rotation vectors between samples, interpolated), and its
    validity ``[n]``."""
    t = _grid_s(grid, poses.t_ns)
    q = poses.quat_wxyz
    rot = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]])
    rel = (rot[:-1].inv() * rot[1:]).as_rotvec()
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(rel, axis=0)])
    valid = _inside(grid, t, 0.5 * window_s, max_gap_s)
    return np.where(valid[:, None], _window_means(t, cum, grid, window_s), 0.0), valid


def gyro_rate_norm(imu: ImuSeries, grid: Grid, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``|`` :func:`gyro_rate` ``|`` ``[n]`` and its validity."""
    w, valid = gyro_rate(imu, grid, window_s)
    return np.linalg.norm(w, axis=1), valid


def pose_rate_norm(poses: PoseSeries, grid: Grid, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``|`` :func:`pose_rate` ``|`` ``[n]`` and its validity."""
    w, valid = pose_rate(poses, grid, window_s)
    return np.linalg.norm(w, axis=1), valid


def pose_attitude(poses: PoseSeries, grid: Grid) -> Rotation:
    """The pose orientation (world from tracked frame) at each grid point, by slerp (held beyond the ends)."""
    t = _grid_s(grid, poses.t_ns)
    q = poses.quat_wxyz
    rot = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]])
    return Slerp(t, rot)(np.clip(grid.t_s, t[0], t[-1]))


def pose_acceleration(poses: PoseSeries, grid: Grid, smooth_s: float, max_gap_s: float = 0.25
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Second derivative of the positions, Gaussian-smoothed (sigma ``smooth_s``), ``[n, 3]`` (pose units
    per s^2), and its validity ``[n]`` (4 sigmas clear of the span's ends and of gaps)."""
    t = _grid_s(grid, poses.t_ns)
    g = grid.t_s
    p = np.column_stack([np.interp(g, t, poses.p_m[:, c]) for c in range(3)])
    sigma = smooth_s / grid.dt_s
    acc = gaussian_filter1d(p, sigma, axis=0, order=2, mode="nearest") / grid.dt_s**2
    valid = _inside(grid, t, 4 * smooth_s, max_gap_s)
    return np.where(valid[:, None], acc, 0.0), valid


def specific_force_sq(imu: ImuSeries, grid: Grid, smooth_s: float, max_gap_s: float = 0.1
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The accelerometer's ``|f|^2`` Gaussian-smoothed (sigma ``smooth_s``) at each grid point ``[n]``,
    and its validity ``[n]``."""
    t = _grid_s(grid, imu.t_ns)
    g = grid.t_s
    f2 = np.interp(g, t, np.sum(imu.acc_mps2**2, axis=1))
    f2 = gaussian_filter1d(f2, smooth_s / grid.dt_s, mode="nearest")
    valid = _inside(grid, t, 4 * smooth_s, max_gap_s)
    return np.where(valid, f2, 0.0), valid


def specific_force(imu: ImuSeries, grid: Grid, smooth_s: float) -> np.ndarray:
    """The accelerometer's specific force, Gaussian-smoothed (sigma ``smooth_s``), ``[n, 3]``."""
    t = _grid_s(grid, imu.t_ns)
    f = np.column_stack([np.interp(grid.t_s, t, imu.acc_mps2[:, c]) for c in range(3)])
    return gaussian_filter1d(f, smooth_s / grid.dt_s, axis=0, mode="nearest")


def full_correlation(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``sum_n x[n] y[n + k]`` for every lag ``k`` of :func:`lags` (equal lengths ``n``), ``[2n - 1]``: what
    ``scipy.signal.correlate(y, x, mode="full")`` gives, by FFT (scipy.fft: scipy.signal would load
    scipy.stats, ~0.5 s and ~25 MB, into every process that runs the checks)."""
    n = len(x)
    size = next_fast_len(2 * n - 1, real=True)
    full = irfft(rfft(y, size) * np.conj(rfft(x, size)), size)
    return np.concatenate([full[size - (n - 1):], full[:n]]) if n > 1 else full[:1]


def lags(n: int) -> np.ndarray:
    """The lags ``k`` (grid steps) of :func:`masked_lag_correlation` for signals of length ``n``:
    ``-(n - 1) .. n - 1`` (``scipy.signal.correlation_lags(n, n)``)."""
    return np.arange(-(n - 1), n)


def masked_lag_correlation(x: np.ndarray, mx: np.ndarray, y: np.ndarray, my: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Pearson correlation of ``x[n]`` with ``y[n + k]`` over the points valid in both, per lag.

    Args:
        x, y: Signals on one grid, ``[n]`` each (values where the mask is False are ignored).
        mx, my: Their validity, bool ``[n]``.

    Returns:
        ``(r, count)``, each ``[2n - 1]`` over :func:`lags`; ``r`` is NaN where fewer than 3 points overlap.
    """
    fx, fy = mx.astype(float), my.astype(float)
    x, y = np.where(mx, x, 0.0), np.where(my, y, 0.0)
    count = np.rint(full_correlation(fy, fx))
    sx, sy = full_correlation(fy, x), full_correlation(y, fx)
    sxx, syy, sxy = full_correlation(fy, x * x), full_correlation(y * y, fx), full_correlation(y, x)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.maximum(count, 1.0)
        cov = sxy - sx * sy / n
        var = (sxx - sx**2 / n) * (syy - sy**2 / n)
        r = cov / np.sqrt(np.maximum(var, 0.0))
    r[(count < 3) | ~np.isfinite(r)] = np.nan
    return r, count


def masked_lag_regression(features: np.ndarray, mx: np.ndarray, y: np.ndarray, my: np.ndarray,
                          ridge: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares of ``y[n + k]`` on ``features[n]`` (a column of ones included by the caller) over the
    points valid in both, per lag.

    Args:
        features: ``[n, p]`` on the grid (rows where ``mx`` is False are ignored).
        mx, my: Validity of the features' rows and of ``y``, bool ``[n]``.
        y: ``[n]``.
        ridge: Relative Tikhonov term keeping lags with few points solvable.

    Returns:
        ``(r2, coefficients [2n - 1, p], count)`` over :func:`lags`; ``r2`` is NaN with fewer than
        ``2 p`` points.
    """
    F = np.where(mx[:, None], features, 0.0)
    fy = my.astype(float)
    y = np.where(my, y, 0.0)
    p = F.shape[1]
    count = np.rint(full_correlation(fy, mx.astype(float)))
    gram = np.empty((len(count), p, p))
    for i in range(p):
        for j in range(i, p):
            gram[:, i, j] = gram[:, j, i] = full_correlation(fy, F[:, i] * F[:, j])
    rhs = np.stack([full_correlation(y, F[:, i]) for i in range(p)], axis=1)
    yy, ys = full_correlation(y * y, mx.astype(float)), full_correlation(y, mx.astype(float))
    scale = np.maximum(np.trace(gram, axis1=1, axis2=2) / p, 1e-300)
    gram += ridge * scale[:, None, None] * np.eye(p)
    coef = np.linalg.solve(gram, rhs[..., None])[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.maximum(count, 1.0)
        tss = yy - ys**2 / n
        rss = yy - np.einsum("kp,kp->k", coef, rhs)
        r2 = 1.0 - rss / tss
    r2[(count < 2 * p) | ~np.isfinite(r2)] = np.nan
    return r2, coef, count


def parabolic_peak(y: np.ndarray, k: int) -> float:
    """Sub-sample position of the peak of ``y`` around index ``k``, in ``[-0.5, 0.5]`` (0 at an end)."""
    if k <= 0 or k >= len(y) - 1 or not np.all(np.isfinite(y[k - 1:k + 2])):
        return 0.0
    a, b, c = y[k - 1], y[k], y[k + 1]
    den = a - 2 * b + c
    return 0.0 if den == 0 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
