"""Ingest: load an input, check it, apply the allowed repairs, and write the canonical store.

This is the library behind ``biasgt inspect`` / ``biasgt convert`` and the
Snakemake ``ingest`` rule. The reader/check command-line options those commands share
are in :mod:`biasgt.cli.commands._args`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.checks.options import FATAL_HINTS, REPAIR_FOR_CODE, CheckOptions, Repair
from pipeline.checks.repairs import apply_repairs, parse_repairs
from pipeline.checks.run import fatal_findings, reader_warnings, repairable_findings, run_checks, verdict
from pipeline.errors import FatalCheckError
from pipeline.io import load_sequence
from pipeline.store import write_store
from pipeline.types import NS_PER_S, Finding, Sequence, Severity, Verdict

log = logging.getLogger(__name__)

#: Keyword arguments of :func:`pipeline.io.load_sequence` that
#: :func:`biasgt.cli.commands._args.reader_kwargs_from_args` fills.
READER_KWARGS = ("fmt", "name", "csv_mapping", "imu_topic", "pose_topic", "tf_parent", "tf_child", "extra_poses")


def load(input_path: str | Path, reader_kwargs: Mapping[str, Any] | None = None) -> Sequence:
    """Load any supported input through :func:`pipeline.io.load_sequence`.

    Skipped unparseable lines are logged as a warning (:func:`pipeline.checks.run.reader_warnings`),
    for every command that reads an input (a store repeats its reader's findings).

    Args:
        input_path: File or folder.
        reader_kwargs: Keyword arguments for the reader (``None`` values are dropped).
    """
    kwargs = {k: v for k, v in (reader_kwargs or {}).items() if v is not None}
    seq = load_sequence(Path(input_path), **kwargs)
    for text in reader_warnings(seq.findings):
        log.warning("%s", text)
    return seq


@dataclass
class CheckedSequence:
    """A sequence after checks (and possibly repairs).

    Attributes:
        sequence: The (repaired) sequence, ``findings`` set to the final check results.
        findings_before: Findings of the unrepaired input.
        findings: Findings after the repairs.
        changes: What the repairs changed.
    """

    sequence: Sequence
    findings_before: list[Finding]
    findings: list[Finding]
    changes: list[str]

    @property
    def verdict(self) -> Verdict:
        return verdict(self.findings)


def refusal_message(findings: Iterable[Finding], action: str = "convert") -> tuple[str, str] | None:
    """``(problem, hint)`` when ``findings`` forbid using the sequence, else ``None``.

    Fatal findings and remaining repairable ones forbid it; the hint names the
    ``--repair`` flags that would fix the repairable ones.

    Args:
        findings: Check results.
        action: What is refused (``"convert"``, ``"recover"``, ...), for the message.
    """
    findings = list(findings)
    blocking = fatal_findings(findings) + repairable_findings(findings)
    if not blocking:
        return None
    if len(blocking) == 1:  # one problem: its own sentence names what and where
        problem = f"refusing to {action}: {blocking[0].code} ({blocking[0].stream}): {blocking[0].message}"
    else:
        listed = "; ".join(f"{f.code} ({f.stream})" for f in blocking)
        problem = f"refusing to {action}: {len(blocking)} problem(s) remain: {listed}"
    hints: list[str] = []
    flags = sorted({REPAIR_FOR_CODE[f.code].value for f in repairable_findings(findings) if f.code in REPAIR_FOR_CODE})
    if flags:
        hints.append(f"rerun with --repair {','.join(flags)}")
    for code in dict.fromkeys(f.code for f in fatal_findings(findings)):
        hints.append(f"{code}: {FATAL_HINTS.get(code, 'see biasgt inspect')}")
    hints.append("'biasgt inspect INPUT' explains each problem")
    return problem, "; ".join(hints)


def check_and_repair(
    seq: Sequence, repairs: Iterable[Repair | str] = (), check_options: CheckOptions | None = None
) -> CheckedSequence:
    """Check ``seq``, apply the allowed repairs, and check again.

    Returns:
        The result; its ``sequence.findings`` are the final findings and its
        metadata records ``repairs`` (and ``findings_before_repair`` when something changed).
    """
    opts = check_options or CheckOptions()
    before = run_checks(seq, opts)
    allowed = parse_repairs(repairs)
    if allowed:
        repaired, changes = apply_repairs(seq, allowed, opts)
    else:
        repaired, changes = seq, []
    after = run_checks(repaired, opts) if changes else before
    metadata = dict(repaired.metadata)
    metadata.setdefault("repairs", [])
    if changes:
        metadata["findings_before_repair"] = [f.to_dict() for f in before]
    final = replace(repaired, findings=list(after), metadata=metadata)
    return CheckedSequence(final, before, after, changes)


def load_checked(
    input_path: str | Path,
    reader_kwargs: Mapping[str, Any] | None = None,
    *,
    repairs: Iterable[Repair | str] = (),
    check_options: CheckOptions | None = None,
    action: str,
) -> Sequence:
    """Load an input for a stage that uses it directly (recover, validate, interpolate), checked as ``convert`` would.

    Every input, a canonical store included, runs the same checks and repairs as ``biasgt convert``,
    so wrong units, NaN rows or unsorted stamps never reach a result silently.

    Raises:
        FatalCheckError: A fatal or an unrepaired repairable problem; the hint names the
            ``--repair`` flags (or ``--ignore`` for a false positive).
    """
    seq = load(input_path, reader_kwargs)
    checked = check_and_repair(seq, repairs, check_options)
    refusal = refusal_message(checked.findings, action)
    if refusal is not None:
        hint = refusal[1] + "; '--ignore CODE' if a unit finding is a false positive"
        raise FatalCheckError(refusal[0], path=input_path, hint=hint)
    return checked.sequence


def ingest(
    input_path: str | Path,
    out_dir: str | Path,
    *,
    repairs: Iterable[Repair | str] = (),
    reader_kwargs: Mapping[str, Any] | None = None,
    check_options: CheckOptions | None = None,
    resample_hz: float | None = None,
) -> Sequence:
    """Load, check, repair (only what ``repairs`` allows), re-check and write the canonical store.

    Args:
        input_path: Any input :func:`pipeline.io.load_sequence` reads.
        out_dir: Store folder to write (atomically; replaced only on success).
        repairs: Allowed repairs (:class:`Repair` members or flag names, ``"all"``).
        reader_kwargs: Keyword arguments for :func:`pipeline.io.load_sequence`.
        check_options: Check thresholds.
        resample_hz: Resample the IMU to this rate (anti-alias filtered,
            :func:`pipeline.resample.resample_imu_filtered`) after the checks; the calibration's
            ``rate_hz`` becomes it and ``metadata["resampled_from_hz"]`` keeps the recorded rate.

    Returns:
        The sequence as written (findings and repairs recorded in it).

    Raises:
        FatalCheckError: When a fatal or an unrepaired repairable problem remains;
            nothing is written then.
    """
    seq = load(input_path, reader_kwargs)
    checked = check_and_repair(seq, repairs, check_options)
    refusal = refusal_message(checked.findings)
    if refusal is not None:
        raise FatalCheckError(refusal[0], path=input_path, hint=refusal[1])
    out = checked.sequence
    if resample_hz is not None and out.imu is not None:
        from pipeline.resample import resample_imu_filtered

        recorded = NS_PER_S / float(np.median(np.diff(out.imu.t_ns)))
        out = replace(out, imu=resample_imu_filtered(out.imu, resample_hz),
                      calibration=replace(out.calibration, rate_hz=float(resample_hz)),
                      metadata={**out.metadata, "resampled_from_hz": round(recorded, 6)})
        log.info("resampled the IMU from %.4g Hz to %g Hz (anti-alias filtered)", recorded, resample_hz)
    out.metadata.setdefault("source_path", str(input_path))
    write_store(out, out_dir)
    log.info("wrote %s (%s)", out_dir, "; ".join(checked.changes) or "no repairs")
    return out


def severity_rank(sev: Severity) -> int:
    """Sort key: fatal first."""
    return {Severity.FATAL: 0, Severity.REPAIRABLE: 1, Severity.WARNING: 2, Severity.INFO: 3}[sev]
