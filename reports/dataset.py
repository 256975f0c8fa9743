"""The dataset page: one self-contained HTML page (``results/report/index.html``) over every sequence.

Sections (:data:`SECTIONS`): the headline (sequences per verdict, windows per split, what was left
out and why), one sortable row per sequence (split, verdict and its leading reason, label stream
and validation reference, PRMSE / ROE of the label beside zero, constant and the dataset's bias,
held-out figures, clock offset, extrinsic, noise scales, outliers, windows, a link to the
sequence's report), Table I's average rows, and one figure of every sequence's recovered bias.
Columns sort by a click on their header (a few lines of inline script; no framework).

Inputs: :func:`reports.dataset_inputs.gather_dataset`; :func:`build_dataset_report` writes the page
atomically.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path

from matplotlib.figure import Figure

from pipeline.files.atomic import write_text_atomic
from pipeline.errors import ConfigError
from pipeline.layout import DATASET_REPORT_HTML, REPORT_HTML, Stage
from pipeline.types import NS_PER_S, Verdict
from reports.dataset_inputs import DatasetInputs, SequenceRow, average_rows, gather_dataset
from reports.html import Html, esc, figure_img, fmt, join, p, page, section, table, tag, ul

log = logging.getLogger(__name__)

__all__ = ["SECTIONS", "build_dataset_report", "render_dataset_report"]

SECTIONS = (
    ("headline", "Headline"),
    ("sequences", "Sequences"),
    ("table", "Table I (averages)"),
    ("bias", "Recovered bias of every sequence"),
)
SPLIT_COLORS = {"train": "#1f77b4", "val": "#ff7f0e", "test": "#2ca02c"}
OTHER_COLOR = "#7f7f7f"
CHANNELS = ("gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z")
LABELS = ("recovered", "zero", "constant", "dataset's", "held-out")
#: Sorts the table whose header cell was clicked by that column (``data-v``: the sort key; numbers
#: numerically, empty cells last); a second click reverses the order.
SORT_SCRIPT = """
document.querySelectorAll("table.sortable th").forEach(function (th, col) {
  th.addEventListener("click", function () {
    var body = th.closest("table").tBodies[0], rows = Array.prototype.slice.call(body.rows);
    var dir = th.dataset.dir === "asc" ? -1 : 1;
    th.closest("tr").querySelectorAll("th").forEach(function (h) { delete h.dataset.dir; });
    th.dataset.dir = dir === 1 ? "asc" : "desc";
    function key(r) { var c = r.cells[col]; return c.dataset.v !== undefined ? c.dataset.v : c.textContent; }
    rows.sort(function (a, b) {
      var x = key(a), y = key(b), nx = parseFloat(x), ny = parseFloat(y);
      if (x === "" || y === "") { return (x === "") - (y === ""); }
      if (!isNaN(nx) && !isNaN(ny)) { return dir * (nx - ny); }
      return dir * x.localeCompare(y);
    });
    rows.forEach(function (r) { body.appendChild(r); });
  });
});
"""
EXTRA_CSS = ("table.sortable th{cursor:pointer;white-space:nowrap}table.sortable th[data-dir=asc]::after{content:' ▲'}"
             "table.sortable th[data-dir=desc]::after{content:' ▼'}td.PASS{background:#e9f7ee;color:#1e7a43;"
             "font-weight:700}td.WARN{background:#fff6e0;color:#9a6b00;font-weight:700}td.FAIL{background:#fdecec;"
             "color:#a4231f;font-weight:700}.flag{color:#a4231f;font-weight:700}.scroll{overflow-x:auto}"
             ".counts{font-size:1.15em}.count-PASS{color:#1e7a43;font-weight:700}.count-WARN{color:#9a6b00;"
             "font-weight:700}.count-FAIL{color:#a4231f;font-weight:700}")


# ----------------------------------------------------------------------------- sections


def _headline(inp: DatasetInputs) -> Html:
    verdicts = Counter(r.verdict for r in inp.rows)  # None: not validated
    counts = join((tag("span", f"{verdicts.get(v, 0)} {v.value}", class_=f"count-{v.value}",
                       data_count=verdicts.get(v, 0)) for v in Verdict), sep=" · ")
    parts = [p(Html(f"{len(inp.rows)} sequences: " + counts
                    + (f" · {verdicts[None]} not validated" if verdicts.get(None) else "")),
               class_="counts")]
    totals = (inp.manifest or {}).get("totals") or {}
    if inp.manifest is None:
        parts.append(p("No window dataset (results/windows/dataset) was built.", class_="missing"))
    else:
        rows = [[split, int(t.get("sequences", 0)), int(t.get("windows", 0)), int(t.get("candidates", 0)),
                 int(t.get("dropped", 0))] for split, t in totals.items()]
        parts.append(table(["split", "sequences", "windows", "candidate windows", "dropped"], rows,
                           caption="Windows that entered each split of the window dataset"))
        drops = Counter()
        for r in inp.rows:
            drops.update(r.dropped)
        if drops:
            parts.append(p("Windows dropped, by reason: " + ", ".join(f"{k.replace('_', ' ')} {v}"
                                                                      for k, v in sorted(drops.items()))))
    left = [Html(tag("strong", r.name) + esc(f": {r.left_out}")) for r in inp.rows if r.left_out]
    left += [esc(f"not validated (taken as they are): {n}") for n in (inp.manifest or {}).get("not_validated") or []]
    parts.append(Html(tag("h3", "Left out") + (ul(left, class_="left-out") if left else p("Nothing was left out."))))
    if inp.problems:
        parts.append(tag("div", Html(p("Not shown:") + ul(inp.problems)), class_="missing"))
    return section("headline", SECTIONS[0][1], join(parts))


def _cell(text: object, sort: object = None, **attrs: object) -> Html:
    key = None if sort is None else (f"{sort:.9g}" if isinstance(sort, float) else str(sort))
    return tag("td", text, data_v=key, **attrs)


def _metric_cells(r: SequenceRow) -> list[Html]:
    cells = []
    for label in LABELS:
        prmse, roe = r.metrics.get(label, (None, None))
        cells.append(_cell(f"{fmt(prmse, 3)} / {fmt(roe, 3)}" if prmse is not None or roe is not None else "",
                           "" if prmse is None else prmse, class_="num"))
    return cells


def _row(r: SequenceRow, link: str) -> Html:
    reference = "" if r.reference is None else f"{r.reference} ({'independent' if r.independent else 'fitted'})"
    offset = "" if r.offset_s is None else f"{1e3 * r.offset_s:.3f} ± {fmt(None if r.offset_std_s is None else 1e3 * r.offset_std_s, 2)}"
    noise = join((tag("span", f"{axis} {scale:.3g}x" + (" (bound)" if axis in r.at_bound else ""),
                      class_="flag" if axis in r.at_bound else None) for axis, scale in r.noise_scales.items()),
                 sep=", ")
    dropped = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sorted(r.dropped.items()))
    windows = "" if r.windows is None else f"{r.windows} / {r.candidates}"
    cells = [
        _cell(tag("a", r.name, href=link), r.name),
        _cell(r.split or ""),
        _cell(r.verdict.value if r.verdict is not None else "n/a", class_=r.verdict.value if r.verdict else None),
        _cell(r.reason or ("" if r.verdict is not None else "not validated"), class_="small"),
        _cell(f"{r.pose_stream or ''}" + (f" ({r.pose_kind})" if r.pose_kind else "")),
        _cell(reference, "" if r.independent is None else int(bool(r.independent))),
        *_metric_cells(r),
        _cell(offset, "" if r.offset_s is None else r.offset_s, class_="num"),
        _cell(fmt(r.extrinsic_sigmas, 3), "" if r.extrinsic_sigmas is None else r.extrinsic_sigmas, class_="num"),
        _cell(noise, max(r.noise_scales.values()) if r.noise_scales else ""),
        _cell("" if r.outlier_share is None else f"{r.outlier_share:.2%}",
              "" if r.outlier_share is None else r.outlier_share, class_="num"),
        _cell(windows, "" if r.windows is None else r.windows, class_="num"),
        _cell(dropped or (r.left_out or ""), sum(r.dropped.values()) if r.windows is not None else "", class_="small"),
    ]
    return tag("tr", join(cells), data_sequence=r.name)


SEQUENCE_HEADERS = ("sequence", "split", "verdict", "leading reason", "labels from (pose stream)",
                    "validation reference", *(f"{x} PRMSE m / ROE deg" for x in LABELS), "clock offset ms ± σ",
                    "extrinsic vs calibration [σ]", "random-walk scales", "outliers", "windows in / candidates",
                    "dropped (by reason)")


def _sequences(inp: DatasetInputs, out_dir: Path) -> Html:
    rows = []
    for r in inp.rows:
        target = inp.results / Stage.REPORT.folder / r.name / REPORT_HTML
        rows.append(_row(r, Path(os.path.relpath(target.resolve(), out_dir)).as_posix()))
    head = tag("thead", tag("tr", join(tag("th", h, title="sort by this column") for h in SEQUENCE_HEADERS)))
    grid = tag("table", Html(head + tag("tbody", join(rows))), class_="data sortable", id="sequences-table")
    note = p("PRMSE (m) / ROE (deg) of 1-s windows integrated with each bias: the label (the recovered bias), a "
             "zero bias, the label held constant from the first window, the dataset's own bias, and the label "
             "recovered with the window's block held out (cross-validation, where it ran). 'independent': the "
             "validation reference is not the pose stream the label was fitted to. The extrinsic column is the "
             "larger of the rotation and translation differences from the calibration file in their sigmas; "
             "'(bound)' marks a random walk chosen at a bound of the evidence search. Click a header to sort.",
             class_="small")
    return section("sequences", SECTIONS[1][1], Html(tag("div", grid, class_="scroll") + note))


def _table_i(inp: DatasetInputs, out_dir: Path) -> Html:
    avg = average_rows(inp.table)
    training = inp.results / Stage.REPORT.folder / "training.html"
    parts = []
    if avg:
        parts.append(table(["method", "average PRMSE (m)", "average ROE (deg)"],
                           [[m, fmt(x, 4), fmt(y, 4)] for m, x, y in avg], caption="Table I, Average row"))
    else:
        parts.append(p("No Table I (the learning stages did not run: they need train, val and test sequences).",
                       class_="missing"))
    if training.is_file():
        link = tag("a", "The training report", href=Path(os.path.relpath(training.resolve(), out_dir)).as_posix())
        parts.append(p(Html(link + esc(": Table I per sequence, training curves, predictions, calibration."))))
    return section("table", SECTIONS[2][1], join(parts))


def bias_overview_figure(rows: Sequence[SequenceRow]) -> Figure | None:
    """Six panels (gyro x/y/z, acc x/y/z) with every sequence's recovered bias against the seconds
    from its first keyframe, coloured by split; None when no sequence has a bias."""
    drawn = [r for r in rows if r.bias is not None and len(r.bias.t_ns)]
    if not drawn:
        return None
    fig = Figure(figsize=(11, 6.5))
    axes = fig.subplots(3, 2, sharex=True).T.ravel()  # column 0: gyro, column 1: acc
    seen: dict[str, object] = {}
    for r in drawn:
        t_s = (r.bias.t_ns - r.bias.t_ns[0]) / NS_PER_S
        k = max(1, len(t_s) // 2000)
        color = SPLIT_COLORS.get(r.split or "", OTHER_COLOR)
        for c, ax in enumerate(axes):
            (line,) = ax.plot(t_s[::k], r.bias.bias[::k, c], color=color, linewidth=0.9, alpha=0.8)
        seen.setdefault(r.split if r.split in SPLIT_COLORS else "other", line)
    for c, ax in enumerate(axes):
        ax.set_ylabel(f"{CHANNELS[c]} [{'rad/s' if c < 3 else 'm/s²'}]")
        ax.grid(True, alpha=0.3)
    for ax in (axes[2], axes[5]):
        ax.set_xlabel("time since the recording's first keyframe [s]")
    fig.legend(list(seen.values()), list(seen.keys()), loc="upper center", ncol=len(seen), fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return fig


def _figure(inp: DatasetInputs) -> Html:
    fig = bias_overview_figure(inp.rows)
    if fig is None:
        return section("bias", SECTIONS[3][1], p("No recovered bias to draw.", class_="missing"))
    return section("bias", SECTIONS[3][1], figure_img(
        fig, "recovered bias of every sequence", "Recovered bias (6 channels) of every sequence on a shared time "
        "axis from each recording's start, coloured by split (grey: no split or left out)."))


def render_dataset_report(inp: DatasetInputs, out_dir: Path) -> str:
    """The page as HTML text; links are relative to ``out_dir`` (the folder the page is written to)."""
    body = join([
        tag("h1", "biasgt dataset report"),
        p(f"results: {inp.results.name}/ · {len(inp.rows)} sequences", class_="meta"),
        tag("nav", tag("ol", join(tag("li", tag("a", t, href=f"#{a}")) for a, t in SECTIONS)), class_="toc"),
        _headline(inp), _sequences(inp, out_dir), _table_i(inp, out_dir), _figure(inp),
        Html(f"<style>{EXTRA_CSS}</style><script>{SORT_SCRIPT}</script>"),
    ])
    return page("biasgt dataset report", body)


def build_dataset_report(results_dir: str | Path, out_path: str | Path | None = None,
                         sequences: Sequence[str] | None = None, splits: Mapping[str, str] | None = None) -> Path:
    """Write the dataset page of a results folder as one self-contained HTML file.

    Args:
        results_dir: ``results/`` or the folder holding it.
        out_path: The HTML file (default ``results/report/index.html``), written atomically.
        sequences: The sequences, in order (default: every one with a recovery or validation folder).
        splits: Name -> split (default: the window dataset's manifest).

    Returns:
        ``out_path`` as a Path.

    Raises:
        ConfigError: ``out_path`` is a folder, or the results folder holds no sequence.
    """
    inp = gather_dataset(results_dir, sequences, splits)
    out = Path(out_path) if out_path is not None else inp.results / Stage.REPORT.folder / DATASET_REPORT_HTML
    if out.is_dir():
        raise ConfigError("the report output is a folder", path=out, field="--out",
                          hint="give a file name such as index.html")
    if not inp.rows:
        raise ConfigError("no sequence in the results folder (no recovery/ or validation/ sub-folder)",
                          path=inp.results, hint="give the workflow's results/ folder, or run 'biasgt run' first")
    for note in inp.problems:
        log.info("dataset report: %s", note)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = render_dataset_report(inp, out.parent.resolve())
    write_text_atomic(out, text)
    log.info("wrote %s (%d sequences, %.0f kB)", out, len(inp.rows), len(text) / 1024)
    return out
