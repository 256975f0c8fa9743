"""Configuration of the simulator: typed dataclasses with a strict dict/YAML round trip.

Every field has a unit in its name or docstring. ``SimConfig.from_dict`` rejects
unknown keys with a :class:`~pipeline.errors.ConfigError` that names the key, so a
typo in a YAML file never silently falls back to a default.

Motion presets (:class:`MotionPreset`; median / 95th percentile over 120-300 s of motion):

======================  ============  ===========  ============  ===============  ==========
preset                  key interval  waypoints    speed (m/s)   rate (rad/s)     roll/pitch
======================  ============  ===========  ============  ===============  ==========
``handheld``            1.5 s         +-0.8 m box  0.64 / 1.3    0.51 / 1.0       +-25 deg
``aggressive_drone``    1.0 s         +-2.5 m box  3.1 / 6.1     1.4 / 2.9        +-40 deg
``slow_cart``           4.0 s         +-2 m (xy)   0.53 / 1.2    0.08 / 0.29      +-2 deg
======================  ============  ===========  ============  ===============  ==========

With the default 200 Hz IMU, midpoint integration of the noise-free handheld and slow-cart
readings reproduces the true 1-s motion to < 1e-4 m and < 1e-3 deg; the aggressive drone's
1-s windows are reproduced to ~1e-4 m and ~2e-3 deg (the integrator's O(h^2) error).
"""

from __future__ import annotations

import dataclasses
import enum
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pipeline.configs import dataclass_to_mapping, unknown_keys_message
from pipeline.errors import ConfigError
from pipeline.types import DEFAULT_GRAVITY_MPS2

# EuRoC / ADIS16448 datasheet values (mav0/imu0/sensor.yaml).
EUROC_GYRO_NOISE_DENSITY = 1.6968e-4  # rad/s/sqrt(Hz)
EUROC_GYRO_RANDOM_WALK = 1.9393e-5  # rad/s^2/sqrt(Hz)
EUROC_ACC_NOISE_DENSITY = 2.0e-3  # m/s^2/sqrt(Hz)
EUROC_ACC_RANDOM_WALK = 3.0e-3  # m/s^3/sqrt(Hz)


class MotionPreset(str, enum.Enum):
    """Kinds of random motion; see the module docstring for their speeds and rates."""

    HANDHELD = "handheld"
    AGGRESSIVE_DRONE = "aggressive_drone"
    SLOW_CART = "slow_cart"


class PoseFormat(str, enum.Enum):
    """Which pose stream the simulation produces and how it is written."""

    MOCAP = "mocap"  # 6-DoF, mav0/mocap0/data.csv (Vicon-like)
    POSITION = "position"  # position only, mav0/leica0/data.csv (Leica-like)
    VIO = "vio"  # drifting 6-DoF odometry, vio_tum.txt (TUM text)


@dataclass(frozen=True)
class PresetParams:
    """Numbers behind a :class:`MotionPreset`.

    Attributes:
        key_interval_s: Spacing of the random waypoints / key orientations.
        position_amplitude_m: Half-size of the box the waypoints are drawn in, (x, y, z).
        max_roll_pitch_deg: Roll and pitch of the key orientations are uniform in +-this.
        yaw_step_deg: Standard deviation of the yaw change between key orientations.
    """

    key_interval_s: float
    position_amplitude_m: tuple[float, float, float]
    max_roll_pitch_deg: float
    yaw_step_deg: float


PRESETS: dict[MotionPreset, PresetParams] = {
    MotionPreset.HANDHELD: PresetParams(1.5, (0.8, 0.8, 0.3), 25.0, 40.0),
    MotionPreset.AGGRESSIVE_DRONE: PresetParams(1.0, (2.5, 2.5, 1.0), 40.0, 90.0),
    MotionPreset.SLOW_CART: PresetParams(4.0, (2.0, 2.0, 0.01), 2.0, 30.0),
}


@dataclass(frozen=True)
class TemperatureConfig:
    """A slow temperature profile and the bias it causes.

    The die temperature is ``T(t) = ambient + warmup_delta * (1 - exp(-t / warmup_tau)) +
    oscillation_amp * sin(2 pi t / oscillation_period)``. The bias term is
    ``coeff * (lag(T)(t) - reference)``: the temperature seen through a first-order lag
    ``sensor_tau_s`` (starting at ``T(0)``), relative to ``reference_degc`` (default ``T(0)``: the
    term starts at zero), times a per-axis coefficient: ``gyro_coeff_radps_per_degc`` /
    ``acc_coeff_mps2_per_degc`` when given (one IMU unit, the same in every sequence), else drawn
    per sequence with standard deviation ``gyro_coeff_sigma`` / ``acc_coeff_sigma``.

    Attributes:
        enabled: Add the temperature-driven bias term (the temperature is always reported).
        ambient_degc: Temperature at t = 0.
        warmup_delta_degc: Rise during warm-up.
        warmup_tau_s: Warm-up time constant.
        oscillation_amp_degc: Amplitude of a slow oscillation (air conditioning).
        oscillation_period_s: Its period.
        sensor_tau_s: Thermal lag between the die temperature and the bias.
        gyro_coeff_sigma: rad/s per degC.
        acc_coeff_sigma: m/s^2 per degC.
        reference_degc: Temperature at which the term is zero (None: the sequence's ``T(0)``).
        gyro_coeff_radps_per_degc: Fixed gyro coefficients [3] (None: drawn).
        acc_coeff_mps2_per_degc: Fixed accelerometer coefficients [3] (None: drawn).
    """

    enabled: bool = True
    ambient_degc: float = 25.0
    warmup_delta_degc: float = 8.0
    warmup_tau_s: float = 300.0
    oscillation_amp_degc: float = 0.5
    oscillation_period_s: float = 1200.0
    sensor_tau_s: float = 60.0
    gyro_coeff_sigma: float = 2.0e-4
    acc_coeff_sigma: float = 3.0e-3
    reference_degc: float | None = None
    gyro_coeff_radps_per_degc: tuple[float, float, float] | None = None
    acc_coeff_mps2_per_degc: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class ImuNoiseConfig:
    """The true IMU error model, and the noise values the simulated datasheet reports.

    Measurement model (body frame)::

        gyro = M_g @ omega + G @ f + b_g + n_g
        acc  = M_a @ f + b_a + n_a

    with ``b = turn_on + random_walk + temperature_term``, white noise of discrete
    standard deviation ``density * sqrt(rate_hz)`` and ``M = I + diag(scale) + misalignment``.

    Attributes:
        rate_hz: IMU rate.
        start_time_ns: Stamp of the first IMU sample (int64 ns, a realistic epoch with sub-ms digits).
        white_noise: Add white noise.
        gyro_noise_density: True gyro white noise, rad/s/sqrt(Hz).
        acc_noise_density: True accelerometer white noise, m/s^2/sqrt(Hz).
        bias_random_walk: Add the bias random walk.
        gyro_random_walk: True gyro bias random walk, rad/s^2/sqrt(Hz) (default 10x EuRoC datasheet).
        acc_random_walk: True accelerometer bias random walk, m/s^3/sqrt(Hz) (default 10x datasheet).
        turn_on_bias: Add a random constant turn-on bias.
        gyro_turn_on_sigma: rad/s.
        acc_turn_on_sigma: m/s^2.
        gyro_turn_on_mean_radps / acc_turn_on_mean_mps2: The unit's repeatable turn-on bias [3], to which
            each run adds its draw of the sigmas above (one IMU unit: the same in every sequence; None: 0).
        temperature: Temperature-driven bias term.
        gyro_scale_sigma / acc_scale_sigma: Std of the diagonal scale-factor errors (0 = off).
        gyro_misalignment_sigma / acc_misalignment_sigma: Std of the off-diagonal terms, rad (0 = off).
        gyro_g_sensitivity_sigma: Std of the entries of G, rad/s per m/s^2 (0 = off).
        reported_*: What ``sensor.yaml`` and ``Sequence.calibration`` claim (the datasheet),
            which may differ from the true values above.
    """

    rate_hz: float = 200.0
    start_time_ns: int = 1_400_000_000_123_456_789
    white_noise: bool = True
    gyro_noise_density: float = EUROC_GYRO_NOISE_DENSITY
    acc_noise_density: float = EUROC_ACC_NOISE_DENSITY
    bias_random_walk: bool = True
    gyro_random_walk: float = 10.0 * EUROC_GYRO_RANDOM_WALK
    acc_random_walk: float = 10.0 * EUROC_ACC_RANDOM_WALK
    turn_on_bias: bool = True
    gyro_turn_on_sigma: float = 0.02
    acc_turn_on_sigma: float = 0.1
    gyro_turn_on_mean_radps: tuple[float, float, float] | None = None
    acc_turn_on_mean_mps2: tuple[float, float, float] | None = None
    temperature: TemperatureConfig = field(default_factory=TemperatureConfig)
    gyro_scale_sigma: float = 0.0
    acc_scale_sigma: float = 0.0
    gyro_misalignment_sigma: float = 0.0
    acc_misalignment_sigma: float = 0.0
    gyro_g_sensitivity_sigma: float = 0.0
    reported_gyro_noise_density: float = EUROC_GYRO_NOISE_DENSITY
    reported_gyro_random_walk: float = EUROC_GYRO_RANDOM_WALK
    reported_acc_noise_density: float = EUROC_ACC_NOISE_DENSITY
    reported_acc_random_walk: float = EUROC_ACC_RANDOM_WALK


@dataclass(frozen=True)
class MotionConfig:
    """The true motion of the IMU.

    Attributes:
        preset: Kind of random motion; the ``None`` fields below take the preset's values.
        key_interval_s: Spacing of the random waypoints and key orientations.
        position_amplitude_m: Half-size of the waypoint box (x, y, z).
        max_roll_pitch_deg: Bound on roll and pitch of the key orientations.
        yaw_step_deg: Std of the yaw change between key orientations (yaw is unbounded).
        gravity_mps2: Gravity vector in the world frame.
        ground_truth_path: A EuRoC ``state_groundtruth_estimate0/data.csv``: when set, the
            motion AND the bias come from that file ("semi-real" mode) and the preset is unused.
            A TUM pose file of the IMU (``t[s] x y z qx qy qz qw``) gives the motion only; the
            bias is then the IMU model's (``SimTruth.bias_source`` says which).
        gt_position_knot_interval_s: Knot spacing of the least-squares position spline fitted
            to the file (larger = smoother derived accelerometer).
        gt_orientation_key_interval_s: Spacing of the file's orientations used as spline keys.
        gt_margin_s: Seconds dropped at both ends of the file (spline end effects).
        rest_s: Seconds at rest at the start of a random motion (the IMU still at the motion's first
            pose), followed by a smooth 2-s start (:class:`pipeline.sim.motion.RestThenMove`); 0: none.
    """

    preset: MotionPreset = MotionPreset.HANDHELD
    key_interval_s: float | None = None
    position_amplitude_m: tuple[float, float, float] | None = None
    max_roll_pitch_deg: float | None = None
    yaw_step_deg: float | None = None
    gravity_mps2: tuple[float, float, float] = DEFAULT_GRAVITY_MPS2
    ground_truth_path: str | None = None
    gt_position_knot_interval_s: float = 0.1
    gt_orientation_key_interval_s: float = 0.05
    gt_margin_s: float = 0.5
    rest_s: float = 0.0

    def params(self) -> PresetParams:
        """The preset's numbers with this config's overrides applied."""
        base = PRESETS[self.preset]
        return PresetParams(
            key_interval_s=base.key_interval_s if self.key_interval_s is None else float(self.key_interval_s),
            position_amplitude_m=base.position_amplitude_m
            if self.position_amplitude_m is None
            else tuple(float(x) for x in self.position_amplitude_m),  # type: ignore[arg-type]
            max_roll_pitch_deg=base.max_roll_pitch_deg
            if self.max_roll_pitch_deg is None
            else float(self.max_roll_pitch_deg),
            yaw_step_deg=base.yaw_step_deg if self.yaw_step_deg is None else float(self.yaw_step_deg),
        )


@dataclass(frozen=True)
class PoseStreamConfig:
    """The simulated pose sensor.

    Time convention: ``clock_offset_s`` is the recovery contract's ``pose_time_offset_s``,
    the seconds to ADD to a pose stamp to put it on the IMU clock
    (``t_imu_clock = pose_stamp + clock_offset_s``).

    Attributes:
        format: Mocap (6-DoF), position-only (Leica-like) or VIO-like (drifting, TUM text).
        rate_hz: Pose rate; stamps are on their own grid with a random phase.
        position_noise_m: Std of white position noise per axis.
        rotation_noise_rad: Std of white rotation noise per axis (right-multiplied).
        correlated_position_noise_m / correlated_rotation_noise_rad: Stationary std per axis of a
            first-order Gauss-Markov pose error (world-frame position, right-multiplied rotation) on
            top of the white noise: the slow error of real motion capture.
        correlated_noise_tau_s: Its correlation time.
        dropouts: Number of gaps with no poses.
        dropout_max_s: Longest gap (each gap is uniform in [dropout_max_s / 2, dropout_max_s]).
        outliers: Number of samples displaced by ``outlier_offset_m`` in a random direction.
        outlier_offset_m: Size of an outlier's displacement.
        clock_offset_s: See above.
        extrinsic_rotation_deg: Angle of ``T_imu_<frame>``'s rotation about a random axis.
        extrinsic_translation_m: Length of its translation along a random direction.
        extrinsic_rotvec_deg: Explicit rotation vector (deg); overrides the random rotation.
        extrinsic_translation_xyz_m: Explicit translation; overrides the random translation.
        extrinsic_known: Write ``T_BS`` to the stream's ``sensor.yaml`` (and the calibration).
        vio_position_drift_m_per_sqrt_s: VIO position random-walk drift.
        vio_yaw_drift_rad_per_sqrt_s: VIO yaw random-walk drift.
    """

    format: PoseFormat = PoseFormat.MOCAP
    rate_hz: float = 100.0
    position_noise_m: float = 0.5e-3
    rotation_noise_rad: float = 0.5e-3
    correlated_position_noise_m: float = 0.0
    correlated_rotation_noise_rad: float = 0.0
    correlated_noise_tau_s: float = 1.0
    dropouts: int = 0
    dropout_max_s: float = 0.5
    outliers: int = 0
    outlier_offset_m: float = 0.1
    clock_offset_s: float = 0.0
    extrinsic_rotation_deg: float = 0.0
    extrinsic_translation_m: float = 0.0
    extrinsic_rotvec_deg: tuple[float, float, float] | None = None
    extrinsic_translation_xyz_m: tuple[float, float, float] | None = None
    extrinsic_known: bool = False
    vio_position_drift_m_per_sqrt_s: float = 0.01
    vio_yaw_drift_rad_per_sqrt_s: float = 0.002


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines one simulated sequence (same config + seed -> same bytes).

    Attributes:
        duration_s: Length of the IMU record. ``None`` only in ground-truth mode: use the
            whole file.
        seed: Seed of every random draw (each component has its own stream, so switching
            one component off does not change the others).
        imu: IMU error model.
        motion: True motion.
        poses: Pose sensor.
        name: Sequence name.
    """

    duration_s: float | None = 60.0
    seed: int = 0
    imu: ImuNoiseConfig = field(default_factory=ImuNoiseConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    poses: PoseStreamConfig = field(default_factory=PoseStreamConfig)
    name: str = "sim"

    def validate(self) -> "SimConfig":
        """Raise :class:`ConfigError` for values that cannot be simulated; returns self."""
        if self.duration_s is None:
            if self.motion.ground_truth_path is None:
                raise ConfigError("duration_s is required without motion.ground_truth_path", field="duration_s")
        elif not self.duration_s > 0:
            raise ConfigError(f"duration_s must be > 0, got {self.duration_s}", field="duration_s")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}", field="seed")
        if not self.imu.rate_hz > 0:
            raise ConfigError(f"imu.rate_hz must be > 0, got {self.imu.rate_hz}", field="imu.rate_hz")
        if not self.poses.rate_hz > 0:
            raise ConfigError(f"poses.rate_hz must be > 0, got {self.poses.rate_hz}", field="poses.rate_hz")
        for name in ("dropouts", "outliers"):
            if getattr(self.poses, name) < 0:
                raise ConfigError(f"poses.{name} must be >= 0", field=f"poses.{name}")
        if not self.motion.rest_s >= 0 or (self.motion.rest_s and self.motion.ground_truth_path is not None):
            raise ConfigError("motion.rest_s must be >= 0 and applies to a random motion only", field="motion.rest_s")
        if self.motion.params().key_interval_s <= 0:
            raise ConfigError("motion.key_interval_s must be > 0", field="motion.key_interval_s")
        for name in ("position_noise_m", "rotation_noise_rad", "dropout_max_s", "outlier_offset_m",
                     "correlated_position_noise_m", "correlated_rotation_noise_rad"):
            if getattr(self.poses, name) < 0:
                raise ConfigError(f"poses.{name} must be >= 0", field=f"poses.{name}")
        if not self.poses.correlated_noise_tau_s > 0:
            raise ConfigError("poses.correlated_noise_tau_s must be > 0", field="poses.correlated_noise_tau_s")
        return self

    def noise_free(self) -> "SimConfig":
        """The same sequence without white IMU noise and without pose noise (bias is kept)."""
        return dataclasses.replace(
            self,
            imu=dataclasses.replace(self.imu, white_noise=False),
            poses=dataclasses.replace(self.poses, position_noise_m=0.0, rotation_noise_rad=0.0,
                                      correlated_position_noise_m=0.0, correlated_rotation_noise_rad=0.0),
        )

    # -- dict / YAML round trip -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain, YAML-safe dict (enums as values, tuples as lists)."""
        return dataclass_to_mapping(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, path: str | Path | None = None) -> "SimConfig":
        """Build from a (possibly partial) dict; unknown keys raise :class:`ConfigError`."""
        return _from_plain(cls, d, prefix="", path=path).validate()

    @classmethod
    def from_yaml(cls, path: str | Path) -> "SimConfig":
        """Read a YAML file holding a (possibly partial) config."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError("config file not found", path=path) from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"not valid YAML: {exc}", path=path) from None
        if data is None:
            data = {}
        return cls.from_dict(data, path=path)


def _convert(tp: Any, value: Any, key: str, path: str | Path | None) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            if type(None) in typing.get_args(tp):
                return None
            raise ConfigError("must not be null", path=path, field=key)
        return _convert(args[0], value, key, path)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"must be a mapping, got {type(value).__name__}", path=path, field=key)
        return _from_plain(tp, value, prefix=key + ".", path=path)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        if isinstance(value, tp):
            return value
        try:
            return tp(str(value).lower())
        except ValueError:
            allowed = ", ".join(m.value for m in tp)
            raise ConfigError(f"unknown value {value!r}", path=path, field=key, hint=f"use one of {allowed}") from None
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise ConfigError(f"must be a list of {len(args)} numbers, got {value!r}", path=path, field=key)
        return tuple(_convert(a, v, key, path) for a, v in zip(args, value))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"must be true or false, got {value!r}", path=path, field=key)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"must be an integer, got {value!r}", path=path, field=key)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"must be a number, got {value!r}", path=path, field=key)
        return float(value)
    if tp is str:
        if not isinstance(value, (str, Path)):
            raise ConfigError(f"must be a string, got {value!r}", path=path, field=key)
        return str(value)
    return value


def _from_plain(cls: type, d: dict[str, Any], *, prefix: str, path: str | Path | None) -> Any:
    if not isinstance(d, dict):
        raise ConfigError(f"must be a mapping, got {type(d).__name__}", path=path, field=prefix.rstrip(".") or None)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = unknown_keys_message([prefix + str(k) for k in d], [prefix + n for n in names])
    if unknown:
        raise ConfigError(unknown, path=path,
                          hint=f"allowed keys in {prefix.rstrip('.') or 'the top level'}: {', '.join(sorted(names))}")
    kwargs = {k: _convert(hints[k], v, prefix + k, path) for k, v in d.items()}
    return cls(**kwargs)
