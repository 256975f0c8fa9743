"""What ``biasgt run`` says at the end: a dry run's plan in one line, and a finished run's results.

:func:`dry_run_summary` reads Snakemake's dry-run printout (one block per job: ``rule NAME:`` and
its ``reason:``) and says, per rule, how many jobs would run and why. The learning stages depend
on the window dataset's content (its checksum), read once the ``windows`` checkpoint has written
it: when ``windows`` is planned, the jobs after it are planned by Snakemake but run only if the
content changes, and the line says so.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

from pipeline.layout import Stage, dataset_report_path
from pipeline.types import Verdict
from biasgt.workflow.run import JOB_HEADER

#: Rules that depend on the window dataset through its checksum (directly or through evaluations).
DATASET_CONTENT_RULES = ("train", "evaluate", "evaluate_reference", "table", "training_report")

_REASON = re.compile(r"^\s*reason:\s*(.+)$")
#: Snakemake's reason phrases -> short words, in the order they are listed.
_REASONS = (
    ("Missing output files", "new"),
    ("Params have changed", "parameters changed"),
    ("Code has changed", "code changed"),
    ("Set of input files has changed", "inputs changed"),
    ("Updated input files", "newer input"),
    ("Input files updated by another job", "after an upstream job"),
    ("Forced execution", "forced"),
    ("Software environment", "environment changed"),
)


def _reason_words(text: str) -> list[str]:
    return [word for phrase, word in _REASONS if phrase in text] or ["other"]


def dry_run_jobs(text: str) -> list[tuple[str, list[str]]]:
    """``(rule, reasons)`` of every job of a dry-run printout (the target rule ``all`` left out)."""
    jobs: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        head = JOB_HEADER.match(line)
        if head:
            jobs.append((head.group(1), []))
            continue
        reason = _REASON.match(line)
        if reason and jobs and not jobs[-1][1]:
            jobs[-1][1].extend(_reason_words(reason.group(1)))
    return [(rule, reasons or ["other"]) for rule, reasons in jobs if rule != "all"]


def _per_rule(jobs: list[tuple[str, list[str]]]) -> tuple[Counter, dict[str, Counter]]:
    """Jobs per rule, and the reasons per rule."""
    why: dict[str, Counter] = {}
    for rule, reasons in jobs:
        why.setdefault(rule, Counter()).update(reasons)
    return Counter(rule for rule, _ in jobs), why


def _rules_text(jobs: list[tuple[str, list[str]]]) -> str:
    """``"train 5 (parameters changed); evaluate 12 (after an upstream job)"``."""
    counts, why = _per_rule(jobs)
    return "; ".join(f"{rule} {n} ({', '.join(w for w, _ in why[rule].most_common())})" for rule, n in counts.items())


def dry_run_summary(text: str) -> str:
    """One line: how many jobs would run, per rule with why (see the module docstring)."""
    jobs = dry_run_jobs(text)
    if not jobs:
        return "dry run: nothing to do, every output is up to date"
    counts, why = _per_rule(jobs)
    line = f"dry run: {len(jobs)} jobs would run: " + _rules_text(jobs)
    conditional = [r for r in DATASET_CONTENT_RULES if r in counts
                   and set(why[r]) <= {"after an upstream job", "inputs changed"}]
    if "windows" in counts and conditional:
        line += (f"; of these, {', '.join(conditional)} run only if the window dataset's content changes "
                 "(they depend on its checksum)")
    return line


#: Table I names that read the ground truth at test time (not ranked in the headline).
_ORACLES = ("oracle", "Recovered GT bias")
_REASON_CHARS = 110


def _short(text: str, n: int = _REASON_CHARS) -> str:
    return text if len(text) <= n else text[:n - 1].rstrip() + "…"


def _verdict_lines(results: Path) -> list[str]:
    lines = []
    for path in sorted((results / Stage.VALIDATE.folder).glob("*/validation.json")):
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        reasons = data.get("reasons") or []
        why = f": {_short(str(reasons[0]))}" if reasons and Verdict.parse(data.get("verdict")) is not Verdict.PASS else ""
        lines.append(f"  {path.parent.name}: {data.get('verdict', '?')}{why}")
    return lines


def _windows_line(results: Path) -> str | None:
    manifest = results / Stage.WINDOWS.folder / "dataset" / "manifest.json"
    if not manifest.is_file():
        return None
    data = json.loads(manifest.read_text(encoding="utf-8"))
    splits = Counter(s.get("split") for s in (data.get("sequences") or {}).values())
    entered = ", ".join(f"{k} {v}" for k, v in sorted(splits.items()))
    excluded = data.get("excluded") or {}
    left = f"; left out: {', '.join(excluded)}" if excluded else "; none left out"
    return f"  windows: {sum(splits.values())} sequences in the dataset ({entered}){left}"


def table_out_of_date(config_file: str | Path | None, workdir: str | Path) -> str | None:
    """Why Table I (``results/evaluation/table.csv``) is out of date, e.g. "train 5 (parameters changed)",
    or None when it is up to date or absent: Snakemake's dry run of the ``table`` rule under ``config_file``
    lists the jobs it would rerun (after a run stopped short of it: ``--until``, ``--target``)."""
    import subprocess

    from biasgt.workflow.config import DEFAULT_CONFIG
    from biasgt.workflow.run import snakemake_command

    if not (Path(workdir) / "results" / "evaluation" / "table.csv").is_file():
        return None
    cmd = snakemake_command(config_file=Path(config_file or DEFAULT_CONFIG), workdir=workdir, dry_run=True,
                            targets=["table"])
    done = subprocess.run(cmd, capture_output=True, text=True, errors="replace")
    if done.returncode != 0:
        return "its inputs could not be checked (snakemake --dry-run failed)"
    plan = done.stdout + done.stderr
    jobs = dry_run_jobs(plan)
    if not jobs:
        return None
    return _rules_text(jobs)


def _table_line(results: Path, stale: str | None = None) -> str | None:
    table = results / "evaluation" / "table.csv"
    if not table.is_file():
        return None
    import pandas as pd

    frame = pd.read_csv(table, index_col=0)
    if "Average" not in frame.index:
        return None
    avg = frame.loc["Average"]
    ranked = {c[:-len(" PRMSE_m")]: float(avg[c]) for c in frame.columns
              if c.endswith(" PRMSE_m") and not any(o in c for o in _ORACLES)}
    if not ranked:
        return None
    best = min(ranked, key=ranked.get)
    roe = float(avg[f"{best} ROE_deg"])
    if stale is not None:
        return (f"  Table I: OUT OF DATE, not shown: the config changed what it is made of ({stale} would rerun); "
                "'biasgt run' without --until/--target brings it up to date")
    return (f"  Table I: best average {best}: PRMSE {ranked[best]:.4f} m, ROE {roe:.4f} deg "
            f"({len(ranked)} usable rows; results/evaluation/table.md)")


def finished_summary(workdir: str | Path, table_stale: str | None = None) -> list[str]:
    """The end of ``biasgt run``: the verdict per sequence (with the first reason of a WARN or FAIL), what
    entered the window dataset, Table I's headline and where the reports are; [] when nothing ran.

    With ``table_stale`` (:func:`table_out_of_date`), Table I's headline is replaced by a line saying it is
    out of date and why."""
    results = Path(workdir) / "results"
    lines = _verdict_lines(results)
    for extra in (_windows_line(results), _table_line(results, table_stale)):
        if extra:
            lines.append(extra)
    reports = sorted((results / "report").glob("*/report.html"))
    if reports:
        lines.append(f"  quality reports: results/report/<sequence>/report.html ({len(reports)})")
    if (results.parent / dataset_report_path()).is_file():
        lines.append(f"  dataset page: {dataset_report_path()}")
    if (results / "report" / "training.html").is_file():
        lines.append("  training report: results/report/training.html")
    return ["summary:", *lines] if lines else []
