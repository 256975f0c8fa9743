"""``biasgt inspect``: read an input, run the input checks, print streams, findings and a verdict.

Exit codes: 0 when nothing is fatal (verdict ``ok`` or ``repairable``), 1 when
a fatal problem was found (verdict ``fatal``), 2 for errors (unreadable input,
bad options).
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from pipeline.checks.options import CHECK_VERDICT_WORDS, check_verdict
from pipeline.checks.run import run_checks, stream_summaries, verdict
from biasgt.cli.commands._args import (
    add_check_arguments,
    add_reader_arguments,
    check_options_from_args,
    reader_kwargs_from_args,
)
from pipeline.errors import BiasgtError
from pipeline.ingest import load, severity_rank
from pipeline.io.registry import readers_in_words, recorded_format
from pipeline.files.jsonio import dumps, to_plain
from pipeline.types import Finding, Sequence, Severity, Verdict

#: Version of the ``--json`` output; bump when a key changes meaning or disappears.
SCHEMA_VERSION = 1
#: Top-level keys of the ``--json`` object.
JSON_KEYS = ("schema_version", "input", "format", "streams", "findings", "verdict")


def register(subparsers: argparse._SubParsersAction) -> None:

    p = subparsers.add_parser(
        "inspect",
        help="check an input (streams, time stamps, units, overlap) without writing anything",
        description=(
            f"Read INPUT ({readers_in_words()}; see --format), list its streams, "
            "and report every problem the input checks find, each with a stable code, a severity and how to fix it. "
            "Verdict: ok, repairable (biasgt convert --repair can fix it) or fatal. "
            "Exit code 0 = no fatal problem, 1 = fatal problem found, 2 = error."
        ),
    )
    p.add_argument("input", metavar="INPUT", help="file or folder to inspect")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object {schema_version, input, format, streams, findings, verdict}")
    add_reader_arguments(p)
    add_check_arguments(p, repairs=False)
    p.set_defaults(func=run)


def inspect_report(input_path: str, seq: Sequence, findings: list[Finding]) -> dict[str, Any]:
    """The ``--json`` object (keys :data:`JSON_KEYS`)."""
    return to_plain({
        "schema_version": SCHEMA_VERSION,
        "input": str(input_path),
        "format": recorded_format(seq.metadata, variant=True),
        "streams": stream_summaries(seq),
        "findings": [f.to_dict() for f in findings],
        "verdict": CHECK_VERDICT_WORDS[verdict(findings)],
    }, finite_only=True)




def _fmt(x: Any, spec: str) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


#: What the input checks' verdict means for 'biasgt convert'.
_MEANING = {Verdict.PASS: "can be converted as it is", Verdict.WARN: "'biasgt convert --repair ...' can fix it",
            Verdict.FAIL: "cannot be converted"}


def format_report(report: dict[str, Any]) -> str:
    """Human-readable text of an :func:`inspect_report` object."""
    lines = [f"input:  {report['input']}  (format: {report['format'] or 'unknown'})", ""]
    w = max([len("stream")] + [len(s["stream"]) for s in report["streams"]])
    header = (f"{'stream':<{w}} {'kind':<12} {'rows':>8} {'start [s]':>18} {'duration [s]':>12} "
              f"{'rate [Hz]':>10} {'dt std [ms]':>11} {'dt max [ms]':>11}")
    lines += [header, "-" * len(header)]
    for s in report["streams"]:
        t0 = None if s["t0_ns"] is None else s["t0_ns"] / 1e9
        lines.append(
            f"{s['stream']:<{w}} {s['kind']:<12} {s['count']:>8d} {_fmt(t0, '18.3f')} {_fmt(s['duration_s'], '12.3f')} "
            f"{_fmt(s['rate_hz'], '10.2f')} {_fmt(s['dt_std_ms'], '11.3f')} {_fmt(s['dt_max_ms'], '11.3f')}"
        )
    lines.append("")

    findings = sorted(report["findings"], key=lambda f: severity_rank(Severity(f["severity"])))
    if findings:
        lines.append("findings:")
        wc = max(len(f["code"]) for f in findings)
        ws = max(len(f["stream"]) for f in findings)
        for f in findings:
            lines.append(f"  {f['severity'].upper():<10} {f['code']:<{wc}} {f['stream']:<{ws}} {f['message']}")
    else:
        lines.append("findings: none")
    counts = {sev: sum(1 for f in findings if Severity(f["severity"]) is sev)
              for sev in (Severity.FATAL, Severity.REPAIRABLE, Severity.WARNING)}
    summary = ", ".join(f"{n} {sev.value}{'s' if sev is Severity.WARNING and n > 1 else ''}"
                        for sev, n in counts.items() if n) or "no problems"
    meaning = _MEANING[check_verdict(report["verdict"])]
    lines += ["", f"verdict: {report['verdict']} ({summary}): {meaning}"]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    options = check_options_from_args(args)
    try:
        seq = load(args.input, {**reader_kwargs_from_args(args), "all_pose_topics": True})
    except BiasgtError as exc:
        if args.json:  # --json always prints a JSON document
            print(dumps({"schema_version": SCHEMA_VERSION, "input": str(args.input), "verdict": "error", "error": {
                "type": type(exc).__name__, "message": str(exc), "path": exc.path, "line": exc.line,
                "field": exc.field, "hint": exc.hint}}), end="")
        raise
    findings = run_checks(seq, options)
    report = inspect_report(args.input, seq, findings)
    if args.json:
        print(dumps(report), end="")
    else:
        print(format_report(report))
    return 1 if check_verdict(report["verdict"]) is Verdict.FAIL else 0
