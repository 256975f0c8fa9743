"""Table I: per test sequence and on average, PRMSE (m) / ROE (deg) of every evaluated row.

In ``table.csv`` rows are the test sequences and ``Average`` (the mean over sequences, as in the
paper) and columns the evaluated methods and references; ``table.md`` (and the training report)
shows it transposed, one row per method and variant, grouped by method, and one column per
sequence, so that twenty rows still fit a page. A diffusion model gives one column per
sampler and aggregation (:class:`training.evaluation.outputs.Aggregation`): ``<method>`` is the
paper's figure (correct DDIM, metrics averaged over the K samples), ``<method> mean`` /
``median`` use the mean / median of the samples as the prediction, ``<method> released``
uses the released code's sampler. Columns follow the registries' order: the learned methods
(:mod:`training.networks`), then the reference rows (:mod:`training.references`). Summaries of one method from several training seeds are
combined: the cell is the mean over seeds, with the standard deviation over seeds.

Marks, as in the paper (bold best, underlined second): in ``table.md`` the best value of a
row is ``**bold**`` and the second best ``<u>underlined</u>``, separately for PRMSE and ROE,
among the columns that are usable methods: the oracle rows (recovered ground-truth bias,
random-walk oracle), which read the ground truth at test time, are shown but not ranked.

Files: ``table.csv`` (one row per sequence, two numeric columns per method: ``<column>
PRMSE_m``, ``<column> ROE_deg``, plus ``<column> seeds``) and ``table.md`` (the marked table
and a legend).

When test sequences are the paper's EuRoC test sequences (:func:`training.evaluation.paper.paper_sequence`),
``table.md`` also holds Table I **in the paper's shape** (:func:`format_paper_markdown`): methods
as rows; the paper's test sequences as columns (MH_02's cells "no IMU available") and their
Average over the sequences evaluated; below, the paper's published rows
(:mod:`training.evaluation.paper`) averaged over the same sequences; and a footnote stating the protocol
(gravity, the oracle's random walks, the evaluation reference, the sequences whose labels came
from ground-truth poses), read from the evaluation summaries.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from pipeline.files.atomic import write_text_atomic
from pipeline.errors import DataError
from training.networks import network_names
from training.references import get_reference, reference_names
from training.evaluation.paper import COMMON_SEQUENCES, MISSING_SEQUENCES, PAPER_ROWS, PAPER_SEQUENCES, SOURCE, TABLE_I, \
    paper_average, paper_sequence

if TYPE_CHECKING:  # the evaluation (and torch) is imported when a table is written, not with the paths
    from training.evaluation.outputs import EvaluationSummary

log = logging.getLogger(__name__)

__all__ = ["TableColumn", "build_table", "cell_marks", "format_markdown", "format_paper_markdown", "method_label",
           "protocol_notes", "table_columns", "write_table"]

TABLE_CSV = "table.csv"
TABLE_MD = "table.md"
AVERAGE = "Average"


@dataclass(frozen=True)
class TableColumn:
    """One column: a method's row (sampler, aggregation) over one or more seeds.

    Attributes:
        name: Column header.
        ranked: Takes part in best / second-best marks (not an oracle).
        prmse_m / roe_deg: Row name -> values over seeds.
        group: The method or reference (the row group of the transposed table).
        variant: The sampler and aggregation within the group ('' for the headline row).
    """

    name: str
    ranked: bool
    prmse_m: dict[str, list[float]]
    roe_deg: dict[str, list[float]]
    group: str = ""
    variant: str = ""

    @property
    def seeds(self) -> int:
        return max((len(v) for v in self.prmse_m.values()), default=0)


def _order(summary: EvaluationSummary) -> tuple[int, int]:
    names = [*network_names(), *reference_names()]
    return (names.index(summary.method) if summary.method in names else len(names), 0)


def table_columns(summaries: Iterable[EvaluationSummary]) -> list[TableColumn]:
    """Columns from evaluation summaries (same method = seeds of one column), in registry order (methods, then references)."""
    columns: dict[str, TableColumn] = {}
    for s in sorted(summaries, key=_order):
        for row in s.rows:
            name = f"{s.label} {row.key}".strip()
            col = columns.setdefault(name, TableColumn(name, s.kind != "oracle", {}, {}, s.label, row.key.strip()))
            for seq, m in [*row.sequences.items(), (AVERAGE, row.average)]:
                col.prmse_m.setdefault(seq, []).append(m.prmse_m)
                col.roe_deg.setdefault(seq, []).append(m.roe_deg)
    return list(columns.values())


def build_table(columns: list[TableColumn]) -> pd.DataFrame:
    """Numeric table: index = sequences + Average, columns ``<name> PRMSE_m``, ``<name> ROE_deg``, ``<name> seeds``.

    Raises:
        DataError: No column, or columns evaluated on different test sequences.
    """
    if not columns:
        raise DataError("no evaluation to tabulate", hint="run 'biasgt evaluate' for at least one method first")
    rows = [r for r in columns[0].prmse_m if r != AVERAGE]
    for c in columns[1:]:
        if sorted(r for r in c.prmse_m if r != AVERAGE) != sorted(rows):
            raise DataError(f"column '{c.name}' was evaluated on other test sequences than '{columns[0].name}'",
                            hint="evaluate every method on the same dataset")
    index = rows + [AVERAGE]
    data: dict[str, list[float]] = {}
    for c in columns:
        data[f"{c.name} PRMSE_m"] = [float(np.mean(c.prmse_m[r])) for r in index]
        data[f"{c.name} ROE_deg"] = [float(np.mean(c.roe_deg[r])) for r in index]
        data[f"{c.name} seeds"] = [len(c.prmse_m[r]) for r in index]
    return pd.DataFrame(data, index=pd.Index(index, name="sequence"))


def _cell(values: list[float], digits: int) -> str:
    """``mean ± std`` over the seeds, the std the sample standard deviation (ddof 1)."""
    text = f"{np.mean(values):.{digits}f}"
    return text + (f" ± {np.std(values, ddof=1):.{digits}f}" if len(values) > 1 else "")


def cell_marks(columns: list[TableColumn], row: str, metric: str) -> dict[str, str]:
    """Column name -> "best" / "second" for ``metric`` ("prmse_m" or "roe_deg") in ``row``, among ranked columns."""
    ranked = sorted((float(np.mean(getattr(c, metric)[row])), c.name) for c in columns if c.ranked)
    out = {}
    if ranked:
        out[ranked[0][1]] = "best"
    if len(ranked) > 1:
        out[ranked[1][1]] = "second"
    return out


def method_label(column: TableColumn) -> str:
    """A row's method cell: the group, marked as an oracle where it is not ranked."""
    group = column.group or column.name
    return group + (" (oracle)" if not column.ranked and "oracle" not in group.lower() else "")


def format_markdown(columns: list[TableColumn], title: str = "Table I") -> str:
    """The marked Markdown table, one row per method and variant (see the module docstring)."""
    table = build_table(columns)
    wrap = {"best": "**{}**", "second": "<u>{}</u>", None: "{}"}
    marks = {seq: (cell_marks(columns, seq, "prmse_m"), cell_marks(columns, seq, "roe_deg")) for seq in table.index}
    lines = [f"### {title}: PRMSE (m) / ROE (deg) on 1-s test windows", "",
             "| method | variant | " + " | ".join(f"**{s}**" if s == AVERAGE else s for s in table.index) + " |",
             "|---|---|" + "---|" * len(table.index)]
    previous = None
    for c in columns:
        cells = [wrap[marks[seq][0].get(c.name)].format(_cell(c.prmse_m[seq], 4)) + " / "
                 + wrap[marks[seq][1].get(c.name)].format(_cell(c.roe_deg[seq], 4)) for seq in table.index]
        group = method_label(c) if c.group != previous else ""
        previous = c.group
        lines.append(f"| {group} | {c.variant} | " + " | ".join(cells) + " |")
    seeds = max(c.seeds for c in columns)
    lines += ["", "Best **bold**, second best <u>underlined</u> per sequence among usable methods (oracle rows use "
                  "the ground truth at test time and are not ranked). Average = mean over test sequences. A "
                  "diffusion model's first row averages each metric over its K samples (the paper); 'mean' / "
                  "'median' use the sample mean / median as the prediction; 'released' uses the released code's "
                  "sampler." + (f" Learned rows: mean ± std over {seeds} training seeds." if seeds > 1 else "")]
    return "\n".join(lines) + "\n"


#: Raw pose streams of EuRoC: labels recovered from another stream came from ground-truth poses.
RAW_POSE_STREAMS = ("vicon0", "leica0")


def _gravity_note(sources: set[str]) -> str:
    if sources == {"nominal"}:
        return "Gravity: nominal (0, 0, -9.81) m/s^2 in the reference world frame, as the paper (AirIMU's protocol)."
    if sources <= {"recovery", "default"}:
        return "Gravity: each sequence's recovered gravity (nominal where none was recovered); not the paper's."
    return f"Gravity: mixed across rows ({', '.join(sorted(sources))})."


def protocol_notes(summaries: Iterable[EvaluationSummary]) -> list[str]:
    """Footnote lines stating the protocol of the evaluations (see the module docstring)."""
    summaries = list(summaries)
    notes = [_gravity_note({g for s in summaries for g in s.gravity_source.values()})]
    present = {s.method for s in summaries}
    for name in reference_names():
        note = get_reference(name).footnote(summaries) if name in present else None
        if note:
            notes.append(note)
    refs = {k: v for s in summaries for k, v in s.dataset.get("reference", {}).items() if v}
    if refs:
        notes.append("Evaluation reference (window start and end states): "
                     + ", ".join(f"{k} {v}" for k, v in sorted(refs.items())) + " (state = the dataset's "
                     "ground-truth state).")
    streams = {k: v for s in summaries for k, v in s.dataset.get("label_pose_stream", {}).items() if v}
    if streams:
        by: dict[str, list[str]] = {}
        for seq, stream in sorted(streams.items()):
            by.setdefault(stream, []).append(seq)
        notes.append("Labels (biasgt's recovered bias) fitted to the pose stream: "
                     + "; ".join(f"{stream}: {', '.join(seqs)}" for stream, seqs in by.items())
                     + (". Where not a raw stream (" + "/".join(RAW_POSE_STREAMS) + "), the sequence has none or "
                        "its raw-stream recovery does not yet meet the recovery goals (ground_truth, "
                        "groundtruth_poses: EuRoC's ground-truth poses)."
                        if set(by) - set(RAW_POSE_STREAMS) else "."))
    excluded = {k: str(v).split(":")[0] for s in summaries for k, v in s.dataset.get("excluded", {}).items()}
    if excluded:
        notes.append("Left out of the window dataset: " + ", ".join(f"{k} ({v})" for k, v in sorted(excluded.items()))
                     + "; the dataset manifest's 'excluded' says why.")
    return notes


def _paper_cell(values: tuple[float, float]) -> str:
    return f"{values[0]:.4f} / {values[1]:.4f}"


def format_paper_markdown(columns: list[TableColumn], notes: Iterable[str] = ()) -> str | None:
    """Table I in the paper's shape with the paper's block (see the module docstring); None when no
    test sequence is one of the paper's."""
    short = {r: paper_sequence(r) for r in columns[0].prmse_m if r != AVERAGE} if columns else {}
    ours = {p: r for r, p in short.items() if p in PAPER_SEQUENCES}
    if not ours:
        return None
    shared = [p for p in COMMON_SEQUENCES if p in ours]
    wrap = {"best": "**{}**", "second": "<u>{}</u>", None: "{}"}
    lines = ["### Table I in the paper's shape: PRMSE (m) / ROE (deg) on 1-s test windows", "",
             "| method | " + " | ".join(PAPER_SEQUENCES) + f" | Average ({', '.join(shared)}) |",
             "|---|" + "---|" * (len(PAPER_SEQUENCES) + 1)]
    marks = {r: (cell_marks(columns, r, "prmse_m"), cell_marks(columns, r, "roe_deg")) for r in [*ours.values(),
                                                                                                  AVERAGE]}
    for c in columns:
        cells = []
        for row in [*(ours.get(p) for p in PAPER_SEQUENCES), AVERAGE]:
            if row is None:
                cells.append("")
                continue
            mp, mr = marks[row]
            cells.append(wrap[mp.get(c.name)].format(_cell(c.prmse_m[row], 4)) + " / "
                         + wrap[mr.get(c.name)].format(_cell(c.roe_deg[row], 4)))
        cells = [MISSING_SEQUENCES.get(p, cell) if p not in ours else cell
                 for p, cell in zip([*PAPER_SEQUENCES, None], cells)]
        oracle = "" if c.ranked or "oracle" in c.name.lower() else " (oracle)"
        lines.append(f"| {c.name}{oracle} | " + " | ".join(cells) + " |")
    lines.append("| *paper (published)* |" + " |" * (len(PAPER_SEQUENCES) + 1))
    for name in PAPER_ROWS:
        cells = [_paper_cell(TABLE_I[name][p]) for p in PAPER_SEQUENCES] + [_paper_cell(paper_average(name, shared))]
        lines.append(f"| paper: {name} | " + " | ".join(cells) + " |")
    seeds = max(c.seeds for c in columns)
    foot = [f"Average: the mean over {', '.join(shared)} for every row, the paper's included (its own "
            f"Average also covers {', '.join(p for p in PAPER_SEQUENCES if p not in shared)}).",
            *(f"{p}: {why} (a test sequence of the paper; left out, not replaced)."
              for p, why in MISSING_SEQUENCES.items() if p not in ours),
            "Best **bold**, second <u>underlined</u> among usable methods (oracle rows read the ground truth at "
            "test time and are not ranked)." + (f" Learned rows: mean ± std over {seeds} training seeds."
                                                 if seeds > 1 else ""),
            *notes,
            f"Paper rows: {SOURCE}, as printed (Random Walk: its random-walk baseline; AirIMU: as the paper "
            "reports it)."]
    return "\n".join(lines + [""] + [f"- {n}" for n in foot]) + "\n"


def write_table(summary_paths: Iterable[str | Path], out_dir: str | Path) -> pd.DataFrame:
    """Read evaluation summaries and write ``table.csv`` and ``table.md`` into ``out_dir`` (atomically each).

    Returns:
        The numeric table (see :func:`build_table`).
    """
    from training.evaluation.outputs import read_summary

    summaries = [read_summary(p) for p in summary_paths]
    columns = table_columns(summaries)
    table = build_table(columns)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paper = format_paper_markdown(columns, protocol_notes(summaries))
    write_text_atomic(out_dir / TABLE_CSV, table.to_csv(float_format="%.6g"))
    write_text_atomic(out_dir / TABLE_MD, format_markdown(columns) + ("" if paper is None else "\n" + paper))
    return table
