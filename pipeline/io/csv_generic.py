"""Generic CSV files described by a column mapping (:class:`CsvMapping`).

A mapping names (or numbers) the time column and the IMU and/or pose columns,
gives units and the quaternion order. Example (YAML)::

    time_column: "time(ns)"       # header name, or a 0-based column index
    time_unit: ns                 # s | ms | us | ns | auto (guessed and reported)
    position_columns: [px, py, pz]
    quat_columns: [qw, qx, qy, qz]
    quat_order: wxyz              # order of the four quat_columns: wxyz | xyzw
    gyro_columns: [wx, wy, wz]    # optional; with acc_columns
    acc_columns: [ax, ay, az]
    gyro_unit: radps              # radps | degps
    acc_unit: mps2                # mps2 | g
    delimiter: ","                # "," | ";" | "\\t" | whitespace

Header names are matched after stripping ``'#'`` and blanks, exactly first and
then ignoring case.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.configs import dataclass_to_mapping
from pipeline.errors import ConfigError, InputFormatError, UnsupportedInputError
from pipeline.io._stamps import TimeUnit
from pipeline.io._text import Delimiter, Header, parse_table, read_text, split_header, table_findings
from pipeline.io.registry import SOURCE_FORMAT_KEY, supported_hint
from pipeline.types import STANDARD_GRAVITY_MPS2, Finding, ImuSeries, PoseSeries, PoseSourceKind, Sequence

log = logging.getLogger(__name__)

#: Suffixes of a file read as generic CSV when no other reader recognises it.
CSV_SUFFIXES = (".csv", ".txt", ".tsv", ".tum", ".dat")


Column = str | int


class QuatOrder(str, enum.Enum):
    """Order of the four quaternion columns in the file."""

    WXYZ = "wxyz"
    XYZW = "xyzw"


class GyroUnit(str, enum.Enum):
    """Unit of the gyroscope columns."""

    RADPS = "radps"
    DEGPS = "degps"


class AccUnit(str, enum.Enum):
    """Unit of the accelerometer columns."""

    MPS2 = "mps2"
    G = "g"


_ENUM_ALIASES: dict[type[enum.Enum], dict[str, str]] = {
    TimeUnit: {"sec": "s", "seconds": "s", "second": "s", "msec": "ms", "usec": "us", "µs": "us",
               "nsec": "ns", "nanoseconds": "ns"},
    GyroUnit: {"rad/s": "radps", "rad_s": "radps", "deg/s": "degps", "deg_s": "degps", "dps": "degps"},
    AccUnit: {"m/s^2": "mps2", "m/s2": "mps2", "mps^2": "mps2"},
    Delimiter: {"comma": ",", "semicolon": ";", "tab": "\t", "\\t": "\t", "space": "whitespace",
                " ": "whitespace", "whitespace": "whitespace"},
    QuatOrder: {},
}


def _enum_value(cls: type[enum.Enum], value: Any, key: str) -> Any:
    if isinstance(value, cls):
        return value
    text = str(value)
    low = text if (cls is Delimiter and len(text) == 1) else text.strip().lower()
    low = _ENUM_ALIASES.get(cls, {}).get(low, low)
    try:
        return cls(low)
    except ValueError:
        choices = ", ".join(repr(m.value) for m in cls)  # type: ignore[attr-defined]
        raise ConfigError(f"invalid value {value!r}", field=key, hint=f"use one of {choices}") from None


def _columns(value: Any, key: str, n: int) -> tuple[Column, ...] | None:
    if value is None:
        return None
    if isinstance(value, (str, int)) or not isinstance(value, (list, tuple)) or len(value) != n:
        raise ConfigError(f"must be a list of {n} column names or 0-based indices, got {value!r}", field=key,
                          hint=f"write {key}: [{', '.join(['name'] * n)}]")
    out: list[Column] = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (str, int)) or (isinstance(v, int) and v < 0):
            raise ConfigError(f"entry {v!r} is not a column name or a 0-based index", field=key,
                              hint="use header names (strings) or non-negative integers")
        out.append(v)
    return tuple(out)


@dataclass(frozen=True)
class CsvMapping:
    """How to read a generic CSV: which columns hold time, IMU and pose values, in which units.

    Attributes:
        time_column: Header name or 0-based index of the stamp column.
        time_unit: Unit of the stamps (``AUTO`` guesses it and reports STAMP_UNIT_GUESSED).
        gyro_columns: Three columns of angular rate (x, y, z), or ``None``.
        acc_columns: Three columns of specific force (x, y, z), or ``None``.
        position_columns: Three columns of position [m] (x, y, z), or ``None``.
        quat_columns: Four quaternion columns listed in the file's order, or ``None``.
        quat_order: Order of ``quat_columns`` (WXYZ: w first; XYZW: w last).
        delimiter: Field separator.
        gyro_unit: rad/s or deg/s.
        acc_unit: m/s^2 or g (times 9.80665).
        pose_frame: Name of the tracked frame of the pose stream.
    """

    time_column: Column = 0
    time_unit: TimeUnit = TimeUnit.AUTO
    gyro_columns: tuple[Column, Column, Column] | None = None
    acc_columns: tuple[Column, Column, Column] | None = None
    position_columns: tuple[Column, Column, Column] | None = None
    quat_columns: tuple[Column, Column, Column, Column] | None = None
    quat_order: QuatOrder = QuatOrder.WXYZ
    delimiter: Delimiter = Delimiter.COMMA
    gyro_unit: GyroUnit = GyroUnit.RADPS
    acc_unit: AccUnit = AccUnit.MPS2
    pose_frame: str = "imu"

    def __post_init__(self) -> None:
        # Accept plain strings and lists (CsvMapping(delimiter="\t", gyro_columns=[1, 2, 3])).
        for key, cls_ in (("time_unit", TimeUnit), ("quat_order", QuatOrder), ("delimiter", Delimiter),
                          ("gyro_unit", GyroUnit), ("acc_unit", AccUnit)):
            object.__setattr__(self, key, _enum_value(cls_, getattr(self, key), key))
        for key, n in (("gyro_columns", 3), ("acc_columns", 3), ("position_columns", 3), ("quat_columns", 4)):
            object.__setattr__(self, key, _columns(getattr(self, key), key, n))
        if (self.gyro_columns is None) != (self.acc_columns is None):
            raise ConfigError("gyro_columns and acc_columns go together", field="gyro_columns"
                              if self.gyro_columns is None else "acc_columns",
                              hint="give both (IMU) or neither (pose only)")
        if self.quat_columns is not None and self.position_columns is None:
            raise ConfigError("quat_columns need position_columns", field="position_columns",
                              hint="give the three position columns of the pose stream")
        if self.gyro_columns is None and self.position_columns is None:
            raise ConfigError("the mapping selects no data", field="gyro_columns",
                              hint="give gyro_columns + acc_columns and/or position_columns (+ quat_columns)")

    @property
    def has_imu(self) -> bool:
        return self.gyro_columns is not None

    @property
    def has_poses(self) -> bool:
        return self.position_columns is not None

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CsvMapping":
        """Build and validate a mapping from plain data (a parsed YAML/JSON file).

        Raises:
            ConfigError: Unknown key, wrong type or value, or an incomplete mapping; names the key.
        """
        if not isinstance(d, dict):
            raise ConfigError(f"a CSV mapping must be a mapping of keys, got {type(d).__name__}",
                              hint="write 'key: value' pairs (time_column, gyro_columns, ...)")
        known = {f.name for f in fields(cls)}
        for key in d:
            if key not in known:
                raise ConfigError(f"unknown key {key!r} in the CSV mapping", field=str(key),
                                  hint=f"known keys: {', '.join(sorted(known))}")
        kwargs: dict[str, Any] = {}
        if "time_column" in d:
            tc = d["time_column"]
            if isinstance(tc, bool) or not isinstance(tc, (str, int)) or (isinstance(tc, int) and tc < 0):
                raise ConfigError(f"invalid value {tc!r}", field="time_column",
                                  hint="give the stamp column's header name or 0-based index")
            kwargs["time_column"] = tc
        for key, cls_ in (("time_unit", TimeUnit), ("quat_order", QuatOrder), ("delimiter", Delimiter),
                          ("gyro_unit", GyroUnit), ("acc_unit", AccUnit)):
            if key in d:
                kwargs[key] = _enum_value(cls_, d[key], key)
        for key, n in (("gyro_columns", 3), ("acc_columns", 3), ("position_columns", 3), ("quat_columns", 4)):
            if key in d:
                kwargs[key] = _columns(d[key], key, n)
        if "pose_frame" in d:
            if not isinstance(d["pose_frame"], str) or not d["pose_frame"]:
                raise ConfigError(f"invalid value {d['pose_frame']!r}", field="pose_frame",
                                  hint="give the tracked frame's name as a string")
            kwargs["pose_frame"] = d["pose_frame"]
        return cls(**kwargs)

    @classmethod
    def from_file(cls, path: str | Path) -> "CsvMapping":
        """Read a mapping from a YAML (or JSON) file."""
        path = Path(path)
        if not path.is_file():
            raise ConfigError("CSV mapping file does not exist", path=path, hint="check the path")
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except yaml.YAMLError as exc:
            raise ConfigError(f"CSV mapping is not valid YAML ({exc})", path=path,
                              hint="fix the YAML syntax") from exc
        try:
            return cls.from_dict(data)
        except ConfigError as exc:
            raise ConfigError(exc.problem, path=path, field=exc.field, hint=exc.hint) from None

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (enums as values, tuples as lists): what :meth:`from_dict` reads back."""
        return dataclass_to_mapping(self)


def _resolve(col: Column, header: Header, key: str, path: Path, ncols: int) -> int:
    if isinstance(col, int):
        if col >= ncols:
            raise InputFormatError(f"column index {col} is out of range (the file has {ncols} columns)",
                                   path=path, field=key, hint="column indices are 0-based")
        return col
    if header.names is None:
        raise InputFormatError(f"the file has no header, so column {col!r} cannot be found", path=path,
                               field=key, hint="use 0-based column indices in the mapping")
    names = header.names
    if col in names:
        return names.index(col)
    low = [n.lower() for n in names]
    if col.strip().lower() in low:
        return low.index(col.strip().lower())
    raise InputFormatError(f"column {col!r} is not in the header", path=path, line=header.line, field=key,
                           hint=f"the header has: {', '.join(names)}")


def _column_count(text: str, header: Header, delimiter: Delimiter) -> int:
    """The number of columns: the header's, else the first data line's (trailing separators ignored)."""
    if header.names is not None:
        ncols = len(header.names)
    else:
        end = text.find("\n", header.data_offset)
        first = text[header.data_offset:end if end >= 0 else None].strip()
        if delimiter is not Delimiter.WHITESPACE:
            first = first.rstrip(delimiter.value)
        ncols = len(delimiter.split(first))
    return ncols


def _mapped_columns(mapping: CsvMapping, header: Header, path: Path, ncols: int
                    ) -> tuple[int, list[int], list[int], list[int], list[int], list[int]]:
    """``(t_col, gyro, acc, pos, quat, value_cols)``: the mapping's columns as indices; ``value_cols``
    all value columns once each, in that order.

    Raises:
        ConfigError / InputFormatError: Unknown column, or the time column used as a value too.
    """
    def res(cols: tuple[Column, ...] | None, key: str) -> list[int]:
        return [] if cols is None else [_resolve(c, header, key, path, ncols) for c in cols]

    t_col = _resolve(mapping.time_column, header, "time_column", path, ncols)
    gyro = res(mapping.gyro_columns, "gyro_columns")
    acc = res(mapping.acc_columns, "acc_columns")
    pos = res(mapping.position_columns, "position_columns")
    quat = res(mapping.quat_columns, "quat_columns")
    value_cols = list(dict.fromkeys(gyro + acc + pos + quat))
    if t_col in value_cols:
        raise ConfigError("time_column is also used as a value column", path=path, field="time_column",
                          hint="map each column to one quantity")
    return t_col, gyro, acc, pos, quat, value_cols


def detect_csv(path: str | Path) -> bool:
    """Whether ``path`` may be read as generic CSV: a file with a :data:`CSV_SUFFIXES` suffix."""
    path = Path(path)
    return path.is_file() and path.suffix.lower() in CSV_SUFFIXES


def load_csv(path: str | Path, *, name: str | None = None,
             csv_mapping: CsvMapping | dict[str, Any] | str | Path | None = None) -> Sequence:
    """Read a CSV through ``csv_mapping`` (a :class:`CsvMapping`, a dict or a YAML file path).

    Raises:
        UnsupportedInputError: No mapping given.
        ConfigError: Invalid mapping.
        InputFormatError: As :func:`read_csv_generic`.
    """
    if csv_mapping is None:
        raise UnsupportedInputError(
            "CSV file needs a column mapping (its header is not an ASL layout)", path=path,
            hint="pass --csv-mapping FILE.yaml naming time_column, gyro/acc and/or position/quat columns; "
                 + supported_hint(),
        )
    if not isinstance(csv_mapping, (CsvMapping, dict)):
        csv_mapping = CsvMapping.from_file(csv_mapping)
    return read_csv_generic(path, csv_mapping, name=name)


def read_csv_generic(
    path: str | Path,
    mapping: CsvMapping | dict[str, Any],
    *,
    name: str | None = None,
    source_kind: PoseSourceKind = PoseSourceKind.MOCAP,
) -> Sequence:
    """Read a CSV file through a column mapping.

    Args:
        path: The CSV file.
        mapping: Which columns hold what (a dict is validated with :meth:`CsvMapping.from_dict`).
        name: Sequence name; default the file stem.
        source_kind: What produced the pose stream, if the mapping selects one (default MOCAP).

    Returns:
        A Sequence with ``imu`` and/or one pose stream named after the file stem.

    Raises:
        ConfigError: Invalid mapping.
        InputFormatError: Missing/empty file, unknown column, or more than 10 % unparseable lines.
    """
    path = Path(path)
    if not isinstance(mapping, CsvMapping):
        mapping = CsvMapping.from_dict(mapping)
    text = read_text(path)
    header = split_header(text, mapping.delimiter)
    ncols = _column_count(text, header, mapping.delimiter)
    t_col, gyro, acc, pos, quat, value_cols = _mapped_columns(mapping, header, path, ncols)
    parsed = parse_table(path, text, header, ncols=ncols, stamp_col=t_col, value_cols=value_cols,
                         delimiter=mapping.delimiter, unit=mapping.time_unit,
                         what=f"CSV with {ncols} {mapping.delimiter.label}-separated columns")
    index = {c: i for i, c in enumerate(value_cols)}

    def take(cols: list[int]) -> np.ndarray:
        return parsed.values[:, [index[c] for c in cols]]

    stream = path.stem
    seq_name = name or stream
    findings: list[Finding] = []
    imu = None
    poses: dict[str, PoseSeries] = {}
    files: dict[str, str] = {}
    if mapping.has_imu:
        gyro_v = take(gyro)
        if mapping.gyro_unit is GyroUnit.DEGPS:
            gyro_v = np.deg2rad(gyro_v)
        acc_v = take(acc)
        if mapping.acc_unit is AccUnit.G:
            acc_v = acc_v * STANDARD_GRAVITY_MPS2
        imu = ImuSeries(parsed.t_ns, gyro_v, acc_v)
        findings += table_findings(parsed, path, "imu", ncols)
        files["imu"] = str(path)
    if mapping.has_poses:
        quat_v = None
        if quat:
            q = take(quat)
            quat_v = q if mapping.quat_order is QuatOrder.WXYZ else q[:, [3, 0, 1, 2]]
        kind = PoseSourceKind(source_kind)
        if quat_v is None and kind is PoseSourceKind.MOCAP:
            kind = PoseSourceKind.POSITION_TRACKER
        poses[stream] = PoseSeries(parsed.t_ns, take(pos), quat_v, mapping.pose_frame, kind)
        findings += table_findings(parsed, path, f"poses/{stream}", ncols)
        files[f"poses/{stream}"] = str(path)
    log.info("read CSV %s: %s", path, {k: len(v) for k, v in {"imu": imu, **poses}.items() if v is not None})
    return Sequence(
        name=seq_name,
        imu=imu,
        poses=poses,
        findings=findings,
        metadata={"source_path": str(path), SOURCE_FORMAT_KEY: "csv", "files": files,
                  "csv_mapping": mapping.to_dict()},
    )
