"""Initial values of a window's states: velocities from the positions, orientations integrated from
the gyro and, for position-only streams, a closed-form attitude (Wahba's problem per window)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.types import NS_PER_S
from recovery.solver.preintegration import MidpointSamples
from recovery.solver.window import KeyframePoses


def savgol(y: np.ndarray, win: int, dt: float, deriv: int) -> np.ndarray:
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
    vel = savgol(np.asarray(p_m, dtype=float), win, dt, deriv=1)
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
        acc_w = savgol(kf.p_m, win, dt, deriv=2)
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
