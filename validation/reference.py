"""Reference states for validation: a full state, or a pose stream moved onto the IMU clock and into the
IMU frame, its velocity from one smoothing spline (see docs/validation.md for the cutoff choice).
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.spatial.transform import Rotation, Slerp

from pipeline.errors import BiasgtError, DataError, ValidationError
from pipeline.geometry.pose_transform import as_transform, poses_in_imu_frame
from pipeline.io import select_pose_stream
from pipeline.types import (NS_PER_S, PoseSeries, Sequence,
                            StateSeries)
from recovery.outputs import RecoveryOutputs
from validation.config import ValidationConfig

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- reference kinds


class ReferenceKind(str, enum.Enum):
    """Where the reference start/end states come from."""

    STATE = "state"  # a full state (p, q, v): EuRoC ground truth, simulator truth
    POSES = "poses"  # a pose stream; velocity from a smoothing spline



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


def check_increasing(t_ns: np.ndarray, what: str) -> None:
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
    check_increasing(src_t, "ground-truth")
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
    tests/validate/test_validation.py). Fitted on up to three 2000-sample segments for speed. Noise-free
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
    check_increasing(poses.t_ns, "pose")
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
