"""Validation of a bias trajectory by 1-second integration error (AirIMU's metrics).

A recovered bias is "ground truth" only if removing it from the IMU makes short strapdown
integrations land where the reference trajectory says they should. This module reproduces
the evaluation of AirIMU (haleqiu/AirIMU, ``evaluation``): the IMU is cut into windows of
``window_s`` (default 1 s), each window is integrated from the reference position, velocity
and orientation at its first sample with ``imu - bias`` and gravity, and the end state is
compared with the reference at its last sample:

    pos_err  = |p_end - p_ref_end|                          [m]
    rot_err  = |Log(R_ref_end^T R_end)|                     [deg]
    PRMSE    = sqrt(mean over windows of pos_err^2)         [m]
    ROE      = mean over windows of rot_err                 [deg]

Integration goes through :func:`pipeline.integration.integrate` (the project's one
integrator, MIDPOINT scheme by default), in float64, batched by chunks of windows.

Reference states (:class:`ReferenceStates`, :class:`ReferenceKind`)
    STATE: a full state (EuRoC ground truth, simulator truth) interpolated to the IMU stamps:
    linear in p and v, Slerp in R.
    POSES: a pose stream when there is no full state. Poses are moved onto the IMU clock
    (``t_imu = t_pose + pose_time_offset_s``) and into the IMU frame
    (``T_world_imu = T_world_pose @ inv(T_imu_pose)``) by
    :func:`pipeline.pose_transform.poses_in_imu_frame`. Position and velocity come from ONE
    smoothing spline per sequence (:func:`scipy.interpolate.make_smoothing_spline`, penalty
    ``lam * int p''^2``), differentiated for v: a finite difference of 0.5-mm mocap noise at
    100 Hz has ~0.1 m/s of noise, i.e. 10 cm of error after 1 s, far above any bias effect.
    The penalty is set from a cutoff frequency f_c (for samples ``h`` s apart the spline acts
    like ``1 / (1 + (f / f_c)^4)``, so ``lam = 1 / (h (2 pi f_c)^4)``); GCV is not used (about
    80 s for 30 000 samples). f_c is chosen by the discrepancy principle: the position noise
    sigma is estimated from third differences (robust MAD), and f_c is the lowest value of a
    grid (0.5 ... 30 Hz) whose fit residual RMS is <= sigma. Velocity RMS error measured on
    the simulator against the true state (60 s, seed 3, clock offset 12.3 ms, 5 deg / 8 cm
    extrinsic, rotation noise = position noise in rad; a sweep of ``simulate`` +
    :func:`reference_from_poses`; tests/test_validation.py::test_pose_reference_velocity_error
    checks the handheld 100 Hz / 0.5 mm case on 20 s):

        motion            pose rate, noise     chosen f_c   v error     p error
        handheld          100 Hz, 0.5 mm       3 Hz         3.7 mm/s    0.23 mm
        handheld          200 Hz, 0.5 mm       3 Hz         3.4 mm/s    0.17 mm
        handheld          100 Hz, 2 mm         2 Hz         7.4 mm/s    0.74 mm
        aggressive_drone  100 Hz, 0.5 mm       5 Hz         9.4 mm/s    0.32 mm
        aggressive_drone  100 Hz, 2 mm         3 Hz        21.2 mm/s    1.25 mm
        slow_cart         100 Hz, 0.5 mm       1.5 Hz       1.8 mm/s    0.17 mm

    each within one grid step of the best fixed cutoff (a fixed 2 Hz gives 40 mm/s on the
    drone; a fixed 10 Hz gives 13 mm/s on the handheld). ``velocity_cutoff_hz`` fixes f_c.
    Rotation is Slerp of the raw poses (0.5 mrad of rotation noise puts a floor of ~0.03 deg
    under every source's ROE). Stamps inside a pose gap (> ``reference_gap_factor`` x the median pose interval)
    have no reference.

Windows
    Samples ``[i, i + n]`` with ``n = round(window_s * rate)`` and a stride of
    ``round(n * (1 - overlap))`` samples. A window is dropped (and counted, under every reason
    that applies) when it crosses an IMU gap (an interval > ``gap_factor`` x the nominal one),
    holds a non-finite IMU sample, has no reference at either end, or is not covered by one of
    the bias sources. All sources are compared on the SAME windows.

Bias sources (:class:`BiasSourceKind`)
    ZERO; CONSTANT_FIRST_WINDOW (the candidate's mean bias over the first kept window, held
    constant: what a calibration at start-up would give); DATASET (the sequence's own
    ground-truth bias); RECOVERED (the recovery's ``bias.csv``); FILE (any other bias file).
    The *candidate* judged by the verdict is the first RECOVERED source, else the first FILE
    source, else DATASET.

Quality flags
    Per source, a window is flagged when ``pos_err > max(k * median(pos_err), flag_min_pos_m)``
    or ``rot_err > max(k * median(rot_err), flag_min_rot_deg)`` (default k = 5; the floors,
    1 mm and 0.01 deg, keep noise-free simulations from flagging integrator round-off).

Verdict (:class:`Verdict`) per sequence, reasons in plain words
    FAIL when the candidate's PRMSE or ROE is worse than a baseline's (CONSTANT_FIRST_WINDOW,
    and DATASET when present) by more than ``margin`` (default 10 %), i.e.
    ``cand > base * (1 + margin) + tie``;
    WARN when it is worse but within that margin (``base + tie < cand <= base*(1+margin)+tie``),
    or more than ``warn_flagged_fraction`` (5 %) of the candidate's windows are flagged, or more
    than ``warn_dropped_fraction`` (20 %) of the windows were dropped;
    PASS otherwise. ``tie`` (``tie_prmse_m`` = 0.1 mm, ``tie_roe_deg`` = 0.001 deg) makes
    differences below measurement resolution count as equal.
"""

from __future__ import annotations

import enum
import json
import logging
import math
from collections.abc import Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from scipy.interpolate import make_smoothing_spline
from scipy.spatial.transform import Rotation, Slerp

from interpolation.bias import BiasTrack, interpolate_bias, read_bias_csv
from pipeline.atomic import atomic_dir, atomic_path
from pipeline.errors import BiasgtError, DataError, InputFormatError, ValidationError
from pipeline.integration import IntegrationScheme, integrate
from pipeline.pose_transform import as_transform, poses_in_imu_frame, transform_from_json
from pipeline.so3 import rotation_angle_deg
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, Sequence, StateSeries

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
VALIDATION_JSON = "validation.json"
WINDOWS_PARQUET = "windows.parquet"
DEFAULT_GRAVITY_MPS2 = (0.0, 0.0, -9.81)

__all__ = [
    "BiasSource",
    "BiasSourceKind",
    "RecoveryInfo",
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
    "read_recovery_dir",
    "recovered_bias_at_imu",
    "reference_from_poses",
    "reference_from_states",
    "roe_deg",
    "validate_inputs",
    "validate_sequence",
    "window_end_errors",
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


class Verdict(str, enum.Enum):
    """Outcome of a validation (see the module docstring for the rules)."""

    PASS = "PASS"
    WARN = "WARN"
    FAIL = "FAIL"


@dataclass(frozen=True)
class ValidationConfig:
    """Knobs of the validation (every default is documented in the module docstring).

    Attributes:
        window_s: Window length (s).
        overlap: Fraction of a window shared with the next, in [0, 1) (0.5: stride window_s/2).
        gap_factor: An IMU interval longer than this times the nominal one is a gap.
        flag_k: A window is flagged above ``flag_k`` x the source's median error.
        flag_min_pos_m / flag_min_rot_deg: Floors of the flag thresholds.
        margin: Relative margin of the FAIL rule (0.10 = 10 %).
        tie_prmse_m / tie_roe_deg: Differences below these count as equal.
        warn_flagged_fraction: WARN above this fraction of flagged candidate windows.
        warn_dropped_fraction: WARN above this fraction of dropped windows.
        chunk_windows: Windows per batched integration call.
        scheme: Integration scheme (MIDPOINT, second order).
        include_zero / include_constant / include_dataset: Add these sources automatically.
        velocity_cutoff_hz: Smoothing-spline cutoff of a POSES reference (None: automatic).
        reference_gap_factor: A reference interval longer than this times its median one is a gap.
    """

    window_s: float = 1.0
    overlap: float = 0.5
    gap_factor: float = 2.0
    flag_k: float = 5.0
    flag_min_pos_m: float = 1e-3
    flag_min_rot_deg: float = 1e-2
    margin: float = 0.10
    tie_prmse_m: float = 1e-4
    tie_roe_deg: float = 1e-3
    warn_flagged_fraction: float = 0.05
    warn_dropped_fraction: float = 0.20
    chunk_windows: int = 2048
    scheme: IntegrationScheme = IntegrationScheme.MIDPOINT
    include_zero: bool = True
    include_constant: bool = True
    include_dataset: bool = True
    velocity_cutoff_hz: float | None = None
    reference_gap_factor: float = 4.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "scheme", IntegrationScheme(self.scheme))
        checks = (
            ("window_s", self.window_s > 0, "give a positive window length in seconds"),
            ("overlap", 0.0 <= self.overlap < 1.0, "give an overlap in [0, 1), e.g. 0.5"),
            ("gap_factor", self.gap_factor > 1.0, "give a factor > 1, e.g. 2"),
            ("flag_k", self.flag_k > 1.0, "give a factor > 1, e.g. 5"),
            ("margin", self.margin >= 0.0, "give a relative margin >= 0, e.g. 0.1"),
            ("chunk_windows", self.chunk_windows >= 1, "give a positive number of windows"),
            ("velocity_cutoff_hz", self.velocity_cutoff_hz is None or self.velocity_cutoff_hz > 0,
             "give a positive frequency (Hz) or None for the automatic choice"),
            ("reference_gap_factor", self.reference_gap_factor > 1.0, "give a factor > 1, e.g. 4"),
        )
        for name, ok, hint in checks:
            if not ok:
                raise ValidationError(f"invalid {name} = {getattr(self, name)!r}", field=name, hint=hint)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["scheme"] = self.scheme.value
        return d


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


@dataclass(frozen=True)
class RecoveryInfo:
    """What validation takes from a recovery output folder (``recovery.json``).

    Attributes:
        path: The folder.
        bias_csv: ``DIR/bias.csv``.
        time_offset_s: ``pose_time_offset_s`` (seconds to add to pose stamps).
        T_imu_pose: 4x4 ``T_imu_pose``.
        gravity_mps2: ``gravity_world_mps2`` [3] or None.
        random_walk: Bias random walks used, [6] (gyro x3, acc x3), or None.
        pose_stream: The pose stream the recovery used, if named.
        report: The whole ``recovery.json``.
    """

    path: Path
    bias_csv: Path
    time_offset_s: float
    T_imu_pose: np.ndarray
    gravity_mps2: np.ndarray | None
    random_walk: np.ndarray | None
    pose_stream: str | None
    report: dict[str, Any]


def _parse_T(value: Any, path: Path) -> np.ndarray:
    try:
        return transform_from_json(value)
    except DataError as exc:
        raise ValidationError(f"cannot read T_imu_pose ({exc})", path=path, field="T_imu_pose",
                              hint="give a 4x4 matrix or {p_m, quat_wxyz}") from None


def read_recovery_dir(path: str | Path) -> RecoveryInfo:
    """Read ``DIR/recovery.json`` (offset, extrinsic, gravity, random walks) and locate ``DIR/bias.csv``.

    Raises:
        InputFormatError: Missing folder/files or unreadable JSON.
    """
    path = Path(path)
    rj, bias = path / "recovery.json", path / "bias.csv"
    for f in (rj, bias):
        if not f.is_file():
            raise InputFormatError(f"recovery output lacks {f.name}", path=path,
                                   hint="give the folder written by 'biasgt recover --out DIR'")
    try:
        report = json.loads(rj.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputFormatError(f"cannot read recovery.json ({exc})", path=rj, hint="re-run the recovery") from None
    if not isinstance(report, dict):
        raise InputFormatError("recovery.json is not a JSON object", path=rj, hint="re-run the recovery")
    noise = report.get("noise") if isinstance(report.get("noise"), dict) else {}
    rw = None
    g_rw = noise.get("gyro_random_walk", report.get("gyro_random_walk"))
    a_rw = noise.get("acc_random_walk", report.get("acc_random_walk"))
    if g_rw is not None and a_rw is not None:
        rw = np.array([float(g_rw)] * 3 + [float(a_rw)] * 3)
    g = report.get("gravity_world_mps2")
    gravity = None if g is None else np.asarray(g, dtype=float).reshape(3)
    return RecoveryInfo(
        path=path,
        bias_csv=bias,
        time_offset_s=float(report.get("pose_time_offset_s", 0.0) or 0.0),
        T_imu_pose=_parse_T(report.get("T_imu_pose"), rj),
        gravity_mps2=gravity,
        random_walk=rw,
        pose_stream=report.get("pose_stream") if isinstance(report.get("pose_stream"), str) else None,
        report=report,
    )


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

    Accepted: the recovery contract ``bias.csv`` (``t_ns,bg_x,...,ba_z_std``) or an interpolated
    bias table (``.csv``/``.parquet``, same columns); a EuRoC/OpenVINS state CSV
    (``#time(ns),px,py,pz,qw,qx,qy,qz,vx,vy,vz,bwx,bwy,bwz,bax,bay,baz`` or EuRoC's
    ``state_groundtruth_estimate0/data.csv``), whose bias columns are used (std = 0).

    Raises:
        InputFormatError: Missing file or an unknown layout.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError("bias file does not exist", path=path, hint="check the path")
    if path.suffix == ".parquet" or "bg_x" in _header_line(path):
        return read_bias_csv(path)
    from pipeline.io.asl import read_asl_state_csv

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
    """A named bias trajectory and its role."""

    name: str
    kind: BiasSourceKind
    track: BiasTrack


def _infer_kind(name: str) -> BiasSourceKind:
    try:
        return BiasSourceKind(name.lower())
    except ValueError:
        return BiasSourceKind.FILE


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
            "flag_threshold_pos_m": float(self.flag_pos_m),
            "flag_threshold_rot_deg": float(self.flag_rot_deg),
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


def _window_errors(
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


def decide_verdict(
    metrics: Mapping[str, SourceMetrics],
    candidate: str,
    *,
    dropped_fraction: float,
    config: ValidationConfig = ValidationConfig(),
) -> tuple[Verdict, list[str]]:
    """PASS / WARN / FAIL of ``candidate`` against the baselines (rules in the module docstring).

    Baselines: every CONSTANT_FIRST_WINDOW and DATASET source other than the candidate.

    Returns:
        ``(verdict, reasons)``; reasons are plain sentences (empty for a clean PASS).
    """
    cand = metrics[candidate]
    fails: list[str] = []
    warns: list[str] = []
    baselines = [m for name, m in metrics.items() if name != candidate
                 and m.kind in (BiasSourceKind.CONSTANT_FIRST_WINDOW, BiasSourceKind.DATASET)]
    for base in baselines:
        for label, c, b, tie, unit in (
            ("PRMSE", cand.prmse_m, base.prmse_m, config.tie_prmse_m, "m"),
            ("ROE", cand.roe_deg, base.roe_deg, config.tie_roe_deg, "deg"),
        ):
            limit = b * (1.0 + config.margin) + tie
            rel = (c / b - 1.0) * 100.0 if b > 0 else float("inf")
            text = (f"'{candidate}' {label} {c:.4g} {unit} is {rel:+.1f} % against '{base.name}' "
                    f"({base.kind.value}) {b:.4g} {unit}")
            if c > limit:
                fails.append(f"{text}: worse by more than the {config.margin:.0%} margin")
            elif c > b + tie:
                warns.append(f"{text}: worse, within the {config.margin:.0%} margin")
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
        }


def _normalise_sources(sources: Mapping[str, BiasTrack | BiasSource]) -> list[BiasSource]:
    out = []
    for name, s in sources.items():
        if isinstance(s, BiasSource):
            out.append(BiasSource(name, s.kind, s.track))
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


def validate_sequence(
    sequence: Sequence,
    sources: Mapping[str, BiasTrack | BiasSource],
    *,
    reference: ReferenceStates | None = None,
    gravity_mps2: Any = DEFAULT_GRAVITY_MPS2,
    config: ValidationConfig = ValidationConfig(),
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
        gravity_mps2: Gravity in the reference's world frame, [3].
        config: Windows, flags and verdict thresholds.

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
    gravity = np.asarray(gravity_mps2, dtype=np.float64).reshape(-1)
    if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
        raise ValidationError(f"gravity must be a finite 3-vector, got {gravity_mps2!r}", field="gravity_mps2")
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
    for src in evaluated:
        pos, rot = _window_errors(imu, at_imu[src.name], reference, starts, plan.n, gravity, config)
        flagged, thr_p, thr_r = _flags(pos, rot, config)
        metrics[src.name] = SourceMetrics(
            src.name, src.kind, t0, pos, rot, prmse_m(pos), roe_deg(rot),
            flagged, thr_p, thr_r,
        )
        log.info("%-12s PRMSE %.4f m  ROE %.4f deg  (%d windows, %d flagged)", src.name,
                 metrics[src.name].prmse_m, metrics[src.name].roe_deg, len(pos), int(flagged.sum()))
    verdict, reasons = decide_verdict(metrics, candidate, dropped_fraction=dropped["fraction"], config=config)
    ref_info = {"kind": reference.kind.value, **reference.info}
    return ValidationResult(sequence.name, verdict, reasons, candidate, config, metrics, dropped, ref_info,
                            gravity, notes)


# ----------------------------------------------------------------------------- output


def _json_default(obj: Any) -> Any:
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def _write_files(result: ValidationResult, folder: Path, json_path: Path | None = None,
                 parquet_path: Path | None = None) -> None:
    text = json.dumps(result.to_dict(), indent=2, default=_json_default, allow_nan=True) + "\n"
    table = pa.Table.from_pandas(result.windows_frame(), preserve_index=False)
    pq.write_table(table, parquet_path or folder / WINDOWS_PARQUET)
    (json_path or folder / VALIDATION_JSON).write_text(text, encoding="utf-8")


def write_validation(result: ValidationResult, out_dir: str | Path) -> Path:
    """Write ``out_dir/validation.json`` and ``out_dir/windows.parquet`` atomically.

    A new or validation-only folder is replaced as a whole (:func:`atomic_dir`); a folder that
    holds other files (e.g. the recovery's) keeps them and gets both files through temporary
    siblings, ``validation.json`` renamed last.

    Returns:
        ``out_dir``.
    """
    out_dir = Path(out_dir)
    ours = {VALIDATION_JSON, WINDOWS_PARQUET}
    if not out_dir.exists() or (out_dir.is_dir() and {p.name for p in out_dir.iterdir()} <= ours):
        with atomic_dir(out_dir) as tmp:
            _write_files(result, tmp)
    else:
        if not out_dir.is_dir():
            raise ValidationError("output path exists and is not a folder", path=out_dir,
                                  hint="give a folder for --out")
        with atomic_path(out_dir / VALIDATION_JSON) as tj, atomic_path(out_dir / WINDOWS_PARQUET) as tp:
            _write_files(result, out_dir, tj, tp)
    return out_dir


# ----------------------------------------------------------------------------- reference selection


def build_reference(
    sequence: Sequence,
    *,
    pose_stream: str | None = None,
    recovery: RecoveryInfo | None = None,
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
    from pipeline.io import select_pose_stream

    if pose_stream is None and recovery is not None and recovery.pose_stream in sequence.poses:
        pose_stream = recovery.pose_stream
    try:
        name, poses = select_pose_stream(sequence, pose_stream)
    except BiasgtError as exc:
        raise ValidationError(f"no reference for sequence '{sequence.name}': {exc.problem}", field="poses",
                              hint=exc.hint) from None
    if recovery is not None and (recovery.pose_stream is None or recovery.pose_stream == name):
        # the recovery's extrinsic and clock offset belong to the stream it fitted
        T, offset = recovery.T_imu_pose, recovery.time_offset_s
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
    recovery: RecoveryInfo | None = None,
    bias_files: Sequence_[tuple[str | None, str | Path]] = (),
) -> dict[str, BiasSource]:
    """The bias sources of a validation: the recovery's bias and any bias files.

    The recovery's ``bias.csv`` becomes ``"recovered"`` (RECOVERED, interpolated to the IMU stamps
    with the recovery's random walks, else the calibration's). An unnamed file is the bias under
    test (``"recovered"``) when it is the first one and no recovery is given, else FILE named by
    its stem; a named one is FILE.

    Args:
        sequence: The sequence (its IMU stamps and calibration are used).
        recovery: From :func:`read_recovery_dir`, or None.
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
        rw = recovery.random_walk if recovery.random_walk is not None else rw_cal
        track = recovered_bias_at_imu(read_bias_csv(recovery.bias_csv), sequence.imu.t_ns, rw)
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

    Assembles the sources (:func:`bias_sources`), the gravity (``gravity_mps2``, else the
    recovery's estimate, else :data:`DEFAULT_GRAVITY_MPS2`) and the reference
    (:func:`build_reference`), then runs :func:`validate_sequence`. A FAIL verdict is a result,
    not an error.

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
    recovery = read_recovery_dir(recovery_dir) if recovery_dir is not None else None
    sources = bias_sources(sequence, recovery=recovery, bias_files=bias_files)
    if gravity_mps2 is not None:
        gravity = np.asarray(gravity_mps2, dtype=float)
    elif recovery is not None and recovery.gravity_mps2 is not None:
        gravity = recovery.gravity_mps2
    else:
        gravity = np.asarray(DEFAULT_GRAVITY_MPS2)
    reference = build_reference(sequence, pose_stream=pose_stream, recovery=recovery, config=config)
    result = validate_sequence(sequence, sources, reference=reference, gravity_mps2=gravity, config=config)
    if recovery is not None:
        result.notes.append(f"recovery: {recovery.path}")
        if result.reference.get("kind") == ReferenceKind.POSES.value and (
                recovery.pose_stream is None or result.reference.get("stream") == recovery.pose_stream):
            result.notes.append("the reference poses are presumably those the recovery fitted: errors of the poses "
                                "that the bias absorbed are not seen by this check (not an independent test)")
    return result
