"""Interpolation stage: a recovery folder + the IMU stamps -> bias at IMU rate on disk."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from interpolation.bias import interpolate_bias
from interpolation.config import InterpolationConfig
from pipeline.bias_table import read_bias_csv, write_bias_table
from pipeline.errors import DataError, InputFormatError
from pipeline.ingest import load
from recovery.outputs import BIAS_CSV, REPORT_JSON, read_report

log = logging.getLogger(__name__)


def interpolate_recovery(
    recovery_dir: str | Path,
    imu_input: str | Path,
    out_path: str | Path,
    config: InterpolationConfig = InterpolationConfig(),
    *,
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
    keyframes = read_bias_csv(Path(recovery_dir) / BIAS_CSV)
    random_walk = read_report(recovery_dir).require_random_walk(Path(recovery_dir) / REPORT_JSON)
    seq = load(imu_input, reader_kwargs)
    if seq.imu is None:
        raise DataError("input has no IMU stream", path=imu_input, hint="give the input the recovery was run on")
    track = interpolate_bias(keyframes, seq.imu.t_ns, random_walk=random_walk, method=config.method,
                             clamp=config.clamp)
    n_clamped = int(np.sum(track.clamped)) if track.clamped is not None else 0
    if n_clamped:
        log.warning("%d of %d IMU stamps lie outside the recovered span: end values held (flagged)",
                    n_clamped, len(track))
    meta = {"method": config.method.value, "random_walk": random_walk.tolist(), "recovery": str(recovery_dir),
            "clamped_rows": n_clamped}
    written = [write_bias_table(track, out_path, metadata=meta)]
    if config.write_csv and out_path.suffix == ".parquet":
        written.append(write_bias_table(track, out_path.with_suffix(".csv")))
    log.info("interpolated %d keyframes to %d IMU stamps (%s)", len(keyframes), len(track), config.method.value)
    return written


__all__ = ["interpolate_recovery"]
