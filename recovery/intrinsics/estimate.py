"""IMU intrinsics (scale, misalignment, g-sensitivity) estimated around the bias recovery.

Measurement model (the seed paper's Eq. 2, Kalibr's scale-misalignment model; body frame)::

    gyro = M_g omega + G f + b_g + n_g,      M_g = I + S_g      (S_g: 9 terms)
    acc  = M_a f     + b_a + n_a,            M_a = I + S_a      (S_a: 9 terms)

``S`` holds the scale errors on its diagonal and the misalignments off it; ``G`` (rad/s per
m/s^2) is the gyro's g-sensitivity. The factor graph of :mod:`recovery.solver.graph` has no such terms,
so they are estimated in an alternating outer loop (the intrinsics are constants observed
through the trajectory, which the pose stream pins down whatever the bias does):

1. solve as usual;
2. fit, by linear least squares over every keyframe interval, the intrinsics together with a
   random-walk bias correction around the solved bias (the gyro's as ``block_s`` means, the
   accelerometer's low-passed at ``1 / block_s``: slow drift stays with the bias); the
   accelerometer terms' regressor is the bias-free force low-passed at ``REGRESSOR_CUTOFF_HZ``, so
   that it does not share the interval's own noise with the residual (errors in variables: a scale
   estimate pulled up by the noise's variance); a term whose sigma
   exceeds ``max_sigma`` is not observable from this motion: it is not corrected in the readings
   and is named in a warning;
3. correct the readings, ``acc' = M_a^-1 acc``, ``gyro' = M_g^-1 (gyro - G f)``, and solve again;
   a term enters when it differs from zero by 3 sigma, and later fits refine it while they move
   a term by more than ``REFINE_SIGMAS`` sigma (at most ``max_rounds``);
4. after the last round, drop every term within 3 sigma of zero and solve once more
   (:func:`drop_insignificant`).

A position-only pose stream does not pin the trajectory down: nothing is estimated for it
(identity, with a warning). The bias is reported in the raw readings' convention (``b = M b'``),
and its sigma includes the uncertainty of the estimated terms
(:func:`recovery.intrinsics.posterior.intrinsics_bias_variance`): a gravity-axis term times ``f ~ g`` is
nearly a constant bias offset. The terms left out (not significant, not observable) are still in the
readings and in the bias: under a datasheet prior (:class:`recovery.intrinsics.posterior.IntrinsicsPrior`),
their posterior means are taken out of the bias (``left_out_shift``) and their posterior variance is
added to its sigma (:mod:`recovery.intrinsics.posterior`). When the
accelerometer agrees with a calibration file's extrinsic rotation (the solve's turn from it is then
the gyro's own rotation), every fit takes the file's rotation as the accelerometer's
(:mod:`recovery.intrinsics.frame`): the accelerometer readings are turned into the solve's frame
instead of its bias absorbing gravity times the turn. Design notes and the reasons for this scheme:
``docs/internals.md``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.errors import BiasgtError
from pipeline.types import DEFAULT_GRAVITY_MPS2, NOISE_DENSITY_FIELDS, NS_PER_S, ImuNoiseModel, ImuSeries, Sequence
from recovery.config import IntrinsicsMode, PoseFactorMode
from recovery.intrinsics.gyro_consistency import CouplingKind, rate_coupling
from recovery.intrinsics.frame import calibration_agreement, rotation_prior
from recovery.intrinsics.least_squares import solve_with_walk
from recovery.intrinsics.posterior import IntrinsicsPrior, intrinsics_bias_variance, left_out_means, left_out_shift
from recovery.intrinsics.report import TERMS as _TERMS
from recovery.intrinsics.report import intrinsics_report, term_table, unobservable_warning
from recovery.outputs import RecoveryReport

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class ImuIntrinsics:
    """``M_g``, ``M_a`` (3x3, identity = perfect) and ``G`` (3x3, rad/s per m/s^2)."""

    gyro_matrix: np.ndarray
    acc_matrix: np.ndarray
    gyro_g_sensitivity: np.ndarray

    @classmethod
    def identity(cls) -> "ImuIntrinsics":
        return cls(np.eye(3), np.eye(3), np.zeros((3, 3)))

    def correct(self, imu: ImuSeries, bias_acc_mps2: np.ndarray) -> ImuSeries:
        """Readings with the intrinsics removed (``bias_acc_mps2`` [N, 3]: to estimate ``f`` for ``G``)."""
        acc = np.linalg.solve(self.acc_matrix, imu.acc_mps2.T).T
        f = np.linalg.solve(self.acc_matrix, (imu.acc_mps2 - bias_acc_mps2).T).T
        gyro = np.linalg.solve(self.gyro_matrix, (imu.gyro_radps - f @ self.gyro_g_sensitivity.T).T).T
        return replace(imu, gyro_radps=gyro, acc_mps2=acc)

    def deviations(self) -> dict[str, np.ndarray]:
        """Per group (as :class:`IntrinsicsFit`'s), the 3x3 terms: ``M - I`` for the scale and
        misalignment groups, ``G`` for the g-sensitivity."""
        return {"gyro_scale_misalignment": self.gyro_matrix - np.eye(3),
                "acc_scale_misalignment": self.acc_matrix - np.eye(3),
                "gyro_g_sensitivity": np.array(self.gyro_g_sensitivity, dtype=float)}

    def compose(self, step: "ImuIntrinsics") -> "ImuIntrinsics":
        """The intrinsics of raw readings when ``step`` was fitted on readings corrected by ``self``."""
        return ImuIntrinsics(self.gyro_matrix @ step.gyro_matrix, self.acc_matrix @ step.acc_matrix,
                             self.gyro_g_sensitivity + self.gyro_matrix @ step.gyro_g_sensitivity)


@dataclass(frozen=True)
class IntrinsicsFit:
    """One least-squares fit: the step, each term's sigma and whether it was observable.

    Attributes:
        step: Intrinsics of the readings the fit saw (identity where not observable).
        sigma: Per group (``gyro_scale_misalignment``, ``acc_scale_misalignment``,
            ``gyro_g_sensitivity``), the 3x3 sigmas of the terms (NaN where not estimated).
        observable: The same groups, 3x3 booleans.
        residual_rms: Whitening scale of each equation group (rad, m/s) after the fit.
        applied: The same groups, 3x3 booleans: the terms the step changes (significant, or
            present already).
        cov: Covariance of the fitted terms, row-major per group: ``rotation`` (S_g, then G when
            fitted), ``velocity`` (S_a).
        estimate: The same groups, 3x3: every term's least-squares value, applied or not (what the
            readings the fit saw still carry of it).
    """

    step: ImuIntrinsics
    sigma: dict[str, np.ndarray]
    observable: dict[str, np.ndarray]
    residual_rms: dict[str, float]
    estimated: tuple[str, ...] = ("gyro_scale_misalignment", "acc_scale_misalignment")
    applied: dict[str, np.ndarray] | None = None  # per group, 3x3: the terms the step changes
    cov: dict[str, np.ndarray] | None = None  # "rotation": [9 or 18]^2 (S_g, G), "velocity": [9, 9] (S_a)
    estimate: dict[str, np.ndarray] | None = None  # per group, 3x3: the least-squares values

    def moved(self, n_sigma: float = 3.0) -> bool:
        """Whether the step changes any observable term by more than ``n_sigma`` of its sigmas."""
        deltas = self.step.deviations()
        return any(np.any(np.abs(deltas[k][self.observable[k]]) > n_sigma * self.sigma[k][self.observable[k]])
                   for k in self.sigma)


@dataclass(frozen=True)
class _Interval:
    """Rows of the linear system of one keyframe interval."""

    A_rot: np.ndarray  # [3, 9 + 9] (S_g, G)
    A_vel: np.ndarray  # [3, 9]     (S_a)
    B_rot: np.ndarray  # [3, 3] coefficient of the gyro bias correction (sum of J_i dt_i)
    B_vel: np.ndarray  # [3, 3] coefficient of the acc bias correction (sum of R_i dt_i)
    r_vel: np.ndarray  # [3]


def _interval(dt: np.ndarray, gyro: np.ndarray, f: np.ndarray, f_reg: np.ndarray, steps: np.ndarray, half: np.ndarray,
              R0: np.ndarray, R1: np.ndarray, v0: np.ndarray, v1: np.ndarray, gravity: np.ndarray
              ) -> tuple[_Interval, np.ndarray]:
    """Linearised residuals of one interval: samples [n] held ``dt`` [n] (s), their rotations
    ``exp(gyro dt)`` and ``exp(gyro dt / 2)`` ([n, 3, 3] each); ``f`` [n, 3] integrates into the velocity
    residual, ``f_reg`` [n, 3] is the accelerometer terms' regressor. Returns the interval and its rotation
    error [3, 3], whose log is the rotation residual (converted for every interval at once)."""
    n = len(dt)
    # R_i: attitude at sample i (world from body), propagated from the trajectory's R0 by the gyro
    R = np.empty((n + 1, 3, 3))
    R[0] = R0
    for i in range(n):
        R[i + 1] = R[i] @ steps[i]
    # J_i: rotation from sample i + 1 to the end, transposed (body frame at the end)
    after = np.empty((n, 3, 3))
    acc_rot = np.eye(3)
    for i in range(n - 1, -1, -1):
        after[i] = acc_rot.T
        acc_rot = steps[i] @ acc_rot
    dR_imu = R0.T @ R[n]
    Jdt = after * dt[:, None, None]  # [n, 3, 3]
    # d_omega_i = -(S_g omega_i + G f_i) - db: S omega = kron(omega^T, I) vec_row(S) in row-major -> use einsum
    A_sg = -np.einsum("nij,nk->nijk", Jdt, gyro).reshape(n, 3, 9).sum(0)
    A_g = -np.einsum("nij,nk->nijk", Jdt, f).reshape(n, 3, 9).sum(0)
    # the attitude at the middle of each step rotates the step's (midpoint) specific force
    Rdt = np.einsum("nij,njk->nik", R[:n], half) * dt[:, None, None]
    dv_imu = np.einsum("nij,nj->i", Rdt, f) + gravity * dt.sum()
    r_vel = (v1 - v0) - dv_imu
    A_sa = -np.einsum("nij,nk->nijk", Rdt, f_reg).reshape(n, 3, 9).sum(0)
    return _Interval(np.hstack([A_sg, A_g]), A_sa, -Jdt.sum(0), -Rdt.sum(0), r_vel), dR_imu.T @ (R0.T @ R1)


def _hold_durations(t_ns: np.ndarray, a_ns: int, b_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """(indices i of the sample intervals [t_i, t_i+1] that overlap [a, b], seconds of each inside it)."""
    i0 = max(int(np.searchsorted(t_ns, a_ns, side="right")) - 1, 0)
    i1 = int(np.searchsorted(t_ns, b_ns, side="left"))
    idx = np.arange(i0, min(i1, len(t_ns) - 1))
    start = np.maximum(t_ns[idx], a_ns)
    end = np.minimum(t_ns[idx + 1], b_ns)
    keep = end > start
    return idx[keep], (end[keep] - start[keep]) / NS_PER_S


#: Low-pass (Hz) of the accelerometer terms' regressor: a 0.1-s interval holds ~20 % of its weight (against
#: 100 % for the raw force), the handheld and drone motion's tilt and thrust changes pass.
REGRESSOR_CUTOFF_HZ = 1.0


def fit_intrinsics(imu: ImuSeries, t_ns: np.ndarray, quat_wxyz: np.ndarray, v_mps: np.ndarray,
                   bias_at: Callable[[np.ndarray], np.ndarray], gravity_mps2: np.ndarray, noise: ImuNoiseModel, *,
                   g_sensitivity: bool, block_s: float = 10.0, max_sigma: float = 2e-3,
                   max_sigma_g_sensitivity: float = 5e-4, n_sigma: float = 3.0,
                   present: dict[str, np.ndarray] | None = None,
                   acc_prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                   regressor_cutoff_hz: float = REGRESSOR_CUTOFF_HZ) -> IntrinsicsFit:
    """Fit the intrinsics of ``imu`` against a solved trajectory (see the module docstring).

    Per keyframe interval the bias correction is a free variable tied to its neighbours by the
    random-walk prior ``noise`` (a Kalman-smoother-like sparse least squares); the solved bias,
    which may have absorbed rate-correlated error, enters only through its ``block_s`` means (gyro)
    or low-passed at ``1 / block_s`` (accelerometer: a continuous curve, as the block means' steps at
    each block's end exceed what the walk allows and reach the scale terms times g).
    The accelerometer terms' regressor is the force less the solved bias, low-passed at
    ``regressor_cutoff_hz`` (an instrument free of the interval's own noise and of the bias's
    steps; the gyro's noise is too small against the rate for this to matter).

    Args:
        imu: The readings the trajectory was solved with.
        t_ns / quat_wxyz / v_mps: The solved IMU trajectory at the keyframes, [K] / [K, 4] / [K, 3].
        bias_at: The solved bias at given stamps, [N] -> [N, 6].
        gravity_mps2: Gravity in the trajectory's world frame, [3].
        noise: White noise and bias random walk of the fit.
        g_sensitivity: Also fit ``G``.
        block_s: Blocks (gyro) and time scale of the low-pass (accelerometer) of the solved bias before it
            is subtracted.
        max_sigma / max_sigma_g_sensitivity: Largest sigma of an observable term.
        n_sigma: A term is applied only when it differs from zero by more than this many sigmas,
            or when it is ``present`` already (per group, 3x3 booleans: terms applied in earlier
            rounds, whose least-squares refinement is the best estimate of what is left of them;
            gating each refinement again would leave up to ``n_sigma`` sigmas of them unapplied).
        acc_prior: Prior rows ``(H [m, 9], target [m], sigma [m])`` on ``S_a`` (row-major): the
            accelerometer's rotation from a calibration file (:func:`recovery.intrinsics.frame.rotation_prior`).
        regressor_cutoff_hz: Low-pass of the accelerometer terms' regressor.
    """
    R_kf = Rotation.from_quat(quat_wxyz, scalar_first=True).as_matrix()
    # the gyro's solved bias as block means, the accelerometer's low-passed (its scale terms meet the
    # block ends' steps at g times the walk; the gyro's terms at the rate, which the steps barely touch)
    solved = bias_at(imu.t_ns)
    block = np.clip(((imu.t_ns - t_ns[0]) / NS_PER_S // block_s).astype(int), 0, None)
    b = np.hstack([_block_means(solved[:, :3], block), zero_phase_low_pass(imu.t_ns, solved[:, 3:], 1.0 / block_s)])
    gyro, f = imu.gyro_radps - b[:, :3], imu.acc_mps2 - b[:, 3:]
    # midpoint samples: the mean of the readings at both ends of each sample interval (the
    # recovery's preintegration does the same; a zero-order hold lags by half a sample and
    # shows up as a spurious misalignment of ~1e-4)
    gyro = np.vstack([0.5 * (gyro[:-1] + gyro[1:]), gyro[-1:]])
    f = np.vstack([0.5 * (f[:-1] + f[1:]), f[-1:]])
    f_reg = zero_phase_low_pass(imu.t_ns, imu.acc_mps2 - solved[:, 3:], regressor_cutoff_hz)
    held = [_hold_durations(imu.t_ns, int(t_ns[k]), int(t_ns[k + 1])) for k in range(len(t_ns) - 1)]
    kept = [k for k, (idx, _) in enumerate(held) if len(idx) >= 2 and np.all(np.isfinite(gyro[idx]))]
    idx_all = np.concatenate([held[k][0] for k in kept] or [np.zeros(0, int)])
    dt_all = np.concatenate([held[k][1] for k in kept] or [np.zeros(0)])
    rotvec = gyro[idx_all] * dt_all[:, None]
    steps_all = Rotation.from_rotvec(rotvec).as_matrix()  # every interval's sample rotations at once
    half_all = Rotation.from_rotvec(0.5 * rotvec).as_matrix()
    cut = np.cumsum([len(held[k][0]) for k in kept])[:-1]
    rows: list[_Interval] = []
    errors: list[np.ndarray] = []
    for k, dt, s_k, h_k in zip(kept, np.split(dt_all, cut), np.split(steps_all, cut), np.split(half_all, cut)):
        idx = held[k][0]
        iv, err = _interval(dt, gyro[idx], f[idx], f_reg[idx], s_k, h_k, R_kf[k], R_kf[k + 1], v_mps[k], v_mps[k + 1],
                            gravity_mps2)
        rows.append(iv)
        errors.append(err)
    r_rot = Rotation.from_matrix(np.stack(errors)).as_rotvec() if errors else np.zeros((0, 3))
    span = np.array([held[k][1].sum() for k in kept])
    n_int = 18 if g_sensitivity else 9
    x_rot, s_rot, rms_rot, c_rot = solve_with_walk(np.stack([iv.A_rot[:, :n_int] for iv in rows]),
                                             np.stack([iv.B_rot for iv in rows]), r_rot,
                                             span, noise.gyro_noise_density, noise.gyro_random_walk)
    x_vel, s_vel, rms_vel, c_vel = solve_with_walk(np.stack([iv.A_vel for iv in rows]), np.stack([iv.B_vel for iv in rows]),
                                             np.stack([iv.r_vel for iv in rows]), span, noise.acc_noise_density,
                                             noise.acc_random_walk, acc_prior)
    groups = {"gyro_scale_misalignment": (x_rot[:9], s_rot[:9], max_sigma),
              "acc_scale_misalignment": (x_vel[:9], s_vel[:9], max_sigma)}
    if g_sensitivity:
        groups["gyro_g_sensitivity"] = (x_rot[9:18], s_rot[9:18], max_sigma_g_sensitivity)
    mats, sigma, observable, applied, estimate = {}, {}, {}, {}, {}
    for name, (x, s_, limit) in groups.items():
        estimate[name] = x.reshape(3, 3)
        ok = np.isfinite(s_) & (s_ <= limit)
        # a term not significantly different from zero stays zero: applying its noise would move
        # the bias (a G term times gravity is a constant gyro offset) for nothing
        was = np.zeros(9, bool) if present is None or name not in present else np.asarray(present[name]).ravel()
        use = ok & ((np.abs(x) > n_sigma * s_) | was)
        mats[name] = np.where(use, x, 0.0).reshape(3, 3)
        sigma[name] = s_.reshape(3, 3)
        observable[name] = ok.reshape(3, 3)
        applied[name] = use.reshape(3, 3)
    if not g_sensitivity:
        mats["gyro_g_sensitivity"] = np.zeros((3, 3))
        sigma["gyro_g_sensitivity"] = np.full((3, 3), np.nan)
        observable["gyro_g_sensitivity"] = np.zeros((3, 3), bool)
    # The fit is linear in P with w = (I - P_g) gyro - G' f and f = (I - P_a) acc (bias removed):
    # exactly M = (I - P)^-1 and G = M_g G', not just to first order (1 % scale: 1e-4 apart).
    M_g = np.linalg.inv(np.eye(3) - mats["gyro_scale_misalignment"])
    step = ImuIntrinsics(M_g, np.linalg.inv(np.eye(3) - mats["acc_scale_misalignment"]),
                         M_g @ mats["gyro_g_sensitivity"])
    return IntrinsicsFit(step, sigma, observable, {"rotation_rad": rms_rot, "velocity_mps": rms_vel},
                         tuple(groups), applied, {"rotation": c_rot, "velocity": c_vel}, estimate)


def zero_phase_low_pass(t_ns: np.ndarray, values: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """``values`` [N, k] through a zero-phase low-pass with the gain of a 4th-order Butterworth run forwards and
    backwards (``1 / (1 + (f / cutoff_hz)^8)``, as ``scipy.signal.sosfiltfilt``), applied in the frequency domain
    to the series extended by its point reflection at both ends (``filtfilt``'s odd padding: no step or kink at
    the ends, nothing wraps); non-finite rows bridged linearly first."""
    ok = np.all(np.isfinite(values), axis=1)
    filled = np.column_stack([np.interp(t_ns, t_ns[ok], values[ok, c]) for c in range(values.shape[1])])
    n = len(filled)
    rate_hz = NS_PER_S / float(np.median(np.diff(t_ns))) if n > 1 else 0.0
    if cutoff_hz <= 0 or cutoff_hz >= 0.5 * rate_hz:
        return filled
    extended = np.concatenate([2 * filled[0] - filled[::-1], filled, 2 * filled[-1] - filled[::-1]])
    spectrum = np.fft.rfft(extended, axis=0)
    spectrum *= 1.0 / (1.0 + (np.fft.rfftfreq(3 * n, d=1.0 / rate_hz) / cutoff_hz) ** 8)[:, None]
    return np.fft.irfft(spectrum, n=3 * n, axis=0)[n:2 * n]


def _block_means(values: np.ndarray, block: np.ndarray) -> np.ndarray:
    """Each row replaced by the mean of its block's rows ([N, k], block [N] ints >= 0)."""
    counts = np.bincount(block)
    sums = np.stack([np.bincount(block, weights=values[:, c]) for c in range(values.shape[1])], axis=1)
    return (sums / np.maximum(counts, 1)[:, None])[block]


def raw_bias(total: ImuIntrinsics, bias: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bias and sigma [K, 6] in the raw readings' convention from those of corrected readings."""
    out = np.hstack([bias[:, :3] @ total.gyro_matrix.T, bias[:, 3:] @ total.acc_matrix.T])
    var_g = (std[:, :3] ** 2) @ (total.gyro_matrix ** 2).T
    var_a = (std[:, 3:] ** 2) @ (total.acc_matrix ** 2).T
    return out, np.sqrt(np.hstack([var_g, var_a]))


def _fit_noise(sequence: Sequence, report: dict, max_walk_scale: float = 30.0) -> ImuNoiseModel:
    """White noise of the solve, and its random walks capped at ``max_walk_scale`` x the calibration's.

    A solve on readings with intrinsic errors inflates the random walk so that the bias follows
    them (up to 300x); at that strength the walk would absorb the intrinsics again.
    """
    cal = sequence.calibration
    used = report.get("noise") or {}
    def walk(key: str, datasheet: float) -> float:
        return min(float(used.get(key, datasheet)), max_walk_scale * datasheet)
    return ImuNoiseModel(**{f: float(used.get(f, getattr(cal, f))) for f in NOISE_DENSITY_FIELDS},
                         gyro_random_walk=walk("gyro_random_walk", cal.gyro_random_walk),
                         acc_random_walk=walk("acc_random_walk", cal.acc_random_walk))


#: Another round (a full solve on corrected readings) while the fit still moves a term by more than this.
REFINE_SIGMAS = 1.0
#: After the last round a term stays only if its total differs from zero (identity) by more than this
#: many of the last fit's sigmas (the entry gate's 3).
EXIT_SIGMAS = 3.0


def drop_insignificant(total: ImuIntrinsics, fit: IntrinsicsFit, present: dict[str, np.ndarray],
                       n_sigma: float = EXIT_SIGMAS) -> tuple[ImuIntrinsics, dict[str, np.ndarray], list[str]]:
    """``total`` without the terms whose total (raw readings' convention) is within ``n_sigma`` of zero in ``fit``.

    Two ways a term ends up non-zero without being significant: it entered in an early round,
    fitted against a trajectory that still followed other errors, and each refinement removes
    only part of that (see the module docstring); or it was never applied but the composition
    put it there (``G = M_g G'``: a gyro misalignment times a real ``G`` term fills a ``G`` term
    the fits held at zero). On the benchmark's drone a ``G zz`` of 1.6-1.9 sigma stayed either
    way; times ``f_z ~ g`` it is a constant gyro z bias offset (bias RMSE 1.18-1.26x that of the
    same sequence without intrinsic errors).

    Returns:
        The intrinsics, ``present`` without the dropped terms, and their names.
    """
    values = total.deviations()
    keep, dropped = dict(present), []
    for name in fit.sigma:
        was = np.asarray(present.get(name, np.zeros((3, 3), bool)), bool)
        with np.errstate(invalid="ignore"):
            drop = (values[name] != 0.0) & (np.abs(values[name]) <= n_sigma * fit.sigma[name])
        keep[name] = was & ~drop
        values[name] = np.where(drop, 0.0, values[name])
        dropped += [f"{name}[{_TERMS[i]}]" for i in np.flatnonzero(drop.ravel())]
    out = ImuIntrinsics(np.eye(3) + values["gyro_scale_misalignment"], np.eye(3) + values["acc_scale_misalignment"],
                        values["gyro_g_sensitivity"])
    return out, keep, dropped


@dataclass(frozen=True)
class AutoDecision:
    """What ``intrinsics: auto`` decided from the plain solve (:func:`auto_intrinsics`).

    Attributes:
        mode: ``WITH_G_SENSITIVITY`` or ``OFF``.
        reason: One plain sentence (``recovery.json`` ``intrinsics_auto``).
        coupling: The coupling kind found, or None when there was nothing to check.
    """

    mode: IntrinsicsMode
    reason: str
    coupling: str | None = None

    def annotate(self, result):
        """``result`` with ``report["intrinsics_auto"]`` saying what was decided and why."""
        data = dict(result.report.data)
        data["intrinsics_auto"] = {"estimated": self.mode is not IntrinsicsMode.OFF, "coupling": self.coupling,
                                   "reason": self.reason}
        return replace(result, report=RecoveryReport.from_json(data))


def auto_intrinsics(sequence: Sequence, result, block_s: float = 10.0) -> AutoDecision:
    """Estimate the intrinsics only where the gyro shows them (:class:`IntrinsicsMode` ``AUTO``).

    On the plain solve's clock offset and extrinsic, the gyro against a 6-DoF absolute pose stream
    (:func:`recovery.intrinsics.gyro_consistency.rate_coupling`): a coupling of one axis to another axis's
    rate in every excited band is a misalignment (or, with it, a scale error) and starts the loop;
    one below 0.2 Hz only (which no intrinsic term can absorb) does not. Where the coupling finds none,
    one least-squares fit on the plain solve (:func:`gyro_fit_significance`, far more sensitive) starts it
    when the gyro's scale and misalignment terms are jointly significant: without the loop the bias takes
    up their effects (and a g-sensitivity's, times gravity) with no term in its sigma. Position-only
    and relative (VIO) streams do not pin the orientation down: nothing to check.
    """
    rep = result.report
    stream = sequence.poses.get(str(rep.pose_stream)) if rep.pose_stream else None
    if stream is None or stream.quat_wxyz is None or rep.get("pose_factor_mode") != PoseFactorMode.ABSOLUTE.value:
        return AutoDecision(IntrinsicsMode.OFF, "not checked: the fitted pose stream is not a 6-DoF absolute one")
    try:
        coupling = rate_coupling(sequence.imu, stream, R_imu_pose=rep.T_imu_pose[:3, :3], offset_s=rep.time_offset_s)
    except BiasgtError as exc:
        return AutoDecision(IntrinsicsMode.OFF, f"not checked: {exc}")
    kind = coupling.kind()
    if kind is CouplingKind.NONE:
        test = gyro_fit_significance(sequence, result, block_s)
        if test is not None and test["p_value"] < FIT_TEST_P_VALUE:
            reason = (f"{coupling.sentence()}; but the least-squares fit on the plain solve finds the gyro's scale and "
                      f"misalignment terms jointly significant (chi-square {test['chi_square']:.1f} over "
                      f"{test['terms']} terms, p = {test['p_value']:.1e}): an intrinsic error below the coupling's reach")
            return AutoDecision(IntrinsicsMode.WITH_G_SENSITIVITY, reason, kind.value)
    mode = IntrinsicsMode.WITH_G_SENSITIVITY if kind is CouplingKind.INTRINSIC else IntrinsicsMode.OFF
    return AutoDecision(mode, coupling.sentence(), kind.value)


#: The fit test of :func:`auto_intrinsics` starts the loop below this p-value (a calibrated gyro: 1 in 1000).
FIT_TEST_P_VALUE = 1e-3


def gyro_fit_significance(sequence: Sequence, result, block_s: float = 10.0) -> dict | None:
    """Whether the gyro's scale and misalignment terms (``S_g``, 9) differ from zero, from one fit on ``result``.

    The fit of :func:`fit_intrinsics` (with ``G``, so a g-sensitivity does not pass for a scale error) against
    the plain solve's trajectory: a chi-square of its ``S_g`` estimate over their covariance (the observable
    terms). It sees far smaller terms than the rate coupling (every keyframe interval, not the rate's coherence
    per band): on 60-s handheld recordings a 0.1 % scale error is several sigmas, against a coupling gain of
    0.2 % needed to count. ``G`` is left out of the test: its gravity column times ``f ~ g`` is hard to tell from a
    slow bias, so its sigma rests on the bias model.

    Returns:
        ``{"chi_square", "terms", "p_value"}``, or None when no term is observable.
    """
    from scipy.special import gammaincc  # the chi-square survival function without scipy.stats (~0.5 s to load)

    try:
        fit = _fit_round(sequence, sequence, result, ImuIntrinsics.identity(), True, block_s, None, False)
    except (ValueError, RuntimeError, np.linalg.LinAlgError):  # too few intervals, a singular system
        return None
    if fit.estimate is None or fit.cov is None:
        return None
    seen = np.flatnonzero(fit.observable["gyro_scale_misalignment"].ravel())
    if not len(seen):
        return None
    x = fit.estimate["gyro_scale_misalignment"].ravel()[seen]
    C = fit.cov["rotation"][np.ix_(seen, seen)]
    stat = float(x @ np.linalg.lstsq(C, x, rcond=None)[0])
    return {"chi_square": stat, "terms": int(len(seen)), "p_value": float(gammaincc(0.5 * len(seen), 0.5 * stat))}


def _solve_corrected(sequence: Sequence, solve: Callable[[Sequence], object], result, total: ImuIntrinsics,
                     new: ImuIntrinsics) -> tuple[Sequence, object, ImuIntrinsics]:
    """Solve again on the raw readings corrected by ``new`` (``result``: the last solve, on readings
    corrected by ``total``, gives the acc bias that ``G`` needs to tell the force from the readings).

    Returns:
        The corrected sequence, its solve and ``new``.
    """
    raw_acc_bias = result.bias_at(sequence.imu.t_ns)[:, 3:] @ total.acc_matrix.T
    work = replace(sequence, imu=new.correct(sequence.imu, raw_acc_bias))
    return work, solve(work), new


def _fit_round(sequence: Sequence, work: Sequence, result, total: ImuIntrinsics, g_sensitivity: bool, block_s: float,
               present: dict[str, np.ndarray] | None, from_file: bool, prior: IntrinsicsPrior = IntrinsicsPrior()
               ) -> IntrinsicsFit:
    """One fit of the loop on ``work`` (``sequence`` corrected by ``total``) against the solve ``result``; with
    ``from_file``, the accelerometer's rotation is the calibration file's (:func:`rotation_prior` under ``prior``)."""
    gravity = np.asarray(result.report.get("gravity_world_mps2", DEFAULT_GRAVITY_MPS2), dtype=float)
    acc_prior = rotation_prior(result.report.data, total.acc_matrix - np.eye(3), prior) if from_file else None
    return fit_intrinsics(work.imu, result.t_ns, result.quat_wxyz, result.v_mps, result.bias_at, gravity,
                          _fit_noise(sequence, result.report), g_sensitivity=g_sensitivity, block_s=block_s,
                          present=present, acc_prior=acc_prior)


def recover_with_intrinsics(sequence: Sequence, solve: Callable[[Sequence], object], *, g_sensitivity: bool,
                            block_s: float, max_rounds: int = 5, first=None,
                            prior: IntrinsicsPrior = IntrinsicsPrior()):
    """The alternating loop of the module docstring around ``solve`` (a full recovery).

    The solve's extrinsic is never held at a calibration file's: it follows the gyro (whose own rotation
    against the accelerometer it takes), and on agreement the fits turn the accelerometer into it
    (:func:`recovery.intrinsics.frame.rotation_prior`). Held instead, the gyro's rotation would have to be
    fitted beside the g-sensitivity, which a tilting drone's motion confuses with it.

    Args:
        first: ``solve(sequence)`` when the caller has it already.
        prior: The terms' sizes before the data (the prior of those the fit cannot tell from the bias).

    Returns:
        The last solve's :class:`recovery.recover.RecoveryResult`, its bias mapped back to the raw
        readings and ``report["intrinsics"]`` filled in.
    """
    assert sequence.imu is not None
    total = ImuIntrinsics.identity()  # the intrinsics removed from the readings ``result`` was solved on
    result = solve(sequence) if first is None else first
    stream = sequence.poses.get(str(result.report.get("pose_stream")))
    if stream is not None and stream.quat_wxyz is None:
        return _not_estimated(result, str(result.report.get("pose_stream")))
    agreement = None
    work = sequence
    fit = None
    rounds = 0
    present: dict[str, np.ndarray] | None = None
    from_file = False  # the accelerometer's rotation is the calibration file's: a prior in every fit
    for rounds in range(1, max_rounds + 1):
        fit = _fit_round(sequence, work, result, total, g_sensitivity, block_s, present, from_file, prior)
        if rounds == 1 and fit.estimate is not None and fit.cov is not None:
            # the raw readings' accelerometer rotation against the first solve's difference from the file
            agreement = calibration_agreement(fit.estimate["acc_scale_misalignment"], fit.cov["velocity"],
                                              result.report.data)
            if agreement is not None and agreement["agrees"]:
                from_file = True
                log.info("intrinsics: the accelerometer agrees with the calibration's extrinsic rotation; "
                         "its rotation is taken from the file")
                fit = _fit_round(sequence, work, result, total, g_sensitivity, block_s, present, from_file, prior)
        log.info("intrinsics round %d: gyro scale %s, acc scale %s", rounds,
                 np.round(np.diag(fit.step.gyro_matrix) - 1, 5), np.round(np.diag(fit.step.acc_matrix) - 1, 5))
        if rounds > 1 and not fit.moved(REFINE_SIGMAS):
            break
        present = {k: v | (present[k] if present else False) for k, v in fit.applied.items()}
        work, result, total = _solve_corrected(sequence, solve, result, total, total.compose(fit.step))
    assert fit is not None
    dropped: list[str] = []
    # what the final readings still carry of each term: the last fit's estimate, and a dropped term's value
    left = {k: np.nan_to_num(v) for k, v in (fit.estimate or {}).items()}
    if present:
        trimmed, present, dropped = drop_insignificant(total, fit, present)
        if dropped:
            log.info("intrinsics: %s no longer significant, dropped; solving once more", ", ".join(dropped))
            before, after = total.deviations(), trimmed.deviations()
            left = {k: v + before[k] - after[k] for k, v in left.items()}
            work, result, total = _solve_corrected(sequence, solve, result, total, trimmed)
    bias, std = raw_bias(total, np.hstack([result.bias_gyro_radps, result.bias_acc_mps2]),
                         np.hstack([result.bias_gyro_std_radps, result.bias_acc_std_mps2]))
    # the terms' uncertainty in the bias sigmas, at the keyframes' bias-free rate and force; what the bias
    # absorbed of the terms left out (their posterior means times the signals, block-averaged as the bias
    # follows them) taken out of it
    imu = work.imu
    def at(y: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(result.t_ns, imu.t_ns, y[:, c]) for c in range(3)], axis=1)
    omega, force = at(imu.gyro_radps) - result.bias_gyro_radps, at(imu.acc_mps2) - result.bias_acc_mps2
    sigmas = prior.term_sigmas((result.report.get("extrinsic") or {}).get("mode") == "known")
    block = ((result.t_ns - result.t_ns[0]) / NS_PER_S // block_s).astype(int)
    shift = left_out_shift(fit, present or {}, _block_means(omega, block), _block_means(force, block), left, sigmas)
    bias = bias - shift
    # the intrinsics reported with those means in: readings corrected by them match the bias without them
    means, dev = left_out_means(fit, present or {}, left, sigmas), total.deviations()
    reported = ImuIntrinsics(np.eye(3) + dev["gyro_scale_misalignment"] + means["gyro_scale_misalignment"],
                             np.eye(3) + dev["acc_scale_misalignment"] + means["acc_scale_misalignment"],
                             dev["gyro_g_sensitivity"] + means.get("gyro_g_sensitivity", np.zeros((3, 3))))
    added = intrinsics_bias_variance(fit, present or {}, omega, force, left=left, prior=sigmas, corrected=True)
    inflation = np.sqrt(1.0 + added / np.maximum(std**2, 1e-300))
    std = np.sqrt(std**2 + added)
    data = dict(result.report.data)
    table = term_table(total.deviations(), fit.sigma, fit.observable, present or {}, left, dropped, fit.estimated)
    data["intrinsics"] = {**intrinsics_report(reported, fit, rounds), "bias_std_inflation_mean": inflation.mean(0).tolist(),
                          "bias_std_added_mean": np.sqrt(added).mean(0).tolist(),
                          "bias_shift_left_out_mean": shift.mean(0).tolist(), "dropped_at_end": dropped, **table,
                          "left_out_posterior_means": {k: v.tolist() for k, v in means.items()},
                          "matrices_note": "gyro_matrix, acc_matrix and gyro_g_sensitivity include the posterior means "
                                           "of the terms left out, which were taken out of the bias"}
    if agreement is not None:
        data["intrinsics"]["extrinsic_rotation"] = {
            **agreement, "accelerometer_rotation_from_calibration": from_file,
            "why": "the gyro's rotation against the accelerometer is an intrinsic term; the accelerometer alone "
                   "tells the extrinsic rotation: agreement with the calibration file's (first solve, raw readings) "
                   "means the solve's turn from it is the gyro's own rotation, and the file's rotation (within "
                   f"{prior.calibration_rotation_rad:g} rad) then turns the accelerometer into the solve's frame"}
    warning = unobservable_warning(fit)
    if warning:
        data["warnings"] = [*data.get("warnings", []), warning]
    report = RecoveryReport.from_json(data)
    return replace(result, bias_gyro_radps=bias[:, :3], bias_acc_mps2=bias[:, 3:], bias_gyro_std_radps=std[:, :3],
                   bias_acc_std_mps2=std[:, 3:], report=report)


def _not_estimated(result, stream: str):
    """``result`` with ``report["intrinsics"]`` saying why nothing was estimated: a position-only stream.

    From positions alone the solved trajectory's orientation is the gyro's own integration and its
    acceleration is smoothed by the IMU itself, so the premise of the loop (a trajectory pinned down by the
    poses, whatever the readings) fails: the fit would find significant scale errors that a 6-DoF
    reference of the same motion does not show, and move the bias away from it.
    """
    reason = (f"pose stream '{stream}' has positions only: the trajectory's orientation and acceleration come from "
              "the IMU itself, so its intrinsics cannot be fitted against it")
    data = dict(result.report.data)
    identity = ImuIntrinsics.identity()
    data["intrinsics"] = {"method": "not estimated", "reason": reason, "rounds": 0,
                          "gyro_matrix": identity.gyro_matrix.tolist(), "acc_matrix": identity.acc_matrix.tolist(),
                          "gyro_g_sensitivity": identity.gyro_g_sensitivity.tolist(),
                          "bias_std_inflation_mean": [1.0] * 6}
    data["warnings"] = [*data.get("warnings", []), f"IMU intrinsics not estimated: {reason}; give a 6-DoF pose stream"]
    log.warning("IMU intrinsics not estimated: %s", reason)
    return replace(result, report=RecoveryReport.from_json(data))
