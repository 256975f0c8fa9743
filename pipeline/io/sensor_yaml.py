"""Kalibr / EuRoC ``sensor.yaml`` files: IMU noise model and sensor extrinsics.

The files may start with OpenCV's ``%YAML:1.0`` directive (PyYAML rejects it, so it
is stripped) and may tag matrices ``!!opencv-matrix``. A matrix is a mapping
``{cols: 4, rows: 4, data: [...]}`` in row-major order. ``T_BS`` is the pose of
the sensor in the body frame, ``T_body_sensor``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.errors import InputFormatError
from pipeline.types import NOISE_FIELDS, ImuCalibration

#: sensor.yaml key -> ImuCalibration field.
IMU_NOISE_KEYS = {
    "gyroscope_noise_density": "gyro_noise_density",
    "gyroscope_random_walk": "gyro_random_walk",
    "accelerometer_noise_density": "acc_noise_density",
    "accelerometer_random_walk": "acc_random_walk",
    "rate_hz": "rate_hz",
}

#: sensor.yaml key -> ImuCalibration field: the sensor's bias range (optional; plausibility limits).
IMU_LIMIT_KEYS = {
    "gyroscope_bias_max": "gyro_bias_max_radps",
    "accelerometer_bias_max": "acc_bias_max_mps2",
}

_DIRECTIVE = re.compile(r"^[ \t]*%YAML[: ]\s*\d+\.\d+[^\n]*\n", re.MULTILINE)


class _Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """SafeLoader that reads OpenCV's ``!!opencv-matrix`` tag as a plain mapping."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> dict[str, Any]:
    return loader.construct_mapping(node, deep=True)  # type: ignore[arg-type]


_Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)
_Loader.add_constructor("!opencv-matrix", _opencv_matrix)


def load_sensor_yaml(path: str | Path) -> dict[str, Any]:
    """Read a ``sensor.yaml`` file as a dictionary.

    Args:
        path: The file.

    Returns:
        Its top-level mapping.

    Raises:
        InputFormatError: The file is missing, not YAML, or not a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError("file does not exist", path=path, hint="check the path")
    text = path.read_text(encoding="utf-8-sig", errors="replace")
    text = _DIRECTIVE.sub("\n", text, count=1)  # keep the line numbers
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = None if mark is None else mark.line + 1
        raise InputFormatError(f"not valid YAML ({getattr(exc, 'problem', None) or exc})", path=path, line=line,
                               hint="fix the YAML syntax (a Kalibr/EuRoC sensor.yaml)") from exc
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InputFormatError("top level is not a mapping", path=path,
                               hint="a sensor.yaml holds 'key: value' lines")
    return data


def parse_matrix(value: Any, *, path: Path, key: str, shape: tuple[int, int] = (4, 4)) -> np.ndarray:
    """A matrix from ``{cols, rows, data}`` (row-major) or a nested list.

    Args:
        value: The YAML value.
        path: File (for messages).
        key: Key (for messages).
        shape: Expected shape.

    Returns:
        float64 array of ``shape``.

    Raises:
        InputFormatError: Wrong layout, size or non-numeric entries.
    """
    hint = f"write {key} as {{cols: {shape[1]}, rows: {shape[0]}, data: [{shape[0] * shape[1]} numbers, row-major]}}"
    if isinstance(value, dict):
        if "data" not in value:
            raise InputFormatError("matrix has no 'data'", path=path, field=key, hint=hint)
        rows = value.get("rows", shape[0])
        cols = value.get("cols", shape[1])
        if (rows, cols) != shape:
            raise InputFormatError(f"matrix is {rows}x{cols}, expected {shape[0]}x{shape[1]}", path=path, field=key,
                                   hint=hint)
        data = value["data"]
    else:
        data = value
    try:
        arr = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputFormatError("matrix entries are not numbers", path=path, field=key, hint=hint) from exc
    if arr.size != shape[0] * shape[1]:
        raise InputFormatError(f"matrix has {arr.size} entries, expected {shape[0] * shape[1]}", path=path,
                               field=key, hint=hint)
    arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise InputFormatError("matrix has non-finite entries", path=path, field=key, hint=hint)
    return arr


def _check_transform(T: np.ndarray, *, path: Path, key: str) -> np.ndarray:
    R = T[:3, :3]
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9) or not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
        raise InputFormatError("is not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)",
                               path=path, field=key, hint="give a proper 4x4 homogeneous transform")
    return T


def read_T_BS(path: str | Path, data: dict[str, Any] | None = None) -> np.ndarray | None:
    """The ``T_BS`` (pose of the sensor in the body frame) of a sensor.yaml, or ``None`` if it has none."""
    path = Path(path)
    data = load_sensor_yaml(path) if data is None else data
    if "T_BS" not in data:
        return None
    return _check_transform(parse_matrix(data["T_BS"], path=path, key="T_BS"), path=path, key="T_BS")


def _positive_float(data: dict[str, Any], key: str, path: Path) -> float:
    value = data[key]
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise InputFormatError(f"value {value!r} is not a number", path=path, field=key,
                               hint=f"write {key} as a positive number") from exc
    if not np.isfinite(number) or number <= 0:
        raise InputFormatError(f"value {value!r} must be positive", path=path, field=key,
                               hint=f"write {key} as a positive number")
    return number


def read_imu_calibration(path: str | Path) -> ImuCalibration:
    """An :class:`ImuCalibration` from an IMU ``sensor.yaml`` (Kalibr/EuRoC).

    Keys missing from the file keep the EuRoC defaults of :class:`ImuCalibration`;
    ``T_BS`` becomes ``T_body_imu``.

    Args:
        path: The IMU ``sensor.yaml``.

    Returns:
        The calibration (no ``T_imu_frames`` yet).

    Raises:
        InputFormatError: Unreadable YAML, a non-numeric noise value, or a bad T_BS.
    """
    path = Path(path)
    data = load_sensor_yaml(path)
    kwargs: dict[str, Any] = {}
    for key, attr in {**IMU_NOISE_KEYS, **IMU_LIMIT_KEYS}.items():
        if key in data:
            kwargs[attr] = _positive_float(data, key, path)
    T_BS = read_T_BS(path, data)
    if T_BS is not None:
        kwargs["T_body_imu"] = T_BS
    sources = {attr: str(path) for attr in kwargs
               if attr in NOISE_FIELDS or attr in IMU_LIMIT_KEYS.values() or attr == "rate_hz"}
    return ImuCalibration(**kwargs, sources=sources)


def missing_noise_keys(path: str | Path) -> list[str]:
    """Noise keys of :data:`IMU_NOISE_KEYS` that an IMU sensor.yaml lacks (they take defaults)."""
    data = load_sensor_yaml(path)
    return [k for k in IMU_NOISE_KEYS if k not in data]
