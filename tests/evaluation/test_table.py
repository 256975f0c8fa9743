"""Table I from evaluation summaries: values, seeds, best / second-best marks."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pandas as pd
import pytest

from pipeline.errors import DataError
from training.references import get_reference
from training.evaluation.evaluate import evaluate_reference
from training.evaluation.outputs import Metrics, read_summary
from training.evaluation.table import AVERAGE, TABLE_CSV, TABLE_MD, table_columns, write_table
from window_data import make_window_dataset

#: The rows this dataset can evaluate, in their registration (Table I) order.
ROWS = ("zero", "train_mean", "state_bias", "ground_truth", "random_walk_oracle", "random_walk_paper")


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("table")
    data = make_window_dataset(root, splits={"train": 1, "test": 2}, duration_s=5.0)
    for b in ROWS:
        evaluate_reference(b, data, root / "evaluation" / b)
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
    assert table.shape == (3, 3 * len(ROWS))
    md = (evaluated / TABLE_MD).read_text()
    lines = [line for line in md.splitlines() if line.startswith("| ")]
    assert [c.strip() for c in lines[0].split("|")[1:-1]] == ["method", "variant", "test0", "test1", "**Average**"]
    # one row per method; the Average column is the last
    cells = [[c.strip() for c in line.split("|")[1:-1]][-1] for line in lines[1:]]
    # ranked: zero and train mean only (the GT bias and the random-walk oracle are oracles)
    z, m = (table.loc[AVERAGE, f"{get_reference(b).label} PRMSE_m"] for b in ("zero", "train_mean"))
    order = [p.parent.name for p in paths]
    by = dict(zip(sorted(order, key=ROWS.index), cells))
    best, second = ("zero", "train_mean") if z < m else ("train_mean", "zero")
    assert by[best].startswith("**") and by[second].startswith("<u>")
    assert "**" not in by["ground_truth"] and "<u>" not in by["ground_truth"]


def test_seeds_give_mean_and_std(evaluated, tmp_path):
    s = read_summary(evaluated / "zero")
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
    assert f"{2 * a:.4f} ± {2 ** 0.5 * a:.4f}" in md  # mean of (a, 3a) and the sample std (ddof 1)
    with pytest.raises(DataError, match="no evaluation"):
        write_table([], tmp_path / "empty")


def test_twenty_rows_with_their_variants_fit_a_page() -> None:
    """Methods are rows, grouped with their sampler / aggregation variants; sequences are the columns."""
    from training.evaluation.table import TableColumn, format_markdown

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


EUROC = {"test0": "MH_04_difficult", "test1": "V1_03_difficult"}


def _as_euroc(s, extra: str = "V2_02_medium"):
    """The summary with its test sequences renamed to the paper's EuRoC test sequences (test1 doubling as
    ``extra``), the Average recomputed over the three."""
    import numpy as np

    rows = []
    for r in s.rows:
        seqs = {EUROC[k]: v for k, v in r.sequences.items()}
        seqs[extra] = r.sequences["test1"]
        avg = Metrics(float(np.mean([m.prmse_m for m in seqs.values()])),
                      float(np.mean([m.roe_deg for m in seqs.values()])))
        rows.append(dataclasses.replace(r, sequences=seqs, average=avg))
    return dataclasses.replace(s, rows=tuple(rows), dataset={**s.dataset, "excluded": {
        "MH_03_medium": "validation FAIL: held out: worse than the constant bias"}, "label_pose_stream": {
        "MH_04_difficult": "ground_truth", "V1_03_difficult": "ground_truth", "V2_02_medium": "ground_truth",
        "V2_01_easy": "vicon0"}})


def test_paper_shape_with_the_papers_block_and_protocol_footnote(evaluated, tmp_path):
    paths = []
    for p in sorted(evaluated.glob("*/summary.json")):
        out = tmp_path / p.parent.name / "summary.json"
        out.parent.mkdir()
        out.write_text(json.dumps(_as_euroc(read_summary(p)).to_dict()))
        paths.append(out)
    write_table(paths, tmp_path)
    md = (tmp_path / TABLE_MD).read_text()
    paper = md[md.index("### Table I in the paper's shape"):]
    lines = paper.splitlines()
    assert lines[2] == "| method | MH_02 | MH_04 | V1_03 | V2_02 | Average (MH_04, V1_03, V2_02) |"
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in lines[4:]
            if line.startswith("| ")}
    zero = read_summary(tmp_path / "zero" / "summary.json")
    cells = rows[get_reference("zero").label]
    assert cells[0] == "no IMU available"
    for cell, seq in zip(cells[1:], ["MH_04_difficult", "V1_03_difficult", "V2_02_medium"]):
        m = zero.row().sequences[seq]
        assert cell.strip("*<u>/ ").replace("*", "").replace("<u>", "").replace("</u>", "") == \
            f"{m.prmse_m:.4f} / {m.roe_deg:.4f}"
    assert f"{zero.row().average.prmse_m:.4f}" in cells[4]
    assert rows[get_reference("random_walk_oracle").label][0] == "no IMU available"
    assert rows[get_reference("ground_truth").label + " (oracle)"][0] == "no IMU available"
    # rows: zero, train mean, the dataset's own bias, the recovered bias, the random-walk oracle
    names = [n for n in rows if "paper" not in n]
    assert names == [get_reference("zero").label, get_reference("train_mean").label, get_reference("state_bias").label + " (oracle)",
                     get_reference("ground_truth").label + " (oracle)", get_reference("random_walk_oracle").label]
    # the paper's block: printed values, averages over the same three sequences
    assert rows["paper: Ours (RNN)"] == ["0.0225 / 0.0604", "0.0410 / 0.0636", "0.0561 / 0.1931", "0.0703 / 0.2557",
                                         "0.0558 / 0.1708"]
    assert rows["paper: Random Walk"][-1] == "0.0718 / 0.1684"
    assert {"paper: AirIMU", "paper: Ours (UNet)", "paper: Direct Regression (RNN)",
            "paper: Direct Regression (UNet)"} <= set(rows)
    # the footnote states the protocol the evaluations used
    assert "MH_02: no IMU available" in paper
    assert "Gravity: each sequence's recovered gravity" in paper  # the evaluations above used the default
    assert "ground_truth: MH_04_difficult, V1_03_difficult, V2_02_medium; vicon0: V2_01_easy." in paper
    assert "does not yet meet the recovery goals" in paper
    assert "Left out of the window dataset: MH_03_medium (validation FAIL)" in paper


def test_no_paper_block_for_other_sequences(evaluated, tmp_path):
    write_table(sorted(evaluated.glob("*/summary.json")), tmp_path)
    assert "paper's shape" not in (tmp_path / TABLE_MD).read_text()
