"""Synthetic sequences for check tests: smooth motion, consistent IMU and poses (rad/s, m/s^2)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.types import NS_PER_S, ImuSeries, PoseSeries, PoseSourceKind, Sequence

T0_NS = 1_403_715_273_262_142_976  # an EuRoC-like epoch stamp


def _angles(t_s: np.ndarray) -> np.ndarray:
    """Smooth rotation vector trajectory [N, 3] (rad)."""
    return np.column_stack([0.3 * np.sin(0.7 * t_s), 0.2 * np.sin(1.1 * t_s + 0.5), 0.8 * np.sin(0.4 * t_s)])


def make_imu(duration_s: float = 10.0, rate_hz: float = 200.0, t0_ns: int = T0_NS, seed: int = 0) -> ImuSeries:
    """IMU with ~1 rad/s motion, gravity on z, small noise; [N] rows with N = duration * rate."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    t_ns = t0_ns + np.round(np.arange(n) * NS_PER_S / rate_hz).astype(np.int64)
    t_s = (t_ns - t0_ns) / NS_PER_S
    gyro = np.column_stack([0.21 * np.cos(0.7 * t_s), 0.22 * np.cos(1.1 * t_s + 0.5), 0.32 * np.cos(0.4 * t_s)])
    gyro = gyro + 0.8 * np.sin(2.0 * t_s)[:, None] * np.array([1.0, -0.5, 0.3]) + rng.normal(0, 0.003, (n, 3))
    acc = np.column_stack([0.5 * np.sin(1.3 * t_s), 0.4 * np.cos(0.9 * t_s), 9.81 + 0.3 * np.sin(2.1 * t_s)])
    acc = acc + rng.normal(0, 0.03, (n, 3))
    return ImuSeries(t_ns, gyro, acc)


def make_poses(duration_s: float = 10.0, rate_hz: float = 100.0, t0_ns: int = T0_NS,
               frame: str = "vicon_marker") -> PoseSeries:
    """Poses whose angular speed is comparable to :func:`make_imu`'s gyro (~1 rad/s)."""
    n = int(round(duration_s * rate_hz))
    t_ns = t0_ns + np.round(np.arange(n) * NS_PER_S / rate_hz).astype(np.int64)
    t_s = (t_ns - t0_ns) / NS_PER_S
    rotvec = _angles(t_s) + np.column_stack([0.4 * (1 - np.cos(2.0 * t_s)), np.zeros(n), np.zeros(n)])
    quat_xyzw = Rotation.from_rotvec(rotvec).as_quat()
    quat_wxyz = quat_xyzw[:, [3, 0, 1, 2]]
    quat_wxyz *= np.sign(quat_wxyz[:, :1])  # w >= 0, continuous for these small angles
    p = np.column_stack([np.sin(0.3 * t_s), np.cos(0.2 * t_s), 0.1 * t_s])
    return PoseSeries(t_ns, p, quat_wxyz, frame, PoseSourceKind.MOCAP)


def make_sequence(duration_s: float = 10.0, imu_rate_hz: float = 200.0, pose_rate_hz: float = 100.0,
                  name: str = "synth", **kw) -> Sequence:
    """A clean sequence with an IMU and one pose stream ``vicon0`` on the same clock."""
    return Sequence(name=name, imu=make_imu(duration_s, imu_rate_hz, **kw),
                    poses={"vicon0": make_poses(duration_s, pose_rate_hz, **kw)},
                    metadata={"source_format": "synthetic"})


def write_recovery_folder(folder, bias, report: dict, trajectory: PoseSeries | None = None):
    """A recovery folder of known content (e.g. the true bias), written by the stage's own writer.

    Args:
        folder: Output folder.
        bias: Keyframe bias (:class:`pipeline.bias_table.BiasTrack`).
        report: ``recovery.json`` fields (the random walks under ``noise``, ``T_imu_pose``, ...).
        trajectory: The IMU trajectory; default: at rest at the origin at the bias stamps.
    """
    from recovery.outputs import RecoveryOutputs, RecoveryReport

    if trajectory is None:
        n = len(bias.t_ns)
        trajectory = PoseSeries(bias.t_ns, np.zeros((n, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), "imu",
                                PoseSourceKind.GROUND_TRUTH)
    return RecoveryOutputs(bias, RecoveryReport.from_json(report), trajectory).write(folder)
