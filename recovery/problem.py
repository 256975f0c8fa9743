"""The recovery problem: the cleaned pose stream, the IMU pieces between gaps, keyframes and their
samples for any window and clock offset, the calibration window, and the warm starts between solves.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pipeline.checks.rig import placeholder_rows
from pipeline.errors import RecoveryError
from pipeline.io import select_pose_stream
from pipeline.types import GRAVITY_MPS2, NS_PER_S, ImuSeries, PoseSeries, Sequence
from recovery.config import (
    ImuGapPolicy,
    RecoveryConfig,
)
from recovery.solver.fusion import fuse_poses
from recovery.solver.graph import solve_window
from recovery.solver.initial import gyro_keyframe_rotations, propagate_orientations
from recovery.solver.window import KeyframePoses, SolveOptions, WindowInit, WindowSolution
from recovery.solver.preintegration import ImuNoise, MidpointSamples, midpoint_samples
from recovery.solver.segments import plan_segments, stitch

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- input handling


def select_stream(sequence: Sequence, pose_stream: str | None) -> tuple[str, PoseSeries]:
    """The pose stream to fit: ``pose_stream``, else the io package's default priority."""
    return select_pose_stream(sequence, pose_stream)


def clean_poses(poses: PoseSeries, name: str, warnings: list[str]) -> tuple[PoseSeries, np.ndarray]:
    """The stream without non-finite samples and placeholder frames (origin with the identity orientation:
    an occluded tracker's, :func:`pipeline.checks.rig.placeholder_rows`), quaternions normalised; and the
    placeholders' stamps (int64, pose clock), rejected as outliers.

    Raises:
        RecoveryError: The stamps do not increase strictly.
    """
    ok = np.isfinite(poses.p_m).all(axis=1)
    if poses.quat_wxyz is not None:
        ok &= np.isfinite(poses.quat_wxyz).all(axis=1)
        norms = np.linalg.norm(np.where(np.isfinite(poses.quat_wxyz), poses.quat_wxyz, 0.0), axis=1)
        ok &= norms > 0.5
    if not ok.all():
        warnings.append(f"pose stream '{name}': dropped {int((~ok).sum())} non-finite samples")
        poses = poses.take(ok)
    placeholders = placeholder_rows(poses)
    placeholder_t_ns = poses.t_ns[placeholders]
    if placeholders.any():
        t0 = int(poses.t_ns[0])
        warnings.append(f"pose stream '{name}': rejected {int(placeholders.sum())} placeholder frames (origin with "
                        f"the identity orientation: the tracker lost the body) at t="
                        f"{(placeholder_t_ns[0] - t0) / NS_PER_S:.3f}..{(placeholder_t_ns[-1] - t0) / NS_PER_S:.3f} s")
        poses = poses.take(~placeholders)
    if len(poses) >= 2 and not (np.diff(poses.t_ns) > 0).all():
        raise RecoveryError(f"pose stream '{name}' stamps are not strictly increasing",
                            hint="run 'biasgt convert' (it sorts and deduplicates when allowed)")
    if poses.quat_wxyz is not None:
        q = poses.quat_wxyz / np.linalg.norm(poses.quat_wxyz, axis=1, keepdims=True)
        poses = PoseSeries(poses.t_ns, poses.p_m, q, poses.frame, poses.source_kind, poses.world_frame)
    return poses, placeholder_t_ns


def imu_pieces(imu: ImuSeries, config: RecoveryConfig, warnings: list[str]) -> list[tuple[int, int]]:
    """Gap-free spans of the IMU ``[(t0_ns, t1_ns)]``."""
    dt = np.diff(imu.t_ns)
    if not (dt > 0).all():
        raise RecoveryError("IMU stamps are not strictly increasing",
                            hint="run 'biasgt convert' (it sorts and deduplicates when allowed)")
    if not (np.isfinite(imu.gyro_radps).all() and np.isfinite(imu.acc_mps2).all()):
        raise RecoveryError("IMU readings contain non-finite values", hint="run 'biasgt inspect' on the input")
    limit = int(config.max_imu_gap_s * NS_PER_S)
    gaps = np.nonzero(dt > limit)[0]
    if len(gaps) and config.imu_gap_policy == ImuGapPolicy.REFUSE:
        g = gaps[0]
        raise RecoveryError(
            f"IMU gap of {dt[g] / NS_PER_S:.3f} s at t_ns={int(imu.t_ns[g])} exceeds max_imu_gap_s={config.max_imu_gap_s}",
            hint="raise max_imu_gap_s or set imu_gap_policy: split")
    bounds = [0, *(gaps + 1).tolist(), len(imu.t_ns)]
    pieces = [(int(imu.t_ns[a]), int(imu.t_ns[b - 1])) for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= 2]
    for g in gaps:
        warnings.append(f"IMU gap of {dt[g] / NS_PER_S:.3f} s at t_ns={int(imu.t_ns[g])}: recording split there "
                        "(no bias across the gap)")
    return pieces


def shifted_stamps(poses: PoseSeries, offset_s: float) -> np.ndarray:
    return poses.t_ns + int(round(offset_s * NS_PER_S))


def _select_keyframes(t_ns: np.ndarray, rate_hz: float | None, t_origin_ns: int) -> np.ndarray:
    """Indices of the keyframes: all, or the first sample of each 1/rate bin (global grid)."""
    if rate_hz is None:
        return np.arange(len(t_ns))
    period = NS_PER_S / rate_hz
    bins = np.floor((t_ns - t_origin_ns) / period).astype(np.int64)
    _, first = np.unique(bins, return_index=True)
    return first


FUSED_KEYFRAME_RATE_HZ = 10.0  # keyframe_rate_hz null + pose_fusion: bins of this rate (same accuracy as
# 20 Hz or every sample on the clean/hard benchmarks, half the keyframes of 20 Hz)


class Problem:
    """Pose stream + IMU; builds windows (IMU samples + keyframes) at a given clock offset.

    With ``fuse`` (6-DoF absolute streams), the pose samples of each keyframe bin are fused
    into the keyframe through the IMU (:mod:`recovery.solver.fusion`), linearised at the extrinsic,
    gravity and bias set by :meth:`set_linearisation`; otherwise a keyframe is one sample.
    """

    def __init__(self, imu: ImuSeries, poses: PoseSeries, pieces: list[tuple[int, int]], fuse: bool = False,
                 gravity_mps2: float = GRAVITY_MPS2) -> None:
        self.imu = imu
        self.imu_6 = imu.imu_6
        self.poses = poses
        self.pieces = pieces
        self.origin = int(imu.t_ns[0])
        self.fuse = fuse
        self.T_imu_pose = np.eye(4)
        self.gravity_world = np.array([0.0, 0.0, -gravity_mps2])
        self.gravity_mps2 = gravity_mps2
        self.bias: Any = None  # None, [6] (gyro, acc), or a function t_ns [M] -> [M, 6]

    def set_linearisation(self, *, T_imu_pose: np.ndarray | None = None, gravity_unit: np.ndarray | None = None,
                          bias: Any = None) -> None:
        """Extrinsic, gravity direction and bias the fusion moves samples with (unchanged if None)."""
        if T_imu_pose is not None:
            self.T_imu_pose = np.asarray(T_imu_pose, dtype=float).copy()
        if gravity_unit is not None:
            u = np.asarray(gravity_unit, dtype=float)
            self.gravity_world = u / np.linalg.norm(u) * self.gravity_mps2
        if bias is not None:
            self.bias = bias

    def window(self, offset_s: float, t0_ns: int, t1_ns: int, rate_hz: float | None
               ) -> tuple[MidpointSamples, KeyframePoses] | None:
        t = shifted_stamps(self.poses, offset_s)
        piece = next(((a, b) for a, b in self.pieces if a <= t0_ns <= b or a <= t1_ns <= b), None)
        if piece is None:
            return None
        lo, hi = max(t0_ns, piece[0]), min(t1_ns, piece[1])
        sel = np.nonzero((t > lo) & (t < hi))[0]
        if len(sel) < 3:
            return None
        if self.fuse and rate_hz is None:
            rate_hz = FUSED_KEYFRAME_RATE_HZ
        if self.fuse:
            # whole bins only: a keyframe in two overlapping windows fuses the same samples
            period = NS_PER_S / rate_hz
            b = np.floor((t[sel] - self.origin) / period)
            sel = sel[(b >= math.ceil((lo - self.origin) / period)) & (b < math.floor((hi - self.origin) / period))]
            if len(sel) < 3:
                return None
            bias = self.bias(t[sel]) if callable(self.bias) else self.bias
            fused = fuse_poses(t[sel], self.poses.p_m[sel], self.poses.quat_wxyz[sel], self.imu.t_ns, self.imu_6,
                               rate_hz, self.origin, self.T_imu_pose, self.gravity_world, bias)
            if len(fused) < 3:
                return None
            kf = KeyframePoses.from_fused(fused, self.poses.source_kind)
        else:
            sel = sel[_select_keyframes(t[sel], rate_hz, self.origin)]
            if len(sel) < 3:
                return None
            kf = KeyframePoses(t[sel], self.poses.p_m[sel],
                               None if self.poses.quat_wxyz is None else self.poses.quat_wxyz[sel],
                               self.poses.source_kind)
        kf = kf.with_gap_keyframes()  # pose pauses: keyframes without pose factors (recovery.solver.gaps)
        return midpoint_samples(self.imu.t_ns, self.imu_6, kf.t_ns), kf


#: A calibration window whose pose stream pauses longer than this is taken only when no other is left.
CALIBRATION_MAX_POSE_GAP_S = 1.0


def calibration_window(imu: ImuSeries, pieces: list[tuple[int, int]], overlap: tuple[int, int],
                        length_s: float, pose_t_ns: np.ndarray | None = None) -> tuple[int, int]:
    """The ``length_s`` window (inside one IMU piece and the pose overlap) with the most rotation,
    among those where the poses (``pose_t_ns``, IMU clock) never pause longer than
    :data:`CALIBRATION_MAX_POSE_GAP_S` when there are such (else the one with the shortest pause):
    a pose gap is a stretch the calibration solves cannot see."""
    best, best_score = None, (-np.inf, -1.0)
    w2 = np.sum(imu.gyro_radps**2, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(w2)])
    for a, b in pieces:
        a, b = max(a, overlap[0]), min(b, overlap[1])
        if b <= a:
            continue
        L = int(length_s * NS_PER_S)
        if b - a <= L:
            cand = [(a, b)]
        else:
            starts = np.linspace(a, b - L, num=max(2, int((b - a - L) / NS_PER_S) + 1)).astype(np.int64)
            cand = [(int(s), int(s) + L) for s in starts]
        for s, e in cand:
            i0, i1 = np.searchsorted(imu.t_ns, [s, e])
            gap_s = _longest_pause_s(pose_t_ns, s, e) if pose_t_ns is not None else 0.0
            score = (-max(gap_s, CALIBRATION_MAX_POSE_GAP_S), cum[i1] - cum[i0])
            if score > best_score:
                best, best_score = (s, e), score
    if best is None:
        raise RecoveryError("no time overlap between the IMU and the pose stream")
    return best


def _longest_pause_s(t_ns: np.ndarray, start_ns: int, end_ns: int) -> float:
    """The longest stretch of ``[start_ns, end_ns]`` without a stamp of ``t_ns`` (sorted), seconds."""
    i0, i1 = np.searchsorted(t_ns, [start_ns, end_ns])
    edges = np.concatenate([[start_ns], t_ns[i0:i1], [end_ns]])
    return float(np.max(np.diff(edges)) / NS_PER_S)



def continue_from(prev: WindowSolution, w: tuple[MidpointSamples, KeyframePoses],
                   gravity_unit: np.ndarray, imu: tuple[np.ndarray, np.ndarray] | None = None) -> WindowInit:
    """Initial values of a position-only segment from another segment's solution ``prev``.

    Orientation is the weak direction of position-only sources: a segment started from
    the closed-form guess can settle in a wrong minimum (a tilted attitude explained by a
    large gyro bias). Keyframes within ``prev``'s span take its solution (interpolated in time);
    the others are propagated from the nearest of them with the gyro minus ``prev``'s bias there.
    A segment wholly after ``prev`` (their overlap in a pose gap) starts from ``prev``'s last
    orientation carried forward by ``imu`` (stamps int64 [N], readings [N, 6] gyro then acc);
    otherwise, or without ``imu``, from the closed-form guess.
    """
    samples, kf = w
    K = len(kf)
    q = np.zeros((K, 4))
    q[:, 0] = 1.0
    known = (kf.t_ns >= prev.t_ns[0]) & (kf.t_ns <= prev.t_ns[-1])
    x, xq = (prev.t_ns - prev.t_ns[0]).astype(float), (kf.t_ns - prev.t_ns[0]).astype(float)
    bias = np.stack([np.interp(xq, x, prev.bias[:, c]) for c in range(6)], axis=1)
    if known.any():
        q[known] = Slerp(x, Rotation.from_quat(prev.quat_wxyz, scalar_first=True))(xq[known]).as_quat(scalar_first=True)
        edge_bias = bias[np.nonzero(known)[0][-1]]
    elif imu is not None and prev.t_ns[-1] < kf.t_ns[0]:
        edge_bias = prev.bias[-1]
        across = midpoint_samples(imu[0], imu[1], np.array([prev.t_ns[-1], kf.t_ns[0]], dtype=np.int64))
        rel = gyro_keyframe_rotations(across, edge_bias[:3])[1]
        q[0] = (Rotation.from_quat(prev.quat_wxyz[-1], scalar_first=True) * rel).as_quat(scalar_first=True)
        known[0] = True
        bias[:] = edge_bias
    else:
        return WindowInit(gravity_unit=gravity_unit)
    q = propagate_orientations(samples, q, known, edge_bias[:3])
    return WindowInit(gravity_unit=gravity_unit, bias=bias, rot_wxyz=q)


def chained_solution(problem: "Problem", offset_s: float, win: tuple[int, int], rate_hz: float | None,
                      imu_noise: ImuNoise, T: np.ndarray, opts: SolveOptions, gravity_unit: np.ndarray,
                      piece_s: float, overlap_s: float, seed: WindowSolution | None = None) -> Any:
    """Position-only streams: an initial guess over a long window, by consecutive shorter solves.

    One graph over minutes of positions, started from the closed-form attitude guess, can settle
    in a wrong attitude minimum (its pose residuals stay at a few sigma);
    solves of ``piece_s`` chained by :func:`continue_from` (as the segments are) do not. The
    first solve starts from ``seed`` (a solution inside ``win``, e.g. the calibration window's)
    where given: the closed-form guess fails more easily where the positions pause.

    Returns:
        The stitched solutions (``t_ns``, ``quat_wxyz``, ``bias``, ``v_mps``), or None.
    """
    o = replace(opts, compute_marginals=False, marginal_extras=False, reject_outliers=False)
    sols: list[WindowSolution] = []
    for s_ns, e_ns in plan_segments(win[0], win[1], piece_s, overlap_s):
        w = problem.window(offset_s, s_ns, e_ns, rate_hz)
        if w is None or len(w[1]) < 3:
            continue
        prev = sols[-1] if sols else seed
        init = (continue_from(prev, w, gravity_unit, (problem.imu.t_ns, problem.imu_6)) if prev is not None
                else WindowInit(gravity_unit=gravity_unit))
        sols.append(solve_window(w[0], w[1], imu_noise, T, o, init))
    return stitch(sols) if sols else None


COARSE_OFFSET_SPAN_S = 600.0  # the coarse clock offset looks at most this much of the recording



def bias_guess(t_ns: np.ndarray, coarse: WindowSolution | None, prev: WindowSolution | None) -> np.ndarray | None:
    """Initial bias of a full-rate segment, [K, 6]: the previous segment's solution where it
    reaches, else the decimated gravity solve (interpolated; held constant past either's end).

    Started from zero bias, LM spends its first iterations moving every keyframe's bias
    (and the preintegration's linearisation point is off by the bias); from this guess
    it converges in fewer iterations.
    """
    out = None
    for sol in (coarse, prev):
        if sol is None or len(sol.t_ns) < 2:
            continue
        x = (sol.t_ns - sol.t_ns[0]).astype(float)
        xq = (t_ns - sol.t_ns[0]).astype(float)
        b = np.stack([np.interp(xq, x, sol.bias[:, c]) for c in range(6)], axis=1)
        if out is None:
            out = b
        else:  # prev overrides where it reaches, and past the coarse solve's end
            use = (t_ns <= sol.t_ns[-1]) | (t_ns > coarse.t_ns[-1])
            out[use] = b[use]
    return out
