"""Fuse high-rate pose samples into sparser keyframes through the IMU (every sample counts).

A 100-Hz mocap stream holds far more samples than the bias needs keyframes: the bias
moves on a time scale of seconds, while each GTSAM keyframe costs ~0.1 ms per
optimiser iteration. Dropping the samples between keyframes throws their
information away; this module keeps it. The samples of one keyframe bin
(``1 / keyframe_rate_hz`` long) are moved to the keyframe time ``t_k`` with the
IMU's own relative motion (bias-corrected, preintegrated from ``t_k``), then
fused:

    R_imu,j = R_k dR_kj                                   (dR_kj: gyro, t_k -> t_j)
    p_pose,j = p_pose,k + v_k dt_j + 1/2 g dt_j^2 + R_k dp_kj + R_k (dR_kj - I) t_E

(``dp_kj``: double integral of the rotated specific force, ``t_E`` the lever arm of
``T_imu_pose``). Per bin this is a linear model in ``(R_k, p_pose,k, v_k)``; with
``t_k`` the mean sample time the position and velocity estimates decouple, so the
fused keyframe is a pose measurement with covariance ``Sigma / n`` plus a velocity
measurement with std ``sigma_p / sqrt(sum dt_j^2)`` -- sufficient statistics of the
bin's samples. The residuals orthogonal to that model depend on the pose noise
only; their sums of squares (:class:`WithinBinStats`) complete the evidence of a
pose-noise hypothesis (:mod:`recovery.noise.evidence`).

The approximation: the IMU relative motion over half a bin is taken as exact (its
noise, ~4e-5 m over 25 ms for EuRoC's accelerometer, is an order below mocap
noise, and it is linearised at the current bias estimate). Samples that disagree
with their bin by more than ``outlier_sigmas`` times a robust per-axis scale are
rejected before fusing (a 10-cm mocap glitch must not move the keyframe).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.types import NS_PER_S
from recovery.solver.rotations import matrix_to_quat_wxyz, matrix_to_rotvec

INTEGRATION_STEP_S = 0.005  # sub-step of the relative-motion integration (IMU linearly interpolated)
# Floors of the robust residual scales used to reject samples: smoothed ground-truth poses have
# almost no within-bin scatter (hundredths of a millimetre), so their small model errors (spline knots,
# the IMU's own scale errors over a bin) would otherwise count as outliers. With these floors a
# sample within 5e-4 m / 5e-4 rad of its bin's fit is never rejected; a mocap glitch is centimetres.
MIN_SCALE_M = 1e-4
MIN_SCALE_RAD = 1e-4
# A sample is a glitch beyond this many robust sigmas (per-axis scales, norm over the axes): a
# Gaussian sample never gets there (chi(3) tail ~1e-13), while mocap's sample noise is heavier
# tailed than Gaussian (EuRoC Vicon: 1-4 % of samples beyond 5) and those samples are not glitches.
OUTLIER_SIGMAS = 8.0


@dataclass(frozen=True)
class WithinBinStats:
    """Residuals of the samples about their fused keyframe (orthogonal to the bin model).

    Attributes:
        pos_sq_m2: Sum of squared position residuals. pos_dof: Their degrees of freedom (3 (n - 2) per bin).
        rot_sq_rad2: Sum of squared rotation residuals. rot_dof: Their degrees of freedom (3 (n - 2) per
            bin: a mean and a rate are fitted, the rate absorbing a gyro-bias linearisation error).
    """

    pos_sq_m2: float
    pos_dof: int
    rot_sq_rad2: float
    rot_dof: int

    def log_likelihood(self, position_sigma_m: float, rotation_sigma_rad: float) -> float:
        """log N(residuals; 0, sigma^2 I) without the 2 pi constant (same for every hypothesis)."""
        out = 0.0
        if self.pos_dof > 0:
            out += -0.5 * self.pos_sq_m2 / position_sigma_m**2 - self.pos_dof * math.log(position_sigma_m)
        if self.rot_dof > 0:
            out += -0.5 * self.rot_sq_rad2 / rotation_sigma_rad**2 - self.rot_dof * math.log(rotation_sigma_rad)
        return out



@dataclass(frozen=True)
class PerBin:
    """Per-keyframe within-bin residual sums and their degrees of freedom, [K] each."""

    pos_sq: np.ndarray
    pos_dof: np.ndarray
    rot_sq: np.ndarray
    rot_dof: np.ndarray

    def total(self) -> WithinBinStats:
        """The sums over all keyframes."""
        return WithinBinStats(float(self.pos_sq.sum()), int(self.pos_dof.sum()),
                              float(self.rot_sq.sum()), int(self.rot_dof.sum()))


@dataclass(frozen=True)
class FusedPoses:
    """Keyframe measurements fused from every pose sample of their bin.

    Attributes:
        t_ns: Keyframe stamps (mean of the bin's sample stamps, IMU clock), int64 [K].
        p_m: Fused position of the tracked frame at ``t_ns``, [K, 3].
        quat_wxyz: Fused orientation of the tracked frame, [K, 4].
        v_mps: Fused IMU velocity in the world frame, [K, 3] (meaningless where ``dt2_s2 == 0``).
        count: Samples fused per keyframe, int [K] (pose covariance is ``Sigma / count``).
        dt2_s2: ``sum dt_j^2`` per keyframe, [K] (velocity std = ``sigma_p / sqrt(dt2_s2)``).
        per_bin: Within-bin residual sums per keyframe.
        rejected_t_ns: Stamps (IMU clock) of the samples rejected as outliers, int64 [R].
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    count: np.ndarray
    dt2_s2: np.ndarray
    per_bin: PerBin
    rejected_t_ns: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)


class _ImuInterp:
    """Linear interpolation of all six IMU channels at once (one search per query)."""

    def __init__(self, imu_t_ns: np.ndarray, imu_6: np.ndarray) -> None:
        self.ref = int(imu_t_ns[0])
        self.x = (imu_t_ns - self.ref).astype(np.float64)
        self.y = np.asarray(imu_6, dtype=float)

    def __call__(self, t_rel_ns: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(self.x, t_rel_ns, side="right") - 1, 0, len(self.x) - 2)
        w = np.clip((t_rel_ns - self.x[i]) / (self.x[i + 1] - self.x[i]), 0.0, 1.0)[:, None]
        return self.y[i] * (1.0 - w) + self.y[i + 1] * w


def _step(interp: _ImuInterp, R: np.ndarray, v: np.ndarray, p: np.ndarray, t_rel_ns: np.ndarray, h: np.ndarray,
          bias: np.ndarray) -> None:
    """One midpoint step of signed length ``h`` [n] s from ``t_rel_ns`` [n], in place on R [n,3,3], v, p [n,3]."""
    m = interp(t_rel_ns + 0.5 * h * NS_PER_S) - bias
    w, f = m[:, :3], m[:, 3:]
    f_mid = f + np.cross(0.5 * h[:, None] * w, f)  # the force at the midpoint, in the step's start frame
    a = np.matmul(R, f_mid[:, :, None])[:, :, 0]
    p += v * h[:, None] + 0.5 * a * (h**2)[:, None]
    v += a * h[:, None]
    R[:] = np.matmul(R, Rotation.from_rotvec(w * h[:, None]).as_matrix())


def relative_motion(
    imu_t_ns: np.ndarray,
    imu_6: np.ndarray,
    t_from_ns: np.ndarray,
    t_to_ns: np.ndarray,
    bias: np.ndarray,
    step_s: float = INTEGRATION_STEP_S,
) -> tuple[np.ndarray, np.ndarray]:
    """IMU relative motion from ``t_from`` to ``t_to`` (either order), vectorised over pairs.

    Midpoint integration of the bias-corrected, linearly interpolated IMU. Pairs that
    share a start are integrated together: from each distinct start, forward and
    backward in ``step_s`` steps to the farthest end (vectorised over starts), then one
    partial step per pair from the node before its end.

    Args:
        imu_t_ns: IMU stamps, int64 [N]. imu_6: gyro then acc, [N, 6].
        t_from_ns / t_to_ns: int64 [M].
        bias: [6] gyro then acc, or per pair [M, 6] (pairs sharing a start use their mean).
        step_s: Longest integration step.

    Returns:
        ``dR`` [M, 3, 3] (``R_from^T R_to``) and ``dp`` [M, 3]: the double integral of the
        specific force rotated into the ``from`` frame (no gravity, zero initial velocity).
    """
    t_from_ns = np.asarray(t_from_ns, dtype=np.int64)
    t_to_ns = np.asarray(t_to_ns, dtype=np.int64)
    M = len(t_from_ns)
    interp = _ImuInterp(imu_t_ns, imu_6)
    starts, group = np.unique(t_from_ns, return_inverse=True)
    G = len(starts)
    b = np.broadcast_to(np.asarray(bias, dtype=float), (M, 6))
    cnt = np.bincount(group, minlength=G).astype(float)
    b_g = np.stack([np.bincount(group, weights=b[:, c], minlength=G) for c in range(6)], 1) / cnt[:, None]
    dt_s = (t_to_ns - t_from_ns) / NS_PER_S
    t0 = (starts - interp.ref).astype(np.float64)
    dR = np.empty((M, 3, 3))
    dp = np.empty((M, 3))
    for sign in (1.0, -1.0):
        mine = (dt_s >= 0) if sign > 0 else (dt_s < 0)
        if not mine.any():
            continue
        span = np.abs(dt_s[mine])
        n_nodes = int(math.floor(span.max() / step_s)) + 1
        # nodes i * step_s from every start: R, v, p after i full steps, [n_nodes, G, ...]
        R = np.broadcast_to(np.eye(3), (G, 3, 3)).copy()
        v = np.zeros((G, 3))
        p = np.zeros((G, 3))
        nodes_R, nodes_v, nodes_p = [R.copy()], [v.copy()], [p.copy()]
        h = np.full(G, sign * step_s)
        for i in range(1, n_nodes):
            _step(interp, R, v, p, t0 + sign * (i - 1) * step_s * NS_PER_S, h, b_g)
            nodes_R.append(R.copy())
            nodes_v.append(v.copy())
            nodes_p.append(p.copy())
        idx = np.nonzero(mine)[0]
        g = group[idx]
        node = np.minimum(np.floor(span / step_s).astype(np.int64), n_nodes - 1)
        Rn = np.stack(nodes_R)[node, g]
        vn = np.stack(nodes_v)[node, g]
        pn = np.stack(nodes_p)[node, g]
        rest = sign * (span - node * step_s)
        _step(interp, Rn, vn, pn, t0[g] + sign * node * step_s * NS_PER_S, rest, b_g[g])
        dR[idx] = Rn
        dp[idx] = pn
    return dR, dp


def _bin_mean(values: np.ndarray, bins: np.ndarray, n_bins: int, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of ``values`` [M, D] per bin, [n_bins, D] (NaN for empty bins)."""
    w = weights.astype(float)
    tot = np.bincount(bins, weights=w, minlength=n_bins)
    out = np.stack([np.bincount(bins, weights=values[:, d] * w, minlength=n_bins) for d in range(values.shape[1])], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return out / tot[:, None]


def _bin_slope(values: np.ndarray, dt_s: np.ndarray, bins: np.ndarray, n_bins: int, keep: np.ndarray,
               dt2: np.ndarray) -> np.ndarray:
    """Least-squares slope of ``values`` [M, D] over ``dt_s`` per bin (``sum dt = 0``), [n_bins, D]; 0 if undetermined."""
    num = np.stack([np.bincount(bins, weights=np.where(keep, dt_s * values[:, d], 0.0), minlength=n_bins)
                    for d in range(values.shape[1])], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(dt2[:, None] > 0, num / dt2[:, None], 0.0)


def _standardised_norm(res: np.ndarray, sample: np.ndarray, floor: float) -> np.ndarray:
    """Norm of each residual [M, 3] over its axis's robust scale (1.4826 MAD of ``sample``'s rows, at least ``floor``)."""
    scale = np.maximum(1.4826 * np.median(np.abs(res[sample]), axis=0), floor)
    return np.linalg.norm(res / scale, axis=1)


class _BinFit:
    """Per-bin fits of the samples moved to their keyframe stamps (the module docstring's model).

    Holds what every refit needs, prepared once, and the last fit's IMU relative motions, so a
    refit integrates again only the bins whose keyframe stamp moved (a rejected sample moves its
    own bin's only).
    """

    def __init__(self, t_ns: np.ndarray, p_m: np.ndarray, quat_wxyz: np.ndarray, imu_t_ns: np.ndarray,
                 imu_6: np.ndarray, rate_hz: float, origin_ns: int, T_imu_pose: np.ndarray,
                 gravity_world_mps2: np.ndarray, bias: np.ndarray):
        self.t_ns, self.p_m, self.imu_t_ns, self.imu_6, self.bias = t_ns, p_m, imu_t_ns, imu_6, bias
        self.origin_ns = origin_ns
        period = NS_PER_S / rate_hz
        raw_bins = np.floor((t_ns - origin_ns) / period).astype(np.int64)
        _, self.bins = np.unique(raw_bins, return_inverse=True)
        self.K = int(self.bins.max()) + 1 if len(t_ns) else 0
        self.R_E = np.asarray(T_imu_pose, dtype=float)[:3, :3]
        self.lever = np.asarray(T_imu_pose, dtype=float)[:3, 3]
        self.g = np.asarray(gravity_world_mps2, dtype=float)
        R_pose = Rotation.from_quat(quat_wxyz, scalar_first=True).as_matrix()
        self.R_imu_j = R_pose @ self.R_E.T  # [M, 3, 3]
        self.moved: dict[str, np.ndarray] = {}  # the last fit's keyframe stamps and relative motions

    def relative(self, t_k_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """dR [M, 3, 3], dp [M, 3] from each sample's keyframe stamp."""
        bins, moved = self.bins, self.moved
        if not moved:
            dR, dp = relative_motion(self.imu_t_ns, self.imu_6, t_k_ns[bins], self.t_ns, self.bias)
        else:
            dR, dp = moved["dR"].copy(), moved["dp"].copy()
            redo = np.nonzero(t_k_ns[bins] != moved["t_k_ns"][bins])[0]
            if len(redo):
                b = self.bias if self.bias.ndim == 1 else self.bias[redo]
                dR[redo], dp[redo] = relative_motion(self.imu_t_ns, self.imu_6, t_k_ns[bins[redo]], self.t_ns[redo], b)
        moved.update(t_k_ns=t_k_ns, dR=dR, dp=dp)
        return dR, dp

    def fit(self, keep: np.ndarray) -> dict[str, np.ndarray]:
        """Keyframe stamps, rotations, positions and rates from the kept samples, with residuals."""
        bins, K, t_ns = self.bins, self.K, self.t_ns
        cnt = np.bincount(bins, weights=keep.astype(float), minlength=K)
        t_k = _bin_mean(t_ns[:, None].astype(np.float64) - float(self.origin_ns), bins, K, keep)[:, 0]
        t_k_ns = np.round(np.nan_to_num(t_k)).astype(np.int64) + self.origin_ns
        dt_j = (t_ns - t_k_ns[bins]) / NS_PER_S
        dR, dp = self.relative(t_k_ns)
        # rotation: each sample's estimate of R_k, averaged in the tangent space of a reference
        R_k_j = self.R_imu_j @ np.transpose(dR, (0, 2, 1))
        first = np.zeros(K, dtype=np.int64)
        idx = np.nonzero(keep)[0]
        first[bins[idx[::-1]]] = idx[::-1]  # the first kept sample of each bin
        ref = R_k_j[first]
        delta = matrix_to_rotvec(np.transpose(ref[bins], (0, 2, 1)) @ R_k_j)
        mean_delta = _bin_mean(delta, bins, K, keep)
        R_k = ref @ Rotation.from_rotvec(np.nan_to_num(mean_delta)).as_matrix()
        dt2 = np.bincount(bins, weights=np.where(keep, dt_j**2, 0.0), minlength=K)
        dt2[cnt < 2] = 0.0  # one sample: no rate (its dt is only the rounding of t_k to 1 ns)
        # a rate term absorbs a gyro-bias error of the linearisation (delta drifts by db * dt); it is
        # orthogonal to the mean because sum dt = 0, so the fused rotation loses nothing
        rate = _bin_slope(delta, dt_j, bins, K, keep, dt2)
        rot_res = delta - mean_delta[bins] - rate[bins] * dt_j[:, None]
        # position of the tracked frame moved to t_k; a line in dt per bin (sum dt = 0 by construction)
        Rk_j = R_k[bins]
        lever = self.lever
        y = (self.p_m - 0.5 * self.g * (dt_j**2)[:, None] - np.einsum("mij,mj->mi", Rk_j, dp)
             - np.einsum("mij,mj->mi", Rk_j, np.einsum("mij,j->mi", dR, lever) - lever))
        p_k = _bin_mean(y, bins, K, keep)
        v_k = _bin_slope(y, dt_j, bins, K, keep, dt2)
        pos_res = y - p_k[bins] - v_k[bins] * dt_j[:, None]
        # standardised residuals (leverage of a line fit)
        with np.errstate(invalid="ignore", divide="ignore"):
            lev = 1.0 / cnt[bins] + np.where(dt2[bins] > 0, dt_j**2 / dt2[bins], 0.0)
            scale = np.sqrt(np.maximum(1.0 - lev, 1e-3))
        return dict(cnt=cnt, t_k_ns=t_k_ns, R_k=R_k, p_k=p_k, v_k=v_k, dt2=dt2, pos_res=pos_res / scale[:, None],
                    rot_res=rot_res / scale[:, None], pos_raw=pos_res, rot_raw=rot_res)


def _fit_rejecting(bf: _BinFit, keep: np.ndarray, outlier_sigmas: float) -> dict[str, np.ndarray]:
    """Fit, then drop the worst sample of each bin beyond ``outlier_sigmas`` and refit (up to 8 times).

    Updates ``keep`` in place. One glitch biases its whole bin's fit, hence one sample per bin at a
    time; the robust scales are per axis (mocap noise is anisotropic), from bins with spare degrees
    of freedom.
    """
    bins = bf.bins
    f = bf.fit(keep)
    for _ in range(8):
        spare = keep & (f["cnt"][bins] >= 3)
        if spare.sum() < 10:
            break
        z = np.where(spare, np.maximum(_standardised_norm(f["pos_res"], spare, MIN_SCALE_M),
                                       _standardised_norm(f["rot_res"], spare, MIN_SCALE_RAD)), 0.0)
        zmax = np.zeros(bf.K)
        np.maximum.at(zmax, bins, z)
        cand = np.nonzero((z > outlier_sigmas) & (z == zmax[bins]))[0]
        if len(cand) == 0:
            break
        keep[cand] = False
        f = bf.fit(keep)
    return f


def fuse_poses(
    t_ns: np.ndarray,
    p_m: np.ndarray,
    quat_wxyz: np.ndarray,
    imu_t_ns: np.ndarray,
    imu_6: np.ndarray,
    rate_hz: float,
    origin_ns: int,
    T_imu_pose: np.ndarray,
    gravity_world_mps2: np.ndarray,
    bias: np.ndarray | None = None,
    outlier_sigmas: float = OUTLIER_SIGMAS,
) -> FusedPoses:
    """Fuse 6-DoF pose samples into keyframes on a ``rate_hz`` grid (see the module docstring).

    Args:
        t_ns: Sample stamps on the IMU clock, int64 [M], increasing, inside the IMU span.
        p_m / quat_wxyz: Tracked-frame poses in the world frame, [M, 3] / [M, 4].
        imu_t_ns / imu_6: The IMU, [N] / [N, 6] (gyro then acc), covering the samples.
        rate_hz: Keyframe rate; bins are ``[origin + i / rate, origin + (i + 1) / rate)``.
        origin_ns: Grid origin (the same for every window, so keyframes line up across segments).
        T_imu_pose: 4x4 pose of the tracked frame in the IMU frame.
        gravity_world_mps2: Gravity in the world frame, [3].
        bias: Linearisation bias, [6] or per sample [M, 6] (gyro, acc); zeros if None.
        outlier_sigmas: Samples further than this many robust sigmas from their bin fit are rejected
            (robust per-axis scales; the larger of the position and rotation norms).

    Returns:
        The fused keyframes.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    bias = np.zeros(6) if bias is None else np.asarray(bias, dtype=float)
    bf = _BinFit(t_ns, p_m, quat_wxyz, imu_t_ns, imu_6, rate_hz, origin_ns, T_imu_pose, gravity_world_mps2, bias)
    bins, K = bf.bins, bf.K
    keep = np.ones(len(t_ns), dtype=bool)
    f = _fit_rejecting(bf, keep, outlier_sigmas)
    cnt, t_k_ns, R_k, p_k, v_k, dt2 = f["cnt"], f["t_k_ns"], f["R_k"], f["p_k"], f["v_k"], f["dt2"]
    pos_res, rot_res = f["pos_raw"], f["rot_raw"]

    has = cnt > 0
    n = cnt.astype(int)
    pos_sq = np.bincount(bins, weights=np.where(keep, np.sum(pos_res**2, axis=1), 0.0), minlength=K)
    rot_sq = np.bincount(bins, weights=np.where(keep, np.sum(rot_res**2, axis=1), 0.0), minlength=K)
    dof = 3 * np.maximum(n[has] - 2, 0)  # a line per axis: position + velocity, rotation + rate
    per_bin = PerBin(pos_sq[has], dof, rot_sq[has], dof)
    R_pose_k = R_k[has] @ bf.R_E
    return FusedPoses(
        t_ns=t_k_ns[has],
        p_m=p_k[has],
        quat_wxyz=matrix_to_quat_wxyz(R_pose_k),
        v_mps=v_k[has],
        count=n[has],
        dt2_s2=dt2[has],
        per_bin=per_bin,
        rejected_t_ns=t_ns[~keep],
    )
