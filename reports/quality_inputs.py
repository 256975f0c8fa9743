"""The quality report's inputs (the stage folders of one sequence, read leniently) and the small
helpers its sections share.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from pipeline.bias_table import BiasTrack, read_bias_csv
from pipeline.errors import BiasgtError, InputFormatError
from pipeline.layout import Stage
from pipeline.store import is_store, read_store
from pipeline.types import DEFAULT_GRAVITY_MPS2, NS_PER_S, PoseSeries, Sequence
from recovery.outputs import (
    BIAS_CSV,
    REPORT_JSON,
    RESIDUALS_CSV,
    TRAJECTORY_TUM,
    RecoveryReport,
    read_report,
    read_residuals,
    read_trajectory,
)
from validation.outputs import (
    HELDOUT_SOURCE,
    VALIDATION_JSON,
    WINDOWS_PARQUET,
    ValidationSummary,
    read_summary,
    read_windows,
)
from reports.html import Html, fmt, tag

log = logging.getLogger(__name__)



#: Stage folder names under a results folder (the workflow's, else the rule's); the first that exists is used.
STAGE_FOLDERS = {
    "ingest": (Stage.INGEST.folder,),
    "recovery": (Stage.RECOVER.folder, Stage.RECOVER.value),
    "validation": (Stage.VALIDATE.folder, Stage.VALIDATE.value),
}
#: Rows of the flagged-window table shown (the rest are counted).
MAX_FLAGGED_ROWS = 40

#: Section anchors and headings, in page order (the tests check all of them).
SECTIONS = (
    ("verdict", "1. Verdict"),
    ("streams", "2. Streams and input checks"),
    ("calibration", "3. Calibration estimated"),
    ("bias", "4. Recovered bias over time"),
    ("residuals", "5. Pose and IMU residuals"),
    ("integration", "6. Integration error per bias source"),
    ("allan", "7. Allan deviation of the IMU"),
)
TITLE = dict(SECTIONS)


# ----------------------------------------------------------------------------- inputs


@dataclass
class ReportInputs:
    """Everything the report shows, read from the stage folders.

    Attributes:
        ingest_dir / recovery_dir / validation_dir: Where the inputs came from (None: not given).
        sequence: The canonical store's sequence.
        recovery: ``recovery.json`` content, or None.
        bias: The recovered bias (``pipeline.bias_table.BiasTrack``), or None.
        trajectory: The recovered IMU trajectory, or None.
        residuals: Per-keyframe residual table (``t_ns`` + numeric columns), or None.
        validation: ``validation.json`` content, or None.
        windows: ``windows.parquet`` (t0_ns, source, pos_err_m, rot_err_deg[, flagged]), or None.
        missing: Plain sentences: what is missing (shown in the page).
        problems: Plain sentences: inputs that exist but could not be read.
    """

    ingest_dir: Path
    sequence: Sequence
    recovery_dir: Path | None = None
    validation_dir: Path | None = None
    recovery: RecoveryReport | None = None
    bias: BiasTrack | None = None
    trajectory: PoseSeries | None = None
    residuals: pd.DataFrame | None = None
    validation: ValidationSummary | None = None
    windows: pd.DataFrame | None = None
    missing: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def t0_ns(self) -> int:
        """Time origin of every plot: the first IMU stamp (else the first pose stamp, else 0)."""
        seq = self.sequence
        if seq.imu is not None and len(seq.imu):
            return int(seq.imu.t_ns[0])
        for poses in seq.poses.values():
            if len(poses):
                return int(poses.t_ns[0])
        if self.bias is not None and len(self.bias.t_ns):
            return int(self.bias.t_ns[0])
        return 0


def stage_dirs(results_dir: str | Path, sequence: str) -> dict[str, Path | None]:
    """The stage folders of ``sequence`` under a results folder (None where absent).

    ``results_dir`` is the ``results/`` folder itself or a folder holding ``results/``.
    The recovery may live in ``recovery/`` or ``recover/``, the validation in
    ``validation/`` or ``validate/``. The ingest entry is always a path (it may not exist;
    :func:`gather_inputs` then raises a one-line error).
    """
    root = Path(results_dir)
    if not any((root / names[0]).is_dir() for names in STAGE_FOLDERS.values()) and (root / "results").is_dir():
        root = root / "results"
    out: dict[str, Path | None] = {}
    for stage, names in STAGE_FOLDERS.items():
        found = next((root / n / sequence for n in names if (root / n / sequence).is_dir()), None)
        out[stage] = found if found is not None or stage != "ingest" else root / names[0] / sequence
    return out


def gather_inputs(
    ingest_dir: str | Path,
    *,
    recovery_dir: str | Path | None = None,
    validation_dir: str | Path | None = None,
    sequence: Sequence | None = None,
) -> ReportInputs:
    """Read every available input; note what is missing or unreadable instead of failing.

    ``sequence``: the sequence already loaded from ``ingest_dir`` (any input the readers take, e.g.
    a raw ASL folder with added poses); else ``ingest_dir`` must be a canonical store.

    Raises:
        InputFormatError: ``ingest_dir`` is not a canonical store and no sequence was given.
    """
    ingest_dir = Path(ingest_dir)
    if sequence is None and not is_store(ingest_dir):
        raise InputFormatError(
            "no ingest store here (sequence.yaml missing)", path=ingest_dir,
            hint="run the ingest stage ('biasgt convert INPUT --out DIR' or 'biasgt run') first, "
                 "or give the right --ingest folder")
    inputs = ReportInputs(ingest_dir=ingest_dir, sequence=read_store(ingest_dir) if sequence is None else sequence)

    # --- recovery
    if recovery_dir is None:
        inputs.missing.append("Recovery: no recovery folder was given or found, so there is no recovered bias, "
                              "calibration or residuals.")
    else:
        rdir = inputs.recovery_dir = Path(recovery_dir)
        if not rdir.is_dir():
            inputs.missing.append(f"Recovery: the folder {rdir} does not exist (the recovery stage has not run "
                                  "or failed), so there is no recovered bias, calibration or residuals.")
        else:
            _gather_recovery(inputs, rdir)

    # --- validation
    if validation_dir is None:
        inputs.missing.append("Validation: no validation folder was given or found, so there is no verdict and "
                              "no integration-error statistics.")
    else:
        vdir = inputs.validation_dir = Path(validation_dir)
        vj = vdir / VALIDATION_JSON
        if not vj.is_file():
            inputs.missing.append(f"Validation: {vj} does not exist (the validation stage has not run or failed), "
                                  "so there is no verdict and no integration-error statistics.")
        else:
            inputs.validation = _read_noting_problems(inputs, "Validation", vj, lambda _: read_summary(vdir))
            wp = vdir / WINDOWS_PARQUET
            if wp.is_file():
                inputs.windows = _read_noting_problems(inputs, "Validation", wp, lambda _: read_windows(vdir),
                                                       (OSError, ValueError))
            else:
                inputs.missing.append(f"Validation: {wp} does not exist, so the per-window error "
                                      "distributions cannot be drawn (the summary table is shown).")
    return inputs


def _read_noting_problems(inputs: ReportInputs, stage: str, path: Path, reader: Callable[[Path], Any],
                          io_errors: tuple[type[Exception], ...] = ()) -> Any:
    """``reader(path)``, or None with a plain sentence in ``inputs.problems`` when it fails.

    A :class:`BiasgtError` is reported as it reads (it names the file); an error in
    ``io_errors`` (caught first) as ``cannot read PATH (error)``.
    """
    try:
        return reader(path)
    except io_errors as exc:
        inputs.problems.append(f"{stage}: cannot read {path} ({exc})")
    except BiasgtError as exc:
        inputs.problems.append(f"{stage}: {exc}")
    return None


def _gather_recovery(inputs: ReportInputs, rdir: Path) -> None:
    for name, attr, reader, absent in (
        (REPORT_JSON, "recovery", lambda _: read_report(rdir), "so the estimated calibration is not shown"),
        (BIAS_CSV, "bias", read_bias_csv, "so the recovered bias is not shown"),
        (TRAJECTORY_TUM, "trajectory", lambda _: read_trajectory(rdir), None),
        (RESIDUALS_CSV, "residuals", lambda _: read_residuals(rdir), None),
    ):
        path = rdir / name
        if path.is_file():
            setattr(inputs, attr, _read_noting_problems(inputs, "Recovery", path, reader, (OSError, ValueError)))
        elif absent is not None:
            inputs.missing.append(f"Recovery: {path} does not exist, {absent}.")


# ----------------------------------------------------------------------------- small helpers


def num(d: Any, *keys: str) -> float | None:
    """``d[k0][k1]...`` as a float, None when absent or not a finite number."""
    cur = d
    for k in keys:
        if not isinstance(cur, dict) or k not in cur:
            return None
        cur = cur[k]
    try:
        v = float(cur)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def missing_box(text: str) -> Html:
    return tag("div", text, class_="missing")


def rel_s(t_ns: np.ndarray, t0_ns: int) -> np.ndarray:
    return (np.asarray(t_ns, dtype=np.int64) - t0_ns) / NS_PER_S


def validation_sources(validation: dict[str, Any]) -> dict[str, dict[str, Any]]:
    src = validation.get("sources")
    return {str(k): v for k, v in src.items() if isinstance(v, dict)} if isinstance(src, dict) else {}


def candidate_name(validation: dict[str, Any]) -> str | None:
    """The judged source: ``candidate`` when given, else the first recovered / file / dataset source."""
    sources = validation_sources(validation)
    cand = validation.get("candidate")
    if isinstance(cand, str) and cand in sources:
        return cand
    for kind in ("recovered", "file", "dataset"):
        for name, s in sources.items():
            if s.get("kind") == kind:
                return name
    return next(iter(sources), None)


def first_of_kind(validation: dict[str, Any], kind: str, exclude: str | None) -> str | None:
    return next((n for n, s in validation_sources(validation).items() if s.get("kind") == kind and n != exclude), None)


def source_label(name: str, kind: str | None) -> str:
    return {
        "recovered": "The recovered bias",
        "dataset": "The dataset's own bias",
        "constant_first_window": "A constant bias",
        "zero": "A zero bias",
    }.get(kind or "", f"The bias '{name}'")


#: From this ratio of errors on, a comparison reads "N times the error of", not "(N-1)*100 % worse".
RATIO_FROM = 2.0


def better_worse(cand: float | None, base: float | None) -> str | None:
    """How an error ``cand`` compares with ``base``, to follow "integrates": ``as well as``, ``12% better
    than``, ``40% worse than``, or ``with 148 times the error of`` (at :data:`RATIO_FROM` and above)."""
    if cand is None or base is None or base <= 0:
        return None
    rel = 1.0 - cand / base
    if abs(rel) < 0.005:
        return "as well as"
    if cand / base >= RATIO_FROM:
        return f"with {cand / base:.3g} times the error of"
    return f"{abs(rel):.0%} {'better' if rel > 0 else 'worse'} than"


def relative_cell(cand: float | None, base: float | None) -> str:
    """A table cell comparing two errors: ``-12.0 %``, ``+40.0 %``, or ``148× (worse)`` from :data:`RATIO_FROM`."""
    if cand is None or not base:
        return "—"
    if cand / base >= RATIO_FROM:
        return f"{cand / base:.3g}× (worse)"
    return f"{(cand / base - 1.0) * 100:+.1f} %"


def other_estimates_sentence(validation: dict[str, Any]) -> str | None:
    """What the other bias estimates of the sequence (sources of kind ``file``) say against the judged one.

    Each is compared on the same windows and reference: its PRMSE as a multiple of the judged bias's, and
    the difference of the mean accelerometer biases with the tilt of the same size (``|d b_a| / |g|``), since
    a bias is only meaningful together with the attitude and gravity it was estimated against. None when
    there is no such source.
    """
    sources, cand = validation_sources(validation), candidate_name(validation)
    others = [n for n, s in sources.items() if s.get("kind") == "file" and n != cand]
    if cand is None or not others:
        return None
    base = num(sources[cand], "prmse_m")
    g = float(np.linalg.norm(validation.get("gravity_mps2") or DEFAULT_GRAVITY_MPS2))
    parts = []
    for name in others:
        s = sources[name]
        prmse = num(s, "prmse_m")
        if name == HELDOUT_SOURCE:
            parts.append(f"'{name}', the recovery cross-validated by time blocks (recovered again without the "
                         f"poses of each block, used on that block only), integrates to "
                         f"{fmt(None if prmse is None else 1e3 * prmse, 4)} mm"
                         + (f", {prmse / base:.2g}x the judged bias's {fmt(1e3 * base, 4)} mm: what the recovery "
                            "is worth on poses it was not fitted to" if prmse is not None and base else ""))
            continue
        text = f"'{name}' integrates to {fmt(None if prmse is None else 1e3 * prmse, 4)} mm"
        if prmse is not None and base:
            text += f", {prmse / base:.2g}x the judged bias's {fmt(1e3 * base, 4)} mm"
        mean_o, mean_c = s.get("mean_bias"), sources[cand].get("mean_bias")
        if isinstance(mean_o, list) and isinstance(mean_c, list) and len(mean_o) == len(mean_c) == 6:
            d = np.asarray(mean_o[3:], dtype=float) - np.asarray(mean_c[3:], dtype=float)
            text += (f"; its mean accelerometer bias differs by ({', '.join(f'{x:+.3f}' for x in d)}) m/s^2, what "
                     f"a {math.degrees(float(np.linalg.norm(d)) / g):.2f}-deg tilt of the attitude would explain")
        parts.append(text)
    frame_note = (" A bias is only meaningful with the attitude and gravity it was estimated against: an estimate "
                  "made against another pose source fits this reference only as well as the two sources' attitudes "
                  "agree." if any(n != HELDOUT_SOURCE for n in others) else "")
    return ("Other estimates of this sequence's bias, integrated on the same windows against the same reference: "
            + "; ".join(parts) + "." + frame_note)
