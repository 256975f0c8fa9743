"""``recover(sequence) -> RecoveryResult``: bias ground truth by joint optimisation.

Stages (each logged; all results and choices land in ``recovery.json``):

1. checks: an IMU and a pose stream with enough samples, increasing stamps, a
   time overlap; IMU gaps longer than ``max_imu_gap_s`` split the recording
   (or are refused, ``imu_gap_policy``).
2. calibration window: the ``calib_window_s`` with the most rotation.
3. clock offset: coarse |omega| (or |f|) correlation from
   :mod:`recovery.calibration_init`, refined to sub-millisecond at the minimum of
   the optimised graph cost (Newton steps on its analytic slope and curvature for
   6-DoF absolute streams, else a parabola through three offsets); std from its curvature.
4. extrinsic ``T_imu_pose``: known (calibration) or initialised in closed form
   and refined jointly in the graph (``E(0)`` Pose3 for 6-DoF sources, ``L(0)``
   lever arm for position trackers) on a decimated window.
5. noise: bias random walks by maximum evidence (:mod:`recovery.noise`); pose sigmas
   in closed form from the scatter of fused samples (else by evidence too).
6. the full solve, by overlapping segments (bounded memory), with robust
   pose factors, outlier rejection, gravity direction and bias marginals
   that include the uncertainty of the estimated clock offset and extrinsic
   (:mod:`recovery.calibration_uncertainty`); stitched without seams
   (:mod:`recovery.segments`).

Keyframes: for 6-DoF absolute streams every pose sample is used through
10-Hz keyframes that fuse the samples of their bin (:mod:`recovery.fusion`,
linearised at the latest extrinsic / gravity / bias estimate); other streams use
one keyframe per sample. ``recovery.json`` also states the accuracy floor of the
noise at hand (:mod:`recovery.bounds`).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pipeline.bias_table import BiasTrack
from pipeline.checks import reader_warnings
from pipeline.errors import BiasgtError, RecoveryError
from pipeline.io import select_pose_stream
from pipeline.types import GRAVITY_MPS2, NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind, Sequence
from recovery.config import (
    DEFAULT_POSE_SIGMAS,
    CalibrationSolve,
    ExtrinsicMode,
    OffsetRefineMethod,
    ImuGapPolicy,
    IntrinsicsMode,
    NoiseEstimation,
    PoseFactorMode,
    PoseErrorMode,
    PoseSigmaMethod,
    RecoveryConfig,
    TimeOffsetMode,
)
from recovery import calibration_init as ci
from recovery.bounds import bias_rmse_floor
from recovery.extrinsic import CalibrationDifference, calibration_difference
from recovery.calibration_uncertainty import OFFSET_INDEX, CalibrationCovariance
from recovery.fusion import fuse_poses
from recovery.graph import KeyframePoses, SolveOptions, WindowInit, WindowSolution, propagate_orientations, solve_window
from recovery.noise import NoiseChoice, PoseErrorGrid, estimate_noise
from recovery.pose_error import PoseErrorModel
from recovery.outputs import RecoveryOutputs, RecoveryReport
from recovery.preintegration import ImuNoise, MidpointSamples, midpoint_samples
from recovery.segments import plan_segments, stitch

log = logging.getLogger(__name__)

IMU_FRAME_NAMES = ("imu", "imu0", "body", "base_link_imu")


@dataclass
class RecoveryResult:
    """Recovered bias and everything needed to judge it.

    Attributes:
        t_ns: Keyframe stamps on the IMU clock, int64 [K].
        bias_gyro_radps / bias_acc_mps2: [K, 3].
        bias_gyro_std_radps / bias_acc_std_mps2: Marginal 1-sigma, [K, 3].
        p_m / quat_wxyz / v_mps: Optimised IMU trajectory in the pose world frame, [K, 3] / [K, 4] / [K, 3].
        report: ``recovery.json`` (:class:`recovery.outputs.RecoveryReport`).
        residuals: Per keyframe [K]: ``pose_whitened_rms``, ``imu_whitened_rms`` (NaN where a keyframe
            has no such factor) and ``outlier`` (its pose was rejected); written as ``residuals.csv``.
    """

    t_ns: np.ndarray
    bias_gyro_radps: np.ndarray
    bias_acc_mps2: np.ndarray
    bias_gyro_std_radps: np.ndarray
    bias_acc_std_mps2: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    report: RecoveryReport
    residuals: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def warnings(self) -> list[str]:
        return list(self.report.warnings)

    def outputs(self) -> RecoveryOutputs:
        """What the output folder holds of this result (:class:`recovery.outputs.RecoveryOutputs`)."""
        t_ns = np.asarray(self.t_ns, dtype=np.int64)
        bias = BiasTrack(t_ns, np.hstack([self.bias_gyro_radps, self.bias_acc_mps2]).astype(float),
                         np.hstack([self.bias_gyro_std_radps, self.bias_acc_std_mps2]).astype(float))
        trajectory = PoseSeries(t_ns, self.p_m, self.quat_wxyz, "imu", PoseSourceKind.GROUND_TRUTH)
        residuals = None
        if self.residuals:
            residuals = pd.DataFrame({"t_ns": t_ns, **{k: np.asarray(v) for k, v in self.residuals.items()}})
        return RecoveryOutputs(bias, self.report, trajectory, residuals)

    def bias_at(self, t_ns: np.ndarray) -> np.ndarray:
        """Bias linearly interpolated at ``t_ns``, [M, 6] (gyro, acc); clamped at the ends."""
        b = np.hstack([self.bias_gyro_radps, self.bias_acc_mps2])
        x = (self.t_ns - self.t_ns[0]).astype(float)
        xq = (np.asarray(t_ns, dtype=np.int64) - self.t_ns[0]).astype(float)
        return np.stack([np.interp(xq, x, b[:, c]) for c in range(6)], axis=1)

    def std_at(self, t_ns: np.ndarray) -> np.ndarray:
        """Marginal bias std linearly interpolated at ``t_ns``, [M, 6]; clamped at the ends."""
        s = np.hstack([self.bias_gyro_std_radps, self.bias_acc_std_mps2])
        x = (self.t_ns - self.t_ns[0]).astype(float)
        xq = (np.asarray(t_ns, dtype=np.int64) - self.t_ns[0]).astype(float)
        return np.stack([np.interp(xq, x, s[:, c]) for c in range(6)], axis=1)


def write_recovery(result: RecoveryResult, out_dir: str | Path) -> Path:
    """Write the recovery folder of ``result`` atomically (:meth:`recovery.outputs.RecoveryOutputs.write`)."""
    return result.outputs().write(out_dir)


def agreement_z(a: RecoveryResult, b: RecoveryResult) -> np.ndarray:
    """|a - b| / sqrt(sigma_a^2 + sigma_b^2) at ``a``'s keyframes inside ``b``'s span, [M, 6].

    Used to check that two recoveries of one recording (e.g. from Leica positions and from
    ground-truth poses) agree within their combined uncertainty.
    """
    sel = (a.t_ns >= b.t_ns[0]) & (a.t_ns <= b.t_ns[-1])
    t = a.t_ns[sel]
    ba = np.hstack([a.bias_gyro_radps, a.bias_acc_mps2])[sel]
    sa = np.hstack([a.bias_gyro_std_radps, a.bias_acc_std_mps2])[sel]
    return np.abs(ba - b.bias_at(t)) / np.sqrt(sa**2 + b.std_at(t) ** 2)


# ----------------------------------------------------------------------------- input handling


def _select_stream(sequence: Sequence, pose_stream: str | None) -> tuple[str, PoseSeries]:
    """The pose stream to fit: ``pose_stream``, else the io package's default priority."""
    return select_pose_stream(sequence, pose_stream)


def _clean_poses(poses: PoseSeries, name: str, warnings: list[str]) -> PoseSeries:
    ok = np.isfinite(poses.p_m).all(axis=1)
    if poses.quat_wxyz is not None:
        ok &= np.isfinite(poses.quat_wxyz).all(axis=1)
        norms = np.linalg.norm(np.where(np.isfinite(poses.quat_wxyz), poses.quat_wxyz, 0.0), axis=1)
        ok &= norms > 0.5
    if not ok.all():
        warnings.append(f"pose stream '{name}': dropped {int((~ok).sum())} non-finite samples")
        poses = poses.take(ok)
    if len(poses) >= 2 and not (np.diff(poses.t_ns) > 0).all():
        raise RecoveryError(f"pose stream '{name}' stamps are not strictly increasing",
                            hint="run 'biasgt convert' (it sorts and deduplicates when allowed)")
    if poses.quat_wxyz is not None:
        q = poses.quat_wxyz / np.linalg.norm(poses.quat_wxyz, axis=1, keepdims=True)
        poses = PoseSeries(poses.t_ns, poses.p_m, q, poses.frame, poses.source_kind, poses.world_frame)
    return poses


def _imu_pieces(imu: ImuSeries, config: RecoveryConfig, warnings: list[str]) -> list[tuple[int, int]]:
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


def _shifted_stamps(poses: PoseSeries, offset_s: float) -> np.ndarray:
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


class _Problem:
    """Pose stream + IMU; builds windows (IMU samples + keyframes) at a given clock offset.

    With ``fuse`` (6-DoF absolute streams), the pose samples of each keyframe bin are fused
    into the keyframe through the IMU (:mod:`recovery.fusion`), linearised at the extrinsic,
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
        t = _shifted_stamps(self.poses, offset_s)
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
        return midpoint_samples(self.imu.t_ns, self.imu_6, kf.t_ns), kf


#: A calibration window whose pose stream pauses longer than this is taken only when no other is left.
CALIBRATION_MAX_POSE_GAP_S = 1.0


def _calibration_window(imu: ImuSeries, pieces: list[tuple[int, int]], overlap: tuple[int, int],
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


# ----------------------------------------------------------------------------- offset


#: A Newton step on the clock offset longer than this many of its sigmas is taken again from where
#: it lands: one step from 0.1 ms away lands within 0.05 sigma of the parabola's vertex on the
#: benchmark and the hard simulated cases, and the error grows with the step.
OFFSET_NEWTON_MAX_SIGMAS = 2.0
OFFSET_NEWTON_MAX_SOLVES = 5  # then the parabola


@dataclass(frozen=True)
class _OffsetRefinement:
    """The refined clock offset and its 1-sigma, the solves (``recovery.json``
    ``pose_time_offset_search``), the last solve's gravity and median bias (a linearisation point
    for fusion), and the method."""

    offset_s: float
    std_s: float
    table: list[dict[str, float]]
    last: WindowInit | None
    method: OffsetRefineMethod


def _refine_offset(problem: _Problem, coarse_s: float, coarse_std_s: float, window: tuple[int, int], noise: ImuNoise, T: np.ndarray,
                   opts: SolveOptions, config: RecoveryConfig) -> _OffsetRefinement:
    """The offset at the minimum of the optimised graph cost, its std from the cost's curvature.

    Newton steps on the cost's analytic slope and curvature in the offset when the pose factors
    are 6-DoF absolute (:func:`recovery.calibration_uncertainty.parameter_slope_and_information`;
    one solve when the coarse offset lies within two sigmas); else, or when the steps do not
    settle, a 1-D search: a parabola through the cost at three offsets.
    """
    o = replace(opts, reject_outliers=False, compute_marginals=False, marginal_extras=False, residuals=False)
    rate = config.calibration_rate_hz(CalibrationSolve.OFFSET_REFINE, problem.fuse)
    newton = _newton_offset(problem, coarse_s, window, noise, T, o, rate, config.max_time_offset_s)
    if newton is not None:
        return newton
    cache: dict[int, float] = {}
    n_keyframes: dict[int, int] = {}
    init: dict[str, WindowInit] = {}

    def cost(off: float) -> float:
        key = int(round(off * 1e9))
        if key in cache:
            return cache[key]
        w = problem.window(off, window[0], window[1], rate)
        if w is None:
            c = float("inf")
        else:
            try:
                sol = solve_window(w[0], w[1], noise, T, o, init.get("x"))
                # normalise per keyframe: the keyframe set can change by one between offsets
                c = sol.cost / len(w[1]) * 1000.0
                n_keyframes[key] = len(w[1])
                init["x"] = WindowInit(gravity_unit=sol.gravity_unit, bias=np.median(sol.bias, axis=0))
            except BiasgtError:
                c = float("inf")
        cache[key] = c
        return c

    # 3-point grid around the coarse value (the cost is quadratic within +-2 coarse sigmas);
    # slide it while the minimum is at an edge
    h = float(np.clip(2.0 * coarse_std_s, config.offset_refine_step_s / 8, config.offset_refine_step_s))
    center = coarse_s
    grid_k = np.arange(-1, 2)
    for _ in range(12):
        xs = center + grid_k * h
        cs = np.array([cost(x) for x in xs])
        i = int(np.argmin(cs))
        if 0 < i < len(xs) - 1 or not np.isfinite(cs[i]):
            break
        center = xs[i]
    fine, fc = xs, cs
    ok = np.isfinite(fc)
    if ok.sum() < 3:
        raise RecoveryError("the clock-offset search found no finite cost")
    a, b, _ = np.polyfit(fine[ok], fc[ok], 2)
    table = [{"offset_s": float(k / 1e9), "cost_per_kkf": float(v)} for k, v in sorted(cache.items())]
    if a <= 0:
        return _OffsetRefinement(float(fine[int(np.argmin(fc))]), float(h), table, init.get("x"),
                                 OffsetRefineMethod.PARABOLA)
    vertex = float(-b / (2 * a))
    vertex = float(np.clip(vertex, fine[0], fine[-1]))
    # cost = 0.5 chi2 / K * 1000  -> d2(0.5 chi2)/d off2 = 2a K / 1000
    # keyframes at the evaluated offset nearest the vertex (a window more or less changes the std by < 1 %)
    n_kf = n_keyframes[min(n_keyframes, key=lambda k: abs(k / 1e9 - vertex))]
    curv = 2 * a * n_kf / 1000.0
    std = float(1.0 / math.sqrt(curv)) if curv > 0 else float(h)
    return _OffsetRefinement(vertex, std, table, init.get("x"), OffsetRefineMethod.PARABOLA)


def _newton_offset(problem: _Problem, coarse_s: float, window: tuple[int, int], noise: ImuNoise, T: np.ndarray,
                   opts: SolveOptions, rate: float, max_offset_s: float) -> _OffsetRefinement | None:
    """Newton steps on the clock offset from ``coarse_s`` (see :func:`_refine_offset`); None when
    the factors give no slope (not 6-DoF absolute), a solve fails, or the steps do not settle."""
    o = replace(opts, offset_sensitivity=True)
    offset, init, table = coarse_s, None, []
    for _ in range(OFFSET_NEWTON_MAX_SOLVES):
        w = problem.window(offset, window[0], window[1], rate)
        if w is None:
            return None
        try:
            sol = solve_window(w[0], w[1], noise, T, o, init)
        except BiasgtError:
            return None
        slope, information = sol.extras.get("offset_slope"), sol.extras.get("offset_information", 0.0)
        if slope is None or not information > 0:
            return None
        step, std = -slope / information, 1.0 / math.sqrt(information)
        table.append({"offset_s": float(offset), "cost_per_kkf": float(sol.cost / len(w[1]) * 1000.0),
                      "newton_step_s": float(step)})
        init = WindowInit(gravity_unit=sol.gravity_unit, bias=np.median(sol.bias, axis=0))
        offset += step
        if abs(offset - coarse_s) > max_offset_s:
            return None
        if abs(step) <= OFFSET_NEWTON_MAX_SIGMAS * std:
            return _OffsetRefinement(float(offset), float(std), table, init, OffsetRefineMethod.NEWTON)
    return None


# ----------------------------------------------------------------------------- extrinsic


def _rotation_excitation_deg(poses: PoseSeries) -> float:
    """Spread of the orientations: 2x the RMS angle from the mean orientation, degrees."""
    if poses.quat_wxyz is None or len(poses) < 3:
        return 0.0
    q = poses.quat_wxyz[:: max(1, len(poses) // 2000)]
    r = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]])
    mean = r.mean()
    ang = (mean.inv() * r).magnitude()
    return float(2.0 * np.degrees(np.sqrt(np.mean(ang**2))))


def _known_extrinsic(sequence: Sequence, poses: PoseSeries) -> np.ndarray | None:
    T = sequence.calibration.T_imu_frames.get(poses.frame)
    if T is not None:
        return np.asarray(T, dtype=float)
    if poses.frame.lower() in IMU_FRAME_NAMES or poses.source_kind == PoseSourceKind.GROUND_TRUTH:
        return np.eye(4)
    return None


def _matrix_to_dict(T: np.ndarray) -> dict[str, list[float]]:
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return {"p_m": [float(x) for x in T[:3, 3]], "quat_wxyz": [float(q[3]), float(q[0]), float(q[1]), float(q[2])]}


def _continue_from(prev: WindowSolution, w: tuple[MidpointSamples, KeyframePoses],
                   gravity_unit: np.ndarray) -> WindowInit:
    """Initial values of a position-only segment from the previous segment's solution.

    Orientation is the weak direction of position-only sources: a segment started from
    the closed-form guess can settle in a wrong minimum (a tilted attitude explained by a
    large gyro bias). Overlap keyframes take the previous solution; later ones are
    propagated with the gyro minus the previous bias.
    """
    samples, kf = w
    K = len(kf)
    q = np.zeros((K, 4))
    q[:, 0] = 1.0
    _, ia, ib = np.intersect1d(kf.t_ns, prev.t_ns, assume_unique=True, return_indices=True)
    known = np.zeros(K, dtype=bool)
    if len(ia) == 0 or ia[0] != 0:
        return WindowInit(gravity_unit=gravity_unit)
    q[ia] = prev.quat_wxyz[ib]
    known[ia] = True
    last_bias = prev.bias[ib[-1]]
    q = propagate_orientations(samples, q, known, last_bias[:3])
    bias = np.tile(last_bias, (K, 1))
    bias[ia] = prev.bias[ib]
    return WindowInit(gravity_unit=gravity_unit, bias=bias, rot_wxyz=q)


def _chained_solution(problem: "_Problem", offset_s: float, win: tuple[int, int], rate_hz: float | None,
                      imu_noise: ImuNoise, T: np.ndarray, opts: SolveOptions, gravity_unit: np.ndarray,
                      piece_s: float, overlap_s: float) -> Any:
    """Position-only streams: an initial guess over a long window, by consecutive shorter solves.

    One graph over minutes of positions, started from the closed-form attitude guess, can settle
    in a wrong attitude minimum (seen on EuRoC MH_01: 180 s at 10 Hz, pose residuals 2.4 sigma);
    solves of ``piece_s`` chained by :func:`_continue_from` (as the segments are) do not.

    Returns:
        The stitched solutions (``t_ns``, ``quat_wxyz``, ``bias``, ``v_mps``), or None.
    """
    o = replace(opts, compute_marginals=False, marginal_extras=False, reject_outliers=False)
    sols: list[WindowSolution] = []
    for s_ns, e_ns in plan_segments(win[0], win[1], piece_s, overlap_s):
        w = problem.window(offset_s, s_ns, e_ns, rate_hz)
        if w is None or len(w[1]) < 3:
            continue
        init = _continue_from(sols[-1], w, gravity_unit) if sols else WindowInit(gravity_unit=gravity_unit)
        sols.append(solve_window(w[0], w[1], imu_noise, T, o, init))
    return stitch(sols) if sols else None


COARSE_OFFSET_SPAN_S = 600.0  # the coarse clock offset looks at most this much of the recording


def _coarse_offset_inputs(imu: ImuSeries, poses: PoseSeries, pieces: list[tuple[int, int]],
                          max_offset_s: float) -> tuple[ImuSeries, PoseSeries]:
    """The IMU and poses of the ``COARSE_OFFSET_SPAN_S`` with the most rotation (long recordings).

    The correlation over a whole hour costs ~3 s and ~200 MB of temporaries for an offset that
    ten minutes of motion already pin down to a fraction of a sample (it is refined in the graph).
    """
    if (imu.t_ns[-1] - imu.t_ns[0]) / NS_PER_S <= 1.5 * COARSE_OFFSET_SPAN_S:
        return imu, poses
    overlap = (max(int(imu.t_ns[0]), int(poses.t_ns[0])), min(int(imu.t_ns[-1]), int(poses.t_ns[-1])))
    try:
        a, b = _calibration_window(imu, pieces, overlap, COARSE_OFFSET_SPAN_S)
    except RecoveryError:
        return imu, poses
    sel = (poses.t_ns >= a) & (poses.t_ns <= b)
    if sel.sum() < 100:
        return imu, poses
    margin = int((max_offset_s + 1.0) * NS_PER_S)
    i0, i1 = np.searchsorted(imu.t_ns, [a - margin, b + margin])
    return imu.take(slice(int(i0), int(i1))), poses.take(sel)


def _bias_guess(t_ns: np.ndarray, coarse: WindowSolution | None, prev: WindowSolution | None) -> np.ndarray | None:
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


# ----------------------------------------------------------------------------- main entry


def recover(sequence: Sequence, *, pose_stream: str | None = None,
            config: RecoveryConfig | None = None) -> RecoveryResult:
    """Recover the bias trajectory of ``sequence``'s IMU from one of its pose streams.

    Args:
        sequence: IMU + poses (+ calibration); anything :func:`pipeline.io.load_sequence` returns.
        pose_stream: Name of the pose stream; may be omitted when there is one.
        config: Options; defaults are meant to work without tuning.

    Returns:
        The bias per keyframe with marginal std, the optimised trajectory and the report.

    Raises:
        RecoveryError: The input cannot give a trustworthy result (one line saying why).
        AmbiguousInputError: The named pose stream does not exist (lists the streams).
        DataError: The sequence has no pose stream and no ground truth.
    """
    config = config or RecoveryConfig()
    try:
        if config.intrinsics is IntrinsicsMode.OFF or sequence.imu is None:
            return _recover(sequence, pose_stream=pose_stream, config=replace(config, intrinsics=IntrinsicsMode.OFF))
        from recovery.intrinsics import auto_intrinsics, recover_with_intrinsics

        plain = replace(config, intrinsics=IntrinsicsMode.OFF)
        first = _recover(sequence, pose_stream=pose_stream, config=plain)
        decision = auto_intrinsics(sequence, first) if config.intrinsics is IntrinsicsMode.AUTO else None
        if decision is not None and decision.mode is IntrinsicsMode.OFF:
            return decision.annotate(first)
        mode = config.intrinsics if decision is None else decision.mode
        result = recover_with_intrinsics(
            sequence, lambda seq: _recover(seq, pose_stream=pose_stream, config=plain),
            g_sensitivity=mode is IntrinsicsMode.WITH_G_SENSITIVITY, block_s=config.intrinsics_block_s, first=first)
        result = _record_intrinsics_mode(result, mode)
        return result if decision is None else decision.annotate(result)
    except (RuntimeError, ValueError) as exc:
        # GTSAM reports a singular (unobservable) problem as a bare RuntimeError, a factor graph
        # that a failed solve left inconsistent as a ValueError from its EliminationTree.
        text = str(exc)
        if not any(word in text for word in ("ndetermina", "ill-posed", "ingular", "EliminationTree")):
            raise
        first = text.strip().splitlines()[0] if text.strip() else "singular system"
        raise RecoveryError(
            f"sequence '{sequence.name}': the optimisation is degenerate ({first}); the motion does not "
            "make the bias, clock offset or extrinsic observable",
            hint=_ignored_units_hint(sequence) + degenerate_hint(sequence, pose_stream, config),
        ) from exc


#: Unit findings whose --ignore makes a degenerate solve likely.
_UNIT_CODES = ("GYRO_DEGPS", "ACC_IN_G")


def _ignored_units_hint(sequence: Sequence) -> str:
    """The first words of the hint when the user ignored a unit finding (likely the cause)."""
    from pipeline.checks import REPAIR_FOR_CODE

    ignored = list(dict.fromkeys(f.code for f in sequence.findings
                                 if f.code in _UNIT_CODES and f.details.get("ignored")))
    if not ignored:
        return ""
    repairs = ",".join(REPAIR_FOR_CODE[c].value for c in ignored)
    return (f"the units finding(s) {', '.join(ignored)} were ignored (--ignore) and are likely "
            f"real: rerun with --repair {repairs} instead; ")


#: Keyframe rate the degenerate-recovery hint suggests for relative (odometry, VIO) pose streams.
DEGENERATE_KEYFRAME_RATE_HZ = 10.0


def degenerate_hint(sequence: Sequence, pose_stream: str | None, config: RecoveryConfig) -> str:
    """The fixes of a degenerate recovery that apply to this case, most promising first: fewer keyframes
    for a relative (odometry, VIO) stream only when that lowers their rate; fixing the extrinsic and the
    clock offset only when they are still estimated; more varied motion always."""
    fixes = []
    try:
        _, poses = select_pose_stream(sequence, pose_stream)
    except BiasgtError:
        poses = None
    if poses is not None and poses.source_kind is PoseSourceKind.VIO and len(poses.t_ns) > 1:
        rate_hz = NS_PER_S / float(np.median(np.diff(poses.t_ns)))
        current = config.keyframe_rate_hz or rate_hz
        if current > 1.2 * DEGENERATE_KEYFRAME_RATE_HZ:
            fixes.append(f"use fewer keyframes for these odometry/VIO poses at {current:.0f} Hz "
                         f"(--keyframe-rate {DEGENERATE_KEYFRAME_RATE_HZ:g})")
    if config.extrinsic_mode is not ExtrinsicMode.KNOWN:
        fixes.append("fix the extrinsic (--extrinsic known, with T_imu_<frame> in the calibration)")
    fixed_offset = config.time_offset_mode is TimeOffsetMode.FIXED or (
        config.time_offset_mode is TimeOffsetMode.AUTO and poses is not None
        and poses.source_kind is PoseSourceKind.GROUND_TRUTH)
    if not fixed_offset:
        fixes.append("fix the clock offset (--time-offset-s)")
    fixes.append("record more varied motion (rotation about several axes)")
    if len(fixes) == 1 and poses is not None and poses.source_kind is PoseSourceKind.VIO:
        fixes.append("use a 6-DoF absolute pose source (motion capture): planar odometry leaves roll, pitch and "
                     "the vertical unobserved")
    return "; or ".join(fixes)


def _record_intrinsics_mode(result: RecoveryResult, mode: IntrinsicsMode) -> RecoveryResult:
    """``result`` with ``recovery.json`` ``config.intrinsics`` the mode the intrinsics were estimated
    with (its solves ran with them off: the loop corrects the readings itself), so that a
    re-recovery from that config (cross-validation) estimates them too."""
    data = dict(result.report.data)
    data["config"] = {**dict(data.get("config") or {}), "intrinsics": mode.value}
    return replace(result, report=RecoveryReport.from_json(data))


@dataclass(frozen=True)
class _Inputs:
    """Stage 1, the checked inputs and what follows from them alone.

    Attributes:
        imu: The IMU. stream / poses / kind: The pose stream fitted (cleaned; orientations dropped
            for position trackers), its name and source kind.
        has_rot: The pose stream measures orientation.
        pieces: Gap-free IMU spans ``[(t0_ns, t1_ns)]``.
        pose_mode: Absolute or relative pose factors (AUTO resolved).
        estimate_gravity: Estimate the gravity direction (AUTO resolved).
        level_test: The pose frame is level by convention (mocap, ground truth: AUTO): the tilt is kept
            only where the data tell it from the accelerometer bias (``gravity_tilt_sigmas``).
        position_sigma_m / rotation_sigma_rad: Pose noise before any estimation.
        imu_noise: IMU noise before any estimation (calibration, or the config's overrides).
        calibration_noise: ``imu_noise`` with the random walks at the middle of the evidence grid:
            the noise of the calibration solves before the noise is estimated.
        opts: Solve options common to every solve.
        fuse: Fuse the pose samples between keyframes into them.
        warnings: Plain sentences.
    """

    imu: ImuSeries
    stream: str
    poses: PoseSeries
    kind: PoseSourceKind
    has_rot: bool
    pieces: list[tuple[int, int]]
    pose_mode: PoseFactorMode
    estimate_gravity: bool
    level_test: bool
    position_sigma_m: float
    rotation_sigma_rad: float
    imu_noise: ImuNoise
    calibration_noise: ImuNoise
    opts: SolveOptions
    fuse: bool
    warnings: tuple[str, ...]


def _checked_inputs(sequence: Sequence, pose_stream: str | None, config: RecoveryConfig) -> _Inputs:
    """Stage 1: select and clean the pose stream, split the IMU at gaps, resolve the AUTO modes."""
    warnings: list[str] = reader_warnings(sequence.findings)  # skipped input lines, kept in recovery.json
    imu = sequence.imu
    if imu is None or len(imu) < 10:
        raise RecoveryError(f"sequence '{sequence.name}' has no IMU data (or fewer than 10 samples)")
    name, poses = _select_stream(sequence, pose_stream)
    poses = _clean_poses(poses, name, warnings)
    kind = poses.source_kind
    if len(poses) < config.min_poses:
        raise RecoveryError(f"pose stream '{name}' has {len(poses)} samples, fewer than min_poses={config.min_poses}")
    pieces = _imu_pieces(imu, config, warnings)
    imu_calibration = sequence.calibration
    has_rot = poses.quat_wxyz is not None and kind != PoseSourceKind.POSITION_TRACKER
    if kind == PoseSourceKind.POSITION_TRACKER and poses.quat_wxyz is not None:
        poses = PoseSeries(poses.t_ns, poses.p_m, None, poses.frame, kind, poses.world_frame)
    pose_mode = config.pose_factor_mode
    if pose_mode == PoseFactorMode.AUTO:
        pose_mode = PoseFactorMode.RELATIVE if kind == PoseSourceKind.VIO else PoseFactorMode.ABSOLUTE
    if pose_mode == PoseFactorMode.RELATIVE and not has_rot:
        raise RecoveryError("relative pose factors need orientations; this stream is position-only",
                            field="pose_factor_mode", hint="use absolute")
    # Total stations (compensator) and GNSS (ENU) frames are levelled; the gravity tilt is also
    # barely observable from positions alone: keep z-up there unless told otherwise.
    estimate_g = config.estimate_gravity
    if estimate_g is None:
        estimate_g = kind != PoseSourceKind.POSITION_TRACKER
    # motion-capture and ground-truth frames are level by convention, their tilt a hypothesis to test
    level_test = config.estimate_gravity is None and kind in (PoseSourceKind.MOCAP, PoseSourceKind.GROUND_TRUTH)
    default_sp, default_sr = DEFAULT_POSE_SIGMAS[kind]
    base_sp = config.position_sigma_m or default_sp
    base_sr = config.rotation_sigma_rad or default_sr
    imu_noise = ImuNoise(
        gyro_noise_density=config.gyro_noise_density or imu_calibration.gyro_noise_density,
        acc_noise_density=config.acc_noise_density or imu_calibration.acc_noise_density,
        gyro_random_walk=config.gyro_random_walk or imu_calibration.gyro_random_walk,
        acc_random_walk=config.acc_random_walk or imu_calibration.acc_random_walk,
        integration_sigma=config.integration_sigma,
    )
    opts = SolveOptions(
        pose_mode=pose_mode, relative_horizon=config.relative_horizon, position_sigma_m=base_sp,
        rotation_sigma_rad=base_sr, robust_loss=config.robust_loss, robust_k=config.robust_k,
        outlier_threshold=config.outlier_threshold, estimate_gravity=estimate_g,
        gravity_mps2=config.gravity_mps2, max_iterations=config.max_iterations,
        relative_error_tol=config.relative_error_tol,
    )
    # the noise scales during calibration start at the middle of the candidate grid
    start_scale = 10.0 if config.noise_estimation == NoiseEstimation.EVIDENCE else 1.0
    calibration_noise = replace(imu_noise, gyro_random_walk=imu_noise.gyro_random_walk * start_scale,
                                acc_random_walk=imu_noise.acc_random_walk * start_scale)
    fuse = bool(config.pose_fusion and has_rot and pose_mode == PoseFactorMode.ABSOLUTE)
    return _Inputs(imu, name, poses, kind, has_rot, pieces, pose_mode, bool(estimate_g), level_test, base_sp, base_sr,
                   imu_noise, calibration_noise, opts, fuse, tuple(warnings))


@dataclass(frozen=True)
class _ClockOffset:
    """Stages 2 and 5, the pose stream's clock offset (seconds to add to its stamps).

    Attributes:
        mode: FIXED or ESTIMATE (AUTO resolved).
        offset_s / std_s: The offset and its 1-sigma.
        coarse_method: The cross-correlation's signal (:func:`recovery.calibration_init.estimate_time_offset`),
            None when not estimated or when it failed.
        refine_method: How the graph cost refined it, None when it did not.
        search: The refinement's cost per offset (``recovery.json`` ``pose_time_offset_search``).
        warnings: Plain sentences.
    """

    mode: TimeOffsetMode
    offset_s: float
    std_s: float
    coarse_method: str | None = None
    refine_method: OffsetRefineMethod | None = None
    search: tuple[dict[str, float], ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def method(self) -> str:
        """``recovery.json`` ``pose_time_offset_method``: e.g. ``correlation_gyro+graph_cost_newton``."""
        if self.mode != TimeOffsetMode.ESTIMATE:
            return "fixed"
        coarse = f"correlation_{self.coarse_method}" if self.coarse_method else "fixed"
        return coarse + (f"+{self.refine_method.value}" if self.refine_method else "")


def _coarse_offset(inputs: _Inputs, config: RecoveryConfig) -> _ClockOffset:
    """Stage 2: the clock offset by cross-correlation (ESTIMATE), else as configured."""
    mode = config.time_offset_mode
    if mode == TimeOffsetMode.AUTO:
        mode = TimeOffsetMode.FIXED if inputs.kind == PoseSourceKind.GROUND_TRUTH else TimeOffsetMode.ESTIMATE
    fixed = _ClockOffset(mode, float(config.time_offset_s), 0.0)
    if mode != TimeOffsetMode.ESTIMATE:
        return fixed
    try:
        imu_c, poses_c = _coarse_offset_inputs(inputs.imu, inputs.poses, inputs.pieces, config.max_time_offset_s)
        coarse = ci.estimate_time_offset(imu_c, poses_c, max_offset_s=config.max_time_offset_s)
    except BiasgtError as exc:
        # search with the widest grid step
        return replace(fixed, std_s=config.offset_refine_step_s, warnings=(
            f"coarse clock offset failed ({exc}); starting from time_offset_s={config.time_offset_s}",))
    return replace(fixed, offset_s=coarse.offset_s, std_s=coarse.std_s, coarse_method=coarse.method)


@dataclass(frozen=True)
class _CalibrationWindows:
    """Stage 3: ``overlap`` of the IMU and the (shifted) poses, and ``calib_window``, the
    ``calib_window_s`` inside it with the most rotation, where the calibration solves run."""

    overlap: tuple[int, int]
    calib_window: tuple[int, int]


def _calibration_windows(inputs: _Inputs, offset_s: float, config: RecoveryConfig) -> _CalibrationWindows:
    """Stage 3 (see :class:`_CalibrationWindows`).

    Raises:
        RecoveryError: The IMU and the pose stream do not overlap by ``min_poses`` samples.
    """
    imu = inputs.imu
    t_pose = _shifted_stamps(inputs.poses, offset_s)
    overlap = (max(int(imu.t_ns[0]), int(t_pose[0])), min(int(imu.t_ns[-1]), int(t_pose[-1])))
    n_overlap = int(((t_pose > imu.t_ns[0]) & (t_pose < imu.t_ns[-1])).sum())
    if overlap[1] <= overlap[0] or n_overlap < config.min_poses:
        raise RecoveryError(
            f"no usable time overlap between the IMU and pose stream '{inputs.stream}' ({n_overlap} poses inside "
            "the IMU span)", hint="check that both come from the same recording and that the stamps use the same epoch")
    return _CalibrationWindows(overlap, _calibration_window(imu, inputs.pieces, overlap, config.calib_window_s,
                                                            t_pose))


@dataclass(frozen=True)
class _ExtrinsicInit:
    """Stage 4, the extrinsic ``T_imu_pose`` before the joint solve.

    Attributes:
        mode: KNOWN or ESTIMATE (AUTO resolved). known: The calibration's (or identity for IMU /
            ground-truth frames), or None.
        T_imu_pose: The initial value, 4x4.
        info: ``recovery.json`` ``extrinsic`` so far (mode, source, initialisation residual).
        excitation_deg: Spread of the orientations (NaN without them).
        rotation_observable: Whether the rotation can be estimated (None: position-only stream).
        opts: Options of the joint extrinsic solve (``estimate_extrinsic``: whether it runs).
        estimate_lever: The lever arm is estimated (refined again by the gravity solve).
        warnings: Plain sentences.
    """

    mode: ExtrinsicMode
    known: np.ndarray | None
    T_imu_pose: np.ndarray
    info: dict[str, Any]
    excitation_deg: float
    rotation_observable: bool | None
    opts: SolveOptions
    estimate_lever: bool
    warnings: tuple[str, ...]


def _extrinsic_init(sequence: Sequence, inputs: _Inputs, offset_s: float, config: RecoveryConfig) -> _ExtrinsicInit:
    """Stage 4: the calibration's extrinsic, or a closed-form rotation and lever arm from the data
    (with the calibration's value as a prior in PRIOR mode)."""
    imu, poses, warnings = inputs.imu, inputs.poses, []
    known_T = _known_extrinsic(sequence, poses)
    mode = config.extrinsic_mode
    if mode == ExtrinsicMode.AUTO:
        from_calibration = poses.frame in sequence.calibration.T_imu_frames
        mode = (ExtrinsicMode.PRIOR if from_calibration else
                ExtrinsicMode.KNOWN if known_T is not None else ExtrinsicMode.ESTIMATE)
    if mode == ExtrinsicMode.PRIOR and known_T is None:
        mode = ExtrinsicMode.ESTIMATE  # no calibration value to be a prior
    T = known_T.copy() if known_T is not None else np.eye(4)
    info: dict[str, Any] = {"mode": mode.value, "source": "calibration" if known_T is not None else "identity"}
    excitation = _rotation_excitation_deg(poses) if inputs.has_rot else float("nan")
    rot_observable, estimate_rotation, estimate_lever = True, False, False
    estimating = mode in (ExtrinsicMode.ESTIMATE, ExtrinsicMode.PRIOR)
    if estimating and not inputs.has_rot:
        estimate_lever = True
    elif estimating:
        try:
            rot = ci.estimate_extrinsic_rotation(imu, poses, offset_s)
            rot_observable = bool(rot.observable) and excitation >= config.min_rotation_excitation_deg
            if rot_observable:
                T[:3, :3] = rot.R_imu_pose
                info["rotation_init_residual"] = float(rot.residual_deg)
        except BiasgtError as exc:
            rot_observable = False
            warnings.append(f"extrinsic rotation initialisation failed: {exc}")
        if not rot_observable:
            warnings.append(
                f"extrinsic rotation unobservable (rotation excitation {excitation:.1f} deg): using the "
                f"{'calibration' if known_T is not None else 'identity'} rotation")
        else:
            try:
                lev = ci.estimate_lever_arm(imu, poses, offset_s, T[:3, :3])
                if lev.observable:
                    T[:3, 3] = lev.p_imu_pose_m
            except BiasgtError as exc:
                warnings.append(f"lever-arm initialisation failed: {exc}")
        estimate_rotation = estimate_lever = rot_observable
    prior = None
    if mode == ExtrinsicMode.PRIOR and (estimate_rotation or estimate_lever):
        prior = (known_T.copy(), np.array([math.radians(config.extrinsic_prior_rotation_deg)] * 3
                                          + [config.extrinsic_prior_translation_m] * 3))
        info["prior_sigma"] = {"rotation_deg": float(config.extrinsic_prior_rotation_deg),
                               "translation_m": float(config.extrinsic_prior_translation_m)}
    opts = replace(inputs.opts, estimate_extrinsic=estimate_rotation or estimate_lever, marginal_extras=True,
                   extrinsic_prior=prior)
    return _ExtrinsicInit(mode, known_T, T, info, excitation, bool(rot_observable) if inputs.has_rot else None,
                          opts, estimate_lever, tuple(warnings))


def _solve_extrinsic(problem: _Problem, inputs: _Inputs, calib_window: tuple[int, int], T: np.ndarray,
                     opts: SolveOptions, offset_s: float, config: RecoveryConfig) -> WindowSolution | None:
    """The joint extrinsic solve on the calibration window; fusion is then linearised at its
    extrinsic, gravity and median bias. None when the window holds too few poses."""
    rate = config.calibration_rate_hz(CalibrationSolve.EXTRINSIC, problem.fuse)
    w = problem.window(offset_s, calib_window[0], calib_window[1], rate)
    if w is None:
        return None
    sol = solve_window(w[0], w[1], inputs.calibration_noise, T, opts)
    problem.set_linearisation(T_imu_pose=sol.T_imu_pose, gravity_unit=sol.gravity_unit,
                              bias=np.median(sol.bias, axis=0))
    return sol


def _refined_offset(problem: _Problem, inputs: _Inputs, coarse: _ClockOffset, windows: _CalibrationWindows,
                    T: np.ndarray, config: RecoveryConfig) -> _ClockOffset:
    """Stage 5: the offset at the vertex of the graph cost (ESTIMATE), else ``coarse``."""
    if coarse.mode != TimeOffsetMode.ESTIMATE:
        return coarse
    try:
        off_win = windows.calib_window
        if config.offset_window_s(problem.fuse) < config.calib_window_s:
            off_win = _calibration_window(inputs.imu, inputs.pieces, off_win, config.offset_window_s(problem.fuse),
                                          _shifted_stamps(inputs.poses, coarse.offset_s))
        refined = _refine_offset(problem, coarse.offset_s, coarse.std_s, off_win,
                                 inputs.calibration_noise, T, inputs.opts, config)
    except (BiasgtError, ValueError, np.linalg.LinAlgError) as exc:
        return replace(coarse, warnings=coarse.warnings + (
            f"clock offset refinement failed ({exc}); using the coarse estimate",))
    if refined.last is not None and problem.bias is None:
        problem.set_linearisation(gravity_unit=refined.last.gravity_unit, bias=refined.last.bias)
    return replace(coarse, offset_s=refined.offset_s, std_s=refined.std_s, refine_method=refined.method,
                   search=tuple(refined.table))


def _extrinsic_info(init: _ExtrinsicInit, sol: WindowSolution | None) -> dict[str, Any]:
    """``recovery.json`` ``extrinsic`` after the joint solve: its 1-sigma and where T came from."""
    info = dict(init.info)
    if sol is not None:
        if "extrinsic_cov" in sol.extras:
            c = np.sqrt(np.diag(sol.extras["extrinsic_cov"]))
            info["rotation_std_deg"] = [float(np.degrees(x)) for x in c[:3]]
            info["translation_std_m"] = [float(x) for x in c[3:]]
        if "lever_arm_cov" in sol.extras:
            info["translation_std_m"] = [float(x) for x in np.sqrt(np.diag(sol.extras["lever_arm_cov"]))]
        info["source"] = "estimated"
    elif init.mode in (ExtrinsicMode.ESTIMATE, ExtrinsicMode.PRIOR) and init.rotation_observable is False:
        info["source"] = "fallback_" + info["source"]
    return info


def _difference_from_calibration(init: _ExtrinsicInit, ext_sol: WindowSolution | None, gravity: "_Gravity",
                                 config: RecoveryConfig) -> CalibrationDifference | None:
    """The estimated extrinsic against the calibration's prior (PRIOR mode, when estimated)."""
    if init.mode != ExtrinsicMode.PRIOR or init.known is None or ext_sol is None:
        return None
    lever_cov = (gravity.solution.extras.get("lever_arm_cov") if gravity.solution is not None
                 and gravity.extrinsic_info.get("lever_arm_refined_window_s") else ext_sol.extras.get("lever_arm_cov"))
    return calibration_difference(init.known, gravity.T_imu_pose, ext_sol.extras.get("extrinsic_cov"), lever_cov,
                                  config.extrinsic_max_sigmas)


@dataclass(frozen=True)
class _Noise:
    """Stage 6: the noise model (``choice``), the position-only chained solution the segments may
    start from (``chain``), the evidence window's length and the grid-edge warnings."""

    choice: NoiseChoice
    chain: Any
    window_s: float | None
    warnings: tuple[str, ...]


def _noise(problem: _Problem, inputs: _Inputs, windows: _CalibrationWindows, offset_s: float, T: np.ndarray,
           config: RecoveryConfig) -> _Noise:
    """Stage 6: bias random walks and pose sigmas by maximum evidence (EVIDENCE), else as given."""
    calib = windows.calib_window
    if problem.fuse and problem.bias is None:
        # fusion moves samples with the IMU: linearise it at a first bias estimate (a gyro-bias
        # error is absorbed by the fit, an acc-bias error of 0.5 m/s^2 would add ~1e-4 m of scatter)
        rate = config.calibration_rate_hz(CalibrationSolve.NOISE, problem.fuse)
        w = problem.window(offset_s, calib[0], calib[1], rate)
        if w is not None:
            sol0 = solve_window(w[0], w[1], inputs.calibration_noise, T,
                                replace(inputs.opts, reject_outliers=False, residuals=False))
            problem.set_linearisation(gravity_unit=sol0.gravity_unit, bias=_bias_function(sol0))
    if config.noise_estimation != NoiseEstimation.EVIDENCE:
        choice = NoiseChoice(inputs.imu_noise, inputs.position_sigma_m, inputs.rotation_sigma_rad,
                             pose_error=_fixed_pose_error(inputs, config))
        return _Noise(choice, None, None, ())
    rate = config.calibration_rate_hz(CalibrationSolve.NOISE, problem.fuse)
    noise_win, init, chain = calib, None, None
    down = np.array([0.0, 0.0, -1.0])
    if not inputs.has_rot and config.position_only_window_s > config.calib_window_s:
        # position-only: the gyro random walk needs minutes to show (see position_only_window_s)
        noise_win = _calibration_window(inputs.imu, inputs.pieces, windows.overlap, config.position_only_window_s,
                                        _shifted_stamps(inputs.poses, offset_s))
        if noise_win != calib:
            chain = _chained_solution(problem, offset_s, noise_win, rate, inputs.calibration_noise, T, inputs.opts,
                                      down, config.calib_window_s, config.calib_window_s / 6)
    w = problem.window(offset_s, noise_win[0], noise_win[1], rate)
    if w is None:
        raise RecoveryError("too few poses in the calibration window to estimate the noise",
                            hint="set noise_estimation: fixed and give the random walks")
    if chain is not None:
        init = _continue_from(chain, w, down)
    elif problem.bias is not None:
        # start (and preintegrate) at the calibration solves' gravity and bias: fewer LM iterations
        bias = problem.bias(w[1].t_ns) if callable(problem.bias) else problem.bias
        init = WindowInit(gravity_unit=problem.gravity_world / np.linalg.norm(problem.gravity_world), bias=bias)
    sp, sr, pose_method = _pose_sigmas_from_fusion(w[1], inputs.position_sigma_m, inputs.rotation_sigma_rad, config)
    searched_error = (PoseErrorGrid(tuple(config.pose_error_sigma_scales), tuple(config.pose_error_taus_s))
                      if config.pose_error is PoseErrorMode.AUTO and _correlated_error_applies(inputs) else None)
    choice = estimate_noise(w[0], w[1], inputs.imu_noise, sp, sr, T,
                            replace(inputs.opts, pose_error=_fixed_pose_error(inputs, config)), config.random_walk_scales,
                            estimate_pose=config.position_sigma_m is None and pose_method is PoseSigmaMethod.EVIDENCE,
                            pose_scales=config.pose_sigma_scales, init=init, pose_error=searched_error,
                            density_scales=config.noise_density_scales if len(config.noise_density_scales) > 1 else None)
    if pose_method is not PoseSigmaMethod.EVIDENCE:
        choice.pose_scale = sp / inputs.position_sigma_m
        choice.pose_method = pose_method
    if searched_error is None:
        choice.pose_error = _fixed_pose_error(inputs, config)
    window_s = float((noise_win[1] - noise_win[0]) / NS_PER_S)
    return _Noise(choice, chain, window_s, _grid_edge_warnings(choice, inputs.kind, config))


def _correlated_error_applies(inputs: _Inputs) -> bool:
    """Whether the stream can carry a time-correlated error model (6-DoF absolute pose factors)."""
    return inputs.has_rot and inputs.pose_mode == PoseFactorMode.ABSOLUTE


def _fixed_pose_error(inputs: _Inputs, config: RecoveryConfig) -> PoseErrorModel | None:
    """The configured time-correlated pose error (FIXED, 6-DoF absolute streams), else None."""
    if config.pose_error is not PoseErrorMode.FIXED or not _correlated_error_applies(inputs):
        return None
    model = PoseErrorModel(config.pose_error_rotation_sigma_rad, config.pose_error_rotation_tau_s,
                           config.pose_error_position_sigma_m, config.pose_error_position_tau_s)
    return model if model.active else None


def _grid_edge_warnings(choice: NoiseChoice, kind: PoseSourceKind, config: RecoveryConfig) -> tuple[str, ...]:
    """Warnings for evidence searches that ended on an edge of their candidate grid."""
    out = []
    grid = config.random_walk_scales
    for sensor, scale in (("gyro", choice.gyro_rw_scale), ("acc", choice.acc_rw_scale)):
        if scale <= min(grid) or scale >= max(grid):
            out.append(
                f"{sensor} random walk: the evidence search hit its bound ({scale:g}x the calibration; "
                f"random_walk_scales spans {min(grid):g}x-{max(grid):g}x). Either the calibration's random "
                "walk is far off or the pose stream has artefacts the bias would absorb; widen "
                "random_walk_scales only if the calibration is known to be wrong")
    grid = config.pose_sigma_scales
    # a fixed pose sigma is not searched; smoothed ground-truth poses legitimately hit the lower edge
    searched = config.position_sigma_m is None and kind != PoseSourceKind.GROUND_TRUTH
    if searched and (choice.pose_scale <= min(grid) or choice.pose_scale >= max(grid)):
        out.append(f"pose sigma scale {choice.pose_scale:g} is at the edge of its candidate grid "
                   "(pose_sigma_scales); widen the grid")
    return tuple(out)


@dataclass(frozen=True)
class _Gravity:
    """Stage 7, the gravity direction and the segment plan.

    Attributes:
        unit: Gravity direction in the pose world frame, [3].
        estimated: The full solve estimates it (False: held at ``unit``, given or kept level).
        solution: The decimated long-window solve (the prior of the segments' gravity), or None.
        window: Its span ``(t0_ns, t1_ns)``, or None.
        T_imu_pose: The extrinsic, its lever arm refined by that solve when it is estimated.
        info: ``recovery.json`` ``gravity`` so far. extrinsic_info: Additions to ``extrinsic``.
        segment_s / segment_overlap_s: The segment plan of the full solve.
    """

    unit: np.ndarray
    estimated: bool
    solution: WindowSolution | None
    window: tuple[int, int] | None
    T_imu_pose: np.ndarray
    info: dict[str, Any]
    extrinsic_info: dict[str, Any]
    segment_s: float
    segment_overlap_s: float


def _gravity(problem: _Problem, inputs: _Inputs, offset_s: float, T: np.ndarray, ext_sol: WindowSolution | None,
             estimate_lever: bool, choice: NoiseChoice, config: RecoveryConfig,
             extrinsic_prior: tuple[np.ndarray, np.ndarray] | None = None) -> _Gravity:
    """Stage 7: one decimated solve over a long window for the gravity direction (and the lever arm)."""
    t_pose = _shifted_stamps(inputs.poses, offset_s)
    info: dict[str, Any] = {}
    ext_info: dict[str, Any] = {}
    unit = np.array([0.0, 0.0, -1.0])
    gsol, gwin = None, None
    gopts = replace(inputs.opts, position_sigma_m=choice.position_sigma_m, rotation_sigma_rad=choice.rotation_sigma_rad,
                    marginal_extras=True, pose_error=choice.pose_error)
    refine_lever = ext_sol is not None and inputs.has_rot and estimate_lever
    seg_s, seg_overlap_s = config.segment_plan(_solve_rate_hz(config, problem))
    if not inputs.has_rot and config.position_only_window_s > seg_s:  # see position_only_window_s
        seg_s, seg_overlap_s = config.position_only_window_s, config.position_only_window_s / 6
    spans = [(max(a, int(t_pose[0])), min(b, int(t_pose[-1]))) for a, b in inputs.pieces]
    spans = [(a, b) for a, b in spans if b > a]
    # one piece solved as one segment: it estimates gravity itself, a separate solve adds nothing
    one_segment = len(spans) == 1 and len(plan_segments(spans[0][0], spans[0][1], seg_s, seg_overlap_s)) == 1
    estimated = inputs.estimate_gravity
    if refine_lever or (inputs.estimate_gravity and not one_segment):
        longest = max(inputs.pieces, key=lambda ab: min(ab[1], int(t_pose[-1])) - max(ab[0], int(t_pose[0])))
        ga, gb = max(longest[0], int(t_pose[0])), min(longest[1], int(t_pose[-1]))
        gb = min(gb, ga + int(config.gravity_window_s * NS_PER_S))
        w = problem.window(offset_s, ga, gb, config.calibration_rate_hz(CalibrationSolve.GRAVITY, problem.fuse))
        gwin = (ga, gb)
        if w is not None:
            g_init = ext_sol.gravity_unit if ext_sol is not None and inputs.estimate_gravity else None
            gsol = solve_window(w[0], w[1], choice.imu, T, replace(gopts, estimate_lever_arm=refine_lever,
                                                                   extrinsic_prior=extrinsic_prior),
                                WindowInit(gravity_unit=g_init))
            unit = gsol.gravity_unit
            if refine_lever:
                T = gsol.T_imu_pose
                if "lever_arm_cov" in gsol.extras:
                    ext_info["translation_std_m"] = [float(x) for x in np.sqrt(np.diag(gsol.extras["lever_arm_cov"]))]
                ext_info["lever_arm_refined_window_s"] = float((gb - ga) / NS_PER_S)
            if "gravity_cov_tangent" in gsol.extras:
                info["tilt_std_rad"] = float(np.sqrt(np.trace(gsol.extras["gravity_cov_tangent"]) / 2))
                if inputs.level_test and inputs.estimate_gravity:
                    info["level_test"] = _level_test(unit, info["tilt_std_rad"], config.gravity_tilt_sigmas,
                                                     config.gravity_level_tolerance_deg)
                    if info["level_test"]["level"]:
                        unit, estimated = np.array([0.0, 0.0, -1.0]), False
            problem.set_linearisation(T_imu_pose=T, gravity_unit=unit, bias=_bias_function(gsol))
            info["window_s"] = float((gb - ga) / NS_PER_S)
    elif inputs.estimate_gravity:
        unit = problem.gravity_world / np.linalg.norm(problem.gravity_world)
        info["window_s"] = float((spans[0][1] - spans[0][0]) / NS_PER_S) if spans else 0.0
    info["estimated"] = bool(estimated)
    return _Gravity(unit, bool(estimated), gsol, gwin, T, info, ext_info, seg_s, seg_overlap_s)


def _level_test(unit: np.ndarray, tilt_std_rad: float, max_sigmas: float, tolerance_deg: float) -> dict[str, Any]:
    """Whether a level frame keeps its nominal gravity (``recovery.json`` ``gravity.level_test``).

    The tilt of gravity from the frame's -z and an accelerometer bias explain the same specific
    force under little attitude change; a user of a levelled frame integrates with its nominal
    gravity, so the bias written must be the one consistent with it. The frame is kept level unless
    its estimated tilt both exceeds what levelling a frame leaves (``tolerance_deg``: then the frame
    is not levelled, or its z is not up) and stands out of its sigma (``max_sigmas``: the data tell
    it from the bias); then the tilt is kept and the bias is consistent with the estimated gravity.
    """
    tilt = math.degrees(float(np.arccos(np.clip(-unit[2] / np.linalg.norm(unit), -1.0, 1.0))))
    std = math.degrees(tilt_std_rad)
    z = tilt / std if std > 0 else float("inf")
    level = bool(tilt <= tolerance_deg or z < max_sigmas)
    why = (f"within the {tolerance_deg:g}-deg levelling tolerance" if tilt <= tolerance_deg else
           f"within {max_sigmas:g} sigma" if z < max_sigmas else
           f"beyond the {tolerance_deg:g}-deg levelling tolerance and {z:.1f} sigma from the frame's -z")
    return {"tilt_deg": tilt, "tilt_std_deg": std, "tilt_sigmas": z, "level": level,
            "reason": (f"kept level (nominal gravity): the estimated tilt {tilt:.2f} +- {std:.2f} deg is {why}"
                       if level else f"tilted: the estimated tilt {tilt:.2f} +- {std:.2f} deg is {why}")}


@dataclass(frozen=True)
class _FullSolve:
    """Stage 8, the full-rate solve by segments.

    Attributes:
        solutions: Per gap-free IMU piece, its segments' solutions.
        stitched: Per piece, the segments blended into one solution.
        gravity_unit: Gravity direction (the single segment's own estimate where there was no prior solve).
        info: Additions to ``recovery.json`` ``gravity``.
        fusion_rejected / fusion_counts / fusion_within: Per segment, what pose fusion did.
        calibration: The covariance of the calibration held fixed, propagated into the bias sigmas.
    """

    solutions: list[list[WindowSolution]]
    stitched: list[Any]
    gravity_unit: np.ndarray
    info: dict[str, Any]
    fusion_rejected: list[np.ndarray]
    fusion_counts: list[np.ndarray]
    fusion_within: list[Any]
    calibration: CalibrationCovariance | None = None

    @property
    def flat(self) -> list[WindowSolution]:
        return [s for ps in self.solutions for s in ps]


def _calibration_covariance(offset: _ClockOffset, ext_sol: WindowSolution | None,
                            gravity: _Gravity) -> CalibrationCovariance | None:
    """Covariance of the estimated calibration the full solve holds fixed (None: all of it given)."""
    lever = gravity.solution.extras.get("lever_arm_cov") if gravity.solution is not None else None
    return CalibrationCovariance.assemble(
        extrinsic_cov=None if ext_sol is None else ext_sol.extras.get("extrinsic_cov"),
        lever_arm_cov=lever, R_imu_pose=gravity.T_imu_pose[:3, :3],
        offset_std_s=offset.std_s if offset.mode == TimeOffsetMode.ESTIMATE and offset.refine_method is not None else None)


def _full_solve(problem: _Problem, inputs: _Inputs, offset_s: float, gravity: _Gravity, noise: _Noise,
                config: RecoveryConfig, calibration: CalibrationCovariance | None = None) -> _FullSolve:
    """Stage 8: every keyframe, segment by segment (gravity: a variable per segment with the gravity
    solve as prior; the uncertainty of ``calibration`` propagated into the bias marginals). A single
    segment that estimates gravity itself in a level frame (``level_test``) is solved again level
    when its tilt does not stand out."""
    choice, gsol = noise.choice, gravity.solution
    info: dict[str, Any] = {}
    full_opts = replace(inputs.opts, position_sigma_m=choice.position_sigma_m, pose_error=choice.pose_error,
                        rotation_sigma_rad=choice.rotation_sigma_rad, compute_marginals=config.compute_marginals,
                        estimate_gravity=False, marginal_rate_hz=config.marginal_rate_hz,
                        calibration_cov=calibration)
    if gsol is not None and gravity.estimated and "gravity_cov_tangent" in gsol.extras:
        # Gravity stays a variable in every segment, with the calibration solve's estimate as a
        # prior: its uncertainty then reaches the bias marginals (held fixed, a ~1 mrad tilt
        # error leaked into the x/y accelerometer bias unreported: acc NEES ~2 at 60 s, ~1.2 now).
        full_opts = replace(full_opts, estimate_gravity=True, gravity_prior_cov=gsol.extras["gravity_cov_tangent"])
        info["per_segment"] = True
    elif gravity.estimated and gsol is None:
        full_opts = replace(full_opts, estimate_gravity=True, marginal_extras=True)  # the single segment estimates it
        info["per_segment"] = True
    out = _segments(problem, inputs, offset_s, gravity, noise, config, full_opts,
                    _FullSolve([], [], gravity.unit, info, [], [], [], calibration))
    flat = out.flat
    if gravity.estimated and gsol is None and len(flat) == 1:
        if "gravity_cov_tangent" in flat[0].extras:
            info["tilt_std_rad"] = float(np.sqrt(np.trace(flat[0].extras["gravity_cov_tangent"]) / 2))
            if inputs.level_test:
                info["level_test"] = _level_test(flat[0].gravity_unit, info["tilt_std_rad"], config.gravity_tilt_sigmas,
                                                 config.gravity_level_tolerance_deg)
                if info["level_test"]["level"]:  # solved again in the level frame
                    level = replace(gravity, unit=np.array([0.0, 0.0, -1.0]), estimated=False)
                    info.pop("per_segment", None)
                    info.pop("segment_max_tilt_change_rad", None)
                    info["estimated"] = False
                    return _segments(problem, inputs, offset_s, level, noise, config,
                                     replace(full_opts, estimate_gravity=False, marginal_extras=False),
                                     _FullSolve([], [], level.unit, info, [], [], [], calibration))
        return replace(out, gravity_unit=flat[0].gravity_unit)
    return out


def _segments(problem: _Problem, inputs: _Inputs, offset_s: float, gravity: _Gravity, noise: _Noise,
              config: RecoveryConfig, full_opts: SolveOptions, out: _FullSolve) -> _FullSolve:
    """The full solve's segments, piece by piece, into ``out`` (see :func:`_full_solve`)."""
    t_pose = _shifted_stamps(inputs.poses, offset_s)
    choice, gsol, gwin, T = noise.choice, gravity.solution, gravity.window, gravity.T_imu_pose
    for a, b in inputs.pieces:
        a2, b2 = max(a, int(t_pose[0])), min(b, int(t_pose[-1]))
        if b2 <= a2:
            continue
        piece_solutions: list[WindowSolution] = []
        for s_ns, e_ns in plan_segments(a2, b2, gravity.segment_s, gravity.segment_overlap_s):
            w = problem.window(offset_s, s_ns, e_ns, config.keyframe_rate_hz)
            if w is None or len(w[1]) < 3:
                continue
            prev = piece_solutions[-1] if piece_solutions else None
            guess = _bias_guess(w[1].t_ns, gsol, prev)
            if guess is None and problem.bias is not None:  # the calibration solves' bias, not zero
                guess = (problem.bias(w[1].t_ns) if callable(problem.bias)
                         else np.tile(np.asarray(problem.bias, dtype=float), (len(w[1]), 1)))
            init = WindowInit(gravity_unit=gravity.unit, bias=guess)
            if not inputs.has_rot and (prev is not None or noise.chain is not None):
                init = _continue_from(prev if prev is not None else noise.chain, w, gravity.unit)
            seg_opts = full_opts
            if full_opts.gravity_prior_cov is not None:
                # the calibration solve saw this segment's data too: keep only the information
                # of the rest of its window in the prior (none left: gravity from this segment alone)
                seen = max(0, min(e_ns, gwin[1]) - max(s_ns, gwin[0])) / max(gwin[1] - gwin[0], 1)
                seg_opts = replace(full_opts, gravity_prior_cov=None if seen > 0.9
                                   else np.asarray(full_opts.gravity_prior_cov) / (1.0 - seen))
            piece_solutions.append(solve_window(w[0], w[1], choice.imu, T, seg_opts, init))
            if w[1].rejected_t_ns is not None:
                out.fusion_rejected.append(w[1].rejected_t_ns)
            if w[1].count is not None:
                out.fusion_counts.append(w[1].count)
                out.fusion_within.append(w[1].within_bin())
        if piece_solutions:
            out.solutions.append(piece_solutions)
    if not out.solutions:
        raise RecoveryError(f"too few poses of '{inputs.stream}' inside the IMU span to build a graph")
    out.stitched.extend(stitch(ps) for ps in out.solutions)
    if out.info.get("per_segment"):
        cosang = [float(np.clip(np.dot(s.gravity_unit, gravity.unit), -1.0, 1.0)) for s in out.flat]
        out.info["segment_max_tilt_change_rad"] = float(np.max(np.arccos(cosang)))
    return out


#: The rounds of a recovery that :func:`_rounds_bar` counts (extrinsic, clock offset, noise, gravity, solve).
RECOVERY_ROUNDS = 5


def _rounds_bar(name: str):
    """Progress over the recovery's rounds (rate and ETA; a log line every 30 s off a terminal)."""
    from pipeline.progress import progress

    bar = progress(RECOVERY_ROUNDS, desc=f"recover {name}", unit="round", logger=log)
    bar.set_postfix_str("extrinsic", refresh=False)
    return bar


def _next_round(bar, what: str) -> None:
    bar.update(1)
    bar.set_postfix_str(what, refresh=False)


def _recover(sequence: Sequence, *, pose_stream: str | None, config: RecoveryConfig) -> RecoveryResult:
    """The stages in order (each returns a frozen record); ``problem`` carries the fusion's
    linearisation point (extrinsic, gravity, bias), which the calibration solves update."""
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    inputs = _checked_inputs(sequence, pose_stream, config)
    problem = _Problem(inputs.imu, inputs.poses, inputs.pieces, fuse=inputs.fuse, gravity_mps2=config.gravity_mps2)
    bar = _rounds_bar(sequence.name)

    t0 = time.perf_counter()
    coarse = _coarse_offset(inputs, config)
    timings["offset_coarse_s"] = time.perf_counter() - t0
    windows = _calibration_windows(inputs, coarse.offset_s, config)

    ext_init = _extrinsic_init(sequence, inputs, coarse.offset_s, config)
    problem.set_linearisation(T_imu_pose=ext_init.T_imu_pose)
    t0 = time.perf_counter()
    T, ext_sol = ext_init.T_imu_pose, None
    if ext_init.opts.estimate_extrinsic:
        ext_sol = _solve_extrinsic(problem, inputs, windows.calib_window, T, ext_init.opts, coarse.offset_s, config)
        T = ext_sol.T_imu_pose if ext_sol is not None else T
    timings["extrinsic_s"] = time.perf_counter() - t0
    _next_round(bar, "clock offset")

    t0 = time.perf_counter()
    offset = _refined_offset(problem, inputs, coarse, windows, T, config)
    if offset.mode == TimeOffsetMode.ESTIMATE and ext_init.opts.estimate_extrinsic:
        ext_sol = _solve_extrinsic(problem, inputs, windows.calib_window, T, ext_init.opts, offset.offset_s, config)
        T = ext_sol.T_imu_pose if ext_sol is not None else T
    timings["offset_refine_s"] = time.perf_counter() - t0
    _next_round(bar, "noise by evidence")

    t0 = time.perf_counter()
    noise = _noise(problem, inputs, windows, offset.offset_s, T, config)
    timings["noise_s"] = time.perf_counter() - t0
    _next_round(bar, "gravity")

    t0 = time.perf_counter()
    gravity = _gravity(problem, inputs, offset.offset_s, T, ext_sol, ext_init.estimate_lever, noise.choice, config,
                       ext_init.opts.extrinsic_prior)
    timings["gravity_s"] = time.perf_counter() - t0
    _next_round(bar, "full solve")

    t0 = time.perf_counter()
    calibration = _calibration_covariance(offset, ext_sol, gravity)
    full = _full_solve(problem, inputs, offset.offset_s, gravity, noise, config, calibration)
    timings["solve_s"] = time.perf_counter() - t0
    _next_round(bar, "done")
    bar.close()

    extrinsic_info = {**_extrinsic_info(ext_init, ext_sol), **gravity.extrinsic_info}
    refine_warnings = offset.warnings[len(coarse.warnings):]
    warnings = [*inputs.warnings, *coarse.warnings, *ext_init.warnings, *refine_warnings, *noise.warnings]
    difference = _difference_from_calibration(ext_init, ext_sol, gravity, config)
    if difference is not None:
        extrinsic_info["difference_from_calibration"] = difference.to_dict()
        if difference.exceeds:
            warnings.append(difference.sentence())
    return _result(sequence, config, inputs, offset, windows.calib_window, ext_init, extrinsic_info, noise, gravity,
                   full, warnings, timings, t_start)


def calibration_sources(sequence: Sequence, config: RecoveryConfig) -> dict[str, str]:
    """Where each IMU noise value the recovery started from came from: the recovery config, the
    input's calibration file, the simulator, or the EuRoC default nobody gave."""
    sources = sequence.calibration.value_sources()
    return {k: ("recovery config" if getattr(config, k) is not None else v) for k, v in sources.items()}


def _result(sequence: Sequence, config: RecoveryConfig, inputs: _Inputs, offset: _ClockOffset,
            calib_window: tuple[int, int], ext_init: _ExtrinsicInit, extrinsic_info: dict[str, Any], noise: _Noise,
            gravity: _Gravity, full: _FullSolve, warnings: list[str], timings: dict[str, float],
            t_start: float) -> RecoveryResult:
    """Stage 9: the stitched keyframes, the last warnings and ``recovery.json``."""
    stitched, flat, choice = full.stitched, full.flat, noise.choice
    t_ns = np.concatenate([s.t_ns for s in stitched])
    bias = np.concatenate([s.bias for s in stitched])
    bias_std = np.concatenate([s.bias_std for s in stitched])
    n_kf = len(t_ns)
    outlier_t = np.unique(np.concatenate([s.t_ns[s.outliers] for s in flat])) if flat else np.zeros(0)
    # samples rejected while fusing (the same sample may sit in two overlapping segments)
    rejected = np.unique(np.concatenate(full.fusion_rejected)) if full.fusion_rejected else np.zeros(0, np.int64)
    if len(outlier_t) > 0.05 * n_kf:
        warnings.append(f"{len(outlier_t)} of {n_kf} poses rejected as outliers: check the pose noise / the stream")
    weights = np.array([len(s.t_ns) for s in flat], dtype=float)
    pose_rms = float(np.sqrt(np.average([s.pose_whitened_rms**2 for s in flat], weights=weights)))
    imu_rms = float(np.sqrt(np.average([s.imu_whitened_rms**2 for s in flat], weights=weights)))
    if pose_rms > 3.0:
        warnings.append(f"pose residuals are {pose_rms:.1f} sigma RMS: the pose stream disagrees with the IMU "
                        "(wrong extrinsic, clock offset, or noise)")
    if flat and any(s.iterations >= config.max_iterations for s in flat):
        warnings.append("the optimiser hit max_iterations in at least one segment (may not have converged)")
    for message in warnings:
        log.warning("%s", message)
    flags: dict[str, Any] = {"rotation_excitation_deg": ext_init.excitation_deg,
                             "extrinsic_rotation_observable": ext_init.rotation_observable}
    if noise.window_s is not None:
        flags["noise_window_s"] = noise.window_s
    source_kind = sequence.metadata.get("source_format") or sequence.metadata.get("source_kind")
    report: dict[str, Any] = {
        "sequence": sequence.name,
        "pose_stream": inputs.stream,
        "pose_source_kind": inputs.kind.value,
        "pose_frame": inputs.poses.frame,
        "input_format": source_kind if isinstance(source_kind, str) else None,
        "pose_factor_mode": inputs.pose_mode.value,
        "pose_time_offset_s": float(offset.offset_s),
        "pose_time_offset_std_s": float(offset.std_s),
        "pose_time_offset_method": offset.method,
        "pose_time_offset_search": list(offset.search),
        "T_imu_pose": _matrix_to_dict(gravity.T_imu_pose),
        "extrinsic": extrinsic_info,
        "calibration_uncertainty": _calibration_report(full),
        "gravity_world_mps2": [float(x) for x in full.gravity_unit * config.gravity_mps2],
        "gravity": {**gravity.info, **full.info},
        "noise": choice.to_dict(),
        "calibration_sources": calibration_sources(sequence, config),
        "residuals": {"pose_whitened_rms": pose_rms, "imu_whitened_rms": imu_rms},
        "outliers_rejected": int(len(outlier_t) + len(rejected)),
        "outlier_t_ns": [int(t) for t in np.union1d(outlier_t, rejected)],  # IMU clock
        "pose_fusion": _fusion_report(inputs.fuse, config, full.fusion_counts, full.fusion_within, len(rejected)),
        "accuracy_floor": _accuracy_floor(choice, inputs.poses, inputs.pose_mode, inputs.has_rot),
        "keyframes": int(n_kf),
        "keyframe_rate_hz": config.keyframe_rate_hz,
        "segments": len(flat),
        "segment_s": gravity.segment_s,
        "segment_overlap_s": gravity.segment_overlap_s,
        "segment_seams": [j for s in stitched for j in s.seam_jumps],
        "imu_pieces": len(inputs.pieces),
        "calibration_window_ns": [int(calib_window[0]), int(calib_window[1])],
        "duration_s": float((t_ns[-1] - t_ns[0]) / NS_PER_S) if n_kf > 1 else 0.0,
        "runtime_s": float(time.perf_counter() - t_start),
        "timings_s": {k: float(v) for k, v in timings.items()},
        "flags": flags,
        "extrinsic_rotation_observable": ext_init.rotation_observable,
        "warnings": warnings,
        "config": config.to_dict(),
    }
    return RecoveryResult(
        t_ns=t_ns, bias_gyro_radps=bias[:, :3], bias_acc_mps2=bias[:, 3:],
        bias_gyro_std_radps=bias_std[:, :3], bias_acc_std_mps2=bias_std[:, 3:],
        p_m=np.concatenate([s.p_m for s in stitched]),
        quat_wxyz=np.concatenate([s.quat_wxyz for s in stitched]),
        v_mps=np.concatenate([s.v_mps for s in stitched]),
        report=RecoveryReport.from_json(report),
        residuals=_residuals_at(t_ns, flat, outlier_t),
    )


def _solve_rate_hz(config: RecoveryConfig, problem: "_Problem") -> float:
    """Keyframes per second of the full solve (for sizing segments)."""
    if config.keyframe_rate_hz is not None:
        return float(config.keyframe_rate_hz)
    if problem.fuse:
        return FUSED_KEYFRAME_RATE_HZ
    return _pose_rate_hz(problem.poses) or FUSED_KEYFRAME_RATE_HZ


def _pose_rate_hz(poses: PoseSeries) -> float | None:
    """Mean pose samples per second over the stream's span (None for fewer than two samples)."""
    t = poses.t_ns
    span_s = (t[-1] - t[0]) / NS_PER_S if len(t) > 1 else 0.0
    return float(len(t) / span_s) if span_s > 0 else None


MIN_WITHIN_BIN_DOF = 300  # residual degrees of freedom for the closed-form pose sigma (1/sqrt(2 dof) = 4 %)


def _pose_sigmas_from_fusion(kf: KeyframePoses, base_sp: float, base_sr: float, config: RecoveryConfig
                             ) -> tuple[float, float, PoseSigmaMethod]:
    """Pose sigmas from the scatter of fused samples about their keyframes, when there is enough.

    The residuals orthogonal to each bin's model depend on the pose noise alone, so
    ``sigma^2 = RSS / dof`` is its maximum-likelihood estimate (position and rotation
    separately, white noise assumed), clamped to the ``pose_sigma_scales`` range. Without
    fused keyframes (or with a fixed sigma), the evidence search chooses a common scale.
    """
    within = kf.within_bin()
    if config.position_sigma_m is not None or within is None or min(within.pos_dof, within.rot_dof) < MIN_WITHIN_BIN_DOF:
        return base_sp, base_sr, PoseSigmaMethod.EVIDENCE
    lo, hi = min(config.pose_sigma_scales), max(config.pose_sigma_scales)
    sp = float(np.clip(math.sqrt(within.pos_sq_m2 / within.pos_dof), lo * base_sp, hi * base_sp))
    sr = float(np.clip(math.sqrt(within.rot_sq_rad2 / within.rot_dof), lo * base_sr, hi * base_sr))
    return sp, sr, PoseSigmaMethod.WITHIN_BIN_RESIDUALS


def _accuracy_floor(choice: NoiseChoice, poses: PoseSeries, pose_mode: PoseFactorMode, has_rot: bool
                    ) -> dict[str, float | None]:
    """The optimal smoother's per-axis bias RMSE for the noise used (:mod:`recovery.bounds`): what
    no estimator beats with this IMU and pose stream; absolute pose streams only."""
    rate = _pose_rate_hz(poses)
    if pose_mode != PoseFactorMode.ABSOLUTE or rate is None:
        return {"gyro_radps": None, "acc_mps2": None}
    imu = choice.imu
    acc = bias_rmse_floor(imu.acc_noise_density, imu.acc_random_walk, choice.position_sigma_m, rate, 2)
    gyro = (bias_rmse_floor(imu.gyro_noise_density, imu.gyro_random_walk, choice.rotation_sigma_rad, rate, 1)
            if has_rot else None)  # position-only: attitude is not measured
    return {"gyro_radps": gyro, "acc_mps2": acc}


def _bias_function(sol: WindowSolution) -> Any:
    """Bias of ``sol`` as a function of time (t_ns [M] -> [M, 6]; held constant past its ends)."""
    x = (sol.t_ns - sol.t_ns[0]).astype(float)
    b = sol.bias.copy()

    def at(t_ns: np.ndarray) -> np.ndarray:
        xq = (np.asarray(t_ns, dtype=np.int64) - sol.t_ns[0]).astype(float)
        return np.stack([np.interp(xq, x, b[:, c]) for c in range(6)], axis=1)

    return at


def _calibration_report(full: _FullSolve) -> dict[str, Any]:
    """``recovery.json`` ``calibration_uncertainty``: whether the bias sigmas include the uncertainty of
    the estimated calibration (:mod:`recovery.calibration_uncertainty`), and how much it inflated them."""
    ratios = [s.extras["calibration_std_ratio"] for s in full.flat if "calibration_std_ratio" in s.extras]
    cal = full.calibration
    out: dict[str, Any] = {"included_in_bias_std": bool(ratios), "parameters": list(cal.parameters) if cal else []}
    if cal is not None:
        out["calibration_std"] = {"extrinsic_rotation_rad": np.sqrt(np.diag(cal.cov)[:3]).tolist(),
                                  "extrinsic_translation_m": np.sqrt(np.diag(cal.cov)[3:6]).tolist(),
                                  "clock_offset_s": float(np.sqrt(cal.cov[OFFSET_INDEX, OFFSET_INDEX]))}
    if ratios:
        r = np.concatenate(ratios)
        # std with / without the calibration's uncertainty, per axis (gyro xyz, acc xyz)
        out["std_inflation_mean"] = [float(x) for x in r.mean(0)]
        out["std_inflation_max"] = [float(x) for x in r.max(0)]
    return out


def _fusion_report(enabled: bool, config: RecoveryConfig, counts: list[np.ndarray], within: list[Any],
                   rejected: int) -> dict[str, Any]:
    """What pose fusion did, for recovery.json."""
    out: dict[str, Any] = {"enabled": bool(enabled)}
    if not enabled or not counts:
        return out
    c = np.concatenate(counts)
    pos_sq = sum(w.pos_sq_m2 for w in within)
    pos_dof = sum(w.pos_dof for w in within)
    rot_sq = sum(w.rot_sq_rad2 for w in within)
    rot_dof = sum(w.rot_dof for w in within)
    out.update({
        "keyframe_rate_hz": float(config.keyframe_rate_hz or FUSED_KEYFRAME_RATE_HZ),
        "samples_per_keyframe_mean": float(c.mean()),
        "samples_fused": int(c.sum()),  # counted per segment: overlaps count twice
        "samples_rejected": int(rejected),
        "within_bin_position_rms_m": float(math.sqrt(pos_sq / pos_dof)) if pos_dof else None,
        "within_bin_rotation_rms_rad": float(math.sqrt(rot_sq / rot_dof)) if rot_dof else None,
    })
    return out


def _residuals_at(t_ns: np.ndarray, solutions: list[WindowSolution], outlier_t: np.ndarray) -> dict[str, np.ndarray]:
    """Per-keyframe whitened residuals over the stitched keyframes (in overlaps the later segment wins)."""
    pose = np.full(len(t_ns), np.nan)
    imu = np.full(len(t_ns), np.nan)
    for sol in solutions:
        if sol.pose_residual is None or sol.imu_residual is None:
            continue
        idx = np.searchsorted(t_ns, sol.t_ns)
        ok = (idx < len(t_ns)) & (t_ns[np.minimum(idx, len(t_ns) - 1)] == sol.t_ns)
        pose[idx[ok]] = sol.pose_residual[ok]
        imu[idx[ok]] = sol.imu_residual[ok]
    return {"pose_whitened_rms": pose, "imu_whitened_rms": imu, "outlier": np.isin(t_ns, outlier_t)}
