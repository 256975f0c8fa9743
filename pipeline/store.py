"""Canonical sequence store: one folder per sequence, Parquet tables plus ``sequence.yaml``.

Layout::

    DIR/
      sequence.yaml            name, calibration, pose-stream descriptions, findings, metadata
      imu.parquet              t_ns:int64, gyro_x..z [rad/s], acc_x..z [m/s^2] (+ temperature_degc)
      poses/<stream>.parquet   t_ns:int64, p_x..z [m] (+ qw, qx, qy, qz)
      ground_truth.parquet     t_ns, p_*, q*, v_*, bg_*, ba_*  (when the dataset has one)

Nanosecond stamps are stored as int64, so a write-read round trip is lossless.
The folder is written atomically.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from pipeline.files.atomic import atomic_dir
from pipeline.errors import InputFormatError
from pipeline.files.jsonio import to_plain
from pipeline.types import Finding, ImuCalibration, ImuSeries, PoseSeries, PoseSourceKind, Sequence, StateSeries

STORE_VERSION = 1
META_FILE = "sequence.yaml"
_XYZ = ("x", "y", "z")
_WXYZ = ("qw", "qx", "qy", "qz")


def is_store(path: str | Path) -> bool:
    """True if ``path`` is a canonical store folder."""
    return (Path(path) / META_FILE).is_file()


def stored_name(path: str | Path) -> str | None:
    """The sequence name in a store's ``sequence.yaml`` (read alone), or None when ``path`` is no readable store."""
    try:
        meta = yaml.safe_load((Path(path) / META_FILE).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):
        return None
    return str(meta["name"]) if isinstance(meta, dict) and meta.get("name") is not None else None


def _stream_file_name(stream: str) -> str:
    """A safe file stem for a stream or topic name (``/tf:world->base`` -> ``tf_world-_base``)."""
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", stream).strip("_")
    return stem or "poses"


def _table(t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> pa.Table:
    arrays = {"t_ns": pa.array(np.asarray(t_ns, dtype=np.int64), type=pa.int64())}
    for name, values in columns.items():
        arrays[name] = pa.array(np.asarray(values, dtype=np.float64), type=pa.float64())
    return pa.table(arrays)


def _vec_cols(prefix: str, values: np.ndarray, names: tuple[str, ...] = _XYZ) -> dict[str, np.ndarray]:
    return {f"{prefix}{n}": values[:, i] for i, n in enumerate(names)}


def _read_table(path: Path) -> dict[str, np.ndarray]:
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise InputFormatError(f"cannot read Parquet table ({exc})", path=path,
                               hint="re-create the store with 'biasgt convert'") from exc
    return {name: table.column(name).to_numpy() for name in table.column_names}


def _stack(cols: dict[str, np.ndarray], names: list[str], path: Path) -> np.ndarray:
    missing = [n for n in names if n not in cols]
    if missing:
        raise InputFormatError("missing columns " + ", ".join(missing), path=path,
                               hint="re-create the store with 'biasgt convert'")
    return np.column_stack([cols[n] for n in names])


def write_store(sequence: Sequence, out_dir: str | Path) -> Path:
    """Write ``sequence`` as a canonical store folder, atomically.

    Args:
        sequence: The sequence to write.
        out_dir: Destination folder; replaced only once the new one is complete.

    Returns:
        The folder path.
    """
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        meta: dict[str, Any] = {
            "store_version": STORE_VERSION,
            "name": sequence.name,
            "calibration": sequence.calibration.to_dict(),
            "pose_streams": {},
            "has_imu": sequence.imu is not None,
            "has_ground_truth": sequence.ground_truth is not None,
            "findings": [f.to_dict() for f in sequence.findings],
            "metadata": sequence.metadata,
        }
        if sequence.imu is not None:
            imu = sequence.imu
            cols = {**_vec_cols("gyro_", imu.gyro_radps), **_vec_cols("acc_", imu.acc_mps2)}
            if imu.temperature_degc is not None:
                cols["temperature_degc"] = imu.temperature_degc
            pq.write_table(_table(imu.t_ns, cols), tmp / "imu.parquet")
        if sequence.poses:
            (tmp / "poses").mkdir()
        used: set[str] = set()
        for stream, poses in sequence.poses.items():
            stem = _stream_file_name(stream)
            while stem in used:
                stem += "_"
            used.add(stem)
            cols = _vec_cols("p_", poses.p_m)
            if poses.quat_wxyz is not None:
                cols.update({n: poses.quat_wxyz[:, i] for i, n in enumerate(_WXYZ)})
            pq.write_table(_table(poses.t_ns, cols), tmp / "poses" / f"{stem}.parquet")
            meta["pose_streams"][stream] = {
                "file": f"poses/{stem}.parquet",
                "frame": poses.frame,
                "world_frame": poses.world_frame,
                "source_kind": poses.source_kind.value,
                "has_orientation": poses.has_orientation,
            }
        if sequence.ground_truth is not None:
            gt = sequence.ground_truth
            cols = {
                **_vec_cols("p_", gt.p_m),
                **{n: gt.quat_wxyz[:, i] for i, n in enumerate(_WXYZ)},
                **_vec_cols("v_", gt.v_mps),
                **_vec_cols("bg_", gt.bias_gyro_radps),
                **_vec_cols("ba_", gt.bias_acc_mps2),
            }
            pq.write_table(_table(gt.t_ns, cols), tmp / "ground_truth.parquet")
        (tmp / META_FILE).write_text(yaml.safe_dump(to_plain(meta), sort_keys=False), encoding="utf-8")
    return out_dir




def read_store(path: str | Path, *, name: str | None = None) -> Sequence:
    """Read a canonical store folder written by :func:`write_store` (named ``name`` if given, else as stored)."""
    path = Path(path)
    meta_path = path / META_FILE
    if not meta_path.is_file():
        raise InputFormatError(f"not a biasgt store (no {META_FILE})", path=path,
                               hint="create one with 'biasgt convert INPUT --out DIR'")
    meta = yaml.safe_load(meta_path.read_text(encoding="utf-8"))
    if not isinstance(meta, dict) or meta.get("store_version") != STORE_VERSION:
        raise InputFormatError(f"unsupported store version {meta.get('store_version') if isinstance(meta, dict) else None}",
                               path=meta_path, hint="re-create the store with this version's 'biasgt convert'")
    imu = None
    if meta.get("has_imu"):
        p = path / "imu.parquet"
        cols = _read_table(p)
        imu = ImuSeries(
            cols["t_ns"],
            _stack(cols, ["gyro_x", "gyro_y", "gyro_z"], p),
            _stack(cols, ["acc_x", "acc_y", "acc_z"], p),
            cols.get("temperature_degc"),
        )
    poses: dict[str, PoseSeries] = {}
    for stream, desc in (meta.get("pose_streams") or {}).items():
        p = path / desc["file"]
        cols = _read_table(p)
        quat = _stack(cols, list(_WXYZ), p) if desc.get("has_orientation") else None
        poses[stream] = PoseSeries(
            cols["t_ns"], _stack(cols, ["p_x", "p_y", "p_z"], p), quat,
            desc["frame"], PoseSourceKind(desc["source_kind"]), desc.get("world_frame", "world"),
        )
    gt = None
    if meta.get("has_ground_truth"):
        p = path / "ground_truth.parquet"
        cols = _read_table(p)
        gt = StateSeries(
            cols["t_ns"], _stack(cols, ["p_x", "p_y", "p_z"], p), _stack(cols, list(_WXYZ), p),
            _stack(cols, ["v_x", "v_y", "v_z"], p), _stack(cols, ["bg_x", "bg_y", "bg_z"], p),
            _stack(cols, ["ba_x", "ba_y", "ba_z"], p),
        )
    return Sequence(
        name=name or meta["name"],
        imu=imu,
        poses=poses,
        ground_truth=gt,
        calibration=ImuCalibration.from_dict(meta["calibration"]),
        findings=[Finding.from_dict(f) for f in meta.get("findings") or []],
        metadata=meta.get("metadata") or {},
    )
