"""The per-sequence dataset quality report: one self-contained HTML file.

Inputs (the workflow's layout ``results/<stage>/<sequence>/``; every stage but ingest may be
missing, and the page then says so plainly and shows the rest):

* ingest: the canonical store (:func:`pipeline.store.read_store`), its stream summaries and
  input checks (:mod:`pipeline.checks`) and the repairs applied at conversion;
* recovery: ``bias.csv`` (:func:`pipeline.bias_table.read_bias_csv`), ``recovery.json``
  (clock offset, extrinsic, gravity, noise used, residual statistics, warnings),
  ``trajectory_tum.txt`` (:mod:`recovery.outputs`) and, when the recovery
  writes one, a per-keyframe residual table (``residuals.parquet`` or ``residuals.csv``);
* validation: ``validation.json`` and ``windows.parquet`` (:mod:`validation.validate`).

Sections, in order: verdict; streams and input checks; calibration estimated; recovered bias
over time; pose and IMU residuals; integration-error distributions; Allan deviation.

The page has no external resources: figures are PNG ``data:`` URIs, the stylesheet and a tiny
script (it counts images that failed to decode, for the headless-browser test) are inline.
It is written atomically (:func:`pipeline.atomic.atomic_path`): a failure leaves no file.
"""

from __future__ import annotations

import datetime as _dt
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pipeline import __version__
from pipeline.atomic import atomic_path
from pipeline.bias_table import BiasTrack, read_bias_csv
from pipeline.checks import CHECK_CODES, run_checks, stream_summaries
from pipeline.errors import BiasgtError, ConfigError, InputFormatError
from pipeline.layout import Stage
from pipeline.store import is_store, read_store
from pipeline.types import DEFAULT_GRAVITY_MPS2, NS_PER_S, Finding, PoseSeries, Sequence, Severity
from recovery.gyro_consistency import rate_coupling
from recovery.outputs import (
    BIAS_CSV,
    REPORT_JSON,
    RESIDUALS_CSV,
    TRAJECTORY_TUM,
    RecoveryReport,
    read_report,
    read_residuals,
    read_trajectory,
)
from reports import plots
from validation.plausibility import gravity_tilt_deg, pose_residuals
from validation.outputs import (
    HELDOUT_SOURCE,
    VALIDATION_JSON,
    WINDOWS_PARQUET,
    ValidationSummary,
    read_summary,
    read_windows,
)
from reports.allan import ImuAllan, imu_allan
from reports.html import Html, esc, figure_img, fmt, join, p, page, section, table, tag, ul

log = logging.getLogger(__name__)

#: Stage folder names under a results folder (the workflow's, else the rule's); the first that exists is used.
STAGE_FOLDERS = {
    "ingest": (Stage.INGEST.folder,),
    "recovery": (Stage.RECOVER.folder, Stage.RECOVER.value),
    "validation": (Stage.VALIDATE.folder, Stage.VALIDATE.value),
}
#: Rows of the flagged-window table shown (the rest are counted).
MAX_FLAGGED_ROWS = 40

#: Section anchors and headings, in page order (the tests check all of them).
SECTIONS = (
    ("verdict", "1. Verdict"),
    ("streams", "2. Streams and input checks"),
    ("calibration", "3. Calibration estimated"),
    ("bias", "4. Recovered bias over time"),
    ("residuals", "5. Pose and IMU residuals"),
    ("integration", "6. Integration error per bias source"),
    ("allan", "7. Allan deviation of the IMU"),
)
_TITLE = dict(SECTIONS)


# ----------------------------------------------------------------------------- inputs


@dataclass
class ReportInputs:
    """Everything the report shows, read from the stage folders.

    Attributes:
        ingest_dir / recovery_dir / validation_dir: Where the inputs came from (None: not given).
        sequence: The canonical store's sequence.
        recovery: ``recovery.json`` content, or None.
        bias: The recovered bias (``pipeline.bias_table.BiasTrack``), or None.
        trajectory: The recovered IMU trajectory, or None.
        residuals: Per-keyframe residual table (``t_ns`` + numeric columns), or None.
        validation: ``validation.json`` content, or None.
        windows: ``windows.parquet`` (t0_ns, source, pos_err_m, rot_err_deg[, flagged]), or None.
        missing: Plain sentences: what is missing (shown in the page).
        problems: Plain sentences: inputs that exist but could not be read.
    """

    ingest_dir: Path
    sequence: Sequence
    recovery_dir: Path | None = None
    validation_dir: Path | None = None
    recovery: RecoveryReport | None = None
    bias: BiasTrack | None = None
    trajectory: PoseSeries | None = None
    residuals: pd.DataFrame | None = None
    validation: ValidationSummary | None = None
    windows: pd.DataFrame | None = None
    missing: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def t0_ns(self) -> int:
        """Time origin of every plot: the first IMU stamp (else the first pose stamp, else 0)."""
        seq = self.sequence
        if seq.imu is not None and len(seq.imu):
            return int(seq.imu.t_ns[0])
        for poses in seq.poses.values():
            if len(poses):
                return int(poses.t_ns[0])
        if self.bias is not None and len(self.bias.t_ns):
            return int(self.bias.t_ns[0])
        return 0


def stage_dirs(results_dir: str | Path, sequence: str) -> dict[str, Path | None]:
    """The stage folders of ``sequence`` under a results folder (None where absent).

    ``results_dir`` is the ``results/`` folder itself or a folder holding ``results/``.
    The recovery may live in ``recovery/`` or ``recover/``, the validation in
    ``validation/`` or ``validate/``. The ingest entry is always a path (it may not exist;
    :func:`gather_inputs` then raises a one-line error).
    """
    root = Path(results_dir)
    if not any((root / names[0]).is_dir() for names in STAGE_FOLDERS.values()) and (root / "results").is_dir():
        root = root / "results"
    out: dict[str, Path | None] = {}
    for stage, names in STAGE_FOLDERS.items():
        found = next((root / n / sequence for n in names if (root / n / sequence).is_dir()), None)
        out[stage] = found if found is not None or stage != "ingest" else root / names[0] / sequence
    return out


def gather_inputs(
    ingest_dir: str | Path,
    *,
    recovery_dir: str | Path | None = None,
    validation_dir: str | Path | None = None,
    sequence: Sequence | None = None,
) -> ReportInputs:
    """Read every available input; note what is missing or unreadable instead of failing.

    ``sequence``: the sequence already loaded from ``ingest_dir`` (any input the readers take, e.g.
    a raw ASL folder with added poses); else ``ingest_dir`` must be a canonical store.

    Raises:
        InputFormatError: ``ingest_dir`` is not a canonical store and no sequence was given.
    """
    ingest_dir = Path(ingest_dir)
    if sequence is None and not is_store(ingest_dir):
        raise InputFormatError(
            "no ingest store here (sequence.yaml missing)", path=ingest_dir,
            hint="run the ingest stage ('biasgt convert INPUT --out DIR' or 'biasgt run') first, "
                 "or give the right --ingest folder")
    inputs = ReportInputs(ingest_dir=ingest_dir, sequence=read_store(ingest_dir) if sequence is None else sequence)

    # --- recovery
    if recovery_dir is None:
        inputs.missing.append("Recovery: no recovery folder was given or found, so there is no recovered bias, "
                              "calibration or residuals.")
    else:
        rdir = inputs.recovery_dir = Path(recovery_dir)
        if not rdir.is_dir():
            inputs.missing.append(f"Recovery: the folder {rdir} does not exist (the recovery stage has not run "
                                  "or failed), so there is no recovered bias, calibration or residuals.")
        else:
            _gather_recovery(inputs, rdir)

    # --- validation
    if validation_dir is None:
        inputs.missing.append("Validation: no validation folder was given or found, so there is no verdict and "
                              "no integration-error statistics.")
    else:
        vdir = inputs.validation_dir = Path(validation_dir)
        vj = vdir / VALIDATION_JSON
        if not vj.is_file():
            inputs.missing.append(f"Validation: {vj} does not exist (the validation stage has not run or failed), "
                                  "so there is no verdict and no integration-error statistics.")
        else:
            inputs.validation = _read_noting_problems(inputs, "Validation", vj, lambda _: read_summary(vdir))
            wp = vdir / WINDOWS_PARQUET
            if wp.is_file():
                inputs.windows = _read_noting_problems(inputs, "Validation", wp, lambda _: read_windows(vdir),
                                                       (OSError, ValueError))
            else:
                inputs.missing.append(f"Validation: {wp} does not exist, so the per-window error "
                                      "distributions cannot be drawn (the summary table is shown).")
    return inputs


def _read_noting_problems(inputs: ReportInputs, stage: str, path: Path, reader: Callable[[Path], Any],
                          io_errors: tuple[type[Exception], ...] = ()) -> Any:
    """``reader(path)``, or None with a plain sentence in ``inputs.problems`` when it fails.

    A :class:`BiasgtError` is reported as it reads (it names the file); an error in
    ``io_errors`` (caught first) as ``cannot read PATH (error)``.
    """
    try:
        return reader(path)
    except io_errors as exc:
        inputs.problems.append(f"{stage}: cannot read {path} ({exc})")
    except BiasgtError as exc:
        inputs.problems.append(f"{stage}: {exc}")
    return None


def _gather_recovery(inputs: ReportInputs, rdir: Path) -> None:
    for name, attr, reader, absent in (
        (REPORT_JSON, "recovery", lambda _: read_report(rdir), "so the estimated calibration is not shown"),
        (BIAS_CSV, "bias", read_bias_csv, "so the recovered bias is not shown"),
        (TRAJECTORY_TUM, "trajectory", lambda _: read_trajectory(rdir), None),
        (RESIDUALS_CSV, "residuals", lambda _: read_residuals(rdir), None),
    ):
        path = rdir / name
        if path.is_file():
            setattr(inputs, attr, _read_noting_problems(inputs, "Recovery", path, reader, (OSError, ValueError)))
        elif absent is not None:
            inputs.missing.append(f"Recovery: {path} does not exist, {absent}.")


# ----------------------------------------------------------------------------- small helpers


def _num(d: Any, *keys: str) -> float | None:
    """``d[k0][k1]...`` as a float, None when absent or not a finite number."""
    cur = d
    for k in keys:
        if not isinstance(cur, dict) or k not in cur:
            return None
        cur = cur[k]
    try:
        v = float(cur)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _missing_box(text: str) -> Html:
    return tag("div", text, class_="missing")


def _rel_s(t_ns: np.ndarray, t0_ns: int) -> np.ndarray:
    return (np.asarray(t_ns, dtype=np.int64) - t0_ns) / NS_PER_S


def _sources(validation: dict[str, Any]) -> dict[str, dict[str, Any]]:
    src = validation.get("sources")
    return {str(k): v for k, v in src.items() if isinstance(v, dict)} if isinstance(src, dict) else {}


def _candidate(validation: dict[str, Any]) -> str | None:
    """The judged source: ``candidate`` when given, else the first recovered / file / dataset source."""
    sources = _sources(validation)
    cand = validation.get("candidate")
    if isinstance(cand, str) and cand in sources:
        return cand
    for kind in ("recovered", "file", "dataset"):
        for name, s in sources.items():
            if s.get("kind") == kind:
                return name
    return next(iter(sources), None)


def _first_of_kind(validation: dict[str, Any], kind: str, exclude: str | None) -> str | None:
    return next((n for n, s in _sources(validation).items() if s.get("kind") == kind and n != exclude), None)


def _source_label(name: str, kind: str | None) -> str:
    return {
        "recovered": "The recovered bias",
        "dataset": "The dataset's own bias",
        "constant_first_window": "A constant bias",
        "zero": "A zero bias",
    }.get(kind or "", f"The bias '{name}'")


def _better_worse(cand: float | None, base: float | None) -> str | None:
    if cand is None or base is None or base <= 0:
        return None
    rel = 1.0 - cand / base
    if abs(rel) < 0.005:
        return "as well as"
    return f"{abs(rel):.0%} {'better' if rel > 0 else 'worse'} than"


def other_estimates_sentence(validation: dict[str, Any]) -> str | None:
    """What the other bias estimates of the sequence (sources of kind ``file``) say against the judged one.

    Each is compared on the same windows and reference: its PRMSE as a multiple of the judged bias's, and
    the difference of the mean accelerometer biases with the tilt of the same size (``|d b_a| / |g|``), since
    a bias is only meaningful together with the attitude and gravity it was estimated against. None when
    there is no such source.
    """
    sources, cand = _sources(validation), _candidate(validation)
    others = [n for n, s in sources.items() if s.get("kind") == "file" and n != cand]
    if cand is None or not others:
        return None
    base = _num(sources[cand], "prmse_m")
    g = float(np.linalg.norm(validation.get("gravity_mps2") or DEFAULT_GRAVITY_MPS2))
    parts = []
    for name in others:
        s = sources[name]
        prmse = _num(s, "prmse_m")
        if name == HELDOUT_SOURCE:
            parts.append(f"'{name}', the recovery cross-validated by time blocks (recovered again without the "
                         f"poses of each block, used on that block only), integrates to "
                         f"{fmt(None if prmse is None else 1e3 * prmse, 4)} mm"
                         + (f", {prmse / base:.2g}x the judged bias's {fmt(1e3 * base, 4)} mm: what the recovery "
                            "is worth on poses it was not fitted to" if prmse is not None and base else ""))
            continue
        text = f"'{name}' integrates to {fmt(None if prmse is None else 1e3 * prmse, 4)} mm"
        if prmse is not None and base:
            text += f", {prmse / base:.2g}x the judged bias's {fmt(1e3 * base, 4)} mm"
        mean_o, mean_c = s.get("mean_bias"), sources[cand].get("mean_bias")
        if isinstance(mean_o, list) and isinstance(mean_c, list) and len(mean_o) == len(mean_c) == 6:
            d = np.asarray(mean_o[3:], dtype=float) - np.asarray(mean_c[3:], dtype=float)
            text += (f"; its mean accelerometer bias differs by ({', '.join(f'{x:+.3f}' for x in d)}) m/s^2, what "
                     f"a {math.degrees(float(np.linalg.norm(d)) / g):.2f}-deg tilt of the attitude would explain")
        parts.append(text)
    frame_note = (" A bias is only meaningful with the attitude and gravity it was estimated against: an estimate "
                  "made against another pose source fits this reference only as well as the two sources' attitudes "
                  "agree." if any(n != HELDOUT_SOURCE for n in others) else "")
    return ("Other estimates of this sequence's bias, integrated on the same windows against the same reference: "
            + "; ".join(parts) + "." + frame_note)


# ----------------------------------------------------------------------------- section 1: verdict


_USABILITY = {
    "PASS": "usable for training.",
    "WARN": "usable with care: read the reasons below before training on it.",
    "FAIL": "not usable for training as it is.",
}


def mm_pair(a_m: float | None, b_m: float | None) -> tuple[str, str]:
    """Two distances in mm with the same number of decimals (3 significant digits for the smaller)."""
    vals = [x for x in (a_m, b_m) if x is not None and math.isfinite(x)]
    if not vals:
        return fmt(a_m), fmt(b_m)
    small = max(min(abs(1e3 * x) for x in vals), 1e-9)
    decimals = int(min(6, max(0, 2 - math.floor(math.log10(small)))))
    return tuple("n/a" if x is None or not math.isfinite(x) else f"{1e3 * x:.{decimals}f}"  # type: ignore[return-value]
                 for x in (a_m, b_m))


def dataset_bias_label(sequence: Sequence | None) -> str:
    """How the DATASET source is named: the simulator's truth for a simulated recording, else the dataset's own."""
    src = (sequence.metadata.get("source_path") if sequence is not None else None) or ""
    return ("the simulator's true bias" if src and (Path(src) / "simulation.yaml").is_file()
            else "the dataset's own bias")


def verdict_summary(validation: dict[str, Any] | None,
                    dataset_label: str = "the dataset's own bias") -> tuple[str, str]:
    """``(word, sentence)``: PASS/WARN/FAIL (or NO VERDICT) and one plain-words headline (the DATASET source
    named ``dataset_label``)."""
    if validation is None:
        return "NO VERDICT", "The validation stage's output is missing, so the recovered bias has not been judged."
    word = str(validation.get("verdict", "")).upper() or "NO VERDICT"
    cand = _candidate(validation)
    sources = _sources(validation)
    usable = _USABILITY.get(word, "")
    if cand is None:
        return word, f"The validation holds no bias source. {usable}".strip()
    cs = sources[cand]
    who = _source_label(cand, cs.get("kind"))
    const = _first_of_kind(validation, "constant_first_window", cand)
    parts = []
    if const is not None:
        bs = sources[const]
        rel = _better_worse(_num(cs, "prmse_m"), _num(bs, "prmse_m"))
        if rel is not None:
            a, b = mm_pair(_num(cs, "prmse_m"), _num(bs, "prmse_m"))
            parts.append(
                f"{who} integrates {rel} a constant bias (position error after 1-s windows, PRMSE "
                f"{a} mm vs {b} mm; rotation error "
                f"ROE {fmt(_num(cs, 'roe_deg'), 3)} deg vs {fmt(_num(bs, 'roe_deg'), 3)} deg)")
    ds = _first_of_kind(validation, "dataset", cand)
    if ds is not None:
        rel = _better_worse(_num(cs, "prmse_m"), _num(sources[ds], "prmse_m"))
        if rel is not None and parts:
            parts[-1] += f" and {rel} {dataset_label}"
        elif rel is not None:
            a, b = mm_pair(_num(cs, "prmse_m"), _num(sources[ds], "prmse_m"))
            parts.append(f"{who} integrates {rel} {dataset_label} (PRMSE {a} mm vs {b} mm)")
    if not parts:
        parts.append(f"{who} has PRMSE {fmt(1e3 * (_num(cs, 'prmse_m') or float('nan')), 3)} mm and ROE "
                     f"{fmt(_num(cs, 'roe_deg'), 3)} deg over 1-s windows")
    found = [x for x in validation.get("plausibility") or [] if isinstance(x, Mapping)]
    if found:  # what physics rules out comes before any comparison of errors
        checks = ", ".join(dict.fromkeys(str(x.get("check", "?")).replace("_", " ") for x in found))
        parts.insert(0, f"{who} is physically impossible ({len(found)} plausibility finding"
                        f"{'s' * (len(found) > 1)}: {checks}; framed in red below)")
    sentence = "; ".join(parts) + ". " + (f"It is {usable}" if usable else "")
    return word, sentence.strip()


def checked_and_not(validation: dict[str, Any]) -> list[str]:
    """Plain sentences: what the validation checked, and what it did not."""
    ref, cfg, dropped = (validation.get(k) if isinstance(validation.get(k), dict) else {}
                         for k in ("reference", "config", "windows_dropped"))
    kept = dropped.get("kept", "?")
    if ref.get("kind") == "state":
        against = "the sequence's ground-truth state (position, velocity, orientation)"
    else:
        against = f"the pose stream '{ref.get('stream', '?')}' (velocity from a smoothing spline of its positions)"
    reasons = validation.get("reasons") if isinstance(validation.get("reasons"), list) else []
    independent = not any("not an independent test" in str(r) for r in reasons)
    baselines = sorted({str(s.get("kind")) for s in _sources(validation).values()}
                       & {"constant_first_window", "dataset"})
    return [
        f"Checked: {kept} integrations of {fmt(_num(cfg, 'window_s') or 1.0, 3)} s of the IMU minus the bias, each "
        f"from and against {against}; end-point position and rotation errors (PRMSE, ROE) compared with "
        + " and ".join({"constant_first_window": "a constant bias", "dataset": "the dataset's own bias"}[k]
                       for k in baselines) + ".",
        "Independent reference: " + ("yes." if independent else "no, the reference is what the bias was fitted "
                                                                  "to (pose errors absorbed by the bias are not seen)."),
        *plausibility_checked(validation),
        "Not checked: drift over spans longer than one window; errors the reference and the IMU share (e.g. a "
        "wrong extrinsic used by both); IMU scale and misalignment (not modelled: the bias absorbs them).",
    ]


def plausibility_checked(validation: dict[str, Any]) -> list[str]:
    """The sentence on the plausibility checks (run when the validation had the recovery), or none."""
    notes = validation.get("notes") if isinstance(validation.get("notes"), list) else []
    if "plausibility" not in validation or not any(str(n).startswith("recovery: ") for n in notes):
        return []
    found = validation.get("plausibility") or []
    return [f"Plausibility of the recovery (bias within the sensor's range, gravity direction, attitude against the "
            f"poses, gyro axes against the poses' rotation): {len(found) or 'no'} finding{'s' * (len(found) != 1)}."]


def implausible_frame(inp: ReportInputs, check: str, body: Html | None) -> Html | None:
    """``body`` framed in red, under the finding, when the validation found ``check`` implausible
    (``validation.json`` ``plausibility``, :mod:`validation.plausibility`); else ``body`` as it is."""
    found = [x for x in ((inp.validation.get("plausibility") if inp.validation is not None else None) or [])
             if isinstance(x, Mapping) and x.get("check") == check]
    if not found or body is None:
        return body
    text = "; ".join(str(x.get("text")) for x in found)
    why = p(Html(tag("strong", "Plausibility check failed: ") + esc(text)), class_="why")
    return tag("div", join([why, body]), class_="implausible", data_check=check)


def _verdict_section(inp: ReportInputs) -> Html:
    word, sentence = verdict_summary(inp.validation, dataset_bias_label(inp.sequence))
    cls = {"PASS": "v-pass", "WARN": "v-warn", "FAIL": "v-fail"}.get(word, "v-none")
    body = [Html(tag("span", word, class_="word") + esc(sentence))]
    if inp.validation is not None:
        reasons = [str(r) for r in inp.validation.get("reasons") or []]
        if reasons:
            body.append(p("Reasons:"))
            body.append(ul(reasons))
        elif word == "PASS":
            body.append(p("No reason for concern was found in what was checked: the candidate is at least as good "
                          "as every baseline, few windows are flagged and few were dropped."))
        steps = [str(x) for x in inp.validation.get("next_steps") or [] if isinstance(x, str)]
        if steps:
            body.append(p("What to do next:"))
            body.append(ul(steps))
        body.append(p("What was checked:"))
        body.append(ul(checked_and_not(inp.validation)))
    else:
        where = inp.validation_dir if inp.validation_dir is not None else "(not given)"
        body.append(p(f"Looked for the validation output in {where}. Run the validation stage to get a verdict; "
                      "the sections below show what is available."))
    notes = []
    fatal = [f for f in _current_findings(inp.sequence) if f.severity == Severity.FATAL]
    if fatal:
        notes.append(f"The input checks report {len(fatal)} fatal problem(s) (section 2).")
    warnings = (inp.recovery or {}).get("warnings") or []
    if warnings:
        notes.append(f"The recovery reported {len(warnings)} warning(s) (section 5).")
    notes += inp.missing + inp.problems
    if notes:
        body.append(p("Also note:"))
        body.append(ul(notes))
    return section("verdict", _TITLE["verdict"], tag("div", join(body), class_=f"verdict {cls}"))


# ----------------------------------------------------------------------------- section 2: streams


def _current_findings(seq: Sequence) -> list[Finding]:
    try:
        return run_checks(seq)
    except BiasgtError as exc:  # checks of a store should not fail; show it rather than crash
        return [Finding("CHECKS_FAILED", Severity.WARNING, "all", f"the input checks could not run: {exc}")]


def _streams_section(inp: ReportInputs) -> Html:
    seq = inp.sequence
    rows = []
    for s in stream_summaries(seq):
        kind = s["kind"] if s.get("source_kind") in (None, s["kind"]) else f"{s['kind']} ({s['source_kind']})"
        t0 = None if s.get("t0_ns") is None else (s["t0_ns"] - inp.t0_ns) / NS_PER_S
        t1 = None if s.get("t1_ns") is None else (s["t1_ns"] - inp.t0_ns) / NS_PER_S
        span = "n/a" if t0 is None else f"{t0:.3f} – {t1:.3f} s ({fmt(s.get('duration_s'), 5)} s)"
        rows.append([s["stream"], kind, f"{s['count']:,}", span, fmt(s.get("rate_hz"), 5, "Hz"),
                     fmt(s.get("dt_std_ms"), 3, "ms"), fmt(s.get("dt_max_ms"), 4, "ms"), s.get("frame") or "—"])
    parts = [
        p("Every stream of the canonical store. Span: first and last stamp, in seconds from the first IMU sample. "
          "Rate: from the median step. Jitter: standard deviation of the steps; max step: the longest one "
          "(a gap shows up here)."),
        table(["stream", "kind", "samples", "span", "rate", "jitter", "max step", "frame"], rows, numeric_from=2,
              text_cols=[7]),
    ]
    findings = _current_findings(seq)
    parts.append(tag("h3", "Input checks on the stored data"))
    if findings:
        order = {Severity.FATAL: 0, Severity.REPAIRABLE: 1, Severity.WARNING: 2, Severity.INFO: 3}
        frows = [[tag("span", f.severity.value, class_=f"sev-{f.severity.value}"), f.code, f.stream, f.message]
                 for f in sorted(findings, key=lambda f: order.get(f.severity, 9))]
        parts.append(table(["severity", "code", "stream", "message"], frows, numeric_from=99))
    else:
        parts.append(p("No finding."))
    current = {(f.code, f.stream) for f in findings}
    earlier = [f for f in seq.findings if f.code in CHECK_CODES and (f.code, f.stream) not in current]
    if earlier:
        parts.append(tag("h3", "Found at conversion (before the repairs below)"))
        parts.append(table(["severity", "code", "stream", "message"],
                           [[tag("span", f.severity.value, class_=f"sev-{f.severity.value}"), f.code, f.stream,
                             f.message] for f in earlier], numeric_from=99))
    repairs = [str(r) for r in (seq.metadata.get("repairs") or [])]
    parts.append(tag("h3", "Repairs applied at conversion"))
    parts.append(ul(repairs) if repairs else p("None: the data is stored as it was read."))
    prov = {k: v for k, v in seq.metadata.items() if k != "repairs" and isinstance(v, (str, int, float))}
    if prov:
        parts.append(p(Html("Provenance: " + join((f"{k} = {v}" for k, v in prov.items()), "; ")), class_="small"))
    return section("streams", _TITLE["streams"], join(parts))


# ----------------------------------------------------------------------------- section 3: calibration


def _rotation_text(quat_wxyz: list[float]) -> tuple[str, str, np.ndarray]:
    rot = Rotation.from_quat(np.asarray(quat_wxyz, dtype=float), scalar_first=True)
    rv = rot.as_rotvec()
    ang = float(np.degrees(np.linalg.norm(rv)))
    axis = rv / np.linalg.norm(rv) if ang > 1e-9 else np.array([0.0, 0.0, 1.0])
    rpy = rot.as_euler("xyz", degrees=True)
    aa = f"{ang:.3f} deg about axis [{axis[0]:.3f}, {axis[1]:.3f}, {axis[2]:.3f}]"
    return aa, f"roll {rpy[0]:.3f}, pitch {rpy[1]:.3f}, yaw {rpy[2]:.3f} deg", rot.as_matrix()


def _vec(v: Any, digits: int = 4, scale: float = 1.0) -> str:
    try:
        arr = np.asarray(v, dtype=float).reshape(-1) * scale
    except (TypeError, ValueError):
        return "n/a"
    return "[" + ", ".join(fmt(x, digits) for x in arr) + "]"


def _calibration_section(inp: ReportInputs, allan: ImuAllan | None) -> Html:
    rec = inp.recovery.data if inp.recovery is not None else None  # the JSON object: display fields
    cal = inp.sequence.calibration
    if rec is None:
        return section("calibration", _TITLE["calibration"],
                       _missing_box("Not available: the recovery output (recovery.json) is missing. The sensor's "
                                    "datasheet noise values are shown in section 7."))
    rows = []
    off = _num(rec, "pose_time_offset_s")
    off_std = _num(rec, "pose_time_offset_std_s")
    rows.append(["Clock offset of the pose stream",
                 "n/a" if off is None else f"{off * 1e3:.3f} ms",
                 "n/a" if off_std is None else f"{off_std * 1e3:.3f} ms",
                 f"add it to the pose stamps to put them on the IMU clock; method: "
                 f"{rec.get('pose_time_offset_method', 'n/a')}"])
    T = rec.get("T_imu_pose") if isinstance(rec.get("T_imu_pose"), dict) else {}
    ext = rec.get("extrinsic") if isinstance(rec.get("extrinsic"), dict) else {}
    how = f"source: {ext.get('source', 'n/a')}" + (f", mode: {ext['mode']}" if "mode" in ext else "")
    frame = rec.get("pose_frame") or "pose"
    rows.append([f"Extrinsic translation (pose frame '{frame}' in the IMU frame)", _vec(T.get("p_m"), 4) + " m",
                 _vec(ext.get("translation_std_m"), 2, 1e3) + " mm" if ext.get("translation_std_m") else "n/a", how])
    if T.get("quat_wxyz") is not None:
        try:
            aa, rpy, _ = _rotation_text(T["quat_wxyz"])
        except (ValueError, TypeError):
            aa, rpy = "n/a", "n/a"
        rows.append(["Extrinsic rotation", Html(esc(aa) + tag("br") + esc(rpy)),
                     _vec(ext.get("rotation_std_deg"), 2) + " deg" if ext.get("rotation_std_deg") else "n/a",
                     "roll/pitch/yaw about the fixed x, y, z axes; std per rotation-vector axis"])
    g = rec.get("gravity_world_mps2")
    if g is not None:
        gi = rec.get("gravity") if isinstance(rec.get("gravity"), dict) else {}
        tilt_std = _num(gi, "tilt_std_rad")
        rows.append(["Gravity in the world frame", _vec(g, 5) + f" m/s² (|g| = {fmt(np.linalg.norm(g), 5)})",
                     "n/a", "estimated" if gi.get("estimated") else "as configured"])
        rows.append(["Tilt of gravity from the world −z axis", f"{gravity_tilt_deg(g):.3f} deg",
                     "n/a" if tilt_std is None else f"{math.degrees(tilt_std):.3f} deg",
                     "0 means the pose world frame is z-up"])
    parts = [
        p(f"What the recovery estimated for pose stream '{rec.get('pose_stream', 'n/a')}' "
          f"({rec.get('pose_source_kind', 'n/a')}, pose factors: {rec.get('pose_factor_mode', 'n/a')}). "
          "Uncertainties are 1σ where the recovery gives them."),
        implausible_frame(inp, "gravity_tilt", table(["quantity", "value", "uncertainty (1σ)", "notes"], rows,
                                                     numeric_from=99)),
    ]
    diff = ext.get("difference_from_calibration")
    if isinstance(diff, dict):
        parts.append(tag("div", _difference_text(diff),
                         class_="warnbox" if diff.get("exceeds") else "small"))
    if rec.get("extrinsic_rotation_observable") is False:
        parts.append(tag("div", "The motion did not excite rotation enough to observe the extrinsic rotation: "
                                "the calibration's (or identity) rotation was used.", class_="warnbox"))
    noise = rec.get("noise") if isinstance(rec.get("noise"), dict) else {}
    nrows = []
    for key, label, unit, al in (
        ("gyro_noise_density", "gyro white noise", "rad/s/√Hz", None if allan is None else allan.gyro_white),
        ("gyro_random_walk", "gyro bias random walk", "rad/s²/√Hz", None if allan is None else allan.gyro_rw),
        ("acc_noise_density", "accelerometer white noise", "m/s²/√Hz", None if allan is None else allan.acc_white),
        ("acc_random_walk", "accelerometer bias random walk", "m/s³/√Hz", None if allan is None else allan.acc_rw),
    ):
        used = _num(noise, key)
        if used is None:
            used = _num(rec, key)
        yaml_v = float(getattr(cal, key))
        ratio = "n/a" if used is None or yaml_v == 0 else f"{used / yaml_v:.3g}×"
        if al is None:
            al_v = "n/a"
        elif not np.isfinite(al).any():
            al_v = "not visible" if allan is not None and allan.static else "n/a"
        else:
            al_v = _allan_cell(float(np.nanmean(al)), allan is not None and allan.static, "random_walk" in key)
        nrows.append([label, fmt(used, 4), fmt(yaml_v, 4), ratio, al_v, unit, _calibration_origin(cal, key)])
    parts.append(tag("h3", "Noise strengths: used by the recovery vs. the calibration"))
    parts.append(table(["parameter", "used", "calibration", "used / calibration", "Allan fit (section 7)", "unit",
                        "calibration from"], nrows, numeric_from=1, text_cols=[5, 6]))
    extra = []
    for key, label in (("position_sigma_m", "pose position sigma [m]"), ("rotation_sigma_rad", "pose rotation "
                       "sigma [rad]"), ("gyro_random_walk_scale", "gyro random-walk scale"),
                       ("acc_random_walk_scale", "acc random-walk scale"),
                       ("gyro_density_scale", "gyro white-noise scale"), ("acc_density_scale", "acc white-noise scale")):
        if _num(noise, key) is not None:
            extra.append(f"{label}: {fmt(_num(noise, key), 4)}")
    pose_error = noise.get("pose_error")
    if isinstance(pose_error, dict):
        extra.append("correlated pose error (Gauss-Markov): "
                     f"{fmt(_num(pose_error, 'rotation_sigma_rad'), 3)} rad over {fmt(_num(pose_error, 'rotation_tau_s'), 3)} s, "
                     f"{fmt(_num(pose_error, 'position_sigma_m'), 3)} m over {fmt(_num(pose_error, 'position_tau_s'), 3)} s")
    if noise.get("method"):
        extra.append(f"chosen by: {noise['method']}")
    if noise.get("pose_sigma_method"):
        extra.append(f"pose sigmas from: {str(noise['pose_sigma_method']).replace('_', ' ')}")
    if extra:
        parts.append(p("; ".join(extra) + ".", class_="small"))
    fusion = rec.get("pose_fusion") if isinstance(rec.get("pose_fusion"), dict) else {}
    if fusion.get("enabled") and _num(fusion, "samples_per_keyframe_mean") is not None:
        parts.append(p(
            f"Pose fusion: {fmt(_num(fusion, 'samples_per_keyframe_mean'), 3)} pose samples per "
            f"{fmt(_num(fusion, 'keyframe_rate_hz'), 3)}-Hz keyframe, moved to it through the IMU and fused; "
            f"{int(_num(fusion, 'samples_rejected') or 0)} samples rejected as outliers; scatter about the "
            f"keyframes {fmt(_num(fusion, 'within_bin_position_rms_m'), 3)} m / "
            f"{fmt(_num(fusion, 'within_bin_rotation_rms_rad'), 3)} rad RMS.", class_="small"))
    floor = rec.get("accuracy_floor") if isinstance(rec.get("accuracy_floor"), dict) else {}
    if _num(floor, "acc_mps2") is not None:
        gyro_txt = (f"gyro {fmt(_num(floor, 'gyro_radps'), 3)} rad/s, " if _num(floor, "gyro_radps") is not None
                    else "")
        parts.append(p(
            f"Accuracy floor for this noise (optimal smoother, per axis): {gyro_txt}accelerometer "
            f"{fmt(_num(floor, 'acc_mps2'), 3)} m/s²: no recovery of this recording is more accurate; the bias "
            "sigmas of section 4 sit somewhat above it.", class_="small"))
    return section("calibration", _TITLE["calibration"], join(parts))


def _difference_text(diff: dict) -> str:
    """One sentence: the estimated extrinsic against the calibration file's, in its sigmas."""
    def part(value: float | None, sigmas: float | None, unit: str, scale: float) -> str:
        if value is None:
            return "n/a"
        z = f" ({sigmas:.1f} σ)" if sigmas is not None and math.isfinite(sigmas) else ""
        return f"{value * scale:.2f} {unit}{z}"

    rot = part(_num(diff, "rotation_deg"), _num(diff, "rotation_sigmas"), "deg", 1.0)
    trans = part(_num(diff, "translation_m"), _num(diff, "translation_sigmas"), "cm", 100.0)
    verdict = (f"beyond {fmt(_num(diff, 'max_sigmas'), 2)} σ: the calibration file is off (or the tracked body "
               "was moved); the estimate was used" if diff.get("exceeds") else "within the calibration's prior")
    return f"Estimated extrinsic against the calibration file's: {rot} in rotation, {trans} in translation; {verdict}."


# ----------------------------------------------------------------------------- section 4: bias


def _bias_section(inp: ReportInputs) -> Html:
    if inp.bias is None:
        return section("bias", _TITLE["bias"], _missing_box(
            "Not available: the recovery's bias.csv is missing or could not be read (see the notes in section 1)."))
    b = inp.bias
    t_s = _rel_s(b.t_ns, inp.t0_ns)
    gt = inp.sequence.ground_truth
    gt_t = None if gt is None else _rel_s(gt.t_ns, inp.t0_ns)
    std = np.asarray(b.std, dtype=float)
    parts = [p(f"{len(b.t_ns):,} keyframes over {fmt(t_s[-1] - t_s[0], 5)} s. The shaded band is ± 3 marginal "
               "standard deviations of the recovery" + (
                   "; the dashed black line is the dataset's own bias estimate." if gt is not None else
                   "; the dataset has no bias of its own to compare with."))]
    # milli-units: bias values need no matplotlib offset ("1e-3") on the axis
    parts.append(figure_img(plots.bias_figure(t_s, 1e3 * b.bias[:, :3], 1e3 * std[:, :3], quantity="Gyroscope bias",
                                              unit="mrad/s", dataset_t_s=gt_t,
                                              dataset_bias=None if gt is None else 1e3 * gt.bias_gyro_radps),
                            "gyroscope bias over time", "Gyroscope bias (x, y, z) with ± 3σ."))
    parts.append(figure_img(plots.bias_figure(t_s, 1e3 * b.bias[:, 3:], 1e3 * std[:, 3:],
                                              quantity="Accelerometer bias", unit="10⁻³ m/s²", dataset_t_s=gt_t,
                                              dataset_bias=None if gt is None else 1e3 * gt.bias_acc_mps2),
                            "accelerometer bias over time", "Accelerometer bias (x, y, z) with ± 3σ."))
    rows = []
    names = ["gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z"]
    gt_b = None if gt is None else np.hstack([gt.bias_gyro_radps, gt.bias_acc_mps2])
    for c in range(6):
        v = b.bias[:, c]
        row = [names[c], fmt(v.mean(), 4), fmt(v.min(), 4), fmt(v.max(), 4),
               fmt(np.nanmean(std[:, c]) if np.isfinite(std[:, c]).any() else None, 3)]
        if gt_b is not None:
            ref = np.interp(b.t_ns.astype(float), gt.t_ns.astype(float), gt_b[:, c])
            inside = (b.t_ns >= gt.t_ns[0]) & (b.t_ns <= gt.t_ns[-1])
            row.append(fmt(np.sqrt(np.mean((v[inside] - ref[inside]) ** 2)) if inside.any() else None, 3))
        row.append("rad/s" if c < 3 else "m/s²")
        rows.append(row)
    headers = ["axis", "mean", "min", "max", "mean σ"] + (["RMS diff. to dataset"] if gt_b is not None else [])
    parts.append(implausible_frame(inp, "bias_range", table(headers + ["unit"], rows, numeric_from=1,
                                                            text_cols=[len(headers)])))
    note = _calibration_uncertainty_note(inp.recovery.data if inp.recovery is not None else None)
    if note is not None:
        parts.append(note)
    note = implausible_frame(inp, "frame_swap", gyro_consistency_note(inp))
    if note is not None:
        parts.append(note)
    return section("bias", _TITLE["bias"], join(parts))


def gyro_consistency_note(inp: ReportInputs) -> Html | None:
    """Whether the gyro reads a share of the rate against the fitted pose stream: the sentence the
    recovery's ``intrinsics: auto`` decided on, else :func:`recovery.gyro_consistency.rate_coupling`
    on the recovered offset and extrinsic; None without a 6-DoF pose stream long enough for it."""
    rec, seq = inp.recovery, inp.sequence
    poses = seq.poses.get(rec.pose_stream) if rec is not None and rec.pose_stream else None
    if poses is None or poses.quat_wxyz is None or seq.imu is None:
        return None
    auto = rec.data.get("intrinsics_auto")
    if isinstance(auto, Mapping) and auto.get("coupling") is not None:
        sentence = str(auto.get("reason"))
    else:
        try:
            sentence = rate_coupling(seq.imu, poses, R_imu_pose=rec.T_imu_pose[:3, :3],
                                     offset_s=rec.time_offset_s).sentence()
        except BiasgtError:
            return None
    return p("Gyro against the pose stream's rotation, by frequency band: " + sentence + " "
             + intrinsics_sentence(rec.data), class_="small")


def intrinsics_sentence(rec: Mapping[str, Any]) -> str:
    """What the recovery did about the IMU intrinsics (recovery.json ``intrinsics``, ``intrinsics_auto``)."""
    est = rec.get("intrinsics")
    if isinstance(est, Mapping) and "gyro_matrix" in est:
        terms = {"gyro": np.asarray(est["gyro_matrix"], float) - np.eye(3),
                 "accelerometer": np.asarray(est["acc_matrix"], float) - np.eye(3)}
        largest = "; ".join(f"{name} largest scale/misalignment {m.flat[np.argmax(np.abs(m))]:+.4f}"
                            for name, m in terms.items())
        return (f"The recovery estimated the intrinsics ({est.get('rounds')} rounds; {largest}) and its bias is "
                "free of them.")
    auto = rec.get("intrinsics_auto")
    if isinstance(auto, Mapping) and not auto.get("estimated"):
        return "The recovery estimated no intrinsics (intrinsics: auto)."
    return "The recovery estimated no intrinsics (intrinsics: off)."


def _calibration_uncertainty_note(rec: dict[str, Any] | None) -> Html | None:
    """Whether the σ include the estimated calibration's uncertainty (recovery.json ``calibration_uncertainty``)."""
    cu = rec.get("calibration_uncertainty") if isinstance(rec, dict) else None
    if not isinstance(cu, dict):
        return None
    params = ", ".join(str(x).replace("_", " ") for x in cu.get("parameters") or [])
    if not cu.get("included_in_bias_std"):
        return p("The σ treat the calibration as exact" + (f" ({params} estimated: not propagated for this pose "
                                                           "stream)." if params else " (all of it given)."),
                 class_="small")
    mean, peak = cu.get("std_inflation_mean") or [], cu.get("std_inflation_max") or []
    growth = ", ".join(f"{(m - 1) * 100:.1f} % ({(x - 1) * 100:.0f} % max)" for m, x in zip(mean, peak))
    return p(f"The σ include the uncertainty of the estimated {params} (first-order propagation); it grew them per "
             f"axis (gyro x, y, z, acc x, y, z) by {growth}.", class_="small")


# ----------------------------------------------------------------------------- section 5: residuals


def _residuals_section(inp: ReportInputs) -> Html:
    rec = inp.recovery.data if inp.recovery is not None else None  # the JSON object: display fields
    if rec is None and inp.residuals is None and inp.trajectory is None:
        return section("residuals", _TITLE["residuals"],
                       _missing_box("Not available: the recovery output is missing."))
    parts = []
    if rec is not None:
        res = rec.get("residuals") if isinstance(rec.get("residuals"), dict) else {}
        kf = _num(rec, "keyframes")
        out = _num(rec, "outliers_rejected")
        rows = [[f"{k.replace('_', ' ')}", fmt(_num(res, k), 4)] for k in res if _num(res, k) is not None]
        samples = int(_num(rec.get("pose_fusion") or {}, "samples_rejected") or 0)
        out = None if out is None else out - samples  # outliers_rejected counts both kinds
        rows.append(["keyframe poses rejected as outliers",
                     "n/a" if out is None else (f"{int(out)} of {int(kf)} keyframes ({out / kf:.2%})" if kf else
                                                f"{int(out)}")])
        if samples:
            rows.append(["pose samples rejected before fusion into keyframes", f"{samples}"])
        for key, label in (("segments", "solver segments"), ("imu_pieces", "gap-free IMU pieces"),
                           ("duration_s", "duration [s]"), ("runtime_s", "recovery runtime [s]")):
            if _num(rec, key) is not None:
                rows.append([label, fmt(_num(rec, key), 5)])
        seams = rec.get("segment_seams")
        if isinstance(seams, list) and seams:
            rows.append(["segment seams", f"{len(seams)}"])
        parts.append(p("Residual statistics of the recovery's final solve. A whitened residual divides the error "
                       "by its assumed standard deviation: an RMS near 1 means the data agree with the noise model; "
                       "well above 1 means the pose stream and the IMU disagree (wrong extrinsic, clock offset or "
                       "noise), well below 1 means the noise was assumed too large."))
        parts.append(table(["statistic", "value"], rows, numeric_from=1))
    if inp.residuals is not None and len(inp.residuals):
        frame = inp.residuals
        # a flag column (the rejected outliers) is drawn as marks on the residuals, not as a 0/1 series
        flags = [c for c in frame.columns if pd.api.types.is_bool_dtype(frame[c])]
        cols = [c for c in frame.columns if c != "t_ns" and c not in flags
                and pd.api.types.is_numeric_dtype(frame[c])][:6]
        if cols:
            t_s = _rel_s(frame["t_ns"].to_numpy(), inp.t0_ns)
            outliers = frame[flags[0]].to_numpy(bool) if flags else None
            parts.append(figure_img(plots.residual_series_figure(t_s, {c: frame[c].to_numpy(float) for c in cols},
                                                                 outliers),
                                    "residuals per keyframe", "Residuals per keyframe, as written by the recovery"
                                    + ("; red marks: keyframes rejected as outliers." if flags else ".")))
    else:
        parts.append(_missing_box("Per-keyframe residuals are not available: the recovery writes only the "
                                  "statistics above. The figure below compares the recovered trajectory with the "
                                  "pose stream instead."))
    fig = implausible_frame(inp, "rotation_residual", _pose_residual_figure(inp))
    if fig is not None:
        parts.append(fig)
    warnings = [str(w) for w in ((rec or {}).get("warnings") or [])]
    parts.append(tag("h3", "Warnings of the recovery"))
    parts.append(ul(warnings) if warnings else p("None."))
    return section("residuals", _TITLE["residuals"], join(parts))


def _pose_residual_figure(inp: ReportInputs) -> Html | None:
    rec, traj, seq = inp.recovery, inp.trajectory, inp.sequence
    if rec is None or traj is None:
        return None
    name = rec.get("pose_stream")
    poses = seq.poses.get(name) if isinstance(name, str) else None
    if poses is None and name == "ground_truth" and seq.ground_truth is not None:
        poses = seq.ground_truth.to_pose_series()
    if poses is None or len(poses) < 2:
        return _missing_box(f"The pose stream '{name}' used by the recovery is not in the store: the trajectory "
                            "cannot be compared with it.")
    try:
        t_ns, pos_err, rot_err = pose_residuals(traj, poses, rec.T_imu_pose, rec.time_offset_s)
    except (BiasgtError, ValueError, TypeError) as exc:
        return _missing_box(f"The trajectory could not be compared with the pose stream ({exc}).")
    if len(t_ns) == 0:
        return _missing_box("The recovered trajectory and the pose stream do not overlap in time.")
    rot_txt = "" if rot_err is None else f", rotation RMS {fmt(np.sqrt(np.mean(rot_err ** 2)), 3)} deg"
    caption = (f"Distance between the recovered IMU trajectory and the pose stream '{name}' moved into the IMU frame "
               f"and clock: position RMS {fmt(1e3 * np.sqrt(np.mean(pos_err ** 2)), 3)} mm, max "
               f"{fmt(1e3 * pos_err.max(), 3)} mm{rot_txt} ({len(t_ns):,} keyframes).")
    outlier_t_s = None
    if len(rec.outlier_t_ns):
        outlier_t_s = _rel_s(rec.outlier_t_ns, inp.t0_ns)
        caption += " Red lines: poses rejected as outliers."
    return figure_img(plots.pose_residual_figure(_rel_s(t_ns, inp.t0_ns), pos_err, rot_err, outlier_t_s),
                      "pose residuals over time", caption)


# ----------------------------------------------------------------------------- section 6: integration


def _integration_section(inp: ReportInputs) -> Html:
    v = inp.validation
    if v is None:
        return section("integration", _TITLE["integration"],
                       _missing_box("Not available: the validation output (validation.json) is missing."))
    sources = _sources(v)
    cand = _candidate(v)
    const = _first_of_kind(v, "constant_first_window", None)
    rows = []
    for name, s in sources.items():
        prmse, roe = _num(s, "prmse_m"), _num(s, "roe_deg")
        rel = "—"
        if const is not None and name != const:
            bp = _num(sources[const], "prmse_m")
            if prmse is not None and bp:
                rel = f"{(prmse / bp - 1.0) * 100:+.1f} %"
        nflag = len(s.get("flagged") or [])
        label = name + (" (judged)" if name == cand else "")
        rows.append([label, s.get("kind", "n/a"), fmt(_num(s, "windows"), 6),
                     fmt(None if prmse is None else 1e3 * prmse, 4), fmt(roe, 4), rel, str(nflag)])
    cfg = v.get("config") if isinstance(v.get("config"), dict) else {}
    win = _num(cfg, "window_s") or 1.0
    parts = [
        p(f"Each source's bias is removed from the IMU readings, which are then integrated over {fmt(win, 3)}-s "
          "windows from the reference state; the end of each window is compared with the reference. PRMSE is the RMS "
          "position error, ROE the mean rotation error. Lower is better; the bias judged by the verdict is marked."),
        table(["bias source", "kind", "windows", "PRMSE [mm]", "ROE [deg]", "PRMSE vs constant", "flagged"], rows,
              numeric_from=2),
    ]
    others = other_estimates_sentence(v)
    if others:
        parts.append(p(others))
    dropped = v.get("windows_dropped") if isinstance(v.get("windows_dropped"), dict) else None
    if dropped:
        text = ", ".join(f"{k} {fmt(x, 4) if not isinstance(x, dict) else ''}".strip() for k, x in dropped.items()
                         if not isinstance(x, dict))
        by = dropped.get("by_reason")
        if isinstance(by, dict) and by:
            text += "; by reason: " + ", ".join(f"{k} {x}" for k, x in by.items())
        parts.append(p(f"Windows: {text}.", class_="small"))
    elif v.get("windows_dropped") is not None:
        parts.append(p(f"Windows dropped: {v.get('windows_dropped')}.", class_="small"))
    ref = v.get("reference")
    if isinstance(ref, dict) and ref.get("kind"):
        parts.append(p(f"Reference: {ref.get('kind')}" + (f" (stream {ref['stream']})" if ref.get("stream") else "")
                       + ".", class_="small"))
    w = inp.windows
    if w is not None and len(w) and {"source", "pos_err_m", "rot_err_deg"} <= set(w.columns):
        names = list(dict.fromkeys(w["source"].astype(str)))
        parts.append(figure_img(plots.error_distribution_figure(
            names, [w.loc[w["source"] == n, "pos_err_m"].to_numpy(float) for n in names],
            [w.loc[w["source"] == n, "rot_err_deg"].to_numpy(float) for n in names]),
            "integration-error distributions per bias source",
            "Per-window errors per bias source (box: quartiles, whiskers: 5th–95th percentile, log scale)."))
        if cand is not None and cand in names and "t0_ns" in w.columns:
            wc = w[w["source"] == cand]
            flagged = wc["flagged"].to_numpy(bool) if "flagged" in wc.columns else None
            parts.append(figure_img(plots.window_errors_over_time_figure(
                _rel_s(wc["t0_ns"].to_numpy(), inp.t0_ns), wc["pos_err_m"].to_numpy(float),
                wc["rot_err_deg"].to_numpy(float), flagged, cand),
                "integration error over time", f"Per-window errors of '{cand}' over time; flagged windows circled."))
    elif w is None:
        parts.append(_missing_box("The per-window errors (windows.parquet) are missing: no distributions drawn."))
    parts.append(tag("h3", "Flagged windows" + (f" of '{cand}'" if cand else "")))
    flagged_list = (sources.get(cand) or {}).get("flagged") or [] if cand else []
    if flagged_list:
        overlap = _num(cfg, "overlap")
        stride_s = win * (1.0 - (0.5 if overlap is None else overlap))
        parts.append(p("Windows whose error is far above the source's median (an outlier in the pose stream, a "
                       "bias jump, or a stretch the IMU model does not fit), merged into stretches of consecutive "
                       "windows. Times in seconds from the first IMU sample."))
        srows = [[f"{(a - inp.t0_ns) / NS_PER_S:.3f}", f"{(b - inp.t0_ns) / NS_PER_S + win:.3f}", str(n),
                  fmt(1e3 * pmax, 4), fmt(rmax, 4)]
                 for a, b, n, pmax, rmax in flagged_stretches(flagged_list, stride_s)]
        parts.append(table(["from [s]", "to [s]", "windows", "max position error [mm]", "max rotation error [deg]"],
                           srows, numeric_from=0))
        frows = []
        for f in flagged_list[:MAX_FLAGGED_ROWS]:
            t0 = int(f.get("t0_ns", 0))
            frows.append([f"{(t0 - inp.t0_ns) / NS_PER_S:.3f}", str(t0),
                          fmt(1e3 * (_num(f, "pos_err_m") or math.nan), 4), fmt(_num(f, "rot_err_deg"), 4)])
        more = len(flagged_list) - MAX_FLAGGED_ROWS
        detail = join([
            table(["start [s]", "start t_ns", "position error [mm]", "rotation error [deg]"], frows, numeric_from=0),
            p(f"… and {more} more (all are in validation.json).", class_="small") if more > 0 else "",
        ])
        parts.append(tag("details", Html(tag("summary", f"Every flagged window ({len(flagged_list)})") + detail)))
    else:
        parts.append(p("None."))
    notes = [str(n) for n in v.get("notes") or []]
    if notes:
        parts.append(p("Notes of the validation:"))
        parts.append(ul(notes))
    return section("integration", _TITLE["integration"], join(parts))


def flagged_stretches(flagged: list[dict[str, Any]], stride_s: float) -> list[tuple[int, int, int, float, float]]:
    """Consecutive flagged windows merged: ``[(first_t0_ns, last_t0_ns, count, max_pos_m, max_rot_deg)]``.

    Two flagged windows belong to the same stretch when their starts are at most 1.5 strides apart.
    """
    rows = sorted(((int(f.get("t0_ns", 0)), _num(f, "pos_err_m") or 0.0, _num(f, "rot_err_deg") or 0.0)
                   for f in flagged), key=lambda r: r[0])
    out: list[list[Any]] = []
    limit = 1.5 * stride_s * NS_PER_S
    for t0, pe, re_ in rows:
        if out and t0 - out[-1][1] <= limit:
            last = out[-1]
            last[1], last[2], last[3], last[4] = t0, last[2] + 1, max(last[3], pe), max(last[4], re_)
        else:
            out.append([t0, t0, 1, pe, re_])
    return [tuple(r) for r in out]  # type: ignore[misc]


# ----------------------------------------------------------------------------- section 7: Allan


def _calibration_origin(cal: Any, key: str) -> str:
    """Where a calibration value came from: the file (folder/name), the config, or the default."""
    origin = cal.value_sources()[key]
    path = Path(origin)
    return f"{path.parent.name}/{path.name}" if path.suffix in (".yaml", ".yml") else origin


def _allan_cell(x: float, static: bool, is_rw: bool) -> str:
    """One fitted value as shown: a value, an upper bound (motion), or why there is none."""
    if not static:
        return "— (motion)" if is_rw else (f"≤ {fmt(x, 3)}" if np.isfinite(x) else "n/a")
    return fmt(x, 3) if np.isfinite(x) else "not visible"


def _allan_ratio(fits: np.ndarray, yaml_v: float, static: bool, is_rw: bool) -> str:
    if (is_rw and not static) or not np.isfinite(fits).any() or not yaml_v:
        return "n/a"
    ratio = f"{float(np.nanmean(fits)) / yaml_v:.3g}×"
    return ratio if static else f"≤ {ratio}"


def _allan_section(inp: ReportInputs, allan: ImuAllan | None, error: str | None) -> Html:
    cal = inp.sequence.calibration
    if allan is None:
        return section("allan", _TITLE["allan"], _missing_box(f"Not available: {error or 'no IMU data'}."))
    if allan.static:
        where = (f"Computed on the {len(allan.segments_s)} stretch(es) where the IMU is at rest "
                 f"({allan.used_s:.1f} s in total; longest {max(b - a for a, b in allan.segments_s):.1f} s), "
                 "pooled. This is the sensor's own noise.")
        cls = None
    else:
        why = " ".join(allan.notes)
        where = (f"Computed on the whole recording ({allan.used_s:.1f} s) because {why or 'it has no rest'}. "
                 "Motion dominates the curves then: they show the motion, not the sensor noise, so only an upper "
                 "bound of the white noise is given and the bias random walk cannot be read. Record a few minutes "
                 "at rest for a real noise estimate.")
        cls = "warnbox"
    parts = [tag("div", where, class_=cls) if cls else p(where),
             p("Overlapping Allan deviation per axis. Dotted line: white noise (slope −½, its value at τ = 1 s is "
               "the noise density); dash-dotted line: bias random walk (slope +½, its value at τ = 3 s is the random "
               "walk). Black: fitted to this recording; orange: the calibration.")]
    parts.append(figure_img(plots.allan_figure(
        allan.taus, allan.adev_gyro, title="Gyroscope", unit="rad/s", white=allan.gyro_white,
        random_walk=allan.gyro_rw, sensor_white=cal.gyro_noise_density, sensor_random_walk=cal.gyro_random_walk,
        fits_are_bounds=not allan.static),
        "gyroscope Allan deviation", "Gyroscope Allan deviation."))
    parts.append(figure_img(plots.allan_figure(
        allan.taus, allan.adev_acc, title="Accelerometer", unit="m/s²", white=allan.acc_white,
        random_walk=allan.acc_rw, sensor_white=cal.acc_noise_density, sensor_random_walk=cal.acc_random_walk,
        fits_are_bounds=not allan.static),
        "accelerometer Allan deviation", "Accelerometer Allan deviation."))
    rows = []
    for label, fits, yaml_v, unit, is_rw in (
        ("gyro white noise", allan.gyro_white, cal.gyro_noise_density, "rad/s/√Hz", False),
        ("gyro bias random walk", allan.gyro_rw, cal.gyro_random_walk, "rad/s²/√Hz", True),
        ("accelerometer white noise", allan.acc_white, cal.acc_noise_density, "m/s²/√Hz", False),
        ("accelerometer bias random walk", allan.acc_rw, cal.acc_random_walk, "m/s³/√Hz", True),
    ):
        rows.append([label, *[_allan_cell(x, allan.static, is_rw) for x in fits], fmt(yaml_v, 4),
                     _allan_ratio(fits, yaml_v, allan.static, is_rw), unit])
    parts.append(table(["parameter", "x", "y", "z", "calibration", "fit / calibration", "unit"], rows, numeric_from=1,
                       text_cols=[6]))
    if allan.static:
        parts.append(p("“not visible”: the curve does not rise significantly above the white-noise line within a "
                       "tenth of the longest segment, so the bias random walk cannot be read off this recording "
                       "(the rest periods are too short or the sensor too quiet).", class_="small"))
    else:
        parts.append(p("“≤”: with motion in the data only an upper bound of the white noise can be read (motion adds "
                       "to the curve everywhere); the bias random walk cannot be separated from the motion.",
                       class_="small"))
    return section("allan", _TITLE["allan"], join(parts))


# ----------------------------------------------------------------------------- page


def render_report(inp: ReportInputs) -> str:
    """The whole HTML page for ``inp`` (no file written)."""
    seq = inp.sequence
    allan, allan_error = None, None
    if seq.imu is not None and len(seq.imu) >= 10:
        try:
            allan = imu_allan(seq.imu)
        except BiasgtError as exc:
            allan_error = str(exc)
    else:
        allan_error = "the sequence has no IMU readings"
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    where = [f"ingest: {inp.ingest_dir}", f"recovery: {inp.recovery_dir or 'not given'}",
             f"validation: {inp.validation_dir or 'not given'}"]
    header = join([
        tag("h1", f"Dataset quality report: {seq.name}"),
        p(Html(f"biasgt {esc(__version__)} · generated {esc(now)}" + tag("br") + join(where, " · ")), class_="meta"),
    ])
    toc = tag("nav", Html(tag("strong", "Contents") + tag("ol", join(
        tag("li", tag("a", title.split(". ", 1)[1], href=f"#{anchor}")) for anchor, title in SECTIONS))),
        class_="toc")
    body = join([
        header,
        _verdict_section(inp),
        toc,
        _streams_section(inp),
        _calibration_section(inp, allan),
        _bias_section(inp),
        _residuals_section(inp),
        _integration_section(inp),
        _allan_section(inp, allan, allan_error),
    ])
    return page(f"biasgt quality report: {seq.name}", body)


def build_quality_report(
    ingest_dir: str | Path,
    *,
    recovery_dir: str | Path | None = None,
    validation_dir: str | Path | None = None,
    out_path: str | Path,
    sequence: Sequence | None = None,
) -> Path:
    """Write the quality report of one sequence as one self-contained HTML file.

    Args:
        ingest_dir: The sequence's canonical store (``results/ingest/<sequence>``); required.
        recovery_dir: ``results/recovery/<sequence>`` (bias.csv, recovery.json, ...), or None.
        validation_dir: ``results/validation/<sequence>`` (validation.json, windows.parquet), or None.
        out_path: The HTML file to write (atomically; parent folders are created).
        sequence: The sequence already loaded from ``ingest_dir`` when that is not a store
            (:func:`gather_inputs`).

    Returns:
        ``out_path`` as a Path.

    Raises:
        InputFormatError: ``ingest_dir`` is not a canonical store.
        ConfigError: ``out_path`` is an existing folder.
    """
    out_path = Path(out_path)
    if out_path.is_dir():
        raise ConfigError("the report output is a folder", path=out_path, field="--out",
                          hint="give a file name such as report.html")
    inputs = gather_inputs(ingest_dir, recovery_dir=recovery_dir, validation_dir=validation_dir, sequence=sequence)
    for note in inputs.missing + inputs.problems:
        log.info("report %s: %s", inputs.sequence.name, note)
    text = render_report(inputs)
    with atomic_path(out_path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    log.info("wrote %s (%.0f kB)", out_path, len(text) / 1024)
    return out_path
