"""How a gyro agrees with the attitude of a reference pose stream, independent of the factor graph.

Two diagnostics of the disagreement ``d = gyro - omega_ref`` (the reference's body rate in the
IMU frame), for auditing a reference before trusting the bias recovered against it:

* :func:`rate_coupling`: the transfer from the angular rate to ``d`` by frequency band (cross
  spectra, Welch). An IMU scale or misalignment error ``S omega`` has the same gain in every band
  the motion excites; a gain at low frequencies only is not a property of the IMU's intrinsics
  (which :mod:`recovery.intrinsics.estimate` estimates) but of the reference's attitude or of a slow
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
from scipy.spatial.transform import Rotation
from scipy.special import betaincinv

from pipeline.errors import RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.calibration_init import gyro_integral, pose_rotations

# Shortest Welch segment of :func:`rate_coupling`: its lowest band needs a frequency bin or two.
MIN_SEGMENT_S = 20.0
# Frequency bands of :func:`rate_coupling` (Hz): below, around and above a MAV's manoeuvres.
DEFAULT_BANDS_HZ = ((0.0, 0.05), (0.05, 0.2), (0.2, 1.0), (1.0, 3.0))


class _Reference:
    """The pose stream's orientations on the IMU clock, interpolated where asked (slerp between the
    two samples around each stamp: only where needed, not a scipy ``Slerp`` over every sample)."""

    def __init__(self, poses: PoseSeries, offset_s: float) -> None:
        if poses.quat_wxyz is None:
            raise RecoveryError("the gyro consistency check needs orientations; this pose stream has positions "
                                "only", hint="give a 6-DoF pose stream")
        self.t = poses.t_ns.astype(float) + offset_s * NS_PER_S
        self.rot = pose_rotations(poses)
        self.span = (self.t[0], self.t[-1])

    def at(self, t: np.ndarray) -> Rotation:
        """``R_world_pose`` at ``t`` (ns, inside the span)."""
        i = np.clip(np.searchsorted(self.t, t, side="right"), 1, len(self.t) - 1)
        R0, R1 = self.rot[i - 1], self.rot[i]
        # side="right": t[i - 1] <= t < t[i], except at the last stamp (a repeated one there: no 0 / 0)
        tau = (t - self.t[i - 1]) / np.maximum(self.t[i] - self.t[i - 1], 1.0)
        return R0 * Rotation.from_rotvec((R0.inv() * R1).as_rotvec() * tau[:, None])


def block_rates(imu: ImuSeries, poses: PoseSeries, R_imu_pose: np.ndarray | None = None, offset_s: float = 0.0,
                step: int = 1) -> tuple[np.ndarray, np.ndarray, float]:
    """The gyro's and the reference's mean body rate over blocks of ``step`` IMU sample intervals.

    The gyro's is its integral over the block (the mean of consecutive samples over each interval)
    over the block's duration; the reference's is the rotation between its orientations at the
    block's ends over the same duration. Only blocks inside the pose stream's span.

    Returns:
        ``omega_gyro_radps`` [M, 3], ``omega_ref_radps`` [M, 3] (IMU frame), the block rate in Hz.
    """
    R = np.eye(3) if R_imu_pose is None else np.asarray(R_imu_pose, dtype=float)
    reference = _Reference(poses, offset_s)
    t = imu.t_ns.astype(float)
    inside = np.nonzero((t >= reference.span[0]) & (t <= reference.span[1]))[0]
    edges = inside[::step]
    if len(edges) < 3:
        raise RecoveryError("the IMU and the reference pose stream do not overlap in time")
    _, area = gyro_integral(imu, int(imu.t_ns[0]))  # trapezoid: the mean of consecutive samples per step
    duration_s = np.diff(t[edges]) / NS_PER_S
    gyro = np.diff(area[edges], axis=0) / duration_s[:, None]
    ends = reference.at(t[edges])
    # the IMU's rotation is R_imu_pose dP R_imu_pose^T: its rotation vector R_imu_pose times dP's
    ref = (ends[:-1].inv() * ends[1:]).as_rotvec() @ R.T / duration_s[:, None]
    return gyro, ref, float(1.0 / np.median(duration_s))


# An element of the transfer counts in a band where the multiple coherence of its row reaches this
# (or the level that three unrelated inputs reach by chance in COUPLING_CHANCE of cases with the
# band's independent averages, if higher) and its gain this much.
COUPLING_MIN_COHERENCE = 0.5
COUPLING_CHANCE = 0.001
COUPLING_MIN_GAIN = 2e-3
# Bands from this frequency up tell an intrinsic error (every band) from a slow process.
FAST_BAND_HZ = 0.2
# A share of the rate this large is no IMU intrinsic error (those are percents) but a frame mismatch: a gyro
# axis reading another axis's rotation, or a rotation the pose stream lacks (validation.plausibility).
FRAME_SWAP_GAIN = 0.5


class CouplingKind(str, enum.Enum):
    """What :class:`RateCoupling` shows."""

    NONE = "none"  # no share of the rate that counts in two bands or below FAST_BAND_HZ alone
    INTRINSIC = "intrinsic"  # a gain that counts in two bands or more, one from FAST_BAND_HZ up, the same in each
    SLOW = "slow"  # a gain that counts below FAST_BAND_HZ only, under a quarter of it above: not an intrinsic error


@dataclass(frozen=True)
class RateCoupling:
    """Transfer from the angular rate to the gyro's disagreement with a reference, by band.

    ``d = gyro - omega_ref`` is modelled as ``d = H omega`` plus what the rate does not explain,
    with the three rate axes as joint inputs (so a scale error on one axis does not pass for a
    misalignment of another that moves with it).

    Attributes:
        bands_hz: Band edges [n, 2].
        gain: Real part of ``H`` over each band [n, 3, 3] (rows: the axis of ``d``, columns: the
            rate axis). A scale / misalignment error ``S`` shows as ``gain[b] = S`` in every
            excited band.
        coherence: Multiple coherence of each axis of ``d`` with the rate over each band [n, 3]:
            the share of its power the rate explains (0-1).
        coherence_needed: Per band [n], the coherence an element's row needs to count: at least
            ``COUPLING_MIN_COHERENCE``, and above chance for the band's number of independent
            averages ``n`` (bins times non-overlapping segments; the multiple coherence of three
            unrelated inputs follows Beta(3, n - 3)). The lowest band of a two-minute recording
            rarely counts: slow signals are few cycles long.
    """

    bands_hz: np.ndarray
    gain: np.ndarray
    coherence: np.ndarray
    coherence_needed: np.ndarray

    def _counts(self) -> np.ndarray:
        """[n, 3, 3]: where an element counts (its row's coherence and its own gain)."""
        return ((self.coherence >= self.coherence_needed[:, None])[:, :, None]
                & (np.abs(self.gain) >= COUPLING_MIN_GAIN))

    def _elements(self, kind: CouplingKind) -> np.ndarray:
        """[3, 3]: the elements that show ``kind`` (INTRINSIC or SLOW; see :class:`CouplingKind`)."""
        counts, fast = self._counts(), self.bands_hz[:, 0] >= FAST_BAND_HZ
        out = np.zeros((3, 3), bool)
        for i in range(3):
            for j in range(3):
                c, g = counts[:, i, j], self.gain[:, i, j]
                if kind is CouplingKind.INTRINSIC and c.sum() >= 2 and c[fast].any():
                    gc = g[c]
                    out[i, j] = (np.all(gc > 0) or np.all(gc < 0)) and np.abs(gc).max() <= 2.0 * np.abs(gc).min()
                elif kind is CouplingKind.SLOW and c[~fast].any() and not c[fast].any():
                    out[i, j] = bool(np.all(np.abs(g[fast]) < 0.25 * np.abs(g[c]).max()))
        return out

    def kind(self) -> CouplingKind:
        """INTRINSIC if some element shows it, else SLOW if some element shows that, else NONE."""
        for kind in (CouplingKind.INTRINSIC, CouplingKind.SLOW):
            if self._elements(kind).any():
                return kind
        return CouplingKind.NONE

    def strongest(self) -> tuple[int, int, int]:
        """(band, row, column) of the largest counting gain among the elements that show :meth:`kind`
        (for NONE: of the largest gain in the most coherent row)."""
        kind = self.kind()
        if kind is CouplingKind.NONE:
            b, i = np.unravel_index(np.argmax(self.coherence), self.coherence.shape)
            mask = np.zeros(self.gain.shape, bool)
            mask[b, i] = True
        else:
            mask = self._counts() & self._elements(kind)[None]
        score = np.where(mask, np.abs(self.gain), -1.0)
        return tuple(int(x) for x in np.unravel_index(np.argmax(score), score.shape))  # type: ignore[return-value]

    def sentence(self) -> str:
        """One plain sentence on what the coupling shows, for reports."""
        b, r, c = self.strongest()
        kind = self.kind()
        lo, hi = self.bands_hz[b]
        row = ", ".join(f"{g:+.4f}" for g in self.gain[b, r])
        where = f"at {lo:g}-{hi:g} Hz the gyro {'xyz'[r]} reads ({row}) of the rate about (x, y, z)"
        if kind is CouplingKind.NONE:
            need = (f"{self.coherence_needed[b]:.2f} needed" if self.coherence_needed[b] < 0.995
                    else "too few independent averages in that band to tell it from chance")
            return (f"The gyro follows the pose stream's rotation: no share of the rate counts (most coherent: "
                    f"{where}, coherence {self.coherence[b, r]:.2f}; {need}).")
        if abs(self.gain[b, r, c]) >= FRAME_SWAP_GAIN:
            return (f"Against this pose stream {where} (coherence {self.coherence[b, r]:.2f}): a share of "
                    f"{abs(self.gain[b, r, c]):.2f} of the rate is no IMU error (scale and misalignment are percents) "
                    "but a frame mismatch: a gyro axis reads another axis's rotation, or one the pose stream lacks "
                    "(a wrong pose-to-IMU rotation, planar odometry).")
        if kind is CouplingKind.INTRINSIC:
            return (f"Against this pose stream {where} (coherence {self.coherence[b, r]:.2f}), the "
                    f"{'xyz'[c]} term alike in every band where it counts up to {self.bands_hz[-1, 1]:g} Hz: a "
                    f"{'scale' if r == c else 'misalignment'} error of the IMU (or of the extrinsic), which "
                    "recovery.intrinsics.estimate estimates; without it the bias follows the rate.")
        fast = self.bands_hz[:, 0] >= FAST_BAND_HZ
        return (f"Against this pose stream {where} (coherence {self.coherence[b, r]:.2f}), but the {'xyz'[c]} "
                f"term reaches at most {np.max(np.abs(self.gain[fast, r, c])):.4f} from {FAST_BAND_HZ:g} Hz up: "
                "not an IMU scale or misalignment (those read the same in every band) but a slow process that "
                "follows the rotation: a bias that changes with it, or an attitude error of the reference. The "
                "bias absorbs it (its random walk rises) and no intrinsic term can.")


def cross_spectra(x: np.ndarray, fs_hz: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """Welch cross-spectral densities of the columns of ``x`` [M, C].

    The values of ``scipy.signal.csd(x[:, :, None], x[:, None, :], fs_hz, nperseg=nperseg, axis=0)``
    (periodic Hann window, half-overlapping segments, each segment's mean removed, one-sided
    density) without importing scipy.signal, which would add ~0.5 s and ~25 MB to every recovery
    process.

    Returns:
        ``f`` [F] (Hz) and ``S`` [F, C, C] with ``S[f, k, l] = mean over segments of conj(X_k) X_l``.
    """
    step = nperseg - nperseg // 2
    n_seg = (len(x) - nperseg) // step + 1
    window = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    seg = x[np.arange(n_seg)[:, None] * step + np.arange(nperseg)[None, :]]  # [n_seg, nperseg, C]
    X = np.fft.rfft((seg - seg.mean(axis=1, keepdims=True)) * window[None, :, None], axis=1)
    S = np.einsum("sfk,sfl->fkl", np.conj(X), X) / (n_seg * fs_hz * np.sum(window**2))
    S[1:None if nperseg % 2 else -1] *= 2.0  # one-sided: every bin but DC (and an even length's Nyquist)
    return np.fft.rfftfreq(nperseg, 1.0 / fs_hz), S


def rate_coupling(imu: ImuSeries, poses: PoseSeries, R_imu_pose: np.ndarray | None = None, offset_s: float = 0.0,
                  bands_hz: tuple[tuple[float, float], ...] = DEFAULT_BANDS_HZ,
                  segment_s: float = 40.0) -> RateCoupling:
    """:class:`RateCoupling` of ``d = gyro - omega_ref`` against the gyro's rate.

    Welch cross-spectra over ``segment_s`` segments (at most half the recording, at least
    ``MIN_SEGMENT_S``: their resolution must resolve the lowest band), summed over each band;
    per band ``H^T = S_ww^-1 S_wd`` (the three rate axes as joint inputs). The bands stop at 3 Hz:
    above, the reference's rate (its orientations interpolated) no longer follows the gyro's.

    Raises:
        RecoveryError: if the overlap is shorter than two segments or the stream has no orientation.
    """
    t = imu.t_ns
    imu_rate_hz = (len(t) - 1) * NS_PER_S / float(t[-1] - t[0])
    # blocks of >= 1 / (5x the top band): the same low pass on the rate and on d leaves the transfer
    # between them as it is, at a fraction of the samples (and of the slerps)
    step = max(1, int(imu_rate_hz // (5.0 * bands_hz[-1][1])))
    w, ref, rate_hz = block_rates(imu, poses, R_imu_pose, offset_s, step)
    d = w - ref
    # at most half the recording per segment: two segments at least (fewer averages on a short
    # recording raise the coherence a band needs, so it stays a fair test)
    nper = int(min(segment_s * rate_hz, len(w) / 2))
    if nper / rate_hz < MIN_SEGMENT_S:
        raise RecoveryError(f"the rate coupling needs at least {2 * MIN_SEGMENT_S:.0f} s of overlap, "
                            f"got {math.floor(10 * len(w) / rate_hz) / 10:.1f} s", hint="use a longer recording")
    x = np.hstack([w - w.mean(0), d - d.mean(0)])  # [M, 6]: rate, then d
    # S[f, k, l] = E[conj(X_k) X_l] over the six signals
    f, S = cross_spectra(x, rate_hz, nper)
    bands = np.asarray(bands_hz, dtype=float)
    gain = np.zeros((len(bands), 3, 3))
    coh = np.zeros((len(bands), 3))
    # a band of three or fewer independent averages has coherence 1 whatever the signals: it never counts
    needed = np.full(len(bands), np.inf)
    segments = len(x) // nper  # independent ones: Welch's half-overlapping segments are correlated
    for b, (lo, hi) in enumerate(bands):
        sel = (f > lo) & (f <= hi)
        if not sel.any():
            continue
        averages = int(sel.sum()) * segments
        # the Beta(3, n - 3) quantile of the chance coherence of three inputs
        if averages > 3:
            needed[b] = max(COUPLING_MIN_COHERENCE, float(betaincinv(3, averages - 3, 1.0 - COUPLING_CHANCE)))
        Sb = S[sel].sum(0)
        S_ww, S_wd, S_dd = Sb[:3, :3], Sb[:3, 3:], np.real(np.diag(Sb[3:, 3:]))
        Ht = np.linalg.solve(S_ww, S_wd)  # [rate, d]
        gain[b] = np.real(Ht).T
        coh[b] = np.real(np.einsum("ki,ki->i", np.conj(S_wd), Ht)) / S_dd
    return RateCoupling(bands, gain, coh, needed)


def attitude_increments(imu: ImuSeries, poses: PoseSeries, interval_s: float = 0.1, R_imu_pose: np.ndarray | None = None,
                        offset_s: float = 0.0) -> np.ndarray:
    """``Log(dR_ref^T dR_gyro)`` over consecutive ``interval_s`` blocks of IMU samples [M, 3] (rad).

    ``dR_gyro`` integrates the gyro (the mean of consecutive samples over each step); ``dR_ref`` is
    the reference's rotation over the same stamps. Their sum over time is the attitude the gyro
    loses against the reference.
    """
    E = Rotation.from_matrix(np.eye(3) if R_imu_pose is None else np.asarray(R_imu_pose, dtype=float))
    reference = _Reference(poses, offset_s)
    t = imu.t_ns.astype(float)
    inside = np.nonzero((t >= reference.span[0]) & (t <= reference.span[1]))[0]
    dt_s = np.diff(t) / NS_PER_S
    step = max(1, int(round(interval_s / float(np.median(dt_s)))))
    starts = inside[: (len(inside) - 2) // step * step : step]
    if len(starts) < 3:
        raise RecoveryError("the IMU and the reference pose stream overlap for too short a time")
    dR = Rotation.identity(len(starts))
    for s in range(step):
        i = starts + s
        dR = dR * Rotation.from_rotvec(0.5 * (imu.gyro_radps[i] + imu.gyro_radps[i + 1]) * dt_s[i, None])
    ref = E * reference.at(t[starts]).inv() * reference.at(t[starts + step]) * E.inv()  # in the IMU frame
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
