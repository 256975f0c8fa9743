"""A degenerate recovery (GTSAM finds the system singular) as one sentence that names the likely cause and
the fixes that apply: ignored unit findings, a long pause of the pose stream, the extrinsic or clock offset
still estimated, too little motion."""

from __future__ import annotations

import numpy as np

from pipeline.errors import BiasgtError, RecoveryError
from pipeline.io import select_pose_stream
from pipeline.types import NS_PER_S, PoseSourceKind, Sequence
from recovery.config import ExtrinsicMode, RecoveryConfig, TimeOffsetMode

#: A pose pause at least this long is named as the likely cause of a degenerate solve (s).
LONG_POSE_GAP_S = 5.0


def degenerate_error(sequence: Sequence, pose_stream: str | None, config: RecoveryConfig,
                     exc: Exception) -> RecoveryError | None:
    """The error for GTSAM's ``exc`` when it says the system is singular (None: another error)."""
    text = str(exc)
    if not any(word in text for word in ("ndetermina", "ill-posed", "ingular", "EliminationTree")):
        return None
    first = text.strip().splitlines()[0] if text.strip() else "singular system"
    gap = _longest_pose_gap(sequence, pose_stream)
    where = "" if gap is None else f"; {gap}"
    return RecoveryError(
        f"sequence '{sequence.name}': the optimisation is degenerate ({first}){where}; the motion does not "
        "make the bias, clock offset or extrinsic observable",
        hint=_ignored_units_hint(sequence) + degenerate_hint(sequence, pose_stream, config))


def _longest_pose_gap(sequence: Sequence, pose_stream: str | None) -> str | None:
    """``"pose stream 'x' pauses for 30.0 s (t=45.0..75.0 s after its start)"`` when its longest pause
    reaches :data:`LONG_POSE_GAP_S`, else None."""
    try:
        name, poses = select_pose_stream(sequence, pose_stream)
    except BiasgtError:
        return None
    t = np.sort(poses.t_ns)
    if len(t) < 2:
        return None
    i = int(np.argmax(np.diff(t)))
    length_s = (t[i + 1] - t[i]) / NS_PER_S
    if length_s < LONG_POSE_GAP_S:
        return None
    a, b = (t[i] - t[0]) / NS_PER_S, (t[i + 1] - t[0]) / NS_PER_S
    return (f"pose stream '{name}' pauses for {length_s:.1f} s (t={a:.1f}..{b:.1f} s after its start), where the "
            "bias rests on the IMU alone: recover the parts before and after it apart")


#: Unit findings whose --ignore makes a degenerate solve likely.
_UNIT_CODES = ("GYRO_DEGPS", "ACC_IN_G")


def _ignored_units_hint(sequence: Sequence) -> str:
    """The first words of the hint when the user ignored a unit finding (likely the cause)."""
    from pipeline.checks.options import REPAIR_FOR_CODE

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


