"""ROS1 / ROS2 bag reading and writing (via the ``rosbags`` library).

Reading (:func:`~pipeline.io.rosbag.reader.read_bag`) turns a bag into a :class:`~pipeline.types.Sequence`:

* ``sensor_msgs/Imu`` -> :class:`~pipeline.types.ImuSeries` (angular_velocity, linear_acceleration);
* ``geometry_msgs/PoseStamped``, ``PoseWithCovarianceStamped``, ``TransformStamped``,
  ``nav_msgs/Odometry`` and ``tf2_msgs/TFMessage`` (``/tf``, with ``/tf_static`` for static
  links of a chain) -> :class:`~pipeline.types.PoseSeries`.

Stamps are the message *header* stamps (``sec * 1e9 + nanosec``, exact int64 ns), never the
bag receive times; only when every header stamp of a stream is zero does the reader fall back
to receive times and say so in a ``BAG_HEADER_STAMP_ZERO`` finding.

Accepted inputs: a ROS1 ``.bag`` (uncompressed, bz2 or lz4 chunks), a ROS2 bag folder with
``metadata.yaml`` (sqlite3 or MCAP storage), a bare ``.db3`` / ``.mcap`` file, or a folder
without ``metadata.yaml`` that holds exactly one ``.db3`` / ``.mcap`` file.

Writing (:func:`~pipeline.io.rosbag.writer.write_bag`) exports ``Sequence.imu`` and one pose stream to ROS1 ``.bag`` or a
ROS2 bag folder (sqlite3 by default, MCAP on request; ``rosbags`` 0.11 writes both).

Modules: :mod:`~pipeline.io.rosbag.formats` (message types, bag formats), :mod:`~pipeline.io.rosbag.reader`
and :mod:`~pipeline.io.rosbag.writer`.
"""

from __future__ import annotations

from pathlib import Path

#: File suffix of a ROS 1 bag.
ROS1_SUFFIX = ".bag"
#: File suffix of a ROS 2 bag's MCAP storage file.
MCAP_SUFFIX = ".mcap"
#: File suffixes of a ROS 2 bag's storage files (MCAP, sqlite3).
ROS2_SUFFIXES = (MCAP_SUFFIX, ".db3")
#: File suffixes of a bag (ROS 1 ``.bag``; ROS 2 storage files).
BAG_SUFFIXES = (ROS1_SUFFIX, *ROS2_SUFFIXES)


def detect_bag(path: str | Path) -> bool:
    """Whether ``path`` is a bag: a :data:`BAG_SUFFIXES` file or a folder with ``metadata.yaml``.

    Light on purpose (no ``rosbags`` import, ~0.3 s): it runs for every input that is detected.
    """
    path = Path(path)
    return (path / "metadata.yaml").is_file() if path.is_dir() else path.suffix.lower() in BAG_SUFFIXES
