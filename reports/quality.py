"""The per-sequence dataset quality report: one self-contained HTML file.

Inputs (the workflow's layout ``results/<stage>/<sequence>/``; every stage but ingest may be
missing, and the page then says so plainly and shows the rest):

* ingest: the canonical store (:func:`pipeline.store.read_store`), its stream summaries and
  input checks (:mod:`pipeline.checks`) and the repairs applied at conversion;
* recovery: ``bias.csv`` (:func:`pipeline.bias_table.read_bias_csv`), ``recovery.json``
  (clock offset, extrinsic, gravity, noise used, residual statistics, warnings),
  ``trajectory_tum.txt`` (:mod:`recovery.outputs`) and, when the recovery
  writes one, a per-keyframe residual table (``residuals.parquet`` or ``residuals.csv``);
* validation: ``validation.json`` and ``windows.parquet`` (:mod:`validation.validate`).

Sections, in order: verdict; streams and input checks; calibration estimated; recovered bias
over time; pose and IMU residuals; integration-error distributions; Allan deviation.

The page has no external resources: figures are PNG ``data:`` URIs, the stylesheet and a tiny
script (it counts images that failed to decode, for the headless-browser test) are inline.
It is written atomically (:func:`pipeline.files.atomic.atomic_path`): a failure leaves no file.
"""

from __future__ import annotations

import datetime as _dt
import logging
from pathlib import Path


from pipeline import __version__
from pipeline.files.atomic import atomic_path
from pipeline.errors import BiasgtError, ConfigError
from pipeline.layout import DATASET_REPORT_HTML, REPORT_HTML, Stage
from pipeline.types import Sequence
from recovery.noise.allan import imu_allan
from reports.html import Html, back_link, esc, join, p, page, tag
from reports.quality_calibration import bias_section, calibration_section
from reports.quality_inputs import SECTIONS, ReportInputs, gather_inputs
from reports.quality_residuals import allan_section, integration_section, residuals_section
from reports.quality_verdict import streams_section, verdict_section
from reports import plots  # noqa: F401  (the page's figures: tests replace one through quality.plots)
from reports.quality_calibration import gyro_consistency_note
from reports.quality_inputs import STAGE_FOLDERS, other_estimates_sentence, stage_dirs
from reports.quality_residuals import flagged_stretches
from reports.quality_verdict import dataset_bias_label, mm_pair, verdict_summary
from validation.plausibility import gravity_tilt_deg, pose_residuals

__all__ = ["SECTIONS", "STAGE_FOLDERS", "ReportInputs", "build_quality_report", "dataset_bias_label", "dataset_page_href", "flagged_stretches",
           "gather_inputs", "gravity_tilt_deg", "gyro_consistency_note", "mm_pair", "other_estimates_sentence",
           "pose_residuals", "render_report", "stage_dirs", "verdict_summary"]

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------- page


def dataset_page_href(out_path: str | Path) -> str | None:
    """The dataset page relative to a quality report written at the workflow's place
    (``results/report/<sequence>/report.html`` -> ``../index.html``); None elsewhere."""
    out = Path(out_path)
    if out.name == REPORT_HTML and out.parent.parent.name == Stage.REPORT.folder:
        return f"../{DATASET_REPORT_HTML}"
    return None


def render_report(inp: ReportInputs, index_href: str | None = None) -> str:
    """The whole HTML page for ``inp`` (no file written); ``index_href``: the dataset page, linked on top."""
    seq = inp.sequence
    allan, allan_error = None, None
    if seq.imu is not None and len(seq.imu) >= 10:
        try:
            allan = imu_allan(seq.imu)
        except BiasgtError as exc:
            allan_error = str(exc)
    else:
        allan_error = "the sequence has no IMU readings"
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    where = [f"ingest: {inp.ingest_dir}", f"recovery: {inp.recovery_dir or 'not given'}",
             f"validation: {inp.validation_dir or 'not given'}"]
    header = join([
        back_link(index_href),
        tag("h1", f"Sequence quality report: {seq.name}"),
        p(Html(f"biasgt {esc(__version__)} · generated {esc(now)}" + tag("br") + join(where, " · ")), class_="meta"),
    ])
    toc = tag("nav", Html(tag("strong", "Contents") + tag("ol", join(
        tag("li", tag("a", title.split(". ", 1)[1], href=f"#{anchor}")) for anchor, title in SECTIONS))),
        class_="toc")
    body = join([
        header,
        verdict_section(inp),
        toc,
        streams_section(inp),
        calibration_section(inp, allan),
        bias_section(inp),
        residuals_section(inp),
        integration_section(inp),
        allan_section(inp, allan, allan_error),
    ])
    return page(f"biasgt sequence quality report: {seq.name}", body)


def build_quality_report(
    ingest_dir: str | Path,
    *,
    recovery_dir: str | Path | None = None,
    validation_dir: str | Path | None = None,
    out_path: str | Path,
    sequence: Sequence | None = None,
) -> Path:
    """Write the quality report of one sequence as one self-contained HTML file (linking back to the dataset
    page when written at the workflow's place, :func:`dataset_page_href`).

    Args:
        ingest_dir: The sequence's canonical store (``results/ingest/<sequence>``); required.
        recovery_dir: ``results/recovery/<sequence>`` (bias.csv, recovery.json, ...), or None.
        validation_dir: ``results/validation/<sequence>`` (validation.json, windows.parquet), or None.
        out_path: The HTML file to write (atomically; parent folders are created).
        sequence: The sequence already loaded from ``ingest_dir`` when that is not a store
            (:func:`gather_inputs`).

    Returns:
        ``out_path`` as a Path.

    Raises:
        InputFormatError: ``ingest_dir`` is not a canonical store.
        ConfigError: ``out_path`` is an existing folder.
    """
    out_path = Path(out_path)
    if out_path.is_dir():
        raise ConfigError("the report output is a folder", path=out_path, field="--out",
                          hint="give a file name such as report.html")
    inputs = gather_inputs(ingest_dir, recovery_dir=recovery_dir, validation_dir=validation_dir, sequence=sequence)
    for note in inputs.missing + inputs.problems:
        log.info("report %s: %s", inputs.sequence.name, note)
    text = render_report(inputs, dataset_page_href(out_path))
    with atomic_path(out_path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    log.info("wrote %s (%.0f kB)", out_path, len(text) / 1024)
    return out_path
