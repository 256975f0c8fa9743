"""Writing a recovery result: ``bias.csv``, ``recovery.json``, ``trajectory_tum.txt``, ``residuals.csv``.

The folder is written through :func:`pipeline.atomic.atomic_dir`: it appears
complete or not at all.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.bias_table import CSV_HEADER
from pipeline.atomic import atomic_dir
from pipeline.types import PoseSeries, PoseSourceKind
from recovery.recover import RecoveryResult
BIAS_CSV = "bias.csv"
REPORT_JSON = "recovery.json"
TRAJECTORY_TUM = "trajectory_tum.txt"
RESIDUALS_CSV = "residuals.csv"


def bias_frame(result: RecoveryResult) -> pd.DataFrame:
    """The ``bias.csv`` table (columns :data:`CSV_HEADER`)."""
    data = np.hstack([result.bias_gyro_radps, result.bias_acc_mps2, result.bias_gyro_std_radps,
                      result.bias_acc_std_mps2])
    frame = pd.DataFrame(data, columns=list(CSV_HEADER[1:]))
    frame.insert(0, "t_ns", np.asarray(result.t_ns, dtype=np.int64))
    return frame


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def _write_tum(path: Path, result: RecoveryResult) -> None:
    poses = PoseSeries(result.t_ns, result.p_m, result.quat_wxyz, "imu", PoseSourceKind.GROUND_TRUTH)
    try:
        from pipeline.io.tum import write_tum
    except ImportError:  # pragma: no cover - io package always ships tum
        write_tum = None
    if write_tum is not None:
        write_tum(path, poses)
        return
    q = result.quat_wxyz  # pragma: no cover
    with open(path, "w", encoding="utf-8") as fh:  # pragma: no cover
        for i in range(len(result.t_ns)):
            fh.write(f"{result.t_ns[i] / 1e9:.9f} {result.p_m[i, 0]!r} {result.p_m[i, 1]!r} {result.p_m[i, 2]!r} "
                     f"{q[i, 1]!r} {q[i, 2]!r} {q[i, 3]!r} {q[i, 0]!r}\n")


def _write_bias_csv(path: Path, result: RecoveryResult) -> None:
    """``bias.csv`` as :func:`bias_frame` would write with ``to_csv(float_format="%.9g", na_rep="nan")``,
    formatted with one %-format per row (pandas' CSV writer takes ~1 s for 18000 rows)."""
    data = np.hstack([result.bias_gyro_radps, result.bias_acc_mps2, result.bias_gyro_std_radps,
                      result.bias_acc_std_mps2]).astype(float)
    t = np.asarray(result.t_ns, dtype=np.int64)
    fmt = "%d" + ",%.9g" * data.shape[1] + "\n"
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(CSV_HEADER) + "\n")
        fh.writelines(fmt % (ti, *row) for ti, row in zip(t.tolist(), data.tolist()))


def write_recovery(result: RecoveryResult, out_dir: str | Path) -> Path:
    """Write ``bias.csv``, ``recovery.json`` and ``trajectory_tum.txt`` into ``out_dir`` atomically.

    Args:
        result: From :func:`recovery.recover.recover`.
        out_dir: Output folder (replaced as a whole when it exists).

    Returns:
        ``out_dir`` as a Path.
    """
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        _write_bias_csv(tmp / BIAS_CSV, result)
        (tmp / REPORT_JSON).write_text(json.dumps(_json_safe(result.report), indent=2, allow_nan=False) + "\n",
                                       encoding="utf-8")
        _write_tum(tmp / TRAJECTORY_TUM, result)
        if result.residuals:
            frame = pd.DataFrame({"t_ns": np.asarray(result.t_ns, dtype=np.int64),
                                  **{k: np.asarray(v) for k, v in result.residuals.items()}})
            frame.to_csv(tmp / RESIDUALS_CSV, index=False, float_format="%.6g", na_rep="nan")
    return out_dir
