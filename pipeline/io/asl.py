"""ASL dataset folders (EuRoC MAV, TUM-VI) and standalone ASL-format CSV files.

Layout (``ROOT/mav0/`` or the ``mav0`` folder itself)::

    imu0/data.csv                        timestamp [ns], w xyz [rad/s], a xyz [m/s^2]
                                         (+ optional last column 'temperature [degC]')
    imu0/sensor.yaml                     noise model, rate, T_BS (-> ImuCalibration)
    vicon0/ mocap0/ <name>0/data.csv     timestamp [ns], p xyz [m], q wxyz      (6-DoF pose streams)
    leica0/data.csv                      timestamp [ns], p xyz [m]              (position only)
    <stream>/sensor.yaml                 T_BS: pose of the tracked point in the body frame
    state_groundtruth_estimate0/data.csv timestamp, p xyz, q wxyz, v xyz, b_w xyz, b_a xyz
    gt0/data.csv                         same, Kimera-VIO's folder name

Pose streams land in ``Sequence.poses`` under their folder name, the EuRoC ground
truth in ``Sequence.ground_truth``. Nothing is sorted, deduplicated or normalised
here (:mod:`pipeline.checks` does that); unparseable lines are skipped and reported.

IMU temperature: EuRoC's and TUM-VI's ``imu0/data.csv`` hold the seven columns above and no
temperature. biasgt (its simulator) adds the die temperature as an optional eighth column named
``temperature [degC]`` (any name starting with ``temp``), read into ``ImuSeries.temperature_degc``;
tools that read the first seven columns are unaffected. It needs the header: eight unnamed
columns are a pose file.
"""

from __future__ import annotations

import enum
import logging
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.errors import InputFormatError
from pipeline.io._stamps import TimeUnit
from pipeline.io._text import Delimiter, Header, ParsedTable, parse_table, read_text, split_header, table_findings
from pipeline.io.sensor_yaml import IMU_NOISE_KEYS, load_sensor_yaml, read_imu_calibration, read_T_BS
from pipeline.io.registry import SOURCE_FORMAT_KEY
from pipeline.types import (
    Finding,
    ImuCalibration,
    ImuSeries,
    PoseSeries,
    PoseSourceKind,
    Sequence,
    Severity,
    StateSeries,
)

log = logging.getLogger(__name__)

IMU_STREAM = "imu0"
#: Ground-truth state folders, in order of preference.
GROUND_TRUTH_STREAMS = ("state_groundtruth_estimate0", "gt0")
#: The ASL reader's format name (pipeline.io.registry), recorded in ``metadata[SOURCE_FORMAT_KEY]``.
ASL_FORMAT = "asl"
#: Known pose-stream folders: (source kind, tracked-frame name).
KNOWN_POSE_STREAMS: dict[str, tuple[PoseSourceKind, str]] = {
    "vicon0": (PoseSourceKind.MOCAP, "vicon_marker"),
    "mocap0": (PoseSourceKind.MOCAP, "mocap_marker"),
    "leica0": (PoseSourceKind.POSITION_TRACKER, "leica_prism"),
}
CODE_CALIBRATION_DEFAULTED = "CALIBRATION_DEFAULTED"


class AslTable(str, enum.Enum):
    """The kinds of ASL ``data.csv`` this reader understands (by column layout)."""

    IMU = "imu"  # 7 columns: t, w xyz, a xyz
    IMU_TEMPERATURE = "imu_temperature"  # 8 columns: t, w xyz, a xyz, temperature (named in the header)
    POSE = "pose"  # 8 columns: t, p xyz, q wxyz
    POSITION = "position"  # 4 columns: t, p xyz
    STATE = "state"  # 17 columns: t, p xyz, q wxyz, v xyz, b_w xyz, b_a xyz


_NCOLS = {AslTable.IMU: 7, AslTable.IMU_TEMPERATURE: 8, AslTable.POSE: 8, AslTable.POSITION: 4, AslTable.STATE: 17}
IMU_TABLES = (AslTable.IMU, AslTable.IMU_TEMPERATURE)
_WHAT = {
    AslTable.IMU: "ASL IMU CSV (timestamp [ns], w xyz [rad/s], a xyz [m/s^2])",
    AslTable.IMU_TEMPERATURE: "ASL IMU CSV (timestamp [ns], w xyz [rad/s], a xyz [m/s^2], temperature [degC])",
    AslTable.POSE: "ASL pose CSV (timestamp [ns], p xyz [m], q wxyz)",
    AslTable.POSITION: "ASL position CSV (timestamp [ns], p xyz [m])",
    AslTable.STATE: "EuRoC ground-truth CSV (timestamp [ns], p xyz, q wxyz, v xyz, b_w xyz, b_a xyz)",
}
_UNIT_RE = re.compile(r"\[[^\]]*\]|\([^)]*\)")


def _norm(name: str) -> str:
    """``'q_RS_w []'`` -> ``'q_rs_w'``, ``'#time(ns)'`` -> ``'time'``."""
    return _UNIT_RE.sub("", name).strip().lstrip("#").strip().lower()


def _starts(names: list[str], prefixes: tuple[str, ...]) -> bool:
    return all(n.startswith(prefixes) for n in names)


def classify_header(names: list[str] | None, n_fields: int | None = None) -> AslTable | None:
    """The ASL table kind a header describes, or ``None`` if it is not one.

    Args:
        names: Header column names (``None`` for a file without header).
        n_fields: Field count of the first data line, used when there is no header.

    Returns:
        The kind, or ``None``.
    """
    if names is None:
        return {7: AslTable.IMU, 8: AslTable.POSE, 4: AslTable.POSITION, 17: AslTable.STATE}.get(n_fields or -1)
    norm = [_norm(n) for n in names]
    if not norm or not (norm[0].startswith(("time", "stamp")) or norm[0] == "t"):
        return None
    rest = norm[1:]
    if len(norm) in (7, 8) and _starts(rest[:3], ("w", "g")) and _starts(rest[3:6], ("a",)):
        if len(norm) == 7:
            return AslTable.IMU
        if rest[6].startswith("temp"):
            return AslTable.IMU_TEMPERATURE
    if len(norm) == 8 and _starts(rest[:3], ("p",)) and _starts(rest[3:], ("q",)):
        return AslTable.POSE
    if len(norm) == 4 and _starts(rest, ("p",)):
        return AslTable.POSITION
    if (len(norm) == 17 and _starts(rest[:3], ("p",)) and _starts(rest[3:7], ("q",))
            and _starts(rest[7:10], ("v",)) and _starts(rest[10:], ("b",))):
        return AslTable.STATE
    return None


def _quat_wxyz_order(names: list[str] | None, first: int) -> list[int]:
    """Column indices of w, x, y, z among the 4 quaternion columns starting at ``first``.

    ASL files are w, x, y, z; a header whose quaternion names end in a permutation of
    ``wxyz`` (``q_RS_x, ..., q_RS_w``) is honoured.
    """
    default = [first, first + 1, first + 2, first + 3]
    if names is None or len(names) < first + 4:
        return default
    last = [_norm(n)[-1:] for n in names[first:first + 4]]
    if sorted(last) != ["w", "x", "y", "z"]:
        return default
    return [first + last.index(axis) for axis in "wxyz"]


@dataclass(frozen=True)
class _Table:
    kind: AslTable
    header: Header
    parsed: ParsedTable
    quat_cols: list[int]


def _first_fields(text: str, header: Header) -> int | None:
    end = text.find("\n", header.data_offset)
    line = text[header.data_offset:end if end >= 0 else None].strip()
    return len(line.split(",")) if line else None


def _read_table(path: Path, expected: tuple[AslTable, ...], stream: str) -> tuple[_Table, list[Finding]]:
    """Parse an ASL CSV whose kind must be one of ``expected``."""
    text = read_text(path)
    header = split_header(text, Delimiter.COMMA)
    kind = classify_header(header.names, _first_fields(text, header))
    trusted = AslTable.IMU if expected == IMU_TABLES else (expected[0] if len(expected) == 1 else None)
    if kind is None and header.names is not None and trusted is not None:
        # Unusual names but the right column count (e.g. a hand-written header): trust the folder.
        # (A temperature column is recognised by its name only.)
        if len(header.names) == _NCOLS[trusted]:
            kind = trusted
    if kind not in expected:
        wanted = " or ".join(_WHAT[k] for k in expected)
        got = ("no header" if header.names is None
               else f"header with {len(header.names)} columns: {', '.join(header.names[:8])}"
               + (", ..." if len(header.names) > 8 else ""))
        raise InputFormatError(
            f"not a {wanted} ({got})", path=path, line=header.line or header.first_data_line,
            hint=f"the file needs the header and the {' or '.join(str(_NCOLS[k]) for k in expected)} "
                 "comma-separated columns of that format",
        )
    ncols = _NCOLS[kind]
    parsed = parse_table(path, text, header, ncols=ncols, stamp_col=0, value_cols=list(range(1, ncols)),
                         delimiter=Delimiter.COMMA, unit=TimeUnit.NS, what=_WHAT[kind])
    quat_cols = _quat_wxyz_order(header.names, 4) if kind in (AslTable.POSE, AslTable.STATE) else []
    return _Table(kind, header, parsed, quat_cols), table_findings(parsed, path, stream, ncols)


def _values(table: _Table, cols: list[int]) -> np.ndarray:
    """Columns of the parsed table by file column index (value column j is file column j + 1)."""
    return table.parsed.values[:, [c - 1 for c in cols]]


def read_asl_imu_csv(path: str | Path, *, stream: str = "imu") -> tuple[ImuSeries, list[Finding]]:
    """Read an ASL IMU ``data.csv``.

    Args:
        path: The file.
        stream: Stream name used in findings.

    Returns:
        ``(imu, findings)``: readings (t_ns [N], gyro_radps [N, 3], acc_mps2 [N, 3] and, from an
        eighth ``temperature`` column, temperature_degc [N]) and parse findings.
    """
    path = Path(path)
    table, findings = _read_table(path, IMU_TABLES, stream)
    temperature = _values(table, [7])[:, 0] if table.kind is AslTable.IMU_TEMPERATURE else None
    return ImuSeries(table.parsed.t_ns, _values(table, [1, 2, 3]), _values(table, [4, 5, 6]), temperature), findings


def read_asl_state_csv(path: str | Path, *, stream: str = "ground_truth") -> tuple[StateSeries, list[Finding]]:
    """Read an EuRoC ground-truth state CSV (``state_groundtruth_estimate0/data.csv``, ``gt0/data.csv``).

    Returns:
        ``(state, findings)``.
    """
    path = Path(path)
    table, findings = _read_table(path, (AslTable.STATE,), stream)
    state = StateSeries(
        table.parsed.t_ns,
        _values(table, [1, 2, 3]),
        _values(table, table.quat_cols),
        _values(table, [8, 9, 10]),
        _values(table, [11, 12, 13]),
        _values(table, [14, 15, 16]),
    )
    return state, findings


def _pose_series(path: Path, stream: str, source_kind: PoseSourceKind | None, frame: str | None,
                 finding_stream: str) -> tuple[PoseSeries, list[Finding]]:
    table, findings = _read_table(path, (AslTable.POSE, AslTable.POSITION), finding_stream)
    _, known_frame = KNOWN_POSE_STREAMS.get(stream, (None, stream))
    if table.kind is AslTable.POSE:
        quat = _values(table, table.quat_cols)
        kind = source_kind or PoseSourceKind.MOCAP
    else:
        quat = None
        kind = source_kind or PoseSourceKind.POSITION_TRACKER
    poses = PoseSeries(table.parsed.t_ns, _values(table, [1, 2, 3]), quat, frame or known_frame, kind)
    return poses, findings


def read_asl_pose_csv(
    path: str | Path,
    *,
    source_kind: PoseSourceKind | None = None,
    frame: str | None = None,
    name: str | None = None,
    stream: str | None = None,
) -> Sequence:
    """Read a standalone ASL-format pose CSV (a TUM-VI ``mocap0/data.csv``, a ``vicon0`` file) as a pose-only Sequence.

    Accepts ``timestamp [ns], p xyz [m], q wxyz`` (6-DoF) or ``timestamp [ns], p xyz``
    (position only); headers may have spaces after the commas.

    Args:
        path: The CSV file.
        source_kind: What produced it; default MOCAP for 6-DoF, POSITION_TRACKER for position only.
        frame: Tracked-frame name; default from the stream name (``vicon0`` -> ``vicon_marker``,
            ``mocap0`` -> ``mocap_marker``, ``leica0`` -> ``leica_prism``, else the stream name).
        name: Sequence name; default the file stem (the folder name for ``<stream>/data.csv``).
        stream: Pose-stream name; default as ``name``'s default.

    Returns:
        A Sequence with one pose stream and the parse findings.
    """
    path = Path(path)
    default = _standalone_stream_name(path)
    stream = stream or default
    source_kind = None if source_kind is None else PoseSourceKind(source_kind)
    poses, findings = _pose_series(path, stream, source_kind, frame, f"poses/{stream}")
    return Sequence(
        name=name or default,
        poses={stream: poses},
        findings=findings,
        metadata={"source_path": str(path), SOURCE_FORMAT_KEY: ASL_FORMAT, "files": {f"poses/{stream}": str(path)}},
    )


def _standalone_stream_name(path: Path) -> str:
    """``.../vicon0/data.csv`` -> ``vicon0``; ``dataset-room1_512_16.csv`` -> ``dataset-room1_512_16``."""
    if path.stem == "data" and path.parent.name:
        return path.parent.name
    return path.stem


def sniff_asl_csv(path: str | Path) -> AslTable | None:
    """The ASL table kind of a CSV file judged from its header alone, or ``None``."""
    path = Path(path)
    try:
        with path.open("r", encoding="utf-8-sig", errors="replace") as f:
            head = f.read(8192)
    except OSError:
        return None
    header = split_header(head, Delimiter.COMMA)
    if header.names is None:
        return None
    return classify_header(header.names)


def detect_asl(path: str | Path) -> bool:
    """Whether ``path`` is ASL input: a folder with ``mav0/`` (or its streams), or a CSV whose header is an ASL layout."""
    path = Path(path)
    return find_mav0(path) is not None if path.is_dir() else sniff_asl_csv(path) is not None


def load_asl(path: str | Path, *, name: str | None = None) -> Sequence:
    """An ASL folder (:func:`read_asl`) or one ASL CSV (:func:`read_asl_csv`) as a Sequence."""
    path = Path(path)
    return read_asl(path, name=name) if path.is_dir() else read_asl_csv(path, name=name)


def read_asl_csv(path: str | Path, *, name: str | None = None,
                 source_kind: PoseSourceKind | None = None) -> Sequence:
    """Read one standalone ASL-format CSV of any kind (IMU, pose, position, EuRoC ground truth).

    Args:
        path: The CSV file (its header decides the kind).
        name: Sequence name; default the file stem (or the folder of a ``data.csv``).
        source_kind: For pose files, what produced them (see :func:`read_asl_pose_csv`).

    Returns:
        A Sequence holding the one stream.

    Raises:
        InputFormatError: The header is not one of the ASL layouts.
    """
    path = Path(path)
    kind = sniff_asl_csv(path)
    if kind in (AslTable.POSE, AslTable.POSITION):
        return read_asl_pose_csv(path, source_kind=source_kind, name=name)
    default = _standalone_stream_name(path)
    meta = {"source_path": str(path), SOURCE_FORMAT_KEY: ASL_FORMAT}
    if kind in IMU_TABLES:
        imu, findings = read_asl_imu_csv(path)
        return Sequence(name=name or default, imu=imu, findings=findings,
                        metadata={**meta, "files": {"imu": str(path)}})
    if kind is AslTable.STATE:
        gt, findings = read_asl_state_csv(path)
        return Sequence(name=name or default, ground_truth=gt, findings=findings,
                        metadata={**meta, "files": {"ground_truth": str(path)}})
    text = read_text(path)  # raises for missing / empty files
    header = split_header(text, Delimiter.COMMA)
    raise InputFormatError(
        "header is not an ASL layout (IMU, pose, position or EuRoC ground truth)",
        path=path, line=header.line or 1,
        hint="give an ASL CSV ('#timestamp [ns], ...') or a CSV column mapping (--csv-mapping)",
    )


def find_mav0(path: str | Path) -> Path | None:
    """The ``mav0``-like folder of an ASL dataset: ``path/mav0``, or ``path`` if it holds the streams."""
    path = Path(path)
    if (path / "mav0").is_dir():
        return path / "mav0"
    if path.is_dir() and ((path / IMU_STREAM).is_dir() or path.name == "mav0"
                          or any((path / g / "data.csv").is_file() for g in GROUND_TRUTH_STREAMS)
                          or any((path / p / "data.csv").is_file() for p in KNOWN_POSE_STREAMS)):
        return path
    return None


def _calibration(mav0: Path, pose_frames: dict[str, str]) -> tuple[ImuCalibration, list[Finding]]:
    """IMU calibration from imu0/sensor.yaml plus ``T_imu_<frame>`` from the pose streams' sensor.yaml."""
    findings: list[Finding] = []
    imu_yaml = mav0 / IMU_STREAM / "sensor.yaml"
    if imu_yaml.is_file():
        calib = read_imu_calibration(imu_yaml)
        missing = [k for k in IMU_NOISE_KEYS if k not in load_sensor_yaml(imu_yaml)]
        if missing:
            findings.append(Finding(
                CODE_CALIBRATION_DEFAULTED, Severity.WARNING, "imu",
                f"{imu_yaml} lacks {', '.join(missing)}; using the EuRoC (ADIS16448) defaults for them; "
                "add them to the sensor.yaml if this is another IMU",
                {"file": str(imu_yaml), "missing_keys": missing},
            ))
    else:
        calib = ImuCalibration()
        findings.append(Finding(
            CODE_CALIBRATION_DEFAULTED, Severity.WARNING, "imu",
            f"no {IMU_STREAM}/sensor.yaml in {mav0}: using the EuRoC (ADIS16448) noise model and identity "
            "T_body_imu; add a Kalibr-style imu0/sensor.yaml if this is another IMU",
            {"file": str(imu_yaml), "missing_keys": list(IMU_NOISE_KEYS)},
        ))
    T_imu_body = np.linalg.inv(calib.T_body_imu)
    frames: dict[str, np.ndarray] = dict(calib.T_imu_frames)
    for stream, frame in pose_frames.items():
        yaml_path = mav0 / stream / "sensor.yaml"
        if not yaml_path.is_file():
            continue
        T_BS = read_T_BS(yaml_path)
        if T_BS is not None:
            frames[frame] = T_imu_body @ T_BS
    return replace(calib, T_imu_frames=frames), findings


def read_asl(path: str | Path, *, name: str | None = None) -> Sequence:
    """Read an ASL dataset folder (EuRoC MAV, TUM-VI).

    Args:
        path: The dataset root holding ``mav0/``, or the ``mav0`` folder itself.
        name: Sequence name; default the dataset root's folder name.

    Returns:
        The Sequence: ``imu`` from imu0, ``poses`` keyed by stream folder (``vicon0``,
        ``leica0``, ...), ``ground_truth`` from state_groundtruth_estimate0 (or gt0),
        the calibration and every parse finding.

    Raises:
        InputFormatError: The folder is missing or holds no readable stream, or a file is malformed.
    """
    root = Path(path)
    if not root.exists():
        raise InputFormatError("does not exist", path=root, hint="check the path")
    mav0 = find_mav0(root)
    if mav0 is None:
        raise InputFormatError(
            "not an ASL dataset folder (no mav0/, imu0/ or pose/ground-truth stream folders)", path=root,
            hint="pass the dataset root that holds mav0/ (EuRoC, TUM-VI layout)",
        )
    seq_name = name or (mav0.parent.name if mav0.name == "mav0" else mav0.name) or "sequence"
    findings: list[Finding] = []
    files: dict[str, str] = {}
    imu = None
    imu_csv = mav0 / IMU_STREAM / "data.csv"
    if imu_csv.is_file():
        imu, f = read_asl_imu_csv(imu_csv)
        findings += f
        files["imu"] = str(imu_csv)

    ground_truth = None
    for gt_stream in GROUND_TRUTH_STREAMS:
        gt_csv = mav0 / gt_stream / "data.csv"
        if gt_csv.is_file():
            ground_truth, f = read_asl_state_csv(gt_csv)
            findings += f
            files["ground_truth"] = str(gt_csv)
            break

    poses: dict[str, PoseSeries] = {}
    frames: dict[str, str] = {}
    for sub in sorted(p for p in mav0.iterdir() if p.is_dir()):
        stream = sub.name
        csv_path = sub / "data.csv"
        if stream == IMU_STREAM or stream in GROUND_TRUTH_STREAMS or not csv_path.is_file():
            continue
        if stream not in KNOWN_POSE_STREAMS:
            kind = sniff_asl_csv(csv_path)
            if kind not in (AslTable.POSE, AslTable.POSITION):
                log.debug("skipping %s: not a pose stream (%s)", csv_path, kind)
                continue
        series, f = _pose_series(csv_path, stream, None, None, f"poses/{stream}")
        poses[stream] = series
        frames[stream] = series.frame
        findings += f
        files[f"poses/{stream}"] = str(csv_path)

    if imu is None and ground_truth is None and not poses:
        raise InputFormatError(
            "ASL folder holds no readable stream (imu0/data.csv, pose or ground-truth data.csv)", path=mav0,
            hint="pass a folder with the EuRoC/TUM-VI layout mav0/<stream>/data.csv",
        )
    calib, f = _calibration(mav0, frames)
    findings = f + findings
    log.info("read ASL %s: imu %s rows, pose streams %s, ground truth %s rows", mav0,
             0 if imu is None else len(imu), {k: len(v) for k, v in poses.items()},
             0 if ground_truth is None else len(ground_truth))
    return Sequence(
        name=seq_name,
        imu=imu,
        poses=poses,
        ground_truth=ground_truth,
        calibration=calib,
        findings=findings,
        metadata={"source_path": str(root), SOURCE_FORMAT_KEY: ASL_FORMAT, "files": files},
    )
