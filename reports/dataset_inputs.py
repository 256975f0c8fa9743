"""The dataset page's inputs: one :class:`SequenceRow` per sequence of a results folder, read leniently.

Reads, per sequence, ``validation/<name>/validation.json`` (through
:class:`validation.outputs.ValidationSummary`), ``recovery/<name>/recovery.json`` and ``bias.csv``,
and for the whole run ``windows/dataset/manifest.json`` and ``evaluation/table.csv``. A missing
or unreadable file leaves its cells empty and is listed in :attr:`DatasetInputs.problems`.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.bias_table import BiasTrack, read_bias_csv
from pipeline.errors import BiasgtError
from pipeline.layout import WINDOWS_DATASET, Stage
from pipeline.types import Verdict
from recovery.outputs import BIAS_CSV, read_report
from training.data.dataset import MANIFEST
from training.evaluation.table import AVERAGE, TABLE_CSV
from training.references import get_reference, reference_names
from validation.outputs import HELDOUT_SOURCE, ValidationSummary, read_summary

log = logging.getLogger(__name__)

#: The rows of the per-sequence comparison: validation source kind -> column label.
BASELINE_KINDS = (("zero", "zero"), ("constant_first_window", "constant"), ("dataset", "dataset's"))


@dataclass
class SequenceRow:
    """What the dataset page shows of one sequence (None: not available).

    Attributes:
        name: Sequence name.
        split: train / val / test / none, or None when unknown.
        verdict: PASS / WARN / FAIL, or None (not validated).
        reason: The leading reason of the verdict; ``reason_code``: its rule's code ("" when the file has none).
        next_steps: What the validation says to do about a WARN or FAIL.
        pose_stream / pose_kind: The pose stream the labels (the recovered bias) came from.
        reference: The validation reference, in words; ``independent``: it is not the stream fitted.
        metrics: Source label (``recovered``, ``zero``, ``constant``, ``dataset's``, ``held-out``)
            -> ``(prmse_m, roe_deg)``.
        offset_s / offset_std_s: The clock offset and its sigma.
        extrinsic_sigmas: The extrinsic's difference from the calibration in its sigmas (max of
            rotation and translation), None when no calibration was given.
        noise_scales: ``gyro`` / ``acc`` -> the random-walk scale chosen; ``at_bound``: those at a
            bound of the evidence search.
        outlier_share: Share of keyframe poses rejected as outliers.
        windows / candidates / dropped: Windows in the dataset, candidate windows, dropped by reason.
        left_out: Why the sequence stayed out of the window dataset.
        bias: The recovered bias track (for the figure).
    """

    name: str
    split: str | None = None
    verdict: Verdict | None = None
    reason: str = ""
    reason_code: str = ""
    next_steps: tuple[str, ...] = ()
    pose_stream: str | None = None
    pose_kind: str | None = None
    reference: str | None = None
    independent: bool | None = None
    metrics: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)
    offset_s: float | None = None
    offset_std_s: float | None = None
    extrinsic_sigmas: float | None = None
    noise_scales: dict[str, float] = field(default_factory=dict)
    at_bound: tuple[str, ...] = ()
    outlier_share: float | None = None
    windows: int | None = None
    candidates: int | None = None
    dropped: dict[str, int] = field(default_factory=dict)
    left_out: str | None = None
    bias: BiasTrack | None = None


@dataclass
class DatasetInputs:
    """Everything the dataset page shows.

    Attributes:
        results: The ``results/`` folder.
        rows: One per sequence, in order.
        manifest: ``manifest.json`` of the window dataset, or None.
        table: Table I (``table.csv``: one row per sequence and ``Average``), or None.
        problems: Files that could not be read, one sentence each.
    """

    results: Path
    rows: list[SequenceRow]
    manifest: dict[str, Any] | None = None
    table: pd.DataFrame | None = None
    problems: list[str] = field(default_factory=list)


def results_root(results_dir: str | Path) -> Path:
    """The ``results/`` folder: ``results_dir`` itself, or the ``results/`` folder it holds."""
    root = Path(results_dir)
    if not (root / Stage.VALIDATE.folder).is_dir() and (root / "results").is_dir():
        return root / "results"
    return root


def sequence_names(results: Path) -> list[str]:
    """The sequences with a recovery or validation folder, sorted."""
    names = set()
    for stage in (Stage.RECOVER, Stage.VALIDATE):
        folder = results / stage.folder
        if folder.is_dir():
            names |= {p.name for p in folder.iterdir() if p.is_dir()}
    return sorted(names)


def _num(d: Any, *keys: str) -> float | None:
    for k in keys:
        if not isinstance(d, Mapping):
            return None
        d = d.get(k)
    if isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(float(d)):
        return None
    return float(d)


def gather_dataset(results_dir: str | Path, sequences: Sequence[str] | None = None,
                   splits: Mapping[str, str] | None = None) -> DatasetInputs:
    """Read the results folder for the dataset page.

    Args:
        results_dir: ``results/`` or the folder holding it.
        sequences: The sequences, in order (default: every one with a recovery or validation folder).
        splits: Name -> split (default: the window dataset's manifest).
    """
    results = results_root(results_dir)
    inputs = DatasetInputs(results, [])
    inputs.manifest = _read_json(results / Stage.WINDOWS.folder / WINDOWS_DATASET / MANIFEST, inputs, optional=True)
    table_path = results / Stage.EVALUATE.folder / TABLE_CSV
    if table_path.is_file():
        try:
            inputs.table = pd.read_csv(table_path, index_col=0)
        except (OSError, ValueError) as exc:
            inputs.problems.append(f"{table_path}: unreadable ({exc})")
    entries = (inputs.manifest or {}).get("sequences") or {}
    excluded = (inputs.manifest or {}).get("excluded") or {}
    for name in (list(sequences) if sequences is not None else sequence_names(results)):
        row = SequenceRow(name, split=(splits or {}).get(name) or (entries.get(name) or {}).get("split"))
        _fill_validation(row, results / Stage.VALIDATE.folder / name, inputs)
        _fill_recovery(row, results / Stage.RECOVER.folder / name, inputs)
        entry = entries.get(name)
        if entry is not None:
            row.windows, row.candidates = int(entry.get("windows", 0)), int(entry.get("candidates", 0))
            row.dropped = {str(k): int(v) for k, v in (entry.get("dropped") or {}).items() if v}
        elif name in excluded:
            row.left_out = str(excluded[name])
        elif inputs.manifest is not None:
            row.left_out = "no split (not windowed)" if row.split in (None, "none") else "not in the window dataset"
        inputs.rows.append(row)
    return inputs


def _read_json(path: Path, inputs: DatasetInputs, optional: bool = False) -> dict[str, Any] | None:
    if not path.is_file():
        if not optional:
            inputs.problems.append(f"{path}: missing")
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        inputs.problems.append(f"{path}: unreadable ({exc})")
        return None
    return data if isinstance(data, dict) else None


def _fill_validation(row: SequenceRow, folder: Path, inputs: DatasetInputs) -> None:
    try:
        summary: ValidationSummary = read_summary(folder)
    except BiasgtError as exc:
        inputs.problems.append(f"{row.name}: no validation ({exc})")
        return
    row.verdict = summary.verdict
    row.reason = summary.reasons[0] if summary.reasons else ""
    row.reason_code = summary.reason_codes[0] if summary.reasons and summary.reason_codes else ""
    row.next_steps = tuple(summary.next_steps)
    sources = summary.data.get("sources") or {}
    cand = sources.get(summary.candidate) or {}
    row.metrics["recovered"] = (_num(cand, "prmse_m"), _num(cand, "roe_deg"))
    for kind, label in BASELINE_KINDS:
        found = next((s for s in sources.values() if isinstance(s, Mapping) and s.get("kind") == kind), None)
        if found is not None:
            row.metrics[label] = (_num(found, "prmse_m"), _num(found, "roe_deg"))
    if isinstance(sources.get(HELDOUT_SOURCE), Mapping):
        held = sources[HELDOUT_SOURCE]
        row.metrics["held-out"] = (_num(held, "prmse_m"), _num(held, "roe_deg"))
    ref = summary.data.get("reference") or {}
    row.reference = str(ref.get("stream") or ref.get("source") or ref.get("kind") or "") or None
    row.independent = ref.get("kind") != "poses"  # refined by the recovery's stream (_fill_recovery)


def _fill_recovery(row: SequenceRow, folder: Path, inputs: DatasetInputs) -> None:
    try:
        report = read_report(folder)
    except BiasgtError as exc:
        inputs.problems.append(f"{row.name}: no recovery ({exc})")
        return
    rec = report.data
    row.pose_stream, row.pose_kind = report.pose_stream, rec.get("pose_source_kind")
    if row.reference is not None and row.independent is False:
        row.independent = row.reference != report.pose_stream
    row.offset_s, row.offset_std_s = report.time_offset_s, _num(rec, "pose_time_offset_std_s")
    diff = (rec.get("extrinsic") or {}).get("difference_from_calibration") or {}
    sig = [x for x in (_num(diff, "rotation_sigmas"), _num(diff, "translation_sigmas")) if x is not None]
    row.extrinsic_sigmas = max(sig) if sig else None
    noise = rec.get("noise") or {}
    grid = (rec.get("config") or {}).get("random_walk_scales") or []
    bound = []
    for axis in ("gyro", "acc"):
        scale = _num(noise, f"{axis}_random_walk_scale")
        if scale is None:
            continue
        row.noise_scales[axis] = scale
        if noise.get("method") == "evidence" and grid and (scale >= max(grid) or scale <= min(grid)):
            bound.append(axis)
    row.at_bound = tuple(bound)
    out, kf = _num(rec, "outliers_rejected"), _num(rec, "keyframes")
    samples = _num(rec.get("pose_fusion") or {}, "samples_rejected") or 0.0
    if out is not None and kf:
        row.outlier_share = max(out - samples, 0.0) / kf  # outliers_rejected counts fused samples too
    if (folder / BIAS_CSV).is_file():
        try:
            row.bias = read_bias_csv(folder / BIAS_CSV)
        except BiasgtError as exc:
            inputs.problems.append(f"{row.name}: {exc}")


def oracle_labels() -> tuple[str, ...]:
    """Table I labels of the reference rows that read the ground truth at test time (not ranked)."""
    return tuple(get_reference(n).label for n in reference_names() if get_reference(n).oracle)


def is_oracle(column: str) -> bool:
    """Whether a Table I column (``<label>`` or ``<label> <variant>``) is an oracle row."""
    return any(column == label or column.startswith(label + " ") for label in oracle_labels())


def average_rows(table: pd.DataFrame | None) -> list[tuple[str, float, float, bool]]:
    """Table I's ``Average`` row as ``(method, prmse_m, roe_deg, oracle)`` per method, in the table's order."""
    if table is None or AVERAGE not in table.index:
        return []
    avg = table.loc[AVERAGE]
    out = []
    for col in table.columns:
        if col.endswith(" PRMSE_m") and f"{col[:-len(' PRMSE_m')]} ROE_deg" in table.columns:
            method = col[:-len(" PRMSE_m")]
            out.append((method, float(avg[col]), float(avg[f"{method} ROE_deg"]), is_oracle(method)))
    return [r for r in out if np.isfinite(r[1]) or np.isfinite(r[2])]
