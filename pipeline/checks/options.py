"""What the input checks take and give: :class:`CheckOptions`, the finding codes, :class:`Repair`
and how a verdict reads (:data:`CHECK_VERDICT_WORDS`).

Finding codes produced here (readers add PARSE_SKIPPED_LINES, STAMP_PRECISION_LOSS,
STAMP_UNIT_GUESSED, CALIBRATION_DEFAULTED, BAG_HEADER_STAMP_ZERO):

==================  ==========  ==================================================
code                severity    meaning (repair)
==================  ==========  ==================================================
EMPTY_STREAM        fatal       fewer than 2 rows (warning if another pose stream is usable)
NONFINITE_ROWS      repairable  NaN/inf or a zero quaternion (drop-nonfinite); fatal if all
NON_MONOTONIC       repairable  stamps go backwards (sort)
DUPLICATE_STAMPS    repairable  repeated stamps (drop-duplicates: keeps the first row)
GAPS                warning     a step longer than ``gap_factor`` x the median step
POSE_RATE_LOW       warning     a pose stream slower than ``min_pose_rate_hz`` (10 Hz)
RATE                info        nominal rate and step jitter
GYRO_DEGPS          repairable  gyro looks like deg/s (gyro-deg-to-rad)
ACC_IN_G            repairable  accelerometer looks like g (acc-g-to-mps2)
ACC_SCALE_SUSPECT   warning     |acc| neither ~1 g nor ~9.81 m/s^2; no automatic repair
SATURATION          warning     an axis sits at its extreme value (clipping)
QUAT_NOT_UNIT       repairable  quaternion norms deviate from 1 (normalise-quaternions)
QUAT_SIGN_FLIPS     info        q and -q alternate (continuous-quaternions, optional)
NO_TIME_OVERLAP     fatal       IMU and pose spans do not overlap (warning if another does)
CLOCK_MISMATCH      fatal/warn  stamps on different clocks (fatal), or overlap < 50 %
TOO_SHORT           fatal       IMU shorter than ``min_duration_s``
NO_IMU              fatal       no IMU stream (info with ``allow_pose_only``)
NO_POSES            warning     IMU only: bias recovery needs a pose stream
STAMP_UNIT          repairable  stamps in s, ms or us where nanoseconds are required (stamps-to-ns)
POSE_PLACEHOLDERS   warning     frames at the origin with identity orientation (drop-placeholder-poses)
CLOCK_OFFSET        warning     a pose clock seconds off the IMU's (:mod:`pipeline.checks.rig`)
POSITION_UNIT       repairable  positions in mm or cm (positions-to-m)
FRAME_DISAGREEMENT  warning     IMU and poses disagree about the body frame (recover refuses the stream)
==================  ==========  ==================================================
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

from pipeline.errors import ConfigError
from pipeline.types import STANDARD_GRAVITY_MPS2, Verdict

G_MPS2 = STANDARD_GRAVITY_MPS2
DEG_TO_RAD = math.pi / 180.0
EPOCH_2000_S = 946_684_800  # stamps after this are (almost surely) Unix epoch time
MAX_LISTED = 20  # at most this many items (gaps, indices) are listed in details

IMU_STREAM = "imu"
GROUND_TRUTH_STREAM = "ground_truth"


class Repair(str, enum.Enum):
    """A repair ``biasgt convert --repair`` may apply; the value is the flag name."""

    SORT = "sort"
    DROP_DUPLICATES = "drop-duplicates"
    DROP_NONFINITE = "drop-nonfinite"
    NORMALISE_QUATERNIONS = "normalise-quaternions"
    CONTINUOUS_QUATERNIONS = "continuous-quaternions"
    GYRO_DEG_TO_RAD = "gyro-deg-to-rad"
    ACC_G_TO_MPS2 = "acc-g-to-mps2"
    STAMPS_TO_NS = "stamps-to-ns"
    POSITIONS_TO_M = "positions-to-m"
    DROP_PLACEHOLDER_POSES = "drop-placeholder-poses"


#: The repair that fixes each repairable (or optionally repairable) finding code.
REPAIR_FOR_CODE: dict[str, Repair] = {
    "NON_MONOTONIC": Repair.SORT,
    "DUPLICATE_STAMPS": Repair.DROP_DUPLICATES,
    "NONFINITE_ROWS": Repair.DROP_NONFINITE,
    "QUAT_NOT_UNIT": Repair.NORMALISE_QUATERNIONS,
    "QUAT_SIGN_FLIPS": Repair.CONTINUOUS_QUATERNIONS,
    "GYRO_DEGPS": Repair.GYRO_DEG_TO_RAD,
    "ACC_IN_G": Repair.ACC_G_TO_MPS2,
    "STAMP_UNIT": Repair.STAMPS_TO_NS,
    "POSITION_UNIT": Repair.POSITIONS_TO_M,
    "POSE_PLACEHOLDERS": Repair.DROP_PLACEHOLDER_POSES,
}

#: How to get past each fatal finding code (used in refusal messages).
FATAL_HINTS: dict[str, str] = {
    "TOO_SHORT": "record a longer sequence or lower --min-duration",
    "NO_IMU": "give an input with IMU data, or pass --allow-pose-only",
    "EMPTY_STREAM": "check the topic/file selection (--imu-topic, --pose-topic)",
    "NO_TIME_OVERLAP": "choose a pose stream recorded at the same time as the IMU",
    "CLOCK_MISMATCH": "re-stamp one stream onto the other's clock before converting",
    "NONFINITE_ROWS": "no usable row: check the column mapping and the input's units",
}

#: Every code :func:`run_checks` itself produces (reader findings with these codes are not repeated).
CHECK_CODES = frozenset({
    "EMPTY_STREAM", "NONFINITE_ROWS", "NON_MONOTONIC", "DUPLICATE_STAMPS", "GAPS", "RATE", "GYRO_DEGPS",
    "ACC_IN_G", "ACC_SCALE_SUSPECT", "SATURATION", "QUAT_NOT_UNIT", "QUAT_SIGN_FLIPS", "NO_TIME_OVERLAP",
    "CLOCK_MISMATCH", "TOO_SHORT", "NO_IMU", "NO_POSES", "POSE_RATE_LOW", "IMU_RATE_MISMATCH", "STAMP_UNIT",
    "POSE_PLACEHOLDERS", "CLOCK_OFFSET", "POSITION_UNIT", "FRAME_DISAGREEMENT",
})

#: A recorded IMU rate this far (relative) from the calibration's ``rate_hz`` is IMU_RATE_MISMATCH.
IMU_RATE_TOLERANCE = 0.05


#: How the input checks' :class:`pipeline.types.Verdict` reads (``biasgt inspect``, its ``--json``).
CHECK_VERDICT_WORDS = {Verdict.PASS: "ok", Verdict.WARN: "repairable", Verdict.FAIL: "fatal"}


def check_verdict(word: str) -> Verdict:
    """The :class:`pipeline.types.Verdict` a report's verdict word (:data:`CHECK_VERDICT_WORDS`) stands for.

    Raises:
        KeyError: Not one of the words.
    """
    return {w: v for v, w in CHECK_VERDICT_WORDS.items()}[word]


@dataclass(frozen=True)
class CheckOptions:
    """Thresholds of the input checks.

    Attributes:
        min_duration_s: IMU spans shorter than this are fatal (TOO_SHORT).
        gap_factor: A step longer than ``gap_factor`` x the median step is a gap.
        allow_pose_only: Without IMU, report NO_IMU as info instead of fatal.
        quat_norm_tol: Largest tolerated | |q| - 1 | before QUAT_NOT_UNIT.
        min_overlap_fraction: Overlap of IMU and a pose stream, as a fraction of
            the shorter span, below which CLOCK_MISMATCH is a warning.
        saturation_min_count: Fewest samples at an axis's extreme value for SATURATION.
        min_pose_rate_hz: Pose streams slower than this get POSE_RATE_LOW.
        ignore: Codes the user declared false positives: non-fatal findings with
            these codes are demoted to info (fatal ones cannot be ignored).
    """

    min_duration_s: float = 2.0
    gap_factor: float = 2.0
    allow_pose_only: bool = False
    quat_norm_tol: float = 1e-3
    min_overlap_fraction: float = 0.5
    saturation_min_count: int = 5
    min_pose_rate_hz: float = 10.0
    ignore: frozenset[str] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        if not self.min_duration_s >= 0:
            raise ConfigError(f"min_duration_s must be >= 0, got {self.min_duration_s}", field="min_duration_s")
        if not self.gap_factor > 1:
            raise ConfigError(f"gap_factor must be > 1, got {self.gap_factor}", field="gap_factor")
        codes = self.ignore.split(",") if isinstance(self.ignore, str) else self.ignore
        object.__setattr__(self, "ignore", frozenset(str(c).strip().upper() for c in codes if str(c).strip()))
