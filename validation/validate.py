"""Validation of a bias trajectory by 1-second integration error (AirIMU's metrics).

The IMU is cut into windows of ``window_s`` (default 1 s, ``overlap`` 0.5); each window is
integrated (:func:`pipeline.integration.integrate`, MIDPOINT, float64) from the reference state at
its first sample with ``imu - bias`` and gravity, and its end compared with the reference:

    pos_err = |p_end - p_ref_end| [m]     rot_err = |Log(R_ref_end^T R_end)| [deg]
    PRMSE   = sqrt(mean pos_err^2) [m]     ROE     = mean rot_err [deg]

Contracts:
    * References (:class:`ReferenceStates`): a full state (linear p, v; Slerp R), else a pose
      stream on the IMU clock and in the IMU frame, its velocity from one smoothing spline
      whose cutoff follows the discrepancy principle.
    * Every source (:class:`BiasSourceKind`) is judged on the SAME windows; a window is dropped,
      counted per reason, when it crosses an IMU gap, holds a non-finite sample, lacks a
      reference end or a bias.
    * Each row is integrated with its own gravity (stated per source in validation.json).
    * The verdict (:func:`decide_verdict`): equal to a baseline up to the candidate's own sigma,
      WARN within the margin, FAIL beyond it only when a paired one-sided t-test over
      non-overlapping windows says so; worse than zero bias is always FAIL; limitations
      (:func:`recovery_limitations`) make a PASS a WARN; every WARN/FAIL has next steps.
    * Where the reference is the stream the bias was fitted to, the held-out blocks of the
      cross-validation judge (FAIL when significantly worse than zero or constant bias).

The derivations and measured figures behind these choices: docs/validation.md.
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from scipy.interpolate import make_smoothing_spline
from scipy.spatial.transform import Rotation, Slerp

from interpolation.bias import interpolate_bias
from pipeline.bias_table import BiasTrack, read_bias_csv
from pipeline.checks import reader_warnings
from pipeline.errors import BiasgtError, DataError, InputFormatError, ValidationError
from pipeline.integration import integrate
from pipeline.io import select_pose_stream
from pipeline.io.asl import read_asl_state_csv
from pipeline.pose_transform import as_transform, poses_in_imu_frame
from pipeline.so3 import rotation_angle_deg
from pipeline.types import (DEFAULT_GRAVITY_MPS2, NS_PER_S, ImuSeries, IntegrationScheme, PoseSeries, Sequence,
                            Severity, StateSeries)
from recovery.outputs import RecoveryOutputs
from validation.config import CrossvalMode, ValidationConfig
from validation.plausibility import plausibility_findings
from validation.outputs import HELDOUT_SOURCE, SCHEMA_VERSION, Verdict, write_folder

log = logging.getLogger(__name__)

__all__ = [
    "BiasSource",
    "BiasSourceKind",
    "ReferenceKind",
    "ReferenceStates",
    "SourceMetrics",
    "ValidationConfig",
    "ValidationResult",
    "Verdict",
    "WindowPlan",
    "build_reference",
    "bias_sources",
    "dataset_bias",
    "decide_verdict",
    "gap_free_mask",
    "plan_windows",
    "prmse_m",
    "read_bias_file",
    "sigma_window_errors",
    "recovery_limitations",
    "input_limitations",
    "Limitation",
    "next_steps",
    "recovered_bias_at_imu",
    "reference_from_poses",
    "reference_from_states",
    "roe_deg",
    "validate_inputs",
    "validate_sequence",
    "window_end_errors",
    "window_errors",
    "windows_with_any",
    "write_validation",
]


# ----------------------------------------------------------------------------- enums and config


class ReferenceKind(str, enum.Enum):
    """Where the reference start/end states come from."""

    STATE = "state"  # a full state (p, q, v): EuRoC ground truth, simulator truth
    POSES = "poses"  # a pose stream; velocity from a smoothing spline


class BiasSourceKind(str, enum.Enum):
    """What a bias source is (decides its role in the verdict)."""

    ZERO = "zero"
    CONSTANT_FIRST_WINDOW = "constant_first_window"
    DATASET = "dataset"
    RECOVERED = "recovered"
    FILE = "file"


# ----------------------------------------------------------------------------- reference states


@dataclass(frozen=True)
class ReferenceStates:
    """Reference navigation states at given stamps (normally every IMU stamp).

    Attributes:
        t_ns: Stamps on the IMU clock, int64 [N].
        R: World-from-imu orientation, [N, 3, 3].
        v: Velocity of the IMU in world, [N, 3] (m/s).
        p: Position of the IMU in world, [N, 3] (m).
        valid: True where a reference exists (inside the source's span, not in a gap), [N].
        kind: Where it comes from.
        info: Provenance (stream, offset, extrinsic, smoothing), JSON-serialisable.
    """

    t_ns: np.ndarray
    R: np.ndarray
    v: np.ndarray
    p: np.ndarray
    valid: np.ndarray
    kind: ReferenceKind
    info: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_ns)


def gap_free_mask(src_t_ns: np.ndarray, query_t_ns: np.ndarray, gap_factor: float) -> np.ndarray:
    """Which query stamps a source stream covers without a gap.

    A query stamp is covered when it lies inside the source's span and not strictly inside a
    gap, i.e. a source interval longer than ``gap_factor`` times the median one (a query
    stamp equal to a source stamp at a gap's edge is covered).

    Args:
        src_t_ns: Stamps of the source stream, sorted, int64 [M].
        query_t_ns: Stamps to test, int64 [N] (any order).
        gap_factor: Source intervals longer than this times the median are gaps (> 1).

    Returns:
        Boolean mask [N].
    """
    src_t_ns = np.asarray(src_t_ns, dtype=np.int64)
    query_t_ns = np.asarray(query_t_ns, dtype=np.int64)
    inside = (query_t_ns >= src_t_ns[0]) & (query_t_ns <= src_t_ns[-1])
    if len(src_t_ns) < 2:
        return inside
    d = np.diff(src_t_ns)
    big = d > gap_factor * np.median(d)
    if not big.any():
        return inside
    k = np.clip(np.searchsorted(src_t_ns, query_t_ns, side="right") - 1, 0, len(d) - 1)
    exact = src_t_ns[np.clip(np.searchsorted(src_t_ns, query_t_ns), 0, len(src_t_ns) - 1)] == query_t_ns
    return inside & (~big[k] | exact)


def _check_increasing(t_ns: np.ndarray, what: str) -> None:
    if len(t_ns) >= 2 and not np.all(np.diff(t_ns) > 0):
        bad = int(np.argmax(np.diff(t_ns) <= 0))
        raise ValidationError(
            f"{what} stamps are not strictly increasing (row {bad + 1})", field="t_ns",
            hint="run 'biasgt convert --repair all' to sort and deduplicate the input first",
        )


def _slerp(src_t_ns: np.ndarray, quat_wxyz: np.ndarray, query_t_ns: np.ndarray, t_origin_ns: int) -> np.ndarray:
    x = (np.asarray(src_t_ns, dtype=np.int64) - t_origin_ns) / NS_PER_S
    xq = (np.clip(query_t_ns, src_t_ns[0], src_t_ns[-1]) - t_origin_ns) / NS_PER_S
    rot = Rotation.from_quat(np.asarray(quat_wxyz, dtype=np.float64), scalar_first=True)
    if len(x) == 1:
        return np.repeat(rot.as_matrix(), len(xq), axis=0)
    return Slerp(x, rot)(xq).as_matrix()


def reference_from_states(
    state: StateSeries | ReferenceStates, t_ns: np.ndarray, *, gap_factor: float = 4.0
) -> ReferenceStates:
    """A full-state reference at ``t_ns``: linear p and v, Slerp R (kind STATE).

    Args:
        state: Ground-truth state on the IMU clock (or a reference at other stamps).
        t_ns: Query stamps (the IMU stamps), int64 [N].
        gap_factor: State intervals longer than this times the median are gaps (no reference).

    Returns:
        The reference at ``t_ns``; ``valid`` is False outside the state's span and in gaps.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if isinstance(state, ReferenceStates):
        keep = state.valid
        src_t, p, v = state.t_ns[keep], state.p[keep], state.v[keep]
        quat = Rotation.from_matrix(state.R[keep]).as_quat(scalar_first=True)
        info = dict(state.info)
    else:
        src_t, p, v, quat = state.t_ns, state.p_m, state.v_mps, state.quat_wxyz
        info = {"source": "ground_truth_state", "rate_hz": float(state.rate_hz)}
    if len(src_t) == 0:
        raise ValidationError("the reference state is empty", hint="give a ground truth with samples")
    _check_increasing(src_t, "ground-truth")
    t0 = int(src_t[0])
    x = (src_t - t0) / NS_PER_S
    xq = (np.clip(t_ns, src_t[0], src_t[-1]) - t0) / NS_PER_S
    p_q = np.column_stack([np.interp(xq, x, p[:, i]) for i in range(3)])
    v_q = np.column_stack([np.interp(xq, x, v[:, i]) for i in range(3)])
    R_q = _slerp(src_t, quat, t_ns, t0)
    valid = gap_free_mask(src_t, t_ns, gap_factor)
    valid &= np.isfinite(p_q).all(1) & np.isfinite(v_q).all(1) & np.isfinite(R_q).all((1, 2))
    return ReferenceStates(t_ns, R_q, v_q, p_q, valid, ReferenceKind.STATE, info)


def _as_T(T: Any) -> np.ndarray:
    try:
        return as_transform(T)
    except DataError as exc:
        raise ValidationError(exc.problem, field="T_imu_pose", hint=exc.hint) from None


def _spline_lambda(h_s: float, cutoff_hz: float) -> float:
    """Penalty of :func:`make_smoothing_spline` acting like ``1 / (1 + (w / w_c)^4)`` on samples ``h_s`` apart.

    With ``sum_i (y_i - f(x_i))^2 ~ (1/h) int (y - f)^2``, the penalised fit has the transfer
    function ``1 / (1 + lam h w^4)``, so ``lam = 1 / (h w_c^4)``.
    """
    return 1.0 / (h_s * (2.0 * math.pi * cutoff_hz) ** 4)


def _noise_sigma_m(p: np.ndarray) -> float:
    """White position-noise std from third differences (robust MAD; smooth motion cancels), m."""
    if len(p) < 8:
        return 0.0
    d3 = np.diff(p, 3, axis=0)
    mad = np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0) / 0.6745
    return float(np.sqrt(np.mean(mad**2) / 20.0))  # Var(d3) = 20 sigma^2


#: Cutoffs tried by the automatic choice, ascending (Hz).
_CUTOFF_GRID_HZ = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0)


def _choose_cutoff_hz(x: np.ndarray, p: np.ndarray, h_s: float, sigma: float) -> float:
    """Smoothing cutoff by the discrepancy principle: the lowest cutoff whose fit residual is <= the noise.

    The residual RMS (winsorised at 4 sigma against outliers) falls towards ``sigma`` as the cutoff
    rises; the first grid cutoff where it reaches ``sigma`` removes the noise without eating the
    motion. On the simulator this lands within one grid step of the cutoff with the least velocity
    error for slow, handheld and aggressive motion, 0.5-2 mm noise, 100-200 Hz (see
    tests/test_validation.py). Fitted on up to three 2000-sample segments for speed. Noise-free
    poses (sigma < 1 um) get the highest cutoff below a quarter of the pose rate.
    """
    top = [f for f in _CUTOFF_GRID_HZ if f <= 0.25 / h_s] or [_CUTOFF_GRID_HZ[0]]
    if sigma < 1e-6:
        return float(top[-1])
    seg = 2000
    if len(x) <= 3 * seg:
        pieces = [slice(0, len(x))]
    else:
        mids = (len(x) // 6, len(x) // 2, len(x) - len(x) // 6)
        pieces = [slice(m - seg // 2, m + seg // 2) for m in mids]
    for fc in top:
        lam = _spline_lambda(h_s, fc)
        sq = []
        for sl in pieces:
            r = make_smoothing_spline(x[sl], p[sl], lam=lam)(x[sl]) - p[sl]
            sq.append(np.minimum(r**2, (4.0 * sigma) ** 2).ravel())
        if math.sqrt(float(np.mean(np.concatenate(sq)))) <= sigma:
            return float(fc)
    return float(top[-1])


def reference_from_poses(
    poses: PoseSeries,
    t_ns: np.ndarray,
    *,
    T_imu_pose: np.ndarray | None = None,
    time_offset_s: float = 0.0,
    velocity_cutoff_hz: float | None = None,
    gap_factor: float = 4.0,
) -> ReferenceStates:
    """A reference from a 6-DoF pose stream (kind POSES); see the module docstring.

    Args:
        poses: ``T_world_<frame>`` samples on the pose clock.
        t_ns: Query stamps on the IMU clock (the IMU stamps), int64 [N].
        T_imu_pose: 4x4 ``T_imu_<frame>`` (identity when the poses are of the IMU).
        time_offset_s: Seconds to ADD to pose stamps to put them on the IMU clock.
        velocity_cutoff_hz: Cutoff of the smoothing spline used for p and v; None chooses it from
            the data (discrepancy principle, see :func:`_choose_cutoff_hz`).
        gap_factor: Pose intervals longer than this times the median are gaps (no reference).

    Returns:
        The reference at ``t_ns``.

    Raises:
        ValidationError: Position-only stream, fewer than 5 poses, or unordered stamps.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if poses.quat_wxyz is None:
        raise ValidationError(
            f"pose stream '{poses.frame}' has no orientation: a POSES reference needs 6-DoF poses", field="poses",
            hint="choose a 6-DoF stream with --poses, or a sequence with a ground-truth state",
        )
    ok = np.isfinite(poses.p_m).all(1) & np.isfinite(poses.quat_wxyz).all(1)
    ok &= np.linalg.norm(np.where(np.isfinite(poses.quat_wxyz), poses.quat_wxyz, 0.0), axis=1) > 0.5
    poses = poses.take(ok)
    if len(poses) < 5:
        raise ValidationError(f"pose stream has only {len(poses)} usable poses", field="poses",
                              hint="give a pose stream covering at least one window")
    _check_increasing(poses.t_ns, "pose")
    T = _as_T(T_imu_pose)
    imu_poses = poses_in_imu_frame(poses, T, time_offset_s)
    src_t, p_wi = imu_poses.t_ns, imu_poses.p_m  # on the IMU clock, in the IMU frame
    t0 = int(src_t[0])
    x = (src_t - t0) / NS_PER_S
    h = float(np.median(np.diff(x)))
    sigma = _noise_sigma_m(p_wi)
    auto = velocity_cutoff_hz is None
    cutoff = _choose_cutoff_hz(x, p_wi, h, sigma) if auto else float(velocity_cutoff_hz)
    lam = _spline_lambda(h, cutoff)
    spline = make_smoothing_spline(x, p_wi, lam=lam)
    xq = (np.clip(t_ns, src_t[0], src_t[-1]) - t0) / NS_PER_S
    p_q = spline(xq)
    v_q = spline.derivative()(xq)
    R_q = _slerp(src_t, imu_poses.quat_wxyz, t_ns, t0)
    valid = gap_free_mask(src_t, t_ns, gap_factor)
    info = {
        "source": "poses",
        "frame": poses.frame,
        "rate_hz": float(poses.rate_hz),
        "time_offset_s": float(time_offset_s),
        "T_imu_pose": T.tolist(),
        "velocity": "smoothing spline derivative",
        "velocity_cutoff_hz": float(cutoff),
        "velocity_cutoff_auto": bool(auto),
        "position_noise_m": float(sigma),
        "spline_lambda": float(lam),
    }
    return ReferenceStates(t_ns, R_q, np.asarray(v_q), np.asarray(p_q), valid, ReferenceKind.POSES, info)


# ----------------------------------------------------------------------------- recovery output and bias files


def _header_line(path: Path) -> str:
    try:
        with path.open("r", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.strip():
                    return line
    except OSError as exc:
        raise InputFormatError(f"cannot read bias file ({exc.strerror})", path=path) from None
    return ""


def read_bias_file(path: str | Path) -> BiasTrack:
    """Read any bias file biasgt knows, as a :class:`BiasTrack` (not yet at IMU rate).

    Accepted: the recovery contract ``bias.csv`` (``t_ns,bg_x,...,ba_z_std``; the ``*_std``
    columns optional, 0 when absent) or an interpolated bias table (``.csv``/``.parquet``, same
    columns); a EuRoC/OpenVINS state CSV
    (``#time(ns),px,py,pz,qw,qx,qy,qz,vx,vy,vz,bwx,bwy,bwz,bax,bay,baz`` or EuRoC's
    ``state_groundtruth_estimate0/data.csv``), whose bias columns are used (std = 0).

    Raises:
        InputFormatError: Missing file or an unknown layout.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError("bias file does not exist", path=path, hint="check the path")
    if path.suffix == ".parquet" or "bg_x" in _header_line(path):
        return read_bias_csv(path, require_std=False)
    try:
        state, _ = read_asl_state_csv(path, stream="bias")
    except InputFormatError as exc:
        raise InputFormatError(
            f"not a bias file ({exc.problem})", path=path,
            hint="give a bias.csv (t_ns,bg_x,...,ba_z_std), a bias .parquet, or a EuRoC/OpenVINS state CSV",
        ) from None
    return _state_bias_track(state, path)


def _state_bias_track(state: StateSeries, path: Path | None = None) -> BiasTrack:
    order = np.argsort(state.t_ns, kind="stable")
    t = state.t_ns[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    bias = np.hstack([state.bias_gyro_radps, state.bias_acc_mps2])[order][keep]
    if not np.all(np.isfinite(bias)):
        raise DataError("bias columns hold NaN or inf values", path=path, hint="clean the bias file")
    return BiasTrack(t[keep], bias, np.zeros_like(bias))


def dataset_bias(sequence: Sequence) -> BiasTrack | None:
    """The sequence's own ground-truth bias (EuRoC ``b_w``, ``b_a``), or None."""
    if sequence.ground_truth is None or len(sequence.ground_truth) == 0:
        return None
    return _state_bias_track(sequence.ground_truth)


def recovered_bias_at_imu(keyframes: BiasTrack, imu_t_ns: np.ndarray, random_walk: np.ndarray | None) -> BiasTrack:
    """The recovery's keyframe bias at the IMU stamps (:func:`interpolate_bias`, LINEAR).

    Stamps outside the recovered span are held and flagged ``clamped`` (validation drops them).
    """
    rw = np.zeros(6) if random_walk is None else np.asarray(random_walk, dtype=float)
    return interpolate_bias(keyframes, imu_t_ns, random_walk=rw, clamp=True)


@dataclass(frozen=True)
class BiasSource:
    """A named bias trajectory and its role.

    Attributes:
        name / kind / track: The source.
        gravity_mps2: The gravity, in the reference's world frame, that this bias was estimated
            against and is integrated with, [3]; None: the reference's own gravity.
    """

    name: str
    kind: BiasSourceKind
    track: BiasTrack
    gravity_mps2: np.ndarray | None = None


def _infer_kind(name: str) -> BiasSourceKind:
    try:
        return BiasSourceKind(name.lower())
    except ValueError:
        return BiasSourceKind.FILE


def _std_at(track: BiasTrack, t_ns: np.ndarray) -> np.ndarray:
    """The track's sigma at ``t_ns`` [N, 6] (linear, ends held; zeros for a track without sigma)."""
    std = np.asarray(track.std, dtype=np.float64)
    if not np.any(std):
        return np.zeros((len(t_ns), 6))
    t = np.asarray(track.t_ns, dtype=np.float64)
    return np.stack([np.interp(np.asarray(t_ns, dtype=np.float64), t, std[:, c]) for c in range(6)], axis=1)


def _bias_at(track: BiasTrack, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bias [N, 6], covered [N]) of a track at the IMU stamps (linear; never extrapolated)."""
    if len(track.t_ns) == len(t_ns) and np.array_equal(track.t_ns, t_ns):
        covered = np.ones(len(t_ns), bool) if track.clamped is None else ~np.asarray(track.clamped, bool)
        return np.asarray(track.bias, dtype=np.float64), covered
    t = np.asarray(track.t_ns, dtype=np.int64)
    if len(t) == 1:  # a constant bias covers everything
        return np.repeat(np.asarray(track.bias, dtype=np.float64), len(t_ns), axis=0), np.ones(len(t_ns), bool)
    _check_increasing(t, "bias")
    at = interpolate_bias(track, t_ns, random_walk=np.zeros(6), clamp=True)
    covered = ~at.clamped
    if track.clamped is not None and np.any(track.clamped):  # rows held by an earlier interpolation
        held = np.asarray(track.clamped, bool)
        inner = t[~held]
        covered &= (t_ns >= inner[0]) & (t_ns <= inner[-1]) if len(inner) else False
    return at.bias, covered


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
    _check_increasing(t, "IMU")
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


def _flags(pos: np.ndarray, rot: np.ndarray, config: ValidationConfig) -> tuple[np.ndarray, float, float]:
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
    :func:`pipeline.integration.integrate`, no gradient.

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


# ----------------------------------------------------------------------------- verdict


def sigma_window_errors(std: np.ndarray, R_world_imu: np.ndarray, window_s: float,
                        gravity_mps2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """End-point errors that a bias sigma explains, per window (first-order propagation).

    A constant acc bias error ``da`` (sigma ``s_a`` per axis) moves the end point by
    ``0.5 da T^2``; a gyro bias error ``dw`` tilts the attitude by ``R dw t``, which leaks
    gravity into the horizontal acceleration and moves the end point by ``|(R dw) x g| T^3 / 6``;
    it also rotates the end attitude by ``|dw| T``. With ``S = R diag(s_g^2) R^T`` (world frame),
    ``E|(R dw) x g|^2 = |g|^2 (tr S - g_hat^T S g_hat)``, so

        sigma_pos^2 = (T^2 / 2)^2 sum(s_a^2) + (|g| T^3 / 6)^2 (tr S - g_hat^T S g_hat)
        sigma_rot   = T sqrt(sum(s_g^2))

    Args:
        std: Bias sigma at each window's start, [W, 6] (rad/s, m/s^2).
        R_world_imu: Reference attitude at each window's start, [W, 3, 3].
        window_s: Window length T (s).
        gravity_mps2: Gravity in the world frame, [3].

    Returns:
        ``(sigma_pos_m [W], sigma_rot_deg [W])``.
    """
    T = float(window_s)
    g = np.asarray(gravity_mps2, dtype=float)
    g_norm = float(np.linalg.norm(g))
    g_hat = g / g_norm
    var_g, var_a = std[:, :3] ** 2, std[:, 3:] ** 2
    S = np.einsum("wij,wj,wkj->wik", R_world_imu, var_g, R_world_imu)
    tilt_var = np.trace(S, axis1=1, axis2=2) - np.einsum("i,wij,j->w", g_hat, S, g_hat)
    sigma_pos = np.sqrt((0.5 * T**2) ** 2 * var_a.sum(axis=1) + (g_norm * T**3 / 6.0) ** 2 * np.maximum(tilt_var, 0))
    sigma_rot = np.degrees(T * np.sqrt(var_g.sum(axis=1)))
    return sigma_pos, sigma_rot


def _paired_p_value(cand: np.ndarray, base: np.ndarray, stride: int) -> float:
    """One-sided p-value of "the candidate's window errors are larger" (paired t-test).

    Windows that share samples are correlated: only every ``stride``-th window enters (with 50 %
    overlap, the non-overlapping ones).
    """
    from scipy.stats import ttest_rel

    d = cand[::stride] - base[::stride]
    if len(d) < 3 or not np.any(d):
        return 1.0
    if np.ptp(d) <= 1e-12 * np.max(np.abs(d)):  # the same difference in every window: no spread to test
        return 0.0 if d[0] > 0 else 1.0
    return float(ttest_rel(cand[::stride], base[::stride], alternative="greater").pvalue)


def _compare(label: str, unit: str, cand: float, base: float, allowed: tuple[float, float], p_value: float,
             config: ValidationConfig) -> tuple[str | None, str | None]:
    """(fail reason, warn reason) of one metric; ``allowed``: (equal up to, within the margin up to)."""
    if cand <= allowed[0]:
        return None, None
    rel = (cand / base - 1.0) * 100.0 if base > 0 else float("inf")
    text = f"{label} {cand:.4g} {unit} is {rel:+.1f} % against {base:.4g} {unit}"
    margin = f"the {config.margin:.0%} margin"
    if cand <= allowed[1]:
        return None, f"{text}: worse beyond its own sigma, within {margin}"
    if p_value < config.significance:
        return f"{text}: worse by more than {margin} and its own sigma (paired test p = {p_value:.2g})", None
    return None, (f"{text}: worse by more than {margin}, but not significantly over these windows "
                  f"(paired test p = {p_value:.2g} >= {config.significance:g})")


def _worse_than_zero(metrics: Mapping[str, SourceMetrics], candidate: str, config: ValidationConfig) -> list[str]:
    """FAIL reasons of a candidate that integrates worse than the zero bias (beyond the ties), whatever its sigma."""
    cand, fails = metrics[candidate], []
    for zero in (m for name, m in metrics.items() if name != candidate and m.kind is BiasSourceKind.ZERO):
        for label, unit, c, z, tie in (("PRMSE", "m", cand.prmse_m, zero.prmse_m, config.tie_prmse_m),
                                       ("ROE", "deg", cand.roe_deg, zero.roe_deg, config.tie_roe_deg)):
            if c > z + tie:
                fails.append(f"'{candidate}' {label} {c:.4g} {unit} is worse than the zero bias's {z:.4g} {unit}: "
                             "subtracting it makes the integration worse than no bias estimate at all")
    return fails


def decide_verdict(
    metrics: Mapping[str, SourceMetrics],
    candidate: str,
    *,
    dropped_fraction: float,
    config: ValidationConfig = ValidationConfig(),
    limitations: Sequence_[str] = (),
    fails: Sequence_[str] = (),
) -> tuple[Verdict, list[str]]:
    """PASS / WARN / FAIL of ``candidate`` against the baselines (rules in the module docstring).

    Baselines: every CONSTANT_FIRST_WINDOW and DATASET source other than the candidate. Per
    metric, the candidate counts as equal up to what its own sigma explains
    (``sqrt(base^2 + (k sigma_prmse)^2)`` for PRMSE, ``base + k sigma_roe`` for ROE, plus the
    tie); as worse within the margin up to ``(1 + margin)`` times the baseline's part; beyond
    that it FAILs only when a paired one-sided t-test over independent windows says so at
    ``significance``.

    Args:
        metrics: Per source.
        candidate: The source judged.
        dropped_fraction: Fraction of candidate windows dropped.
        config: Thresholds.
        limitations: What limits the candidate's use though the numbers pass (e.g. a noise
            estimate at its search bound); each one makes a PASS a WARN, listed first.
        fails: Reasons already found for a FAIL (e.g. the held-out rule), listed first.

    Returns:
        ``(verdict, reasons)``; reasons are plain sentences (empty for a clean PASS).
    """
    cand = metrics[candidate]
    fails = list(fails)
    warns: list[str] = list(limitations)
    stride = max(1, int(round(1.0 / (1.0 - config.overlap))))
    k = config.sigma_k
    baselines = [m for name, m in metrics.items() if name != candidate
                 and m.kind in (BiasSourceKind.CONSTANT_FIRST_WINDOW, BiasSourceKind.DATASET)]
    for base in baselines:
        where = f"'{candidate}' against '{base.name}' ({base.kind.value})"
        sigma_pos, sigma_rot = k * cand.sigma_prmse_m, k * cand.sigma_roe_deg
        # a sigma beyond the baseline's own error excuses the candidate's error, but leaves it too
        # uncertain to be useful beside that baseline (an unobservable position-only recovery, say)
        for label, unit, s, c, b, tie in (("PRMSE", "m", sigma_pos, cand.prmse_m, base.prmse_m, config.tie_prmse_m),
                                           ("ROE", "deg", sigma_rot, cand.roe_deg, base.roe_deg, config.tie_roe_deg)):
            if s > b + tie and c > b + tie:
                warns.append(f"{where}: its own {k:g} sigma ({s:.4g} {unit} of {label}) exceed that baseline's error "
                             f"({b:.4g} {unit}): too uncertain to tell it from the baseline")
        prmse_allowed = tuple(float(np.hypot(base.prmse_m * f, sigma_pos)) + config.tie_prmse_m
                              for f in (1.0, 1.0 + config.margin))
        roe_allowed = tuple(base.roe_deg * f + sigma_rot + config.tie_roe_deg for f in (1.0, 1.0 + config.margin))
        for fail, warn in (
            _compare("PRMSE", "m", cand.prmse_m, base.prmse_m, prmse_allowed,
                     _paired_p_value(cand.pos_err_m**2, base.pos_err_m**2, stride), config),
            _compare("ROE", "deg", cand.roe_deg, base.roe_deg, roe_allowed,
                     _paired_p_value(cand.rot_err_deg, base.rot_err_deg, stride), config),
        ):
            fails += [f"{where}: {fail}"] if fail else []
            warns += [f"{where}: {warn}"] if warn else []
    fails += _worse_than_zero(metrics, candidate, config)
    if cand.windows:
        frac = float(np.mean(cand.flagged))
        if frac > config.warn_flagged_fraction:
            warns.append(f"{int(cand.flagged.sum())} of {cand.windows} windows ({frac:.1%}) of '{candidate}' are "
                         f"flagged as outliers (more than {config.warn_flagged_fraction:.0%})")
    if dropped_fraction > config.warn_dropped_fraction:
        warns.append(f"{dropped_fraction:.1%} of the windows were dropped (more than "
                     f"{config.warn_dropped_fraction:.0%}): the validation covers only part of the sequence")
    if not baselines:
        warns.append(f"no baseline (constant or dataset bias) to compare '{candidate}' with")
    if fails:
        return Verdict.FAIL, fails + warns
    if warns:
        return Verdict.WARN, warns
    return Verdict.PASS, []


# ----------------------------------------------------------------------------- main entry


@dataclass
class ValidationResult:
    """Outcome of :func:`validate_sequence`.

    Attributes:
        sequence: Sequence name.
        verdict / reasons: See :func:`decide_verdict`.
        candidate: Name of the judged source.
        config: The config used.
        sources: Metrics per source name (in evaluation order).
        windows_dropped: Counts: ``candidates``, ``kept``, ``dropped``, ``fraction`` and ``by_reason``.
        reference: Reference kind and provenance.
        gravity_mps2: Gravity used, [3].
        notes: What could not be validated, and other remarks.
        next_steps: What to do about a WARN or FAIL (:func:`next_steps`).
    """

    sequence: str
    verdict: Verdict
    reasons: list[str]
    candidate: str
    config: ValidationConfig
    sources: dict[str, SourceMetrics]
    windows_dropped: dict[str, Any]
    reference: dict[str, Any]
    gravity_mps2: np.ndarray
    notes: list[str] = field(default_factory=list)
    next_steps: list[str] = field(default_factory=list)
    heldout: dict[str, Any] | None = None
    plausibility: list[dict[str, Any]] = field(default_factory=list)

    def windows_frame(self) -> pd.DataFrame:
        """Per-window errors: t0_ns, source, pos_err_m, rot_err_deg, flagged."""
        parts = [
            pd.DataFrame({"t0_ns": m.t0_ns.astype(np.int64), "source": name, "pos_err_m": m.pos_err_m,
                          "rot_err_deg": m.rot_err_deg, "flagged": m.flagged.astype(bool)})
            for name, m in self.sources.items()
        ]
        return pd.concat(parts, ignore_index=True)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema_version": SCHEMA_VERSION,
            "sequence": self.sequence,
            "verdict": self.verdict.value,
            "reasons": list(self.reasons),
            "candidate": self.candidate,
            "config": self.config.to_dict(),
            "reference": self.reference,
            "gravity_mps2": [float(x) for x in self.gravity_mps2],
            "sources": {name: m.to_dict() for name, m in self.sources.items()},
            "windows_dropped": self.windows_dropped,
            "notes": list(self.notes),
            "next_steps": list(self.next_steps),
            **({} if self.heldout is None else {"heldout": self.heldout}),
            "plausibility": list(self.plausibility),
        }


def _normalise_sources(sources: Mapping[str, BiasTrack | BiasSource]) -> list[BiasSource]:
    out = []
    for name, s in sources.items():
        if isinstance(s, BiasSource):
            out.append(BiasSource(name, s.kind, s.track, s.gravity_mps2))
        elif isinstance(s, BiasTrack):
            out.append(BiasSource(name, _infer_kind(name), s))
        else:
            raise ValidationError(f"bias source '{name}' is a {type(s).__name__}, not a BiasTrack", field=name)
        b = np.asarray(out[-1].track.bias)
        if b.ndim != 2 or b.shape[1] != 6 or len(b) != len(out[-1].track.t_ns) or len(b) == 0:
            raise ValidationError(f"bias source '{name}' must hold [N, 6] values at N stamps, got {b.shape}",
                                  field=name)
    return out


def _imu_notes(imu: ImuSeries, sequence: Sequence, plan: WindowPlan) -> list[str]:
    notes = []
    cal = float(sequence.calibration.rate_hz) if sequence.calibration is not None else float("nan")
    if math.isfinite(cal) and cal > 0 and abs(plan.rate_hz / cal - 1.0) > 0.05:
        notes.append(f"the IMU runs at {plan.rate_hz:.2f} Hz but the calibration says {cal:g} Hz; windows use "
                     f"the measured rate ({plan.n} intervals per window)")
    dt = np.diff(imu.t_ns)
    nominal = NS_PER_S / plan.rate_hz
    irregular = float(np.mean(np.abs(dt / nominal - 1.0) > 0.1))
    if irregular > 0.01:
        notes.append(f"irregular IMU stamps: {irregular:.1%} of the intervals differ from the nominal by > 10 %; "
                     "each window is integrated with its actual intervals")
    return notes


def _checked_gravity(value: Any, field: str) -> np.ndarray:
    """``value`` as a finite 3-vector [3]."""
    gravity = np.asarray(value, dtype=np.float64).reshape(-1)
    if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
        raise ValidationError(f"gravity must be a finite 3-vector, got {value!r}", field=field)
    return gravity


def validate_sequence(
    sequence: Sequence,
    sources: Mapping[str, BiasTrack | BiasSource],
    *,
    reference: ReferenceStates | None = None,
    gravity_mps2: Any = DEFAULT_GRAVITY_MPS2,
    config: ValidationConfig = ValidationConfig(),
    limitations: Sequence_[str] = (),
    heldout: BiasSource | None = None,
    judge_heldout: bool = False,
    heldout_info: Mapping[str, Any] | None = None,
    fails: Sequence_[str] = (),
) -> ValidationResult:
    """Validate bias trajectories by 1-s integration error against a reference (AirIMU metrics).

    Args:
        sequence: The sequence (its IMU is integrated; its ground-truth bias becomes the DATASET
            source when ``config.include_dataset``).
        sources: Bias sources by name: :class:`BiasSource`, or a plain :class:`BiasTrack` whose kind
            follows the name (``"recovered"`` -> RECOVERED, ``"dataset"`` -> DATASET, else FILE).
            Tracks at any stamps (keyframes or IMU rate) on the IMU clock; never extrapolated.
        reference: Reference states; default the ground-truth state (STATE). Built for other
            stamps it is re-interpolated to the IMU stamps.
        gravity_mps2: The reference's own gravity in its world frame, [3]: every source is integrated
            with it, but a :class:`BiasSource` that names its own (the gravity it was estimated
            against, in the same frame), so that no source's gravity changes another's errors.
        config: Windows, flags and verdict thresholds.
        limitations: What limits the candidate though its numbers pass (:func:`decide_verdict`).
        heldout: The candidate cross-validated by time blocks (:mod:`validation.crossval`; NaN where a
            fold was dropped): measured on the kept windows it covers, beside every other source on
            the same windows (``result.heldout``).
        judge_heldout: The held-out errors judge the verdict (the reference is the stream the bias
            was fitted to): worse than the zero or the constant bias on those windows is a FAIL.
        heldout_info: What the cross-validation did (blocks, folds, dropped folds), for the output.
        fails: Reasons for a FAIL found before the integration (e.g. :mod:`validation.plausibility`),
            listed first.

    Returns:
        The result, with per-source metrics, the verdict and its reasons.

    Raises:
        ValidationError: No IMU; no reference; a sequence shorter than one window; no bias source
            to judge; no window left after dropping.
    """
    imu = sequence.imu
    if imu is None or len(imu) == 0:
        raise ValidationError(f"sequence '{sequence.name}' has no IMU to integrate",
                              hint="give an input with IMU readings")
    gravity = _checked_gravity(gravity_mps2, "gravity_mps2")
    notes: list[str] = []
    plan = plan_windows(imu, config)
    notes += _imu_notes(imu, sequence, plan)

    if reference is None:
        if sequence.ground_truth is None:
            raise ValidationError(
                f"sequence '{sequence.name}' has no ground-truth state and no reference was given",
                hint="build a POSES reference (build_reference / --poses STREAM) from a 6-DoF pose stream",
            )
        reference = reference_from_states(sequence.ground_truth, imu.t_ns, gap_factor=config.reference_gap_factor)
    elif not (len(reference.t_ns) == len(imu.t_ns) and np.array_equal(reference.t_ns, imu.t_ns)):
        kind = reference.kind
        reference = reference_from_states(reference, imu.t_ns, gap_factor=config.reference_gap_factor)
        reference = ReferenceStates(reference.t_ns, reference.R, reference.v, reference.p, reference.valid, kind,
                                    reference.info)

    given = _normalise_sources(sources)
    if config.include_dataset and not any(s.kind is BiasSourceKind.DATASET for s in given):
        ds = dataset_bias(sequence)
        if ds is not None:
            given.append(BiasSource("dataset", BiasSourceKind.DATASET, ds))
        else:
            notes.append("no DATASET source: the sequence has no ground-truth bias")
    if not given:
        raise ValidationError(f"no bias to validate for sequence '{sequence.name}'",
                              hint="give a bias file (--bias FILE) or a recovery folder (--recovery DIR)")
    order = {BiasSourceKind.RECOVERED: 0, BiasSourceKind.FILE: 1, BiasSourceKind.DATASET: 2}
    judged = sorted((s for s in given if s.kind in order), key=lambda s: order[s.kind])
    if not judged:
        raise ValidationError("no bias source to judge (only zero / constant given)",
                              hint="give a recovered, dataset or file bias")
    candidate = judged[0].name

    s, e = plan.starts, plan.starts + plan.n
    keep = plan.keep.copy()
    by_reason = dict(plan.dropped)
    no_ref = ~(reference.valid[s] & reference.valid[e])
    by_reason["no_reference"] = int(no_ref.sum())
    keep &= ~no_ref
    at_imu: dict[str, np.ndarray] = {}
    for src in given:
        bias, covered = _bias_at(src.track, imu.t_ns)
        covered = covered & np.isfinite(bias).all(axis=1)
        uncovered = windows_with_any(~covered, s, plan.n + 1)
        by_reason[f"bias_not_covered:{src.name}"] = int(uncovered.sum())
        if uncovered.any():
            log.info("bias source '%s' does not cover %d of %d windows", src.name, int(uncovered.sum()), len(s))
        keep &= ~uncovered
        at_imu[src.name] = bias
    n_cand = len(s)
    n_keep = int(keep.sum())
    dropped = {"candidates": n_cand, "kept": n_keep, "dropped": n_cand - n_keep,
               "fraction": float((n_cand - n_keep) / n_cand), "by_reason": by_reason}
    if n_keep == 0:
        worst = max(by_reason, key=lambda k: by_reason[k])
        raise ValidationError(
            f"no window of sequence '{sequence.name}' can be validated: all {n_cand} dropped "
            f"(mostly {worst}: {by_reason[worst]})",
            hint="make the bias and the reference cover the IMU span, or fix the IMU gaps",
        )
    if n_cand - n_keep:
        log.info("validating %d of %d windows (%s)", n_keep, n_cand,
                 ", ".join(f"{k} {v}" for k, v in by_reason.items() if v))

    starts = s[keep]
    evaluated: list[BiasSource] = []
    if config.include_zero:
        zero = np.zeros((len(imu), 6))
        at_imu["zero"] = zero
        evaluated.append(BiasSource("zero", BiasSourceKind.ZERO, BiasTrack(imu.t_ns, zero, zero)))
    if config.include_constant:
        i0 = int(starts[0])
        const = at_imu[candidate][i0:i0 + plan.n + 1].mean(axis=0)
        at_imu["constant"] = np.broadcast_to(const, (len(imu), 6))
        evaluated.append(BiasSource("constant", BiasSourceKind.CONSTANT_FIRST_WINDOW,
                                    BiasTrack(imu.t_ns[:1], const[None], np.zeros((1, 6)))))
        notes.append(f"'constant' is the mean of '{candidate}' over the first kept window "
                     f"(t0_ns {int(imu.t_ns[i0])}), held constant")
    names = [x.name for x in evaluated]
    for src in given:
        if src.name in names:
            raise ValidationError(f"two bias sources are named '{src.name}'", field=src.name,
                                  hint="give each --bias a distinct NAME (zero and constant are reserved)")
        evaluated.append(src)
        names.append(src.name)

    metrics: dict[str, SourceMetrics] = {}
    t0 = imu.t_ns[starts]
    window_s = plan.n / plan.rate_hz
    for src in evaluated:
        g_src = gravity if src.gravity_mps2 is None else _checked_gravity(src.gravity_mps2, f"{src.name}.gravity_mps2")
        pos, rot = window_errors(imu, at_imu[src.name], reference, starts, plan.n, g_src, config)
        flagged, thr_p, thr_r = _flags(pos, rot, config)
        sigma_pos, sigma_rot = sigma_window_errors(_std_at(src.track, t0), reference.R[starts], window_s, g_src)
        metrics[src.name] = SourceMetrics(
            src.name, src.kind, t0, pos, rot, prmse_m(pos), roe_deg(rot),
            flagged, thr_p, thr_r, sigma_pos, sigma_rot, at_imu[src.name][starts].mean(axis=0), g_src,
        )
        log.info("%-12s PRMSE %.4f m  ROE %.4f deg  (%d windows, %d flagged)", src.name,
                 metrics[src.name].prmse_m, metrics[src.name].roe_deg, len(pos), int(flagged.sum()))
    heldout_part, heldout_fails = None, []
    limitations = list(limitations)
    if heldout is not None:
        heldout_part, heldout_fails, heldout_warns = _heldout_metrics(
            imu, heldout, reference, plan, starts, gravity, metrics, config, judge_heldout, dict(heldout_info or {}))
        limitations = [*heldout_warns, *limitations]
    verdict, reasons = decide_verdict(metrics, candidate, dropped_fraction=dropped["fraction"], config=config,
                                      limitations=limitations, fails=[*fails, *heldout_fails])
    ref_info = {"kind": reference.kind.value, **reference.info}
    return ValidationResult(sequence.name, verdict, reasons, candidate, config, metrics, dropped, ref_info,
                            gravity, notes, heldout=heldout_part)


def _heldout_metrics(imu: ImuSeries, heldout: BiasSource, reference: ReferenceStates, plan: WindowPlan,
                     starts: np.ndarray, gravity: np.ndarray, metrics: dict[str, SourceMetrics],
                     config: ValidationConfig, judge: bool, info: dict[str, Any]
                     ) -> tuple[dict[str, Any], list[str], list[str]]:
    """The held-out source's metrics on the kept windows it covers (added to ``metrics``), every other
    source's on the same windows, and, when it judges the verdict, the FAIL reasons (worse than the
    zero or the constant bias beyond the ties, significantly by the paired test over non-overlapping
    windows) and the WARN reasons (worse, but not significantly: a tie at the reference's noise floor)."""
    bias, covered = _bias_at(heldout.track, imu.t_ns)
    covered &= np.isfinite(bias).all(axis=1)
    ok = ~windows_with_any(~covered, starts, plan.n + 1)
    part: dict[str, Any] = {**info, "source": heldout.name, "judged": bool(judge), "windows": int(ok.sum())}
    if not ok.any():
        part["note"] = "no kept window lies in a held-out block with a recovered bias"
        return part, [], []
    g = gravity if heldout.gravity_mps2 is None else np.asarray(heldout.gravity_mps2, dtype=np.float64)
    pos, rot = window_errors(imu, bias, reference, starts[ok], plan.n, g, config)
    flagged, thr_p, thr_r = _flags(pos, rot, config)
    metrics[heldout.name] = SourceMetrics(heldout.name, heldout.kind, imu.t_ns[starts[ok]], pos, rot, prmse_m(pos),
                                          roe_deg(rot), flagged, thr_p, thr_r, mean_bias=bias[starts[ok]].mean(axis=0),
                                          gravity_mps2=g)
    same = {name: {"prmse_m": prmse_m(m.pos_err_m[ok]), "roe_deg": roe_deg(m.rot_err_deg[ok])}
            for name, m in metrics.items() if name != heldout.name and len(m.pos_err_m) == len(ok)}
    part["others_on_these_windows"] = same
    fails, warns = [], []
    stride = max(1, int(round(1.0 / (1.0 - config.overlap))))
    for name, m in same.items():
        base = metrics[name]
        if not judge or base.kind not in (BiasSourceKind.ZERO, BiasSourceKind.CONSTANT_FIRST_WINDOW):
            continue
        for label, unit, h, b, tie, errs in (
                ("PRMSE", "m", prmse_m(pos), m["prmse_m"], config.tie_prmse_m, (pos**2, base.pos_err_m[ok] ** 2)),
                ("ROE", "deg", roe_deg(rot), m["roe_deg"], config.tie_roe_deg, (rot, base.rot_err_deg[ok]))):
            if h <= b + tie:
                continue
            p_value = _paired_p_value(*errs, stride)
            text = (f"held out: '{heldout.name}' {label} {h:.4g} {unit} is worse than the '{name}' bias's {b:.4g} {unit} "
                    f"on the same {int(ok.sum())} windows")
            if p_value < config.significance:
                fails.append(f"{text} (p = {p_value:.2g}): on poses it was not fitted to the recovered bias does "
                             "worse than no estimate (it absorbed errors of the poses it saw)")
            else:
                warns.append(f"{text}, not significantly (p = {p_value:.2g}): held out it is no better than that bias")
    return part, fails, warns


# ----------------------------------------------------------------------------- output


def write_validation(result: ValidationResult, out_dir: str | Path) -> Path:
    """Write ``out_dir/validation.json`` and ``out_dir/windows.parquet`` atomically
    (:func:`validation.outputs.write_folder`); returns ``out_dir``."""
    return write_folder(result.to_dict(), result.windows_frame(), out_dir)


# ----------------------------------------------------------------------------- reference selection


def build_reference(
    sequence: Sequence,
    *,
    pose_stream: str | None = None,
    recovery: RecoveryOutputs | None = None,
    config: ValidationConfig = ValidationConfig(),
) -> ReferenceStates:
    """The reference for ``sequence``: its ground-truth state, else a pose stream.

    Rules: ``pose_stream`` given (other than ``"ground_truth"``) -> POSES from that stream;
    else the ground-truth state when there is one (STATE); else POSES from the default
    stream (:func:`pipeline.io.select_pose_stream`; the recovery's stream when it names one).
    POSES use the recovery's ``T_imu_pose`` and clock offset when ``recovery`` is given, else
    the calibration's ``T_imu_<frame>`` (identity for IMU/ground-truth frames) and offset 0.

    Raises:
        ValidationError: No usable reference, or an unknown pose-to-IMU extrinsic.
    """
    imu = sequence.imu
    if imu is None:
        raise ValidationError(f"sequence '{sequence.name}' has no IMU", hint="give an input with IMU readings")
    if (pose_stream is None or pose_stream == "ground_truth") and sequence.ground_truth is not None:
        return reference_from_states(sequence.ground_truth, imu.t_ns, gap_factor=config.reference_gap_factor)
    fitted = recovery.report.pose_stream if recovery is not None else None
    if pose_stream is None and fitted in sequence.poses:
        pose_stream = fitted
    try:
        name, poses = select_pose_stream(sequence, pose_stream)
    except BiasgtError as exc:
        raise ValidationError(f"no reference for sequence '{sequence.name}': {exc.problem}", field="poses",
                              hint=exc.hint) from None
    if poses.quat_wxyz is None:
        full = [k for k, v in sequence.poses.items() if v.quat_wxyz is not None]
        if sequence.ground_truth is not None:
            instead = "validate against the sequence's ground-truth state instead: drop --poses"
        elif full:
            instead = f"validate against a 6-DoF stream instead: --poses {' or --poses '.join(full)}"
        else:
            instead = ("add 6-DoF poses or a ground truth of the same run (--add-poses FILE:ground_truth) and "
                       "validate against them with --poses")
        raise ValidationError(f"pose stream '{pose_stream or name}' has positions only: the 1-s integration "
                              "check needs the orientation at each window's start", field="--poses", hint=instead)
    if recovery is not None and (fitted is None or fitted == name):
        # the recovery's extrinsic and clock offset belong to the stream it fitted
        T, offset = recovery.report.T_imu_pose, recovery.report.time_offset_s
    else:
        T = sequence.calibration.T_imu_frames.get(poses.frame)
        offset = 0.0
        if T is None:
            if poses.frame.lower() in ("imu", "imu0", "body") or poses.source_kind.value == "ground_truth":
                T = np.eye(4)
            else:
                raise ValidationError(
                    f"pose stream '{name}' tracks frame '{poses.frame}' whose pose in the IMU frame is unknown",
                    field="poses", hint="give the recovery folder (--recovery DIR), which holds T_imu_pose "
                                        "and the clock offset",
                )
    ref = reference_from_poses(poses, imu.t_ns, T_imu_pose=T, time_offset_s=offset,
                               velocity_cutoff_hz=config.velocity_cutoff_hz, gap_factor=config.reference_gap_factor)
    ref.info["stream"] = name
    return ref


# ----------------------------------------------------------------------------- assembling the inputs (CLI, workflow)


def bias_sources(
    sequence: Sequence,
    *,
    recovery: RecoveryOutputs | None = None,
    bias_files: Sequence_[tuple[str | None, str | Path]] = (),
) -> dict[str, BiasSource]:
    """The bias sources of a validation: the recovery's bias and any bias files.

    The recovery's ``bias.csv`` becomes ``"recovered"`` (RECOVERED, interpolated to the IMU stamps
    with the recovery's random walks, else the calibration's). An unnamed file is the bias under
    test (``"recovered"``) when it is the first one and no recovery is given, else FILE named by
    its stem; a named one is FILE.

    Args:
        sequence: The sequence (its IMU stamps and calibration are used).
        recovery: The recovery folder (:meth:`recovery.outputs.RecoveryOutputs.read`), or None.
        bias_files: ``(name or None, path)`` pairs.

    Raises:
        ValidationError: Nothing to validate, or a name used twice or reserved.
        InputFormatError: An unreadable bias file.
    """
    if not bias_files and recovery is None:
        raise ValidationError("nothing to validate", field="--bias", hint="give --recovery DIR or --bias FILE")
    if sequence.imu is None:
        raise ValidationError(f"sequence '{sequence.name}' has no IMU to integrate",
                              hint="give an input with IMU readings")
    cal = sequence.calibration
    rw_cal = np.array([cal.gyro_random_walk] * 3 + [cal.acc_random_walk] * 3, dtype=float)
    sources: dict[str, BiasSource] = {}
    if recovery is not None:
        rw = recovery.report.random_walk if recovery.report.random_walk is not None else rw_cal
        track = recovered_bias_at_imu(recovery.bias, sequence.imu.t_ns, rw)
        sources["recovered"] = BiasSource("recovered", BiasSourceKind.RECOVERED, track)
    unnamed = 0
    for name, path in bias_files:
        path = Path(path)
        track = read_bias_file(path)
        if name is None:
            unnamed += 1
            first = unnamed == 1 and recovery is None
            name = "recovered" if first else path.stem
            kind = BiasSourceKind.RECOVERED if first else BiasSourceKind.FILE
        else:
            kind = BiasSourceKind.FILE
        if name in sources or name in ("zero", "constant"):
            raise ValidationError(f"bias source name '{name}' is used twice or reserved", field="--bias",
                                  hint="name the sources with --bias NAME=FILE (zero and constant are reserved)")
        sources[name] = BiasSource(name, kind, track)
    return sources


@dataclass(frozen=True)
class Limitation:
    """Something that limits what a bias is good for, and what to do about it.

    Attributes:
        text: What was found (a reason of the verdict).
        next_step: What the user can do next.
    """

    text: str
    next_step: str


def recovery_limitations(recovery: RecoveryOutputs, config: ValidationConfig = ValidationConfig()) -> list[Limitation]:
    """What limits a recovered bias though its integration errors may pass, from ``recovery.json``.

    Each item makes a PASS a WARN (:func:`decide_verdict`): a random walk chosen at the upper edge
    of the evidence search (the true value may lie beyond it), one far from the calibration's
    (``max_random_walk_scale``: unmodelled errors such as scale or misalignment that the bias
    absorbs, or a wrong datasheet), and an extrinsic rotation that could not be estimated.
    """
    report = recovery.report
    noise = report.get("noise") if isinstance(report.get("noise"), Mapping) else {}
    grid = (report.get("config") or {}).get("random_walk_scales") or []
    out: list[Limitation] = []
    noise_step = ("check the IMU noise values of the calibration (sensor.yaml: random walks) against the "
                  "datasheet, and the pose stream for artefacts (biasgt report's residual plot)")
    for axis in ("gyro", "acc"):
        scale = noise.get(f"{axis}_random_walk_scale")
        if not isinstance(scale, (int, float)) or not math.isfinite(scale):
            continue
        # Only the upper edge limits the bias: a walk that wants to be looser than the search allows
        # means the bias absorbs other errors. At the lower edge (a nearly constant bias, e.g. the
        # semi-real sequences' EuRoC bias) the recovered bias is only a little less smooth than it
        # could be, and its sigma errs on the safe side.
        if noise.get("method") == "evidence" and grid and scale >= max(grid):
            out.append(Limitation(
                f"the {axis} bias random walk was chosen at the upper edge of its search ({scale:g}x the "
                f"calibration; searched {min(grid):g}x-{max(grid):g}x): the bias may absorb other errors",
                noise_step + "; widen recovery.random_walk_scales only if the calibration is known to be wrong"))
        elif not 1.0 / config.max_random_walk_scale <= scale <= config.max_random_walk_scale:
            out.append(Limitation(
                f"the {axis} bias random walk is {scale:.3g}x the calibration's: the bias likely absorbs "
                "unmodelled errors (scale, misalignment, pose artefacts) or the datasheet is off", noise_step))
    diff = (report.get("extrinsic") or {}).get("difference_from_calibration") or {}
    if diff.get("exceeds"):
        out.append(Limitation(
            f"the extrinsic T_imu_pose estimated from the data differs from the calibration's by "
            f"{diff['rotation_deg']:.2f} deg and {100 * diff['translation_m']:.1f} cm, beyond "
            f"{diff['max_sigmas']:g} of its sigmas: the calibration file is off (or the tracked body moved); the "
            "bias is the one consistent with the estimate",
            "if the tracked body was not moved, put the estimate (recovery.json T_imu_pose) into the calibration "
            "file; else check the mount and recover again"))
    if report.get("extrinsic_rotation_observable") is False:
        out.append(Limitation(
            "the rotation between the pose frame and the IMU was not observable (too little rotation): the "
            "calibration's or the identity was used, and the bias absorbs any error in it",
            "record a stretch rotating about every axis, or give T_imu_pose in the calibration and recover "
            "with --extrinsic known"))
    return out


#: Input findings that limit what a bias recovered from that input is good for, and what to do.
_LIMITING_FINDINGS = {
    "POSE_RATE_LOW": "use a faster pose stream (motion capture at 100 Hz or more) if the recording has one",
    "CALIBRATION_DEFAULTED": "give the IMU's own noise values (sensor.yaml or the recovery config) and recover again",
    "SATURATION": "record with a larger sensor range, or drop the saturated stretches",
    "STAMP_UNIT_GUESSED": "write the stamps as integer nanoseconds so that their unit is not guessed",
    "IMU_RATE_MISMATCH": "resample the IMU to the calibration's rate (biasgt convert --resample-hz) or correct "
                         "rate_hz in sensor.yaml, and recover again",
}


def input_limitations(sequence: Sequence) -> list[Limitation]:
    """The sequence's WARNING findings that limit a bias recovered from it (:data:`_LIMITING_FINDINGS`)."""
    return [Limitation(f"input: {f.message}", _LIMITING_FINDINGS[f.code]) for f in sequence.findings
            if f.code in _LIMITING_FINDINGS and f.severity is Severity.WARNING]


def validate_inputs(
    sequence: Sequence,
    *,
    recovery_dir: str | Path | None = None,
    bias_files: Sequence_[tuple[str | None, str | Path]] = (),
    pose_stream: str | None = None,
    gravity_mps2: Any = None,
    config: ValidationConfig = ValidationConfig(),
) -> ValidationResult:
    """Validate a sequence from what ``biasgt validate`` and the workflow's rule are given.

    Assembles the sources (:func:`bias_sources`) and the reference (:func:`build_reference`), then
    runs :func:`validate_sequence`. A FAIL verdict is a result, not an error.

    Gravity: ``gravity_mps2`` for every row when given. Else each row is integrated with the
    reference's own gravity, nominal ``(0, 0, -|g|)`` (a ground-truth state, a mocap or survey frame
    are level), except the recovered bias (and its held-out version) against the very stream it was
    fitted to, which takes the recovery's gravity (its world frame is that stream's): no candidate's
    gravity changes another row.

    Cross-validation (``config.crossval``): against the stream the bias was fitted to, the held-out
    blocks are the independent test and judge the verdict; against an independent reference they are
    a row compared with the others.

    Args:
        sequence: The sequence (canonical store or any input, already loaded).
        recovery_dir: A recovery output folder (``bias.csv`` + ``recovery.json``), or None.
        bias_files: ``(name or None, path)`` bias files (see :func:`bias_sources`).
        pose_stream: Reference pose stream (None: ground truth, else the recovery's stream).
        gravity_mps2: Gravity in the reference world frame, [3], or None.
        config: Validation options.

    Raises:
        ValidationError / InputFormatError / DataError: Bad or insufficient inputs.
    """
    recovery = RecoveryOutputs.read(recovery_dir) if recovery_dir is not None else None
    sources = bias_sources(sequence, recovery=recovery, bias_files=bias_files)
    reference = build_reference(sequence, pose_stream=pose_stream, recovery=recovery, config=config)
    fitted = recovery is not None and reference.kind is ReferenceKind.POSES and (
        recovery.report.pose_stream is None or reference.info.get("stream") == recovery.report.pose_stream)
    own_gravity = None  # the recovery's gravity for its own rows, in the fitted stream's frame
    if gravity_mps2 is not None:
        gravity = np.asarray(gravity_mps2, dtype=float)
    else:
        gravity = nominal_gravity(recovery)
        if fitted and recovery.report.gravity_world_mps2 is not None:
            own_gravity = np.asarray(recovery.report.gravity_world_mps2, dtype=float)
            sources = {k: (replace(s, gravity_mps2=own_gravity) if s.kind is BiasSourceKind.RECOVERED else s)
                       for k, s in sources.items()}
    heldout, heldout_info = None, None
    if config.crossval_block_s is not None and (config.crossval is CrossvalMode.ON or
                                                (config.crossval is CrossvalMode.AUTO and fitted)):
        heldout, heldout_info = _heldout_source(sequence, recovery, config, required=config.crossval is CrossvalMode.ON)
        if heldout is not None and own_gravity is not None:
            heldout = replace(heldout, gravity_mps2=own_gravity)
    judged = fitted and heldout is not None and len(heldout_info["dropped_folds"]) < config.crossval_folds
    implausible = plausibility_findings(sequence, recovery) if recovery is not None else []
    limitations = input_limitations(sequence)
    limitations += recovery_limitations(recovery, config) if recovery is not None else []
    if fitted and not judged:
        limitations.append(Limitation(
            "not an independent test: the reference poses are those the recovery fitted, so pose errors that "
            "the bias absorbed are not seen" + (" (and no cross-validation fold could be recovered)"
                                                if heldout is not None else ""),
            "validate against another pose stream or a ground truth (--poses STREAM, --add-poses FILE:KIND), or "
            "cross-validate (--crossval on)"))
    result = validate_sequence(sequence, sources, reference=reference, gravity_mps2=gravity, config=config,
                               limitations=[lim.text for lim in limitations], heldout=heldout, judge_heldout=judged,
                               heldout_info=heldout_info, fails=[x.text for x in implausible])
    result.plausibility = [x.to_dict() for x in implausible]
    result.next_steps = next_steps(result, [Limitation(x.text, x.next_step) for x in implausible] + limitations)
    if own_gravity is not None:
        result.notes.append(f"'recovered' is integrated with the recovery's gravity {np.round(own_gravity, 4).tolist()} "
                            f"m/s^2 (the reference is the stream it was fitted to); the other rows with "
                            f"{np.round(gravity, 4).tolist()}")
    if judged:
        result.notes.append("the reference is the stream the bias was fitted to: the held-out blocks judge the verdict")
    if recovery is not None:
        result.notes.append(f"recovery: {recovery_dir}")
    result.notes += reader_warnings(sequence.findings)  # skipped input lines
    return result


def nominal_gravity(recovery: RecoveryOutputs | None = None) -> np.ndarray:
    """``(0, 0, -|g|)``, [3]: gravity in a level world frame (``|g|`` of the recovery's options, else 9.81)."""
    magnitude = (recovery.report.get("config") or {}).get("gravity_mps2") if recovery is not None else None
    return np.array([0.0, 0.0, -float(magnitude if magnitude is not None else -DEFAULT_GRAVITY_MPS2[2])])


def _heldout_source(sequence: Sequence, recovery: RecoveryOutputs | None, config: ValidationConfig,
                    required: bool) -> tuple[BiasSource | None, dict[str, Any] | None]:
    """The recovery cross-validated by blocks (``crossval_block_s``) as the source ``recovered_heldout``,
    and what the cross-validation did (``dropped_folds``: the folds whose recovery failed, with why).

    Raises:
        ValidationError: ``required`` and there is no recovery of a pose stream of this sequence.
    """
    from validation.crossval import BlockFolds, heldout_track

    stream = recovery.report.pose_stream if recovery is not None else None
    if recovery is None or stream not in sequence.poses:
        if not required:
            return None, None
        raise ValidationError("cross-validation needs the recovery and the pose stream it fitted" + (
            f" ('{stream}' is not among the sequence's pose streams)" if recovery is not None else ""),
            field="crossval",
            hint="give the recovery folder of a pose-stream recovery, or --crossval off")
    folds = BlockFolds(int(sequence.imu.t_ns[0]), float(config.crossval_block_s), int(config.crossval_folds))
    log.info("cross-validating the recovery from '%s' by %d folds of %g-s blocks", stream, folds.n_folds,
             folds.block_s)
    track, dropped = heldout_track(sequence, stream, dict(recovery.report.get("config") or {}), folds)
    for k, why in dropped.items():
        log.warning("cross-validation fold %d of %d dropped: %s", k + 1, folds.n_folds, why)
    info = {"block_s": folds.block_s, "folds": folds.n_folds,
            "dropped_folds": [{"fold": int(k), "reason": why} for k, why in sorted(dropped.items())]}
    return BiasSource(HELDOUT_SOURCE, BiasSourceKind.FILE, track), info


def next_steps(result: ValidationResult, limitations: Sequence_[Limitation] = ()) -> list[str]:
    """What to do about a WARN or FAIL, one sentence per cause (empty for a PASS)."""
    if result.verdict is Verdict.PASS:
        return []
    cand = result.sources[result.candidate]
    baselines = [m for name, m in result.sources.items() if name != result.candidate
                 and m.kind in (BiasSourceKind.CONSTANT_FIRST_WINDOW, BiasSourceKind.DATASET)]
    steps = [lim.next_step for lim in limitations]
    if any(cand.prmse_m > b.prmse_m + result.config.tie_prmse_m for b in baselines):
        steps.append("position error: record more varied motion (accelerate along and rotate about every axis) so "
                     "the accelerometer bias separates from attitude and gravity; prefer a 6-DoF pose source "
                     "(motion capture) to position-only; check the accelerometer units ('biasgt inspect')")
    if any(cand.roe_deg > b.roe_deg + result.config.tie_roe_deg for b in baselines):
        steps.append("rotation error: check the gyro units and the pose-to-IMU rotation (recovery.json "
                     "T_imu_pose), and rotate more about every axis")
    if cand.windows and float(np.mean(cand.flagged)) > result.config.warn_flagged_fraction:
        steps.append("many flagged windows: look at them in the quality report (pose outliers, IMU glitches); "
                     "recover with a robust loss ('--robust cauchy') if the poses have outliers")
    if result.windows_dropped.get("fraction", 0.0) > result.config.warn_dropped_fraction:
        steps.append("many dropped windows: close the IMU gaps or cover the whole IMU span with poses "
                     "(windows_dropped.by_reason in validation.json says which)")
    return said_once(steps)


def said_once(steps: Sequence_[str]) -> list[str]:
    """``steps`` without repeats: a step that another repeats with more words is kept the longer way."""
    steps = list(dict.fromkeys(steps))
    return [s for s in steps if not any(o != s and o.startswith(s) for o in steps)]
