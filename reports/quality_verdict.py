"""Sections 1 and 2 of the quality report: the verdict box and the streams.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path
from collections.abc import Mapping
from typing import Any


from pipeline.checks.options import CHECK_CODES
from pipeline.checks.run import run_checks, stream_summaries
from pipeline.errors import BiasgtError
from pipeline.types import NS_PER_S, Finding, Sequence, Severity, Verdict
from recovery.intrinsics.report import intrinsics_clause
from reports.html import Html, esc, fmt, join, p, section, table, tag, ul
from reports.quality_inputs import (TITLE, ReportInputs, better_worse, candidate_name, first_of_kind, num,
                                    source_label, validation_sources)

log = logging.getLogger(__name__)

#: The rule code of a reference that is the stream the bias was fitted to (validation.rules).
NOT_INDEPENDENT = "NOT_INDEPENDENT"


# ----------------------------------------------------------------------------- section 1: verdict


_USABILITY = {
    Verdict.PASS: "usable for training.",
    Verdict.WARN: "usable with care: read the reasons below before training on it.",
    Verdict.FAIL: "not usable for training as it is.",
}
#: The verdict box's CSS class (no verdict: ``v-none``).
_VERDICT_CLASS = {Verdict.PASS: "v-pass", Verdict.WARN: "v-warn", Verdict.FAIL: "v-fail"}
#: The verdict word of a validation without one.
NO_VERDICT = "NO VERDICT"


def mm_pair(a_m: float | None, b_m: float | None) -> tuple[str, str]:
    """Two distances in mm with the same number of decimals (3 significant digits for the smaller)."""
    vals = [x for x in (a_m, b_m) if x is not None and math.isfinite(x)]
    if not vals:
        return fmt(a_m), fmt(b_m)
    small = max(min(abs(1e3 * x) for x in vals), 1e-9)
    decimals = int(min(6, max(0, 2 - math.floor(math.log10(small)))))
    return tuple("n/a" if x is None or not math.isfinite(x) else f"{1e3 * x:.{decimals}f}"  # type: ignore[return-value]
                 for x in (a_m, b_m))


#: The DATASET source of a simulated recording.
SIMULATOR_TRUTH = "the simulator's true bias"
#: Why a recovered bias that integrates below the simulator's truth is not called better than it.
IN_SAMPLE = ("a bias fitted to these poses absorbs some of their noise, so an in-sample error below the truth's "
             "is expected and no sign of a better estimate")


def dataset_bias_label(sequence: Sequence | None) -> str:
    """How the DATASET source is named: the simulator's truth for a simulated recording, else the dataset's own."""
    src = (sequence.metadata.get("source_path") if sequence is not None else None) or ""
    return SIMULATOR_TRUTH if src and (Path(src) / "simulation.yaml").is_file() else "the dataset's own bias"


def verdict_summary(validation: dict[str, Any] | None,
                    dataset_label: str = "the dataset's own bias") -> tuple[str, str]:
    """``(word, sentence)``: PASS/WARN/FAIL (or NO VERDICT) and one plain-words headline (the DATASET source
    named ``dataset_label``). A recovered bias is never called better than the simulator's truth
    (:data:`SIMULATOR_TRUTH`): its lower error there is in-sample (:data:`IN_SAMPLE`)."""
    if validation is None:
        return NO_VERDICT, "The validation stage's output is missing, so the recovered bias has not been judged."
    verdict = Verdict.parse(validation.get("verdict"))
    word = verdict.value if verdict is not None else str(validation.get("verdict") or "").upper() or NO_VERDICT
    cand = candidate_name(validation)
    sources = validation_sources(validation)
    usable = _USABILITY.get(verdict, "")
    if cand is None:
        return word, f"The validation holds no bias source. {usable}".strip()
    cs = sources[cand]
    who = source_label(cand, cs.get("kind"))
    const = first_of_kind(validation, "constant_first_window", cand)
    parts = []
    if const is not None:
        bs = sources[const]
        rel = better_worse(num(cs, "prmse_m"), num(bs, "prmse_m"))
        if rel is not None:
            a, b = mm_pair(num(cs, "prmse_m"), num(bs, "prmse_m"))
            parts.append(
                f"{who} integrates {rel} a constant bias (position error after 1-s windows, PRMSE "
                f"{a} mm vs {b} mm; rotation error "
                f"ROE {fmt(num(cs, 'roe_deg'), 3)} deg vs {fmt(num(bs, 'roe_deg'), 3)} deg)")
    ds = first_of_kind(validation, "dataset", cand)
    if ds is not None:
        rel = better_worse(num(cs, "prmse_m"), num(sources[ds], "prmse_m"))
        if rel is not None and rel.endswith("better than") and dataset_label == SIMULATOR_TRUTH:
            a, b = mm_pair(num(cs, "prmse_m"), num(sources[ds], "prmse_m"))
            rel, dataset_label = f"as well as {dataset_label} ({a} mm vs {b} mm: {IN_SAMPLE})", ""
        if rel is not None and parts:
            parts[-1] += f" and {rel} {dataset_label}".rstrip()
        elif rel is not None:
            a, b = mm_pair(num(cs, "prmse_m"), num(sources[ds], "prmse_m"))
            parts.append(f"{who} integrates {rel} {dataset_label}".rstrip()
                         + ("" if IN_SAMPLE in rel else f" (PRMSE {a} mm vs {b} mm)"))
    if not parts:
        parts.append(f"{who} has PRMSE {fmt(1e3 * (num(cs, 'prmse_m') or float('nan')), 3)} mm and ROE "
                     f"{fmt(num(cs, 'roe_deg'), 3)} deg over 1-s windows")
    found = [x for x in validation.get("plausibility") or [] if isinstance(x, Mapping)]
    if found:  # what physics rules out comes before any comparison of errors
        checks = ", ".join(dict.fromkeys(str(x.get("check", "?")).replace("_", " ") for x in found))
        # its 1-s errors are then no evidence for it: said as such, not as a second, contrary finding
        errors = "; ".join(re.sub(f"^{re.escape(who)} ", "it ", x) for x in parts)
        parts = [f"{who} is physically impossible ({len(found)} plausibility finding{'s' * (len(found) > 1)}: "
                 f"{checks}; framed in red below), so its 1-s errors do not count for it ({errors})"]
    sentence = "; ".join(parts) + ". " + (f"It is {usable}" if usable else "")
    return word, sentence.strip()


def checked_and_not(validation: dict[str, Any], recovery: Mapping[str, Any] | None = None,
                    dataset_label: str = "the dataset's own bias") -> list[str]:
    """Plain sentences: what the validation checked, and what it did not (the IMU intrinsics: as
    ``recovery``, ``recovery.json``'s data, says the recovery ran; the DATASET source named ``dataset_label``)."""
    ref, cfg, dropped = (validation.get(k) if isinstance(validation.get(k), dict) else {}
                         for k in ("reference", "config", "windows_dropped"))
    kept = dropped.get("kept", "?")
    if ref.get("kind") == "state":
        against = "the sequence's ground-truth state (position, velocity, orientation)"
    else:
        against = f"the pose stream '{ref.get('stream', '?')}' (velocity from a smoothing spline of its positions)"
    independent = NOT_INDEPENDENT not in reason_codes(validation)
    baselines = sorted({str(s.get("kind")) for s in validation_sources(validation).values()}
                       & {"constant_first_window", "dataset"})
    return [
        f"Checked: {kept} integrations of {fmt(num(cfg, 'window_s') or 1.0, 3)} s of the IMU minus the bias, each "
        f"from and against {against}; end-point position and rotation errors (PRMSE, ROE) compared with "
        + " and ".join({"constant_first_window": "a constant bias", "dataset": dataset_label}[k]
                       for k in baselines) + ".",
        "Independent reference: " + ("yes." if independent else "no, the reference is what the bias was fitted "
                                                                  "to (pose errors absorbed by the bias are not seen)."),
        *plausibility_checked(validation),
        "Not checked: drift over spans longer than one window; errors the reference and the IMU share (e.g. a "
        f"wrong extrinsic used by both); {intrinsics_clause(recovery)}.",
    ]


def reason_codes(validation: Mapping[str, Any]) -> list[str]:
    """The rule code of each reason (``validation.json`` ``reason_codes``; "" where a file lacks one)."""
    codes = validation.get("reason_codes") if isinstance(validation.get("reason_codes"), list) else []
    reasons = validation.get("reasons") if isinstance(validation.get("reasons"), list) else []
    return [str(c) for c in codes] + [""] * (len(reasons) - len(codes))


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


def verdict_section(inp: ReportInputs) -> Html:
    word, sentence = verdict_summary(inp.validation, dataset_bias_label(inp.sequence))
    verdict = Verdict.parse(word)
    cls = _VERDICT_CLASS.get(verdict, "v-none")
    body = [Html(tag("span", word, class_="word") + esc(sentence))]
    if inp.validation is not None:
        reasons = [str(r) for r in inp.validation.get("reasons") or []]
        if reasons:
            body.append(p("Reasons (with the rule's code):"))
            body.append(ul([Html(esc(r) + (" " + tag("code", esc(c), class_="rule") if c else ""))
                            for r, c in zip(reasons, reason_codes(inp.validation))]))
        elif verdict is Verdict.PASS:
            body.append(p("No reason for concern was found in what was checked: the candidate is at least as good "
                          "as every baseline, few windows are flagged and few were dropped."))
        steps = [str(x) for x in inp.validation.get("next_steps") or [] if isinstance(x, str)]
        if steps:
            body.append(p("What to do next:"))
            body.append(ul(steps))
        body.append(p("What was checked:"))
        body.append(ul(checked_and_not(inp.validation, inp.recovery.data if inp.recovery is not None else None,
                                       dataset_bias_label(inp.sequence))))
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
    return section("verdict", TITLE["verdict"], tag("div", join(body), class_=f"verdict {cls}"))


# ----------------------------------------------------------------------------- section 2: streams


def _current_findings(seq: Sequence) -> list[Finding]:
    try:
        return run_checks(seq)
    except BiasgtError as exc:  # checks of a store should not fail; show it rather than crash
        return [Finding("CHECKS_FAILED", Severity.WARNING, "all", f"the input checks could not run: {exc}")]


#: How each pose source kind reads in the streams table (the enum's value says "vio" for any odometry).
SOURCE_KIND_WORDS = {"mocap": "motion capture, 6-DoF", "position_tracker": "position tracker",
                      "vio": "odometry (visual or wheel): drifts", "ground_truth": "ground truth"}


def streams_section(inp: ReportInputs) -> Html:
    seq = inp.sequence
    rows = []
    for s in stream_summaries(seq):
        words = SOURCE_KIND_WORDS.get(s.get("source_kind"), s.get("source_kind"))
        kind = s["kind"] if s.get("source_kind") in (None, s["kind"]) else f"{s['kind']} ({words})"
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
    return section("streams", TITLE["streams"], join(parts))
