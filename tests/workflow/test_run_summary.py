"""biasgt run's closing lines: the verdict per sequence, the window dataset, Table I's headline, the reports."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from biasgt.workflow.run_summary import dry_run_summary, finished_summary


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_finished_run_ends_with_a_per_sequence_summary(tmp_path: Path) -> None:
    results = tmp_path / "results"
    _write(results / "validation" / "a" / "validation.json", json.dumps({"verdict": "PASS", "reasons": []}))
    _write(results / "validation" / "b" / "validation.json",
           json.dumps({"verdict": "FAIL", "reasons": ["impossible bias: the accelerometer bias reaches 12.3 m/s^2"]}))
    _write(results / "windows" / "dataset" / "manifest.json",
           json.dumps({"sequences": {"a": {"split": "train"}}, "excluded": {"b": "verdict FAIL"}}))
    _write(results / "evaluation" / "table.csv",
           "sequence,zero PRMSE_m,zero ROE_deg,regression_rnn PRMSE_m,regression_rnn ROE_deg,"
           "Random walk (oracle) PRMSE_m,Random walk (oracle) ROE_deg\n"
           "t,1,2,0.5,1.5,0.1,0.1\nAverage,1,2,0.5,1.5,0.1,0.1\n")
    _write(results / "report" / "a" / "report.html", "")
    _write(results / "report" / "training.html", "")
    _write(results / "report" / "index.html", "")
    assert finished_summary(tmp_path) == [
        "summary:",
        "  a: PASS",
        "  b: FAIL: impossible bias: the accelerometer bias reaches 12.3 m/s^2",
        "  windows: 1 sequences in the dataset (train 1); left out: b",
        "  Table I: best average regression_rnn: PRMSE 0.5000 m, ROE 1.5000 deg (2 usable rows; "
        "results/evaluation/table.md)",
        "  quality reports: results/report/<sequence>/report.html (1)",
        "  dataset page: results/report/index.html",
        "  training report: results/report/training.html",
    ]
    assert finished_summary(tmp_path / "nothing") == []


def test_dry_run_summary_names_rules_and_reasons() -> None:
    text = ("rule validate:\n    reason: Params have changed since last execution\n"
            "checkpoint windows:\n    reason: Input files updated by another job: results/validation/a\n"
            "rule train:\n    reason: Input files updated by another job: results/windows/dataset\n"
            "localrule all:\n    reason: Input files updated by another job\n")
    assert dry_run_summary(text) == (
        "dry run: 3 jobs would run: validate 1 (parameters changed); windows 1 (after an upstream job); "
        "train 1 (after an upstream job); of these, train run only if the window dataset's content changes "
        "(they depend on its checksum)")
    assert dry_run_summary("Nothing to be done.") == "dry run: nothing to do, every output is up to date"


@pytest.mark.slow
def test_demo_position_only_cart_is_explained_by_its_own_sigma(tmp_path: Path) -> None:
    """The built-in demo's position-only cart, as the config says: a few mm worse than the simulator's truth,
    within its own 2 sigma, well ahead of a constant bias: PASS, no FAIL in the demo."""
    import io

    from biasgt.workflow.run import run_workflow

    run_workflow(workdir=tmp_path, echo=io.StringIO(), targets=["results/validation/sim_cart_leica_01"])
    data = json.loads((tmp_path / "results" / "validation" / "sim_cart_leica_01" / "validation.json").read_text())
    src = data["sources"]
    rec, truth = src["recovered"], src["dataset"]
    assert data["verdict"] == "PASS", data["reasons"]
    assert truth["prmse_m"] < rec["prmse_m"] <= (truth["prmse_m"] ** 2 + (2 * rec["sigma_prmse_m"]) ** 2) ** 0.5
    assert rec["prmse_m"] < 0.5 * src["constant"]["prmse_m"]
    config = (Path(__file__).resolve().parents[2] / "config" / "config.yaml").read_text()
    assert "within what its own sigma says" in config
