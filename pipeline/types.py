"""The sequence data model: pure, typed containers with unit-carrying names.

Conventions (used everywhere in biasgt):
    * time stamps are int64 nanoseconds, ``t_ns`` [N];
    * angular rates in rad/s (``gyro_radps``), accelerations in m/s^2 (``acc_mps2``);
    * quaternions are Hamilton, scalar first, named ``quat_wxyz`` [N, 4];
    * ``T_a_b`` is the 4x4 pose of frame b expressed in frame a (maps points from b to a).

Containers do not sort, deduplicate or normalise: readers return what the file
holds and :mod:`pipeline.checks` reports and, when allowed, repairs it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, fields, make_dataclass, replace
from typing import Any

import numpy as np

from pipeline.errors import DataError

NS_PER_S = 1_000_000_000
#: Gravity's magnitude in biasgt's level world frames (EuRoC's, the simulator's) and its vector there
#: (z up); the standard gravity converts accelerometer readings in g.
GRAVITY_MPS2 = 9.81
DEFAULT_GRAVITY_MPS2 = (0.0, 0.0, -GRAVITY_MPS2)
STANDARD_GRAVITY_MPS2 = 9.80665


class Split(str, enum.Enum):
    """Role of a sequence for training: one value, one meaning everywhere (workflow config,
    ``biasgt windows``, the window dataset)."""

    TRAIN = "train"  # windowed; its windows train the model and give the normalisation statistics
    VAL = "val"  # windowed; model selection
    TEST = "test"  # windowed; final evaluation
    NONE = "none"  # no role in training: not windowed

    @property
    def windowed(self) -> bool:
        """Whether the sequence's windows go into the window dataset."""
        return self is not Split.NONE


class IntegrationScheme(str, enum.Enum):
    """How samples are integrated between two stamps (see :mod:`pipeline.geometry.integration`)."""

    EULER = "euler"  # sample k held over [t_k, t_{k+1}] (AirIMU / GTSAM), first order
    MIDPOINT = "midpoint"  # mid-point rotation, trapezoid velocity, second order


class PoseSourceKind(str, enum.Enum):
    """Where a pose stream comes from; decides how recovery weights it."""

    MOCAP = "mocap"  # full 6-DoF motion capture (Vicon, OptiTrack, ...)
    POSITION_TRACKER = "position_tracker"  # position only (Leica total station, GNSS)
    VIO = "vio"  # visual(-inertial) odometry: locally accurate, drifts globally
    GROUND_TRUTH = "ground_truth"  # a dataset's own fused ground-truth state


class Verdict(str, enum.Enum):
    """The project's one three-level judgement of whether something is usable.

    The validation's verdict on a bias (``validation.json``: PASS, WARN, FAIL; the rules are
    :mod:`validation.rules`) and the input checks' on a recording (PASS: nothing wrong, WARN:
    repairable, FAIL: fatal; ``biasgt inspect`` words them as
    :data:`pipeline.checks.options.CHECK_VERDICT_WORDS`).
    """

    PASS = "PASS"
    WARN = "WARN"
    FAIL = "FAIL"

    @classmethod
    def parse(cls, value: Any) -> Verdict | None:
        """The verdict a file holds (``"PASS"``, any case, or a :class:`Verdict`); None when it holds none
        or something else. Every reader of a written verdict compares what this returns, never the text."""
        if isinstance(value, cls):
            return value
        try:
            return cls(str(value).strip().upper())
        except ValueError:
            return None


class Severity(str, enum.Enum):
    """Severity of an input-check finding."""

    INFO = "info"
    WARNING = "warning"
    REPAIRABLE = "repairable"  # wrong, but ``convert`` can fix it when allowed
    FATAL = "fatal"  # the sequence cannot be written


@dataclass(frozen=True)
class Finding:
    """One result of an input check.

    Attributes:
        code: Stable identifier (e.g. ``"IMU_NON_MONOTONIC"``), part of the
            ``inspect --json`` contract.
        severity: How bad it is.
        stream: The stream it concerns (``"imu"``, ``"poses/vicon0"``, a topic, ...).
        message: One line that says what is wrong and how to fix it.
        details: JSON-serialisable extras (counts, times, line numbers).
    """

    code: str
    severity: Severity
    stream: str
    message: str
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "code": self.code,
            "severity": self.severity.value,
            "stream": self.stream,
            "message": self.message,
            "details": self.details,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Finding":
        return cls(d["code"], Severity(d["severity"]), d["stream"], d["message"], dict(d.get("details", {})))


def _as_array(name: str, value: Any, dtype: Any, width: int | None) -> np.ndarray:
    arr = np.ascontiguousarray(value, dtype=dtype)
    if width is None:
        if arr.ndim != 1:
            raise DataError(f"{name} must have shape [N], got {arr.shape}")
    elif arr.ndim != 2 or arr.shape[1] != width:
        raise DataError(f"{name} must have shape [N, {width}], got {arr.shape}")
    return arr


def _check_lengths(owner: str, t_ns: np.ndarray, **arrays: np.ndarray | None) -> None:
    for name, arr in arrays.items():
        if arr is not None and len(arr) != len(t_ns):
            raise DataError(f"{owner}.{name} has {len(arr)} rows but t_ns has {len(t_ns)}")


def _median_rate_hz(t_ns: np.ndarray) -> float:
    if len(t_ns) < 2:
        return float("nan")
    dt = np.diff(t_ns)
    dt = dt[dt > 0]
    if len(dt) == 0:
        return float("nan")
    return float(NS_PER_S / np.median(dt))


@dataclass(frozen=True)
class ImuSeries:
    """IMU readings.

    Attributes:
        t_ns: Stamps, int64 [N].
        gyro_radps: Angular rate, [N, 3].
        acc_mps2: Specific force, [N, 3].
        temperature_degc: Optional temperature, [N].
    """

    t_ns: np.ndarray
    gyro_radps: np.ndarray
    acc_mps2: np.ndarray
    temperature_degc: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", _as_array("t_ns", self.t_ns, np.int64, None))
        object.__setattr__(self, "gyro_radps", _as_array("gyro_radps", self.gyro_radps, np.float64, 3))
        object.__setattr__(self, "acc_mps2", _as_array("acc_mps2", self.acc_mps2, np.float64, 3))
        if self.temperature_degc is not None:
            object.__setattr__(
                self, "temperature_degc", _as_array("temperature_degc", self.temperature_degc, np.float64, None)
            )
        _check_lengths(
            "ImuSeries", self.t_ns, gyro_radps=self.gyro_radps, acc_mps2=self.acc_mps2,
            temperature_degc=self.temperature_degc,
        )

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def duration_s(self) -> float:
        return float(self.t_ns[-1] - self.t_ns[0]) / NS_PER_S if len(self) > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        """Nominal rate from the median positive stamp difference."""
        return _median_rate_hz(self.t_ns)

    @property
    def imu_6(self) -> np.ndarray:
        """Gyro then accelerometer, [N, 6]."""
        return np.hstack([self.gyro_radps, self.acc_mps2])

    def take(self, index: np.ndarray | slice) -> "ImuSeries":
        """Rows selected by an index array, boolean mask or slice."""
        temp = None if self.temperature_degc is None else self.temperature_degc[index]
        return ImuSeries(self.t_ns[index], self.gyro_radps[index], self.acc_mps2[index], temp)

    def between(self, t0_ns: int, t1_ns: int) -> "ImuSeries":
        """Rows with ``t0_ns <= t_ns <= t1_ns``."""
        return self.take((self.t_ns >= t0_ns) & (self.t_ns <= t1_ns))


@dataclass(frozen=True)
class PoseSeries:
    """Poses of a tracked frame in a world frame, ``T_world_<frame>``.

    Attributes:
        t_ns: Stamps on the pose source's clock, int64 [N].
        p_m: Positions of the tracked frame in the world frame, [N, 3].
        quat_wxyz: Orientations (world from tracked frame), [N, 4]; ``None``
            for position-only trackers.
        frame: Name of the tracked frame (``"vicon_marker"``, ``"leica_prism"``, ``"imu"``, ...).
        source_kind: What produced the stream.
        world_frame: Name of the world frame.
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray | None
    frame: str
    source_kind: PoseSourceKind
    world_frame: str = "world"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", _as_array("t_ns", self.t_ns, np.int64, None))
        object.__setattr__(self, "p_m", _as_array("p_m", self.p_m, np.float64, 3))
        if self.quat_wxyz is not None:
            object.__setattr__(self, "quat_wxyz", _as_array("quat_wxyz", self.quat_wxyz, np.float64, 4))
        object.__setattr__(self, "source_kind", PoseSourceKind(self.source_kind))
        _check_lengths("PoseSeries", self.t_ns, p_m=self.p_m, quat_wxyz=self.quat_wxyz)

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def has_orientation(self) -> bool:
        return self.quat_wxyz is not None

    @property
    def duration_s(self) -> float:
        return float(self.t_ns[-1] - self.t_ns[0]) / NS_PER_S if len(self) > 1 else 0.0

    @property
    def rate_hz(self) -> float:
        return _median_rate_hz(self.t_ns)

    def take(self, index: np.ndarray | slice) -> "PoseSeries":
        quat = None if self.quat_wxyz is None else self.quat_wxyz[index]
        return replace(self, t_ns=self.t_ns[index], p_m=self.p_m[index], quat_wxyz=quat)


@dataclass(frozen=True)
class StateSeries:
    """A full navigation state with bias, e.g. EuRoC's ``state_groundtruth_estimate0``.

    Attributes:
        t_ns: Stamps on the IMU clock, int64 [N].
        p_m: Position of the IMU (body) in the world frame, [N, 3].
        quat_wxyz: Orientation world-from-IMU, [N, 4].
        v_mps: Velocity in the world frame, [N, 3].
        bias_gyro_radps: Gyroscope bias, [N, 3].
        bias_acc_mps2: Accelerometer bias, [N, 3].
    """

    t_ns: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    bias_gyro_radps: np.ndarray
    bias_acc_mps2: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", _as_array("t_ns", self.t_ns, np.int64, None))
        for name, width in (("p_m", 3), ("quat_wxyz", 4), ("v_mps", 3), ("bias_gyro_radps", 3), ("bias_acc_mps2", 3)):
            object.__setattr__(self, name, _as_array(name, getattr(self, name), np.float64, width))
        _check_lengths(
            "StateSeries", self.t_ns, p_m=self.p_m, quat_wxyz=self.quat_wxyz, v_mps=self.v_mps,
            bias_gyro_radps=self.bias_gyro_radps, bias_acc_mps2=self.bias_acc_mps2,
        )

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def rate_hz(self) -> float:
        return _median_rate_hz(self.t_ns)

    @property
    def duration_s(self) -> float:
        return float(self.t_ns[-1] - self.t_ns[0]) / NS_PER_S if len(self) > 1 else 0.0

    def take(self, index: np.ndarray | slice) -> "StateSeries":
        return StateSeries(
            self.t_ns[index], self.p_m[index], self.quat_wxyz[index], self.v_mps[index],
            self.bias_gyro_radps[index], self.bias_acc_mps2[index],
        )

    def to_pose_series(self, frame: str = "imu") -> PoseSeries:
        """The poses of this state as a ground-truth pose stream."""
        return PoseSeries(self.t_ns, self.p_m, self.quat_wxyz, frame, PoseSourceKind.GROUND_TRUTH)


@dataclass(frozen=True)
class ImuNoiseModel:
    """The IMU's continuous-time noise: white-noise densities and bias random walks, the four values of a
    Kalibr ``sensor.yaml`` (``gyroscope_noise_density`` ...). The one definition of these four names: the
    calibration (:class:`ImuCalibration`), the recovery's preintegration noise and its config overrides,
    the noise read off a rest and the intrinsics fit carry them through this record. Defaults: the EuRoC
    (ADIS16448) datasheet's.

    Attributes:
        gyro_noise_density: rad/s/sqrt(Hz) (continuous-time white noise).
        gyro_random_walk: rad/s^2/sqrt(Hz) (bias random walk).
        acc_noise_density: m/s^2/sqrt(Hz).
        acc_random_walk: m/s^3/sqrt(Hz).
    """

    gyro_noise_density: float = 1.6968e-4
    gyro_random_walk: float = 1.9393e-5
    acc_noise_density: float = 2.0e-3
    acc_random_walk: float = 3.0e-3

    def noise_dict(self) -> dict[str, float]:
        """The four values by name (:data:`NOISE_FIELDS`)."""
        return {name: float(getattr(self, name)) for name in NOISE_FIELDS}

    def noise_model(self) -> "ImuNoiseModel":
        """The four values alone (a subclass's extra fields dropped)."""
        return ImuNoiseModel(**self.noise_dict())


#: The names of :class:`ImuNoiseModel`'s values, and of its white-noise densities.
NOISE_FIELDS = tuple(f.name for f in fields(ImuNoiseModel))
NOISE_DENSITY_FIELDS = tuple(name for name in NOISE_FIELDS if name.endswith("_noise_density"))
#: The same values, each optional (None: not given): the overrides a stage's config may carry.
ImuNoiseOverrides = make_dataclass("ImuNoiseOverrides", [(name, "float | None", field(default=None))
                                                        for name in NOISE_FIELDS])
ImuNoiseOverrides.__doc__ = ("Optional overrides of :class:`ImuNoiseModel`'s values (None: not given), a base "
                             "of a stage's config.")

#: What :meth:`ImuCalibration.value_sources` says of a value nobody gave.
CALIBRATION_DEFAULT_SOURCE = "default (EuRoC ADIS16448 datasheet)"


@dataclass(frozen=True)
class ImuCalibration(ImuNoiseModel):
    """IMU noise model (:class:`ImuNoiseModel`'s values, first) and known extrinsics.

    Attributes:
        rate_hz: Nominal IMU rate.
        gyro_bias_max_radps: The largest gyro bias per axis the sensor can have (its datasheet's bias
            range); a recovered bias beyond it is impossible. Default 0.35 rad/s (20 deg/s): well above
            the specified bias range of MEMS gyros (a few deg/s); ``gyroscope_bias_max`` in sensor.yaml.
        acc_bias_max_mps2: The same for the accelerometer. Default 2 m/s^2 (0.2 g): well above the
            specified bias range of MEMS accelerometers (tens of mg); ``accelerometer_bias_max``.
        T_body_imu: 4x4 pose of the IMU in the body frame (EuRoC ``T_BS`` of imu0).
        T_imu_frames: Known 4x4 ``T_imu_<frame>`` per tracked-frame name.
        sources: Where each noise value came from (attribute name -> a file path, or
            ``"config"``); a value not listed is the EuRoC ADIS16448 default
            (:data:`CALIBRATION_DEFAULT_SOURCE`).
    """

    rate_hz: float = 200.0
    gyro_bias_max_radps: float = 0.35
    acc_bias_max_mps2: float = 2.0
    T_body_imu: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_imu_frames: dict[str, np.ndarray] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)

    def value_sources(self) -> dict[str, str]:
        """Every noise value's origin (:data:`NOISE_FIELDS` -> file, ``config`` or the default)."""
        return {k: self.sources.get(k, CALIBRATION_DEFAULT_SOURCE) for k in NOISE_FIELDS}

    def defaulted(self) -> list[str]:
        """Noise values that are the EuRoC defaults, not read from anywhere."""
        return [k for k in NOISE_FIELDS if k not in self.sources]

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.noise_dict(),
            "rate_hz": float(self.rate_hz),
            "gyro_bias_max_radps": float(self.gyro_bias_max_radps),
            "acc_bias_max_mps2": float(self.acc_bias_max_mps2),
            "T_body_imu": np.asarray(self.T_body_imu, dtype=float).tolist(),
            "T_imu_frames": {k: np.asarray(v, dtype=float).tolist() for k, v in self.T_imu_frames.items()},
            "sources": dict(self.sources),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ImuCalibration":
        return cls(
            **{name: float(d[name]) for name in NOISE_FIELDS},
            rate_hz=float(d["rate_hz"]),
            gyro_bias_max_radps=float(d.get("gyro_bias_max_radps", cls.gyro_bias_max_radps)),
            acc_bias_max_mps2=float(d.get("acc_bias_max_mps2", cls.acc_bias_max_mps2)),
            T_body_imu=np.asarray(d.get("T_body_imu", np.eye(4)), dtype=float),
            T_imu_frames={k: np.asarray(v, dtype=float) for k, v in d.get("T_imu_frames", {}).items()},
            sources={str(k): str(v) for k, v in (d.get("sources") or {}).items()},
        )


@dataclass
class Sequence:
    """Everything biasgt knows about one recording.

    Attributes:
        name: Sequence name (``"V1_01_easy"``).
        imu: IMU readings, or ``None`` for pose-only inputs.
        poses: Pose streams by stream name (``"vicon0"``, ``"/odom"``, ...).
        ground_truth: Full ground-truth state with bias, if the dataset has one.
        calibration: IMU noise model and extrinsics.
        findings: What the reader found while parsing (skipped lines, precision loss).
        metadata: Free-form provenance (source path, source kind, repairs applied).
    """

    name: str
    imu: ImuSeries | None = None
    poses: dict[str, PoseSeries] = field(default_factory=dict)
    ground_truth: StateSeries | None = None
    calibration: ImuCalibration = field(default_factory=ImuCalibration)
    findings: list[Finding] = field(default_factory=list)
    metadata: dict[str, Any] = field(default_factory=dict)
