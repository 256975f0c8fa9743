"""The training report: sections, Table I marks, figures; and in headless Chromium (every image decodes)."""

from __future__ import annotations

import re
from html import escape
from pathlib import Path

import pytest

from biasgt.workflow.learning import evaluate_step
from reports.training import SECTIONS, build_training_report
from html_tables import parse_page
from window_data import make_window_dataset, train_tiny

METHODS = ("diffusion_rnn", "regression_rnn", "indirect_rnn")
REFERENCES = ("zero", "train_mean", "state_bias", "ground_truth", "random_walk_oracle", "random_walk_paper")
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
    for ref in REFERENCES:
        evaluate_step(data, root / "evaluation" / ref, EVAL, reference=ref)
        evals.append(root / "evaluation" / ref)
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
        pytest.skip("chromium is not installed (tests/reporting/test_report_chromium.py installs it where it can)")
    dom = _run(chromium, tmp_path / "profile", "--virtual-time-budget=10000", "--dump-dom", report.resolve().as_uri())
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(r"<body\b[^>]*>", dom.stdout).group(0)
    assert 'data-broken-images="0"' in body and 'data-images="4"' in body, body
    for _, title in SECTIONS:
        assert escape(title, quote=False) in dom.stdout


def test_summary_on_top_says_the_models_are_demo_sized(report):
    html = report.read_text()
    top = html[:html.index('id="table"')]
    assert 'id="summary"' in top and "Demo-sized models" in top and "preset tiny" in top
    assert "Best usable average (Table I, over" in top
    # both metrics: a row best by PRMSE is named as such, and the best by ROE beside it
    assert "by position error," in top and ("also best by rotation error" in top or "by rotation error," in top)
    assert "made non-overlapping" in top  # why its test windows are fewer than the dataset page's


def test_report_links_back_to_the_dataset_page(report):
    links = parse_page(report.read_text())[1]
    assert links[0] == "index.html"  # the first link: back to the dataset page beside it


def test_curve_legend_sits_beside_the_curves(tmp_path):
    import pandas as pd

    from reports.training import curves_figure

    runs = []
    for method in METHODS:
        run = tmp_path / method / "seed0"
        run.mkdir(parents=True)
        pd.DataFrame({"step": [10, 20, 30], "train_loss": [1.0, 0.5, 0.3], "val_loss": [1.1, 0.6, 0.4]}).to_csv(
            run / "metrics.csv", index=False)
        runs.append(run)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = curves_figure(runs)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is not None:
            box, area = legend.get_window_extent(renderer), ax.get_window_extent(renderer)
            assert box.x0 >= area.x1 or box.y1 <= area.y0  # outside the panel
    # one row of panels per objective: diffusion, regression and indirect losses never share an axis
    assert len(fig.axes) == 2 * 3
    ylabels = [ax.get_ylabel() for ax in fig.axes[::2]]
    assert [y.split(":")[0] for y in ylabels] == ["diffusion", "regression", "indirect"]
    for i in range(3):
        methods = {line.get_label().split("/")[0] for line in fig.axes[2 * i].get_lines()}
        assert methods == {METHODS[i]}


def test_demo_training_records_enough_points_for_a_curve():
    import yaml

    options = yaml.safe_load((Path(__file__).resolve().parents[2] / "config" / "config.yaml").read_text())
    options = options["training"]["options"]
    assert options["max_steps"] // options["val_every"] >= 8  # a validation loss (and a train loss) every val_every


def test_example_figure_draws_samples_and_the_dataset_bias_like_the_papers_fig_3():
    """A test window's panels: the recovered label, the dataset's own bias (where finite), the sample mean
    with its 95% band and each kept sample."""
    import numpy as np
    import pandas as pd

    from reports.training import example_figure
    from training.evaluation.evaluate import CHANNELS

    T = 11
    rows = []
    for ch in CHANNELS:
        for k in range(T):
            rows.append({"window": 3, "sequence": "s", "t_s": k * 0.1, "channel": ch, "sampler": "ddim",
                         "truth": 0.01, "dataset": 0.012, "mean": 0.011, "q0.025": 0.009, "q0.975": 0.013,
                         "sample0": 0.010, "sample1": 0.012})
    fig = example_figure({"diffusion_rnn": pd.DataFrame(rows)}, 3)
    labels = [ln.get_label() for ln in fig.axes[0].lines]
    assert {"recovered GT bias", "the dataset's own bias", "diffusion_rnn samples", "diffusion_rnn (mean)"} <= set(labels)
    assert sum(1 for ln in fig.axes[0].lines if ln.get_linewidth() == 0.5) == 2  # one thin line per sample
    assert np.allclose(next(ln for ln in fig.axes[0].lines if ln.get_label() == "the dataset's own bias").get_ydata(), 0.012)
