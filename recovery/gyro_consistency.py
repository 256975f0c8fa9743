"""How a gyro agrees with the attitude of a reference pose stream, independent of the factor graph.

Two diagnostics of the disagreement ``d = gyro - omega_ref`` (the reference's body rate in the
IMU frame), for auditing a reference before trusting the bias recovered against it:

* :func:`rate_coupling`: the transfer from the angular rate to ``d`` by frequency band (cross
  spectra, Welch). An IMU scale or misalignment error ``S omega`` has the same gain in every band
  the motion excites; a gain at low frequencies only is not a property of the IMU's intrinsics
  (which :mod:`recovery.intrinsics` estimates) but of the reference's attitude or of a slow
  process, and no intrinsic term can absorb it.
* :func:`fit_walk`: per axis, the maximum-likelihood gyro bias random walk of the attitude
  increments (gyro integrated over ``interval_s`` against the reference's relative rotation),
  with the reference's attitude error modelled as white, or as white plus a first-order
  Gauss-Markov process (time-correlated attitude error). A Kalman filter gives the likelihood.
  It is a check of the recovery's evidence search from a different model (no positions, no
  accelerometer, axes separate).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.signal import csd, welch
from scipy.spatial.transform import Rotation, Slerp

from pipeline.errors import RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries

# Frequency bands of :func:`rate_coupling` (Hz): below, around and above a MAV's manoeuvres.
DEFAULT_BANDS_HZ = ((0.0, 0.05), (0.05, 0.2), (0.2, 1.0), (1.0, 3.0), (3.0, 10.0))


def _reference_slerp(poses: PoseSeries, R_imu_pose: np.ndarray, offset_s: float) -> tuple[Slerp, np.ndarray]:
    """Slerp of the IMU's orientation as the reference has it, on the IMU clock, and its span [2] (ns)."""
    if poses.quat_wxyz is None:
        raise RecoveryError("the gyro consistency check needs orientations; this pose stream has positions only",
                            hint="give a 6-DoF pose stream")
    t = poses.t_ns.astype(float) + offset_s * NS_PER_S
    R_world_imu = Rotation.from_quat(poses.quat_wxyz[:, [1, 2, 3, 0]]) * Rotation.from_matrix(R_imu_pose).inv()
    return Slerp(t, R_world_imu), np.array([t[0], t[-1]])


def reference_rates(imu: ImuSeries, poses: PoseSeries, R_imu_pose: np.ndarray | None = None, offset_s: float = 0.0,
                    half_step_s: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
    """The reference's body rate at the IMU stamps inside its span.

    Args:
        imu: The IMU readings. poses: The reference (orientation needed).
        R_imu_pose: Rotation of the pose frame in the IMU frame [3, 3] (default identity).
        offset_s: Added to the pose stamps to put them on the IMU clock.
        half_step_s: Half the central difference's step.

    Returns:
        ``index`` [M] of the IMU samples used and ``omega_radps`` [M, 3] in the IMU frame.
    """
    R = np.eye(3) if R_imu_pose is None else np.asarray(R_imu_pose, dtype=float)
    slerp, span = _reference_slerp(poses, R, offset_s)
    h = half_step_s * NS_PER_S
    t = imu.t_ns.astype(float)
    index = np.nonzero((t - h > span[0]) & (t + h < span[1]))[0]
    if len(index) < 2:
        raise RecoveryError("the IMU and the reference pose stream do not overlap in time")
    rel = slerp(t[index] - h).inv() * slerp(t[index] + h)
    return index, rel.as_rotvec() / (2.0 * half_step_s)


# A coupling counts where its coherence reaches this in a band and its gain this much.
COUPLING_MIN_COHERENCE = 0.5
COUPLING_MIN_GAIN = 2e-3
# Bands from this frequency up tell an intrinsic error (every band) from a slow process.
FAST_BAND_HZ = 0.2


class CouplingKind(str, enum.Enum):
    """What the strongest cross-axis coupling of :class:`RateCoupling` looks like."""

    NONE = "none"  # no axis follows another axis's rate
    INTRINSIC = "intrinsic"  # the same gain at FAST_BAND_HZ and above: scale or misalignment
    SLOW = "slow"  # below FAST_BAND_HZ only: not an intrinsic error


@dataclass(frozen=True)
class RateCoupling:
    """Transfer from the angular rate to the gyro's disagreement with a reference, by band.

    Attributes:
        bands_hz: Band edges [n, 2].
        gain: Real part of the transfer ``d_i / omega_j`` over each band [n, 3, 3]
            (rows: the axis of the disagreement, columns: the rate axis). A misalignment ``S``
            shows as ``gain[b] = S`` in every excited band.
        coherence: Magnitude-squared coherence of ``d_i`` with ``omega_j`` over each band [n, 3, 3] (0-1).
    """

    bands_hz: np.ndarray
    gain: np.ndarray
    coherence: np.ndarray

    def strongest(self) -> tuple[int, int, int]:
        """(band, row, column) of the off-diagonal pair with the highest coherence (the diagonal
        also holds the reference's own smoothing)."""
        c = self.coherence.copy()
        c[:, np.arange(3), np.arange(3)] = -1.0
        return tuple(int(i) for i in np.unravel_index(np.argmax(c), c.shape))  # type: ignore[return-value]

    def kind(self) -> CouplingKind:
        """:class:`CouplingKind` of the :meth:`strongest` pair: INTRINSIC when it counts in a band from
        ``FAST_BAND_HZ`` up with a gain within a factor 2 of its slow bands' (or it has no slow band);
        SLOW when it counts below ``FAST_BAND_HZ`` only and the fast bands carry under a quarter of
        that gain."""
        _, r, c = self.strongest()
        counts = (self.coherence[:, r, c] >= COUPLING_MIN_COHERENCE) & (np.abs(self.gain[:, r, c]) >= COUPLING_MIN_GAIN)
        if not counts.any():
            return CouplingKind.NONE
        fast = self.bands_hz[:, 0] >= FAST_BAND_HZ
        g = self.gain[:, r, c]
        slow_gain = np.max(np.abs(g[counts & ~fast])) if (counts & ~fast).any() else None
        if (counts & fast).any():
            fast_gain = np.max(np.abs(g[counts & fast]))
            if slow_gain is None or 0.5 <= fast_gain / slow_gain <= 2.0:
                return CouplingKind.INTRINSIC
        if slow_gain is not None and np.all(np.abs(g[fast]) < 0.25 * slow_gain):
            return CouplingKind.SLOW
        return CouplingKind.INTRINSIC if (counts & fast).any() else CouplingKind.SLOW

    def sentence(self) -> str:
        """One plain sentence on the strongest coupling, for reports."""
        b, r, c = self.strongest()
        kind = self.kind()
        lo, hi = self.bands_hz[b]
        pair = f"gyro {'xyz'[r]} against the rate about {'xyz'[c]}"
        if kind is CouplingKind.NONE:
            return (f"The gyro follows the pose stream's rotation on every axis: no axis reads another axis's rate "
                    f"(strongest: {pair}, coherence {self.coherence[b, r, c]:.2f} at {lo:g}-{hi:g} Hz).")
        if kind is CouplingKind.INTRINSIC:
            return (f"The {pair} reads {self.gain[b, r, c]:+.4f} of that rate in bands up to "
                    f"{self.bands_hz[-1, 1]:g} Hz (coherence {self.coherence[b, r, c]:.2f} at {lo:g}-{hi:g} Hz): a "
                    "scale or misalignment error of the IMU against this pose stream, which recovery.intrinsics "
                    "estimates; without it the bias follows the rate.")
        fast = self.bands_hz[:, 0] >= FAST_BAND_HZ
        return (f"The {pair} departs by {self.gain[b, r, c]:+.4f} of that rate at {lo:g}-{hi:g} Hz (coherence "
                f"{self.coherence[b, r, c]:.2f}) but by at most {np.max(np.abs(self.gain[fast, r, c])):.4f} from "
                f"{FAST_BAND_HZ:g} Hz up: not an IMU scale or misalignment (those read the same in every band) but "
                "a slow process, such as an attitude error of the reference that follows the rotation. The bias "
                "absorbs it (its random walk rises) and no intrinsic term can.")


def rate_coupling(imu: ImuSeries, poses: PoseSeries, R_imu_pose: np.ndarray | None = None, offset_s: float = 0.0,
                  bands_hz: tuple[tuple[float, float], ...] = DEFAULT_BANDS_HZ,
                  segment_s: float = 40.0) -> RateCoupling:
    """:class:`RateCoupling` of ``d = gyro - omega_ref`` against the gyro's rate.

    Welch spectra over ``segment_s`` segments (their resolution, 1 / ``segment_s``, must resolve
    the lowest band), summed over each band. The highest band is limited by the reference: its
    rate is a central difference of interpolated orientations.

    Raises:
        RecoveryError: if the overlap is shorter than two segments or the stream has no orientation.
    """
    index, omega_ref = reference_rates(imu, poses, R_imu_pose, offset_s)
    t = imu.t_ns[index]
    rate_hz = (len(t) - 1) * NS_PER_S / float(t[-1] - t[0])
    nper = int(2 ** round(math.log2(segment_s * rate_hz)))
    if len(t) < 2 * nper:
        raise RecoveryError(f"the rate coupling needs at least {2 * nper / rate_hz:.0f} s of overlap, "
                            f"got {len(t) / rate_hz:.0f} s", hint="use a longer recording")
    w = imu.gyro_radps[index]
    d = w - omega_ref
    w, d = w - w.mean(0), d - d.mean(0)
    f, p_ww = welch(w, fs=rate_hz, nperseg=nper, axis=0)  # [F, 3]
    _, p_dd = welch(d, fs=rate_hz, nperseg=nper, axis=0)
    bands = np.asarray(bands_hz, dtype=float)
    gain = np.zeros((len(bands), 3, 3))
    coh = np.zeros((len(bands), 3, 3))
    for j in range(3):
        _, p_wd = csd(w[:, [j]], d, fs=rate_hz, nperseg=nper, axis=0)  # [F, 3]: rate j against every d_i
        for b, (lo, hi) in enumerate(bands):
            sel = (f > lo) & (f <= hi)
            if not sel.any():
                continue
            # spectra summed over the band (weighted by power, not averaged per bin: bins the
            # motion does not excite would add their noise ratios)
            cross, auto = p_wd[sel].sum(0), p_ww[sel, j].sum()
            gain[b, :, j] = np.real(cross) / auto
            coh[b, :, j] = np.abs(cross) ** 2 / (auto * p_dd[sel].sum(0))
    return RateCoupling(bands, gain, coh)


def attitude_increments(imu: ImuSeries, poses: PoseSeries, interval_s: float = 0.1, R_imu_pose: np.ndarray | None = None,
                        offset_s: float = 0.0) -> np.ndarray:
    """``Log(dR_ref^T dR_gyro)`` over consecutive ``interval_s`` blocks of IMU samples [M, 3] (rad).

    ``dR_gyro`` integrates the gyro (the mean of consecutive samples over each step); ``dR_ref`` is the reference's rotation
    over the same stamps. Their sum over time is the attitude the gyro loses against the reference.
    """
    R = np.eye(3) if R_imu_pose is None else np.asarray(R_imu_pose, dtype=float)
    slerp, span = _reference_slerp(poses, R, offset_s)
    t = imu.t_ns.astype(float)
    inside = np.nonzero((t >= span[0]) & (t <= span[1]))[0]
    dt_s = np.diff(t) / NS_PER_S
    step = max(1, int(round(interval_s / float(np.median(dt_s)))))
    starts = inside[: (len(inside) - 2) // step * step : step]
    if len(starts) < 3:
        raise RecoveryError("the IMU and the reference pose stream overlap for too short a time")
    dR = Rotation.identity(len(starts))
    for s in range(step):
        i = starts + s
        dR = dR * Rotation.from_rotvec(0.5 * (imu.gyro_radps[i] + imu.gyro_radps[i + 1]) * dt_s[i, None])
    ref = slerp(t[starts]).inv() * slerp(t[starts + step])
    return (ref.inv() * dR).as_rotvec()


@dataclass(frozen=True)
class WalkFit:
    """Maximum-likelihood noise of one axis's attitude increments (:func:`fit_walk`).

    Attributes:
        random_walk: Gyro bias random walk, rad/s/sqrt(s).
        white_rad: White attitude error of the reference, rad.
        gm_sigma_rad / gm_tau_s: Its Gauss-Markov part (0 / nan when not modelled).
        log_likelihood: At the optimum.
    """

    random_walk: float
    white_rad: float
    gm_sigma_rad: float
    gm_tau_s: float
    log_likelihood: float


def walk_log_likelihood(increments: np.ndarray, interval_s: float, noise_density: float, random_walk: float,
                        white_rad: float, gm_sigma_rad: float = 0.0, gm_tau_s: float = 1.0) -> float:
    """Log-likelihood of one axis's increments [M] under bias walk + reference error.

    Kalman filter on the summed increments ``phi_k = p_k + g_k + w_k``: ``p`` the gyro's own
    attitude error (``p' = p + dt b + n``, ``n`` white with ``noise_density``), ``b`` the bias
    (``b' = b + random walk``), ``g`` the Gauss-Markov error (``g' = a g``, ``a = exp(-dt/tau)``) and
    ``w`` white (``white_rad``). Scalar arithmetic: the state is 3-dimensional.
    """
    dt = float(interval_s)
    a = math.exp(-dt / gm_tau_s) if gm_sigma_rad > 0 else 0.0
    qp, qb, qg = noise_density**2 * dt, random_walk**2 * dt, gm_sigma_rad**2 * (1.0 - a * a)
    r = white_rad**2
    z = np.concatenate([[0.0], np.cumsum(increments)])
    # the first sum is 0 by construction: p starts diffuse and is fixed by that first update
    p, b, g = 0.0, float(np.mean(increments[: max(1, min(len(increments), 20))]) / dt), 0.0
    pp, pb, pg, bb, bg, gg = 1.0, 0.0, 0.0, 1e-2, 0.0, gm_sigma_rad**2
    ll = 0.0
    for k, zk in enumerate(z):
        if k:  # predict
            p += dt * b
            g *= a
            pp, pb, pg = pp + 2 * dt * pb + dt * dt * bb + qp, pb + dt * bb, a * (pg + dt * bg)
            bg, gg = a * bg, a * a * gg + qg
            bb += qb
        # update with z = p + g + w
        s = pp + 2 * pg + gg + r
        res = zk - p - g
        ll -= 0.5 * (math.log(2 * math.pi * s) + res * res / s)
        kp, kb, kg = (pp + pg) / s, (pb + bg) / s, (pg + gg) / s
        p, b, g = p + kp * res, b + kb * res, g + kg * res
        pp, pb, pg = pp - kp * kp * s, pb - kp * kb * s, pg - kp * kg * s
        bb, bg, gg = bb - kb * kb * s, bg - kb * kg * s, gg - kg * kg * s
    return ll


def fit_walk(increments: np.ndarray, interval_s: float, noise_density: float, gauss_markov: bool = False,
             start_random_walk: float = 1e-3) -> WalkFit:
    """:class:`WalkFit` of one axis (Nelder-Mead on the log parameters from a few starts)."""
    y = np.asarray(increments, dtype=float)

    def nll(x: np.ndarray) -> float:
        e = np.exp(x)
        gm = (e[2], e[3]) if gauss_markov else (0.0, 1.0)
        return -walk_log_likelihood(y, interval_s, noise_density, e[0], e[1], *gm)

    starts = [[start_random_walk, 1e-4, 3e-3, 1.0], [start_random_walk / 10, 1e-4, 3e-3, 10.0],
              [start_random_walk * 10, 3e-4, 1e-3, 0.3]]
    best = None
    for s in starts:
        x0 = np.log(s if gauss_markov else s[:2])
        out = minimize(nll, x0, method="Nelder-Mead", options={"maxiter": 800, "xatol": 1e-3, "fatol": 1e-3})
        if best is None or out.fun < best.fun:
            best = out
    e = np.exp(best.x)
    return WalkFit(float(e[0]), float(e[1]), float(e[2]) if gauss_markov else 0.0,
                   float(e[3]) if gauss_markov else float("nan"), float(-best.fun))
