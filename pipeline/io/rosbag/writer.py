"""Writing ``Sequence.imu`` and one pose stream to a ROS1 ``.bag`` or a ROS2 bag folder (:func:`write_bag`).
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.files.atomic import atomic_dir, atomic_path
from pipeline.errors import ConfigError, DataError
from pipeline.io.rosbag.formats import (
    IMU_TYPE,
    ODOMETRY,
    POSE_COV_STAMPED,
    POSE_STAMPED,
    TF_MESSAGE,
    TRANSFORM_STAMPED,
    PoseMsgType,
    Ros2Storage,
    RosVersion,
)
from pipeline.io.rosbag import ROS1_SUFFIX
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, Sequence

logger = logging.getLogger(__package__)  # reader and writer log as one: 'pipeline.io.rosbag'


class _MsgFactory:
    """Builds ROS messages of one typestore (ROS1 Noetic or ROS2 Humble)."""

    def __init__(self, ros_version: RosVersion) -> None:
        self.ros1 = ros_version == RosVersion.ROS1
        self.ts = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if TF_MESSAGE not in self.ts.types:  # tf2_msgs is not part of the stock typestores
            self.ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))
        self.T = self.ts.types
        self.seq: dict[str, int] = {}

    def serialize(self, msg: Any, msgtype: str) -> bytes:
        if self.ros1:
            return bytes(self.ts.serialize_ros1(msg, msgtype))
        return bytes(self.ts.serialize_cdr(msg, msgtype))

    def header(self, t_ns: int, frame_id: str, counter: str) -> Any:
        stamp = self.T["builtin_interfaces/msg/Time"](sec=int(t_ns // NS_PER_S), nanosec=int(t_ns % NS_PER_S))
        if self.ros1:
            n = self.seq.get(counter, 0)
            self.seq[counter] = n + 1
            return self.T["std_msgs/msg/Header"](seq=n, stamp=stamp, frame_id=frame_id)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def vec3(self, v: np.ndarray) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def point(self, v: np.ndarray) -> Any:
        return self.T["geometry_msgs/msg/Point"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q_wxyz: np.ndarray | None) -> Any:
        if q_wxyz is None:  # position-only stream: an all-zero quaternion marks "no orientation"
            return self.T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=0.0)
        return self.T["geometry_msgs/msg/Quaternion"](
            x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]), w=float(q_wxyz[0]))

    def imu(self, t_ns: int, gyro: np.ndarray, acc: np.ndarray, frame_id: str) -> Any:
        cov_unknown_orientation = np.zeros(9)
        cov_unknown_orientation[0] = -1.0  # REP 145: orientation not provided
        return self.T[IMU_TYPE](
            header=self.header(t_ns, frame_id, "imu"),
            orientation=self.T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=cov_unknown_orientation,
            angular_velocity=self.vec3(gyro), angular_velocity_covariance=np.zeros(9),
            linear_acceleration=self.vec3(acc), linear_acceleration_covariance=np.zeros(9),
        )

    def pose_msg(self, kind: PoseMsgType, t_ns: int, p: np.ndarray, q: np.ndarray | None,
                 world: str, child: str) -> tuple[Any, str]:
        header = self.header(t_ns, world, "pose")
        pose = self.T["geometry_msgs/msg/Pose"](position=self.point(p), orientation=self.quat(q))
        if kind == PoseMsgType.POSE_STAMPED:
            return self.T[POSE_STAMPED](header=header, pose=pose), POSE_STAMPED
        if kind == PoseMsgType.POSE_WITH_COVARIANCE_STAMPED:
            pwc = self.T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
            return self.T[POSE_COV_STAMPED](header=header, pose=pwc), POSE_COV_STAMPED
        if kind == PoseMsgType.ODOMETRY:
            pwc = self.T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
            twist = self.T["geometry_msgs/msg/TwistWithCovariance"](
                twist=self.T["geometry_msgs/msg/Twist"](linear=self.vec3(np.zeros(3)), angular=self.vec3(np.zeros(3))),
                covariance=np.zeros(36))
            return self.T[ODOMETRY](header=header, child_frame_id=child, pose=pwc, twist=twist), ODOMETRY
        tr = self.T["geometry_msgs/msg/TransformStamped"](
            header=header, child_frame_id=child,
            transform=self.T["geometry_msgs/msg/Transform"](translation=self.vec3(p), rotation=self.quat(q)))
        if kind == PoseMsgType.TRANSFORM_STAMPED:
            return tr, TRANSFORM_STAMPED
        return self.T[TF_MESSAGE](transforms=[tr]), TF_MESSAGE


def _check_stamps(name: str, t_ns: np.ndarray) -> None:
    if len(t_ns) and int(t_ns.min()) < 0:
        raise DataError(f"{name} has negative stamps (min {int(t_ns.min())} ns); ROS times are unsigned",
                        field=name, hint="shift the sequence to non-negative times before writing a bag")


def write_bag(
    sequence: Sequence,
    path: str | Path,
    *,
    ros_version: RosVersion,
    imu_topic: str = "/imu0",
    pose_topic: str | None = None,
    pose_stream: str | None = None,
    pose_msg: PoseMsgType = PoseMsgType.POSE_STAMPED,
    storage: Ros2Storage = Ros2Storage.SQLITE3,
    imu_frame: str = "imu",
) -> Path:
    """Write ``sequence.imu`` and one pose stream to a ROS1 or ROS2 bag, atomically.

    Header stamps and bag receive times are both the sequence's ``t_ns`` (exact ns). A
    position-only stream (``quat_wxyz is None``) is written with all-zero quaternions, which
    :func:`~pipeline.io.rosbag.reader.read_bag` reads back as ``quat_wxyz=None``. IMU orientation is marked unknown
    (``orientation_covariance[0] = -1``).

    Args:
        sequence: What to write; ``imu`` and/or ``poses``.
        path: ``.bag`` file for ROS1; a folder for ROS2 (holding ``<name>.db3`` or ``<name>.mcap``
            and ``metadata.yaml``). An existing output is replaced only on success.
        ros_version: ROS1 or ROS2.
        imu_topic: Topic of the ``sensor_msgs/Imu`` messages.
        pose_topic: Topic of the pose messages; default ``"/tf"`` for ``PoseMsgType.TF``, else ``"/pose"``.
        pose_stream: Name of the stream in ``sequence.poses`` to write; default the first one.
        pose_msg: Message type of the poses.
        storage: ROS2 storage plugin (sqlite3 or MCAP); ignored for ROS1.
        imu_frame: ``header.frame_id`` of the IMU messages.

    Returns:
        The written path.

    Raises:
        ConfigError: Bad output path or unknown pose stream.
        DataError: Nothing to write, or negative stamps.
    """
    path = Path(path)
    ros_version = RosVersion(ros_version)
    pose_msg = PoseMsgType(pose_msg)
    if ros_version == RosVersion.ROS1 and path.suffix != ROS1_SUFFIX:
        raise ConfigError("a ROS1 bag must be a .bag file", path=path, hint="give an output path ending in .bag")
    if pose_topic is None:
        pose_topic = "/tf" if pose_msg == PoseMsgType.TF else "/pose"
    imu, poses = _streams_to_write(sequence, pose_stream, path)

    # merge both streams in time order (stable: IMU before pose at equal stamps)
    t_imu = imu.t_ns if imu is not None else np.empty(0, np.int64)
    t_pose = poses.t_ns if poses is not None else np.empty(0, np.int64)
    t_all, which, index, order = _merged_order(t_imu, t_pose)

    fac = _MsgFactory(ros_version)

    def write_all(writer: Any) -> None:
        kw: dict[str, Any] = {"typestore": fac.ts}
        conn_imu = writer.add_connection(imu_topic, IMU_TYPE, **kw) if imu is not None else None
        conn_pose = None
        if poses is not None:
            _, pose_type = fac.pose_msg(pose_msg, 0, np.zeros(3), None, "w", "c")
            conn_pose = writer.add_connection(pose_topic, pose_type, **kw)
            fac.seq.pop("pose", None)
        for k in order:
            i = int(index[k])
            t = int(t_all[k])
            if which[k] == 0:
                assert imu is not None
                msg = fac.imu(t, imu.gyro_radps[i], imu.acc_mps2[i], imu_frame)
                writer.write(conn_imu, t, fac.serialize(msg, IMU_TYPE))
            else:
                assert poses is not None
                q = None if poses.quat_wxyz is None else poses.quat_wxyz[i]
                msg, typ = fac.pose_msg(pose_msg, t, poses.p_m[i], q, poses.world_frame, poses.frame)
                writer.write(conn_pose, t, fac.serialize(msg, typ))

    _write_bag_file(path, ros_version, storage, write_all)
    logger.info("wrote %s bag %s: imu=%d, poses=%d", ros_version.value, path,
                len(t_imu), len(t_pose))
    return path


def _merged_order(t_imu: np.ndarray, t_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(t_all, which, index, order)``: both streams' stamps, the stream of each (0 IMU, 1 pose), its
    row in that stream, and the stable time order of them all."""
    t_all = np.concatenate([t_imu, t_pose])
    which = np.concatenate([np.zeros(len(t_imu), np.int8), np.ones(len(t_pose), np.int8)])
    index = np.concatenate([np.arange(len(t_imu)), np.arange(len(t_pose))])
    order = np.argsort(t_all, kind="stable")
    return t_all, which, index, order


def _streams_to_write(sequence: Sequence, pose_stream: str | None, path: Path
                      ) -> tuple[ImuSeries | None, PoseSeries | None]:
    """``(imu, poses)`` of ``sequence`` to write: the named pose stream (default the first one),
    stamps checked.

    Raises:
        ConfigError: Unknown pose stream.
        DataError: Nothing to write, or negative stamps.
    """
    poses: PoseSeries | None = None
    if pose_stream is not None:
        if pose_stream not in sequence.poses:
            raise ConfigError(f"sequence has no pose stream '{pose_stream}'", field=pose_stream,
                              hint=f"choose one of: {', '.join(sequence.poses) or 'none'}")
        poses = sequence.poses[pose_stream]
    elif sequence.poses:
        poses = next(iter(sequence.poses.values()))
    imu = sequence.imu
    if imu is None and poses is None:
        raise DataError(f"sequence '{sequence.name}' has neither IMU nor poses; nothing to write", path=path)
    if imu is not None:
        _check_stamps("imu.t_ns", imu.t_ns)
    if poses is not None:
        _check_stamps("poses.t_ns", poses.t_ns)
    return imu, poses


def _write_bag_file(path: Path, ros_version: RosVersion, storage: Ros2Storage,
                    write_all: Callable[[Any], None]) -> None:
    """Open a ROS1 or ROS2 bag writer on a temporary path, let ``write_all`` fill it, and move it
    to ``path`` atomically."""
    if ros_version == RosVersion.ROS1:
        with atomic_path(path) as tmp:
            tmp.unlink()  # rosbags refuses to overwrite; the name stays reserved by us
            with Ros1Writer(tmp) as writer:
                write_all(writer)
    else:
        plugin = StoragePlugin.MCAP if Ros2Storage(storage) == Ros2Storage.MCAP else StoragePlugin.SQLITE3
        # rosbags names the storage file after the folder, so write into a work folder whose
        # bag folder already has the final name, then move the files into the atomic folder.
        path.parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".work", dir=path.parent))
        try:
            bag_dir = work / path.name
            with Ros2Writer(bag_dir, version=9, storage_plugin=plugin) as writer:
                write_all(writer)
            with atomic_dir(path) as tmp:
                for f in bag_dir.iterdir():
                    os.replace(f, tmp / f.name)
        finally:
            shutil.rmtree(work, ignore_errors=True)
