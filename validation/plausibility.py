"""Plausibility of a recovered bias: results that no working IMU and no consistent frame can give.

A recovery can fit a pose stream well and still be physically impossible: with a wrong pose-to-IMU
rotation (a frame mismatch), the bias absorbs gravity and the rotation the pose frame does not
share with the IMU. Integration errors cannot always tell (the bias was fitted to those poses), so
each check here compares a result with what physics allows; every finding makes the verdict FAIL
(:func:`validation.validate.validate_inputs`) with its reason first:

* BIAS_RANGE: a bias beyond the sensor's bias range on some axis (``ImuCalibration``'s
  ``gyro_bias_max_radps`` / ``acc_bias_max_mps2``: 0.35 rad/s and 2 m/s^2 by default, well above
  any MEMS datasheet's bias range; ``gyroscope_bias_max`` / ``accelerometer_bias_max`` in
  sensor.yaml override them).
* GRAVITY_TILT: gravity tilted from a level pose frame's -z (motion capture, ground truth, a
  position tracker: their world frames are level) by more than ``max_gravity_tilt_deg``, or, in any
  frame, changing direction between the recovery's segments by more than
  ``max_gravity_tilt_change_deg`` (a world frame does not tilt during a recording).
* ROTATION_RESIDUAL: the recovered trajectory's attitude off the pose stream's (moved into the IMU
  frame) by more than ``max_rotation_residual_deg`` RMS; for relative pose factors (VIO, odometry,
  which drift) the rotation over 1 s instead, beyond ``max_relative_rotation_residual_deg``.
* FRAME_SWAP: the gyro's disagreement with the pose stream's rate carries half the rate or more of
  some axis at high coherence in two bands or more
  (:func:`recovery.intrinsics.gyro_consistency.rate_coupling`): a gyro axis reads another axis's rotation (or
  one the pose stream lacks), which no IMU error does (scale and misalignment are percents).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pipeline.errors import BiasgtError
from pipeline.geometry.pose_transform import offset_ns, poses_in_imu_frame
from pipeline.types import NS_PER_S, PoseSeries, PoseSourceKind, Sequence
from recovery.intrinsics.gyro_consistency import FRAME_SWAP_GAIN, rate_coupling
from recovery.outputs import RecoveryOutputs


class PlausibilityCheck(str, enum.Enum):
    """What a :class:`Implausible` finding checked (see the module docstring)."""

    BIAS_RANGE = "bias_range"
    GRAVITY_TILT = "gravity_tilt"
    ROTATION_RESIDUAL = "rotation_residual"
    FRAME_SWAP = "frame_swap"


@dataclass(frozen=True)
class PlausibilityLimits:
    """Limits of the checks (the bias range is the calibration's).

    Attributes:
        max_gravity_tilt_deg: Largest tilt of gravity from -z in a level pose frame.
        max_gravity_tilt_change_deg: Largest change of gravity's direction between segments.
        max_rotation_residual_deg: Largest RMS attitude difference, trajectory vs poses.
        max_relative_rotation_residual_deg: The same for the rotation over ``relative_interval_s``
            (relative pose factors).
        relative_interval_s: Interval of the relative rotation residual.
        frame_swap_gain: Share of an axis's rate that marks a frame mismatch.
        frame_swap_coherence: Coherence the share needs (and at least the band's chance level).
    """

    max_gravity_tilt_deg: float = 10.0
    max_gravity_tilt_change_deg: float = 5.0
    max_rotation_residual_deg: float = 5.0
    max_relative_rotation_residual_deg: float = 1.0
    relative_interval_s: float = 1.0
    frame_swap_gain: float = FRAME_SWAP_GAIN
    frame_swap_coherence: float = 0.9


#: Pose sources whose world frame is level (z up), so gravity must point along -z.
LEVEL_SOURCES = (PoseSourceKind.MOCAP, PoseSourceKind.GROUND_TRUTH, PoseSourceKind.POSITION_TRACKER)

@dataclass(frozen=True)
class Implausible:
    """One result that physics rules out.

    Attributes:
        check: Which check found it.
        text: What was found, with the figure and its limit (a reason of the verdict).
        value: The figure that triggered it (unit in ``text``).
        limit: Its limit.
    """

    check: PlausibilityCheck
    text: str
    value: float
    limit: float

    def to_dict(self) -> dict[str, Any]:
        return {"check": self.check.value, "text": self.text, "value": float(self.value), "limit": float(self.limit)}


def bias_range_findings(bias: np.ndarray, gyro_max_radps: float, acc_max_mps2: float,
                        limit_source: str) -> list[Implausible]:
    """Axes whose recovered bias (``bias`` [N, 6]: gyro rad/s, acc m/s^2) exceeds the sensor's range."""
    out = []
    peak = np.nanmax(np.abs(np.asarray(bias, dtype=float)), axis=0)
    for first, name, unit, limit in ((0, "gyro", "rad/s", gyro_max_radps), (3, "accelerometer", "m/s^2", acc_max_mps2)):
        axis = int(np.argmax(peak[first:first + 3]))
        value = float(peak[first + axis])
        if value > limit:
            out.append(Implausible(
                PlausibilityCheck.BIAS_RANGE,
                f"impossible bias: the {name} bias reaches {value:.3g} {unit} on axis {'xyz'[axis]}, beyond the "
                f"sensor's bias range of {limit:g} {unit} ({limit_source}): the bias absorbed something else, most "
                "often gravity or rotation through a wrong pose-to-IMU frame", value, limit))
    return out


def gravity_findings(report: dict[str, Any], source_kind: str | None,
                     limits: PlausibilityLimits = PlausibilityLimits()) -> list[Implausible]:
    """Gravity tilted in a level frame, or changing between segments (recovery.json's ``gravity``)."""
    out = []
    g = report.get("gravity_world_mps2")
    info = report.get("gravity") if isinstance(report.get("gravity"), dict) else {}
    if g is not None and source_kind in {k.value for k in LEVEL_SOURCES} and info.get("estimated", True):
        tilt = gravity_tilt_deg(g)
        if tilt > limits.max_gravity_tilt_deg:
            out.append(Implausible(
                PlausibilityCheck.GRAVITY_TILT,
                f"frame mismatch: gravity is tilted {tilt:.1f} deg from the -z axis of the {source_kind} pose "
                f"frame, which is level (more than {limits.max_gravity_tilt_deg:g} deg)", tilt,
                limits.max_gravity_tilt_deg))
    change = info.get("segment_max_tilt_change_rad")
    if isinstance(change, (int, float)) and math.degrees(change) > limits.max_gravity_tilt_change_deg:
        deg = math.degrees(change)
        out.append(Implausible(
            PlausibilityCheck.GRAVITY_TILT,
            f"frame mismatch: gravity changes direction by {deg:.1f} deg between parts of the recording (more than "
            f"{limits.max_gravity_tilt_change_deg:g} deg); the pose frame does not tilt, so the IMU's rotation and "
            "the pose stream's disagree", deg, limits.max_gravity_tilt_change_deg))
    return out


def gravity_tilt_deg(gravity_world_mps2: Any) -> float:
    """Angle between the gravity vector and the world's -z axis (0 for a z-up world), degrees."""
    g = np.asarray(gravity_world_mps2, dtype=float).reshape(3)
    n = float(np.linalg.norm(g))
    if n == 0:
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(-g[2] / n, -1.0, 1.0))))


def pose_residuals(
    trajectory: PoseSeries,
    poses: PoseSeries,
    T_imu_pose: np.ndarray,
    time_offset_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Distance and angle between the recovered IMU trajectory and a pose stream moved into the IMU frame.

    The pose stream is interpolated at the trajectory's stamps taken back to the pose clock
    (linear in position, Slerp in rotation), then moved onto the IMU clock and into the IMU
    frame by :func:`pipeline.geometry.pose_transform.poses_in_imu_frame` (for a position-only stream the
    lever arm is removed with the recovered orientation; when the trajectory has none either,
    positions are compared as they are). Stamps outside the pose span are skipped.

    Args:
        trajectory: Recovered ``T_world_imu`` on the IMU clock, [K0] rows.
        poses: ``T_world_<frame>`` on the pose clock (``quat_wxyz`` may be None).
        T_imu_pose: 4x4 ``T_imu_<frame>``.
        time_offset_s: Seconds to ADD to pose stamps to put them on the IMU clock.

    Returns:
        ``(t_ns [K], pos_err_m [K], rot_err_deg [K] or None)``.
    """
    t_ns, pos_err, R_pose, R_traj = _aligned(trajectory, poses, T_imu_pose, time_offset_s)
    rot_err = None if R_pose is None else np.degrees((R_pose.inv() * R_traj).magnitude())
    return t_ns, pos_err, rot_err


def _aligned(trajectory: PoseSeries, poses: PoseSeries, T_imu_pose: np.ndarray, time_offset_s: float
             ) -> tuple[np.ndarray, np.ndarray, Rotation | None, Rotation | None]:
    """Stamps, position error and both attitudes (None without one) of :func:`pose_residuals`."""
    shift_ns = offset_ns(time_offset_s)
    t_pose = poses.t_ns + shift_ns
    tq = trajectory.t_ns
    keep = (tq >= t_pose[0]) & (tq <= t_pose[-1])
    tq = tq[keep]
    if len(tq) == 0 or len(t_pose) < 2:
        return tq, np.zeros(0), None, None
    x, xq = (t_pose - t_pose[0]).astype(float), (tq - t_pose[0]).astype(float)
    p_wp = np.column_stack([np.interp(xq, x, poses.p_m[:, i]) for i in range(3)])
    quat_wp = None
    if poses.quat_wxyz is not None:
        quat_wp = Slerp(x, Rotation.from_quat(poses.quat_wxyz, scalar_first=True))(xq).as_quat(scalar_first=True)
    traj_q = trajectory.quat_wxyz[keep] if trajectory.quat_wxyz is not None else None
    if quat_wp is None and traj_q is None:
        T_imu_pose = np.eye(4)  # no attitude on either side: the lever arm cannot be removed
    at_pose = replace(poses, t_ns=tq - shift_ns, p_m=p_wp, quat_wxyz=quat_wp)
    in_imu = poses_in_imu_frame(at_pose, T_imu_pose, time_offset_s, imu_quat_wxyz=traj_q)
    pos_err = np.linalg.norm(trajectory.p_m[keep] - in_imu.p_m, axis=1)
    if in_imu.quat_wxyz is None or traj_q is None:
        return tq, pos_err, None, None
    return (tq, pos_err, Rotation.from_quat(in_imu.quat_wxyz, scalar_first=True),
            Rotation.from_quat(traj_q, scalar_first=True))


def rotation_findings(trajectory: PoseSeries, poses: PoseSeries, T_imu_pose: np.ndarray, time_offset_s: float,
                      relative: bool, limits: PlausibilityLimits = PlausibilityLimits()) -> list[Implausible]:
    """The trajectory's attitude far from the pose stream's (absolute RMS, or over 1 s when ``relative``)."""
    t_ns, _, R_pose, R_traj = _aligned(trajectory, poses, T_imu_pose, time_offset_s)
    if R_pose is None or len(t_ns) < 2:
        return []
    if not relative:
        rms = float(np.sqrt(np.mean(np.degrees((R_pose.inv() * R_traj).magnitude()) ** 2)))
        limit, what = limits.max_rotation_residual_deg, "attitude"
    else:
        j = np.searchsorted(t_ns, t_ns + int(limits.relative_interval_s * NS_PER_S))
        i = np.nonzero(j < len(t_ns))[0]
        if len(i) == 0:
            return []
        j = j[i]
        err = ((R_pose[i].inv() * R_pose[j]).inv() * (R_traj[i].inv() * R_traj[j])).magnitude()
        rms = float(np.degrees(np.sqrt(np.mean(err ** 2))))
        limit, what = limits.max_relative_rotation_residual_deg, f"rotation over {limits.relative_interval_s:g} s"
    if rms <= limit:
        return []
    return [Implausible(
        PlausibilityCheck.ROTATION_RESIDUAL,
        f"frame mismatch: the recovered trajectory's {what} is {rms:.2f} deg RMS off the pose stream's (more than "
        f"{limit:g} deg): the IMU's rotation and the pose stream's do not agree", rms, limit)]


def frame_swap_findings(sequence: Sequence, poses: PoseSeries, T_imu_pose: np.ndarray, time_offset_s: float,
                        limits: PlausibilityLimits = PlausibilityLimits()) -> list[Implausible]:
    """A gyro axis that reads half or more of some axis's rate beyond the pose stream's (see the module)."""
    if poses.quat_wxyz is None or sequence.imu is None:
        return []
    try:
        c = rate_coupling(sequence.imu, poses, R_imu_pose=np.asarray(T_imu_pose)[:3, :3], offset_s=time_offset_s)
    except BiasgtError:
        return []  # too short or no overlap: not checked
    need = np.maximum(c.coherence_needed, limits.frame_swap_coherence)[:, None, None]
    counts = (c.coherence[:, :, None] >= need) & (np.abs(c.gain) >= limits.frame_swap_gain)
    swapped = counts.sum(axis=0) >= 2  # [3, 3]
    if not swapped.any():
        return []
    # another axis's rate read by a gyro axis says more than its own rate missing from the poses
    off = ~np.eye(3, dtype=bool)
    prefer = off if (swapped & off).any() else ~off
    score = np.where(counts & (swapped & prefer)[None], np.abs(c.gain), -1.0)
    b, r, col = (int(x) for x in np.unravel_index(np.argmax(score), score.shape))
    lo, hi = c.bands_hz[b]
    gain = float(c.gain[b, r, col])
    what = (f"the gyro {'xyz'[r]} reads {gain:+.2f} of the rate about {'xyz'[col]} beyond the pose stream's"
            if r != col else f"the gyro {'xyz'[r]} reads {gain:+.2f} of its own rate beyond the pose stream's "
            "(the pose stream lacks or reverses that rotation)")
    return [Implausible(
        PlausibilityCheck.FRAME_SWAP,
        f"frame mismatch: at {lo:g}-{hi:g} Hz {what}, coherence {c.coherence[b, r]:.2f}, in "
        f"{int(counts[:, r, col].sum())} bands: no IMU error does that (scale and misalignment are percents), a "
        "swapped or rotated frame does", abs(gain), limits.frame_swap_gain)]


def plausibility_findings(sequence: Sequence, recovery: RecoveryOutputs,
                          limits: PlausibilityLimits = PlausibilityLimits()) -> list[Implausible]:
    """Every finding of the four checks on a recovery of ``sequence`` (empty: nothing impossible)."""
    report = recovery.report
    cal = sequence.calibration
    source = cal.sources.get("acc_bias_max_mps2") or cal.sources.get("gyro_bias_max_radps")
    out = bias_range_findings(recovery.bias.bias, cal.gyro_bias_max_radps, cal.acc_bias_max_mps2,
                              f"from {source}" if source else "the default; give the sensor's own in sensor.yaml")
    data = dict(report.data)
    out += gravity_findings(data, data.get("pose_source_kind"), limits)
    poses = sequence.poses.get(report.pose_stream) if report.pose_stream else None
    if poses is None and report.pose_stream == "ground_truth" and sequence.ground_truth is not None:
        poses = sequence.ground_truth.to_pose_series()
    if poses is not None and len(poses) >= 2:
        if recovery.trajectory is not None and len(recovery.trajectory) >= 2:
            out += rotation_findings(recovery.trajectory, poses, report.T_imu_pose, report.time_offset_s,
                                     data.get("pose_factor_mode") == "relative", limits)
        out += frame_swap_findings(sequence, poses, report.T_imu_pose, report.time_offset_s, limits)
    return out
