"""The recovery stage's output folder, written and read in one place.

Files (names defined here only): ``bias.csv`` (keyframe bias + sigma, :mod:`pipeline.bias_table`
columns), ``recovery.json`` (:class:`RecoveryReport`), ``trajectory_tum.txt`` (the optimised IMU
trajectory), ``residuals.csv`` (per keyframe: whitened residuals and the outlier flag) and, when no
calibration gave the IMU's noise densities, ``sensor.yaml`` (a Kalibr-style file with the noise the
recording suggests, read off its rest or, without one, chosen by the evidence search:
:func:`suggested_sensor_yaml`).

:meth:`RecoveryOutputs.write` writes the folder through :func:`pipeline.files.atomic.atomic_dir` (it
appears complete or not at all, and replaces only these files in an existing folder); :meth:`RecoveryOutputs.read` reads it back. Every consumer
(interpolation, validation, windows, the report, the CLI and the workflow) reads through here.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.files.atomic import atomic_dir
from pipeline.bias_table import CSV_HEADER, BiasTrack, read_bias_csv
from pipeline.errors import BiasgtError, InputFormatError
from pipeline.geometry.pose_transform import transform_from_json
from pipeline.io.tum import read_tum_poses, write_tum
from pipeline.files.jsonio import JsonRecord, dumps, number, read_json_object
from pipeline.types import CALIBRATION_DEFAULT_SOURCE, PoseSeries, PoseSourceKind

BIAS_CSV = "bias.csv"
REPORT_JSON = "recovery.json"
TRAJECTORY_TUM = "trajectory_tum.txt"
RESIDUALS_CSV = "residuals.csv"
#: The noise the recording suggests, written when no calibration gave the densities (:func:`suggested_sensor_yaml`).
SENSOR_YAML = "sensor.yaml"
#: Every file of the folder, in the order they are described above.
FILES = (BIAS_CSV, REPORT_JSON, TRAJECTORY_TUM, RESIDUALS_CSV, SENSOR_YAML)

_RERUN = "re-run 'biasgt recover' (or the workflow's recover stage) to write the folder again"


@dataclass(frozen=True, eq=False)  # holds arrays: compare .data / the fields
class RecoveryReport(JsonRecord):
    """``recovery.json``: the typed fields every later stage reads, plus the whole object.

    Attributes:
        data: The whole JSON object (display fields of the quality report, benchmarks);
            ``report["key"]`` reads it.
        pose_stream: The pose stream fitted, or None when unnamed.
        time_offset_s: ``pose_time_offset_s``: seconds to add to the pose stamps (IMU clock).
        T_imu_pose: The pose-to-IMU extrinsic ``T_imu_pose``, 4x4.
        gravity_world_mps2: Gravity in the pose world frame, [3], or None.
        random_walk: The bias random walks used (``noise``), [6] = gyro x3 (rad/s^2/sqrt(Hz)),
            acc x3 (m/s^3/sqrt(Hz)), or None when absent.
        outlier_t_ns: Stamps (IMU clock) of the pose samples and keyframe poses rejected as outliers,
            int64 [M].
        warnings: Plain sentences.
    """

    data: Mapping[str, Any]
    pose_stream: str | None
    time_offset_s: float
    T_imu_pose: np.ndarray
    gravity_world_mps2: np.ndarray | None
    random_walk: np.ndarray | None
    outlier_t_ns: np.ndarray
    warnings: tuple[str, ...]

    @classmethod
    def from_json(cls, data: Mapping[str, Any], path: str | Path | None = None) -> RecoveryReport:
        """Parse the JSON object (as written by :func:`recovery.recover.recover`).

        Raises:
            InputFormatError: A field has the wrong form (naming it).
        """
        field = "T_imu_pose"
        try:
            T = transform_from_json(data.get("T_imu_pose"))
            field = "gravity_world_mps2"
            g = data.get("gravity_world_mps2")
            gravity = None if g is None else np.asarray(g, dtype=np.float64).reshape(3)
            field = "noise"
            noise = data.get("noise") if isinstance(data.get("noise"), Mapping) else {}
            g_rw, a_rw = noise.get("gyro_random_walk"), noise.get("acc_random_walk")
            rw = None if g_rw is None or a_rw is None else np.array([float(g_rw)] * 3 + [float(a_rw)] * 3)
            field = "pose_time_offset_s"
            offset_s = number(data.get("pose_time_offset_s", 0.0))
            field = "outlier_t_ns"
            outliers = np.asarray(data.get("outlier_t_ns") or [], dtype=np.int64).reshape(-1)
        except (BiasgtError, TypeError, ValueError) as exc:
            raise InputFormatError(f"recovery.json field {field} is malformed ({exc})", path=path, field=field,
                                   hint=_RERUN) from None
        stream = data.get("pose_stream")
        return cls(data=dict(data), pose_stream=stream if isinstance(stream, str) else None,
                   time_offset_s=offset_s, T_imu_pose=T, gravity_world_mps2=gravity, random_walk=rw,
                   outlier_t_ns=outliers, warnings=tuple(str(w) for w in data.get("warnings") or ()))

    def require_random_walk(self, path: str | Path | None = None) -> np.ndarray:
        """:attr:`random_walk`, which interpolation needs.

        Raises:
            InputFormatError: recovery.json names no random walks.
        """
        if self.random_walk is None:
            raise InputFormatError("recovery.json has no bias random walks (noise.gyro_random_walk, "
                                   "noise.acc_random_walk)", path=path, field="noise", hint=_RERUN)
        return self.random_walk


def read_report(folder: str | Path) -> RecoveryReport:
    """``folder/recovery.json``.

    Raises:
        InputFormatError: Missing, unreadable or malformed.
    """
    path = Path(folder) / REPORT_JSON
    return RecoveryReport.from_json(read_json_object(path, hint=_RERUN + " (or give the folder it wrote)"), path)


def read_trajectory(folder: str | Path) -> PoseSeries:
    """``folder/trajectory_tum.txt``: the optimised IMU trajectory (frame ``imu``, IMU clock)."""
    path = Path(folder) / TRAJECTORY_TUM
    return read_tum_poses(path, source_kind=PoseSourceKind.GROUND_TRUTH, frame="imu", stream="recovered")[0]


def read_residuals(folder: str | Path) -> pd.DataFrame | None:
    """``folder/residuals.csv`` (``t_ns`` int64, whitened residuals, ``outlier``), None when absent.

    Raises:
        InputFormatError: Present but without a ``t_ns`` column.
    """
    path = Path(folder) / RESIDUALS_CSV
    if not path.is_file():
        return None
    frame = pd.read_csv(path)
    if "t_ns" not in frame.columns:
        raise InputFormatError("residual table has no t_ns column", path=path, hint=_RERUN)
    frame["t_ns"] = frame["t_ns"].astype(np.int64)
    return frame


@dataclass(frozen=True, eq=False)  # holds arrays: compare .data / the fields
class RecoveryOutputs:
    """The content of a recovery folder.

    Attributes:
        bias: Keyframe bias and marginal sigma (``bias.csv``).
        report: ``recovery.json``.
        trajectory: The optimised IMU trajectory (``trajectory_tum.txt``).
        residuals: Per keyframe: ``t_ns``, ``pose_whitened_rms``, ``imu_whitened_rms``, ``outlier``
            (``residuals.csv``), or None.
    """

    bias: BiasTrack
    report: RecoveryReport
    trajectory: PoseSeries
    residuals: pd.DataFrame | None = None

    def write(self, out_dir: str | Path) -> Path:
        """Write the folder atomically; returns it as a Path.

        An existing folder gets these files replaced and keeps what other stages wrote there
        (e.g. ``bias_imu.parquet``, ``validation/`` in the README's single-folder layout).
        """
        out_dir = Path(out_dir)
        with atomic_dir(out_dir, owned=FILES) as tmp:
            _write_bias_csv(tmp / BIAS_CSV, self.bias)
            (tmp / REPORT_JSON).write_text(dumps(self.report.data), encoding="utf-8")
            write_tum(tmp / TRAJECTORY_TUM, self.trajectory)
            if self.residuals is not None:
                self.residuals.to_csv(tmp / RESIDUALS_CSV, index=False, float_format="%.6g", na_rep="nan")
            suggested = suggested_sensor_yaml(self.report.data)
            if suggested is not None:
                (tmp / SENSOR_YAML).write_text(suggested, encoding="utf-8")
        return out_dir

    @classmethod
    def read(cls, folder: str | Path) -> RecoveryOutputs:
        """Read a folder written by :meth:`write`.

        Raises:
            InputFormatError: Not a recovery folder, or a file is missing or malformed.
        """
        folder = Path(folder)
        for name in (REPORT_JSON, BIAS_CSV, TRAJECTORY_TUM):
            if not (folder / name).is_file():
                raise InputFormatError(f"recovery output lacks {name}", path=folder,
                                       hint="give the folder written by 'biasgt recover --out DIR'")
        return cls(read_bias_csv(folder / BIAS_CSV), read_report(folder), read_trajectory(folder),
                   read_residuals(folder))


def bias_sha256(folder: str | Path) -> str | None:
    """SHA-256 of the recovery folder's ``bias.csv`` (what a validation judged), or None without one."""
    path = Path(folder) / BIAS_CSV
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def _write_bias_csv(path: Path, bias: BiasTrack) -> None:
    """``bias.csv`` as ``BiasTrack.to_frame().to_csv(float_format="%.9g", na_rep="nan")`` would write
    it, formatted with one %-format per row (pandas' CSV writer takes ~1 s for 18000 rows)."""
    data = np.hstack([bias.bias, bias.std]).astype(float)
    fmt = "%d" + ",%.9g" * data.shape[1] + "\n"
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(CSV_HEADER) + "\n")
        fh.writelines(fmt % (ti, *row) for ti, row in zip(np.asarray(bias.t_ns, np.int64).tolist(), data.tolist()))


def _line(key: str, value: float, comment: str) -> str:
    return f"{key}: {value:.6g}  # {comment}\n"


def _density_lines(report: Mapping[str, Any]) -> tuple[list[str], float] | None:
    """The white-noise densities' lines and the IMU rate: read off the recording's rest (``noise_from_data``),
    else chosen by the evidence search from the default densities (no rest found); None otherwise."""
    data = report.get("noise_from_data")
    if isinstance(data, Mapping):
        rest = (f"white-noise line (tau = 1 s) of the Allan deviation over {float(data['rest_s']):.1f} s at rest in "
                f"{int(data['rest_stretches'])} stretch(es), RMS of the three axes")
        return ([_line("gyroscope_noise_density", float(data["gyro_noise_density"]), f"rad/s/sqrt(Hz): {rest}"),
                 _line("accelerometer_noise_density", float(data["acc_noise_density"]), f"m/s^2/sqrt(Hz): {rest}")],
                float(data.get("rate_hz") or 0.0))
    noise, config = report.get("noise") or {}, report.get("config") or {}
    sources = report.get("calibration_sources") or {}
    searched = noise.get("method") == "evidence" and len(config.get("noise_density_scales") or []) > 1
    fields = ("gyro_noise_density", "acc_noise_density")
    if not searched or any(sources.get(f) != CALIBRATION_DEFAULT_SOURCE for f in fields):
        return None
    lines, grid = [], [float(x) for x in config["noise_density_scales"]]
    for key, field, unit in (("gyroscope_noise_density", "gyro", "rad/s/sqrt(Hz)"),
                             ("accelerometer_noise_density", "acc", "m/s^2/sqrt(Hz)")):
        value, scale = noise.get(f"{field}_noise_density"), float(noise.get(f"{field}_noise_density_scale") or 1.0)
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            return None
        edge = ("; at the edge of its grid: the recording hardly tells it, the true value may lie beyond"
                if scale in (min(grid), max(grid)) else "")
        lines.append(_line(key, float(value), f"{unit}: the recording never rests, so the recovery's evidence search "
                                              f"chose it ({scale:.3g}x the {sources[f'{field}_noise_density']}{edge})"))
    return lines, float(report.get("imu_rate_hz") or 0.0)


def suggested_sensor_yaml(report: Mapping[str, Any]) -> str | None:
    """A Kalibr-style ``sensor.yaml`` from ``recovery.json``, or None where a calibration file (or the config)
    gave the densities: the densities read off the recording's rest (``noise_from_data``) or, without a rest,
    those the evidence search chose from the defaults; the random walks the evidence search chose. Each
    value carries a comment on where it came from."""
    found = _density_lines(report)
    if found is None:
        return None
    densities, rate = found
    noise = report.get("noise") or {}
    parts = ["%YAML:1.0\n",
             f"# IMU noise of '{report.get('sequence', '')}' suggested by 'biasgt recover' (no calibration file gave "
             "it). Put it where the reader looks (imu0/sensor.yaml of an ASL folder) and recover again.\n",
             "sensor_type: imu\n", *densities]
    for key, field, unit in (("gyroscope_random_walk", "gyro", "rad/s^2/sqrt(Hz)"),
                             ("accelerometer_random_walk", "acc", "m/s^3/sqrt(Hz)")):
        walk, scale = noise.get(f"{field}_random_walk"), noise.get(f"{field}_random_walk_scale")
        start = (report.get("calibration_sources") or {}).get(f"{field}_random_walk", "the calibration")
        if isinstance(walk, (int, float)) and math.isfinite(walk):
            how = f"{scale:.3g}x the value of {start}" if isinstance(scale, (int, float)) else f"from {start}"
            parts.append(_line(key, float(walk), f"{unit}: the recovery's evidence search chose it ({how})"))
    if rate > 0:
        parts.append(_line("update_rate", rate, "Hz: the IMU's rate in the recording (Kalibr's key)"))
        parts.append(_line("rate_hz", rate, "Hz: the same, under EuRoC's key"))
    return "".join(parts)
