"""Input readers and the dispatcher that picks one.

Supported inputs: the readers registered in :mod:`pipeline.io.registry` (each with its name,
aliases, detection and loader; ``biasgt inspect --help`` lists them under ``--format``).
:func:`load_sequence` reads any of them, :func:`detect_format` names the one that recognises a path.

Pose-stream selection (:func:`select_pose_stream`), default priority:
``vicon0`` > ``mocap0`` > ``leica0`` > other MOCAP streams > other POSITION_TRACKER streams >
VIO streams > GROUND_TRUTH-kind pose streams > the ground-truth state as poses (``"ground_truth"``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pipeline.errors import AmbiguousInputError, ConfigError, DataError, InputFormatError
from pipeline.io._stamps import TimeUnit
from pipeline.io.asl import (
    CODE_CALIBRATION_DEFAULTED,
    AslTable,
    read_asl,
    read_asl_csv,
    read_asl_pose_csv,
)
from pipeline.io.csv_generic import AccUnit, CsvMapping, GyroUnit, QuatOrder, read_csv_generic
from pipeline.io.registry import (
    SOURCE_FORMAT_KEY,
    Reader,
    detect_format,
    parse_format,
    recorded_format,
    register,
    select_reader,
    supported_hint,
    unregister,
)
from pipeline.io.tum import read_tum, write_tum
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


def load_sequence(
    path: str | Path,
    *,
    fmt: str | None = None,
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
        fmt: Force a format (a reader's name or alias, :func:`parse_format`); default
            :func:`detect_format` (a given ``csv_mapping`` implies CSV for files).
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
            choice (for describing a bag, :func:`pipeline.io.rosbag.reader.read_bag`); ignored
            by readers that do not take it.

    Returns:
        The sequence, with the reader's findings and ``metadata[SOURCE_FORMAT_KEY]`` (what the
        reader recorded, else its name).

    Raises:
        InputFormatError: Missing or malformed input.
        UnsupportedInputError: Not a supported input; the message lists what is.
        ConfigError: An option that does not apply to this format, or a bad mapping.
    """
    options = {"csv_mapping": csv_mapping, "imu_topic": imu_topic, "pose_topic": pose_topic,
               "tf_parent": tf_parent, "tf_child": tf_child}
    seq, reader = _load_one(Path(path), fmt=fmt, name=name, options=options, all_pose_topics=all_pose_topics)
    extras = [PoseInput.coerce(p) for p in extra_poses]
    seq = add_pose_inputs(seq, extras) if extras else seq
    return seq if reader.is_store else _with_calibration_finding(seq)


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


def _load_one(path: Path, *, fmt: str | None, name: str | None, options: dict[str, Any],
              all_pose_topics: bool = False) -> tuple[Sequence, Reader]:
    """Read ``path`` with the reader :func:`~pipeline.io.registry.select_reader` picks, passing it
    the given ``options`` (checked: each applies to this reader) and ``all_pose_topics`` where it
    takes it; the reader's name is recorded as ``metadata[SOURCE_FORMAT_KEY]`` unless it recorded one."""
    if not path.exists():
        raise InputFormatError("does not exist", path=path, hint="check the path")
    reader = select_reader(path, fmt, options)
    kwargs = {k: v for k, v in options.items() if v is not None}
    if "all_pose_topics" in reader.options:
        kwargs["all_pose_topics"] = all_pose_topics
    log.debug("loading %s as %s", path, reader.name)
    seq = reader.loader()(path, name=name, **kwargs)
    if not reader.is_store and recorded_format(seq.metadata) is None:  # a store keeps what its reader recorded
        seq.metadata[SOURCE_FORMAT_KEY] = reader.name
    return seq, reader


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
    fmt: str | None = None
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
        other, _ = _load_one(Path(item.path), fmt=item.fmt, name=None, options={"pose_topic": item.pose_topic})
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
    "Reader",
    "SOURCE_FORMAT_KEY",
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
    "recorded_format",
    "register",
    "select_pose_stream",
    "supported_hint",
    "unregister",
    "write_tum",
]
