"""Moving a pose stream into the IMU frame and onto the IMU clock.

A pose stream gives ``T_world_pose`` (the tracked frame: a mocap marker, a Leica prism, a
camera) on its own clock. The recovery estimates the extrinsic ``T_imu_pose`` (pose of the
tracked frame in the IMU frame) and the clock offset ``pose_time_offset_s`` (seconds to ADD
to pose stamps to put them on the IMU clock), both in ``recovery.json``. The same stream
seen as a trajectory of the IMU is then

    t_imu       = t_pose + time_offset_s
    T_world_imu = T_world_pose @ inv(T_imu_pose)
                  i.e. R_world_imu = R_world_pose R_imu_pose^T,
                       p_world_imu = p_world_pose - R_world_imu p_imu_pose

A position-only stream (no orientation) needs the IMU attitude from elsewhere (e.g. the
recovered trajectory) to remove the lever arm ``p_imu_pose``.

:func:`transform_from_json` reads ``T_imu_pose`` in the forms ``recovery.json`` uses.

This module needs only NumPy and SciPy (no torch), so the report can use it without the
validation's integration stack. Users: :func:`validation.reference.reference_from_poses`,
:func:`recovery.outputs.RecoveryOutputs.read`, :func:`reports.quality.pose_residuals` and
:func:`reports.quality.transform_from_report`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.errors import DataError
from pipeline.types import NS_PER_S, PoseSeries

__all__ = ["IMU_FRAME", "as_transform", "offset_ns", "poses_in_imu_frame", "transform_from_json"]

#: ``frame`` of the streams returned by :func:`poses_in_imu_frame`.
IMU_FRAME = "imu"


def offset_ns(time_offset_s: float) -> int:
    """A clock offset in seconds as whole nanoseconds (rounded to the nearest)."""
    return int(round(float(time_offset_s) * NS_PER_S))


def as_transform(T_imu_pose: Any) -> np.ndarray:
    """``T_imu_pose`` as a float64 4x4 matrix; None is the identity.

    Raises:
        DataError: Not a finite 4x4 matrix.
    """
    T = np.eye(4) if T_imu_pose is None else np.asarray(T_imu_pose, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(f"T_imu_pose must be a finite 4x4 matrix, got shape {T.shape}", field="T_imu_pose",
                        hint="give a 4x4 homogeneous matrix or {p_m, quat_wxyz}")
    return T


def transform_from_json(value: Any) -> np.ndarray:
    """4x4 ``T_imu_pose`` from its ``recovery.json`` forms.

    Accepted: None (identity), ``{"p_m": [3], "quat_wxyz": [4]}`` (either key may be left
    out), ``{"matrix": 4x4}``, or a 4x4 nested list.

    Raises:
        DataError: None of these forms, or not finite.
    """
    if isinstance(value, dict) and "matrix" in value:
        value = value["matrix"]
    if isinstance(value, dict):
        T = np.eye(4)
        try:
            if value.get("quat_wxyz") is not None:
                quat = np.asarray(value["quat_wxyz"], dtype=np.float64)
                T[:3, :3] = Rotation.from_quat(quat, scalar_first=True).as_matrix()
            T[:3, 3] = np.asarray(value.get("p_m", [0.0, 0.0, 0.0]), dtype=np.float64).reshape(3)
        except (ValueError, TypeError) as exc:
            raise DataError(f"T_imu_pose {{p_m, quat_wxyz}} is malformed ({exc})", field="T_imu_pose",
                            hint="give p_m as 3 numbers and quat_wxyz as 4 (w first)") from None
        value = T
    try:
        return as_transform(value)
    except (ValueError, TypeError) as exc:  # not numeric at all
        raise DataError(f"T_imu_pose is not a matrix ({exc})", field="T_imu_pose",
                        hint="give a 4x4 homogeneous matrix or {p_m, quat_wxyz}") from None


def poses_in_imu_frame(
    poses: PoseSeries,
    T_imu_pose: np.ndarray | None = None,
    time_offset_s: float = 0.0,
    *,
    imu_quat_wxyz: np.ndarray | None = None,
) -> PoseSeries:
    """The pose stream as poses of the IMU, on the IMU clock (see the module docstring).

    Sample by sample, no interpolation: row ``i`` of the result is row ``i`` of ``poses``
    moved by the extrinsic, stamped ``poses.t_ns[i] + round(time_offset_s * 1e9)``.

    Args:
        poses: ``T_world_<frame>`` samples on the pose clock, [N] rows; ``quat_wxyz`` may be None
            (position-only stream).
        T_imu_pose: 4x4 ``T_imu_<frame>``; None is the identity (the poses are of the IMU).
        time_offset_s: Seconds to ADD to pose stamps to put them on the IMU clock.
        imu_quat_wxyz: World-from-IMU attitude at the same N rows, [N, 4] (Hamilton, scalar
            first); used only for a position-only stream, to remove the lever arm.

    Returns:
        ``T_world_imu`` samples: ``t_ns`` on the IMU clock [N], ``p_m`` [N, 3], ``quat_wxyz``
        [N, 4] (None for a position-only stream), ``frame`` :data:`IMU_FRAME`, same
        ``source_kind`` and ``world_frame`` as ``poses``.

    Raises:
        DataError: ``T_imu_pose`` is not a finite 4x4 matrix, or a position-only stream with a
            non-zero lever arm and no ``imu_quat_wxyz`` (or one of the wrong shape).
    """
    T = as_transform(T_imu_pose)
    R_ip, p_ip = T[:3, :3], T[:3, 3]
    t_ns = poses.t_ns + offset_ns(time_offset_s)
    if poses.quat_wxyz is not None:
        R_wi = Rotation.from_quat(poses.quat_wxyz, scalar_first=True).as_matrix() @ R_ip.T
        quat_wi = Rotation.from_matrix(R_wi).as_quat(scalar_first=True)
    else:
        quat_wi = None
        if imu_quat_wxyz is None:
            if np.any(p_ip != 0.0):
                raise DataError(
                    f"pose stream '{poses.frame}' has no orientation and no IMU attitude was given: the lever arm "
                    "cannot be removed", field="imu_quat_wxyz",
                    hint="pass the IMU attitude at the pose stamps (e.g. the recovered trajectory's)")
            R_wi = np.broadcast_to(np.eye(3), (len(poses), 3, 3))
        else:
            q = np.asarray(imu_quat_wxyz, dtype=np.float64)
            if q.shape != (len(poses), 4):
                raise DataError(f"imu_quat_wxyz must be [{len(poses)}, 4], got shape {q.shape}",
                                field="imu_quat_wxyz", hint="give one IMU attitude per pose")
            R_wi = Rotation.from_quat(q, scalar_first=True).as_matrix()
    p_wi = poses.p_m - np.einsum("nij,j->ni", R_wi, p_ip)
    return PoseSeries(t_ns, p_wi, quat_wi, IMU_FRAME, poses.source_kind, poses.world_frame)
