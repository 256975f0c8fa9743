"""Tests of pipeline.io.rosbag (reader and writer) on the real bags in shared/data/ros_bags and on synthetic round trips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from pipeline.errors import AmbiguousInputError, ConfigError, InputFormatError, UnsupportedInputError
from pipeline.io.rosbag.formats import PoseMsgType, Ros2Storage, RosVersion
from pipeline.io.rosbag.reader import read_bag
from pipeline.io.rosbag.writer import write_bag
from pipeline.types import ImuSeries, PoseSeries, PoseSourceKind, Sequence, Severity


@pytest.fixture(scope="module")
def bags(shared_data: Path) -> Path:
    return shared_data / "ros_bags"


def _header_and_recv_ns(path: Path, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Independent read: header stamps, receive times and [gyro, acc] by full deserialisation."""
    hdr, recv, vals = [], [], []
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
        for conn, t, raw in r.messages([c for c in r.connections if c.topic == topic]):
            m = r.deserialize(raw, conn.msgtype)
            hdr.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
            recv.append(t)
            w, a = m.angular_velocity, m.linear_acceleration
            vals.append((w.x, w.y, w.z, a.x, a.y, a.z))
    return np.array(hdr, np.int64), np.array(recv, np.int64), np.array(vals)


# ------------------------------------------------------------------------------------ real bags


def test_test1_bag_imu_and_odom(bags: Path) -> None:
    path = bags / "robot_localization_test" / "test1.bag"
    seq = read_bag(path)
    assert seq.name == "test1"
    assert len(seq.imu) == 11865
    assert list(seq.poses) == ["/husky_velocity_controller/odom"]
    odom = seq.poses["/husky_velocity_controller/odom"]
    assert len(odom) == 3952
    assert odom.source_kind == PoseSourceKind.VIO
    assert (odom.frame, odom.world_frame) == ("base_link", "odom")
    np.testing.assert_allclose(np.linalg.norm(odom.quat_wxyz, axis=1), 1.0, atol=1e-6)
    assert [f.code for f in seq.findings] == ["TOPICS_NOT_USED"]  # /fix, a GNSS fix

    # header stamps (not receive times), and the vectorised decoder matches full deserialisation
    hdr, recv, vals = _header_and_recv_ns(path, "/imu/data")
    assert seq.imu.t_ns[0] == hdr[0] == 1432235497988949113
    assert recv[0] == 1432235498025043042 != seq.imu.t_ns[0]
    np.testing.assert_array_equal(seq.imu.t_ns, hdr)
    np.testing.assert_array_equal(seq.imu.gyro_radps, vals[:, :3])
    np.testing.assert_array_equal(seq.imu.acc_mps2, vals[:, 3:])
    assert seq.imu.rate_hz == pytest.approx(30.0, rel=0.01)

    bag = seq.metadata["bag"]
    assert bag["format"] == "rosbag1"
    assert bag["message_count"] == 11865 + 3952 + 989
    assert bag["topics"]["/fix"] == {"type": "sensor_msgs/msg/NavSatFix", "count": 989}
    assert bag["imu_topic"] == "/imu/data"
    assert bag["duration_s"] == pytest.approx(395.3, abs=0.1)


def test_test2_bag_counts(bags: Path) -> None:
    seq = read_bag(bags / "robot_localization_test" / "test2.bag")
    assert len(seq.imu) == 3061
    odom = seq.poses["/jackal_velocity_controller/odom"]
    assert len(odom) == 3060 and odom.source_kind == PoseSourceKind.VIO
    assert seq.imu.t_ns[0] == 47_580_000_000  # sim time, exact ns


def test_evo_example_ambiguous_then_chosen(bags: Path) -> None:
    path = bags / "evo_test_data" / "ROS_example.bag"
    with pytest.raises(AmbiguousInputError) as exc:
        read_bag(path)
    msg = str(exc.value)
    for needle in ("ROS_example.bag", "groundtruth", "ORB-SLAM", "S-PTAM", "--pose-topic TOPIC"):
        assert needle in msg
    seq = read_bag(path, pose_topic="groundtruth")
    assert seq.imu is None
    gt = seq.poses["groundtruth"]
    assert len(gt) == 12765 and gt.source_kind == PoseSourceKind.MOCAP
    assert np.all(np.diff(gt.t_ns) > 0)
    # kind override
    assert read_bag(path, pose_topic="S-PTAM", pose_kind=PoseSourceKind.VIO).poses["S-PTAM"].source_kind == "vio"


def test_tf_example_bag_lz4(bags: Path) -> None:
    path = bags / "evo_test_data" / "tf_example.bag"
    seq = read_bag(path)  # /tf holds a single dynamic pair: chosen without options
    (stream,) = seq.poses
    assert stream == "/tf:odom->base_footprint"
    pose = seq.poses[stream]
    assert len(pose) == 517 and (pose.world_frame, pose.frame) == ("odom", "base_footprint")
    np.testing.assert_allclose(np.linalg.norm(pose.quat_wxyz, axis=1), 1.0, atol=1e-9)
    assert seq.metadata["bag"]["tf_pairs"]["base_footprint->base_link"]["topic"] == "/tf_static"

    # chain through the static link base_footprint->base_link equals the explicit composition
    chain = read_bag(path, tf_parent="odom", tf_child="base_link").poses["/tf:odom->base_link"]
    np.testing.assert_array_equal(chain.t_ns, pose.t_ns)
    with AnyReader([path]) as r:
        conn = next(c for c in r.connections if c.topic == "/tf_static")
        tr = r.deserialize(next(r.messages([conn]))[2], conn.msgtype).transforms[0]
    t_s = np.array([tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z])
    q = tr.transform.rotation
    r_s = Rotation.from_quat([q.x, q.y, q.z, q.w])
    r_d = Rotation.from_quat(pose.quat_wxyz, scalar_first=True)
    np.testing.assert_allclose(chain.p_m, pose.p_m + r_d.apply(t_s), atol=1e-12)
    np.testing.assert_allclose(
        np.abs(np.sum(chain.quat_wxyz * (r_d * r_s).as_quat(scalar_first=True), axis=1)), 1.0, atol=1e-12
    )

    with pytest.raises(AmbiguousInputError, match="both a parent and a child"):
        read_bag(path, tf_parent="odom")
    with pytest.raises(AmbiguousInputError, match="no tf chain from 'base_link' down to 'odom'"):
        read_bag(path, tf_parent="base_link", tf_child="odom")


def test_tf_example_ros2_folder_and_bare_db3(bags: Path) -> None:
    ros1 = read_bag(bags / "evo_test_data" / "tf_example.bag").poses["/tf:odom->base_footprint"]
    folder = read_bag(bags / "evo_test_data" / "tf_example")
    bare = read_bag(bags / "evo_test_data" / "tf_example" / "tf_example.db3")
    assert folder.metadata["bag"]["format"] == "rosbag2-sqlite3"
    for seq in (folder, bare):
        pose = seq.poses["/tf:odom->base_footprint"]
        assert len(pose) == 517
        np.testing.assert_array_equal(pose.t_ns, ros1.t_ns)
        np.testing.assert_array_equal(pose.p_m, ros1.p_m)
        np.testing.assert_array_equal(pose.quat_wxyz, ros1.quat_wxyz)


def test_nav2_mcap(bags: Path) -> None:
    path = bags / "evo_test_data" / "nav2_turtlebot.mcap"
    with pytest.raises(AmbiguousInputError) as exc:
        read_bag(path)
    assert "/odom" in str(exc.value) and "/amcl_pose" in str(exc.value)
    odom = read_bag(path, pose_topic="/odom")
    assert odom.metadata["bag"]["format"] == "rosbag2-mcap"
    assert len(odom.poses["/odom"]) == 2639 and odom.poses["/odom"].source_kind == PoseSourceKind.VIO
    amcl = read_bag(path, pose_topic="amcl_pose").poses["/amcl_pose"]  # leading '/' optional
    assert len(amcl) == 135 and amcl.world_frame == "map"
    np.testing.assert_allclose(np.linalg.norm(amcl.quat_wxyz, axis=1), 1.0, atol=1e-6)

    # /tf holds several pairs: listed, and one chosen pair is read
    with pytest.raises(AmbiguousInputError) as exc:
        read_bag(path, pose_topic="/tf")
    for needle in ("odom->base_link", "map->odom", "base_link->left_wheel", "--tf-parent P --tf-child C"):
        assert needle in str(exc.value)
    tf = read_bag(path, tf_parent="map", tf_child="odom").poses["/tf:map->odom"]
    assert len(tf) == 921
    with pytest.raises(UnsupportedInputError, match="2 time-varying"):
        read_bag(path, tf_parent="map", tf_child="base_link")


# ------------------------------------------------------------------------------------ synthetic


def _synthetic(n_imu: int = 50, n_pose: int = 12, t0_ns: int = 1_600_000_000_123_456_789) -> Sequence:
    rng = np.random.default_rng(0)
    t_imu = t0_ns + np.arange(n_imu, dtype=np.int64) * 5_000_001
    t_pose = t0_ns + 3 + np.arange(n_pose, dtype=np.int64) * 20_000_007
    quat = Rotation.random(n_pose, random_state=1).as_quat(scalar_first=True)
    imu = ImuSeries(t_imu, rng.normal(size=(n_imu, 3)), rng.normal(size=(n_imu, 3)) + [0, 0, 9.81])
    pose = PoseSeries(t_pose, rng.normal(size=(n_pose, 3)), quat, "body", PoseSourceKind.MOCAP, "map")
    return Sequence("synthetic", imu=imu, poses={"vicon0": pose})


@pytest.mark.parametrize(
    ("version", "storage", "suffix"),
    [(RosVersion.ROS1, Ros2Storage.SQLITE3, ".bag"), (RosVersion.ROS2, Ros2Storage.SQLITE3, ""),
     (RosVersion.ROS2, Ros2Storage.MCAP, "")],
)
@pytest.mark.parametrize("pose_msg", list(PoseMsgType))
def test_round_trip(tmp_path: Path, version: RosVersion, storage: Ros2Storage, suffix: str,
                    pose_msg: PoseMsgType) -> None:
    seq = _synthetic()
    out = write_bag(seq, tmp_path / f"out{suffix}", ros_version=version, storage=storage, pose_msg=pose_msg)
    if version == RosVersion.ROS2:
        ext = ".mcap" if storage == Ros2Storage.MCAP else ".db3"
        assert sorted(p.name for p in out.iterdir()) == sorted(["metadata.yaml", f"out{ext}"])
    assert [p.name for p in tmp_path.iterdir()] == [out.name]  # no temp leftovers
    back = read_bag(out, tf_parent="map", tf_child="body") if pose_msg == PoseMsgType.TF else read_bag(out)
    np.testing.assert_array_equal(back.imu.t_ns, seq.imu.t_ns)
    np.testing.assert_array_equal(back.imu.gyro_radps, seq.imu.gyro_radps)
    np.testing.assert_array_equal(back.imu.acc_mps2, seq.imu.acc_mps2)
    (stream,) = back.poses
    assert stream == ("/tf:map->body" if pose_msg == PoseMsgType.TF else "/pose")
    pose, orig = back.poses[stream], seq.poses["vicon0"]
    np.testing.assert_array_equal(pose.t_ns, orig.t_ns)
    np.testing.assert_array_equal(pose.p_m, orig.p_m)
    np.testing.assert_array_equal(pose.quat_wxyz, orig.quat_wxyz)
    assert pose.world_frame == "map"
    if pose_msg in (PoseMsgType.ODOMETRY, PoseMsgType.TRANSFORM_STAMPED, PoseMsgType.TF):
        assert pose.frame == "body"
    assert pose.source_kind == (PoseSourceKind.VIO if pose_msg == PoseMsgType.ODOMETRY else PoseSourceKind.MOCAP)
    assert back.findings == []


@pytest.mark.parametrize("frame", ["", "a", "imu", "imu_link", "imu_link_long_name"])
@pytest.mark.parametrize("version", list(RosVersion))
def test_imu_decoder_padding(tmp_path: Path, frame: str, version: RosVersion) -> None:
    """The vectorised IMU decoder handles every frame_id length (CDR alignment) exactly."""
    seq = Sequence("s", imu=_synthetic(n_imu=7).imu)
    out = write_bag(seq, tmp_path / ("b.bag" if version == RosVersion.ROS1 else "b"), ros_version=version,
                    imu_frame=frame)
    back = read_bag(out)
    hdr, _, vals = _header_and_recv_ns(out if version == RosVersion.ROS1 else out, "/imu0")
    np.testing.assert_array_equal(back.imu.t_ns, hdr)
    np.testing.assert_array_equal(back.imu.imu_6, vals)
    np.testing.assert_array_equal(back.imu.imu_6, seq.imu.imu_6)


def test_position_only_and_overwrite(tmp_path: Path) -> None:
    seq = _synthetic()
    p = seq.poses["vicon0"]
    seq.poses = {"leica": PoseSeries(p.t_ns, p.p_m, None, "prism", PoseSourceKind.POSITION_TRACKER)}
    out = tmp_path / "bag2"
    write_bag(_synthetic(n_imu=3), out, ros_version=RosVersion.ROS2)
    write_bag(seq, out, ros_version=RosVersion.ROS2, pose_topic="/leica")  # replaces the old bag
    back = read_bag(out, pose_kind=PoseSourceKind.POSITION_TRACKER)
    assert len(back.imu) == 50
    assert back.poses["/leica"].quat_wxyz is None
    np.testing.assert_array_equal(back.poses["/leica"].p_m, p.p_m)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["bag2"]


def test_zero_header_stamps_fall_back_to_receive_time(tmp_path: Path) -> None:
    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    path = tmp_path / "zero.bag"
    recv = 1_000_000_000 + np.arange(5, dtype=np.int64) * 10_000_000
    with Ros1Writer(path) as w:
        conn = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        for i, t in enumerate(recv):
            v = T["geometry_msgs/msg/Vector3"](x=float(i), y=0.0, z=9.8)
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                                frame_id="imu"),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9), angular_velocity=v, angular_velocity_covariance=np.zeros(9),
                linear_acceleration=v, linear_acceleration_covariance=np.zeros(9))
            w.write(conn, int(t), ts.serialize_ros1(msg, "sensor_msgs/msg/Imu"))
    seq = read_bag(path)
    np.testing.assert_array_equal(seq.imu.t_ns, recv)
    (finding,) = seq.findings
    assert finding.code == "BAG_HEADER_STAMP_ZERO" and finding.severity == Severity.WARNING
    assert finding.stream == "/imu" and "receive times" in finding.message


# ------------------------------------------------------------------------------------ bad input


def test_text_file_named_bag(tmp_path: Path) -> None:
    bad = tmp_path / "x.bag"
    bad.write_text("this is not a bag\n")
    with pytest.raises(InputFormatError) as exc:
        read_bag(bad)
    assert str(bad) in str(exc.value) and "ROS1 .bag" in str(exc.value)


def test_truncated_and_odd_paths(tmp_path: Path, bags: Path) -> None:
    raw = (bags / "evo_test_data" / "nav2_turtlebot.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(InputFormatError, match="cut.mcap"):
        read_bag(tmp_path / "cut.mcap")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFormatError, match="no metadata.yaml"):
        read_bag(tmp_path / "empty")
    with pytest.raises(InputFormatError, match="does not exist"):
        read_bag(tmp_path / "missing.bag")
    (tmp_path / "x.txt").write_text("x")
    with pytest.raises(UnsupportedInputError, match="extension"):
        read_bag(tmp_path / "x.txt")
    with pytest.raises(ConfigError, match=".bag"):
        write_bag(_synthetic(), tmp_path / "out.db3", ros_version=RosVersion.ROS1)


def test_missing_and_wrong_type_topics(bags: Path) -> None:
    path = bags / "robot_localization_test" / "test1.bag"
    with pytest.raises(AmbiguousInputError) as exc:
        read_bag(path, imu_topic="/imu/raw")
    for needle in ("test1.bag", "/imu/raw", "/imu/data", "/fix", "/husky_velocity_controller/odom"):
        assert needle in str(exc.value)
    with pytest.raises(UnsupportedInputError, match="not sensor_msgs/Imu"):
        read_bag(path, imu_topic="/fix")
    with pytest.raises(UnsupportedInputError, match="not a pose type"):
        read_bag(path, pose_topic="/fix")
    with pytest.raises(AmbiguousInputError, match="no tf2_msgs/TFMessage"):
        read_bag(path, tf_parent="odom", tf_child="base_link")
