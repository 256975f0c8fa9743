"""Table I: per test sequence and on average, PRMSE (m) / ROE (deg) of every evaluated row.

In ``table.csv`` rows are the test sequences and ``Average`` (the mean over sequences, as in the
paper) and columns the evaluated methods and references; ``table.md`` (and the training report)
shows it transposed, one row per method and variant, grouped by method, and one column per
sequence, so that twenty rows still fit a page. A diffusion model gives one column per
sampler and aggregation (:class:`training.evaluate.Aggregation`): ``diffusion_rnn`` is the
paper's figure (correct DDIM, metrics averaged over the K samples), ``diffusion_rnn mean`` /
``median`` use the mean / median of the samples as the prediction, ``diffusion_rnn released``
uses the released code's sampler. Summaries of one method from several training seeds are
combined: the cell is the mean over seeds, with the standard deviation over seeds.

Marks, as in the paper (bold best, underlined second): in ``table.md`` the best value of a
row is ``**bold**`` and the second best ``<u>underlined</u>``, separately for PRMSE and ROE,
among the columns that are usable methods: the oracle rows (recovered ground-truth bias,
random-walk oracle), which read the ground truth at test time, are shown but not ranked.

Files: ``table.csv`` (one row per sequence, two numeric columns per method: ``<column>
PRMSE_m``, ``<column> ROE_deg``, plus ``<column> seeds``) and ``table.md`` (the marked table
and a legend).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from pipeline.atomic import write_text_atomic
from pipeline.errors import DataError
from training.config import Baseline
from training.config import Method

if TYPE_CHECKING:  # the evaluation (and torch) is imported when a table is written, not with the paths
    from training.evaluate import EvaluationSummary

log = logging.getLogger(__name__)

__all__ = ["TableColumn", "build_table", "cell_marks", "format_markdown", "method_label", "table_columns", "write_table"]

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
    names = [m.value for m in Method] + [b.value for b in Baseline]
    return (names.index(summary.method) if summary.method in names else len(names), 0)


def table_columns(summaries: Iterable[EvaluationSummary]) -> list[TableColumn]:
    """Columns from evaluation summaries (same method = seeds of one column), in Method then Baseline order."""
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
    text = f"{np.mean(values):.{digits}f}"
    return text + (f" ± {np.std(values):.{digits}f}" if len(values) > 1 else "")


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


def write_table(summary_paths: Iterable[str | Path], out_dir: str | Path) -> pd.DataFrame:
    """Read evaluation summaries and write ``table.csv`` and ``table.md`` into ``out_dir`` (atomically each).

    Returns:
        The numeric table (see :func:`build_table`).
    """
    from training.evaluate import read_summary

    columns = table_columns(read_summary(p) for p in summary_paths)
    table = build_table(columns)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_dir / TABLE_CSV, table.to_csv(float_format="%.6g"))
    write_text_atomic(out_dir / TABLE_MD, format_markdown(columns))
    return table
