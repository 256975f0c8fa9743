"""The simulated pose sensor: mocap, position-only tracker or drifting VIO.

Clock convention (the recovery contract's ``pose_time_offset_s``)::

    t_imu_clock = pose_stamp + clock_offset_s

so the pose with stamp ``s`` shows the tracked frame at IMU-clock time ``s + clock_offset_s``.
The tracked frame is ``T_world_<frame> = T_world_imu @ T_imu_<frame>``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.errors import ConfigError
from pipeline.sim.config import PoseFormat, PoseStreamConfig
from pipeline.sim.motion import Trajectory, quat_wxyz_continuous
from pipeline.types import PoseSeries, PoseSourceKind

NS_PER_S = 1_000_000_000

#: stream name, tracked-frame name, source kind, world frame per format.
STREAMS: dict[PoseFormat, tuple[str, str, PoseSourceKind, str]] = {
    PoseFormat.MOCAP: ("mocap0", "mocap_marker", PoseSourceKind.MOCAP, "world"),
    PoseFormat.POSITION: ("leica0", "leica_prism", PoseSourceKind.POSITION_TRACKER, "world"),
    PoseFormat.VIO: ("vio", "vio_body", PoseSourceKind.VIO, "vio_world"),
}


@dataclass(frozen=True)
class PoseTruth:
    """What the pose stream really is.

    Attributes:
        stream: Stream name in ``Sequence.poses``.
        frame: Tracked-frame name.
        T_imu_frame: True 4x4 ``T_imu_<frame>``.
        clock_offset_s: Seconds to add to pose stamps to get IMU-clock time.
        clock_offset_ns: The same, as applied (int64 ns).
        true_t_ns: IMU-clock time of each output pose, int64 [M].
        p_true_m: Noise- and outlier-free position of the tracked frame (after VIO drift), [M, 3].
        quat_true_wxyz: Noise-free orientation of the tracked frame, [M, 4] (also for position-only).
        dropout_intervals_ns: Removed intervals on the POSE clock, int64 [K, 2] (start, end).
        outlier_stamps_ns: Pose stamps of the displaced samples, int64 [L].
        vio_drift_p_m / vio_drift_yaw_rad: The VIO drift at each output pose ([M, 3], [M]); zeros otherwise.
    """

    stream: str
    frame: str
    T_imu_frame: np.ndarray
    clock_offset_s: float
    clock_offset_ns: int
    true_t_ns: np.ndarray
    p_true_m: np.ndarray
    quat_true_wxyz: np.ndarray
    dropout_intervals_ns: np.ndarray
    outlier_stamps_ns: np.ndarray
    vio_drift_p_m: np.ndarray
    vio_drift_yaw_rad: np.ndarray


def make_extrinsic(cfg: PoseStreamConfig, rng: np.random.Generator) -> np.ndarray:
    """``T_imu_<frame>`` [4, 4]: explicit values when given, else random axis/direction with the given size."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    if cfg.extrinsic_rotvec_deg is not None:
        rotvec = np.deg2rad(np.asarray(cfg.extrinsic_rotvec_deg, dtype=float))
    else:
        rotvec = axis * np.deg2rad(cfg.extrinsic_rotation_deg)
    if cfg.extrinsic_translation_xyz_m is not None:
        trans = np.asarray(cfg.extrinsic_translation_xyz_m, dtype=float)
    else:
        trans = direction * cfg.extrinsic_translation_m
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = trans
    return T


def _dropout_intervals(cfg: PoseStreamConfig, span_s: float, rng: np.random.Generator) -> np.ndarray:
    """K disjoint gaps [start, end) in seconds, one per equal slot of the (margin-trimmed) span."""
    n = cfg.dropouts
    if n == 0:
        return np.zeros((0, 2))
    if cfg.dropout_max_s < 2.0 / cfg.rate_hz:
        raise ConfigError(
            f"poses.dropout_max_s={cfg.dropout_max_s} is shorter than two pose periods; no sample would be removed",
            field="poses.dropout_max_s",
        )
    margin = 0.05 * span_s
    slot = (span_s - 2 * margin) / n
    lengths = rng.uniform(0.5, 1.0, n) * cfg.dropout_max_s
    if lengths.max() >= 0.8 * slot:
        raise ConfigError(
            f"{n} dropouts of up to {cfg.dropout_max_s} s do not fit in {span_s:.1f} s of poses",
            field="poses.dropouts",
            hint="use fewer or shorter dropouts, or a longer duration",
        )
    starts = margin + slot * np.arange(n) + rng.uniform(0.0, 1.0, n) * (slot - lengths)
    return np.column_stack([starts, starts + lengths])


def gauss_markov(t_s: np.ndarray, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """Six unit-variance first-order Gauss-Markov processes sampled exactly at ``t_s`` [M], [M, 6]:
    ``x_{k+1} = a x_k + sqrt(1 - a^2) w_k`` with ``a = exp(-dt / tau)``, stationary from the start."""
    w = rng.normal(0.0, 1.0, size=(len(t_s), 6))
    x = np.empty_like(w)
    x[0] = w[0]
    a = np.exp(-np.diff(t_s) / tau_s)
    for k in range(1, len(t_s)):
        x[k] = a[k - 1] * x[k - 1] + np.sqrt(1.0 - a[k - 1] ** 2) * w[k]
    return x


def simulate_pose_stream(
    cfg: PoseStreamConfig,
    trajectory: Trajectory,
    imu_t0_ns: int,
    duration_s: float,
    rngs: dict[str, np.random.Generator],
) -> tuple[PoseSeries, PoseTruth]:
    """Sample the pose sensor.

    Args:
        cfg: Pose sensor configuration.
        trajectory: True IMU motion (time in seconds from ``imu_t0_ns``).
        imu_t0_ns: First IMU stamp.
        duration_s: The poses' true times cover ``[0, duration_s]`` of the IMU record.
        rngs: Independent streams ``extrinsic``, ``phase``, ``noise``, ``dropouts``, ``outliers``, ``vio``.

    Returns:
        The pose series (stamps on the pose clock) and its truth.
    """
    stream, frame, kind, world = STREAMS[cfg.format]
    T_imu_frame = make_extrinsic(cfg, rngs["extrinsic"])
    offset_ns = int(round(cfg.clock_offset_s * NS_PER_S))
    period_ns = NS_PER_S / cfg.rate_hz
    phase_ns = int(rngs["phase"].integers(0, max(int(period_ns), 1)))
    n = int(np.floor((duration_s * NS_PER_S - phase_ns) / period_ns)) + 1
    rel_ns = phase_ns + np.round(np.arange(n) * period_ns).astype(np.int64)
    rel_ns = rel_ns[rel_ns <= int(round(duration_s * NS_PER_S))]
    true_t_ns = imu_t0_ns + rel_ns
    stamps_ns = true_t_ns - offset_ns
    t_s = rel_ns / NS_PER_S

    rot_imu = trajectory.rotation(t_s)
    p_imu = trajectory.position(t_s)
    R_ie = Rotation.from_matrix(T_imu_frame[:3, :3])
    p_true = p_imu + rot_imu.apply(T_imu_frame[:3, 3])
    rot_true = rot_imu * R_ie

    p_true, rot_true, drift_p, drift_yaw = _vio_drift(cfg, t_s, p_true, rot_true, rngs["vio"])
    p_meas, rot_meas = _measured(cfg, t_s, p_true, rot_true, rngs)
    keep, gaps_ns = _kept_poses(cfg, t_s, duration_s, imu_t0_ns - offset_ns, rngs["dropouts"])
    out_idx = _add_outliers(cfg, keep, p_meas, rngs["outliers"])

    quat = None if cfg.format is PoseFormat.POSITION else quat_wxyz_continuous(rot_meas[keep])
    series = PoseSeries(stamps_ns[keep], p_meas[keep], quat, frame, kind, world)
    truth = PoseTruth(
        stream=stream,
        frame=frame,
        T_imu_frame=T_imu_frame,
        clock_offset_s=float(cfg.clock_offset_s),
        clock_offset_ns=offset_ns,
        true_t_ns=true_t_ns[keep],
        p_true_m=p_true[keep],
        quat_true_wxyz=quat_wxyz_continuous(rot_true[keep]),
        dropout_intervals_ns=gaps_ns,
        outlier_stamps_ns=stamps_ns[out_idx],
        vio_drift_p_m=drift_p[keep],
        vio_drift_yaw_rad=drift_yaw[keep],
    )
    return series, truth


def _vio_drift(cfg: PoseStreamConfig, t_s: np.ndarray, p_true: np.ndarray, rot_true: Rotation,
               rng_vio: np.random.Generator) -> tuple[np.ndarray, Rotation, np.ndarray, np.ndarray]:
    """``(p_true, rot_true, drift_p, drift_yaw)``: a VIO stream's true poses drift (random walks in
    position and yaw); other formats keep theirs (the steps are drawn all the same)."""
    m = len(t_s)
    vio_steps = rng_vio.normal(0.0, 1.0, size=(max(m - 1, 0), 4)) * np.sqrt(1.0 / cfg.rate_hz)
    drift_p = np.zeros((m, 3))
    drift_yaw = np.zeros(m)
    if cfg.format is PoseFormat.VIO and m > 1:
        drift_p[1:] = np.cumsum(vio_steps[:, :3], axis=0) * cfg.vio_position_drift_m_per_sqrt_s
        drift_yaw[1:] = np.cumsum(vio_steps[:, 3]) * cfg.vio_yaw_drift_rad_per_sqrt_s
        rz = Rotation.from_rotvec(np.column_stack([np.zeros(m), np.zeros(m), drift_yaw]))
        p_true = rz.apply(p_true) + drift_p
        rot_true = rz * rot_true
    return p_true, rot_true, drift_p, drift_yaw


def _measured(cfg: PoseStreamConfig, t_s: np.ndarray, p_true: np.ndarray, rot_true: Rotation,
              rngs: dict[str, np.random.Generator]) -> tuple[np.ndarray, Rotation]:
    """The measured poses: white plus correlated (Gauss-Markov) noise on the true ones."""
    m = len(t_s)
    noise = rngs["noise"].normal(0.0, 1.0, size=(m, 6))
    slow = gauss_markov(t_s, cfg.correlated_noise_tau_s, rngs["correlated"]) if m else np.zeros((0, 6))
    p_meas = p_true + noise[:, :3] * cfg.position_noise_m + slow[:, :3] * cfg.correlated_position_noise_m
    if cfg.format is PoseFormat.POSITION or cfg.rotation_noise_rad == cfg.correlated_rotation_noise_rad == 0:
        rot_meas = rot_true
    else:
        rot_meas = rot_true * Rotation.from_rotvec(noise[:, 3:] * cfg.rotation_noise_rad
                                                   + slow[:, 3:] * cfg.correlated_rotation_noise_rad)
    return p_meas, rot_meas


def _kept_poses(cfg: PoseStreamConfig, t_s: np.ndarray, duration_s: float, t0_pose_clock_ns: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``(keep, gaps_ns)``: the poses outside the dropouts, and the dropouts on the pose clock."""
    gaps_s = _dropout_intervals(cfg, duration_s, rng)
    keep = np.ones(len(t_s), dtype=bool)
    for start, end in gaps_s:
        keep &= ~((t_s >= start) & (t_s < end))
    gaps_ns = t0_pose_clock_ns + np.round(gaps_s * NS_PER_S).astype(np.int64).reshape(-1, 2)
    return keep, gaps_ns


def _add_outliers(cfg: PoseStreamConfig, keep: np.ndarray, p_meas: np.ndarray, rng_out: np.random.Generator
                  ) -> np.ndarray:
    """Move ``cfg.outliers`` kept positions by ``cfg.outlier_offset_m`` in random directions (in place);
    returns their indices."""
    kept_idx = np.flatnonzero(keep)
    if cfg.outliers > len(kept_idx):
        raise ConfigError(f"poses.outliers={cfg.outliers} exceeds the {len(kept_idx)} poses", field="poses.outliers")
    out_idx = np.sort(rng_out.choice(kept_idx, size=cfg.outliers, replace=False)) if cfg.outliers else np.zeros(0, int)
    directions = rng_out.normal(size=(len(out_idx), 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True).clip(1e-12)
    p_meas[out_idx] += directions * cfg.outlier_offset_m
    return out_idx
