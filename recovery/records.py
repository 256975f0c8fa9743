"""The records the recovery's stages hand to each other (inputs, clock offset, calibration windows,
extrinsic, noise, gravity, full solve): typed, frozen, one per stage."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.checks.rig import RigFit
from pipeline.types import ImuSeries, PoseSeries, PoseSourceKind
from recovery.config import (
    ExtrinsicMode,
    OffsetRefineMethod,
    PoseFactorMode,
    TimeOffsetMode,
)
from recovery.solver.calibration_uncertainty import CalibrationCovariance
from recovery.solver.window import SolveOptions, WindowSolution
from recovery.noise.evidence import NoiseChoice
from recovery.noise.from_data import DataNoise
from recovery.solver.preintegration import ImuNoise


@dataclass(frozen=True)
class Inputs:
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
        data_noise: The white-noise densities read off the recording's rest when no calibration gave
            them (``imu_noise`` holds them), else None.
        rig: The pose stream against the IMU over the whole overlap (:func:`recovery.clock.coarse.screen_rig`:
            coarse clock offset, positions' unit, frame agreement), None when it could not be judged.
        placeholder_t_ns: Stamps (pose clock) of the placeholder frames dropped from the stream.
        densities_defaulted: No calibration, config override or rest gave the white-noise densities
            (the evidence may then lower them below the defaults, :func:`recovery.recover.density_grid`).
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
    data_noise: DataNoise | None = None
    rig: RigFit | None = None
    placeholder_t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    densities_defaulted: bool = False


@dataclass(frozen=True)
class ClockOffset:
    """Stages 2 and 5, the pose stream's clock offset (seconds to add to its stamps).

    Attributes:
        mode: FIXED or ESTIMATE (AUTO resolved).
        offset_s / std_s: The offset and its 1-sigma.
        coarse_method: The cross-correlation's signal (:func:`recovery.calibration_init.estimate_time_offset`),
            None when not estimated or when it failed.
        refine_method: How the graph cost refined it, None when it did not.
        search: The refinement's cost per offset (``recovery.json`` ``pose_time_offset_search``).
        warnings: Plain sentences.
        curvature_std_s: The refinement's sigma from the cost's curvature (None: not refined).
        window_offsets_s: The offset refined on the refinement window, then on the windows of
            :func:`recovery.clock.offset.offset_spread_windows`; ``std_s`` is at least their scatter.
        wide_search: The search over the whole overlap (:mod:`recovery.clock.coarse`; ``recovery.json``
            ``pose_time_offset_wide_search``), None when it did not run.
    """

    mode: TimeOffsetMode
    offset_s: float
    std_s: float
    coarse_method: str | None = None
    refine_method: OffsetRefineMethod | None = None
    search: tuple[dict[str, float], ...] = ()
    warnings: tuple[str, ...] = ()
    curvature_std_s: float | None = None
    window_offsets_s: tuple[float, ...] = ()
    wide_search: dict[str, Any] | None = None

    @property
    def method(self) -> str:
        """``recovery.json`` ``pose_time_offset_method``: e.g. ``correlation_gyro+graph_cost_newton``."""
        if self.mode != TimeOffsetMode.ESTIMATE:
            return "fixed"
        coarse = f"correlation_{self.coarse_method}" if self.coarse_method else "fixed"
        return coarse + (f"+{self.refine_method.value}" if self.refine_method else "")


@dataclass(frozen=True)
class CalibrationWindows:
    """Stage 3: ``overlap`` of the IMU and the (shifted) poses, and ``calib_window``, the
    ``calib_window_s`` inside it with the most rotation, where the calibration solves run."""

    overlap: tuple[int, int]
    calib_window: tuple[int, int]


@dataclass(frozen=True)
class ExtrinsicInit:
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


@dataclass(frozen=True)
class NoiseStage:
    """Stage 6: the noise model (``choice``), the position-only chained solution the segments may
    start from (``chain``), the evidence window's length and the grid-edge warnings."""

    choice: NoiseChoice
    chain: Any
    window_s: float | None
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class GravityStage:
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


@dataclass(frozen=True)
class FullSolve:
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
