"""The bias table: keyframe (``bias.csv``) or IMU-rate (``bias_imu.parquet``) bias with sigmas.

One format for both stage outputs: ``t_ns`` then :data:`BIAS_COLUMNS` (gyro rad/s, accel m/s^2)
then :data:`STD_COLUMNS` (marginal standard deviations). Recovery writes it at keyframes,
interpolation at every IMU stamp; validation, windows and the report read it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.files.atomic import atomic_path
from pipeline.errors import DataError, InputFormatError
from pipeline.files.jsonio import dumps

BIAS_COLUMNS = ("bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z")
STD_COLUMNS = tuple(f"{c}_std" for c in BIAS_COLUMNS)
CSV_HEADER = ("t_ns",) + BIAS_COLUMNS + STD_COLUMNS



@dataclass(frozen=True)
class BiasTrack:
    """Bias samples with marginal standard deviations.

    Attributes:
        t_ns: Stamps on the IMU clock, int64 [N], strictly increasing.
        bias: ``[bg_x, bg_y, bg_z, ba_x, ba_y, ba_z]`` in rad/s and m/s^2, [N, 6].
        std: Marginal standard deviations, [N, 6].
        clamped: True where the value was held beyond the recovered span, [N].
    """

    t_ns: np.ndarray
    bias: np.ndarray
    std: np.ndarray
    clamped: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def bias_gyro_radps(self) -> np.ndarray:
        return self.bias[:, :3]

    @property
    def bias_acc_mps2(self) -> np.ndarray:
        return self.bias[:, 3:]

    def to_frame(self) -> pd.DataFrame:
        frame = pd.DataFrame({"t_ns": np.asarray(self.t_ns, dtype=np.int64)})
        for i, c in enumerate(BIAS_COLUMNS):
            frame[c] = self.bias[:, i]
        for i, c in enumerate(STD_COLUMNS):
            frame[c] = self.std[:, i]
        return frame


def read_bias_csv(path: str | Path, *, require_std: bool = True) -> BiasTrack:
    """Read a ``bias.csv`` (the recovery contract) or an interpolated bias CSV/Parquet.

    Args:
        path: The table.
        require_std: Whether the six ``*_std`` columns must be there. A bias to compare against
            (a constant, another tool's estimate) may have none: its sigma is then 0.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError("bias file does not exist", path=path,
                               hint="run 'biasgt recover' first or give the right path")
    try:
        frame = pq.read_table(path).to_pandas() if path.suffix == ".parquet" else pd.read_csv(
            path, dtype={"t_ns": np.int64})
    except (ValueError, OSError, pa.ArrowInvalid) as exc:
        raise InputFormatError(f"cannot parse bias table ({exc})", path=path,
                               hint=f"the header must be {','.join(CSV_HEADER)}") from exc
    missing = [c for c in CSV_HEADER if c not in frame.columns]
    if not require_std and missing == list(STD_COLUMNS):
        frame[list(STD_COLUMNS)] = 0.0
        missing = []
    if missing:
        raise InputFormatError("missing columns " + ", ".join(missing), path=path,
                               hint=f"the header must be {','.join(CSV_HEADER)}")
    t_ns = frame["t_ns"].to_numpy(dtype=np.int64)
    if len(t_ns) == 0:
        raise DataError("bias table is empty", path=path, hint="re-run the recovery")
    if np.any(np.diff(t_ns) <= 0):
        bad = int(np.argmax(np.diff(t_ns) <= 0)) + 3  # header is line 1
        raise DataError("bias stamps are not strictly increasing", path=path, line=bad,
                        hint="sort the rows by t_ns and drop duplicates")
    bias = frame[list(BIAS_COLUMNS)].to_numpy(dtype=np.float64)
    std = frame[list(STD_COLUMNS)].to_numpy(dtype=np.float64)
    if not (np.all(np.isfinite(bias)) and np.all(np.isfinite(std))):
        raise DataError("bias table holds NaN or inf values", path=path, hint="re-run the recovery")
    return BiasTrack(t_ns, bias, std)


def write_bias_table(track: BiasTrack, path: str | Path, *, metadata: dict | None = None) -> Path:
    """Write a bias track as CSV (``.csv``) or Parquet (``.parquet``), atomically.

    The columns are those of ``bias.csv``: ``t_ns,bg_x,...,ba_z_std``. For Parquet
    the ``metadata`` dict (and the clamped count) is stored in the schema metadata.
    """
    path = Path(path)
    frame = track.to_frame()
    with atomic_path(path) as tmp:
        if path.suffix == ".parquet":
            table = pa.Table.from_pandas(frame, preserve_index=False)
            meta = dict(metadata or {})
            if track.clamped is not None:
                meta["clamped_rows"] = int(np.sum(track.clamped))
            table = table.replace_schema_metadata({b"biasgt": dumps(meta, indent=None).strip().encode()})
            pq.write_table(table, tmp)
        else:
            frame.to_csv(tmp, index=False, float_format="%.10g")
    return path
