"""Running the input checks: :func:`run_checks` (per-stream and cross-stream checks), the
:func:`verdict`, and one summary row per stream (:func:`stream_summaries`, ``inspect --json``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

import numpy as np

from pipeline.checks.options import (
    CHECK_CODES,
    EPOCH_2000_S,
    FATAL_HINTS,
    IMU_RATE_TOLERANCE,
    IMU_STREAM,
    CheckOptions,
)
from pipeline.checks.stream_checks import (
    check_imu_units,
    check_nonfinite,
    check_pose_rate,
    check_quaternions,
    check_saturation,
    check_stamps,
)
from pipeline.checks.stamp_unit import check_stamp_unit
from pipeline.checks.streams import round_or_none, StreamView, stream_views, time_stats, TimeStats, valid_rows
from pipeline.types import NS_PER_S, Finding, PoseSeries, Sequence, Severity, StateSeries, Verdict

log = logging.getLogger(__package__)  # findings and repairs log as one: 'pipeline.checks'


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
        details = {"imu_t0_s": round_or_none(i0 / NS_PER_S, 3), "imu_t1_s": round_or_none(i1 / NS_PER_S, 3),
                   "stream_t0_s": round_or_none(p0 / NS_PER_S, 3), "stream_t1_s": round_or_none(p1 / NS_PER_S, 3),
                   "offset_s": round_or_none((p0 - i0) / NS_PER_S, 3), "overlap_s": round_or_none(max(overlap_ns, 0) / NS_PER_S, 3)}
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
            details["overlap_fraction"] = round_or_none(frac, 4)
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


def _check_imu_rate(seq: Sequence, s: StreamView, ts: TimeStats) -> list[Finding]:
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
        {"rate_hz": round_or_none(rate), "calibration_rate_hz": float(cal.rate_hz)},
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
    streams = stream_views(seq)
    n_pose_usable = sum(1 for s in streams if s.kind != "imu" and len(s.t_ns) >= 2)
    spans: dict[str, tuple[int, int]] = {}
    t0s = {s.name: int(np.min(s.t_ns)) for s in streams if len(s.t_ns) >= 2}
    for s in streams:
        n = len(s.t_ns)
        if n < 2:
            fatal = s.kind == "imu" or n_pose_usable == 0
            findings.append(Finding(
                "EMPTY_STREAM", Severity.FATAL if fatal else Severity.WARNING, s.name,
                f"{s.name} has {n} rows; " + FATAL_HINTS["EMPTY_STREAM"], {"count": n}))
            continue
        findings += _stream_findings(seq, s, opts, [t for name, t in t0s.items() if name != s.name], spans)
    findings += _check_overlap(seq, spans, opts)
    if not any(f.code in _NO_RIG_CHECKS or f.severity is Severity.FATAL for f in findings):
        from pipeline.checks.rig import rig_findings  # scipy: off the CLI start-up path

        findings += rig_findings(seq)
    return _apply_ignore(findings, opts)


#: Findings (besides fatal ones) after which the rig checks are not run: they would compare streams read in
#: the wrong units.
_NO_RIG_CHECKS = ("STAMP_UNIT", "GYRO_DEGPS", "ACC_IN_G")


def _stream_findings(seq: Sequence, s: StreamView, opts: CheckOptions, other_t0_ns: list[int],
                     spans: dict[str, tuple[int, int]]) -> list[Finding]:
    """The checks of one stream with at least 2 rows; records its span (ns) in ``spans``. A stream whose
    stamps are not nanoseconds (STAMP_UNIT) gets no stamp, rate or duration findings: they would quote
    its stamps in the wrong unit."""
    valid = valid_rows(s)
    findings = check_nonfinite(s, valid)
    ts = time_stats(s.t_ns)
    unit = check_stamp_unit(s, ts, other_t0_ns)
    findings += unit
    factor = int(unit[0].details["factor_to_ns"]) if unit else 1
    spans[s.name] = (ts.t0_ns * factor, ts.t1_ns * factor)
    if not unit:
        findings += check_stamps(s, ts, opts)
        findings += check_pose_rate(s, ts, opts)
        findings += _check_imu_rate(seq, s, ts)
    findings += check_quaternions(s, valid, opts)
    if s.kind == "imu":
        assert seq.imu is not None
        duration = (ts.t1_ns - ts.t0_ns) * factor / NS_PER_S
        if duration < opts.min_duration_s:
            findings.append(Finding(
                "TOO_SHORT", Severity.FATAL, s.name,
                f"imu spans {duration:.3f} s, less than the {opts.min_duration_s:g} s minimum; "
                + FATAL_HINTS["TOO_SHORT"],
                {"duration_s": round_or_none(duration), "min_duration_s": opts.min_duration_s}))
        findings += check_imu_units(seq, valid)
        findings += check_saturation(seq.imu, valid, opts)
    return findings


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
    """FAIL if any finding is fatal, else WARN if any is repairable, else PASS (worded ``fatal``,
    ``repairable``, ``ok``: :data:`pipeline.checks.options.CHECK_VERDICT_WORDS`)."""
    sev = {f.severity for f in findings}
    if Severity.FATAL in sev:
        return Verdict.FAIL
    if Severity.REPAIRABLE in sev:
        return Verdict.WARN
    return Verdict.PASS




def _finite_stats(t_ns: np.ndarray) -> dict[str, Any]:
    if len(t_ns) == 0:
        return {"t0_ns": None, "t1_ns": None, "duration_s": 0.0, "rate_hz": None, "dt_std_ms": None,
                "dt_max_ms": None}
    ts = time_stats(t_ns)
    dt_ms = ts.dt_ns / 1e6
    return {
        "t0_ns": ts.t0_ns, "t1_ns": ts.t1_ns, "duration_s": round_or_none((ts.t1_ns - ts.t0_ns) / NS_PER_S),
        "rate_hz": round_or_none(NS_PER_S / ts.nominal_ns) if len(dt_ms) else None,
        "dt_std_ms": round_or_none(float(dt_ms.std())) if len(dt_ms) else None,
        "dt_max_ms": round_or_none(float(dt_ms.max())) if len(dt_ms) else None,
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
    for s in stream_views(seq):
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
