"""The rig checks: what a pose stream implies against what the IMU measures, over the whole recording.

Per pose stream that overlaps the IMU (and the ground truth):

==================  ==========  ==================================================
code                severity    meaning (repair)
==================  ==========  ==================================================
POSE_PLACEHOLDERS   warning     frames at the origin with the identity orientation (occlusion placeholders);
                                ``recover`` rejects them as outliers (drop-placeholder-poses)
CLOCK_OFFSET        warning     the stream's clock runs more than the recovery's fine search (0.5 s) off the
                                IMU's (:func:`pipeline.checks.clock.coarse_clock_offset`); ``recover`` finds it
POSITION_UNIT       repairable  positions in millimetres or centimetres (positions-to-m)
FRAME_DISAGREEMENT  warning     the IMU and the poses disagree about the body frame (swapped or flipped axes,
                                quaternion order); ``recover`` refuses the stream
==================  ==========  ==================================================

:func:`rig_findings` runs them (a few tenths of a second for an hour of data); :func:`frame_refusal` is
the sentence ``recover`` refuses a stream with, from the same fits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.checks.clock import CoarseOffset, coarse_clock_offset
from pipeline.checks.options import GROUND_TRUTH_STREAM, MAX_LISTED, Repair
from pipeline.checks.rig_fit import POSITION_UNITS, FrameAgreement, PositionScale, frame_agreement, position_scale
from pipeline.checks.rig_signals import sorted_valid_imu, sorted_valid_poses
from pipeline.checks.streams import pose_stream_label, round_or_none
from pipeline.types import NS_PER_S, STANDARD_GRAVITY_MPS2, Finding, ImuSeries, PoseSeries, Sequence, Severity

#: Offsets within this of zero are left to the recovery's fine search (its ``max_time_offset_s``).
FINE_SEARCH_S = 0.5
#: The gyro fit's residual share above which the gyro and the pose orientations disagree.
MAX_GYRO_RESIDUAL = 0.45
#: The specific-force fit's RMS residual above which the accelerometer and the poses disagree (m/s^2).
MAX_ACC_RESIDUAL_MPS2 = 1.5
#: Fitted biases above these are not biases (as :mod:`recovery.frame.check` judges a solve).
MAX_ACC_BIAS_MPS2 = 0.3 * STANDARD_GRAVITY_MPS2
MAX_GYRO_BIAS_RADPS = 0.5
#: Below this gyro rate (RMS, rad/s) the frames are not judged: too little rotation.
MIN_RATE_RMS_RADPS = 0.1
#: Below this attitude spread (deg) the accelerometer is not judged (a rig that never tilts).
MIN_ATTITUDE_SPREAD_DEG = 10.0
#: The scale check needs the motion to explain this share of |f|^2.
MIN_SCALE_R2 = 0.3


def placeholder_rows(poses: PoseSeries) -> np.ndarray:
    """Rows at exactly the origin with exactly the identity orientation (w first or last), bool ``[N]``: what
    many trackers write for a frame they lost. None are flagged where the stream itself sits at the origin."""
    at_origin = np.all(poses.p_m == 0.0, axis=1)
    if poses.quat_wxyz is not None:
        q = poses.quat_wxyz
        identity = np.all(q == [1.0, 0.0, 0.0, 0.0], axis=1) | np.all(q == [0.0, 0.0, 0.0, 1.0], axis=1)
        at_origin &= identity
    if at_origin.sum() * 2 > len(at_origin):
        return np.zeros(len(at_origin), dtype=bool)
    return at_origin


@dataclass(frozen=True)
class RigFit:
    """What :func:`fit_rig` found for one pose stream (each None where it could not be judged)."""

    offset: CoarseOffset | None
    scale: PositionScale | None
    frames: FrameAgreement | None

    @property
    def offset_s(self) -> float:
        """The trusted coarse offset, else 0 (the recovery's fine search then starts at zero)."""
        return self.offset.offset_s if self.offset is not None and self.offset.trusted else 0.0

    @property
    def position_factor(self) -> float:
        """The factor that turns the positions into metres (1 where the unit is metres or unknown)."""
        if self.scale is None or self.scale.unit is None or self.scale.r2 < MIN_SCALE_R2:
            return 1.0
        return next(k for k, v in POSITION_UNITS.items() if v == self.scale.unit)


def fit_rig(imu: ImuSeries, poses: PoseSeries) -> RigFit | None:
    """The coarse clock offset, the positions' unit and the frame agreement of ``poses`` against ``imu``
    (placeholder frames and non-finite rows left out); None when the streams do not overlap usably."""
    imu_v = sorted_valid_imu(imu)
    poses_v = sorted_valid_poses(poses.take(np.flatnonzero(~placeholder_rows(poses))))
    if imu_v is None or poses_v is None:
        return None
    offset = coarse_clock_offset(imu_v, poses_v)
    if offset is None:
        return None
    tau = offset.offset_s if offset.trusted else 0.0
    scale = position_scale(imu_v, poses_v, tau)
    fit = RigFit(offset, scale, None)
    return RigFit(offset, scale, frame_agreement(imu_v, poses_v, tau, fit.position_factor))


def frame_refusal(fit: RigFit | None, stream: str) -> str | None:
    """Why the IMU and pose stream ``stream`` disagree about the body frame, one sentence; None when they agree
    or cannot be judged (too little rotation, no orientations, an untrusted clock)."""
    fa = None if fit is None else fit.frames
    if fa is None or fa.rate_rms_radps < MIN_RATE_RMS_RADPS:
        return None
    found = []
    if fa.gyro_residual > MAX_GYRO_RESIDUAL:
        found.append(f"no rotation maps the pose orientations' rates onto the gyro's ({100 * fa.gyro_residual:.0f} % "
                     "of the rate left over)")
    elif fa.gyro_bias_radps > MAX_GYRO_BIAS_RADPS:
        found.append(f"the gyro would need a bias of {fa.gyro_bias_radps:.2f} rad/s")
    if fa.attitude_spread_deg >= MIN_ATTITUDE_SPREAD_DEG and not found:
        if fa.acc_residual_mps2 > MAX_ACC_RESIDUAL_MPS2:
            found.append(f"the accelerometer disagrees with the poses' attitude and acceleration by "
                         f"{fa.acc_residual_mps2:.1f} m/s^2 RMS")
        elif fa.acc_bias_mps2 > MAX_ACC_BIAS_MPS2:
            found.append(f"the accelerometer would need a bias of {fa.acc_bias_mps2:.1f} m/s^2 "
                         f"({fa.acc_bias_mps2 / STANDARD_GRAVITY_MPS2:.2f} g)")
    if not found:
        return None
    gyro = fa.gyro_residual > MAX_GYRO_RESIDUAL or fa.gyro_bias_radps > MAX_GYRO_BIAS_RADPS
    quats = "the pose quaternion order (w-first vs w-last)"
    cause = (f"{quats}, or the gyro's axis order" if gyro
             else "the accelerometer's axis order (columns swapped or a sign flipped in the IMU file)")
    if fit.offset is None or not fit.offset.trusted:
        cause += (", or the streams' clocks or bodies differ (no clear clock offset: "
                  f"{'no overlap to search' if fit.offset is None else fit.offset.describe()})")
    return (f"the IMU and pose stream '{stream}' disagree about the body frame: {'; '.join(found)}; likely cause: "
            f"{cause}")


def _offset_finding(label: str, c: CoarseOffset) -> list[Finding]:
    if not c.trusted or abs(c.offset_s) <= FINE_SEARCH_S:
        return []
    side = "behind" if c.offset_s > 0 else "ahead of"
    found = ("recover takes a ground truth as on the imu clock: estimate it (--estimate-time-offset)"
             if label == GROUND_TRUTH_STREAM else "recover finds it over the whole overlap")
    return [Finding(
        "CLOCK_OFFSET", Severity.WARNING, label,
        f"{label} stamps run {abs(c.offset_s):.3f} s {side} the imu's ({c.describe()}); {found}, or fix it: "
        f"--time-offset-s {c.offset_s:.3f} (or re-stamp the poses)",
        {"offset_s": round_or_none(c.offset_s), "peak": round_or_none(c.peak, 3),
         "runner_up": round_or_none(c.runner_up, 3), "method": c.method})]


def _unit_finding(label: str, fit: RigFit) -> list[Finding]:
    s = fit.scale
    factor = fit.position_factor
    if s is None or factor == 1.0:
        return []
    return [Finding(
        "POSITION_UNIT", Severity.REPAIRABLE, label,
        f"{label} positions look like {s.unit}, not metres (their second derivative matches the accelerometer "
        f"times {1 / s.scale:.4g}); scale them to metres with --repair {Repair.POSITIONS_TO_M.value}",
        {"unit": s.unit, "factor_to_m": factor, "scale_estimate": round_or_none(s.scale), "r2": round_or_none(s.r2, 3)})]


def _placeholder_finding(label: str, poses: PoseSeries) -> list[Finding]:
    bad = np.flatnonzero(placeholder_rows(poses))
    if not len(bad):
        return []
    t0 = int(poses.t_ns.min())
    t_s = (poses.t_ns[bad] - t0) / NS_PER_S
    return [Finding(
        "POSE_PLACEHOLDERS", Severity.WARNING, label,
        f"{label} has {len(bad)} frames at the origin with the identity orientation (t={t_s.min():.3f}..{t_s.max():.3f} "
        f"s): placeholders of an occluded tracker, not poses; recover rejects them as outliers "
        f"(or drop them with --repair {Repair.DROP_PLACEHOLDER_POSES.value})",
        {"count": int(len(bad)), "first_rows": [int(i) for i in bad[:MAX_LISTED]],
         "first_t_s": [round_or_none(float(x)) for x in t_s[:MAX_LISTED]]})]


def rig_findings(seq: Sequence) -> list[Finding]:
    """The rig checks of the module docstring on every pose stream of ``seq`` (and its ground truth)."""
    if seq.imu is None or len(seq.imu) < 10:
        return []
    streams = {pose_stream_label(k): (k, p) for k, p in seq.poses.items()}
    if seq.ground_truth is not None and len(seq.ground_truth) >= 10:
        streams[GROUND_TRUTH_STREAM] = (GROUND_TRUTH_STREAM, seq.ground_truth.to_pose_series())
    out: list[Finding] = []
    for label, (name, poses) in streams.items():
        out += _placeholder_finding(label, poses)
        fit = fit_rig(seq.imu, poses)
        if fit is None or fit.offset is None:
            continue
        out += _offset_finding(label, fit.offset)
        out += _unit_finding(label, fit)
        why = frame_refusal(fit, name)
        if why is not None:
            out.append(Finding("FRAME_DISAGREEMENT", Severity.WARNING, label,
                               f"{why}; recover refuses this stream: check the IMU file's column order and the pose "
                               "file's quaternion order against their headers",
                               {"gyro_residual": round_or_none(fit.frames.gyro_residual, 3),
                                "acc_residual_mps2": round_or_none(fit.frames.acc_residual_mps2, 3),
                                "gyro_bias_radps": round_or_none(fit.frames.gyro_bias_radps, 3),
                                "acc_bias_mps2": round_or_none(fit.frames.acc_bias_mps2, 3)}))
    return out
