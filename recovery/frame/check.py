"""Refuse a recovery whose IMU and pose stream disagree about the body frame.

An IMU file with two axes swapped (a column-order mistake) or a pose file whose quaternions are
stored in another order (w-last under a w-first header) still gives a solve: the bias, given a
large random walk, absorbs the disagreement. What it absorbs does not look like a bias: an
accelerometer "bias" of a sizeable fraction of gravity (or a gyro one of tens of degrees per
second) that moves by as much within the recording, and a noise search that needed its largest
random walk or left many pose factors far outside their sigma. :func:`check_frames` refuses such
a result with a :class:`~pipeline.errors.RecoveryError` naming the likely causes.

Rule (both parts must hold, so a correct recording with a merely poor fit passes):

1. *Implausible bias*: the norm of the accelerometer bias exceeds :data:`ACC_BIAS_IMPLAUSIBLE_MPS2`
   (or the gyro one :data:`GYRO_BIAS_IMPLAUSIBLE_RADPS`) at a keyframe, by more than
   :data:`MIN_SIGMAS` of its marginal sigma there (a poorly determined bias is not evidence).
2. *Frames disagree*: the noise evidence search ended on the largest random walk of its grid, or
   more than :data:`MAX_BEYOND_FRACTION` of the keyframes' pose factors lie beyond the outlier
   threshold after the solve, or the bias moves by more than the implausible level within the
   recording (a sensor bias drifts by a small fraction of that).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from pipeline.errors import RecoveryError

__all__ = ["ACC_BIAS_IMPLAUSIBLE_MPS2", "GYRO_BIAS_IMPLAUSIBLE_RADPS", "MIN_SIGMAS", "MAX_BEYOND_FRACTION",
           "frame_disagreement", "check_frames"]

log = logging.getLogger(__name__)

STANDARD_GRAVITY_MPS2 = 9.80665
#: An accelerometer bias above 0.3 g is not a bias (consumer MEMS parts stay below ~0.15 g).
ACC_BIAS_IMPLAUSIBLE_MPS2 = 0.3 * STANDARD_GRAVITY_MPS2
#: A gyro bias above 0.5 rad/s (~29 deg/s) is not a bias (consumer MEMS parts stay below ~20 deg/s).
GYRO_BIAS_IMPLAUSIBLE_RADPS = 0.5
#: The implausible bias must be this many marginal sigmas away from zero.
MIN_SIGMAS = 5.0
#: More than this share of keyframes with a pose factor beyond the outlier threshold: the poses disagree.
MAX_BEYOND_FRACTION = 0.2
#: Gravity tilted this far from the pose world's -z (or the extrinsic's rotation residual this large)
#: points at the pose orientations (quaternion order) rather than the IMU axes.
_ROTATION_SUSPECT_DEG = 20.0


def _worst(bias: np.ndarray, std: np.ndarray) -> tuple[float, float, float]:
    """(largest norm, its sigma ratio, largest per-axis range) of a bias track [K, 3] with sigma [K, 3]."""
    norm = np.linalg.norm(bias, axis=1)
    k = int(np.nanargmax(norm))
    sigma = float(np.linalg.norm(std[k])) if std is not None and len(std) else float("nan")
    ratio = norm[k] / sigma if np.isfinite(sigma) and sigma > 0 else float("inf")
    return float(norm[k]), float(ratio), float(np.max(np.ptp(bias, axis=0)))


def _disagreement_evidence(report: Any, residuals: dict[str, np.ndarray], excursion: bool) -> list[str]:
    """The signs that the pose stream disagrees with the IMU, as short phrases (empty: none)."""
    config = report.get("config") or {}
    noise = report.get("noise") or {}
    out = []
    grid = config.get("random_walk_scales") or []
    if grid and noise.get("method") == "evidence":
        at_bound = [s for s in ("acc", "gyro") if float(noise.get(f"{s}_random_walk_scale") or 0) >= max(grid)]
        if at_bound:
            out.append(f"the noise search needed its largest {' and '.join(at_bound)} random walk ({max(grid):g}x)")
    pose = np.asarray(residuals.get("pose_whitened_rms", []), dtype=float)
    pose = pose[np.isfinite(pose)]
    threshold = float(config.get("outlier_threshold") or 5.0)
    if len(pose) and np.mean(pose > threshold) > MAX_BEYOND_FRACTION:
        out.append(f"{int(np.sum(pose > threshold))} of {len(pose)} pose factors lie beyond {threshold:g} sigma")
    if excursion:
        out.append("the bias moves by as much within the recording")
    return out


def _likely_cause(report: Any) -> str:
    tilt = float(((report.get("gravity") or {}).get("level_test") or {}).get("tilt_deg") or 0.0)
    residual = float((report.get("extrinsic") or {}).get("rotation_init_residual") or 0.0)
    axes = "the IMU's axis order (columns swapped or a sign flipped in the IMU file)"
    quats = "the pose quaternion order (w-first vs w-last, e.g. a w-last file read under a w-first header)"
    if max(tilt, residual) > _ROTATION_SUSPECT_DEG:
        return f"{quats}, or {axes}"
    return f"{axes}, or {quats}"


def frame_disagreement(result: Any) -> str | None:
    """Why ``result`` (a :class:`recovery.result.RecoveryResult`) is refused, or None when it passes.

    See the module docstring for the rule. Reads the bias tracks [K, 3] (rad/s, m/s^2) with their
    marginal sigmas, ``result.residuals['pose_whitened_rms']`` [K] and the report's noise, config,
    gravity and extrinsic fields.
    """
    if len(result.t_ns) == 0:
        return None
    acc, acc_z, acc_range = _worst(np.asarray(result.bias_acc_mps2, float), np.asarray(result.bias_acc_std_mps2, float))
    gyro, gyro_z, gyro_range = _worst(np.asarray(result.bias_gyro_radps, float),
                                      np.asarray(result.bias_gyro_std_radps, float))
    found = []
    if acc > ACC_BIAS_IMPLAUSIBLE_MPS2 and acc_z > MIN_SIGMAS:
        found.append(f"the accelerometer bias reaches {acc:.2f} m/s^2 ({acc / STANDARD_GRAVITY_MPS2:.2f} g; a real "
                     f"one stays below {ACC_BIAS_IMPLAUSIBLE_MPS2 / STANDARD_GRAVITY_MPS2:.1f} g)")
    if gyro > GYRO_BIAS_IMPLAUSIBLE_RADPS and gyro_z > MIN_SIGMAS:
        found.append(f"the gyro bias reaches {gyro:.2f} rad/s (a real one stays below "
                     f"{GYRO_BIAS_IMPLAUSIBLE_RADPS:g} rad/s)")
    if not found:
        return None
    excursion = acc_range > ACC_BIAS_IMPLAUSIBLE_MPS2 or gyro_range > GYRO_BIAS_IMPLAUSIBLE_RADPS
    evidence = _disagreement_evidence(result.report, result.residuals or {}, excursion)
    if not evidence:
        return None
    stream = result.report.get("pose_stream") or "the pose stream"
    return (f"the IMU and pose stream '{stream}' disagree about the body frame: {' and '.join(found)}, and "
            f"{'; '.join(evidence)}; likely cause: {_likely_cause(result.report)}")


def check_frames(result: Any, sequence_name: str, *, refuse: bool = True) -> None:
    """Raise when :func:`frame_disagreement` refuses ``result`` (with ``refuse=False``: log a warning
    and keep it, for the verdict to judge).

    Raises:
        RecoveryError: Naming the evidence and the likely causes (axis order, quaternion order).
    """
    why = frame_disagreement(result)
    if why is not None and not refuse:
        log.warning("sequence '%s': %s (kept: --keep-frame-disagreement)", sequence_name, why)
    elif why is not None:
        raise RecoveryError(
            f"sequence '{sequence_name}': {why}",
            hint="check the IMU file's column order and the pose file's quaternion order against their headers "
                 "('biasgt inspect' shows the first rows; a generic CSV's mapping: --csv-mapping), fix them, and "
                 "recover again (or, to keep the result for its verdict, which FAILs, --keep-frame-disagreement)")
