"""The dataset page: one self-contained HTML page (``results/report/index.html``) over every sequence.

Sections (:data:`SECTIONS`): the headline (sequences per verdict, windows per split, what was left
out and why); the sequences at a glance (one sortable row per sequence, most severe verdict first,
with the columns an auditor decides on: split, verdict and its leading reason with the rule's code,
label stream, PRMSE / ROE of the label beside the constant bias and the held-out label, windows in,
a link to the sequence's report; an empty cell says why); the next steps of every WARN and FAIL; the
sequences in detail (validation reference, zero and dataset's bias, clock offset, extrinsic, random
walks, outliers, dropped windows); Table I's average rows (oracle rows marked and footnoted as in
``table.md``); one figure of every sequence's recovered bias (:mod:`reports.dataset_figure`).
Wide tables scroll in their own box; the page itself never scrolls sideways. Columns sort by a
click on their header (a few lines of inline script; no framework).

Inputs: :func:`reports.dataset_inputs.gather_dataset`; :func:`build_dataset_report` writes the page
atomically.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path

from pipeline.files.atomic import write_text_atomic
from pipeline.errors import ConfigError
from pipeline.layout import DATASET_REPORT_HTML, REPORT_HTML, Stage
from pipeline.types import Verdict
from reports.dataset_figure import CHANNELS, UNITS, bias_overview_figure, channel_outliers
from reports.dataset_inputs import DatasetInputs, SequenceRow, average_rows, gather_dataset
from reports.quality_calibration import calibration_word
from reports.html import Html, code_words, esc, figure_picture, fmt, fmt_unc, join, p, page, scroll_box, section, table, tag, ul

log = logging.getLogger(__name__)

__all__ = ["SECTIONS", "SEVERITY", "build_dataset_report", "by_severity", "render_dataset_report"]

SECTIONS = (
    ("headline", "Headline"),
    ("sequences", "Sequences at a glance"),
    ("next", "Next steps"),
    ("details", "Sequences in detail"),
    ("table", "Table I (averages)"),
    ("bias", "Recovered bias of every sequence"),
)
LABELS = ("recovered", "zero", "constant", "dataset's", "held-out")
#: Sort key of a verdict: the most severe first (None: not validated, last).
SEVERITY = {Verdict.FAIL: 0, Verdict.WARN: 1, Verdict.PASS: 2, None: 3}
#: The footnote of oracle rows, as in ``table.md``.
ORACLE_NOTE = ("(oracle): reads the ground truth at test time; a bound on what the labels allow, not a method, "
               "and not ranked.")
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
EXTRA_CSS = ("table.sortable th{cursor:pointer}table.sortable th[data-dir=asc]::after{content:' ▲'}"
             "table.sortable th[data-dir=desc]::after{content:' ▼'}td.PASS{background:#e9f7ee;color:#1e7a43;"
             "font-weight:700}td.WARN{background:#fff6e0;color:#9a6b00;font-weight:700}td.FAIL{background:#fdecec;"
             "color:#a4231f;font-weight:700}.flag{color:#a4231f;font-weight:700}"
             "table.glance{width:100%;font-size:.88em}table.glance td.reason{min-width:14em}"
             "td.num span{white-space:nowrap}"
             "td.why{color:#5b6672;font-style:italic}tr.oracle td{font-style:italic;color:#4b5661}"
             ".counts{font-size:1.15em}.count-PASS{color:#1e7a43;font-weight:700}.count-WARN{color:#9a6b00;"
             "font-weight:700}.count-FAIL{color:#a4231f;font-weight:700}code.rule{font-size:.85em}")


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
        parts.append(p("These are the window dataset's windows, which overlap (the manifest's stride). Table I "
                       "integrates the test split's windows made non-overlapping, so the training report counts "
                       "about half as many test windows.", class_="small"))
        drops = Counter()
        for r in inp.rows:
            drops.update(r.dropped)
        if drops:
            parts.append(p(Html("Windows dropped, by reason: " + join((_drop_words(k, v) for k, v in sorted(
                drops.items())), sep=", "))))
        widened = _widened_labels(inp.manifest)
        if widened:
            parts.append(p(Html("Labels whose bias sigma the held-out check widened (the window dataset carries "
                                "the widened sigma): " + join(widened, sep="; ")), class_="widened"))
    left = [Html(tag("strong", r.name) + esc(f": {r.left_out}")) for r in inp.rows if r.left_out]
    left += [esc(f"not validated (taken as they are): {n}") for n in (inp.manifest or {}).get("not_validated") or []]
    parts.append(Html(tag("h3", "Left out") + (ul(left, class_="left-out") if left else p("Nothing was left out."))))
    if inp.problems:
        parts.append(tag("div", Html(p("Not shown:") + ul(inp.problems)), class_="missing"))
    return section("headline", SECTIONS[0][1], join(parts))


_AXES = ("gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z")


def _widened_labels(manifest: Mapping[str, object]) -> list[Html]:
    """Per windowed sequence whose ``info.bias_std_factor`` exceeds 1 on some axis: its name and those factors."""
    out = []
    for name, seq in sorted((manifest.get("sequences") or {}).items()):
        factor = ((seq or {}).get("info") or {}).get("bias_std_factor") or []
        axes = [f"{axis} x{f:.2f}" for axis, f in zip(_AXES, factor) if f > 1.0]
        if axes:
            out.append(Html(tag("strong", name) + esc(": " + ", ".join(axes))))
    return out


def _drop_words(code: str, count: int) -> Html:
    return Html(esc(f"{code_words(code)} ") + tag("code", code, class_="rule") + esc(f": {count}"))


def _cell(text: object, sort: object = None, **attrs: object) -> Html:
    key = None if sort is None else (f"{sort:.9g}" if isinstance(sort, float) else str(sort))
    return tag("td", text, data_v=key, **attrs)


def _why(text: str) -> Html:
    """A cell that says why it holds no value (sorts last)."""
    return _cell(text, "", class_="why")


def _metric_cell(r: SequenceRow, label: str) -> Html:
    """PRMSE (mm) / ROE (deg) of one bias source, or why there is none."""
    prmse, roe = r.metrics.get(label, (None, None))
    if prmse is None and roe is None:
        if r.verdict is None:
            return _why("not validated")
        return _why("not run" if label in ("held-out", "dataset's", "constant") else "n/a")
    mm = None if prmse is None else 1e3 * prmse
    # each figure unbroken; the cell wraps between them, at " / ", when the column is narrow
    text = Html(tag("span", f"{fmt(mm, 3)} mm") + " / " + tag("span", f"{fmt(roe, 3)}°"))
    return _cell(text, "" if prmse is None else prmse, class_="num")


def _windows_cell(r: SequenceRow, manifest: bool) -> Html:
    if r.windows is not None:
        return _cell(f"{r.windows} of {r.candidates}", r.windows, class_="num")
    if r.left_out:
        return _why("left out: " + r.left_out.split(":")[0])
    return _why("no window dataset" if not manifest else "not windowed")


def _verdict_cell(r: SequenceRow) -> Html:
    word = r.verdict.value if r.verdict is not None else "not validated"
    return _cell(word, SEVERITY[r.verdict], class_=r.verdict.value if r.verdict else "why")


def _reason_cell(r: SequenceRow) -> Html:
    if r.verdict is None:
        return _why("not validated")
    if not r.reason:
        return _cell("no reason for concern", class_="reason")
    code = (" " + tag("code", r.reason_code, class_="rule")) if r.reason_code else ""
    return _cell(Html(esc(r.reason) + code), r.reason, class_="reason")


GLANCE_HEADERS = ("sequence", "split", "verdict", "leading reason (rule code)", "labels from (pose stream)",
                  "label: PRMSE / ROE", "constant bias: PRMSE / ROE", "held out: PRMSE / ROE", "windows in")


def _glance_row(r: SequenceRow, link: str, manifest: bool) -> Html:
    cells = [
        _cell(tag("a", r.name, href=link), r.name),
        _cell(r.split or "", None) if r.split else _why("no split"),
        _verdict_cell(r),
        _reason_cell(r),
        _cell(f"{r.pose_stream or ''}" + (f" ({r.pose_kind})" if r.pose_kind else "")) if r.pose_stream
        else _why("no recovery"),
        _metric_cell(r, "recovered"),
        _metric_cell(r, "constant"),
        _metric_cell(r, "held-out"),
        _windows_cell(r, manifest),
    ]
    return tag("tr", join(cells), data_sequence=r.name)


def _walk_words(axis: str, scale: float, at_bound: bool) -> Html:
    text = f"{axis} {fmt(scale, 3)}× ({calibration_word(scale)}{', at a bound' if at_bound else ''})"
    return tag("span", text, class_="flag" if at_bound else None)


DETAIL_HEADERS = ("sequence", "validation reference", "zero bias: PRMSE / ROE", "dataset's bias: PRMSE / ROE",
                  "clock offset", "extrinsic vs calibration", "bias random walk used ÷ calibration's",
                  "pose outliers", "windows dropped (by reason)")


def _detail_row(r: SequenceRow) -> Html:
    reference = ("" if r.reference is None
                 else f"{code_words(r.reference)} ({'independent' if r.independent else 'fitted'})")
    noise = join((_walk_words(axis, scale, axis in r.at_bound) for axis, scale in r.noise_scales.items()), sep=", ")
    dropped = join((_drop_words(k, v) for k, v in sorted(r.dropped.items())), sep=", ")
    cells = [
        _cell(r.name, r.name),
        _cell(reference, "" if r.independent is None else int(bool(r.independent))) if reference
        else _why("not validated"),
        _metric_cell(r, "zero"),
        _metric_cell(r, "dataset's"),
        _cell(fmt_unc(1e3 * r.offset_s, None if r.offset_std_s is None else 1e3 * r.offset_std_s, "ms"),
              r.offset_s, class_="num") if r.offset_s is not None else _why("no recovery"),
        _cell(f"{r.extrinsic_sigmas:.1f} σ", r.extrinsic_sigmas, class_="num") if r.extrinsic_sigmas is not None
        else _why("no calibration given"),
        _cell(noise, max(r.noise_scales.values())) if r.noise_scales else _why("not chosen"),
        _cell(f"{r.outlier_share:.1%}", r.outlier_share, class_="num") if r.outlier_share is not None
        else _why("no recovery"),
        (_cell(dropped or "none", sum(r.dropped.values()), class_="small") if r.windows is not None
         else _why("left out" if r.left_out else "not windowed")),
    ]
    return tag("tr", join(cells), data_sequence=r.name)


def _sortable(headers: Sequence[str], rows: Sequence[Html], table_id: str, class_: str) -> Html:
    head = tag("thead", tag("tr", join(tag("th", h, title="sort by this column") for h in headers)))
    grid = tag("table", Html(head + tag("tbody", join(rows))), class_=f"data sortable {class_}", id=table_id)
    return scroll_box(grid)


def by_severity(rows: Sequence[SequenceRow]) -> list[SequenceRow]:
    """The rows, most severe verdict first (FAIL, WARN, PASS, not validated); the given order within one."""
    return sorted(rows, key=lambda r: SEVERITY[r.verdict])


def _report_link(inp: DatasetInputs, name: str, out_dir: Path) -> str:
    target = inp.results / Stage.REPORT.folder / name / REPORT_HTML
    return Path(os.path.relpath(target.resolve(), out_dir)).as_posix()


def _sequences(inp: DatasetInputs, out_dir: Path) -> Html:
    rows = [_glance_row(r, _report_link(inp, r.name, out_dir), inp.manifest is not None) for r in by_severity(inp.rows)]
    note = p("The label is the recovered bias. PRMSE (position, mm) / ROE (rotation, deg) of 1-s windows integrated "
             "with it, beside the same label held constant from the first window, and recovered with each window's "
             "block held out (cross-validation, where it ran). Rows: most severe verdict first; click a header to "
             "sort. The other figures of each sequence are in the table 'Sequences in detail' below, and all of "
             "them in its report (the sequence's link).", class_="small")
    return section("sequences", SECTIONS[1][1],
                   Html(_sortable(GLANCE_HEADERS, rows, "sequences-table", "glance") + note))


def _details(inp: DatasetInputs) -> Html:
    rows = [_detail_row(r) for r in by_severity(inp.rows)]
    note = p("'independent': the validation reference is not the pose stream the label was fitted to. Extrinsic: "
             "the larger of the rotation and translation differences from the calibration file, in their sigmas. "
             "Bias random walk: the one the recovery used, as a multiple of the calibration's ('at a bound': the "
             "evidence search chose the edge of its grid, so the data may want more). Pose outliers: share of "
             "keyframe poses rejected.", class_="small")
    return section("details", SECTIONS[3][1], Html(_sortable(DETAIL_HEADERS, rows, "details-table", "details") + note))


def _next_steps(inp: DatasetInputs, out_dir: Path) -> Html:
    items = []
    for r in by_severity(inp.rows):
        if r.verdict not in (Verdict.WARN, Verdict.FAIL):
            continue
        head = Html(tag("a", r.name, href=_report_link(inp, r.name, out_dir)) + esc(f" ({r.verdict.value}): "))
        steps = list(r.next_steps) or ["see the reasons in its report"]
        items.append(Html(head + (esc(steps[0]) if len(steps) == 1 else ul(steps))))
    body = ul(items, class_="next-steps") if items else p("Nothing to do: no sequence has a WARN or FAIL.")
    return section("next", SECTIONS[2][1], body)


def _table_i(inp: DatasetInputs, out_dir: Path) -> Html:
    avg = average_rows(inp.table)
    training = inp.results / Stage.REPORT.folder / "training.html"
    parts = []
    if avg:
        rows = [tag("tr", join([tag("td", m + (" (oracle)" if oracle and "oracle" not in m.lower() else "")),
                                tag("td", f"{x:.4f}", class_="num"), tag("td", f"{y:.4f}", class_="num")]),
                    class_="oracle" if oracle else None, data_oracle="1" if oracle else None)
                for m, x, y, oracle in avg]
        head = tag("thead", tag("tr", join(tag("th", h) for h in ("method", "average PRMSE (m)",
                                                                   "average ROE (deg)"))))
        parts.append(scroll_box(tag("table", Html(tag("caption", "Table I, Average row") + head
                                                  + tag("tbody", join(rows))), class_="data", id="table-i")))
        if any(o for *_, o in avg):
            parts.append(p(ORACLE_NOTE, class_="small footnote"))
    else:
        parts.append(p("No Table I (the learning stages did not run: they need train, val and test sequences).",
                       class_="missing"))
    if training.is_file():
        link = tag("a", "The training report", href=Path(os.path.relpath(training.resolve(), out_dir)).as_posix())
        parts.append(p(Html(link + esc(": Table I per sequence, training curves, predictions, calibration."))))
    return section("table", SECTIONS[4][1], join(parts))


def _figure(inp: DatasetInputs) -> Html:
    wide = bias_overview_figure(inp.rows, "wide")
    if wide is None:
        return section("bias", SECTIONS[5][1], p("No recovered bias to draw.", class_="missing"))
    clipped = channel_outliers(inp.rows)
    note = ("" if not clipped else " Clipped, so that they do not set the scale: " + "; ".join(
        f"{CHANNELS[c]}: " + ", ".join(f"{n} (peak {v:.3g} {UNITS[c]})" for n, v in found)
        for c, found in sorted(clipped.items())) + ".")
    return section("bias", SECTIONS[5][1], figure_picture(
        wide, bias_overview_figure(inp.rows, "narrow"), "recovered bias of every sequence",
        "Recovered bias (6 channels) of every sequence on a shared time axis from each recording's start: one "
        "colour per sequence, named in the legend with its split and verdict; line style by verdict." + note))


def render_dataset_report(inp: DatasetInputs, out_dir: Path) -> str:
    """The page as HTML text; links are relative to ``out_dir`` (the folder the page is written to)."""
    body = join([
        tag("h1", "biasgt dataset report"),
        p(f"results: {inp.results.name}/ · {len(inp.rows)} sequences", class_="meta"),
        tag("nav", tag("ol", join(tag("li", tag("a", t, href=f"#{a}")) for a, t in SECTIONS)), class_="toc"),
        _headline(inp), _sequences(inp, out_dir), _next_steps(inp, out_dir), _details(inp),
        _table_i(inp, out_dir), _figure(inp),
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
