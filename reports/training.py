"""The training report: one self-contained HTML page about the learning stage.

Sections (:data:`SECTIONS`): Table I (PRMSE / ROE per test sequence and method, best and second
best marked as in the paper), the training curves (``metrics.csv`` of every run), predicted vs
ground-truth bias on random test windows (the paper's Fig. 3 analogue: diffusion with its
sample spread, regression and indirect; from each evaluation's ``examples.parquet``), the
calibration of the diffusion models' spread (coverage of the ground truth by the central
intervals of the K samples against the nominal level), and parameters, training time and
evaluation latency per method.

Inputs are the workflow's folders (``results/evaluation/...`` written by
:func:`training.evaluation.outputs.write_evaluation`, ``results/training/...`` written by
``biasgt train``); :func:`build_training_report` writes the page atomically.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pipeline.files.atomic import write_text_atomic
from pipeline.layout import DATASET_REPORT_HTML, Stage
from reports.html import Html, back_link, esc, figure_img, fmt, join, p, page, section, table, tag, ul
from training.evaluation.outputs import EXAMPLES_PARQUET, EvaluationSummary, read_summary
from training.networks import get_network, network_names
from training.evaluation.predictions import CHANNELS
from training.evaluation.table import AVERAGE, TableColumn, build_table, cell_marks, method_label, table_columns

log = logging.getLogger(__name__)

__all__ = ["SECTIONS", "build_training_report"]

SECTIONS = (
    ("table", "Table I: integration error on the test split"),
    ("curves", "Training curves"),
    ("examples", "Predicted vs ground-truth bias on test windows"),
    ("calibration", "Calibration of the diffusion models' spread"),
    ("cost", "Parameters, training time and latency"),
)
CHANNEL_UNITS = ("rad/s",) * 3 + ("m/s²",) * 3
#: How far below the nominal level a coverage may be before the spread is called overconfident.
COVERAGE_TOLERANCE = 0.10


def _method_color(name: str, default: str | None) -> str | None:
    """A registered method's report colour (:attr:`training.networks.Network.color`), else ``default``."""
    return get_network(name).color if name in network_names() else default


# ----------------------------------------------------------------------------- sections


def _table_section(columns: list[TableColumn]) -> Html:
    """Table I transposed: one row per method and variant (grouped), one column per test sequence."""
    frame = build_table(columns)
    marks = {seq: (cell_marks(columns, seq, "prmse_m"), cell_marks(columns, seq, "roe_deg")) for seq in frame.index}
    rows, previous = [], None
    for c in columns:
        cells = []
        for seq in frame.index:
            mp, mr = marks[seq]
            pr = tag({"best": "strong", "second": "u"}.get(mp.get(c.name), "span"), f"{np.mean(c.prmse_m[seq]):.4f}")
            ro = tag({"best": "strong", "second": "u"}.get(mr.get(c.name), "span"), f"{np.mean(c.roe_deg[seq]):.4f}")
            cells.append(Html(pr + " / " + ro))
        rows.append([method_label(c) if c.group != previous else "", c.variant, *cells])
        previous = c.group
    headers = ["method", "variant"] + [tag("strong", s) if s == AVERAGE else s for s in frame.index]
    note = p("PRMSE (m) / ROE (deg) of non-overlapping 1-s test windows, each integrated from the reference "
             "start state with the predicted bias subtracted; Average = mean over test sequences. Best bold, "
             "second best underlined per sequence among usable methods; oracle rows read the ground truth at test "
             "time and are not ranked. A diffusion model's first row averages each metric over the K samples "
             "(the paper); 'mean' / 'median' use the sample mean / median as the prediction; 'released' uses the "
             "released code's sampler.", class_="small")
    return Html(table(headers, rows) + note)


#: The y-axis of each objective's loss: the objectives' losses are different quantities, never one axis.
OBJECTIVE_LOSS = {
    "diffusion": "diffusion: noise-prediction MSE (normalised)",
    "regression": "regression: MSE of the normalised bias",
    "indirect": "indirect: integration error against the reference end state",
}


def _objective(method: str) -> str:
    return get_network(method).objective.value if method in network_names() else "other"


def curves_figure(runs: Sequence[Path]) -> Figure | None:
    """Train and validation loss per step of every run, one row of panels per objective (their losses are
    different quantities; :data:`OBJECTIVE_LOSS` labels each y-axis); None without a ``metrics.csv``."""
    frames = [(r, pd.read_csv(r / "metrics.csv")) for r in runs if (r / "metrics.csv").is_file()]
    if not frames:
        return None
    objectives = list(dict.fromkeys(_objective(r.parent.name) for r, _ in frames))
    fig = Figure(figsize=(10, 1.0 + 3.0 * len(objectives)))
    axes = fig.subplots(len(objectives), 2, squeeze=False)
    for run, f in frames:
        ax_t, ax_v = axes[objectives.index(_objective(run.parent.name))]
        name = f"{run.parent.name}/{run.name}"
        color = _method_color(run.parent.name, None)
        ax_t.plot(f["step"], f["train_loss"], color=color, linewidth=1.0, label=name)
        val = f.dropna(subset=["val_loss"])
        ax_v.plot(val["step"], val["val_loss"], color=color, marker="o", markersize=3, linewidth=1.0, label=name)
    for objective, (ax_t, ax_v) in zip(objectives, axes):
        for ax, title in ((ax_t, "train loss"), (ax_v, "validation loss")):
            ax.set_yscale("log")
            ax.set_xlabel("optimiser step")
            ax.set_title(f"{title} ({objective})", fontsize=9)
            ax.grid(True, alpha=0.3)
        ax_t.set_ylabel(OBJECTIVE_LOSS.get(objective, "loss").replace(": ", ":\n", 1), fontsize=8)
        # the legend beside the panels, not over the curves
        ax_v.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    return fig


def example_figure(examples: dict[str, pd.DataFrame], window: int) -> Figure:
    fig = Figure(figsize=(11, 6.5))
    axes = fig.subplots(2, 3, sharex=True).reshape(-1)
    truth_drawn = False
    for name, ex in examples.items():
        w = ex[ex["window"] == window]
        color = _method_color(name, "#7f7f7f")
        samples = sorted(col for col in w.columns if col.startswith("sample") and col[6:].isdigit())
        for i, ch in enumerate(CHANNELS):
            c = w[w["channel"] == ch]
            if not truth_drawn:
                axes[i].plot(c["t_s"], c["truth"], color="black", linewidth=1.6, label="recovered GT bias")
                if "dataset" in c and np.isfinite(c["dataset"]).any():
                    axes[i].plot(c["t_s"], c["dataset"], color="black", linestyle="--", linewidth=1.2,
                                 label="the dataset's own bias")
            for j, col in enumerate(samples):
                axes[i].plot(c["t_s"], c[col], color=color, linewidth=0.5, alpha=0.5,
                             label=f"{name} samples" if j == 0 else None)
            if (c["q0.975"] > c["q0.025"]).any():
                axes[i].fill_between(c["t_s"], c["q0.025"], c["q0.975"], color=color, alpha=0.18, linewidth=0,
                                     label=f"{name} 95% of samples")
            axes[i].plot(c["t_s"], c["mean"], color=color, linewidth=1.1, label=f"{name} (mean)")
        truth_drawn = True
    for i, ax in enumerate(axes):
        ax.set_title(f"{CHANNELS[i]} [{CHANNEL_UNITS[i]}]", fontsize=9)
        ax.grid(True, alpha=0.3)
    for ax in axes[3:]:
        ax.set_xlabel("time in window [s]")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=min(4, max(1, len(labels))))
    fig.tight_layout(rect=(0, 0.08, 1, 1))  # room for the legend under the panels, off the curves
    return fig


def _examples_section(summaries: list[tuple[Path, EvaluationSummary]]) -> Html:
    examples: dict[str, pd.DataFrame] = {}
    for folder, s in summaries:
        f = folder / EXAMPLES_PARQUET
        if s.kind != "learned" or s.method in examples or not f.is_file():
            continue
        ex = pd.read_parquet(f)
        if "sampler" in ex and (ex["sampler"] == "ddim").any():
            ex = ex[ex["sampler"] == "ddim"]
        examples[s.method] = ex
    if not examples:
        return tag("div", "No learned method was evaluated: nothing to show.", class_="missing")
    windows = sorted(set.intersection(*(set(e["window"]) for e in examples.values())))
    parts = []
    for w in windows[:2]:
        seq = next(iter(examples.values()))
        seq = seq[seq["window"] == w]["sequence"].iloc[0]
        parts.append(figure_img(example_figure(examples, w), f"bias of test window {w}",
                                f"Test window {w} of {seq}: recovered ground-truth bias (black), the dataset's own "
                                "bias where it has one (dashed), each method's prediction (the sample mean for "
                                "diffusion models, with a few of its samples as thin lines and the band holding the "
                                "central 95% of the samples). Windows drawn at random, the same for every method."))
    return join(parts)


def _calibration_figure(calibrations: list[tuple[str, object]]) -> Figure:
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, len(calibrations), squeeze=False)[0]
    for ax, (name, cal) in zip(axes, calibrations):
        levels = np.asarray(cal.levels)
        cov = np.asarray(cal.coverage)
        ax.plot([0, 1], [0, 1], color="black", linestyle="--", linewidth=0.8, label="calibrated")
        for i, ch in enumerate(CHANNELS):
            ax.plot(levels, cov[:, i], marker="o", markersize=3, linewidth=1.0, label=ch)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("nominal level of the central interval")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("fraction of GT bias inside")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return fig


def _calibration_verdict(cal: object) -> str:
    cov = np.asarray(cal.coverage)
    i68, i95 = cal.levels.index(0.68), cal.levels.index(0.95)
    short = [CHANNELS[i] for i in range(6) if cov[i95, i] < 0.95 - COVERAGE_TOLERANCE]
    wide = [CHANNELS[i] for i in range(6) if cov[i68, i] > 0.68 + COVERAGE_TOLERANCE]
    words = []
    if short:
        words.append(f"overconfident on {', '.join(short)} (95% interval covers < {0.95 - COVERAGE_TOLERANCE:.0%})")
    if wide:
        words.append(f"too wide on {', '.join(wide)} (68% interval covers > {0.68 + COVERAGE_TOLERANCE:.0%})")
    return "; ".join(words) if words else f"calibrated within {COVERAGE_TOLERANCE:.0%} at 68% and 95%"


def _calibration_section(summaries: list[tuple[Path, EvaluationSummary]]) -> Html:
    cals = [(f"{s.method} {folder.name if folder.name.startswith('seed') else ''} {c.sampler.value}".replace("  ", " "),
             c) for folder, s in summaries for c in s.calibration]
    if not cals:
        return tag("div", "No diffusion model was evaluated: no sample spread to calibrate.", class_="missing")
    rows = [[name, *(f"{x:.2f}" for x in c.at(0.68)), *(f"{x:.2f}" for x in c.at(0.95)), _calibration_verdict(c)]
            for name, c in cals]
    headers = ["model / sampler", *(f"68% {c}" for c in CHANNELS), *(f"95% {c}" for c in CHANNELS), "finding"]
    shown = cals[:4]
    return Html(p("Per channel, the fraction of ground-truth bias values (every sample of every test window) that "
                  "fall inside the central interval of the K samples. A calibrated model follows the diagonal; "
                  "below it the spread is too narrow (overconfident).")
                + figure_img(_calibration_figure(shown), "calibration curves",
                             "Coverage against nominal level" + (" (first four shown)" if len(cals) > 4 else ""))
                + table(headers, rows, text_cols=[len(headers) - 1]))


def _cost_section(summaries: list[tuple[Path, EvaluationSummary]]) -> Html:
    rows = []
    for folder, s in summaries:
        if s.kind != "learned":
            continue
        ck = s.checkpoint
        passes = s.windows * s.samples * max(1, len(s.calibration))
        per = 1000.0 * s.seconds / passes if passes else float("nan")
        rows.append([s.method, folder.name, fmt(ck.get("parameters"), 7), ck.get("preset", "n/a"),
                     fmt(ck.get("steps")), fmt(ck.get("train_seconds"), 4, "s"), fmt(ck.get("windows_per_s"), 4),
                     fmt(s.seconds, 4, "s"), fmt(per, 3, "ms")])
    if not rows:
        return tag("div", "No learned method was evaluated.", class_="missing")
    headers = ["method", "run", "parameters", "preset", "steps", "train time", "train windows/s", "evaluation time",
               "evaluation per window and sample"]
    return Html(table(headers, rows, text_cols=[1, 3])
                + p("Evaluation time covers every sampler and the metrics; a diffusion sample is "
                    "'steps' denoising passes. Latency of one window on 2 CPU threads, in PyTorch eager, TorchScript "
                    "and onnxruntime, is printed by benchmarks/learning/training.py.", class_="small"))


# ----------------------------------------------------------------------------- page


#: Fewest optimiser steps of a run that is more than a demonstration of the pipeline.
DEMO_STEPS = 2000


def summary_box(columns: list[TableColumn], run_dirs: Sequence[Path]) -> Html:
    """What the report says on top: how many models, how trained, the best usable average by each metric
    (PRMSE and ROE; a row best by one is not called best by both), and whether the models are demo-sized (a
    CPU preset or fewer than :data:`DEMO_STEPS` steps)."""
    runs = []
    for r in run_dirs:
        try:
            runs.append(json.loads((Path(r) / "run.json").read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue
    items = []
    if runs:
        presets = sorted({str(x.get("preset")) for x in runs})
        steps = sorted({int(x.get("steps") or 0) for x in runs})
        items.append(f"{len(runs)} trained models ({len({x.get('method') for x in runs})} methods), preset "
                     f"{'/'.join(presets)}, {'/'.join(map(str, steps))} optimiser steps each.")
        if max(steps) < DEMO_STEPS or any(x != "paper" for x in presets):
            items.append(Html(tag("strong", "Demo-sized models: ") + esc(
                f"a CPU preset or fewer than {DEMO_STEPS} steps exercise the whole learning stage; their errors "
                "are not the paper's and say nothing about the methods (train with preset: paper, on a GPU, for "
                "that).")))
    ranked = [c for c in columns if c.ranked]
    if ranked:
        by_p = min(ranked, key=lambda c: float(np.mean(c.prmse_m[AVERAGE])))
        by_r = min(ranked, key=lambda c: float(np.mean(c.roe_deg[AVERAGE])))
        text = (f"Best usable average (Table I, over {len(ranked)} usable rows): by position error, {by_p.name} "
                f"(PRMSE {np.mean(by_p.prmse_m[AVERAGE]):.4f} m, ROE {np.mean(by_p.roe_deg[AVERAGE]):.4f} deg)")
        if by_r is by_p:
            text += "; it is also best by rotation error."
        else:
            text += (f"; by rotation error, {by_r.name} (PRMSE {np.mean(by_r.prmse_m[AVERAGE]):.4f} m, ROE "
                     f"{np.mean(by_r.roe_deg[AVERAGE]):.4f} deg): no row is best on both.")
        items.append(text)
    return tag("div", ul(items), class_="verdict v-none", id="summary")


def build_training_report(evaluation_dirs: Sequence[str | Path], run_dirs: Sequence[str | Path],
                          out_path: str | Path, *, title: str = "biasgt training report") -> Path:
    """Write the training report (one self-contained HTML file) atomically.

    Args:
        evaluation_dirs: Evaluation folders (``summary.json``, ``examples.parquet``).
        run_dirs: Training run folders (``metrics.csv``); missing ones are skipped.
        out_path: The HTML file; at the workflow's place (``results/report/``) it links back to the dataset page.
        title: Page title.
    """
    out = Path(out_path)
    summaries = [(Path(d), read_summary(d)) for d in evaluation_dirs]
    columns = table_columns(s for _, s in summaries)
    curves = curves_figure([Path(r) for r in run_dirs])
    bodies = {
        "table": _table_section(columns),
        "curves": (figure_img(curves, "training curves", "Train loss per step and validation loss (validation "
                                                        "split: it chooses best.pt) per run, one row per "
                                                        "objective: their losses are different quantities and "
                                                        "are not compared across rows.")
                   if curves is not None else tag("div", "No training run to show.", class_="missing")),
        "examples": _examples_section(summaries),
        "calibration": _calibration_section(summaries),
        "cost": _cost_section(summaries),
    }
    toc = tag("nav", tag("ol", join(tag("li", tag("a", t, href=f"#{a}")) for a, t in SECTIONS)), class_="toc")
    dataset = summaries[0][1].dataset if summaries else {}
    meta = p(f"Dataset {dataset.get('path', 'n/a')} (config hash {dataset.get('config_hash', 'n/a')}), "
             f"{summaries[0][1].windows if summaries else 0} test windows of {dataset.get('window_samples', 'n/a')} "
             f"samples at {fmt(dataset.get('rate_hz'))} Hz: the test split's windows made non-overlapping (the "
             "dataset page counts the split's overlapping windows, about twice as many).", class_="meta")
    index = f"{DATASET_REPORT_HTML}" if out.parent.name == Stage.REPORT.folder else None
    body = join([back_link(index), tag("h1", title), meta, summary_box(columns, [Path(r) for r in run_dirs]), toc,
                 *(section(a, t, bodies[a]) for a, t in SECTIONS)])
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, page(title, body))
    log.info("wrote %s", out)
    return out
