"""Reading a ROS1 / ROS2 bag into a :class:`~pipeline.types.Sequence` (:func:`read_bag`).
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, TypesysError, get_typestore
from scipy.spatial.transform import Rotation

from pipeline.errors import AmbiguousInputError, InputFormatError, UnsupportedInputError
from pipeline.io.rosbag.formats import (
    BAG_HINT,
    BAG_READ_ERRORS,
    IMU_TYPE,
    ODOMETRY,
    POSE_COV_STAMPED,
    POSE_STAMPED,
    POSE_TYPES,
    TF_MESSAGE,
    TRANSFORM_STAMPED,
)
from pipeline.io.registry import SOURCE_FORMAT_KEY
from pipeline.io.rosbag import BAG_SUFFIXES, MCAP_SUFFIX, ROS1_SUFFIX, ROS2_SUFFIXES
from pipeline.types import NS_PER_S, Finding, ImuCalibration, ImuSeries, PoseSeries, PoseSourceKind, Sequence, Severity

logger = logging.getLogger(__package__)  # reader and writer log as one: 'pipeline.io.rosbag'


def _resolve_bag_path(path: Path) -> Path:
    """The path AnyReader should open (a folder without metadata.yaml -> its single storage file)."""
    if not path.exists():
        raise InputFormatError("bag does not exist", path=path, hint="check the path")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        files = sorted(p for p in path.iterdir() if p.suffix in ROS2_SUFFIXES and p.is_file())
        if len(files) == 1:
            return files[0]
        storage = "/".join(ROS2_SUFFIXES)
        raise InputFormatError(
            "folder is not a ROS2 bag: it has no metadata.yaml"
            + (f" and {len(files)} {storage} files" if files else f" and no {storage} file"),
            path=path,
            hint=f"give the bag folder that holds metadata.yaml, or one {storage} file",
        )
    if path.is_file() and path.suffix not in BAG_SUFFIXES:
        raise UnsupportedInputError(
            f"unknown bag file extension {path.suffix!r}", path=path,
            hint=f"ROS1 bags end in {ROS1_SUFFIX}; ROS2 storage files in {' or '.join(ROS2_SUFFIXES)}",
        )
    return path


def _stamp_ns(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    """Exact int64 ns from header ``sec`` / ``nanosec`` arrays."""
    return np.asarray(sec, dtype=np.int64) * NS_PER_S + np.asarray(nanosec, dtype=np.int64)


def _topic_list(topics: dict[str, tuple[str, int]]) -> str:
    return ", ".join(f"{name} ({typ.replace('/msg/', '/')}, {n} msgs)" for name, (typ, n) in sorted(topics.items()))


def _match_topic(requested: str, topics: dict[str, tuple[str, int]]) -> str | None:
    """The bag topic named ``requested``; a missing or extra leading '/' is tolerated."""
    if requested in topics:
        return requested
    alt = requested[1:] if requested.startswith("/") else "/" + requested
    return alt if alt in topics else None


@dataclass
class _Stamped:
    """Per-message arrays collected from one stream before building a series."""

    header_ns: np.ndarray  # [N] int64
    recv_ns: np.ndarray  # [N] int64
    values: np.ndarray  # [N, K] float64
    header_frame: str
    child_frame: str


def _choose_stamps(stream: str, s: _Stamped, findings: list[Finding]) -> np.ndarray:
    """Header stamps, or the receive times (with a finding) when every header stamp is zero."""
    if len(s.header_ns) and not np.any(s.header_ns):
        findings.append(Finding(
            "BAG_HEADER_STAMP_ZERO", Severity.WARNING, stream,
            f"every header stamp on {stream} is zero; using the bag receive times instead "
            "(they include transport latency)",
            {"messages": int(len(s.header_ns))},
        ))
        return s.recv_ns.copy()
    return s.header_ns


def _pose_fields(msgtype: str, msg: Any) -> tuple[Any, Any, Any, str]:
    """(header, position-like, quaternion-like, child frame) of one pose-type message."""
    if msgtype == ODOMETRY:
        return msg.header, msg.pose.pose.position, msg.pose.pose.orientation, msg.child_frame_id
    if msgtype == POSE_COV_STAMPED:
        return msg.header, msg.pose.pose.position, msg.pose.pose.orientation, ""
    if msgtype == POSE_STAMPED:
        return msg.header, msg.pose.position, msg.pose.orientation, ""
    if msgtype == TRANSFORM_STAMPED:
        return msg.header, msg.transform.translation, msg.transform.rotation, msg.child_frame_id
    raise AssertionError(msgtype)  # callers only pass POSE_TYPES


_IMU_FLOATS = 37  # orientation 4 + cov 9 + angular_velocity 3 + cov 9 + linear_acceleration 3 + cov 9
_IMU_STD_HASH = {
    False: get_typestore(Stores.ROS1_NOETIC).generate_msgdef(IMU_TYPE)[1],
    True: get_typestore(Stores.ROS2_HUMBLE).hash_rihs01(IMU_TYPE),
}


def _gather_u32(buf: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Little-endian uint32 at each byte offset of a uint8 buffer, [N] int64."""
    b = buf[offsets[:, None] + np.arange(4)].astype(np.int64)
    return b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16) | (b[:, 3] << 24)


def _decode_imu_raw(raws: list[bytes], is2: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """Vectorised decoding of standard sensor_msgs/Imu messages from their raw bytes.

    ROS1: ``seq, sec, nsec (u32), frame_id (u32 length + bytes)`` then 37 float64.
    ROS2 (little-endian CDR): 4-byte encapsulation header, ``sec (i32), nanosec (u32),
    frame_id (u32 length incl. NUL + bytes)``, padding to 8 (relative to the payload), then 37
    float64.

    Returns:
        ``(header_ns [N] int64, floats [N, 37])``, or ``None`` when any message does not have
        the expected layout (the caller then deserialises message by message).
    """
    if not raws:
        return np.empty(0, np.int64), np.empty((0, _IMU_FLOATS))
    lengths = np.fromiter((len(r) for r in raws), np.int64, len(raws))
    if lengths.min() < 16:
        return None
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    buf = np.frombuffer(b"".join(raws), np.uint8)
    if is2:
        if np.any(buf[starts[:, None] + np.arange(2)] != np.array([0, 1], np.uint8)):
            return None  # not little-endian CDR
        sec = _gather_u32(buf, starts + 4)
        sec = np.where(sec >= 2**31, sec - 2**32, sec)  # int32
        nsec = _gather_u32(buf, starts + 8)
        body = 16 + _gather_u32(buf, starts + 12) - 4
        data_off = 4 + ((body + 7) // 8) * 8
        ok = lengths >= data_off + 8 * _IMU_FLOATS
    else:
        sec = _gather_u32(buf, starts + 4)
        nsec = _gather_u32(buf, starts + 8)
        data_off = 16 + _gather_u32(buf, starts + 12)
        ok = lengths == data_off + 8 * _IMU_FLOATS
    if not np.all(ok):
        return None
    rows = buf[(starts + data_off)[:, None] + np.arange(8 * _IMU_FLOATS)]
    floats = np.ascontiguousarray(rows).view("<f8").reshape(len(raws), _IMU_FLOATS).astype(np.float64)
    return _stamp_ns(sec, nsec), floats


def _read_imu(reader: AnyReader, msgs: list) -> _Stamped:
    """IMU samples from ``(connection, receive ns, raw bytes)`` tuples of one topic."""
    recv, raws, types = [], [], set()
    for conn, t_recv, raw in msgs:
        recv.append(t_recv)
        raws.append(raw)
        types.add(conn.msgtype)
    frame = reader.deserialize(raws[0], IMU_TYPE).header.frame_id if raws else ""
    try:
        standard = (reader.typestore.hash_rihs01(IMU_TYPE) if reader.is2
                    else reader.typestore.generate_msgdef(IMU_TYPE)[1]) == _IMU_STD_HASH[reader.is2]
    except TypesysError:
        standard = False
    fast = _decode_imu_raw(raws, reader.is2) if standard and types == {IMU_TYPE} else None
    if fast is not None:
        header_ns, floats = fast
        vals = floats[:, [13, 14, 15, 25, 26, 27]]  # angular_velocity, linear_acceleration
    else:
        logger.debug("IMU messages are not in the standard layout; deserialising one by one")
        sec, nsec, rows = [], [], []
        for raw in raws:
            m = reader.deserialize(raw, IMU_TYPE)
            sec.append(m.header.stamp.sec)
            nsec.append(m.header.stamp.nanosec)
            w, a = m.angular_velocity, m.linear_acceleration
            rows.append((w.x, w.y, w.z, a.x, a.y, a.z))
        header_ns, vals = _stamp_ns(sec, nsec), np.asarray(rows, np.float64).reshape(-1, 6)
    return _Stamped(header_ns, np.asarray(recv, np.int64), vals, "", frame)


def _read_pose_topic(reader: AnyReader, msgs: list, msgtype: str) -> _Stamped:
    """Pose samples from ``(connection, receive ns, raw bytes)`` tuples of one topic."""
    sec, nsec, recv, vals = [], [], [], []
    header_frame = child_frame = ""
    for conn, t_recv, raw in msgs:
        m = reader.deserialize(raw, conn.msgtype)
        header, p, q, child = _pose_fields(msgtype, m)
        sec.append(header.stamp.sec)
        nsec.append(header.stamp.nanosec)
        recv.append(t_recv)
        vals.append((p.x, p.y, p.z, q.w, q.x, q.y, q.z))  # ROS xyzw -> wxyz
        header_frame = header_frame or header.frame_id
        child_frame = child_frame or child
    return _Stamped(_stamp_ns(sec, nsec), np.asarray(recv, np.int64),
                    np.asarray(vals, np.float64).reshape(-1, 7), header_frame, child_frame)


@dataclass
class _TfEdge:
    """All samples of one parent->child transform on the tf topics."""

    parent: str
    child: str
    static: bool
    topic: str
    sec: list
    nsec: list
    recv: list
    vals: list  # (x, y, z, qw, qx, qy, qz)


def _read_tf(reader: AnyReader, msgs: list) -> dict[tuple[str, str], _TfEdge]:
    """Every (parent, child) edge in ``(connection, receive ns, raw bytes)`` TFMessage tuples."""
    edges: dict[tuple[str, str], _TfEdge] = {}
    for conn, t_recv, raw in msgs:
        static = conn.topic.rstrip("/").endswith("tf_static")
        m = reader.deserialize(raw, conn.msgtype)
        for tr in m.transforms:
            parent = tr.header.frame_id.lstrip("/")
            child = tr.child_frame_id.lstrip("/")
            key = (parent, child)
            edge = edges.get(key)
            if edge is None or (edge.static and not static):
                edge = edges[key] = _TfEdge(parent, child, static, conn.topic, [], [], [], [])
            elif static and not edge.static:
                continue  # a dynamic edge wins over a static one of the same name
            t, r = tr.transform.translation, tr.transform.rotation
            edge.sec.append(tr.header.stamp.sec)
            edge.nsec.append(tr.header.stamp.nanosec)
            edge.recv.append(t_recv)
            edge.vals.append((t.x, t.y, t.z, r.w, r.x, r.y, r.z))
    return edges


def _pair_list(edges: dict[tuple[str, str], _TfEdge], *, dynamic_only: bool) -> str:
    rows = [e for e in edges.values() if not (dynamic_only and e.static)]
    return ", ".join(
        f"{e.parent}->{e.child} ({e.topic}, {len(e.sec)} msgs)" for e in sorted(rows, key=lambda e: (e.parent, e.child))
    )


def _edge_stamped(edge: _TfEdge) -> _Stamped:
    return _Stamped(_stamp_ns(edge.sec, edge.nsec), np.asarray(edge.recv, np.int64),
                    np.asarray(edge.vals, np.float64).reshape(-1, 7), edge.parent, edge.child)


def _tf_chain(
    path: Path, edges: dict[tuple[str, str], _TfEdge], parent: str, child: str
) -> tuple[_Stamped, str]:
    """T_parent_child over time, composing one dynamic edge with any static edges.

    Returns:
        The composed samples and the name of the dynamic edge's topic.
    """
    parent_of = {c: p for (p, c) in edges}
    chain: list[_TfEdge] = []
    node = child
    while node != parent:
        if node not in parent_of or len(chain) > len(edges):
            raise AmbiguousInputError(
                f"no tf chain from '{parent}' down to '{child}'",
                path=path, field="/tf",
                hint=f"choose frames with --tf-parent P --tf-child C where P is an ancestor of C; "
                     f"transforms in the bag: {_pair_list(edges, dynamic_only=False)}",
            )
        p = parent_of[node]
        chain.append(edges[(p, node)])
        node = p
    chain.reverse()  # parent ... child
    dynamic = [e for e in chain if not e.static]
    if len(dynamic) != 1:
        what = "only static transforms" if not dynamic else f"{len(dynamic)} time-varying transforms"
        raise UnsupportedInputError(
            f"the tf chain {parent}->{child} holds {what}; biasgt reads chains with exactly one "
            "time-varying (/tf) link",
            path=path, field="/tf",
            hint=f"choose one of the /tf pairs: {_pair_list(edges, dynamic_only=True)}",
        )
    dyn = _edge_stamped(dynamic[0])
    vals = dyn.values
    p_m = vals[:, :3]
    rot = Rotation.from_quat(vals[:, 3:7], scalar_first=True) if len(vals) else None
    if len(chain) > 1 and rot is not None:
        # compose T = T_1 ... T_dyn ... T_n with the latest sample of each static link
        def static_T(e: _TfEdge) -> tuple[np.ndarray, Rotation]:
            v = np.asarray(e.vals[-1], np.float64)
            return v[:3], Rotation.from_quat(v[3:7], scalar_first=True)

        i = chain.index(dynamic[0])
        for e in reversed(chain[:i]):  # left-multiply: T_e * T
            t_e, r_e = static_T(e)
            p_m = t_e + r_e.apply(p_m)
            rot = r_e * rot
        for e in chain[i + 1:]:  # right-multiply: T * T_e
            t_e, r_e = static_T(e)
            p_m = p_m + rot.apply(t_e)
            rot = rot * r_e
        vals = np.hstack([p_m, rot.as_quat(scalar_first=True)])
    out = _Stamped(dyn.header_ns, dyn.recv_ns, vals, parent, child)
    return out, dynamic[0].topic


def _pose_series(s: _Stamped, t_ns: np.ndarray, kind: PoseSourceKind, frame_default: str) -> PoseSeries:
    quat = s.values[:, 3:7]
    if len(quat) and not np.any(quat):  # all-zero quaternions: a position-only stream (see write_bag)
        quat = None
    return PoseSeries(
        t_ns=t_ns, p_m=s.values[:, :3], quat_wxyz=quat,
        frame=s.child_frame or frame_default, source_kind=kind,
        world_frame=s.header_frame or "world",
    )


def _choice_finding(what: str, option: str) -> Finding:
    return Finding("POSE_STREAM_CHOICE", Severity.INFO, "poses",
                   f"the bag has {what}: 'biasgt recover' and 'convert' need one, chosen with {option}",
                   {"option": option})


def read_bag(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    pose_topic: str | None = None,
    tf_parent: str | None = None,
    tf_child: str | None = None,
    pose_kind: PoseSourceKind | None = None,
    name: str | None = None,
    all_pose_topics: bool = False,
) -> Sequence:
    """Read IMU and pose streams from a ROS1 or ROS2 bag.

    Topic choice: with no option, the single ``sensor_msgs/Imu`` topic is the IMU (none ->
    ``imu=None``) and the single pose-type topic (PoseStamped, PoseWithCovarianceStamped,
    TransformStamped, Odometry) is the pose stream; when the bag has no pose-type topic, the
    single parent->child pair on ``/tf`` is used. Several candidates raise
    :class:`AmbiguousInputError`. ``pose_topic`` reads only that topic (a TFMessage topic such
    as ``/tf`` needs a unique pair or ``tf_parent``/``tf_child``). ``tf_parent``/``tf_child``
    read the chain ``T_parent_child`` from ``/tf`` (static links from ``/tf_static`` are
    composed in); combined with ``pose_topic`` both streams are read.

    Args:
        path: ``.bag`` file, ROS2 bag folder, or ``.db3`` / ``.mcap`` file.
        imu_topic: IMU topic to read.
        pose_topic: Pose topic to read.
        tf_parent: Parent frame of the tf chain to read (needs ``tf_child``).
        tf_child: Child frame of the tf chain to read (needs ``tf_parent``).
        pose_kind: Source kind of the pose stream(s); default VIO for Odometry, MOCAP otherwise.
        name: Sequence name; default the bag's file or folder name without extension.
        all_pose_topics: Instead of refusing a choice between several pose topics (or tf pairs),
            read them all and say in a POSE_STREAM_CHOICE finding that recovery needs one
            (``biasgt inspect`` describes a bag this way).

    Returns:
        The sequence: ``imu`` [N], ``poses`` keyed by topic (``"/tf:<parent>-><child>"`` for tf),
        ``findings`` and ``metadata["bag"]`` (format, topics with types and counts, duration).

    Raises:
        InputFormatError: Not a bag, or a damaged one.
        UnsupportedInputError: A chosen topic has a type biasgt cannot read.
        AmbiguousInputError: Several candidate topics or tf pairs, or a requested topic is absent.
    """
    path = Path(path)
    open_path = _resolve_bag_path(path)
    if (tf_parent is None) != (tf_child is None):
        raise AmbiguousInputError(
            "a tf chain needs both a parent and a child frame", path=path,
            hint="give both --tf-parent P and --tf-child C",
        )
    seq_name = name or (path.name if path.is_dir() else path.stem)
    try:
        with AnyReader([open_path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            return _read_open_bag(
                reader, path, open_path, seq_name, imu_topic, pose_topic, tf_parent, tf_child, pose_kind,
                all_pose_topics,
            )
    except BAG_READ_ERRORS as err:
        raise InputFormatError(f"cannot read bag: {err}", path=path, hint=BAG_HINT) from err
    except FileNotFoundError as err:
        raise InputFormatError(f"cannot read bag: {err}", path=path, hint=BAG_HINT) from err


class _PoseJobKind(enum.Enum):
    """Where a pose stream of a bag comes from."""

    TOPIC = "topic"  # a pose-typed topic
    TF = "tf"  # a parent -> child chain of /tf (+ /tf_static)


@dataclass(frozen=True)
class _PoseJob:
    """One pose stream to read: a topic, or a /tf chain (``topic``: its TFMessage topic, None = every
    dynamic one; ``parent`` / ``child``: None = the only dynamic pair)."""

    kind: _PoseJobKind
    topic: str | None
    parent: str | None = None
    child: str | None = None


def _is_static_tf(topic: str) -> bool:
    return topic.rstrip("/").endswith("tf_static")


def _find_topic(requested: str, option: str, topics: dict[str, tuple[str, int]], path: Path) -> str:
    """The bag's topic matching ``requested`` (see :func:`_match_topic`).

    Raises:
        AmbiguousInputError: No such topic (the bag's topics are listed).
    """
    got = _match_topic(requested, topics)
    if got is None:
        raise AmbiguousInputError(f"topic '{requested}' is not in the bag", path=path, field=requested,
                                  hint=f"choose one with {option} TOPIC from: {_topic_list(topics)}")
    return got


def _imu_topic(topics: dict[str, tuple[str, int]], imu_topic: str | None, path: Path) -> str | None:
    """The IMU topic: the requested one (it must be sensor_msgs/Imu), else the only Imu topic."""
    if imu_topic is not None:
        name = _find_topic(imu_topic, "--imu-topic", topics, path)
        if topics[name][0] != IMU_TYPE:
            raise UnsupportedInputError(
                f"topic '{name}' has type {topics[name][0]}, not sensor_msgs/Imu", path=path,
                field=name, hint=f"choose an Imu topic with --imu-topic TOPIC from: {_topic_list(topics)}",
            )
        return name
    cands = sorted(n for n, (t, _) in topics.items() if t == IMU_TYPE)
    if len(cands) > 1:
        raise AmbiguousInputError(f"the bag has {len(cands)} sensor_msgs/Imu topics: {', '.join(cands)}", path=path,
                                  hint="choose one with --imu-topic TOPIC")
    return cands[0] if cands else None


def _plan_pose_jobs(topics: dict[str, tuple[str, int]], pose_topic: str | None, tf_parent: str | None,
                    tf_child: str | None, path: Path, *, all_pose_topics: bool = False,
                    findings: list[Finding] | None = None) -> list[_PoseJob]:
    """The pose streams to read (metadata only): the requested topic and / or /tf chain, else the
    only pose topic (every one, with a POSE_STREAM_CHOICE finding, when ``all_pose_topics``), else
    the dynamic /tf pair."""
    tf_topics = sorted(n for n, (t, _) in topics.items() if t == TF_MESSAGE)

    def tf_job(topic: str | None) -> _PoseJob:
        if not tf_topics:
            raise AmbiguousInputError(
                "the bag has no tf2_msgs/TFMessage topic", path=path, field="/tf",
                hint=f"choose a pose topic with --pose-topic TOPIC from: {_topic_list(topics)}",
            )
        return _PoseJob(_PoseJobKind.TF, topic, tf_parent, tf_child)

    def topic_job(topic: str) -> _PoseJob:
        typ = topics[topic][0]
        if typ == TF_MESSAGE:
            return tf_job(topic)
        if typ in POSE_TYPES:
            return _PoseJob(_PoseJobKind.TOPIC, topic)
        raise UnsupportedInputError(
            f"topic '{topic}' has type {typ}, which is not a pose type", path=path, field=topic,
            hint="choose a PoseStamped, PoseWithCovarianceStamped, TransformStamped, Odometry or "
                 f"TFMessage topic with --pose-topic TOPIC from: {_topic_list(topics)}",
        )

    if pose_topic is not None:
        chosen = _find_topic(pose_topic, "--pose-topic", topics, path)
        jobs = [topic_job(chosen)]
        if tf_parent is not None and topics[chosen][0] != TF_MESSAGE:
            jobs.append(tf_job(None))
        return jobs
    if tf_parent is not None:
        return [tf_job(None)]
    cands = sorted(n for n, (t, _) in topics.items() if t in POSE_TYPES)
    if len(cands) > 1 and all_pose_topics:
        if findings is not None:
            findings.append(_choice_finding(f"{len(cands)} pose topics ({', '.join(cands)})", "--pose-topic TOPIC"))
        return [topic_job(c) for c in cands]
    if len(cands) > 1:
        raise AmbiguousInputError(
            f"the bag has {len(cands)} pose topics: "
            + ", ".join(f"{c} ({topics[c][0].replace('/msg/', '/')}, {topics[c][1]} msgs)" for c in cands),
            path=path,
            hint="choose one with --pose-topic TOPIC" + (" (or a /tf chain with --tf-parent P --tf-child C)"
                                                       if tf_topics else ""),
        )
    if cands:
        return [topic_job(cands[0])]
    if any(not _is_static_tf(t) for t in tf_topics):
        return [tf_job(None)]
    return []


def _tf_sources(topic: str | None, tf_topics: list[str]) -> list[str]:
    """Dynamic tf from the chosen (or every non-static) TFMessage topic, static links from */tf_static."""
    dyn = [topic] if topic else [t for t in tf_topics if not _is_static_tf(t)]
    return dyn + [t for t in tf_topics if _is_static_tf(t) and t not in dyn]


def _read_tf_job(reader: AnyReader, job: _PoseJob, messages: list, path: Path, findings: list[Finding],
                 pose_kind: PoseSourceKind | None, all_pairs: bool = False
                 ) -> tuple[dict[str, PoseSeries], dict[str, Any]]:
    """``({stream name: poses}, {"parent->child": {topic, count}})`` of a /tf chain job: its chain, or
    the only dynamic pair (every one, with a POSE_STREAM_CHOICE finding, when ``all_pairs``)."""
    edges = _read_tf(reader, sorted(messages, key=lambda m: m[1]))
    pairs = {f"{e.parent}->{e.child}": {"topic": e.topic, "count": len(e.sec)} for e in edges.values()}
    chains = [(job.parent, job.child)]
    if job.parent is None:
        chains = [k for k, e in edges.items() if not e.static]
        if len(chains) > 1 and all_pairs:
            findings.append(_choice_finding(f"{len(chains)} tf pairs ({_pair_list(edges, dynamic_only=True)})",
                                            "--tf-parent P --tf-child C"))
        elif len(chains) != 1:
            raise AmbiguousInputError(
                f"{job.topic or '/tf'} holds {len(chains)} parent->child pairs: "
                f"{_pair_list(edges, dynamic_only=True) or 'none'}",
                path=path, field=job.topic or "/tf", hint="choose one with --tf-parent P --tf-child C",
            )
    streams: dict[str, PoseSeries] = {}
    for parent, child in chains:
        assert parent is not None and child is not None
        parent, child = parent.lstrip("/"), child.lstrip("/")
        s, dyn_topic = _tf_chain(path, edges, parent, child)
        stream = f"{dyn_topic}:{parent}->{child}"
        t_ns = _choose_stamps(stream, s, findings)
        streams[stream] = _pose_series(s, t_ns, pose_kind or PoseSourceKind.MOCAP, child)
    return streams, pairs


def _unused_topics(topics: dict[str, tuple[str, int]], needed: set[str], tf_topics: list[str]) -> list[Finding]:
    """TOPICS_NOT_USED (info): the bag's topics that nothing reads (e.g. a GNSS fix), so that a user sees them."""
    unused = sorted(n for n in topics if n not in needed and n not in tf_topics)
    if not unused:
        return []
    listed = ", ".join(f"{n} ({topics[n][0]}, {topics[n][1]} msgs)" for n in unused)
    return [Finding(
        "TOPICS_NOT_USED", Severity.INFO, "bag",
        f"topics not used: {listed}; biasgt reads sensor_msgs/Imu and pose topics (PoseStamped, "
        "PoseWithCovarianceStamped, TransformStamped, Odometry, /tf); a GNSS fix (NavSatFix) has no orientation "
        "and no metric frame: convert it to poses first if it should be a pose stream",
        {"topics": unused},
    )]


def _read_open_bag(
    reader: AnyReader,
    path: Path,
    open_path: Path,
    seq_name: str,
    imu_topic: str | None,
    pose_topic: str | None,
    tf_parent: str | None,
    tf_child: str | None,
    pose_kind: PoseSourceKind | None,
    all_pose_topics: bool = False,
) -> Sequence:
    """Plan the topics to read (metadata only), read every needed topic in one pass, build the sequence."""
    topics = {n: (info.msgtype or "?", int(info.msgcount)) for n, info in reader.topics.items()}
    tf_topics = sorted(n for n, (t, _) in topics.items() if t == TF_MESSAGE)
    findings: list[Finding] = []
    imu_name = _imu_topic(topics, imu_topic, path)
    jobs = _plan_pose_jobs(topics, pose_topic, tf_parent, tf_child, path, all_pose_topics=all_pose_topics,
                           findings=findings)

    needed = {imu_name} if imu_name else set()
    for job in jobs:
        needed.update(_tf_sources(job.topic, tf_topics) if job.kind is _PoseJobKind.TF else [job.topic])
    findings += _unused_topics(topics, needed, tf_topics)
    by_topic: dict[str, list] = {t: [] for t in needed}
    if needed:
        for item in reader.messages([c for c in reader.connections if c.topic in needed]):
            by_topic[item[0].topic].append(item)

    imu = None
    if imu_name is not None:
        s = _read_imu(reader, by_topic[imu_name])
        t_ns = _choose_stamps(imu_name, s, findings)
        imu = ImuSeries(t_ns, s.values[:, :3], s.values[:, 3:6])
    poses: dict[str, PoseSeries] = {}
    read_tf_pairs: dict[str, Any] = {}
    for job in jobs:
        if job.kind is _PoseJobKind.TOPIC:
            typ = topics[job.topic][0]
            s = _read_pose_topic(reader, by_topic[job.topic], typ)
            t_ns = _choose_stamps(job.topic, s, findings)
            src = pose_kind or (PoseSourceKind.VIO if typ == ODOMETRY else PoseSourceKind.MOCAP)
            poses[job.topic] = _pose_series(s, t_ns, src, "pose")
        else:
            messages = [m for t in _tf_sources(job.topic, tf_topics) for m in by_topic[t]]
            streams, pairs = _read_tf_job(reader, job, messages, path, findings, pose_kind, all_pose_topics)
            read_tf_pairs.update(pairs)
            poses.update(streams)

    calibration = ImuCalibration()
    if imu is not None and np.isfinite(imu.rate_hz):
        calibration = ImuCalibration(rate_hz=imu.rate_hz)
    logger.info("read %s: imu=%s (%d msgs), poses=%s", path, imu_name, 0 if imu is None else len(imu),
                {k: len(v) for k, v in poses.items()})
    bag_meta = _bag_metadata(reader, path, open_path, topics, imu_name, poses, read_tf_pairs)
    return Sequence(
        name=seq_name, imu=imu, poses=poses, calibration=calibration, findings=findings,
        metadata={"source_path": str(path), SOURCE_FORMAT_KEY: "rosbag", "bag": bag_meta},
    )


def storage_format(metadata: Mapping[str, Any]) -> str | None:
    """The bag storage :func:`read_bag` recorded in ``metadata`` (``"rosbag1"``, ``"rosbag2-mcap"``, ...), if any."""
    bag = metadata.get("bag")
    return bag["format"] if isinstance(bag, dict) and isinstance(bag.get("format"), str) else None


def _bag_metadata(reader: AnyReader, path: Path, open_path: Path, topics: dict[str, tuple[str, int]],
                  imu_name: str | None, poses: dict[str, PoseSeries], tf_pairs: dict[str, Any]) -> dict[str, Any]:
    """What ``biasgt inspect`` shows of a bag: storage, span, topics, what was read."""
    start, end = int(reader.start_time), int(reader.end_time)
    storage = "rosbag1" if not reader.is2 else (
        "rosbag2-mcap" if (open_path.suffix == MCAP_SUFFIX or any(open_path.glob(f"*{MCAP_SUFFIX}"))) else "rosbag2-sqlite3")
    meta = {
        "path": str(path),
        "format": storage,
        "message_count": int(reader.message_count),
        "start_time_ns": start,
        "end_time_ns": end,
        "duration_s": (end - start) / NS_PER_S if reader.message_count else 0.0,
        "topics": {n: {"type": t, "count": c} for n, (t, c) in sorted(topics.items())},
        "imu_topic": imu_name,
        "pose_streams": sorted(poses),
    }
    if tf_pairs:
        meta["tf_pairs"] = tf_pairs
    return meta
