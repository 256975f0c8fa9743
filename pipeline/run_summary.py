"""What ``biasgt run`` says at the end: a dry run's plan in one line, and a finished run's results.

:func:`dry_run_summary` reads Snakemake's dry-run printout (one block per job: ``rule NAME:`` and
its ``reason:``) and says, per rule, how many jobs would run and why. The learning stages depend
on the window dataset's content (its checksum), read once the ``windows`` checkpoint has written
it: when ``windows`` is planned, the jobs after it are planned by Snakemake but run only if the
content changes, and the line says so.
"""

from __future__ import annotations

import re
from collections import Counter

from pipeline.workflow import _JOB_HEADER

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
        head = _JOB_HEADER.match(line)
        if head:
            jobs.append((head.group(1), []))
            continue
        reason = _REASON.match(line)
        if reason and jobs and not jobs[-1][1]:
            jobs[-1][1].extend(_reason_words(reason.group(1)))
    return [(rule, reasons or ["other"]) for rule, reasons in jobs if rule != "all"]


def dry_run_summary(text: str) -> str:
    """One line: how many jobs would run, per rule with why (see the module docstring)."""
    jobs = dry_run_jobs(text)
    if not jobs:
        return "dry run: nothing to do, every output is up to date"
    counts = Counter(rule for rule, _ in jobs)
    why: dict[str, Counter] = {}
    for rule, reasons in jobs:
        why.setdefault(rule, Counter()).update(reasons)
    parts = [f"{rule} {n} ({', '.join(w for w, _ in why[rule].most_common())})" for rule, n in counts.items()]
    line = f"dry run: {len(jobs)} jobs would run: " + "; ".join(parts)
    conditional = [r for r in DATASET_CONTENT_RULES if r in counts
                   and set(why[r]) <= {"after an upstream job", "inputs changed"}]
    if "windows" in counts and conditional:
        line += (f"; of these, {', '.join(conditional)} run only if the window dataset's content changes "
                 "(they depend on its checksum)")
    return line
