"""The training report: sections, Table I marks, figures; and in headless Chromium (every image decodes)."""

from __future__ import annotations

import re
from html import escape
from pathlib import Path

import pytest

from reports.training import SECTIONS, build_training_report
from training.config import Baseline
from training.stages import evaluate_step
from window_data import make_window_dataset, train_tiny

METHODS = ("diffusion_rnn", "regression_rnn", "indirect_rnn")
EVAL = {"samples": 4, "steps": 3, "samplers": ["ddim", "released"], "examples": 2}


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("training_report")
    data = make_window_dataset(root, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    evals, runs = [], []
    for method in METHODS:
        run = root / "training" / method / "seed0"
        train_tiny(data, run, method)
        evaluate_step(data, root / "evaluation" / method / "seed0", EVAL, run_dir=run, method=method)
        runs.append(run)
        evals.append(root / "evaluation" / method / "seed0")
    for ref in Baseline:
        evaluate_step(data, root / "evaluation" / ref.value, EVAL, reference=ref.value)
        evals.append(root / "evaluation" / ref.value)
    return build_training_report(evals, runs, root / "report" / "training.html")


def test_report_sections_and_content(report):
    html = report.read_text()
    assert html.startswith("<!DOCTYPE html>")
    for anchor, title in SECTIONS:
        assert f'id="{anchor}"' in html and escape(title) in html
    # Table I: one row per method and variant, grouped; one column per test sequence and the Average, each
    # with one best and one second-best mark per metric
    section = html[html.index('id="table"'):html.index('id="curves"')]
    body_rows = re.findall(r"<tr><td>(.*?)</tr>", section, re.S)
    cells = [re.findall(r"<td[^>]*>(.*?)</td>", "<td>" + r, re.S) for r in body_rows]
    labels = [(c[0], c[1]) for c in cells]
    for label in (("diffusion_rnn", ""), ("", "mean"), ("", "released"), ("regression_rnn", ""),
                  ("indirect_rnn", ""), ("Zero bias", ""), ("Random walk (oracle)", "")):
        assert label in labels, label
    assert re.search(r"<th>variant</th>\s*<th>test0</th>\s*<th><strong>Average</strong></th>", section)
    for col in (2, 3):
        column = "".join(c[col] for c in cells)
        assert column.count("<strong>") == 2 and column.count("<u>") == 2
    assert html.count("data:image/png;base64") == 4  # curves, two example windows, calibration
    assert "diffusion_rnn seed0 ddim" in html and "diffusion_rnn seed0 released" in html
    assert "overconfident" in html or "calibrated within" in html or "too wide" in html


@pytest.mark.chromium
def test_chromium_renders_training_report(report, tmp_path):
    from test_report_chromium import _find_chromium, _run

    chromium = _find_chromium()
    if chromium is None:
        pytest.skip("chromium is not installed (tests/test_report_chromium.py installs it where it can)")
    dom = _run(chromium, tmp_path / "profile", "--virtual-time-budget=10000", "--dump-dom", report.resolve().as_uri())
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(r"<body\b[^>]*>", dom.stdout).group(0)
    assert 'data-broken-images="0"' in body and 'data-images="4"' in body, body
    for _, title in SECTIONS:
        assert escape(title, quote=False) in dom.stdout
