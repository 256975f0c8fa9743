"""Stage 2 of a recovery: the pose stream's clock offset before the graph refines it, and the rig screen.

The offset is searched twice: over the whole overlap, at offsets of up to minutes
(:func:`pipeline.checks.clock.coarse_clock_offset`, the search ``biasgt inspect`` runs too), then
within ``max_time_offset_s`` of that by the finer correlation of
:func:`recovery.calibration_init.estimate_time_offset`. The whole-overlap search moves the fine one
only where it is trusted and lies beyond half the fine one's range, so a recording whose clocks agree
to a fraction of a second is searched exactly as before.

:func:`screen_rig` refuses, before any solve, a stream whose positions are not in metres or whose
body frame disagrees with the IMU's (:mod:`pipeline.checks.rig`, the fits ``biasgt inspect`` reports).
"""

from __future__ import annotations

import logging
from dataclasses import replace

from pipeline.checks.options import Repair
from pipeline.checks.rig import RigFit, fit_rig, frame_refusal
from pipeline.errors import BiasgtError, RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind
from recovery import calibration_init as ci
from recovery.config import RecoveryConfig, TimeOffsetMode
from recovery.clock.offset import coarse_offset_inputs
from recovery.records import ClockOffset, Inputs

log = logging.getLogger(__name__)

#: The hint of a refused frame disagreement (as :func:`recovery.frame.check.check_frames` gives it).
FRAME_HINT = ("check the IMU file's column order and the pose file's quaternion order against their headers "
              "('biasgt inspect' shows the first rows; a generic CSV's mapping: --csv-mapping), fix them, and "
              "recover again (or, to keep the result for its verdict, which FAILs, --keep-frame-disagreement)")


def screen_rig(sequence_name: str, stream: str, imu: ImuSeries, poses: PoseSeries, config: RecoveryConfig
               ) -> RigFit | None:
    """The rig fit of ``poses`` against ``imu`` (:func:`pipeline.checks.rig.fit_rig`).

    Raises:
        RecoveryError: The positions are in millimetres or centimetres; the IMU and the stream disagree
            about the body frame (unless ``config.keep_frame_disagreement``).
    """
    fit = fit_rig(imu, poses)
    if fit is None:
        return None
    if fit.position_factor != 1.0:
        raise RecoveryError(
            f"sequence '{sequence_name}': pose stream '{stream}' positions look like {fit.scale.unit}, not metres "
            f"(their second derivative matches the accelerometer times {1 / fit.scale.scale:.4g})", field="p_m",
            hint=f"scale them to metres: --repair {Repair.POSITIONS_TO_M.value} (recover or convert)")
    why = frame_refusal(fit, stream)
    if why is not None and not config.keep_frame_disagreement:
        raise RecoveryError(f"sequence '{sequence_name}': {why}", hint=FRAME_HINT)
    if why is not None:
        log.warning("sequence '%s': %s (kept: --keep-frame-disagreement)", sequence_name, why)
    return fit


def _shifted(poses: PoseSeries, offset_s: float) -> PoseSeries:
    return replace(poses, t_ns=poses.t_ns + int(round(offset_s * NS_PER_S)))


def coarse_offset(inputs: Inputs, config: RecoveryConfig) -> ClockOffset:
    """The clock offset by cross-correlation (ESTIMATE; see the module docstring), else as configured."""
    mode = config.time_offset_mode
    if mode == TimeOffsetMode.AUTO:
        mode = TimeOffsetMode.FIXED if inputs.kind == PoseSourceKind.GROUND_TRUTH else TimeOffsetMode.ESTIMATE
    fixed = ClockOffset(mode, float(config.time_offset_s), 0.0)
    if mode != TimeOffsetMode.ESTIMATE:
        return fixed
    wide = inputs.rig.offset if inputs.rig is not None else None
    shift = 0.0
    if wide is not None and wide.trusted and abs(wide.offset_s - config.time_offset_s) > config.max_time_offset_s / 2:
        shift = wide.offset_s
        log.info("clock offset over the whole overlap: %s", wide.describe())
    start = shift or float(config.time_offset_s)
    fixed = replace(fixed, offset_s=start, wide_search=None if wide is None else {
        "offset_s": wide.offset_s, "peak": wide.peak, "runner_up": wide.runner_up, "trusted": wide.trusted,
        "searched_s": wide.searched_s, "method": wide.method, "used": bool(shift)})
    try:
        imu_c, poses_c = coarse_offset_inputs(inputs.imu, _shifted(inputs.poses, start), inputs.pieces,
                                              config.max_time_offset_s)
        coarse = ci.estimate_time_offset(imu_c, poses_c, max_offset_s=config.max_time_offset_s)
    except BiasgtError as exc:
        where = (f"the whole-overlap search's {start:+.3f} s" if shift else f"time_offset_s={start}")
        untrusted = (f"; over the whole overlap: {wide.describe()}, not trusted" if wide is not None and not shift
                     else "")
        return replace(fixed, std_s=config.offset_refine_step_s, warnings=(
            f"coarse clock offset failed ({exc}{untrusted}); starting from {where}",))
    return replace(fixed, offset_s=start + coarse.offset_s, std_s=coarse.std_s, coarse_method=coarse.method)
