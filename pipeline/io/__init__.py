"""Input readers and the dispatcher that picks one.

Supported inputs (:class:`SourceFormat`):

* ``STORE``: a canonical biasgt store folder (``sequence.yaml`` + Parquet), :mod:`pipeline.store`;
* ``ASL``:   an ASL dataset folder (EuRoC MAV, TUM-VI: ``ROOT/mav0/imu0/data.csv``, ...) or one
  ASL-format CSV (``#timestamp [ns], p_RS_R_x [m], ...``), :mod:`pipeline.io.asl`;
* ``TUM``:   a TUM trajectory text file (``t[s] x y z qx qy qz qw``), :mod:`pipeline.io.tum`;
* ``CSV``:   any CSV with a column mapping, :mod:`pipeline.io.csv_generic`;
* ``BAG``:   a ROS 1 ``.bag``, ROS 2 ``.db3``/``.mcap`` file or bag folder, :mod:`pipeline.io.rosbag`.

Pose-stream selection (:func:`select_pose_stream`), default priority:
``vicon0`` > ``mocap0`` > ``leica0`` > other MOCAP streams > other POSITION_TRACKER streams >
VIO streams > GROUND_TRUTH-kind pose streams > the ground-truth state as poses (``"ground_truth"``).
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pipeline.errors import AmbiguousInputError, ConfigError, DataError, InputFormatError, UnsupportedInputError
from pipeline.io._stamps import TimeUnit
from pipeline.io.asl import (
    CODE_CALIBRATION_DEFAULTED,
    AslTable,
    find_mav0,
    read_asl,
    read_asl_csv,
    read_asl_pose_csv,
    sniff_asl_csv,
)
from pipeline.io.csv_generic import AccUnit, CsvMapping, GyroUnit, QuatOrder, read_csv_generic
from pipeline.io.tum import read_tum, write_tum
from pipeline.store import is_store, read_store
from pipeline.types import Finding, PoseSeries, PoseSourceKind, Sequence, Severity

log = logging.getLogger(__name__)

#: Name under which the ground-truth state is offered as a pose stream.
GROUND_TRUTH_STREAM = "ground_truth"
#: Named streams first, in this order.
PREFERRED_POSE_STREAMS = ("vicon0", "mocap0", "leica0")
# sequence.metadata key: the pose streams merged from other inputs (--add-poses), first by default
ADDED_POSE_STREAMS_KEY = "added_pose_streams"
_KIND_RANK = {
    PoseSourceKind.MOCAP: 0,
    PoseSourceKind.POSITION_TRACKER: 1,
    PoseSourceKind.VIO: 2,
    PoseSourceKind.GROUND_TRUTH: 3,
}
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
TUM_SUFFIXES = (".txt", ".tum")

SUPPORTED_HINT = (
    "supported inputs: a biasgt store folder (sequence.yaml), an ASL/EuRoC/TUM-VI folder (mav0/imu0/data.csv) "
    "or ASL CSV, a TUM trajectory (.txt/.tum: t x y z qx qy qz qw), a ROS bag (.bag, .mcap, .db3 or a folder "
    "with metadata.yaml), or any CSV with a column mapping (--csv-mapping)"
)


class SourceFormat(str, enum.Enum):
    """Kinds of input :func:`load_sequence` reads."""

    STORE = "store"
    ASL = "asl"
    TUM = "tum"
    CSV = "csv"
    BAG = "bag"


def _first_data_fields(path: Path, limit: int = 65536) -> list[str] | None:
    """Whitespace fields of the first non-comment, non-blank line of a text file, or ``None``."""
    try:
        with path.open("r", encoding="utf-8-sig", errors="replace") as f:
            head = f.read(limit)
    except OSError:
        return None
    if "\x00" in head:
        return None
    for line in head.splitlines():
        s = line.strip()
        if s and not s.startswith("#"):
            return s.split()
    return None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _looks_tum(path: Path) -> bool:
    fields = _first_data_fields(path)
    return fields is not None and len(fields) == 8 and all(_is_number(x) for x in fields)


def detect_format(path: str | Path) -> SourceFormat:
    """Guess the kind of input at ``path``.

    Rules: a folder with ``sequence.yaml`` is a STORE; a folder with ``mav0/`` or ``imu0/`` (or
    ASL stream folders) is ASL; ``.bag``/``.mcap``/``.db3`` files and folders with ``metadata.yaml``
    are BAG; a ``.txt``/``.tum`` file whose first data line has 8 numbers is TUM; a CSV whose header
    is an ASL layout is ASL; any other CSV/text file is CSV (and needs a column mapping).

    Raises:
        InputFormatError: ``path`` does not exist.
        UnsupportedInputError: Nothing fits.
    """
    path = Path(path)
    if not path.exists():
        raise InputFormatError("does not exist", path=path, hint="check the path")
    if path.is_dir():
        if is_store(path):
            return SourceFormat.STORE
        if find_mav0(path) is not None:
            return SourceFormat.ASL
        if (path / "metadata.yaml").is_file():
            return SourceFormat.BAG
        raise UnsupportedInputError("folder is not a recognised input", path=path, hint=SUPPORTED_HINT)
    suffix = path.suffix.lower()
    if suffix in BAG_SUFFIXES:
        return SourceFormat.BAG
    if suffix in TUM_SUFFIXES and _looks_tum(path):
        return SourceFormat.TUM
    if sniff_asl_csv(path) is not None:
        return SourceFormat.ASL
    if suffix in (".csv", ".txt", ".tsv", ".tum", ".dat"):
        return SourceFormat.CSV
    raise UnsupportedInputError(f"unrecognised file type '{suffix or path.name}'", path=path, hint=SUPPORTED_HINT)


#: Other names accepted for a format (``--format rosbag``).
FORMAT_ALIASES = {
    "rosbag": SourceFormat.BAG, "ros": SourceFormat.BAG, "ros1": SourceFormat.BAG, "ros2": SourceFormat.BAG,
    "rosbag1": SourceFormat.BAG, "rosbag2": SourceFormat.BAG, "mcap": SourceFormat.BAG, "db3": SourceFormat.BAG,
    "euroc": SourceFormat.ASL, "tumvi": SourceFormat.ASL, "tum-vi": SourceFormat.ASL,
    "parquet": SourceFormat.STORE, "biasgt": SourceFormat.STORE,
}


def parse_format(fmt: SourceFormat | str) -> SourceFormat:
    """A :class:`SourceFormat` from its value or an alias (``"rosbag"``, ``"euroc"``), case-insensitive.

    Raises:
        ConfigError: Unknown format name.
    """
    if isinstance(fmt, SourceFormat):
        return fmt
    key = str(fmt).strip().lower()
    if key in FORMAT_ALIASES:
        return FORMAT_ALIASES[key]
    try:
        return SourceFormat(key)
    except ValueError:
        names = sorted({f.value for f in SourceFormat} | set(FORMAT_ALIASES))
        raise ConfigError(f"unknown input format {fmt!r}", field="format",
                          hint=f"use one of {', '.join(names)}") from None


def _coerce_mapping(csv_mapping: CsvMapping | dict[str, Any] | str | Path | None) -> CsvMapping | None:
    if csv_mapping is None or isinstance(csv_mapping, CsvMapping):
        return csv_mapping
    if isinstance(csv_mapping, dict):
        return CsvMapping.from_dict(csv_mapping)
    return CsvMapping.from_file(csv_mapping)


def load_sequence(
    path: str | Path,
    *,
    fmt: SourceFormat | str | None = None,
    name: str | None = None,
    csv_mapping: CsvMapping | dict[str, Any] | str | Path | None = None,
    imu_topic: str | None = None,
    pose_topic: str | None = None,
    tf_parent: str | None = None,
    tf_child: str | None = None,
    extra_poses: Iterable[PoseInput | str | dict[str, Any]] = (),
    all_pose_topics: bool = False,
) -> Sequence:
    """Read any supported input as a :class:`Sequence`.

    Args:
        path: File or folder.
        fmt: Force a format; default :func:`detect_format` (a given ``csv_mapping`` implies CSV for files).
        name: Sequence name; default from the path.
        csv_mapping: Column mapping for generic CSV: a :class:`CsvMapping`, a dict, or a YAML file path.
        imu_topic: ROS bags: IMU topic (default: the only sensor_msgs/Imu topic).
        pose_topic: ROS bags: pose topic.
        tf_parent: ROS bags: parent frame of a /tf pose stream.
        tf_child: ROS bags: child frame of a /tf pose stream.
        extra_poses: More pose inputs to merge into the sequence (e.g. IMU from an ASL folder
            and ground-truth or VIO poses from a TUM file): :class:`PoseInput`, ``"PATH"``,
            ``"PATH:KIND"`` or a dict with ``path`` and optional ``fmt``, ``stream``, ``kind``.
        all_pose_topics: ROS bags: read every pose topic (or tf pair) instead of refusing the
            choice (for describing a bag, :func:`pipeline.io.rosbag.reader.read_bag`).

    Returns:
        The sequence, with the reader's findings and ``metadata["source_format"]``.

    Raises:
        InputFormatError: Missing or malformed input.
        UnsupportedInputError: Not a supported input; the message lists what is.
        ConfigError: An option that does not apply to this format, or a bad mapping.
    """
    seq = _load_one(Path(path), fmt=fmt, name=name, csv_mapping=csv_mapping, imu_topic=imu_topic,
                    pose_topic=pose_topic, tf_parent=tf_parent, tf_child=tf_child, all_pose_topics=all_pose_topics)
    extras = [PoseInput.coerce(p) for p in extra_poses]
    seq = add_pose_inputs(seq, extras) if extras else seq
    from_store = (parse_format(fmt) if fmt is not None else detect_format(Path(path))) is SourceFormat.STORE
    return seq if from_store else _with_calibration_finding(seq)


def _with_calibration_finding(seq: Sequence) -> Sequence:
    """Add CALIBRATION_DEFAULTED when IMU noise values are defaults nobody gave (bags, CSV, TUM...).

    Readers that know better (an ASL folder's sensor.yaml, a store that recorded its findings)
    have said so already; a store's calibration is what its writer had.
    """
    if seq.imu is None or any(f.code == CODE_CALIBRATION_DEFAULTED for f in seq.findings):
        return seq
    missing = seq.calibration.defaulted()
    if not missing:
        return seq
    finding = Finding(
        CODE_CALIBRATION_DEFAULTED, Severity.WARNING, "imu",
        f"no IMU noise values for {', '.join(missing)}: using the EuRoC (ADIS16448) datasheet defaults; "
        "give this IMU's values (a Kalibr-style sensor.yaml next to the data, or the recovery config's "
        "gyro_noise_density / gyro_random_walk / acc_noise_density / acc_random_walk)",
        {"missing_keys": missing},
    )
    return replace(seq, findings=[*seq.findings, finding])


def _load_one(
    path: Path,
    *,
    fmt: SourceFormat | str | None,
    name: str | None,
    csv_mapping: CsvMapping | dict[str, Any] | str | Path | None,
    imu_topic: str | None,
    pose_topic: str | None,
    tf_parent: str | None,
    tf_child: str | None,
    all_pose_topics: bool = False,
) -> Sequence:
    if not path.exists():
        raise InputFormatError("does not exist", path=path, hint="check the path")
    mapping = _coerce_mapping(csv_mapping)
    if fmt is None:
        fmt = SourceFormat.CSV if (mapping is not None and path.is_file()) else detect_format(path)
    else:
        fmt = parse_format(fmt)
    bag_opts = {"imu_topic": imu_topic, "pose_topic": pose_topic, "tf_parent": tf_parent, "tf_child": tf_child}
    if fmt is not SourceFormat.BAG:
        given = [k for k, v in bag_opts.items() if v is not None]
        if given:
            raise ConfigError(f"option {given[0]} applies to ROS bags only, but {path.name} is {fmt.value}",
                              field=given[0], hint="drop the option, or pass a bag")
    if mapping is not None and fmt is not SourceFormat.CSV:
        raise ConfigError(f"a CSV mapping applies to CSV input only, but {path.name} is {fmt.value}",
                          field="csv_mapping", hint="drop the mapping or force --format csv")
    log.debug("loading %s as %s", path, fmt.value)
    if fmt is SourceFormat.STORE:
        seq = read_store(path)
        if name:
            seq.name = name
        return seq
    if fmt is SourceFormat.ASL:
        return read_asl(path, name=name) if path.is_dir() else read_asl_csv(path, name=name)
    if fmt is SourceFormat.TUM:
        return read_tum(path, name=name)
    if fmt is SourceFormat.CSV:
        if mapping is None:
            raise UnsupportedInputError(
                "CSV file needs a column mapping (its header is not an ASL layout)", path=path,
                hint="pass --csv-mapping FILE.yaml naming time_column, gyro/acc and/or position/quat columns; "
                     + SUPPORTED_HINT,
            )
        return read_csv_generic(path, mapping, name=name)
    from pipeline.io.rosbag.reader import read_bag  # rosbags takes ~0.3 s to import: load it for bags only

    return read_bag(path, name=name, all_pose_topics=all_pose_topics, **bag_opts)


@dataclass(frozen=True)
class PoseInput:
    """A separate pose input merged into a sequence (see :func:`add_pose_inputs`).

    Attributes:
        path: File or folder with poses (TUM text, ASL pose CSV, ground-truth state CSV, bag, ...).
        fmt: Format; default auto-detected.
        stream: Name of the merged stream; default the file stem (or the input's own stream name).
        kind: Override of the source kind (e.g. ``ground_truth`` for a dataset's ground-truth
            poses given as TUM text, which the TUM reader would call VIO).
        pose_topic: For bags: the pose topic.
    """

    path: str
    fmt: SourceFormat | None = None
    stream: str | None = None
    kind: PoseSourceKind | None = None
    pose_topic: str | None = None

    @classmethod
    def coerce(cls, value: "PoseInput | str | Path | dict[str, Any]") -> "PoseInput":
        """From a :class:`PoseInput`, ``"PATH"``, ``"PATH:KIND"`` or a config mapping."""
        if isinstance(value, PoseInput):
            return value
        if isinstance(value, (str, Path)):
            text = str(value)
            head, sep, tail = text.rpartition(":")
            kinds = {k.value for k in PoseSourceKind}
            if sep and tail in kinds:
                return cls(path=head, kind=PoseSourceKind(tail))
            if sep and head and Path(head).exists() and not Path(text).exists():
                raise ConfigError(f"unknown pose kind {tail!r} in {text!r}", field="--add-poses",
                                  hint="write PATH:KIND with KIND one of " + ", ".join(sorted(kinds)))
            return cls(path=text)
        if isinstance(value, dict):
            unknown = set(value) - {"path", "fmt", "stream", "kind", "pose_topic"}
            if unknown or "path" not in value:
                raise ConfigError(
                    f"pose input {value!r}: " + (f"unknown keys {sorted(unknown)}" if unknown else "no 'path'"),
                    field="poses", hint="give path and optionally fmt, stream, kind, pose_topic")
            try:
                kind = None if value.get("kind") is None else PoseSourceKind(value["kind"])
            except ValueError as exc:
                raise ConfigError(f"unknown pose kind {value['kind']!r}", field="kind",
                                  hint="use one of " + ", ".join(k.value for k in PoseSourceKind)) from exc
            fmt = None if value.get("fmt") is None else parse_format(value["fmt"])
            return cls(path=str(value["path"]), fmt=fmt, stream=value.get("stream"), kind=kind,
                       pose_topic=value.get("pose_topic"))
        raise ConfigError(f"cannot read a pose input from {value!r}", field="poses")


def add_pose_inputs(sequence: Sequence, inputs: Iterable[PoseInput]) -> Sequence:
    """Merge the pose streams (or ground-truth poses) of other inputs into ``sequence``.

    Each input contributes its pose streams; an input with only a ground-truth state (e.g. an
    EuRoC ``state_groundtruth_estimate0/data.csv``) contributes it as ``sequence.ground_truth``
    when the sequence has none, else as a pose stream. Reader findings are kept, with the stream
    names prefixed.

    Raises:
        DataError: An input holds no poses, or a stream name would collide.
    """
    for item in inputs:
        other = _load_one(Path(item.path), fmt=item.fmt, name=None, csv_mapping=None, imu_topic=None,
                          pose_topic=item.pose_topic, tf_parent=None, tf_child=None)
        streams = dict(other.poses)
        if not streams and other.ground_truth is not None:
            if sequence.ground_truth is None and item.stream is None and item.kind is None:
                sequence.ground_truth = other.ground_truth
                sequence.findings.extend(other.findings)
                sequence.metadata.setdefault("extra_inputs", []).append(str(item.path))
                continue
            streams = {GROUND_TRUTH_STREAM: other.ground_truth.to_pose_series()}
        if not streams:
            raise DataError("holds no poses", path=item.path,
                            hint="give a pose input (TUM text, ASL pose CSV, ground-truth CSV, bag)")
        if item.stream is not None and len(streams) > 1:
            raise AmbiguousInputError(f"holds {len(streams)} pose streams ({', '.join(streams)})", path=item.path,
                                      hint="name one with pose_topic, or leave 'stream' unset")
        for name, poses in streams.items():
            new_name = item.stream or (Path(item.path).stem if name == GROUND_TRUTH_STREAM else name)
            if new_name in sequence.poses:
                raise DataError(f"pose stream '{new_name}' already exists in sequence '{sequence.name}'",
                                path=item.path, hint="give the extra input another stream name")
            if item.kind is not None:
                poses = replace(poses, source_kind=item.kind)
            sequence.poses[new_name] = poses
            sequence.metadata.setdefault(ADDED_POSE_STREAMS_KEY, []).append(new_name)
        sequence.findings.extend(other.findings)
        sequence.metadata.setdefault("extra_inputs", []).append(str(item.path))
    return sequence


def _ordered_streams(sequence: Sequence) -> list[str]:
    added = sequence.metadata.get(ADDED_POSE_STREAMS_KEY, [])

    def rank(item: tuple[int, str]) -> tuple[int, int, int]:
        i, stream = item
        if stream in added:  # the user added it for a reason: it comes before the input's own streams
            return (0, added.index(stream), i)
        if stream in PREFERRED_POSE_STREAMS:
            return (1, PREFERRED_POSE_STREAMS.index(stream), i)
        return (2 + _KIND_RANK[sequence.poses[stream].source_kind], 0, i)

    return [s for _, s in sorted(enumerate(sequence.poses), key=rank)]


def list_pose_streams(sequence: Sequence) -> list[str]:
    """Pose streams of ``sequence`` in default-priority order, ``"ground_truth"`` last if it has a state."""
    names = _ordered_streams(sequence)
    if sequence.ground_truth is not None and GROUND_TRUTH_STREAM not in sequence.poses:
        names.append(GROUND_TRUTH_STREAM)
    return names


def select_pose_stream(sequence: Sequence, stream: str | None = None) -> tuple[str, PoseSeries]:
    """The pose stream to use: ``stream`` if given, else the first by default priority.

    Priority: streams merged from other inputs (``--add-poses``, in the order given) > vicon0 >
    mocap0 > leica0 > other MOCAP > other POSITION_TRACKER > VIO > GROUND_TRUTH-kind streams >
    the ground-truth state as poses (``"ground_truth"``, via :meth:`StateSeries.to_pose_series`).

    Args:
        sequence: The sequence.
        stream: A stream name from :func:`list_pose_streams`, or ``None`` for the default.

    Returns:
        ``(name, poses)``.

    Raises:
        AmbiguousInputError: ``stream`` is not one of the sequence's streams (lists them and --poses NAME).
        DataError: The sequence has no pose stream and no ground truth.
    """
    available = list_pose_streams(sequence)
    if stream is not None:
        if stream in sequence.poses:
            return stream, sequence.poses[stream]
        if stream == GROUND_TRUTH_STREAM and sequence.ground_truth is not None:
            return stream, sequence.ground_truth.to_pose_series()
        raise AmbiguousInputError(
            f"sequence '{sequence.name}' has no pose stream '{stream}'",
            field="poses",
            hint=("choose one with --poses NAME: " + ", ".join(available)) if available
            else "this sequence has no pose stream or ground truth",
        )
    if not available:
        raise DataError(f"sequence '{sequence.name}' has no pose stream and no ground truth", field="poses",
                        hint="add a pose source (mocap, position tracker, VIO or ground truth) to the input")
    first = available[0]
    if first == GROUND_TRUTH_STREAM and first not in sequence.poses:
        return first, sequence.ground_truth.to_pose_series()  # type: ignore[union-attr]
    return first, sequence.poses[first]


__all__ = [
    "AccUnit",
    "AslTable",
    "CsvMapping",
    "GROUND_TRUTH_STREAM",
    "GyroUnit",
    "QuatOrder",
    "SourceFormat",
    "TimeUnit",
    "detect_format",
    "list_pose_streams",
    "load_sequence",
    "parse_format",
    "read_asl",
    "read_asl_csv",
    "read_asl_pose_csv",
    "read_csv_generic",
    "read_tum",
    "select_pose_stream",
    "write_tum",
]
