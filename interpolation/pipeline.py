"""Interpolation stage: a recovery folder + the IMU stamps -> bias at IMU rate on disk."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from interpolation.bias import interpolate_bias
from interpolation.config import InterpolationMethod
from pipeline.bias_table import BiasTrack, read_bias_csv, write_bias_table
from pipeline.errors import DataError, InputFormatError
from pipeline.ingest import load

log = logging.getLogger(__name__)


def recovery_random_walk(recovery_dir: str | Path) -> np.ndarray:
    """Random-walk strengths [6] the recovery used (``recovery.json`` ``noise``).

    Raises:
        InputFormatError: recovery.json missing, unreadable or without the random walks.
    """
    path = Path(recovery_dir) / "recovery.json"
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFormatError("recovery.json not found", path=path,
                               hint="give the folder written by 'biasgt recover --out DIR'") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise InputFormatError(f"cannot read recovery.json ({exc})", path=path, hint="re-run the recovery") from None
    noise = report.get("noise") if isinstance(report.get("noise"), Mapping) else {}
    try:
        g_rw = float(noise.get("gyro_random_walk", report.get("gyro_random_walk")))
        a_rw = float(noise.get("acc_random_walk", report.get("acc_random_walk")))
    except (TypeError, ValueError):
        raise InputFormatError("recovery.json has no bias random walks (noise.gyro_random_walk, "
                               "noise.acc_random_walk)", path=path, hint="re-run the recovery") from None
    return np.array([g_rw] * 3 + [a_rw] * 3)


def interpolate_recovery(
    recovery_dir: str | Path,
    imu_input: str | Path,
    out_path: str | Path,
    *,
    method: InterpolationMethod = InterpolationMethod.LINEAR,
    clamp: bool = False,
    write_csv_twin: bool = True,
    reader_kwargs: Mapping[str, Any] | None = None,
) -> list[Path]:
    """Interpolate ``recovery_dir/bias.csv`` to the IMU stamps of ``imu_input`` and write it.

    Returns:
        The files written (``out_path`` and, for Parquet, its CSV twin).

    Raises:
        DataError: The input has no IMU, or stamps lie outside the span (without ``clamp``).
    """
    out_path = Path(out_path)
    if out_path.suffix not in (".parquet", ".csv"):
        raise InputFormatError("output must end in .parquet or .csv", path=out_path)
    keyframes = read_bias_csv(Path(recovery_dir) / "bias.csv")
    random_walk = recovery_random_walk(recovery_dir)
    seq = load(imu_input, reader_kwargs)
    if seq.imu is None:
        raise DataError("input has no IMU stream", path=imu_input, hint="give the input the recovery was run on")
    track = interpolate_bias(keyframes, seq.imu.t_ns, random_walk=random_walk, method=method, clamp=clamp)
    n_clamped = int(np.sum(track.clamped)) if track.clamped is not None else 0
    if n_clamped:
        log.warning("%d of %d IMU stamps lie outside the recovered span: end values held (flagged)",
                    n_clamped, len(track))
    meta = {"method": method.value, "random_walk": random_walk.tolist(), "recovery": str(recovery_dir),
            "clamped_rows": n_clamped}
    written = [write_bias_table(track, out_path, metadata=meta)]
    if write_csv_twin and out_path.suffix == ".parquet":
        written.append(write_bias_table(track, out_path.with_suffix(".csv")))
    log.info("interpolated %d keyframes to %d IMU stamps (%s)", len(keyframes), len(track), method.value)
    return written


__all__ = ["BiasTrack", "interpolate_recovery", "recovery_random_walk"]
