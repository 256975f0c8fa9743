"""``python -m biasgt.results_doc`` on a small run: the page's tables equal the run's own Table I
(``table.md``) and its evaluation summaries, read here without the script's code; a hand edit is caught."""

from __future__ import annotations

import json
import re
import shutil
import statistics
from pathlib import Path

import pytest

from biasgt.results_doc import main
from biasgt.workflow.learning import evaluate_step, table_step
from biasgt.workflow.steps import run_step
from training.config import TrainingPlan
from window_data import TINY_PLAN, make_window_dataset

METHOD = "regression_rnn"
REFERENCES = ("zero", "train_mean", "ground_truth")
PAGE = """# Results

<!-- run small: biasgt run --config small.yaml | 2000-01-01 | 0000000 -->

Prose stays.

<!-- generated: table1 from small (results/evaluation) -->
<!-- end generated -->

<!-- generated: seeds regression_rnn from small (results/evaluation) -->
<!-- end generated -->

<!-- generated: summary train_mean from small (results/evaluation) -->
<!-- end generated -->

More prose.
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A run's folder as the workflow leaves it: results/evaluation (two seeds of one network, three
    reference rows, Table I) and logs/table/table.log."""
    from biasgt.workflow.learning import train_step

    root = tmp_path_factory.mktemp("run")
    data = make_window_dataset(root / "work", splits={"train": 1, "val": 1, "test": 2}, duration_s=5.0)
    plan = TrainingPlan.from_mapping({**TINY_PLAN, "methods": [METHOD]})
    evaluation = root / "results" / "evaluation"
    folders = []
    for seed in (0, 1):
        trained = train_step(data, root / "results" / "training" / METHOD / f"seed{seed}",
                             plan.run_settings(METHOD, seed), threads=1)
        folders.append(evaluate_step(data, evaluation / METHOD / f"seed{seed}", {"samples": 1},
                                     run_dir=trained, method=METHOD))
    folders += [evaluate_step(data, evaluation / ref, {"samples": 1}, reference=ref) for ref in REFERENCES]
    run_step(root / "logs" / "table" / "table.log", table_step, folders, evaluation)
    return root


def _tables(text: str) -> dict[str, list[list[str]]]:
    """Block kind (and argument) -> the rows of its table (header first), cells stripped."""
    out = {}
    for m in re.finditer(r"<!-- generated: (\w+(?: \S+)?) from small .*?-->\n(.*?)<!-- end generated -->", text, re.S):
        rows = [line for line in m.group(2).splitlines() if line.startswith("| ") and not line.startswith("|---")]
        out[m.group(1)] = [[c.strip() for c in r.strip("|").split("|")] for r in rows]
    return out


def _table_md(run: Path) -> list[tuple[str, list[str]]]:
    """table.md's rows: (method label, PRMSE / ROE cells without marks and without the spread)."""
    lines = (run / "results" / "evaluation" / "table.md").read_text().split("\n\n")[1].splitlines()[2:]
    rows, group = [], ""
    for line in lines:
        cells = [c.strip() for c in line.strip("|").split("|")]
        group = cells[0] or group
        figures = [re.sub(r"\*\*|</?u>| ± [0-9.]+", "", c) for c in cells[2:]]
        rows.append(((group + " " + cells[1]).strip(), figures))
    return rows


def _summary(run: Path, folder: str) -> dict:
    return json.loads((run / "results" / "evaluation" / folder / "summary.json").read_text())


def _write(page: Path, run: Path, *extra: str) -> int:
    return main(["--write", "--run", f"small={run}", "--commit", "small=abc1234", "--page", str(page), *extra])


def test_the_tables_are_the_runs_table_i(run: Path, tmp_path: Path) -> None:
    page = tmp_path / "results.md"
    page.write_text(PAGE)
    assert _write(page, run) == 0
    text = page.read_text()
    assert "Prose stays." in text and "More prose." in text
    day = (run / "logs" / "table" / "table.log").read_text()[:10]
    assert f"<!-- run small: biasgt run --config small.yaml | {day} | abc1234 -->" in text
    assert text.count(f"*From run `small`: `biasgt run --config small.yaml`, {day}, commit `abc1234`") == 3
    tables = _tables(text)

    # Table I: every row of table.md, in its order, with the same figures per sequence and on average
    ours, theirs = tables["table1"], _table_md(run)
    assert ours[0] == ["row", "seeds", "average", "test0", "test1"]
    assert len(ours) - 1 == len(theirs) == 1 + len(REFERENCES)
    for row, (label, figures) in zip(ours[1:], theirs):
        assert row[0].startswith(label.removesuffix(" (oracle)")), (row, label)
        assert re.sub(r" ± [0-9.]+", "", row[2]) == figures[-1]  # table.md's Average is its last column
        assert row[3:] == figures[:-1]
    assert ours[1][1] == "2" and [r[0] for r in ours[1:] if r[0].endswith("(oracle)")] == ["Recovered GT bias (oracle)"]
    # the spread over the two seeds, from the summaries: ddof 1
    seeds = [_summary(run, f"{METHOD}/seed{s}")["rows"][0]["average"] for s in (0, 1)]
    p = [s["prmse_m"] for s in seeds]
    assert ours[1][2].startswith(f"{statistics.mean(p):.4f} ± {statistics.stdev(p):.4f} / ")

    # one row per seed, as its summary says, then the mean
    rows = tables[f"seeds {METHOD}"]
    for seed, row in zip((0, 1), rows[1:3]):
        s = _summary(run, f"{METHOD}/seed{seed}")["rows"][0]
        assert row[0] == str(seed)
        assert row[1] == f"{s['average']['prmse_m']:.4f} / {s['average']['roe_deg']:.4f}"
        assert row[2] == f"{s['sequences']['test0']['prmse_m']:.4f} / {s['sequences']['test0']['roe_deg']:.4f}"
    assert rows[3][0] == "mean ± std (ddof 1)" and rows[3][1] == f"**{ours[1][2]}**"

    # the summary: the train mean as Table I has it, and the best usable row by average PRMSE
    summary = {r[0]: r[1] for r in tables["summary train_mean"][1:]}
    assert summary["Train-mean bias (`train_mean`) (1 seed)"] == dict(theirs)["Train-mean bias"][-1]
    usable = {label: float(f[-1].split(" / ")[0]) for label, f in theirs if label in (METHOD, "Zero bias",
                                                                                    "Train-mean bias")}
    best = min(usable, key=usable.get)
    assert any(k.startswith(f"Table I, best usable row in PRMSE: `{best}`") for k in summary)

    # unchanged: --check passes and --write writes nothing
    assert main(["--check", "--run", f"small={run}", "--commit", "small=abc1234", "--page", str(page)]) == 0
    assert _write(page, run) == 0 and page.read_text() == text


def test_check_names_an_altered_figure_and_refuses_bad_results(run: Path, tmp_path: Path, capsys) -> None:
    page = tmp_path / "results.md"
    page.write_text(PAGE)
    assert _write(page, run) == 0
    text = page.read_text()
    figure = _tables(text)["table1"][-1][2]  # the last reference row's average
    page.write_text(text.replace(f"| {figure} |", "| 0.0001 / 0.0001 |", 1))
    capsys.readouterr()
    assert main(["--check", "--run", f"small={run}", "--commit", "small=abc1234", "--page", str(page)]) == 1
    err = capsys.readouterr().err
    assert "line 7: table1 from small: differs from the run's results" in err and len(err.splitlines()) == 1
    # without the run, its blocks are named as not checked, and nothing fails; so for the project's page,
    # whose runs were made on another machine (its markers must still parse)
    assert main(["--check", "--page", str(page)]) == 0
    assert "not checked (give --run small=DIR)" in capsys.readouterr().err
    assert main(["--check"]) == 0 and "docs/results.md: line" in capsys.readouterr().err

    # a folder without results, and a Table I older than its summaries: one line, exit 2, the page unchanged
    before = page.read_text()
    assert _write(page, tmp_path / "empty") == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "results/evaluation: no evaluation summaries" in err
    stale = tmp_path / "stale"
    (stale / "results").mkdir(parents=True)
    shutil.copytree(run / "results" / "evaluation", stale / "results" / "evaluation")
    csv = stale / "results" / "evaluation" / "table.csv"
    csv.write_text(csv.read_text().replace("test0,", "test0,9", 1))
    assert _write(page, stale) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "table.csv: Table I differs from the evaluation summaries" in err
    assert "Traceback" not in err and page.read_text() == before
