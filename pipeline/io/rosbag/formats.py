"""The message types biasgt reads and writes, the bag formats it writes, and the errors a
broken bag raises while reading.
"""

from __future__ import annotations

import enum

from rosbags.highlevel import AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import TypesysError

IMU_TYPE = "sensor_msgs/msg/Imu"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
POSE_TYPES = (POSE_STAMPED, POSE_COV_STAMPED, TRANSFORM_STAMPED, ODOMETRY)

BAG_READ_ERRORS = (AnyReaderError, Ros1ReaderError, Ros2ReaderError, TypesysError)
BAG_HINT = (
    "give a ROS1 .bag file, a ROS2 bag folder with metadata.yaml, or a ROS2 .db3/.mcap file, "
    "and check that the file is complete (not truncated)"
)


class RosVersion(str, enum.Enum):
    """Which bag format :func:`write_bag` writes."""

    ROS1 = "ros1"  # a single .bag file (rosbag v2.0 format)
    ROS2 = "ros2"  # a rosbag2 folder (metadata.yaml + storage file)


class Ros2Storage(str, enum.Enum):
    """Storage plugin of a ROS2 bag written by :func:`write_bag`."""

    SQLITE3 = "sqlite3"  # <folder>/<folder>.db3
    MCAP = "mcap"  # <folder>/<folder>.mcap


class PoseMsgType(str, enum.Enum):
    """Message type :func:`write_bag` uses for the pose stream."""

    POSE_STAMPED = "geometry_msgs/PoseStamped"
    POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/PoseWithCovarianceStamped"
    TRANSFORM_STAMPED = "geometry_msgs/TransformStamped"
    ODOMETRY = "nav_msgs/Odometry"
    TF = "tf2_msgs/TFMessage"  # one TransformStamped per TFMessage, on /tf by default
