"""``simulate(config) -> Simulation``: an in-memory sequence with exactly known bias.

The IMU samples are instantaneous values of the continuous motion at the stamps, so
integrating the noise-free readings minus the true bias from the true initial state
reproduces the true trajectory up to the integrator's discretisation error.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ConfigError
from pipeline.io.registry import SOURCE_FORMAT_KEY
from pipeline.sim.config import SimConfig
from pipeline.sim.imu_model import BiasTruth, SensorMatrices, measure, sensor_matrices, simulate_bias
from pipeline.sim.motion import (
    RestThenMove,
    Trajectory,
    ground_truth_trajectory,
    quat_wxyz_continuous,
    random_trajectory,
    read_ground_truth_file,
)
from pipeline.sim.poses import PoseTruth, simulate_pose_stream
from pipeline.types import NOISE_FIELDS, ImuCalibration, ImuSeries, PoseSeries, Sequence, StateSeries

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


class _Stream(int, enum.Enum):
    """Ids of the independent random streams (``default_rng([seed, id])``); never renumber."""

    MOTION = 1
    TURN_ON = 2
    WALK = 3
    TEMPERATURE = 4
    IMU_NOISE = 5
    MATRICES = 6
    POSE_PHASE = 7
    POSE_NOISE = 8
    DROPOUTS = 9
    OUTLIERS = 10
    EXTRINSIC = 11
    VIO = 12
    POSE_CORRELATED = 13


class MotionSource(str, enum.Enum):
    """Where a simulation's motion comes from (``motion.ground_truth_path`` decides)."""

    RANDOM = "random"  # the motion preset's random splines
    GROUND_TRUTH_STATE = "ground_truth_state"  # semi-real: a EuRoC state file (motion and bias)
    GROUND_TRUTH_POSES = "ground_truth_poses"  # semi-real: a TUM pose file (motion only)


class BiasSource(str, enum.Enum):
    """Where a simulation's true bias comes from."""

    GROUND_TRUTH_FILE = "ground_truth_file"  # the state file's bias (real, recorded)
    SIMULATED = "simulated"  # the IMU model: turn-on + random walk + temperature terms


@dataclass(frozen=True)
class SimTruth:
    """Everything the simulation knows that a recovery stage must find.

    Attributes:
        t_ns: IMU stamps, int64 [N].
        bias_gyro_radps / bias_acc_mps2: True bias at the IMU stamps, [N, 3].
        bias: The bias draws (turn-on, temperature coefficients, temperature).
        matrices: Scale/misalignment/g-sensitivity actually applied.
        poses: Pose-stream truth (clock offset, extrinsic, dropouts, outliers, VIO drift).
        gravity_mps2: Gravity in the world frame, [3].
        motion_source: Random splines, or a ground-truth state or pose file (semi-real).
        bias_source: The ground-truth file's bias, or the IMU model's simulated one.
    """

    t_ns: np.ndarray
    bias_gyro_radps: np.ndarray
    bias_acc_mps2: np.ndarray
    bias: BiasTruth
    matrices: SensorMatrices
    poses: PoseTruth
    gravity_mps2: np.ndarray
    motion_source: MotionSource = MotionSource.RANDOM
    bias_source: BiasSource = BiasSource.SIMULATED

    @property
    def clock_offset_s(self) -> float:
        """Seconds to add to pose stamps to put them on the IMU clock."""
        return self.poses.clock_offset_s

    @property
    def T_imu_frame(self) -> np.ndarray:
        """True 4x4 ``T_imu_<frame>`` of the pose stream's tracked frame."""
        return self.poses.T_imu_frame


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`simulate`.

    Attributes:
        config: The resolved config (``duration_s`` filled in ground-truth mode).
        sequence: IMU, the pose stream, the true state (``ground_truth``, at IMU rate, with the
            true bias) and the REPORTED calibration.
        truth: True bias, clock offset, extrinsic, gravity, ...
        trajectory: The continuous true motion (time in seconds from the first IMU stamp).
    """

    config: SimConfig
    sequence: Sequence
    truth: SimTruth
    trajectory: Trajectory


def _rng(seed: int, stream: _Stream) -> np.random.Generator:
    return np.random.default_rng([seed, int(stream)])


def simulate(config: SimConfig) -> Simulation:
    """Simulate one sequence.

    Args:
        config: The simulation config (validated here).

    Returns:
        The simulation; same config -> identical arrays.

    Raises:
        ConfigError: Invalid config values.
        InputFormatError / DataError: Unreadable ground-truth file in semi-real mode.
    """
    config.validate()
    gravity = np.asarray(config.motion.gravity_mps2, dtype=float)
    config, gt_file, trajectory, t0_ns, duration_s = _motion(config)
    imu_cfg = config.imu

    period_ns = NS_PER_S / imu_cfg.rate_hz
    n = int(np.floor(duration_s * NS_PER_S / period_ns + 1e-9)) + 1
    rel_ns = np.round(np.arange(n) * period_ns).astype(np.int64)
    t_ns = t0_ns + rel_ns
    t_s = rel_ns / NS_PER_S

    motion = trajectory.sample(t_s)
    f_body = motion.specific_force(gravity)
    bias = _bias_truth(config, gt_file, t0_ns, rel_ns, t_s)
    matrices = sensor_matrices(imu_cfg, _rng(config.seed, _Stream.MATRICES))
    gyro, acc = measure(
        imu_cfg,
        motion.omega_body_radps,
        f_body,
        bias.bias_gyro_radps,
        bias.bias_acc_mps2,
        matrices,
        _rng(config.seed, _Stream.IMU_NOISE),
    )
    pose_series, pose_truth = simulate_pose_stream(config.poses, trajectory, t0_ns, duration_s,
                                                   _pose_rngs(config.seed))

    quat_wxyz = quat_wxyz_continuous(motion.rotation)
    ground_truth = StateSeries(t_ns, motion.p_m, quat_wxyz, motion.v_mps, bias.bias_gyro_radps, bias.bias_acc_mps2)
    sequence = Sequence(
        name=config.name,
        imu=ImuSeries(t_ns, gyro, acc, bias.temperature_degc),
        poses={pose_truth.stream: pose_series},
        ground_truth=ground_truth,
        calibration=_calibration(config, pose_truth),
        metadata={
            SOURCE_FORMAT_KEY: "simulation",
            "seed": int(config.seed),
            "ground_truth_path": None
            if config.motion.ground_truth_path is None
            else str(Path(config.motion.ground_truth_path)),
        },
    )
    truth = SimTruth(
        t_ns=t_ns,
        bias_gyro_radps=bias.bias_gyro_radps,
        bias_acc_mps2=bias.bias_acc_mps2,
        bias=bias,
        matrices=matrices,
        poses=pose_truth,
        gravity_mps2=gravity,
        motion_source=(MotionSource.RANDOM if gt_file is None else MotionSource.GROUND_TRUTH_STATE
                       if isinstance(gt_file, StateSeries) else MotionSource.GROUND_TRUTH_POSES),
        bias_source=BiasSource.GROUND_TRUTH_FILE if isinstance(gt_file, StateSeries) else BiasSource.SIMULATED,
    )
    return Simulation(config=config, sequence=sequence, truth=truth, trajectory=trajectory)


def _motion(config: SimConfig) -> tuple[SimConfig, StateSeries | PoseSeries | None, Trajectory, int, float]:
    """``(config, gt_file, trajectory, t0_ns, duration_s)``: the motion to simulate, random or (semi-real)
    from the ground-truth file, whose span sets the start time and may shorten the duration
    (``config`` is updated to match)."""
    imu_cfg = config.imu
    gt_file = None
    if config.motion.ground_truth_path is not None:
        gt_file = read_ground_truth_file(config.motion.ground_truth_path)
        margin_ns = int(round(config.motion.gt_margin_s * NS_PER_S))
        t0_ns = int(gt_file.t_ns[0]) + margin_ns
        available_s = (int(gt_file.t_ns[-1]) - margin_ns - t0_ns) / NS_PER_S
        if available_s <= 1.0:
            raise ConfigError(
                f"ground-truth file spans only {available_s + 2 * config.motion.gt_margin_s:.2f} s",
                path=config.motion.ground_truth_path,
            )
        duration_s = available_s if config.duration_s is None else min(config.duration_s, available_s)
        if config.duration_s is not None and config.duration_s > available_s:
            log.warning("duration %.2f s shortened to the ground truth's %.2f s", config.duration_s, available_s)
        trajectory = ground_truth_trajectory(
            gt_file,
            t0_ns,
            position_knot_interval_s=config.motion.gt_position_knot_interval_s,
            orientation_key_interval_s=config.motion.gt_orientation_key_interval_s,
        )
        config = dataclasses.replace(
            config,
            duration_s=duration_s,
            imu=dataclasses.replace(imu_cfg, start_time_ns=t0_ns),
        )
        imu_cfg = config.imu
    else:
        duration_s = float(config.duration_s)  # type: ignore[arg-type]
        t0_ns = int(imu_cfg.start_time_ns)
        params = config.motion.params()
        trajectory = random_trajectory(
            params, duration_s, _rng(config.seed, _Stream.MOTION), pad_s=2 * params.key_interval_s
        )
        if config.motion.rest_s > 0:
            trajectory = RestThenMove(trajectory, config.motion.rest_s)
    return config, gt_file, trajectory, t0_ns, duration_s


def _bias_truth(config: SimConfig, gt_file: StateSeries | PoseSeries | None, t0_ns: int, rel_ns: np.ndarray,
                t_s: np.ndarray) -> BiasTruth:
    """The true bias at the IMU stamps: the ground-truth state's (interpolated), else simulated."""
    imu_cfg = config.imu
    if isinstance(gt_file, StateSeries):
        # interpolate on times relative to t0 (int64 epoch ns do not fit float64 exactly)
        t_file = (gt_file.t_ns - t0_ns).astype(np.float64)
        t_rel = rel_ns.astype(np.float64)
        bg = np.column_stack([np.interp(t_rel, t_file, gt_file.bias_gyro_radps[:, i]) for i in range(3)])
        ba = np.column_stack([np.interp(t_rel, t_file, gt_file.bias_acc_mps2[:, i]) for i in range(3)])
        bias = BiasTruth(bg, ba, None, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    else:
        bias = simulate_bias(
            imu_cfg,
            t_s,
            _rng(config.seed, _Stream.TURN_ON),
            _rng(config.seed, _Stream.WALK),
            _rng(config.seed, _Stream.TEMPERATURE),
        )
    return bias


def _pose_rngs(seed: int) -> dict[str, np.random.Generator]:
    """One random stream per part of the pose simulation."""
    return {
        "extrinsic": _rng(seed, _Stream.EXTRINSIC),
        "phase": _rng(seed, _Stream.POSE_PHASE),
        "noise": _rng(seed, _Stream.POSE_NOISE),
        "dropouts": _rng(seed, _Stream.DROPOUTS),
        "outliers": _rng(seed, _Stream.OUTLIERS),
        "vio": _rng(seed, _Stream.VIO),
        "correlated": _rng(seed, _Stream.POSE_CORRELATED),
    }


def _calibration(config: SimConfig, pose_truth: PoseTruth) -> ImuCalibration:
    """The calibration a simulated recording ships: the datasheet (reported) noise values, and the
    pose frame's extrinsic when ``config.poses.extrinsic_known``."""
    imu_cfg = config.imu
    return ImuCalibration(
        gyro_noise_density=imu_cfg.reported_gyro_noise_density,
        gyro_random_walk=imu_cfg.reported_gyro_random_walk,
        acc_noise_density=imu_cfg.reported_acc_noise_density,
        acc_random_walk=imu_cfg.reported_acc_random_walk,
        rate_hz=imu_cfg.rate_hz,
        T_body_imu=np.eye(4),
        T_imu_frames={pose_truth.frame: pose_truth.T_imu_frame.copy()} if config.poses.extrinsic_known else {},
        sources=dict.fromkeys(NOISE_FIELDS, "simulator config (reported datasheet values)"),
    )
