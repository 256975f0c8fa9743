"""Configuration of bias recovery: one dataclass, enums for every mode.

``RecoveryConfig.from_dict`` rejects unknown keys with a :class:`ConfigError`
naming the key, so a typo in a YAML file never silently falls back to a default.
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.configs import dataclass_from_mapping, dataclass_to_mapping
from pipeline.errors import ConfigError
from pipeline.types import GRAVITY_MPS2, NOISE_FIELDS, ImuNoiseOverrides, PoseSourceKind
from recovery.intrinsics.posterior import IntrinsicsPrior

_PRIOR = IntrinsicsPrior()  # the defaults of the intrinsics_prior_* fields


class PoseFactorMode(str, enum.Enum):
    """How pose measurements enter the graph.

    ABSOLUTE: one prior per pose (mocap, ground truth, position trackers).
    RELATIVE: BetweenFactors over a short horizon (VIO): global drift of the
        source cannot leak into the bias, at the price of weaker constraints.
        Trade-off: an absolute factor on a drifting VIO pose explains the drift
        as acceleration (acc bias) and rotation rate (gyro bias); relative factors
        over ``relative_horizon`` keyframes (~0.1-0.3 s) see only the local,
        accurate motion, so the bias is less constrained (larger std) but unbiased.
    AUTO: ABSOLUTE for MOCAP / POSITION_TRACKER / GROUND_TRUTH, RELATIVE for VIO.
    """

    AUTO = "auto"
    ABSOLUTE = "absolute"
    RELATIVE = "relative"


class ExtrinsicMode(str, enum.Enum):
    """Where ``T_imu_pose`` comes from.

    KNOWN: the calibration (``T_imu_frames[frame]``), identity when absent.
    ESTIMATE: initialise from the data and refine jointly in the graph.
    PRIOR: ESTIMATE with the calibration's value as a prior of ``extrinsic_prior_rotation_deg`` /
        ``extrinsic_prior_translation_m`` per axis (KNOWN where the motion does not make it observable).
    AUTO: PRIOR when the calibration names the tracked frame, KNOWN when the frame is the IMU
        itself, else ESTIMATE.
    """

    AUTO = "auto"
    KNOWN = "known"
    ESTIMATE = "estimate"
    PRIOR = "prior"


class CalibrationSolve(str, enum.Enum):
    """The decimated calibration solves; each has its ``<value>_keyframe_rate_hz`` option."""

    OFFSET_REFINE = "offset_refine"
    EXTRINSIC = "extrinsic"
    GRAVITY = "gravity"
    NOISE = "noise"


class OffsetRefineMethod(str, enum.Enum):
    """How the graph cost refined the clock offset (``recovery.json`` ``pose_time_offset_method``)."""

    NEWTON = "graph_cost_newton"  # Newton steps on the cost's analytic slope and curvature (6-DoF poses)
    PARABOLA = "graph_cost_parabola"  # a parabola through the cost at three offsets


class PoseSigmaMethod(str, enum.Enum):
    """How the pose sigmas were chosen (``recovery.json`` ``noise.pose_sigma_method``)."""

    EVIDENCE = "evidence"  # a common scale of both sigmas by maximum evidence
    WITHIN_BIN_RESIDUALS = "within_bin_residuals"  # closed form from the scatter of fused samples
    FIXED = "fixed"  # as given (noise_estimation: fixed)


class RobustLoss(str, enum.Enum):
    """M-estimator on pose factors."""

    HUBER = "huber"
    CAUCHY = "cauchy"
    NONE = "none"


class TimeOffsetMode(str, enum.Enum):
    """How the pose-to-IMU clock offset is obtained.

    FIXED: use ``time_offset_s`` as given.
    ESTIMATE: coarse correlation estimate, refined by a 1-D search of the
        optimised cost (parabolic fit), with an uncertainty.
    AUTO: FIXED (0 when not given) for GROUND_TRUTH streams, which are on the
        IMU clock by construction; ESTIMATE otherwise.
    """

    AUTO = "auto"
    FIXED = "fixed"
    ESTIMATE = "estimate"


class IntrinsicsMode(str, enum.Enum):
    """Which IMU intrinsics are estimated around the solve (:mod:`recovery.intrinsics.estimate`).

    AUTO: WITH_G_SENSITIVITY when the plain solve's gyro reads a share of the rate in every
        frequency band against a 6-DoF absolute pose stream (an intrinsic error:
        :func:`recovery.intrinsics.gyro_consistency.rate_coupling`, on the solved offset and extrinsic),
        else OFF. The check costs < 1 % of a recovery; each round of the loop a full solve.
    OFF: none (readings taken as they are; the bias absorbs scale and misalignment errors).
    SCALE_MISALIGNMENT: gyro and accelerometer scale and misalignment.
    WITH_G_SENSITIVITY: those and the gyro's g-sensitivity.
    """

    AUTO = "auto"
    OFF = "off"
    SCALE_MISALIGNMENT = "scale_misalignment"
    WITH_G_SENSITIVITY = "with_g_sensitivity"


class NoiseEstimation(str, enum.Enum):
    """How bias random-walk strengths are chosen.

    EVIDENCE: maximise the Laplace-approximated marginal likelihood over a grid
        of inflation factors of the calibration's random walks (gyro and acc
        separately), on a decimated graph.
    FIXED: use the calibration (times ``*_random_walk_scale``) as given.
    """

    EVIDENCE = "evidence"
    FIXED = "fixed"


class PoseErrorMode(str, enum.Enum):
    """How the time-correlated error of a 6-DoF absolute pose stream is modelled (:mod:`recovery.solver.pose_error`).

    AUTO: a first-order Gauss-Markov error per axis group (rotation, position), its sigma (zero
        included: none) and correlation time chosen by evidence with the random walks.
    WHITE: none; the pose noise is white.
    FIXED: the ``pose_error_*`` sigmas and correlation times as given.
    """

    AUTO = "auto"
    WHITE = "white"
    FIXED = "fixed"


class ImuGapPolicy(str, enum.Enum):
    """What to do with an IMU gap longer than ``max_imu_gap_s``.

    SPLIT: recover each gap-free piece separately; no keyframe inside a gap.
    REFUSE: raise a RecoveryError.
    """

    SPLIT = "split"
    REFUSE = "refuse"


@dataclass
class RecoveryConfig(ImuNoiseOverrides):
    """All knobs of :func:`recovery.recover.recover`.

    Attributes:
        pose_factor_mode: See :class:`PoseFactorMode`.
        keyframe_rate_hz: Keyframes per second. ``None`` (default): every pose sample's
            information -- 10-Hz keyframes with the samples in between fused into them for
            6-DoF absolute streams (``pose_fusion``), each sample a keyframe otherwise.
        pose_fusion: Fuse the pose samples between keyframes into them through the IMU
            (:mod:`recovery.solver.fusion`; 6-DoF absolute streams). ``False``: keyframes are single
            samples and the samples between them are dropped (every sample with
            ``keyframe_rate_hz: null``: slower, the same information).
        relative_horizon: RELATIVE mode: number of keyframes each BetweenFactor spans
            (factors from every keyframe to the next ``relative_horizon`` ones).
        time_offset_mode: See :class:`TimeOffsetMode`.
        time_offset_s: Seconds added to pose stamps (FIXED mode, or the coarse start).
        max_time_offset_s: Search range of the coarse offset estimate.
        offset_refine_step_s: Largest grid step of the offset refinement (the step is
            2x the coarse std, clamped to [step/8, step]).
        offset_refine_keyframe_rate_hz: Keyframe rate of the refinement solves (``None``: auto,
            :data:`CALIBRATION_RATE_FUSED_HZ` with fused keyframes, else :data:`CALIBRATION_RATE_HZ`;
            the same for the other calibration solves below).
        calib_window_s: Length of data used for offset / extrinsic / noise estimation.
        offset_refine_window_s: Length of the (most rotating) data the clock-offset refinement
            solves; ``None``: :data:`OFFSET_WINDOW_FUSED_S` with fused keyframes, else ``calib_window_s``.
        extrinsic_mode: See :class:`ExtrinsicMode`.
        keep_frame_disagreement: Write a result whose IMU and pose stream disagree about the body frame
            (:mod:`recovery.frame.check`) with a warning, for the verdict to judge (it FAILs on plausibility),
            instead of refusing it.
        extrinsic_keyframe_rate_hz: Keyframe rate of the joint extrinsic solve.
        extrinsic_prior_rotation_deg / extrinsic_prior_translation_m: 1-sigma per axis of the prior a
            calibration's ``T_imu_pose`` puts on its estimate (PRIOR): a calibration file's extrinsic
            is rarely better than a few degrees and centimetres.
        extrinsic_max_sigmas: The estimate's difference from the calibration beyond this many of its
            sigmas is reported (a warning, and a limitation of the verdict).
        estimate_gravity: Estimate the gravity direction in the pose world frame; ``None`` (auto):
            no for POSITION_TRACKER streams (levelled frames), for motion-capture and ground-truth
            frames only where the tilt stands out (``gravity_tilt_sigmas``), else yes.
        gravity_mps2: Gravity magnitude.
        gravity_window_s: Longest span of the decimated solve that estimates the
            gravity direction (then the prior of the per-segment gravity variable).
        gravity_keyframe_rate_hz: Keyframe rate of that solve.
        gravity_tilt_sigmas / gravity_level_tolerance_deg: With ``estimate_gravity`` automatic, a
            motion-capture or ground-truth frame (level by convention) keeps its nominal gravity (-z),
            and the bias consistent with it, unless the estimated tilt exceeds both this many of its
            sigmas (the data tell it from the accelerometer bias) and this many degrees; then the tilt
            is kept and reported. The default tolerance is 0: a tilt the data resolve, however small,
            is kept, since a level gravity in a tilted frame leaks ``|g| sin(tilt)`` (0.09 m/s^2 at
            0.5 deg) into the accelerometer bias, turning with the IMU's attitude.
        position_sigma_m: Pose position noise; ``None`` = default of the source kind.
        rotation_sigma_rad: Pose rotation noise; ``None`` = default of the source kind.
        gyro_noise_density / gyro_random_walk / acc_noise_density / acc_random_walk: Override the
            calibration's IMU noise (:class:`~pipeline.types.ImuNoiseModel`'s values; the fields of
            :data:`~pipeline.types.ImuNoiseOverrides`, this config's base).
        noise_estimation: See :class:`NoiseEstimation`.
        random_walk_scales: Candidate inflation factors of the random walks (relative to
            the calibration / sensor.yaml) for EVIDENCE; their min and max bound the search.
            A narrow range keeps a pose stream with artefacts from choosing a random walk so loose
            that the bias absorbs them; hitting a bound is reported in ``recovery.json`` warnings.
        noise_density_scales: Candidate factors of the calibration's white noise densities (gyro and
            acc separately) for EVIDENCE (a flying platform's vibration raises them far above a
            datasheet's); ``[1]``: as given. Factors below 1 apply only to densities nobody gave (no
            calibration, override or rest): given densities are a floor (:func:`recovery.recover.density_grid`).
        pose_sigma_scales: Candidate factors of the pose sigmas (ignored when
            ``position_sigma_m`` is given).
        noise_keyframe_rate_hz: Keyframe rate of the evidence solves.
        pose_error: See :class:`PoseErrorMode`.
        pose_error_rotation_sigma_rad / pose_error_position_sigma_m: The correlated error's stationary
            1-sigma per axis (FIXED; 0: none).
        pose_error_rotation_tau_s / pose_error_position_tau_s: Its correlation times (FIXED).
        pose_error_sigma_scales: AUTO: candidate sigmas of the correlated error, in units of the white
            pose sigma per sample (0: none).
        pose_error_taus_s: AUTO: candidate correlation times.
        position_only_window_s: Position-only streams (no orientation measured): the noise
            evidence window and the segments span up to this long instead of ``calib_window_s`` /
            ``segment_s``. From positions the gyro bias about gravity is seen only through the
            heading drift it causes (information ~ window^3), so the walk of the bias and the
            bias itself need minutes of data.
            Memory grows with the keyframes per segment (300 s at 20 Hz: 6000).
        integration_sigma: Preintegration integration noise (GTSAM integrationCovariance).
        robust_loss: See :class:`RobustLoss`.
        robust_k: Threshold of the M-estimator, in sigmas of a 1-D error. GTSAM weighs a
            factor by the norm of its whole whitened error, so a factor of dimension d gets the
            chi(d) threshold with the same tail probability (3 -> 3.76 for the 3-D velocity
            priors, 4.48 for 6-DoF pose factors; :func:`recovery.solver.factors.robust_norm_threshold`).
        outlier_threshold: After convergence, a pose factor whose whitened residual
            (per-DoF RMS) exceeds this many sigmas is counted in ``outliers_rejected``,
            removed, and the window solved again.
        segment_s: Segment length for long recordings (bounded memory: peak memory
            grows with the keyframes per segment; run time barely depends on it). ``None``:
            :data:`SEGMENT_KEYFRAMES` keyframes at the solve's keyframe rate, within
            [:data:`SEGMENT_S_MIN`, :data:`SEGMENT_S_MAX`] (300 s at 10 or 20 Hz, 60 s at 100 Hz).
        segment_overlap_s: Overlap between segments (blended linearly); ``None``: a sixth of
            ``segment_s``.
        max_imu_gap_s: Longest IMU gap bridged; see ``imu_gap_policy``.
        imu_gap_policy: See :class:`ImuGapPolicy`.
        intrinsics: See :class:`IntrinsicsMode` (AUTO: estimated when the gyro shows an intrinsic error).
        intrinsics_block_s: Blocks (gyro) and low-pass time scale (accelerometer) of the solved bias the
            intrinsics fit starts from.
        intrinsics_prior_scale_misalignment / intrinsics_prior_g_sensitivity /
            intrinsics_prior_non_orthogonality / intrinsics_prior_calibration_rotation_rad: The intrinsic
            terms' sizes (1 sigma) before the data, a MEMS datasheet's by default
            (:class:`recovery.intrinsics.posterior.IntrinsicsPrior`): a term the fit cannot tell from the bias
            keeps them in the bias sigma, so give a better IMU's or calibration's own.
        min_poses: Fewest pose samples accepted.
        max_iterations: LM iteration limit.
        relative_error_tol: LM relative error tolerance.
        min_rotation_excitation_deg: Below this rotation spread the extrinsic
            rotation is declared unobservable.
        compute_marginals: Compute the bias standard deviations (*_std columns).
        marginal_rate_hz: Exact marginals on this grid (plus ends and gap edges),
            linearly interpolated between; ``None`` = at every keyframe (slower).
    """

    pose_factor_mode: PoseFactorMode = PoseFactorMode.AUTO
    keyframe_rate_hz: float | None = None
    pose_fusion: bool = True
    relative_horizon: int = 5
    time_offset_mode: TimeOffsetMode = TimeOffsetMode.AUTO
    time_offset_s: float = 0.0
    max_time_offset_s: float = 0.5
    offset_refine_step_s: float = 0.002
    offset_refine_keyframe_rate_hz: float | None = None
    calib_window_s: float = 60.0
    offset_refine_window_s: float | None = None
    extrinsic_mode: ExtrinsicMode = ExtrinsicMode.AUTO
    extrinsic_keyframe_rate_hz: float | None = None
    extrinsic_prior_rotation_deg: float = 5.0
    extrinsic_prior_translation_m: float = 0.05
    extrinsic_max_sigmas: float = 3.0
    estimate_gravity: bool | None = None
    gravity_mps2: float = GRAVITY_MPS2
    gravity_window_s: float = 300.0
    gravity_keyframe_rate_hz: float | None = None
    gravity_tilt_sigmas: float = 3.0
    gravity_level_tolerance_deg: float = 0.0
    position_sigma_m: float | None = None
    rotation_sigma_rad: float | None = None
    noise_estimation: NoiseEstimation = NoiseEstimation.EVIDENCE
    random_walk_scales: list[float] = field(default_factory=lambda: [0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0])
    noise_density_scales: list[float] = field(default_factory=lambda: [0.3, 1.0, 3.0, 10.0, 30.0])
    pose_sigma_scales: list[float] = field(default_factory=lambda: [0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0])
    noise_keyframe_rate_hz: float | None = None
    pose_error: PoseErrorMode = PoseErrorMode.AUTO
    pose_error_rotation_sigma_rad: float = 0.0
    pose_error_rotation_tau_s: float = 1.0
    pose_error_position_sigma_m: float = 0.0
    pose_error_position_tau_s: float = 1.0
    pose_error_sigma_scales: list[float] = field(default_factory=lambda: [0.0, 1.0, 3.0, 10.0, 30.0])
    pose_error_taus_s: list[float] = field(default_factory=lambda: [0.1, 0.3, 1.0, 3.0, 10.0])
    position_only_window_s: float = 300.0
    integration_sigma: float = 1e-4
    robust_loss: RobustLoss = RobustLoss.HUBER
    robust_k: float = 3.0
    outlier_threshold: float = 5.0
    segment_s: float | None = None
    segment_overlap_s: float | None = None
    max_imu_gap_s: float = 0.1
    imu_gap_policy: ImuGapPolicy = ImuGapPolicy.SPLIT
    intrinsics: IntrinsicsMode = IntrinsicsMode.AUTO
    intrinsics_block_s: float = 10.0
    intrinsics_prior_scale_misalignment: float = _PRIOR.scale_misalignment
    intrinsics_prior_g_sensitivity: float = _PRIOR.g_sensitivity
    intrinsics_prior_non_orthogonality: float = _PRIOR.non_orthogonality
    intrinsics_prior_calibration_rotation_rad: float = _PRIOR.calibration_rotation_rad
    min_poses: int = 20
    max_iterations: int = 30
    relative_error_tol: float = 1e-6
    min_rotation_excitation_deg: float = 10.0
    compute_marginals: bool = True
    keep_frame_disagreement: bool = False
    marginal_rate_hz: float | None = 5.0

    _ENUMS = {
        "pose_factor_mode": PoseFactorMode,
        "time_offset_mode": TimeOffsetMode,
        "extrinsic_mode": ExtrinsicMode,
        "robust_loss": RobustLoss,
        "noise_estimation": NoiseEstimation,
        "imu_gap_policy": ImuGapPolicy,
        "intrinsics": IntrinsicsMode,
        "pose_error": PoseErrorMode,
    }

    def calibration_rate_hz(self, solve: CalibrationSolve | str, fused: bool) -> float:
        """Keyframe rate of a calibration solve: its option, else the automatic rate."""
        value = getattr(self, f"{CalibrationSolve(solve).value}_keyframe_rate_hz")
        if value is not None:
            return float(value)
        return CALIBRATION_RATE_FUSED_HZ if fused else CALIBRATION_RATE_HZ

    def offset_window_s(self, fused: bool) -> float:
        """Length of the clock-offset refinement window."""
        if self.offset_refine_window_s is not None:
            return float(self.offset_refine_window_s)
        return min(OFFSET_WINDOW_FUSED_S, self.calib_window_s) if fused else float(self.calib_window_s)

    def segment_plan(self, keyframe_rate_hz: float) -> tuple[float, float]:
        """``(segment_s, segment_overlap_s)`` for a solve with this many keyframes per second."""
        seg = self.segment_s
        if seg is None:
            seg = float(np.clip(SEGMENT_KEYFRAMES / keyframe_rate_hz, SEGMENT_S_MIN, SEGMENT_S_MAX))
        overlap = self.segment_overlap_s if self.segment_overlap_s is not None else seg / 6.0
        if overlap * 2 >= seg:
            raise ConfigError(f"must be less than half of segment_s ({seg:g} s)", field="segment_overlap_s")
        return float(seg), float(overlap)

    def __post_init__(self) -> None:
        for name, enum_type in self._ENUMS.items():
            value = getattr(self, name)
            try:
                setattr(self, name, enum_type(value))
            except ValueError:
                choices = ", ".join(e.value for e in enum_type)
                raise ConfigError(f"invalid value {value!r}", field=name, hint=f"use one of {choices}") from None
        positive = ("max_time_offset_s", "offset_refine_step_s", "calib_window_s", "gravity_mps2", "gravity_window_s",
                    "extrinsic_prior_rotation_deg", "extrinsic_prior_translation_m", "extrinsic_max_sigmas",
                    "position_only_window_s", "robust_k", "outlier_threshold", "max_imu_gap_s", "integration_sigma",
                    "intrinsics_prior_scale_misalignment", "intrinsics_prior_g_sensitivity",
                    "intrinsics_prior_non_orthogonality", "intrinsics_prior_calibration_rotation_rad")
        for name in positive:
            if not float(getattr(self, name)) > 0:
                raise ConfigError(f"must be > 0, got {getattr(self, name)!r}", field=name)
        for name in ("keyframe_rate_hz", "marginal_rate_hz", "position_sigma_m", "rotation_sigma_rad", *NOISE_FIELDS,
                     "offset_refine_keyframe_rate_hz",
                     "extrinsic_keyframe_rate_hz", "gravity_keyframe_rate_hz", "noise_keyframe_rate_hz", "segment_s",
                     "offset_refine_window_s"):
            value = getattr(self, name)
            if value is not None and not float(value) > 0:
                raise ConfigError(f"must be > 0 or null, got {value!r}", field=name)
        if self.segment_overlap_s is not None and (
                self.segment_overlap_s < 0 or (self.segment_s is not None and self.segment_overlap_s * 2 >= self.segment_s)):
            raise ConfigError("must be >= 0 and less than half of segment_s", field="segment_overlap_s")
        if self.relative_horizon < 1:
            raise ConfigError("must be >= 1", field="relative_horizon")
        if self.min_poses < 3:
            raise ConfigError("must be >= 3", field="min_poses")
        if not self.random_walk_scales or any(float(s) <= 0 for s in self.random_walk_scales):
            raise ConfigError("must be a non-empty list of positive numbers", field="random_walk_scales")
        self.random_walk_scales = [float(s) for s in self.random_walk_scales]
        for name in ("pose_error_rotation_sigma_rad", "pose_error_position_sigma_m"):
            if not float(getattr(self, name)) >= 0:
                raise ConfigError(f"must be >= 0, got {getattr(self, name)!r}", field=name)
        for name in ("pose_error_rotation_tau_s", "pose_error_position_tau_s"):
            if not float(getattr(self, name)) > 0:
                raise ConfigError(f"must be > 0, got {getattr(self, name)!r}", field=name)
        if not self.pose_error_sigma_scales or any(not float(s) >= 0 for s in self.pose_error_sigma_scales):
            raise ConfigError("must be a non-empty list of numbers >= 0", field="pose_error_sigma_scales")
        if not self.pose_error_taus_s or any(not float(s) > 0 for s in self.pose_error_taus_s):
            raise ConfigError("must be a non-empty list of positive numbers", field="pose_error_taus_s")
        self.pose_error_sigma_scales = [float(s) for s in self.pose_error_sigma_scales]
        self.pose_error_taus_s = [float(s) for s in self.pose_error_taus_s]
        if not self.noise_density_scales or any(not float(s) > 0 for s in self.noise_density_scales):
            raise ConfigError("must be a non-empty list of positive numbers", field="noise_density_scales")
        self.noise_density_scales = [float(s) for s in self.noise_density_scales]
        if not self.pose_sigma_scales or any(float(s) <= 0 for s in self.pose_sigma_scales):
            raise ConfigError("must be a non-empty list of positive numbers", field="pose_sigma_scales")
        self.pose_sigma_scales = [float(s) for s in self.pose_sigma_scales]

    def intrinsics_prior(self) -> IntrinsicsPrior:
        """The ``intrinsics_prior_*`` fields as the intrinsics fit reads them."""
        return IntrinsicsPrior(self.intrinsics_prior_scale_misalignment, self.intrinsics_prior_g_sensitivity,
                               self.intrinsics_prior_non_orthogonality, self.intrinsics_prior_calibration_rotation_rad)

    @classmethod
    def field_names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    def to_dict(self) -> dict[str, Any]:
        return dataclass_to_mapping(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, path: str | Path | None = None) -> "RecoveryConfig":
        if not isinstance(d, dict):
            raise ConfigError("recovery config must be a mapping of option: value", path=path)
        d = dict(d.get("recovery", d)) if isinstance(d.get("recovery"), dict) else dict(d)
        try:
            return dataclass_from_mapping(cls, d, what="recovery option", field="recovery")
        except ConfigError as exc:
            raise ConfigError(exc.problem, path=path, field=exc.field, hint=exc.hint) from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> "RecoveryConfig":
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except FileNotFoundError:
            raise ConfigError("config file not found", path=path) from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"not valid YAML: {' '.join(str(exc).split())}", path=path) from None
        return cls.from_dict(data, path=path)

    def replace(self, **changes: Any) -> "RecoveryConfig":
        return dataclasses.replace(self, **changes)


# Default pose noise per source kind: (position sigma m, rotation sigma rad).
# Automatic keyframe rates of the calibration solves (offset, extrinsic, noise, gravity): fused
# keyframes carry all samples of their bin, so a sparser grid loses little and solves faster.
CALIBRATION_RATE_HZ = 10.0
CALIBRATION_RATE_FUSED_HZ = 5.0
OFFSET_WINDOW_FUSED_S = 20.0
# Automatic segment length: about this many keyframes per segment (memory), within bounds.
SEGMENT_KEYFRAMES = 6000
SEGMENT_S_MIN = 30.0
SEGMENT_S_MAX = 300.0

DEFAULT_POSE_SIGMAS: dict[PoseSourceKind, tuple[float, float]] = {
    PoseSourceKind.MOCAP: (1.0e-3, 1.0e-3),
    PoseSourceKind.GROUND_TRUTH: (1.0e-3, 1.0e-3),
    PoseSourceKind.POSITION_TRACKER: (1.0e-3, 1.0e-3),
    PoseSourceKind.VIO: (5.0e-3, 2.0e-3),
}
