"""Input checks and repairs: what is wrong with a loaded :class:`~pipeline.types.Sequence`, and how to fix it.

Readers return what a file holds; this module reports every problem as a
:class:`~pipeline.types.Finding` with a stable ``code`` (part of the
``biasgt inspect --json`` contract), a :class:`~pipeline.types.Severity`, a
one-line message that says how to fix it and JSON-serialisable ``details``.
``biasgt convert`` applies only the repairs the user allows
(:func:`apply_repairs`), re-checks, and refuses while a fatal or an unrepaired
repairable problem remains.

Streams are named ``"imu"``, ``"poses/<stream>"`` and ``"ground_truth"``.

Finding codes produced here (readers add PARSE_SKIPPED_LINES, STAMP_PRECISION_LOSS,
STAMP_UNIT_GUESSED, CALIBRATION_DEFAULTED, BAG_HEADER_STAMP_ZERO):

==================  ==========  ==================================================
code                severity    meaning (repair)
==================  ==========  ==================================================
EMPTY_STREAM        fatal       a stream has fewer than 2 rows (warning for a pose
                                stream when another usable pose stream exists)
NONFINITE_ROWS      repairable  NaN/inf values or an all-zero quaternion (drop-nonfinite);
                                fatal when every row is bad
NON_MONOTONIC       repairable  stamps go backwards (sort)
DUPLICATE_STAMPS    repairable  repeated stamps (drop-duplicates: keeps the first row)
GAPS                warning     a step longer than ``gap_factor`` x the median step
POSE_RATE_LOW       warning     a pose stream slower than ``min_pose_rate_hz`` (10 Hz)
RATE                info        nominal rate and step jitter
GYRO_DEGPS          repairable  gyro looks like deg/s (gyro-deg-to-rad)
ACC_IN_G            repairable  accelerometer looks like g (acc-g-to-mps2)
ACC_SCALE_SUSPECT   warning     |acc| is neither ~1 g nor ~9.81 m/s^2 (raw counts,
                                gravity removed); no automatic repair
SATURATION          warning     an axis sits at its extreme value (clipping)
QUAT_NOT_UNIT       repairable  quaternion norms deviate from 1 (normalise-quaternions)
QUAT_SIGN_FLIPS     info        q and -q alternate (continuous-quaternions, optional)
NO_TIME_OVERLAP     fatal       IMU and pose spans do not overlap (warning when
                                another pose stream overlaps)
CLOCK_MISMATCH      fatal/warn  stamps on different clocks (fatal), or overlap < 50 %
TOO_SHORT           fatal       IMU shorter than ``min_duration_s``
NO_IMU              fatal       no IMU stream (info with ``allow_pose_only``)
NO_POSES            warning     IMU only: bias recovery needs a pose stream
==================  ==========  ==================================================

Unit heuristics (documented rules, see :func:`detect_gyro_degps` and
:func:`detect_acc_in_g`):

* GYRO_DEGPS, first applicable rule wins:
    1. *pose rule*: when a pose stream with orientation (or the ground truth)
       overlaps the IMU and moves (90th percentile of its angular speed
       >= 0.1 rad/s), the ratio r = p90(|gyro|) / p90(pose angular speed) over the
       common span decides: deg/s if r > sqrt(180/pi) ~= 7.6 (the geometric
       middle between 1 and 57.3);
    2. *range rule*: p99(|gyro|) > 35 (35 rad/s = 2005 deg/s exceeds the full
       scale of any MEMS gyro, so such values can only be deg/s);
    3. *static rule*: in static stretches (0.5-s blocks whose |acc| varies by
       < 1 %), a median |mean gyro| > 1.0 is a bias no working gyro has in
       rad/s (57 deg/s) but an ordinary one in deg/s.
* ACC_IN_G: median |acc| in [0.8, 1.25] and 10th percentile >= 0.5 (gravity
  dominates, so the magnitude clusters around 1 g; gravity-removed data in
  m/s^2 has a 10th percentile near 0).

All checks are vectorised numpy: a 1-hour 200-Hz sequence (720000 rows) takes
well under a second.
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pipeline.errors import ConfigError
from pipeline.types import (NS_PER_S, STANDARD_GRAVITY_MPS2, Finding, ImuSeries, PoseSeries, Sequence, Severity,
                            StateSeries)

log = logging.getLogger(__name__)

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


#: The repair that fixes each repairable (or optionally repairable) finding code.
REPAIR_FOR_CODE: dict[str, Repair] = {
    "NON_MONOTONIC": Repair.SORT,
    "DUPLICATE_STAMPS": Repair.DROP_DUPLICATES,
    "NONFINITE_ROWS": Repair.DROP_NONFINITE,
    "QUAT_NOT_UNIT": Repair.NORMALISE_QUATERNIONS,
    "QUAT_SIGN_FLIPS": Repair.CONTINUOUS_QUATERNIONS,
    "GYRO_DEGPS": Repair.GYRO_DEG_TO_RAD,
    "ACC_IN_G": Repair.ACC_G_TO_MPS2,
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
    "CLOCK_MISMATCH", "TOO_SHORT", "NO_IMU", "NO_POSES", "POSE_RATE_LOW", "IMU_RATE_MISMATCH",
})

#: A recorded IMU rate this far (relative) from the calibration's ``rate_hz`` is IMU_RATE_MISMATCH.
IMU_RATE_TOLERANCE = 0.05


class Verdict(str, enum.Enum):
    """Overall outcome of the checks."""

    OK = "ok"
    REPAIRABLE = "repairable"
    FATAL = "fatal"


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


# --------------------------------------------------------------------------------------------------
# stream views


@dataclass
class _Stream:
    """A uniform view of one time-stamped stream: stamps plus named value arrays."""

    name: str  # as shown: "imu", "poses/<stream>" (see pose_stream_label), "ground_truth"
    kind: str  # "imu", "poses", "ground_truth"
    t_ns: np.ndarray
    values: dict[str, np.ndarray]  # name -> [N, k]
    quat: np.ndarray | None
    obj: Any
    key: str = ""  # the sequence's own key of a pose stream (a topic keeps its leading '/')


def pose_stream_label(name: str) -> str:
    """How findings name a pose stream: ``poses/vicon0``, ``poses/odom`` for topic ``/odom`` (no ``//``)."""
    return f"poses/{name.lstrip('/')}"


def _streams(seq: Sequence) -> list[_Stream]:
    out: list[_Stream] = []
    if seq.imu is not None:
        imu = seq.imu
        out.append(_Stream(IMU_STREAM, "imu", imu.t_ns, {"gyro": imu.gyro_radps, "acc": imu.acc_mps2}, None, imu))
    for name, poses in seq.poses.items():
        vals = {"p": poses.p_m}
        if poses.quat_wxyz is not None:
            vals["quat"] = poses.quat_wxyz
        out.append(_Stream(pose_stream_label(name), "poses", poses.t_ns, vals, poses.quat_wxyz, poses, key=name))
    if seq.ground_truth is not None:
        gt = seq.ground_truth
        vals = {"p": gt.p_m, "quat": gt.quat_wxyz, "v": gt.v_mps, "bg": gt.bias_gyro_radps, "ba": gt.bias_acc_mps2}
        out.append(_Stream(GROUND_TRUTH_STREAM, "ground_truth", gt.t_ns, vals, gt.quat_wxyz, gt))
    return out


def _finite_rows(arr: np.ndarray) -> np.ndarray:
    """Boolean [N]: rows of ``arr`` [N, k] whose values are all finite (column sums: fast for small k)."""
    total = arr[:, 0].copy()
    for i in range(1, arr.shape[1]):
        total += arr[:, i]
    with np.errstate(invalid="ignore"):
        return np.isfinite(total)


def _row_norm(arr: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of ``arr`` [N, k] -> [N]."""
    return np.sqrt(np.einsum("ij,ij->i", arr, arr))


def _rows(arr: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``arr[valid]`` without the copy when every row is valid."""
    return arr if valid.all() else arr[valid]


def _time_order(t_ns: np.ndarray) -> np.ndarray | slice:
    """Index that orders ``t_ns`` by time (a no-op slice when it already is)."""
    if len(t_ns) < 2 or bool(np.all(t_ns[1:] >= t_ns[:-1])):
        return slice(None)
    return np.argsort(t_ns, kind="stable")


def _valid_rows(s: _Stream) -> np.ndarray:
    """Boolean [N]: rows whose values are all finite and whose quaternion is not (near) zero."""
    ok = np.ones(len(s.t_ns), dtype=bool)
    for arr in s.values.values():
        ok &= _finite_rows(arr)
    if s.quat is not None:
        with np.errstate(invalid="ignore"):
            ok &= np.einsum("ij,ij->i", s.quat, s.quat) > 1e-2
    return ok


def _rel_s(t_ns: np.ndarray | int, t0_ns: int) -> Any:
    return (np.asarray(t_ns, dtype=np.int64) - t0_ns) / NS_PER_S


def _round(x: float, nd: int = 6) -> float | None:
    x = float(x)
    return None if not math.isfinite(x) else round(x, nd)


@dataclass
class _TimeStats:
    t0_ns: int
    t1_ns: int
    sorted_unique: np.ndarray
    dt_ns: np.ndarray  # positive steps of sorted_unique
    nominal_ns: float


def _time_stats(t_ns: np.ndarray) -> _TimeStats:
    if len(t_ns) > 1 and bool(np.all(t_ns[1:] > t_ns[:-1])):
        tu = t_ns
    else:
        tu = np.unique(t_ns)
    dt = np.diff(tu)
    nominal = float(np.median(dt)) if len(dt) else float("nan")
    return _TimeStats(int(tu[0]) if len(tu) else 0, int(tu[-1]) if len(tu) else 0, tu, dt, nominal)


# --------------------------------------------------------------------------------------------------
# per-stream checks


def _check_stamps(s: _Stream, ts: _TimeStats, opts: CheckOptions) -> list[Finding]:
    out: list[Finding] = []
    t = s.t_ns
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if len(back):
        rows = back + 1
        out.append(Finding(
            "NON_MONOTONIC", Severity.REPAIRABLE, s.name,
            f"{s.name} stamps go backwards {len(back)} times (first at row {int(rows[0])}, "
            f"t={float(_rel_s(t[rows[0]], ts.t0_ns)):.3f} s); sort them with --repair {Repair.SORT.value}",
            {"count": int(len(back)), "first_rows": [int(i) for i in rows[:MAX_LISTED]],
             "first_t_s": [_round(x) for x in _rel_s(t[rows[:MAX_LISTED]], ts.t0_ns)],
             "max_backward_s": _round(-float(dt[back].min()) / NS_PER_S)},
        ))
    n_dup = len(t) - len(ts.sorted_unique)
    if n_dup:
        if len(back):
            st = np.sort(t)
            dup_t = st[1:][np.diff(st) == 0]
        else:
            dup_t = t[1:][dt == 0]
        out.append(Finding(
            "DUPLICATE_STAMPS", Severity.REPAIRABLE, s.name,
            f"{s.name} has {n_dup} repeated stamps (first at t={float(_rel_s(dup_t[0], ts.t0_ns)):.3f} s); "
            f"keep the first row of each with --repair {Repair.DROP_DUPLICATES.value}",
            {"count": int(n_dup), "first_t_s": [_round(x) for x in _rel_s(dup_t[:MAX_LISTED], ts.t0_ns)]},
        ))
    if len(ts.dt_ns) == 0 or not math.isfinite(ts.nominal_ns):
        return out
    nominal = ts.nominal_ns
    gap_idx = np.flatnonzero(ts.dt_ns > opts.gap_factor * nominal)
    if len(gap_idx):
        durations = ts.dt_ns[gap_idx] / NS_PER_S
        starts = ts.sorted_unique[gap_idx]
        longest = int(np.argmax(durations))
        out.append(Finding(
            "GAPS", Severity.WARNING, s.name,
            f"{s.name} has {len(gap_idx)} gaps longer than {opts.gap_factor:g}x its {nominal / 1e6:.3f} ms period "
            f"(longest {durations[longest]:.3f} s at t={float(_rel_s(starts[longest], ts.t0_ns)):.3f} s); "
            "results across gaps are less reliable, cut the sequence there if they are long",
            {"count": int(len(gap_idx)), "nominal_period_ms": _round(nominal / 1e6),
             "total_gap_s": _round(float(durations.sum())),
             "gaps": [{"start_t_ns": int(a), "start_t_s": _round(float(_rel_s(a, ts.t0_ns))), "duration_s": _round(d)}
                      for a, d in zip(starts[:MAX_LISTED], durations[:MAX_LISTED])]},
        ))
    dt_ms = ts.dt_ns / 1e6
    rate = NS_PER_S / nominal
    details: dict[str, Any] = {
        "rate_hz": _round(rate), "nominal_period_ms": _round(nominal / 1e6),
        "dt_std_ms": _round(float(dt_ms.std())), "dt_min_ms": _round(float(dt_ms.min())),
        "dt_max_ms": _round(float(dt_ms.max())),
    }
    out.append(Finding(
        "RATE", Severity.INFO, s.name,
        f"{s.name} runs at {rate:.2f} Hz (step jitter std {details['dt_std_ms']:.3f} ms, max step "
        f"{details['dt_max_ms']:.3f} ms)",
        details,
    ))
    return out


def _check_pose_rate(s: _Stream, ts: _TimeStats, opts: CheckOptions) -> list[Finding]:
    """POSE_RATE_LOW: a pose stream sampled too sparsely to pin the bias down over 1-s windows."""
    if s.kind == "imu" or not math.isfinite(ts.nominal_ns) or ts.nominal_ns <= 0:
        return []
    rate = NS_PER_S / ts.nominal_ns
    if rate >= opts.min_pose_rate_hz:
        return []
    return [Finding(
        "POSE_RATE_LOW", Severity.WARNING, s.name,
        f"{s.name} runs at {rate:.3g} Hz, below {opts.min_pose_rate_hz:g} Hz: the bias between poses rests on the "
        "IMU alone and 1-s validation windows have few references; use the full-rate stream if there is one",
        {"rate_hz": _round(rate), "min_pose_rate_hz": opts.min_pose_rate_hz},
    )]


def _check_nonfinite(s: _Stream, valid: np.ndarray) -> list[Finding]:
    bad = np.flatnonzero(~valid)
    if not len(bad):
        return []
    if len(bad) == len(valid):
        return [Finding(
            "NONFINITE_ROWS", Severity.FATAL, s.name,
            f"every one of the {len(bad)} rows of {s.name} has NaN/inf values or a zero quaternion; "
            "check the column mapping and the input's units", {"count": int(len(bad)), "first_rows": [0]},
        )]
    return [Finding(
        "NONFINITE_ROWS", Severity.REPAIRABLE, s.name,
        f"{s.name} has {len(bad)} rows with NaN/inf values or a zero quaternion (first row {int(bad[0])}); "
        f"drop them with --repair {Repair.DROP_NONFINITE.value}",
        {"count": int(len(bad)), "first_rows": [int(i) for i in bad[:MAX_LISTED]]},
    )]


def _check_quaternions(s: _Stream, valid: np.ndarray, opts: CheckOptions) -> list[Finding]:
    if s.quat is None:
        return []
    out: list[Finding] = []
    order = _time_order(s.t_ns)
    q = _rows(s.quat[order], valid[order])
    if len(q) == 0:
        return out
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    dev = np.abs(norm - 1.0)
    max_dev = float(dev.max())
    if max_dev > opts.quat_norm_tol:
        out.append(Finding(
            "QUAT_NOT_UNIT", Severity.REPAIRABLE, s.name,
            f"{s.name} quaternion norms deviate from 1 by up to {max_dev:.3g} ({int((dev > opts.quat_norm_tol).sum())} "
            f"rows); normalise them with --repair {Repair.NORMALISE_QUATERNIONS.value}",
            {"max_deviation": _round(max_dev, 9), "count": int((dev > opts.quat_norm_tol).sum()),
             "tolerance": opts.quat_norm_tol},
        ))
    if len(q) > 1:
        flips = int((np.einsum("ij,ij->i", q[1:], q[:-1]) < 0).sum())
        if flips:
            out.append(Finding(
                "QUAT_SIGN_FLIPS", Severity.INFO, s.name,
                f"{s.name} quaternions change sign {flips} times (q and -q are the same rotation); "
                f"make them continuous with --repair {Repair.CONTINUOUS_QUATERNIONS.value} if a tool needs it",
                {"count": flips},
            ))
    return out


def _pose_angular_speed(t_ns: np.ndarray, quat: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angular speed between consecutive valid, time-ordered poses: (mid stamps [M], speed rad/s [M])."""
    order = _time_order(t_ns)
    t = _rows(t_ns[order], valid[order])
    q = _rows(quat[order], valid[order])
    q = q / _row_norm(q)[:, None]
    dt = np.diff(t)
    keep = dt > 0
    if keep.sum() < 2:
        return np.empty(0, np.int64), np.empty(0)
    nominal = float(np.median(dt[keep]))
    keep &= dt <= 5 * nominal
    dot = np.clip(np.abs(np.einsum("ij,ij->i", q[1:], q[:-1])), 0.0, 1.0)
    angle = 2.0 * np.arccos(dot)
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = angle / (dt / NS_PER_S)
    mid = t[:-1] + dt // 2
    return mid[keep], speed[keep]


def detect_gyro_degps(seq: Sequence, valid: np.ndarray | None = None) -> dict[str, Any] | None:
    """Decide whether the IMU gyro is in deg/s (rules in the module docstring).

    Args:
        seq: The sequence (its IMU and, for the pose rule, its oriented pose streams / ground truth).
        valid: Optional boolean [N] of usable IMU rows.

    Returns:
        ``None`` when the gyro looks like rad/s (or there is no IMU), else the
        details of the rule that fired (``rule`` plus its figures).
    """
    imu = seq.imu
    if imu is None or len(imu) < 2:
        return None
    if valid is None:
        valid = _finite_rows(imu.gyro_radps) & _finite_rows(imu.acc_mps2)
    t = _rows(imu.t_ns, valid)
    gyro = _rows(imu.gyro_radps, valid)
    gnorm = _row_norm(gyro)
    if len(gnorm) < 2:
        return None
    # Rule 1: against the pose streams' angular speed.
    candidates: list[tuple[str, np.ndarray, np.ndarray]] = []
    if seq.ground_truth is not None:
        candidates.append((GROUND_TRUTH_STREAM, seq.ground_truth.t_ns, seq.ground_truth.quat_wxyz))
    for name, poses in seq.poses.items():
        if poses.quat_wxyz is not None:
            candidates.append((pose_stream_label(name), poses.t_ns, poses.quat_wxyz))
    for name, pt, pq in candidates:
        if len(pt) < 3:
            continue
        with np.errstate(invalid="ignore"):
            pvalid = _finite_rows(pq) & (np.einsum("ij,ij->i", pq, pq) > 1e-2)
        mid, speed = _pose_angular_speed(pt, pq, pvalid)
        if len(mid) < 10:
            continue
        lo, hi = max(int(mid.min()), int(t.min())), min(int(mid.max()), int(t.max()))
        if hi <= lo:
            continue
        sp = speed[(mid >= lo) & (mid <= hi)]
        gi = gnorm[(t >= lo) & (t <= hi)]
        if len(sp) < 10 or len(gi) < 10:
            continue
        p90_pose = float(np.percentile(sp, 90))
        if p90_pose < 0.1:
            continue
        p90_gyro = float(np.percentile(gi, 90))
        ratio = p90_gyro / p90_pose
        if ratio > math.sqrt(180.0 / math.pi):
            return {"rule": "pose_rate_ratio", "pose_stream": name, "ratio": _round(ratio, 3),
                    "gyro_p90": _round(p90_gyro), "pose_rate_p90_radps": _round(p90_pose)}
        return None  # the poses say rad/s: trust them over the magnitude rules
    # Rule 2: beyond any MEMS full scale in rad/s.
    p99 = float(np.percentile(gnorm, 99))
    if p99 > 35.0:
        return {"rule": "p99_magnitude", "gyro_p99": _round(p99, 3), "threshold": 35.0}
    # Rule 3: static stretches with an absurd bias.
    rate = imu.rate_hz
    block = max(10, int(round(0.5 * rate))) if math.isfinite(rate) else 100
    nb = len(gnorm) // block
    if nb >= 2:
        anorm = _row_norm(_rows(imu.acc_mps2, valid)[: nb * block]).reshape(nb, block)
        mean_a = anorm.mean(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            static = (anorm.std(axis=1) < 0.01 * mean_a) & (mean_a > 0)
        if static.sum() >= 2:
            gmean = gyro[: nb * block].reshape(nb, block, 3).mean(axis=1)[static]
            static_mag = float(np.median(_row_norm(gmean)))
            if static_mag > 1.0:
                return {"rule": "static_magnitude", "static_gyro_magnitude": _round(static_mag, 4),
                        "static_seconds": _round(float(static.sum() * block / rate), 2), "threshold": 1.0}
    return None


def detect_acc_in_g(acc: np.ndarray) -> dict[str, Any] | None:
    """Decide whether accelerometer values [N, 3] are in g (rule in the module docstring).

    Returns:
        ``None`` when they do not look like g, else details (median and 10th percentile of |acc|).
    """
    n = _row_norm(_rows(acc, _finite_rows(acc)))
    if len(n) < 2:
        return None
    p10, med = (float(x) for x in np.percentile(n, [10, 50]))
    if 0.8 <= med <= 1.25 and p10 >= 0.5:
        return {"median_norm": _round(med, 4), "p10_norm": _round(p10, 4)}
    return None


def _check_imu_units(seq: Sequence, valid: np.ndarray) -> list[Finding]:
    imu = seq.imu
    assert imu is not None
    out: list[Finding] = []
    g = detect_gyro_degps(seq, valid)
    if g is not None:
        out.append(Finding(
            "GYRO_DEGPS", Severity.REPAIRABLE, IMU_STREAM,
            f"gyro values look like deg/s, not rad/s (rule {g['rule']}); scale them by pi/180 with "
            f"--repair {Repair.GYRO_DEG_TO_RAD.value} (or --ignore GYRO_DEGPS if they are rad/s)",
            g,
        ))
    acc = _rows(imu.acc_mps2, valid)
    a = detect_acc_in_g(acc)
    if a is not None:
        out.append(Finding(
            "ACC_IN_G", Severity.REPAIRABLE, IMU_STREAM,
            f"accelerometer magnitude clusters at {a['median_norm']:.3f} (1 g), so values look like g, not m/s^2; "
            f"multiply by {G_MPS2} with --repair {Repair.ACC_G_TO_MPS2.value}",
            a,
        ))
    else:
        if len(acc) >= 2:
            med = float(np.median(_row_norm(acc)))
            if not 4.0 <= med <= 20.0:
                out.append(Finding(
                    "ACC_SCALE_SUSPECT", Severity.WARNING, IMU_STREAM,
                    f"median |acc| is {med:.4g}, far from 9.81 m/s^2 (raw counts? gravity removed?); "
                    "give raw specific force in m/s^2",
                    {"median_norm": _round(med, 4)},
                ))
    return out


def _saturated_axis(x: np.ndarray, min_count: int) -> dict[str, Any] | None:
    """Flat top at the largest |value| of one axis [N], or ``None``."""
    a = np.abs(x)
    if len(a) == 0:
        return None
    top = float(a.max())
    if not top > 0:
        return None
    at_top = a >= top * (1 - 1e-9)
    count = int(at_top.sum())
    if count < min_count:
        return None
    # A clipped axis piles up at the top: far more samples there than just below it (within 2 %),
    # and than at the next lower distinct level (the next quantisation step of a quantised sensor,
    # where a Gaussian tail has *more* samples than at its top).
    below = a[~at_top]
    band = int((below >= top * 0.98).sum())
    if len(below):
        next_level = float(below.max())
        next_count = int((below >= next_level * (1 - 1e-9)).sum())
    else:
        next_count = 0
    if count <= 2 * band or count <= 2 * next_count:
        return None  # a smooth peak or a noise tail, not a clipped one
    return {"value": _round(top, 9), "count": count, "band_count": band, "next_level_count": next_count}


def _check_saturation(imu: ImuSeries, valid: np.ndarray, opts: CheckOptions) -> list[Finding]:
    axes: dict[str, Any] = {}
    for prefix, arr in (("gyro", imu.gyro_radps), ("acc", imu.acc_mps2)):
        arr = _rows(arr, valid)
        for i, ax in enumerate("xyz"):
            hit = _saturated_axis(arr[:, i], opts.saturation_min_count)
            if hit is not None:
                axes[f"{prefix}_{ax}"] = hit
    if not axes:
        return []
    desc = ", ".join(f"{k} at |{v['value']:.4g}| x{v['count']}" for k, v in axes.items())
    return [Finding(
        "SATURATION", Severity.WARNING, IMU_STREAM,
        f"IMU axes sit at their extreme value ({desc}): the sensor range was exceeded there; "
        "cut those segments or record with a wider range",
        {"axes": axes, "count": int(sum(v["count"] for v in axes.values()))},
    )]


# --------------------------------------------------------------------------------------------------
# cross-stream checks


def _check_overlap(seq: Sequence, spans: dict[str, tuple[int, int]], opts: CheckOptions) -> list[Finding]:
    if IMU_STREAM not in spans:
        return []
    i0, i1 = spans[IMU_STREAM]
    others = {k: v for k, v in spans.items() if k != IMU_STREAM}
    results: dict[str, tuple[str, dict[str, Any], str]] = {}
    good = 0
    for name, (p0, p1) in others.items():
        overlap_ns = min(i1, p1) - max(i0, p0)
        shorter_ns = max(1, min(i1 - i0, p1 - p0))
        details = {"imu_t0_s": _round(i0 / NS_PER_S, 3), "imu_t1_s": _round(i1 / NS_PER_S, 3),
                   "stream_t0_s": _round(p0 / NS_PER_S, 3), "stream_t1_s": _round(p1 / NS_PER_S, 3),
                   "offset_s": _round((p0 - i0) / NS_PER_S, 3), "overlap_s": _round(max(overlap_ns, 0) / NS_PER_S, 3)}
        epoch_i, epoch_p = i0 / NS_PER_S > EPOCH_2000_S, p0 / NS_PER_S > EPOCH_2000_S
        separation_s = -overlap_ns / NS_PER_S
        longest_s = max(i1 - i0, p1 - p0) / NS_PER_S
        if overlap_ns <= 0 and (epoch_i != epoch_p or separation_s > max(3600.0, 10 * longest_s)):
            results[name] = ("CLOCK_MISMATCH", details,
                             f"{name} and imu stamps differ by {abs(p0 - i0) / NS_PER_S:.4g} s "
                             f"({'epoch' if epoch_p else 'since boot'} vs {'epoch' if epoch_i else 'since boot'}): "
                             "they are on different clocks; re-stamp one onto the other's clock")
        elif overlap_ns <= 0:
            results[name] = ("NO_TIME_OVERLAP", details,
                             f"{name} ({p0 / NS_PER_S:.3f}..{p1 / NS_PER_S:.3f} s) does not overlap the imu "
                             f"({i0 / NS_PER_S:.3f}..{i1 / NS_PER_S:.3f} s); use a pose stream recorded with the IMU")
        else:
            frac = overlap_ns / shorter_ns
            details["overlap_fraction"] = _round(frac, 4)
            good += 1
            if frac < opts.min_overlap_fraction:
                results[name] = ("CLOCK_MISMATCH_PARTIAL", details,
                                 f"{name} overlaps the imu for only {overlap_ns / NS_PER_S:.3f} s "
                                 f"({100 * frac:.0f} % of the shorter span); check the clocks or trim the input")
    out: list[Finding] = []
    for name, (code, details, msg) in results.items():
        if code == "CLOCK_MISMATCH_PARTIAL":
            out.append(Finding("CLOCK_MISMATCH", Severity.WARNING, name, msg, details))
        else:
            sev = Severity.WARNING if good else Severity.FATAL
            if good:
                msg += " (another stream overlaps: this one cannot be used)"
            out.append(Finding(code, sev, name, msg, details))
    return out


# --------------------------------------------------------------------------------------------------
# public API


def _check_imu_rate(seq: Sequence, s: _Stream, ts: _TimeStats) -> list[Finding]:
    """IMU_RATE_MISMATCH: the IMU runs far from the rate its calibration file states."""
    cal = seq.calibration
    where = cal.sources.get("rate_hz")
    if s.kind != "imu" or where is None or not math.isfinite(ts.nominal_ns) or ts.nominal_ns <= 0:
        return []
    rate = NS_PER_S / ts.nominal_ns
    if abs(rate / cal.rate_hz - 1.0) <= IMU_RATE_TOLERANCE:
        return []
    return [Finding(
        "IMU_RATE_MISMATCH", Severity.WARNING, s.name,
        f"imu runs at {rate:.4g} Hz but its calibration ({where}) says {cal.rate_hz:g} Hz: the noise values and a "
        f"model trained at that rate do not fit this recording; resample it (biasgt convert --resample-hz "
        f"{cal.rate_hz:g}) or correct rate_hz",
        {"rate_hz": _round(rate), "calibration_rate_hz": float(cal.rate_hz)},
    )]


def run_checks(seq: Sequence, options: CheckOptions | None = None) -> list[Finding]:
    """All input checks on ``seq``.

    Args:
        seq: The loaded sequence (not modified).
        options: Thresholds; defaults to :class:`CheckOptions`.

    Returns:
        The reader's findings (``seq.findings``, except earlier check results)
        followed by this module's, in stream order.
    """
    opts = options or CheckOptions()
    findings: list[Finding] = [f for f in seq.findings if f.code not in CHECK_CODES]
    if seq.imu is None:
        if opts.allow_pose_only:
            findings.append(Finding("NO_IMU", Severity.INFO, IMU_STREAM,
                                    "no IMU stream; converting poses only (--allow-pose-only)", {}))
        else:
            findings.append(Finding(
                "NO_IMU", Severity.FATAL, IMU_STREAM,
                "the input has no IMU stream (no sensor_msgs/Imu topic, no imu0/data.csv, no IMU columns); "
                "bias recovery needs one: give the recording that holds the IMU, or pass --allow-pose-only "
                "to convert the poses alone", {}))
    elif not seq.poses and seq.ground_truth is None:
        findings.append(Finding("NO_POSES", Severity.WARNING, IMU_STREAM,
                                "the input has no pose stream: bias recovery needs one (add a pose file with "
                                "--add-poses PATH[:KIND], or pick a bag topic with --pose-topic); "
                                "IMU-only data can still be converted", {}))
    streams = _streams(seq)
    n_pose_usable = sum(1 for s in streams if s.kind != "imu" and len(s.t_ns) >= 2)
    spans: dict[str, tuple[int, int]] = {}
    for s in streams:
        n = len(s.t_ns)
        if n < 2:
            fatal = s.kind == "imu" or n_pose_usable == 0
            findings.append(Finding(
                "EMPTY_STREAM", Severity.FATAL if fatal else Severity.WARNING, s.name,
                f"{s.name} has {n} rows; " + FATAL_HINTS["EMPTY_STREAM"], {"count": n}))
            continue
        valid = _valid_rows(s)
        findings += _check_nonfinite(s, valid)
        ts = _time_stats(s.t_ns)
        spans[s.name] = (ts.t0_ns, ts.t1_ns)
        findings += _check_stamps(s, ts, opts)
        findings += _check_pose_rate(s, ts, opts)
        findings += _check_imu_rate(seq, s, ts)
        findings += _check_quaternions(s, valid, opts)
        if s.kind == "imu":
            assert seq.imu is not None
            duration = (ts.t1_ns - ts.t0_ns) / NS_PER_S
            if duration < opts.min_duration_s:
                findings.append(Finding(
                    "TOO_SHORT", Severity.FATAL, s.name,
                    f"imu spans {duration:.3f} s, less than the {opts.min_duration_s:g} s minimum; "
                    + FATAL_HINTS["TOO_SHORT"],
                    {"duration_s": _round(duration), "min_duration_s": opts.min_duration_s}))
            findings += _check_imu_units(seq, valid)
            findings += _check_saturation(seq.imu, valid, opts)
    findings += _check_overlap(seq, spans, opts)
    return _apply_ignore(findings, opts)


def _apply_ignore(findings: list[Finding], opts: CheckOptions) -> list[Finding]:
    if not opts.ignore:
        return findings
    out = []
    for f in findings:
        if f.code in opts.ignore and f.severity != Severity.FATAL:
            f = replace(f, severity=Severity.INFO, message=f"(ignored) {f.message}",
                        details={**f.details, "ignored": True, "severity": f.severity.value})
        elif f.code in opts.ignore:
            log.warning("cannot ignore fatal finding %s on %s", f.code, f.stream)
        out.append(f)
    return out


def fatal_findings(findings: Iterable[Finding]) -> list[Finding]:
    """The findings with :attr:`Severity.FATAL`."""
    return [f for f in findings if f.severity == Severity.FATAL]


def repairable_findings(findings: Iterable[Finding]) -> list[Finding]:
    """The findings with :attr:`Severity.REPAIRABLE`."""
    return [f for f in findings if f.severity == Severity.REPAIRABLE]


def verdict(findings: Iterable[Finding]) -> Verdict:
    """``fatal`` if any finding is fatal, else ``repairable`` if any is repairable, else ``ok``."""
    sev = {f.severity for f in findings}
    if Severity.FATAL in sev:
        return Verdict.FATAL
    if Severity.REPAIRABLE in sev:
        return Verdict.REPAIRABLE
    return Verdict.OK


def parse_repairs(spec: str | Iterable[str | Repair] | None) -> set[Repair]:
    """Repairs from ``"sort,drop-duplicates"``, ``"all"``, ``"none"`` or an iterable of names / :class:`Repair`.

    Raises:
        ConfigError: For an unknown repair name.
    """
    if spec is None:
        return set()
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out: set[Repair] = set()
    for item in items:
        if isinstance(item, Repair):
            out.add(item)
            continue
        name = str(item).strip().lower().replace("_", "-")
        if not name or name == "none":
            continue
        if name == "all":
            out |= set(Repair)
            continue
        try:
            out.add(Repair(name))
        except ValueError:
            raise ConfigError(f"unknown repair '{item}'", field="--repair",
                              hint="use a comma list of " + ", ".join(r.value for r in Repair) + ", or 'all'") from None
    return out


def _replace_stream(obj: Any, **arrays: np.ndarray) -> Any:
    if isinstance(obj, ImuSeries):
        return ImuSeries(obj.t_ns, arrays.get("gyro_radps", obj.gyro_radps), arrays.get("acc_mps2", obj.acc_mps2),
                         obj.temperature_degc)
    return replace(obj, **arrays)


def apply_repairs(seq: Sequence, repairs: Iterable[Repair | str], options: CheckOptions | None = None
                  ) -> tuple[Sequence, list[str]]:
    """Apply the allowed repairs to every stream; ``seq`` is not modified.

    Order: drop non-finite rows, sort, drop duplicates (keeps the first row of
    each stamp), unit scaling, normalise quaternions, make them continuous.
    The unit repairs are applied only where their check fires (so ``--repair all``
    leaves correct data alone) and not when the user ignores that code.

    Args:
        seq: The sequence.
        repairs: The allowed repairs.
        options: Check options (its ``ignore`` set matters for the unit repairs).

    Returns:
        ``(new_sequence, changes)``: ``changes`` says what was changed, with counts;
        it is appended to ``new_sequence.metadata["repairs"]``.
    """
    allowed = parse_repairs(repairs)
    opts = options or CheckOptions()
    changes: list[str] = []
    imu, poses, gt = seq.imu, dict(seq.poses), seq.ground_truth

    def fix_rows(name: str, obj: Any, valid: np.ndarray) -> Any:
        n0 = len(obj)
        if Repair.DROP_NONFINITE in allowed and not valid.all():
            obj = obj.take(np.flatnonzero(valid))
            changes.append(f"{name}: dropped {n0 - len(obj)} rows with non-finite values or zero quaternions")
        t = obj.t_ns
        if Repair.SORT in allowed and len(t) > 1 and bool(np.any(t[1:] < t[:-1])):
            steps = int((t[1:] < t[:-1]).sum())
            obj = obj.take(np.argsort(t, kind="stable"))
            changes.append(f"{name}: sorted {len(t)} rows by time ({steps} backward steps)")
            t = obj.t_ns
        if Repair.DROP_DUPLICATES in allowed and len(t) > 1:
            if bool(np.all(t[1:] >= t[:-1])):
                keep = np.concatenate([[True], t[1:] != t[:-1]])
                idx = np.flatnonzero(keep)
            else:
                _, first = np.unique(t, return_index=True)
                idx = np.sort(first)
            if len(idx) < len(t):
                obj = obj.take(idx)
                changes.append(f"{name}: dropped {len(t) - len(idx)} rows with repeated stamps (kept the first)")
        return obj

    def fix_quat(name: str, obj: Any) -> Any:
        q = obj.quat_wxyz
        if q is None or len(q) == 0:
            return obj
        if Repair.NORMALISE_QUATERNIONS in allowed:
            norm = np.linalg.norm(q, axis=1, keepdims=True)
            dev = np.abs(norm[:, 0] - 1.0)
            n_off = int((dev > opts.quat_norm_tol).sum())
            max_dev = float(np.nanmax(dev)) if np.isfinite(dev).any() else 0.0
            if max_dev > 1e-12:  # leave already-unit quaternions bit-identical
                with np.errstate(divide="ignore", invalid="ignore"):
                    q = q / norm
                obj = _replace_stream(obj, quat_wxyz=q)
                changes.append(f"{name}: normalised quaternions (max norm deviation {max_dev:.3g}; "
                               f"{n_off} rows beyond {opts.quat_norm_tol:g})")
        if Repair.CONTINUOUS_QUATERNIONS in allowed and len(q) > 1:
            dots = np.einsum("ij,ij->i", q[1:], q[:-1])
            flips = int((dots < 0).sum())
            if flips:
                sign = np.concatenate([[1.0], np.cumprod(np.where(dots < 0, -1.0, 1.0))])
                obj = _replace_stream(obj, quat_wxyz=q * sign[:, None])
                changes.append(f"{name}: made quaternions continuous ({flips} sign flips)")
        return obj

    for s in _streams(seq):
        if len(s.t_ns) == 0:
            continue
        obj = fix_rows(s.name, s.obj, _valid_rows(s))
        if s.kind != "imu":
            obj = fix_quat(s.name, obj)
        if s.kind == "imu":
            imu = obj
        elif s.kind == "poses":
            poses[s.key] = obj
        else:
            gt = obj
    work = replace(seq, imu=imu, poses=poses, ground_truth=gt)
    if imu is not None and len(imu) > 1:
        valid = _finite_rows(imu.gyro_radps) & _finite_rows(imu.acc_mps2)
        if Repair.GYRO_DEG_TO_RAD in allowed and "GYRO_DEGPS" not in opts.ignore:
            hit = detect_gyro_degps(work, valid)
            if hit is not None:
                imu = _replace_stream(imu, gyro_radps=imu.gyro_radps * DEG_TO_RAD)
                changes.append(f"imu: scaled gyro by pi/180 (deg/s to rad/s, rule {hit['rule']}; {len(imu)} rows)")
        if Repair.ACC_G_TO_MPS2 in allowed and "ACC_IN_G" not in opts.ignore:
            if detect_acc_in_g(_rows(imu.acc_mps2, valid)) is not None:
                imu = _replace_stream(imu, acc_mps2=imu.acc_mps2 * G_MPS2)
                changes.append(f"imu: scaled accelerometer by {G_MPS2} (g to m/s^2; {len(imu)} rows)")
        work = replace(work, imu=imu)
    metadata = dict(seq.metadata)
    metadata["repairs"] = list(metadata.get("repairs") or []) + changes
    work = replace(work, metadata=metadata, findings=list(seq.findings))
    for c in changes:
        log.info("repair: %s", c)
    return work, changes


def _finite_stats(t_ns: np.ndarray) -> dict[str, Any]:
    if len(t_ns) == 0:
        return {"t0_ns": None, "t1_ns": None, "duration_s": 0.0, "rate_hz": None, "dt_std_ms": None,
                "dt_max_ms": None}
    ts = _time_stats(t_ns)
    dt_ms = ts.dt_ns / 1e6
    return {
        "t0_ns": ts.t0_ns, "t1_ns": ts.t1_ns, "duration_s": _round((ts.t1_ns - ts.t0_ns) / NS_PER_S),
        "rate_hz": _round(NS_PER_S / ts.nominal_ns) if len(dt_ms) else None,
        "dt_std_ms": _round(float(dt_ms.std())) if len(dt_ms) else None,
        "dt_max_ms": _round(float(dt_ms.max())) if len(dt_ms) else None,
    }


#: Keys of each :func:`stream_summaries` entry (part of the ``inspect --json`` contract).
STREAM_SUMMARY_KEYS = ("stream", "kind", "count", "t0_ns", "t1_ns", "duration_s", "rate_hz", "dt_std_ms",
                       "dt_max_ms", "frame", "source_kind", "has_orientation")


def stream_summaries(seq: Sequence) -> list[dict[str, Any]]:
    """One JSON-ready row per stream (keys :data:`STREAM_SUMMARY_KEYS`).

    ``rate_hz`` comes from the median positive step, ``dt_std_ms`` / ``dt_max_ms``
    from the positive steps of the sorted unique stamps; ``frame`` and
    ``source_kind`` are ``None`` for the IMU.
    """
    rows = []
    for s in _streams(seq):
        obj = s.obj
        if isinstance(obj, PoseSeries):
            frame, kind, has_q = obj.frame, obj.source_kind.value, obj.has_orientation
        elif isinstance(obj, StateSeries):
            frame, kind, has_q = "imu", "ground_truth", True
        else:
            frame, kind, has_q = None, None, False
        rows.append({"stream": s.name, "kind": s.kind, "count": int(len(s.t_ns)), **_finite_stats(s.t_ns),
                     "frame": frame, "source_kind": kind, "has_orientation": has_q})
    return rows


#: Reader findings every command that reads the input repeats as a warning (and keeps in its JSON).
READER_WARNING_CODES = ("PARSE_SKIPPED_LINES",)


def reader_warnings(findings: Iterable[Finding]) -> list[str]:
    """``"input: <message>"`` of each reader finding in :data:`READER_WARNING_CODES` (skipped
    unparseable lines: count, first line numbers, file), for a command's warnings and stage JSON."""
    return [f"input: {f.message}" for f in findings if f.code in READER_WARNING_CODES]
