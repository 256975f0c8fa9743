"""Windows and metrics: the window plan, per-window end errors by strapdown integration, PRMSE and ROE
(shared by validation and the evaluation of learned models).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pipeline.errors import ValidationError
from pipeline.geometry.integration import integrate
from pipeline.geometry.so3_numpy import rotation_angle_deg
from pipeline.types import (NS_PER_S, ImuSeries, IntegrationScheme)
from validation.config import ValidationConfig
from validation.reference import ReferenceStates, check_increasing
from validation.sources import BiasSourceKind

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- windows


@dataclass(frozen=True)
class WindowPlan:
    """Candidate windows and why some are dropped.

    Attributes:
        starts: First IMU sample index of every candidate window, [W].
        n: Intervals per window (the window holds samples ``i .. i + n``).
        rate_hz: Nominal IMU rate used for ``n``.
        keep: Windows used, [W].
        dropped: Count per reason (a window counts under every reason that applies).
    """

    starts: np.ndarray
    n: int
    rate_hz: float
    keep: np.ndarray
    dropped: dict[str, int]


def windows_with_any(flags: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """Which windows ``flags[s : s + length]`` hold at least one True (by a cumulative sum).

    For windows of ``n`` IMU intervals use ``length = n`` on per-interval flags [N - 1] and
    ``length = n + 1`` on per-sample flags [N].

    Args:
        flags: Boolean per-row flags, [N].
        starts: First row of each window, int [W]; ``starts + length <= N``.
        length: Rows per window.

    Returns:
        Boolean mask [W].
    """
    c = np.concatenate([[0], np.cumsum(flags.astype(np.int64))])
    return (c[starts + length] - c[starts]) > 0


def plan_windows(imu: ImuSeries, config: ValidationConfig) -> WindowPlan:
    """Cut the IMU into windows and drop those crossing gaps or non-finite samples.

    Raises:
        ValidationError: Unordered stamps, or a sequence shorter than one window.
    """
    t = imu.t_ns
    if len(t) < 2:
        raise ValidationError(f"the IMU has {len(t)} samples: shorter than one {config.window_s:g}-s window",
                              hint="give a longer recording or a shorter --window-s")
    check_increasing(t, "IMU")
    dt = np.diff(t)
    nominal = float(np.median(dt))
    rate = NS_PER_S / nominal
    n = int(round(config.window_s * rate))
    if n < 1:
        raise ValidationError(f"window_s = {config.window_s:g} s is shorter than one IMU interval",
                              field="window_s", hint="give a longer --window-s")
    if len(t) - 1 < n:
        raise ValidationError(
            f"the sequence is shorter than one window ({imu.duration_s:.3f} s < {config.window_s:g} s)",
            hint="give a longer recording or a shorter --window-s",
        )
    stride = max(1, int(round(n * (1.0 - config.overlap))))
    starts = np.arange(0, len(t) - n, stride, dtype=np.int64)
    gap = windows_with_any(dt > config.gap_factor * nominal, starts, n)
    nonfinite_rows = ~(np.isfinite(imu.gyro_radps).all(1) & np.isfinite(imu.acc_mps2).all(1))
    nonfinite = windows_with_any(nonfinite_rows, starts, n + 1)
    dropped = {"imu_gap": int(gap.sum()), "imu_nonfinite": int(nonfinite.sum())}
    return WindowPlan(starts, n, rate, ~(gap | nonfinite), dropped)


# ----------------------------------------------------------------------------- metrics


@dataclass
class SourceMetrics:
    """Integration errors of one bias source over the kept windows.

    Attributes:
        name / kind: The source.
        t0_ns: First stamp of each window, [W].
        pos_err_m / rot_err_deg: End-of-window errors, [W].
        prmse_m: sqrt(mean pos_err^2).
        roe_deg: mean rot_err.
        flagged: Outlier windows, [W] bool.
        flag_pos_m / flag_rot_deg: The thresholds used.
        sigma_pos_m / sigma_rot_deg: Per window, the end-point error that the source's own bias
            sigma explains (:func:`sigma_window_errors`), [W]; zeros for a source without sigma.
        mean_bias: The source's bias averaged over the windows' first samples, [6] (gyro rad/s, acc
            m/s^2), or None: what two sources' errors differ by (a tilt and an acc bias trade off).
        gravity_mps2: The gravity the source was integrated with, [3] (None: not recorded).
        mean_std: The source's bias sigma averaged over the windows' first samples, [6], or None (with
            ``mean_bias``: whether the bias is within its own sigma of zero).
    """

    name: str
    kind: BiasSourceKind
    t0_ns: np.ndarray
    pos_err_m: np.ndarray
    rot_err_deg: np.ndarray
    prmse_m: float
    roe_deg: float
    flagged: np.ndarray
    flag_pos_m: float
    flag_rot_deg: float
    sigma_pos_m: np.ndarray | None = None
    sigma_rot_deg: np.ndarray | None = None
    mean_bias: np.ndarray | None = None
    gravity_mps2: np.ndarray | None = None
    mean_std: np.ndarray | None = None

    @property
    def sigma_prmse_m(self) -> float:
        """The PRMSE the source's own sigma explains: sqrt(mean sigma_pos_m^2)."""
        return 0.0 if self.sigma_pos_m is None else float(np.sqrt(np.mean(self.sigma_pos_m**2)))

    @property
    def sigma_roe_deg(self) -> float:
        """The ROE the source's own sigma explains: mean sigma_rot_deg."""
        return 0.0 if self.sigma_rot_deg is None else float(np.mean(self.sigma_rot_deg))

    @property
    def windows(self) -> int:
        return len(self.t0_ns)

    def to_dict(self) -> dict[str, Any]:
        idx = np.flatnonzero(self.flagged)
        return {
            "kind": self.kind.value,
            "prmse_m": float(self.prmse_m),
            "roe_deg": float(self.roe_deg),
            "windows": int(self.windows),
            "sigma_prmse_m": self.sigma_prmse_m,
            "sigma_roe_deg": self.sigma_roe_deg,
            "flag_threshold_pos_m": float(self.flag_pos_m),
            "flag_threshold_rot_deg": float(self.flag_rot_deg),
            **({} if self.mean_bias is None else {"mean_bias": [float(x) for x in self.mean_bias]}),
            **({} if self.gravity_mps2 is None else {"gravity_mps2": [float(x) for x in self.gravity_mps2]}),
            "flagged": [
                {"t0_ns": int(self.t0_ns[i]), "pos_err_m": float(self.pos_err_m[i]),
                 "rot_err_deg": float(self.rot_err_deg[i])}
                for i in idx
            ],
        }


def flag_windows(pos: np.ndarray, rot: np.ndarray, config: ValidationConfig) -> tuple[np.ndarray, float, float]:
    thr_p = max(config.flag_k * float(np.median(pos)), config.flag_min_pos_m)
    thr_r = max(config.flag_k * float(np.median(rot)), config.flag_min_rot_deg)
    return (pos > thr_p) | (rot > thr_r), thr_p, thr_r


def window_errors(
    imu: ImuSeries,
    bias: np.ndarray,
    ref: ReferenceStates,
    starts: np.ndarray,
    n: int,
    gravity: np.ndarray,
    config: ValidationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """pos_err [W] (m) and rot_err [W] (deg) of windows ``[s, s + n]`` integrated with ``imu - bias``."""
    return _integrate_chunks(imu, bias, ref, starts, n, np.asarray(gravity, dtype=np.float64), config)


def _integrate_chunks(imu: ImuSeries, bias: np.ndarray, ref: ReferenceStates, starts: np.ndarray, n: int,
                      g: np.ndarray, config: ValidationConfig) -> tuple[np.ndarray, np.ndarray]:
    pos_out, rot_out = [], []
    offs = np.arange(n + 1)
    for c0 in range(0, len(starts), config.chunk_windows):
        s = starts[c0:c0 + config.chunk_windows]
        idx = s[:, None] + offs[None, :]  # [B, n+1]
        e = s + n
        pos, rot = window_end_errors(
            imu.imu_6[idx], bias[idx], np.diff(imu.t_ns[idx], axis=1) / NS_PER_S,
            ref.R[s], ref.v[s], ref.p[s], ref.R[e], ref.p[e], gravity_mps2=g, scheme=config.scheme,
        )
        pos_out.append(pos)
        rot_out.append(rot)
    return np.concatenate(pos_out), np.concatenate(rot_out)


def window_end_errors(
    imu: Any,
    bias: Any,
    dt_s: Any,
    start_R: Any,
    start_v: Any,
    start_p: Any,
    end_R: Any,
    end_p: Any,
    *,
    gravity_mps2: Any,
    scheme: IntegrationScheme = IntegrationScheme.MIDPOINT,
) -> tuple[np.ndarray, np.ndarray]:
    """End-of-window errors of windows integrated from their reference start with ``imu - bias``.

    The one metric of the project (validation and the evaluation of learned models): float64,
    :func:`pipeline.geometry.integration.integrate`, no gradient.

    Args:
        imu: Gyro (rad/s) then acc (m/s^2), [B, T, 6].
        bias: Bias subtracted from ``imu``, [B, T, 6] (same order and units).
        dt_s: Sample intervals, [B, T-1] (s).
        start_R / start_v / start_p: Reference world-from-imu, velocity, position at the first
            sample, [B, 3, 3], [B, 3], [B, 3].
        end_R / end_p: Reference orientation and position at the last sample.
        gravity_mps2: Gravity in world, [3].
        scheme: Integration scheme.

    Returns:
        ``pos_err`` [B] (m) = |p_end - p_ref_end| and ``rot_err`` [B] (deg) = |Log(R_ref_end^T R_end)|.
    """
    def f64(x: Any) -> torch.Tensor:
        return torch.as_tensor(np.asarray(x, dtype=np.float64))

    imu_t, bias_t = f64(imu), f64(bias)
    # The per-step tensors are tiny ([B, 3]): intra-op threads only add synchronisation, which
    # on a loaded machine costs 20x (measured 1.2 s vs 0.06 s per call). Restored afterwards.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.no_grad():
            res = integrate(imu_t[..., :3], imu_t[..., 3:], f64(dt_s), f64(start_R), f64(start_v), f64(start_p),
                            gravity_mps2=f64(gravity_mps2), bias_gyro_radps=bias_t[..., :3],
                            bias_acc_mps2=bias_t[..., 3:], scheme=scheme)
    finally:
        torch.set_num_threads(threads)
    end_R, end_p = np.asarray(end_R, dtype=np.float64), np.asarray(end_p, dtype=np.float64)
    pos = np.linalg.norm(res.p.numpy() - end_p, axis=-1)
    rot = np.atleast_1d(rotation_angle_deg(end_R, res.R.numpy()))
    return pos, rot


def prmse_m(pos_err_m: np.ndarray) -> float:
    """PRMSE (m): sqrt(mean over windows of pos_err^2)."""
    return float(np.sqrt(np.mean(np.square(pos_err_m))))


def roe_deg(rot_err_deg: np.ndarray) -> float:
    """ROE (deg): mean over windows of rot_err."""
    return float(np.mean(rot_err_deg))
