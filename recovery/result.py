"""The recovery's result: ``RecoveryResult`` (bias at keyframes with its std, the report for
``recovery.json``), how it is written, and stage 9 that assembles it from the stages' records.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pipeline.bias_table import BiasTrack
from pipeline.io.registry import recorded_format
from pipeline.types import NOISE_DENSITY_FIELDS, NS_PER_S, PoseSeries, PoseSourceKind, Sequence
from recovery.config import (
    PoseFactorMode,
    PoseSigmaMethod,
    RecoveryConfig,
)
from recovery.noise.bounds import bias_rmse_floor
from recovery.solver.calibration_uncertainty import OFFSET_INDEX
from recovery.solver.window import KeyframePoses, WindowSolution
from recovery.noise.evidence import NoiseChoice
from recovery.noise.from_data import DataNoise
from recovery.outputs import RecoveryOutputs, RecoveryReport
from recovery.problem import FUSED_KEYFRAME_RATE_HZ, Problem
from recovery.records import ClockOffset, ExtrinsicInit, FullSolve, GravityStage, Inputs, NoiseStage


log = logging.getLogger(__name__)


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



#: ``calibration_sources`` of a density read off the recording's rest.
DATA_NOISE_SOURCE = "data (Allan deviation of the recording at rest)"


def calibration_sources(sequence: Sequence, config: RecoveryConfig,
                        data_noise: DataNoise | None = None) -> dict[str, str]:
    """Where each IMU noise value the recovery started from came from: the recovery config, the
    input's calibration file, the simulator, the recording's rest (``data_noise``: the densities),
    or the EuRoC default nobody gave."""
    sources = sequence.calibration.value_sources()
    if data_noise is not None:
        sources.update(dict.fromkeys(NOISE_DENSITY_FIELDS, DATA_NOISE_SOURCE))
    return {k: ("recovery config" if getattr(config, k) is not None else v) for k, v in sources.items()}


def build_result(sequence: Sequence, config: RecoveryConfig, inputs: Inputs, offset: ClockOffset,
            calib_window: tuple[int, int], ext_init: ExtrinsicInit, extrinsic_info: dict[str, Any], noise: NoiseStage,
            gravity: GravityStage, full: FullSolve, warnings: list[str], timings: dict[str, float],
            t_start: float) -> RecoveryResult:
    """Stage 9: the stitched keyframes, the last warnings and ``recovery.json``."""
    stitched, flat, choice = full.stitched, full.flat, noise.choice
    t_ns = np.concatenate([s.t_ns for s in stitched])
    bias = np.concatenate([s.bias for s in stitched])
    bias_std = np.concatenate([s.bias_std for s in stitched])
    n_kf = len(t_ns)
    outlier_t, rejected, outliers = _outliers(full, inputs, offset)
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
    report: dict[str, Any] = {
        "sequence": sequence.name,
        "pose_stream": inputs.stream,
        "pose_source_kind": inputs.kind.value,
        "pose_frame": inputs.poses.frame,
        "input_format": recorded_format(sequence.metadata),
        "pose_factor_mode": inputs.pose_mode.value,
        "pose_time_offset_s": float(offset.offset_s),
        "pose_time_offset_std_s": float(offset.std_s),
        "pose_time_offset_method": offset.method,
        "pose_time_offset_search": list(offset.search),
        "pose_time_offset_curvature_std_s": offset.curvature_std_s,
        "pose_time_offset_windows_s": [float(x) for x in offset.window_offsets_s],
        "pose_time_offset_wide_search": offset.wide_search,
        "T_imu_pose": _matrix_to_dict(gravity.T_imu_pose),
        "extrinsic": extrinsic_info,
        "calibration_uncertainty": _calibration_report(full),
        "gravity_world_mps2": [float(x) for x in full.gravity_unit * config.gravity_mps2],
        "gravity": {**gravity.info, **full.info},
        "noise": choice.to_dict(),
        "calibration_sources": calibration_sources(sequence, config, inputs.data_noise),
        "noise_from_data": None if inputs.data_noise is None else inputs.data_noise.to_dict(),
        "residuals": {"pose_whitened_rms": pose_rms, "imu_whitened_rms": imu_rms},
        **outliers,
        "pose_fusion": _fusion_report(inputs.fuse, config, full.fusion_counts, full.fusion_within, len(rejected)),
        "accuracy_floor": _accuracy_floor(choice, inputs.poses, inputs.pose_mode, inputs.has_rot),
        "imu_rate_hz": float(inputs.imu.rate_hz),
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


def _outliers(full: FullSolve, inputs: Inputs, offset: ClockOffset) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The keyframe poses the solves rejected, the samples rejected while fusing (the same sample may sit in
    two overlapping segments; stamps, IMU clock), and ``recovery.json``'s outlier fields (the placeholder
    frames dropped before the solve included)."""
    flat = full.flat
    outlier_t = np.unique(np.concatenate([s.t_ns[s.outliers] for s in flat])) if flat else np.zeros(0)
    rejected = np.unique(np.concatenate(full.fusion_rejected)) if full.fusion_rejected else np.zeros(0, np.int64)
    placeholders = inputs.placeholder_t_ns + int(round(offset.offset_s * NS_PER_S))
    return outlier_t, rejected, {
        "outliers_rejected": int(len(outlier_t) + len(rejected) + len(placeholders)),
        "outlier_t_ns": [int(t) for t in np.union1d(np.union1d(outlier_t, rejected), placeholders)],
        "placeholders_rejected": int(len(placeholders))}


def solve_rate_hz(config: RecoveryConfig, problem: "Problem") -> float:
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


def pose_sigmas_from_fusion(kf: KeyframePoses, base_sp: float, base_sr: float, config: RecoveryConfig
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
    """The optimal smoother's per-axis bias RMSE for the noise used (:mod:`recovery.noise.bounds`): what
    no estimator beats with this IMU and pose stream; absolute pose streams only."""
    rate = _pose_rate_hz(poses)
    if pose_mode != PoseFactorMode.ABSOLUTE or rate is None:
        return {"gyro_radps": None, "acc_mps2": None}
    imu = choice.imu
    acc = bias_rmse_floor(imu.acc_noise_density, imu.acc_random_walk, choice.position_sigma_m, rate, 2)
    gyro = (bias_rmse_floor(imu.gyro_noise_density, imu.gyro_random_walk, choice.rotation_sigma_rad, rate, 1)
            if has_rot else None)  # position-only: attitude is not measured
    return {"gyro_radps": gyro, "acc_mps2": acc}


def bias_function(sol: WindowSolution) -> Any:
    """Bias of ``sol`` as a function of time (t_ns [M] -> [M, 6]; held constant past its ends)."""
    x = (sol.t_ns - sol.t_ns[0]).astype(float)
    b = sol.bias.copy()

    def at(t_ns: np.ndarray) -> np.ndarray:
        xq = (np.asarray(t_ns, dtype=np.int64) - sol.t_ns[0]).astype(float)
        return np.stack([np.interp(xq, x, b[:, c]) for c in range(6)], axis=1)

    return at


def _calibration_report(full: FullSolve) -> dict[str, Any]:
    """``recovery.json`` ``calibration_uncertainty``: whether the bias sigmas include the uncertainty of
    the estimated calibration (:mod:`recovery.solver.calibration_uncertainty`), and how much it inflated them."""
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


def _matrix_to_dict(T: np.ndarray) -> dict[str, list[float]]:
    """``recovery.json``'s form of a 4x4 transform: translation and quaternion (w, x, y, z)."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return {"p_m": [float(x) for x in T[:3, 3]], "quat_wxyz": [float(q[3]), float(q[0]), float(q[1]), float(q[2])]}
