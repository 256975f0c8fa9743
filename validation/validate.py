"""Validation of a bias trajectory by 1-second integration error (AirIMU's metrics).

The IMU is cut into windows of ``window_s`` (default 1 s, ``overlap`` 0.5); each window is
integrated (:func:`pipeline.geometry.integration.integrate`, MIDPOINT, float64) from the reference state at
its first sample with ``imu - bias`` and gravity, and its end compared with the reference:

    pos_err = |p_end - p_ref_end| [m]     rot_err = |Log(R_ref_end^T R_end)| [deg]
    PRMSE   = sqrt(mean pos_err^2) [m]     ROE     = mean rot_err [deg]

Contracts:
    * References (:class:`ReferenceStates`): a full state (linear p, v; Slerp R), else a pose
      stream on the IMU clock and in the IMU frame, its velocity from one smoothing spline
      whose cutoff follows the discrepancy principle.
    * Every source (:class:`BiasSourceKind`) is judged on the SAME windows; a window is dropped,
      counted per reason, when it crosses an IMU gap, holds a non-finite sample, lacks a
      reference end or a bias.
    * Each row is integrated with its own gravity (stated per source in validation.json).
    * The verdict: every rule, its reason code, level and next step, in :mod:`validation.rules`
      (``validation.json`` holds the codes beside the reasons). Where the reference is the stream
      the bias was fitted to, the held-out blocks of the cross-validation judge.

The derivations and measured figures behind these choices: docs/validation.md.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.bias_table import BiasTrack
from pipeline.checks.run import reader_warnings
from pipeline.errors import ValidationError
from pipeline.types import DEFAULT_GRAVITY_MPS2, NS_PER_S, ImuSeries, Sequence
from pipeline.io.asl import CODE_CALIBRATION_DEFAULTED

from recovery.outputs import SENSOR_YAML, RecoveryOutputs, bias_sha256
from validation.attitude import reference_attitude_offset
from validation.config import CrossvalMode, ValidationConfig
from validation.metrics import (SourceMetrics, WindowPlan, flag_windows, plan_windows, prmse_m, roe_deg, window_end_errors,
                                window_errors, windows_with_any)
from validation.reference import (ReferenceKind, ReferenceStates, build_reference, gap_free_mask, reference_from_poses,
                                  reference_from_states)
from validation.sources import (BiasSource, BiasSourceKind, bias_at, infer_kind, std_at, bias_sources, dataset_bias,
                                read_bias_file, recovered_bias_at_imu)
from validation.rules import RULES, Evidence, HeldOut, VerdictInputs, judge, next_steps_for, said_once
from validation.verdict import Limitation, decide_verdict, input_limitations, recovery_limitations, sigma_window_errors
from validation.plausibility import plausibility_findings
from validation.outputs import HELDOUT_SOURCE, SCHEMA_VERSION, write_folder
from pipeline.types import Verdict

log = logging.getLogger(__name__)

#: The rule whose next step names the sensor.yaml a recovery wrote from the recording's rest.
BORROWED_NOISE_RULE = f"INPUT_{CODE_CALIBRATION_DEFAULTED}"

#: An attitude offset is noted when its tilt stands for more accelerometer bias than this many times
#: the recovered bias's median sigma (below, the two attitudes agree within what the bias can tell).
ATTITUDE_NOTE_SIGMAS = 3.0
#: ... and when the positions tie the two world frames this well (IMU positions of both, m RMS).
ATTITUDE_WORLD_RMS_M = 0.05

__all__ = [
    "BiasSource",
    "BiasSourceKind",
    "ReferenceKind",
    "ReferenceStates",
    "SourceMetrics",
    "ValidationConfig",
    "ValidationResult",
    "Verdict",
    "VerdictInputs",
    "WindowPlan",
    "build_reference",
    "bias_sources",
    "dataset_bias",
    "decide_verdict",
    "gap_free_mask",
    "plan_windows",
    "prmse_m",
    "read_bias_file",
    "sigma_window_errors",
    "recovery_limitations",
    "input_limitations",
    "Limitation",
    "next_steps",
    "recovered_bias_at_imu",
    "reference_from_poses",
    "reference_from_states",
    "roe_deg",
    "said_once",
    "validate_inputs",
    "validate_sequence",
    "window_end_errors",
    "window_errors",
    "windows_with_any",
    "write_validation",
]



# ----------------------------------------------------------------------------- main entry


@dataclass
class ValidationResult:
    """Outcome of :func:`validate_sequence`.

    Attributes:
        sequence: Sequence name.
        verdict / reasons: See :mod:`validation.rules`.
        candidate: Name of the judged source.
        config: The config used.
        sources: Metrics per source name (in evaluation order).
        windows_dropped: Counts: ``candidates``, ``kept``, ``dropped``, ``fraction`` and ``by_reason``.
        reference: Reference kind and provenance.
        gravity_mps2: Gravity used, [3].
        notes: What could not be validated, and other remarks.
        next_steps: What to do about a WARN or FAIL (:func:`next_steps`).
        reason_codes: The rule code of each reason (:data:`validation.rules.RULES`), same order.
        heldout: The cross-validation's folds and figures, when it ran.
        plausibility: Physical-plausibility findings on the recovery.
        reference_attitude: Against an independent reference, how its attitude sits on the IMU beside
            the recovery's (:class:`validation.attitude.AttitudeOffset`), when both have one.
    """

    sequence: str
    verdict: Verdict
    reasons: list[str]
    candidate: str
    config: ValidationConfig
    sources: dict[str, SourceMetrics]
    windows_dropped: dict[str, Any]
    reference: dict[str, Any]
    gravity_mps2: np.ndarray
    notes: list[str] = field(default_factory=list)
    next_steps: list[str] = field(default_factory=list)
    heldout: dict[str, Any] | None = None
    plausibility: list[dict[str, Any]] = field(default_factory=list)
    reference_attitude: dict[str, Any] | None = None
    reason_codes: list[str] = field(default_factory=list)
    recovery_bias_sha256: str | None = None

    def windows_frame(self) -> pd.DataFrame:
        """Per-window errors: t0_ns, source, pos_err_m, rot_err_deg, flagged."""
        parts = [
            pd.DataFrame({"t0_ns": m.t0_ns.astype(np.int64), "source": name, "pos_err_m": m.pos_err_m,
                          "rot_err_deg": m.rot_err_deg, "flagged": m.flagged.astype(bool)})
            for name, m in self.sources.items()
        ]
        return pd.concat(parts, ignore_index=True)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema_version": SCHEMA_VERSION,
            "sequence": self.sequence,
            **({} if self.recovery_bias_sha256 is None else {"recovery_bias_sha256": self.recovery_bias_sha256}),
            "verdict": self.verdict.value,
            "reasons": list(self.reasons),
            "reason_codes": list(self.reason_codes),
            "candidate": self.candidate,
            "config": self.config.to_dict(),
            "reference": self.reference,
            "gravity_mps2": [float(x) for x in self.gravity_mps2],
            "sources": {name: m.to_dict() for name, m in self.sources.items()},
            "windows_dropped": self.windows_dropped,
            "notes": list(self.notes),
            "next_steps": list(self.next_steps),
            **({} if self.heldout is None else {"heldout": self.heldout}),
            "plausibility": list(self.plausibility),
            **({} if self.reference_attitude is None else {"reference_attitude": self.reference_attitude}),
        }


def _normalise_sources(sources: Mapping[str, BiasTrack | BiasSource]) -> list[BiasSource]:
    out = []
    for name, s in sources.items():
        if isinstance(s, BiasSource):
            out.append(BiasSource(name, s.kind, s.track, s.gravity_mps2))
        elif isinstance(s, BiasTrack):
            out.append(BiasSource(name, infer_kind(name), s))
        else:
            raise ValidationError(f"bias source '{name}' is a {type(s).__name__}, not a BiasTrack", field=name)
        b = np.asarray(out[-1].track.bias)
        if b.ndim != 2 or b.shape[1] != 6 or len(b) != len(out[-1].track.t_ns) or len(b) == 0:
            raise ValidationError(f"bias source '{name}' must hold [N, 6] values at N stamps, got {b.shape}",
                                  field=name)
    return out


def _imu_notes(imu: ImuSeries, sequence: Sequence, plan: WindowPlan) -> list[str]:
    notes = []
    cal = float(sequence.calibration.rate_hz) if sequence.calibration is not None else float("nan")
    if math.isfinite(cal) and cal > 0 and abs(plan.rate_hz / cal - 1.0) > 0.05:
        notes.append(f"the IMU runs at {plan.rate_hz:.2f} Hz but the calibration says {cal:g} Hz; windows use "
                     f"the measured rate ({plan.n} intervals per window)")
    dt = np.diff(imu.t_ns)
    nominal = NS_PER_S / plan.rate_hz
    irregular = float(np.mean(np.abs(dt / nominal - 1.0) > 0.1))
    if irregular > 0.01:
        notes.append(f"irregular IMU stamps: {irregular:.1%} of the intervals differ from the nominal by > 10 %; "
                     "each window is integrated with its actual intervals")
    return notes


def _checked_gravity(value: Any, field: str) -> np.ndarray:
    """``value`` as a finite 3-vector [3]."""
    gravity = np.asarray(value, dtype=np.float64).reshape(-1)
    if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
        raise ValidationError(f"gravity must be a finite 3-vector, got {value!r}", field=field)
    return gravity


def validate_sequence(
    sequence: Sequence,
    sources: Mapping[str, BiasTrack | BiasSource],
    *,
    reference: ReferenceStates | None = None,
    gravity_mps2: Any = DEFAULT_GRAVITY_MPS2,
    config: ValidationConfig = ValidationConfig(),
    limitations: Sequence_[str] = (),
    heldout: BiasSource | None = None,
    judge_heldout: bool = False,
    heldout_info: Mapping[str, Any] | None = None,
    fails: Sequence_[str] = (),
    inputs: VerdictInputs = VerdictInputs(),
) -> ValidationResult:
    """Validate bias trajectories by 1-s integration error against a reference (AirIMU metrics).

    Args:
        sequence: The sequence (its IMU is integrated; its ground-truth bias becomes the DATASET
            source when ``config.include_dataset``).
        sources: Bias sources by name: :class:`BiasSource`, or a plain :class:`BiasTrack` whose kind
            follows the name (``"recovered"`` -> RECOVERED, ``"dataset"`` -> DATASET, else FILE).
            Tracks at any stamps (keyframes or IMU rate) on the IMU clock; never extrapolated.
        reference: Reference states; default the ground-truth state (STATE). Built for other
            stamps it is re-interpolated to the IMU stamps.
        gravity_mps2: The reference's own gravity in its world frame, [3]: every source is integrated
            with it, but a :class:`BiasSource` that names its own (the gravity it was estimated
            against, in the same frame), so that no source's gravity changes another's errors.
        config: Windows, flags and verdict thresholds.
        limitations: What limits the candidate though its numbers pass (rule GIVEN_LIMITATION).
        heldout: The candidate cross-validated by time blocks (:mod:`validation.crossval.blocks`; NaN where a
            fold was dropped): measured on the kept windows it covers, beside every other source on
            the same windows (``result.heldout``).
        judge_heldout: The held-out errors judge the verdict (the reference is the stream the bias
            was fitted to): worse than the zero or the constant bias on those windows is a FAIL.
        heldout_info: What the cross-validation did (blocks, folds, dropped folds), for the output.
        fails: Reasons for a FAIL found before the integration, listed first (rule GIVEN_FAIL).
        inputs: What the verdict knows beyond the integration errors (the input's findings, the
            recovery, the plausibility findings, whether the test is independent).

    Returns:
        The result, with per-source metrics, the verdict and its reasons.

    Raises:
        ValidationError: No IMU; no reference; a sequence shorter than one window; no bias source
            to judge; no window left after dropping.
    """
    imu = sequence.imu
    if imu is None or len(imu) == 0:
        raise ValidationError(f"sequence '{sequence.name}' has no IMU to integrate",
                              hint="give an input with IMU readings")
    gravity = _checked_gravity(gravity_mps2, "gravity_mps2")
    notes: list[str] = []
    plan = plan_windows(imu, config)
    notes += _imu_notes(imu, sequence, plan)

    reference = _reference_at_imu(sequence, reference, imu, config)
    given, candidate = _given_sources(sequence, sources, config, notes)
    keep, at_imu, dropped = _kept_windows(sequence, imu, plan, reference, given)
    starts = plan.starts[keep]
    evaluated = _evaluated_sources(imu, plan, starts, given, at_imu, candidate, config, notes)
    metrics = _source_metrics(imu, plan, starts, evaluated, at_imu, reference, gravity, config)
    heldout_part, judged = None, None
    if heldout is not None:
        heldout_part, judged = _heldout_metrics(imu, heldout, reference, plan, starts, gravity, metrics, config,
                                                judge_heldout, dict(heldout_info or {}))
    recording_s = float(imu.t_ns[-1] - imu.t_ns[0]) * 1e-9
    verdict, reasons = judge(Evidence(metrics, candidate, config, dropped["fraction"], judged, inputs, tuple(fails),
                                      tuple(limitations), recording_s))
    ref_info = {"kind": reference.kind.value, **reference.info}
    return ValidationResult(sequence.name, verdict, [r.text for r in reasons], candidate, config, metrics, dropped,
                            ref_info, gravity, notes, heldout=heldout_part, reason_codes=[r.code for r in reasons])


def _reference_at_imu(sequence: Sequence, reference: ReferenceStates | None, imu: ImuSeries,
                      config: ValidationConfig) -> ReferenceStates:
    """The reference at the IMU stamps: the ground-truth state by default, else ``reference``
    (re-interpolated when built for other stamps)."""
    if reference is None:
        if sequence.ground_truth is None:
            raise ValidationError(
                f"sequence '{sequence.name}' has no ground-truth state and no reference was given",
                hint="build a POSES reference (build_reference / --poses STREAM) from a 6-DoF pose stream",
            )
        reference = reference_from_states(sequence.ground_truth, imu.t_ns, gap_factor=config.reference_gap_factor)
    elif not (len(reference.t_ns) == len(imu.t_ns) and np.array_equal(reference.t_ns, imu.t_ns)):
        kind = reference.kind
        reference = reference_from_states(reference, imu.t_ns, gap_factor=config.reference_gap_factor)
        reference = ReferenceStates(reference.t_ns, reference.R, reference.v, reference.p, reference.valid, kind,
                                    reference.info)
    return reference


def _given_sources(sequence: Sequence, sources: Mapping[str, BiasTrack | BiasSource], config: ValidationConfig,
                   notes: list[str]) -> tuple[list[BiasSource], str]:
    """The given sources (with the DATASET one when ``config.include_dataset``) and the candidate's
    name: the first of recovered, file, dataset. A missing DATASET source is said in ``notes``."""
    given = _normalise_sources(sources)
    if config.include_dataset and not any(s.kind is BiasSourceKind.DATASET for s in given):
        ds = dataset_bias(sequence)
        if ds is not None:
            given.append(BiasSource("dataset", BiasSourceKind.DATASET, ds))
        else:
            notes.append("no DATASET source: the sequence has no ground-truth bias")
    if not given:
        raise ValidationError(f"no bias to validate for sequence '{sequence.name}'",
                              hint="give a bias file (--bias FILE) or a recovery folder (--recovery DIR)")
    order = {BiasSourceKind.RECOVERED: 0, BiasSourceKind.FILE: 1, BiasSourceKind.DATASET: 2}
    judged = sorted((s for s in given if s.kind in order), key=lambda s: order[s.kind])
    if not judged:
        raise ValidationError("no bias source to judge (only zero / constant given)",
                              hint="give a recovered, dataset or file bias")
    return given, judged[0].name


def _kept_windows(sequence: Sequence, imu: ImuSeries, plan: WindowPlan, reference: ReferenceStates,
                  given: list[BiasSource]) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """``(keep, at_imu, dropped)``: the planned windows the reference and every source cover, each
    source's bias at the IMU stamps, and what was dropped, by reason."""
    s, e = plan.starts, plan.starts + plan.n
    keep = plan.keep.copy()
    by_reason = dict(plan.dropped)
    no_ref = ~(reference.valid[s] & reference.valid[e])
    by_reason["no_reference"] = int(no_ref.sum())
    keep &= ~no_ref
    at_imu: dict[str, np.ndarray] = {}
    for src in given:
        bias, covered = bias_at(src.track, imu.t_ns)
        covered = covered & np.isfinite(bias).all(axis=1)
        uncovered = windows_with_any(~covered, s, plan.n + 1)
        by_reason[f"bias_not_covered:{src.name}"] = int(uncovered.sum())
        if uncovered.any():
            log.info("bias source '%s' does not cover %d of %d windows", src.name, int(uncovered.sum()), len(s))
        keep &= ~uncovered
        at_imu[src.name] = bias
    n_cand = len(s)
    n_keep = int(keep.sum())
    dropped = {"candidates": n_cand, "kept": n_keep, "dropped": n_cand - n_keep,
               "fraction": float((n_cand - n_keep) / n_cand), "by_reason": by_reason}
    if n_keep == 0:
        worst = max(by_reason, key=lambda k: by_reason[k])
        raise ValidationError(
            f"no window of sequence '{sequence.name}' can be validated: all {n_cand} dropped "
            f"(mostly {worst}: {by_reason[worst]})",
            hint="make the bias and the reference cover the IMU span, or fix the IMU gaps",
        )
    if n_cand - n_keep:
        log.info("validating %d of %d windows (%s)", n_keep, n_cand,
                 ", ".join(f"{k} {v}" for k, v in by_reason.items() if v))
    return keep, at_imu, dropped


def _evaluated_sources(imu: ImuSeries, plan: WindowPlan, starts: np.ndarray, given: list[BiasSource],
                       at_imu: dict[str, np.ndarray], candidate: str, config: ValidationConfig,
                       notes: list[str]) -> list[BiasSource]:
    """The rows to integrate: the zero and the constant bias (as configured; added to ``at_imu``),
    then the given sources. Two sources with one name are an error."""
    evaluated: list[BiasSource] = []
    if config.include_zero:
        zero = np.zeros((len(imu), 6))
        at_imu["zero"] = zero
        evaluated.append(BiasSource("zero", BiasSourceKind.ZERO, BiasTrack(imu.t_ns, zero, zero)))
    if config.include_constant:
        i0 = int(starts[0])
        const = at_imu[candidate][i0:i0 + plan.n + 1].mean(axis=0)
        at_imu["constant"] = np.broadcast_to(const, (len(imu), 6))
        evaluated.append(BiasSource("constant", BiasSourceKind.CONSTANT_FIRST_WINDOW,
                                    BiasTrack(imu.t_ns[:1], const[None], np.zeros((1, 6)))))
        notes.append(f"'constant' is the mean of '{candidate}' over the first kept window "
                     f"(t0_ns {int(imu.t_ns[i0])}), held constant")
    names = [x.name for x in evaluated]
    for src in given:
        if src.name in names:
            raise ValidationError(f"two bias sources are named '{src.name}'", field=src.name,
                                  hint="give each --bias a distinct NAME (zero and constant are reserved)")
        evaluated.append(src)
        names.append(src.name)
    return evaluated


def _source_metrics(imu: ImuSeries, plan: WindowPlan, starts: np.ndarray, evaluated: list[BiasSource],
                    at_imu: dict[str, np.ndarray], reference: ReferenceStates, gravity: np.ndarray,
                    config: ValidationConfig) -> dict[str, SourceMetrics]:
    """Each row's window errors, PRMSE / ROE and flags over the kept windows (``starts``), integrated
    with the row's own gravity where it names one, else ``gravity``."""
    metrics: dict[str, SourceMetrics] = {}
    t0 = imu.t_ns[starts]
    window_s = plan.n / plan.rate_hz
    for src in evaluated:
        g_src = gravity if src.gravity_mps2 is None else _checked_gravity(src.gravity_mps2, f"{src.name}.gravity_mps2")
        pos, rot = window_errors(imu, at_imu[src.name], reference, starts, plan.n, g_src, config)
        flagged, thr_p, thr_r = flag_windows(pos, rot, config)
        std = std_at(src.track, t0)
        sigma_pos, sigma_rot = sigma_window_errors(std, reference.R[starts], window_s, g_src)
        metrics[src.name] = SourceMetrics(
            src.name, src.kind, t0, pos, rot, prmse_m(pos), roe_deg(rot),
            flagged, thr_p, thr_r, sigma_pos, sigma_rot, at_imu[src.name][starts].mean(axis=0), g_src,
            std.mean(axis=0),
        )
        log.info("%-12s PRMSE %.4f m  ROE %.4f deg  (%d windows, %d flagged)", src.name,
                 metrics[src.name].prmse_m, metrics[src.name].roe_deg, len(pos), int(flagged.sum()))
    return metrics


def _heldout_metrics(imu: ImuSeries, heldout: BiasSource, reference: ReferenceStates, plan: WindowPlan,
                     starts: np.ndarray, gravity: np.ndarray, metrics: dict[str, SourceMetrics],
                     config: ValidationConfig, judge: bool, info: dict[str, Any]
                     ) -> tuple[dict[str, Any], HeldOut | None]:
    """The held-out source's metrics on the kept windows it covers (added to ``metrics``), every other
    source's on the same windows, and, when it judges the verdict, those windows' errors for the held-out
    rules (:mod:`validation.rules`)."""
    bias, covered = bias_at(heldout.track, imu.t_ns)
    covered &= np.isfinite(bias).all(axis=1)
    ok = ~windows_with_any(~covered, starts, plan.n + 1)
    part: dict[str, Any] = {**info, "source": heldout.name, "judged": bool(judge), "windows": int(ok.sum())}
    if not ok.any():
        part["note"] = "no kept window lies in a held-out block with a recovered bias"
        return part, None
    g = gravity if heldout.gravity_mps2 is None else np.asarray(heldout.gravity_mps2, dtype=np.float64)
    pos, rot = window_errors(imu, bias, reference, starts[ok], plan.n, g, config)
    flagged, thr_p, thr_r = flag_windows(pos, rot, config)
    t0 = imu.t_ns[starts[ok]]
    metrics[heldout.name] = SourceMetrics(heldout.name, heldout.kind, t0, pos, rot, prmse_m(pos), roe_deg(rot), flagged,
                                          thr_p, thr_r, mean_bias=bias[starts[ok]].mean(axis=0), gravity_mps2=g,
                                          mean_std=std_at(heldout.track, t0).mean(axis=0))
    same = {name: m for name, m in metrics.items() if name != heldout.name and len(m.pos_err_m) == len(ok)}
    part["others_on_these_windows"] = {name: {"prmse_m": prmse_m(m.pos_err_m[ok]), "roe_deg": roe_deg(m.rot_err_deg[ok])}
                                       for name, m in same.items()}
    if not judge:
        return part, None
    return part, HeldOut(metrics[heldout.name], {name: (m.kind, m.pos_err_m[ok], m.rot_err_deg[ok])
                                                 for name, m in same.items()})


# ----------------------------------------------------------------------------- output


def write_validation(result: ValidationResult, out_dir: str | Path) -> Path:
    """Write ``out_dir/validation.json`` and ``out_dir/windows.parquet`` atomically
    (:func:`validation.outputs.write_folder`); returns ``out_dir``."""
    return write_folder(result.to_dict(), result.windows_frame(), out_dir)


def validate_inputs(
    sequence: Sequence,
    *,
    recovery_dir: str | Path | None = None,
    bias_files: Sequence_[tuple[str | None, str | Path]] = (),
    pose_stream: str | None = None,
    gravity_mps2: Any = None,
    config: ValidationConfig = ValidationConfig(),
) -> ValidationResult:
    """Validate a sequence from what ``biasgt validate`` and the workflow's rule are given.

    Assembles the sources (:func:`bias_sources`) and the reference (:func:`build_reference`), then
    runs :func:`validate_sequence`. A FAIL verdict is a result, not an error.

    Gravity: ``gravity_mps2`` for every row when given. Else each row is integrated with the
    reference's own gravity, nominal ``(0, 0, -|g|)`` (a ground-truth state, a mocap or survey frame
    are level), except the recovered bias (and its held-out version) against the very stream it was
    fitted to, which takes the recovery's gravity (its world frame is that stream's): no candidate's
    gravity changes another row.

    Cross-validation (``config.crossval``): against the stream the bias was fitted to, the held-out
    blocks are the independent test and judge the verdict; against an independent reference they are
    a row compared with the others.

    Args:
        sequence: The sequence (canonical store or any input, already loaded).
        recovery_dir: A recovery output folder (``bias.csv`` + ``recovery.json``), or None.
        bias_files: ``(name or None, path)`` bias files (see :func:`bias_sources`).
        pose_stream: Reference pose stream (None: ground truth, else the recovery's stream).
        gravity_mps2: Gravity in the reference world frame, [3], or None.
        config: Validation options.

    Raises:
        ValidationError / InputFormatError / DataError: Bad or insufficient inputs.
    """
    recovery = RecoveryOutputs.read(recovery_dir) if recovery_dir is not None else None
    sources = bias_sources(sequence, recovery=recovery, bias_files=bias_files)
    reference = build_reference(sequence, pose_stream=pose_stream, recovery=recovery, config=config)
    fitted = recovery is not None and reference.kind is ReferenceKind.POSES and (
        recovery.report.pose_stream is None or reference.info.get("stream") == recovery.report.pose_stream)
    gravity, own_gravity, sources = _row_gravity(gravity_mps2, recovery, fitted, sources)
    heldout, heldout_info = None, None
    if config.crossval_block_s is not None and (config.crossval is CrossvalMode.ON or
                                                (config.crossval is CrossvalMode.AUTO and fitted)):
        heldout, heldout_info = _heldout_source(sequence, recovery, config, required=config.crossval is CrossvalMode.ON)
        if heldout is not None and own_gravity is not None:
            heldout = replace(heldout, gravity_mps2=own_gravity)
    judged = fitted and heldout is not None and len(heldout_info["dropped_folds"]) < config.crossval_folds
    implausible = plausibility_findings(sequence, recovery) if recovery is not None else []
    inputs = VerdictInputs(tuple(sequence.findings), recovery.report if recovery is not None else None,
                           tuple(implausible), fitted and not judged, heldout is not None)
    result = validate_sequence(sequence, sources, reference=reference, gravity_mps2=gravity, config=config,
                               heldout=heldout, judge_heldout=judged, heldout_info=heldout_info, inputs=inputs)
    result.plausibility = [x.to_dict() for x in implausible]
    result.next_steps = name_suggested_noise(next_steps(result), result.reason_codes, recovery_dir)
    if own_gravity is not None:
        result.notes.append(f"'recovered' is integrated with the recovery's gravity {np.round(own_gravity, 4).tolist()} "
                            f"m/s^2 (the reference is the stream it was fitted to); the other rows with "
                            f"{np.round(gravity, 4).tolist()}")
    if judged:
        result.notes.append("the reference is the stream the bias was fitted to: the held-out blocks judge the verdict")
    if recovery is not None and not fitted:
        _compare_attitude(result, reference, recovery, gravity)
    if recovery is not None:
        result.notes.append(f"recovery: {recovery_dir}")
        result.recovery_bias_sha256 = bias_sha256(recovery_dir)  # what windows checks it cuts
    result.notes += reader_warnings(sequence.findings)  # skipped input lines
    return result


def _compare_attitude(result: ValidationResult, reference: ReferenceStates, recovery: RecoveryOutputs,
                      gravity: np.ndarray) -> None:
    """Record how the independent reference's attitude sits on the IMU beside the recovery's, with a
    note when its tilt stands for more than :data:`ATTITUDE_NOTE_SIGMAS` times the recovered
    accelerometer bias's median sigma and the world frames agree by the positions."""
    offset = reference_attitude_offset(reference, recovery.trajectory, gravity)
    if offset is None:
        return
    result.reference_attitude = offset.to_dict()
    std = np.asarray(recovery.bias.std, dtype=float)[:, 3:]
    sigma = float(np.nanmedian(std)) if np.isfinite(std).any() else 0.0
    if offset.world_rms_m <= ATTITUDE_WORLD_RMS_M and offset.acc_bias_equivalent_mps2 > ATTITUDE_NOTE_SIGMAS * sigma:
        result.notes.append(offset.note())


def _row_gravity(gravity_mps2: Any, recovery: RecoveryOutputs | None, fitted: bool, sources: dict[str, BiasSource]
                 ) -> tuple[np.ndarray, np.ndarray | None, dict[str, BiasSource]]:
    """``(gravity, own_gravity, sources)``: the gravity every row is integrated with (``gravity_mps2``,
    else the nominal one), and, against the stream the recovery was fitted to, the recovery's own
    gravity, set on its rows (``None`` otherwise)."""
    own_gravity = None  # the recovery's gravity for its own rows, in the fitted stream's frame
    if gravity_mps2 is not None:
        gravity = np.asarray(gravity_mps2, dtype=float)
    else:
        gravity = nominal_gravity(recovery)
        if fitted and recovery.report.gravity_world_mps2 is not None:
            own_gravity = np.asarray(recovery.report.gravity_world_mps2, dtype=float)
            sources = {k: (replace(s, gravity_mps2=own_gravity) if s.kind is BiasSourceKind.RECOVERED else s)
                       for k, s in sources.items()}
    return gravity, own_gravity, sources


def name_suggested_noise(steps: list[str], reason_codes: Sequence_[str], recovery_dir: str | Path | None) -> list[str]:
    """``steps`` with the borrowed-noise rule's next step naming the ``sensor.yaml`` the recovery wrote
    (:func:`recovery.outputs.suggested_sensor_yaml`), where it wrote one."""
    suggested = None if recovery_dir is None else Path(recovery_dir) / SENSOR_YAML
    generic = RULES[BORROWED_NOISE_RULE].next_step
    if suggested is None or not suggested.is_file() or BORROWED_NOISE_RULE not in reason_codes:
        return steps
    step = (f"use {suggested}, which the recovery wrote with the noise this recording showed (the densities read "
            "off its rest or, without one, chosen by the evidence search, and the random walks the search chose; each "
            "value's comment says which): put it where the reader looks (imu0/sensor.yaml of an ASL folder) and "
            "recover again")
    return [step if s == generic else s for s in steps]


def nominal_gravity(recovery: RecoveryOutputs | None = None) -> np.ndarray:
    """``(0, 0, -|g|)``, [3]: gravity in a level world frame (``|g|`` of the recovery's options, else 9.81)."""
    magnitude = (recovery.report.get("config") or {}).get("gravity_mps2") if recovery is not None else None
    return np.array([0.0, 0.0, -float(magnitude if magnitude is not None else -DEFAULT_GRAVITY_MPS2[2])])


def _heldout_source(sequence: Sequence, recovery: RecoveryOutputs | None, config: ValidationConfig,
                    required: bool) -> tuple[BiasSource | None, dict[str, Any] | None]:
    """The recovery cross-validated by blocks (``crossval_block_s``) as the source ``recovered_heldout``,
    and what the cross-validation did (``dropped_folds``: the folds whose recovery failed, with why).

    Raises:
        ValidationError: ``required`` and there is no recovery of a pose stream of this sequence.
    """
    from validation.crossval.blocks import BlockFolds, heldout_track

    stream = recovery.report.pose_stream if recovery is not None else None
    if recovery is None or stream not in sequence.poses:
        if not required:
            return None, None
        raise ValidationError("cross-validation needs the recovery and the pose stream it fitted" + (
            f" ('{stream}' is not among the sequence's pose streams)" if recovery is not None else ""),
            field="crossval",
            hint="give the recovery folder of a pose-stream recovery, or --crossval off")
    folds = BlockFolds(int(sequence.imu.t_ns[0]), float(config.crossval_block_s), int(config.crossval_folds))
    log.info("cross-validating the recovery from '%s' by %d folds of %g-s blocks", stream, folds.n_folds,
             folds.block_s)
    track, dropped = heldout_track(sequence, stream, dict(recovery.report.get("config") or {}), folds)
    for k, why in dropped.items():
        log.warning("cross-validation fold %d of %d dropped: %s", k + 1, folds.n_folds, why)
    info = {"block_s": folds.block_s, "folds": folds.n_folds,
            "dropped_folds": [{"fold": int(k), "reason": why} for k, why in sorted(dropped.items())]}
    return BiasSource(HELDOUT_SOURCE, BiasSourceKind.FILE, track), info


def next_steps(result: ValidationResult) -> list[str]:
    """What to do about a WARN or FAIL: the next steps of the rules that fired (empty for a PASS)."""
    return next_steps_for(result.reason_codes)
