"""Table I from evaluation summaries: values, seeds, best / second-best marks."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pandas as pd
import pytest

from pipeline.errors import DataError
from training.baselines import Baseline
from training.evaluate import Metrics, evaluate_reference, read_summary
from training.table import AVERAGE, TABLE_CSV, TABLE_MD, table_columns, write_table
from window_data import make_window_dataset


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("table")
    data = make_window_dataset(root, splits={"train": 1, "test": 2}, duration_s=5.0)
    for b in Baseline:
        evaluate_reference(b, data, root / "evaluation" / b.value)
    return root / "evaluation"


def test_table_values_and_marks(evaluated):
    paths = sorted(evaluated.glob("*/summary.json"))
    table = write_table(paths, evaluated)
    csv = pd.read_csv(evaluated / TABLE_CSV, index_col=0)
    assert list(csv.index) == ["test0", "test1", AVERAGE]
    for p in paths:
        s = read_summary(p)
        row = s.row()
        assert csv.loc[AVERAGE, f"{s.label} PRMSE_m"] == pytest.approx(row.average.prmse_m, rel=1e-5)
        assert csv.loc["test1", f"{s.label} ROE_deg"] == pytest.approx(row.sequences["test1"].roe_deg, rel=1e-5)
    assert table.shape == (3, 3 * len(Baseline))
    md = (evaluated / TABLE_MD).read_text()
    lines = [line for line in md.splitlines() if line.startswith("| ")]
    assert [c.strip() for c in lines[0].split("|")[1:-1]] == ["method", "variant", "test0", "test1", "**Average**"]
    # one row per method; the Average column is the last
    cells = [[c.strip() for c in line.split("|")[1:-1]][-1] for line in lines[1:]]
    # ranked: zero and train mean only (the GT bias and the random-walk oracle are oracles)
    z, m = (table.loc[AVERAGE, f"{b.label} PRMSE_m"] for b in (Baseline.ZERO, Baseline.TRAIN_MEAN))
    order = [Baseline(p.parent.name) for p in paths]
    by = dict(zip(sorted(order, key=lambda b: list(Baseline).index(b)), cells))
    best, second = (Baseline.ZERO, Baseline.TRAIN_MEAN) if z < m else (Baseline.TRAIN_MEAN, Baseline.ZERO)
    assert by[best].startswith("**") and by[second].startswith("<u>")
    assert "**" not in by[Baseline.GROUND_TRUTH] and "<u>" not in by[Baseline.GROUND_TRUTH]


def test_seeds_give_mean_and_std(evaluated, tmp_path):
    s = read_summary(evaluated / Baseline.ZERO.value)
    paths = []
    for i, scale in enumerate((1.0, 3.0)):
        rows = tuple(dataclasses.replace(r, average=Metrics(r.average.prmse_m * scale, r.average.roe_deg * scale),
                                         sequences={k: Metrics(v.prmse_m * scale, v.roe_deg * scale)
                                                    for k, v in r.sequences.items()}) for r in s.rows)
        p = tmp_path / f"seed{i}" / "summary.json"
        p.parent.mkdir()
        p.write_text(json.dumps(dataclasses.replace(s, rows=rows).to_dict()))
        paths.append(p)
    cols = table_columns(read_summary(p) for p in paths)
    assert len(cols) == 1 and cols[0].seeds == 2
    write_table(paths, tmp_path)
    md = (tmp_path / TABLE_MD).read_text()
    a = s.row().average.prmse_m
    assert f"{2 * a:.4f} ± {a:.4f}" in md  # mean of (a, 3a) and population std
    with pytest.raises(DataError, match="no evaluation"):
        write_table([], tmp_path / "empty")


def test_twenty_rows_with_their_variants_fit_a_page() -> None:
    """Methods are rows, grouped with their sampler / aggregation variants; sequences are the columns."""
    from training.table import TableColumn, format_markdown

    seqs = ["MH_02_easy", "V1_03_difficult", "V2_02_medium"]
    columns = []
    for method in ("diffusion_rnn", "diffusion_unet", "regression_rnn", "regression_unet", "indirect_rnn"):
        variants = ["", "mean", "median", "released", "released mean"] if "diffusion" in method else [""]
        for v in variants:
            values = {s: [0.123456] for s in [*seqs, AVERAGE]}
            columns.append(TableColumn(f"{method} {v}".strip(), True, values, dict(values), method, v))
    while len(columns) < 20:
        values = {s: [1.0] for s in [*seqs, AVERAGE]}
        columns.append(TableColumn(f"ref{len(columns)}", False, values, dict(values), f"ref{len(columns)}", ""))
    md = format_markdown(columns)
    rows = [line for line in md.splitlines() if line.startswith("| ")]
    assert len(rows) == 21 and all(len(r.split("|")) == len(seqs) + 5 for r in rows)
    assert max(len(r) for r in rows) <= 140  # ~8 px a character at the report's font: well inside 1280 px
    assert [r.split("|")[1].strip() for r in rows[1:6]] == ["diffusion_rnn", "", "", "", ""]  # grouped
