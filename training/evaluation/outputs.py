"""The evaluation's output folder, written and read in one place.

Files (names defined here only), all written by :func:`write_evaluation` through
:func:`pipeline.files.atomic.atomic_dir` (all of them or none):

* ``summary.json``: :class:`EvaluationSummary` (``schema_version`` :data:`SCHEMA_VERSION`),
  read back by :func:`read_summary`; its rows are :class:`RowResult` (a sampler and an
  :class:`Aggregation`, with :class:`Metrics` per sequence and on average), its calibration
  :class:`Calibration`, its clip use :class:`training.models.clip.ClipUse`.
* ``windows.parquet``: one row per window, sampler, aggregation and sample.
* ``predictions.parquet``: per time step and channel (:mod:`training.evaluation.predictions`).
* ``examples.parquet``: a few test windows, the same for every method, for the report's figure.

The records are computed by :mod:`training.evaluation.evaluate`; Table I (:mod:`training.evaluation.table`), the
training report and the benchmarks read them through here.
"""

from __future__ import annotations

import dataclasses
import enum
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.files.atomic import atomic_dir
from pipeline.errors import InputFormatError
from pipeline.files.jsonio import to_plain
from training.models.clip import ClipUse
from training.config import Sampler
from training.evaluation.predictions import PREDICTIONS_PARQUET

__all__ = [
    "Aggregation",
    "Calibration",
    "EvaluationResult",
    "EvaluationSummary",
    "Metrics",
    "RowResult",
    "read_summary",
    "write_evaluation",
]

SCHEMA_VERSION = 1
SUMMARY_JSON = "summary.json"
WINDOWS_PARQUET = "windows.parquet"
EXAMPLES_PARQUET = "examples.parquet"


class Aggregation(str, enum.Enum):
    """How the K samples of a window become figures (see :mod:`training.evaluation.evaluate`)."""

    SAMPLES = "samples"  # metrics per sample, averaged over the K samples (the paper)
    MEAN = "mean"  # the per-time-step mean of the K samples as the prediction
    MEDIAN = "median"  # the per-time-step median of the K samples as the prediction


# ----------------------------------------------------------------------------- records


@dataclass(frozen=True)
class Metrics:
    """PRMSE (m) and ROE (deg); with K samples, their mean over samples and std over samples."""

    prmse_m: float
    roe_deg: float
    prmse_std_m: float = 0.0
    roe_std_deg: float = 0.0
    windows: int = 0


@dataclass(frozen=True)
class RowResult:
    """One row of figures: a sampler (None: not a diffusion model) and an aggregation."""

    sampler: Sampler | None
    aggregation: Aggregation
    sequences: dict[str, Metrics]
    average: Metrics

    @property
    def key(self) -> str:
        """Column suffix: '' for the headline row, else 'released', 'mean', 'released mean', ..."""
        parts = []
        if self.sampler not in (None, Sampler.DDIM):
            parts.append(self.sampler.value)
        if self.aggregation is not Aggregation.SAMPLES:
            parts.append(self.aggregation.value)
        return " ".join(parts)


@dataclass(frozen=True)
class Calibration:
    """Coverage of the ground truth by the central intervals of the K samples, per channel."""

    sampler: Sampler
    levels: tuple[float, ...]
    coverage: tuple[tuple[float, ...], ...]  # [level][channel]

    def at(self, level: float) -> tuple[float, ...]:
        return self.coverage[self.levels.index(level)]


@dataclass(frozen=True)
class EvaluationSummary:
    """What ``summary.json`` holds (``schema_version`` 1)."""

    method: str
    label: str
    kind: str  # "learned", "reference" or "oracle"
    samples: int
    seed: int
    steps: int | None
    windows: int
    windows_per_sequence: dict[str, int]
    protocol: str
    gravity_source: dict[str, str]
    rows: tuple[RowResult, ...]
    calibration: tuple[Calibration, ...] = ()
    clip: tuple[ClipUse, ...] = ()
    checkpoint: dict[str, Any] = field(default_factory=dict)
    dataset: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    schema_version: int = SCHEMA_VERSION

    def row(self, sampler: Sampler | None = None, aggregation: Aggregation = Aggregation.SAMPLES) -> RowResult:
        """The row of ``sampler`` (default: the first) and ``aggregation``."""
        for r in self.rows:
            if (sampler is None or r.sampler in (None, sampler)) and r.aggregation is aggregation:
                return r
        raise KeyError((sampler, aggregation))

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> EvaluationSummary:
        d = dict(d)
        d["rows"] = tuple(
            RowResult(None if r["sampler"] is None else Sampler(r["sampler"]), Aggregation(r["aggregation"]),
                      {k: Metrics(**v) for k, v in r["sequences"].items()}, Metrics(**r["average"]))
            for r in d["rows"])
        d["calibration"] = tuple(
            Calibration(Sampler(c["sampler"]), tuple(c["levels"]), tuple(tuple(x) for x in c["coverage"]))
            for c in d.get("calibration", ()))
        d["clip"] = tuple(ClipUse.from_dict(c) for c in d.get("clip", ()))
        return cls(**d)


@dataclass
class EvaluationResult:
    """A summary and its per-window, example and prediction frames."""

    summary: EvaluationSummary
    windows: pd.DataFrame
    examples: pd.DataFrame
    predictions: pd.DataFrame = field(default_factory=pd.DataFrame)


# ----------------------------------------------------------------------------- reading and writing


def write_evaluation(result: EvaluationResult, out_dir: str | Path) -> Path:
    """Write ``summary.json``, ``windows.parquet``, ``predictions.parquet`` and ``examples.parquet``
    atomically into ``out_dir`` (all of them or none)."""
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        result.windows.to_parquet(tmp / WINDOWS_PARQUET, index=False)
        result.predictions.to_parquet(tmp / PREDICTIONS_PARQUET, index=False)
        result.examples.to_parquet(tmp / EXAMPLES_PARQUET, index=False)
        (tmp / SUMMARY_JSON).write_text(json.dumps(result.summary.to_dict(), indent=2) + "\n", encoding="utf-8")
    return out_dir


def read_summary(path: str | Path) -> EvaluationSummary:
    """Load ``summary.json`` (a file or its folder).

    Raises:
        InputFormatError: Missing, unreadable or of another schema version.
    """
    path = Path(path)
    if path.is_dir():
        path = path / SUMMARY_JSON
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        if d.get("schema_version") != SCHEMA_VERSION:
            raise InputFormatError(f"evaluation summary of schema {d.get('schema_version')}, expected "
                                   f"{SCHEMA_VERSION}", path=path, hint="re-run 'biasgt evaluate'")
        return EvaluationSummary.from_dict(d)
    except FileNotFoundError:
        raise InputFormatError("no evaluation summary", path=path, hint="run 'biasgt evaluate --out DIR' first") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputFormatError(f"cannot read the evaluation summary ({exc})", path=path,
                               hint="re-run 'biasgt evaluate'") from None
