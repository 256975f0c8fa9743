"""Geometry core: rotations (:mod:`~pipeline.geometry.so3`), IMU integration
(:mod:`~pipeline.geometry.integration`) and pose-frame transforms (:mod:`~pipeline.geometry.pose_transform`)."""
