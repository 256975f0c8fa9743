"""The records of one recovery window: its keyframe poses, how it is solved, where it starts and
what the solve returns (:mod:`recovery.solver.factors` builds the graph, :mod:`recovery.solver.graph` solves it)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pipeline.types import GRAVITY_MPS2, NS_PER_S, PoseSourceKind
from recovery.solver.calibration_uncertainty import CalibrationCovariance
from recovery.config import PoseFactorMode, RobustLoss
from recovery.solver.fusion import FusedPoses, PerBin, WithinBinStats
from recovery.solver.gaps import gap_keyframe_stamps
from recovery.solver.pose_error import PoseErrorModel


@dataclass(frozen=True)
class KeyframePoses:
    """Pose measurements at the keyframes, stamps already on the IMU clock.

    Attributes:
        t_ns: Keyframe stamps (IMU clock), int64 [K], strictly increasing.
        p_m: Measured position of the tracked frame, [K, 3].
        quat_wxyz: Measured orientation of the tracked frame, [K, 4] or None.
        source_kind: The pose source.
        count: Pose samples fused into each keyframe, int [K] (None: one sample each); the pose
            factor's covariance is divided by it.
        v_mps: Fused IMU velocity, [K, 3]; dt2_s2: its information per unit position variance
            (``sum dt^2`` of the bin), [K] (0: no velocity measurement).
        per_bin: Within-bin residual sums of the fused samples (for the noise evidence).
        rejected_t_ns: Pose samples rejected while fusing (outliers), int64 [R].
        measured: Whether each keyframe has a pose measurement, bool [K] (None: all have). The
            others sit inside pose gaps (:mod:`recovery.solver.gaps`): no pose factor, their ``p_m`` and
            ``quat_wxyz`` only placeholders (interpolated, held).
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray | None
    source_kind: PoseSourceKind
    count: np.ndarray | None = None
    v_mps: np.ndarray | None = None
    dt2_s2: np.ndarray | None = None
    per_bin: PerBin | None = None
    rejected_t_ns: np.ndarray | None = None
    measured: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def unmeasured(self) -> np.ndarray:
        """Indices of the keyframes without a pose measurement, int [U]."""
        return np.zeros(0, dtype=int) if self.measured is None else np.nonzero(~self.measured)[0]

    def with_gap_keyframes(self) -> "KeyframePoses":
        """These keyframes plus unmeasured ones inside the pose gaps (:func:`recovery.solver.gaps.gap_keyframe_stamps`)."""
        t_ns, measured = gap_keyframe_stamps(self.t_ns)
        if measured.all():
            return self
        src = np.cumsum(measured) - 1  # the measured keyframe at or before each
        t_s, t_meas = t_ns / NS_PER_S, self.t_ns / NS_PER_S
        p_m = np.column_stack([np.interp(t_s, t_meas, self.p_m[:, i]) for i in range(3)])
        q = None if self.quat_wxyz is None else self.quat_wxyz[src]
        if self.count is None:
            return replace(self, t_ns=t_ns, p_m=p_m, quat_wxyz=q, measured=measured)

        def put(x: np.ndarray, fill: float) -> np.ndarray:
            out = np.full((len(t_ns), *x.shape[1:]), fill, dtype=x.dtype)
            out[measured] = x
            return out

        pb = self.per_bin
        return replace(self, t_ns=t_ns, p_m=p_m, quat_wxyz=q, count=put(self.count, 1), v_mps=put(self.v_mps, 0.0),
                       dt2_s2=put(self.dt2_s2, 0.0), measured=measured,
                       per_bin=PerBin(put(pb.pos_sq, 0.0), put(pb.pos_dof, 0), put(pb.rot_sq, 0.0), put(pb.rot_dof, 0)))

    @classmethod
    def from_fused(cls, fused: FusedPoses, source_kind: PoseSourceKind) -> "KeyframePoses":
        """Keyframes carrying the fused samples of their bins (:mod:`recovery.solver.fusion`)."""
        return cls(fused.t_ns, fused.p_m, fused.quat_wxyz, source_kind, fused.count, fused.v_mps,
                   fused.dt2_s2, fused.per_bin, fused.rejected_t_ns)

    def within_bin(self) -> WithinBinStats | None:
        """Residual sums of the fused samples about their keyframes (None when not fused)."""
        return None if self.per_bin is None else self.per_bin.total()

    def take(self, index: np.ndarray | slice) -> "KeyframePoses":
        q = None if self.quat_wxyz is None else self.quat_wxyz[index]
        measured = None if self.measured is None else self.measured[index]
        if self.count is None:
            return KeyframePoses(self.t_ns[index], self.p_m[index], q, self.source_kind, measured=measured)
        pb = self.per_bin
        return KeyframePoses(self.t_ns[index], self.p_m[index], q, self.source_kind, self.count[index],
                             self.v_mps[index], self.dt2_s2[index],
                             PerBin(pb.pos_sq[index], pb.pos_dof[index], pb.rot_sq[index], pb.rot_dof[index]),
                             self.rejected_t_ns, measured)


@dataclass
class SolveOptions:
    """How one window is built and solved (derived from RecoveryConfig)."""

    pose_mode: PoseFactorMode = PoseFactorMode.ABSOLUTE
    relative_horizon: int = 5
    position_sigma_m: float = 1e-3
    rotation_sigma_rad: float = 1e-3
    robust_loss: RobustLoss = RobustLoss.HUBER
    robust_k: float = 3.0
    outlier_threshold: float = 5.0
    reject_outliers: bool = True
    estimate_gravity: bool = True
    gravity_mps2: float = GRAVITY_MPS2
    estimate_extrinsic: bool = False
    estimate_lever_arm: bool = False  # 6-DoF sources: rotation of T_imu_pose fixed, lever arm L(0) free (native factors)
    max_iterations: int = 30
    relative_error_tol: float = 1e-6
    compute_marginals: bool = False
    marginal_extras: bool = False  # gravity / extrinsic covariances
    marginal_rate_hz: float | None = 20.0  # bias marginals at this rate (+ ends, gap edges), interpolated
    gravity_prior_cov: np.ndarray | None = None  # [2, 2] Unit3-tangent prior on G(0) around init.gravity_unit
    # the calibration held fixed and its covariance: propagated into the bias marginals
    # (recovery.solver.calibration_uncertainty; 6-DoF absolute pose factors only)
    calibration_cov: CalibrationCovariance | None = None
    residuals: bool = True  # the whitened residuals per keyframe and their RMS (NaN without)
    # the cost's slope and information in the clock offset into extras (offset_slope,
    # offset_information; 6-DoF absolute pose factors only): recovery.solver.calibration_uncertainty
    offset_sensitivity: bool = False
    # the stream's time-correlated error as graph states (6-DoF absolute pose factors;
    # recovery.solver.pose_error); None or inactive: white pose noise only
    pose_error: PoseErrorModel | None = None
    # with estimate_extrinsic: a prior on E(0), (T_imu_pose [4, 4], sigmas [6]: rotation rad, translation m)
    extrinsic_prior: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def correlated_error(self) -> PoseErrorModel | None:
        """The active time-correlated pose error model, else None."""
        return self.pose_error if self.pose_error is not None and self.pose_error.active else None


@dataclass
class WindowInit:
    """Optional initial values for a window (e.g. from a previous solve)."""

    gravity_unit: np.ndarray | None = None
    bias: np.ndarray | None = None  # [6] gyro, acc or [K, 6]
    rot_wxyz: np.ndarray | None = None  # [K, 4] IMU orientation (position trackers)
    velocity: np.ndarray | None = None  # [K, 3] velocity guess (else from the positions)
    values: Any = None  # gtsam.Values: an optimum of the same window; every variable starts there


@dataclass
class WindowSolution:
    """Result of :func:`solve_window`.

    Attributes:
        t_ns: Keyframe stamps, int64 [K].
        p_m: IMU positions, [K, 3]. quat_wxyz: IMU orientations, [K, 4]. v_mps: [K, 3].
        bias: [K, 6] gyro xyz then acc xyz. bias_std: [K, 6] (NaN without marginals).
        gravity_unit: [3] gravity direction in the world frame.
        T_imu_pose: 4x4 extrinsic used / estimated.
        cost: Final graph error (0.5 * sum of squared whitened residuals, robust).
        pose_whitened_rms / imu_whitened_rms: Per-DoF RMS of the whitened residuals.
        outliers: Indices of rejected pose keyframes.
        iterations: LM iterations (of the last solve).
        extras: Covariances of shared variables when asked for.
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    bias: np.ndarray
    bias_std: np.ndarray
    gravity_unit: np.ndarray
    T_imu_pose: np.ndarray
    cost: float
    pose_whitened_rms: float
    imu_whitened_rms: float
    outliers: np.ndarray
    iterations: int
    log_evidence: float = float("nan")
    extras: dict[str, Any] = field(default_factory=dict)
    pose_residual: np.ndarray | None = None  # [K] whitened RMS of each keyframe's pose factor(s), NaN if none
    imu_residual: np.ndarray | None = None  # [K] whitened RMS of the IMU factor ending at each keyframe
    values: Any = None  # the optimum as gtsam.Values (with want_evidence: the evidence search starts from it)
