"""The validation stage's output folder, written and read in one place.

Files (names defined here only): ``validation.json`` (:class:`ValidationSummary`: verdict,
reasons and their rule codes, per-source metrics, reference, dropped windows, notes) and ``windows.parquet`` (one
row per window and source: ``t0_ns, source, pos_err_m, rot_err_deg, flagged``).

Non-finite numbers are written as ``null`` (:func:`pipeline.files.jsonio.dumps`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.files.atomic import atomic_dir, atomic_path
from pipeline.errors import InputFormatError, ValidationError
from pipeline.files.jsonio import JsonRecord, dumps, read_json_object
from pipeline.types import Verdict  # the project's one verdict (the rules: validation.rules)

SCHEMA_VERSION = 1
VALIDATION_JSON = "validation.json"
WINDOWS_PARQUET = "windows.parquet"
#: The source name of the recovered bias cross-validated by time blocks (``crossval_block_s``).
HELDOUT_SOURCE = "recovered_heldout"
WINDOWS_COLUMNS = ("t0_ns", "source", "pos_err_m", "rot_err_deg", "flagged")

_RERUN = "re-run 'biasgt validate' (or the workflow's validate stage)"


@dataclass(frozen=True)
class ValidationSummary(JsonRecord):
    """``validation.json``: the typed fields plus the whole object.

    Attributes:
        data: The whole JSON object (per-source metrics, reference, config: the report's tables);
            ``summary["key"]`` reads it.
        sequence: Sequence name.
        verdict: PASS, WARN or FAIL.
        reasons: Why (plain sentences).
        reason_codes: The rule code of each reason (:data:`validation.rules.RULES`), same order.
        candidate: Name of the judged bias source.
        notes: What could not be validated, and other remarks.
        next_steps: What to do about a WARN or FAIL.
        recovery_bias_sha256: SHA-256 of the judged recovery's ``bias.csv`` (None: no recovery judged, or
            a validation.json written before it was recorded).
        sigma_factor: Per axis, the factor that widens the recovered sigma to cover the held-out blocks
            (``heldout.sigma_check.factor``, :mod:`validation.crossval.sigma`; 1 where confirmed), [6],
            or None where no held-out check ran.
    """

    data: Mapping[str, Any]
    sequence: str
    verdict: Verdict
    reasons: tuple[str, ...]
    candidate: str
    notes: tuple[str, ...]
    next_steps: tuple[str, ...] = ()
    reason_codes: tuple[str, ...] = ()
    recovery_bias_sha256: str | None = None
    sigma_factor: tuple[float, ...] | None = None

    @classmethod
    def from_json(cls, data: Mapping[str, Any], path: str | Path | None = None) -> ValidationSummary:
        """Parse the JSON object.

        Raises:
            InputFormatError: No known verdict; a ``heldout.sigma_check.factor`` that is not six factors of
                at least 1.
        """
        try:
            verdict = Verdict(data.get("verdict"))
        except ValueError:
            raise InputFormatError(f"validation.json has no known verdict ({data.get('verdict')!r})", path=path,
                                   field="verdict", hint=_RERUN) from None
        return cls(data=dict(data), sequence=str(data.get("sequence", "")), verdict=verdict,
                   reasons=tuple(str(r) for r in data.get("reasons") or ()),
                   candidate=str(data.get("candidate", "")), notes=tuple(str(n) for n in data.get("notes") or ()),
                   next_steps=tuple(str(n) for n in data.get("next_steps") or ()),
                   reason_codes=tuple(str(c) for c in data.get("reason_codes") or ()),
                   recovery_bias_sha256=data.get("recovery_bias_sha256"), sigma_factor=_sigma_factor(data, path))


def _sigma_factor(data: Mapping[str, Any], path: str | Path | None) -> tuple[float, ...] | None:
    """``heldout.sigma_check.factor`` [6], or None where absent.

    Raises:
        InputFormatError: Not six finite factors of at least 1.
    """
    factor = ((data.get("heldout") or {}).get("sigma_check") or {}).get("factor")
    if factor is None:
        return None
    try:
        out = np.asarray(factor, dtype=np.float64)
    except (TypeError, ValueError):
        out = np.zeros(0)
    if out.shape != (6,) or not np.all(np.isfinite(out) & (out >= 1.0)):
        raise InputFormatError(f"heldout.sigma_check.factor is not six factors of at least 1 ({factor!r})", path=path,
                               field="heldout.sigma_check.factor", hint=_RERUN)
    return tuple(float(x) for x in out)


def read_summary(folder: str | Path) -> ValidationSummary:
    """``folder/validation.json``.

    Raises:
        InputFormatError: Missing, unreadable or malformed.
    """
    path = Path(folder) / VALIDATION_JSON
    return ValidationSummary.from_json(read_json_object(path, hint=_RERUN), path)


def read_windows(folder: str | Path) -> pd.DataFrame:
    """``folder/windows.parquet`` (columns :data:`WINDOWS_COLUMNS`)."""
    return pd.read_parquet(Path(folder) / WINDOWS_PARQUET)


def _write_files(summary: Mapping[str, Any], windows: pd.DataFrame, folder: Path, json_path: Path | None = None,
                 parquet_path: Path | None = None) -> None:
    pq.write_table(pa.Table.from_pandas(windows, preserve_index=False), parquet_path or folder / WINDOWS_PARQUET)
    (json_path or folder / VALIDATION_JSON).write_text(dumps(summary), encoding="utf-8")


def write_folder(summary: Mapping[str, Any], windows: pd.DataFrame, out_dir: str | Path) -> Path:
    """Write ``out_dir/validation.json`` (``summary``) and ``out_dir/windows.parquet`` atomically.

    A new or validation-only folder is replaced as a whole (:func:`atomic_dir`); a folder that
    holds other files (e.g. the recovery's) keeps them and gets both files through temporary
    siblings, ``validation.json`` renamed last.

    Returns:
        ``out_dir``.
    """
    out_dir = Path(out_dir)
    ours = {VALIDATION_JSON, WINDOWS_PARQUET}
    if not out_dir.exists() or (out_dir.is_dir() and {p.name for p in out_dir.iterdir()} <= ours):
        with atomic_dir(out_dir) as tmp:
            _write_files(summary, windows, tmp)
    else:
        if not out_dir.is_dir():
            raise ValidationError("output path exists and is not a folder", path=out_dir,
                                  hint="give a folder for --out")
        with atomic_path(out_dir / VALIDATION_JSON) as tj, atomic_path(out_dir / WINDOWS_PARQUET) as tp:
            _write_files(summary, windows, out_dir, tj, tp)
    return out_dir
