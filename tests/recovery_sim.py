"""Simulated sequences, fast recovery settings and bias errors against the truth, for the recovery tests."""

from __future__ import annotations

import numpy as np

from pipeline.sim import simulate
from pipeline.sim.config import PoseStreamConfig, SimConfig

# Fast settings: noise fixed to the simulator's truth, decimated keyframes.
FAST = dict(keyframe_rate_hz=20.0, noise_estimation="fixed", gyro_random_walk=10 * 1.9393e-5,
            acc_random_walk=10 * 3.0e-3, position_sigma_m=0.5e-3, rotation_sigma_rad=0.5e-3,
            offset_refine_keyframe_rate_hz=10.0, extrinsic_keyframe_rate_hz=10.0, gravity_keyframe_rate_hz=5.0)


def sim_sequence(duration_s: float = 30.0, seed: int = 0, **poses) -> object:
    """A simulation of ``duration_s`` seconds; ``poses`` set the pose stream (extrinsic known by default)."""
    poses.setdefault("extrinsic_known", True)
    return simulate(SimConfig(duration_s=duration_s, seed=seed, poses=PoseStreamConfig(**poses)))


def bias_errors(res, truth) -> tuple[np.ndarray, np.ndarray]:
    """Recovered minus true gyro and accelerometer bias at the recovery's keyframes, each [K, 3]."""
    tb = np.stack([np.interp(res.t_ns, truth.t_ns, truth.bias_gyro_radps[:, c]) for c in range(3)], 1)
    ta = np.stack([np.interp(res.t_ns, truth.t_ns, truth.bias_acc_mps2[:, c]) for c in range(3)], 1)
    return res.bias_gyro_radps - tb, res.bias_acc_mps2 - ta
