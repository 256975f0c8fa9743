"""Simulator: sequences with exactly known bias, clock offset and extrinsic.

Public API::

    from pipeline.sim import SimConfig, simulate, write_simulation
    sim = simulate(SimConfig(duration_s=60, seed=1))
    sim.sequence          # pipeline.types.Sequence (imu, poses, ground_truth = true state)
    sim.truth             # true bias arrays, clock offset, extrinsic, gravity, ...
    write_simulation(sim, "out/sim01")   # EuRoC/ASL folder + simulation.yaml
"""

import importlib

from pipeline.sim.config import (
    ImuNoiseConfig,
    MotionConfig,
    MotionPreset,
    PoseFormat,
    PoseStreamConfig,
    SimConfig,
    TemperatureConfig,
)

# The simulator and writer pull in scipy.signal and pandas: load them on first use so that
# `biasgt --help` and config validation stay fast (PEP 562 module __getattr__).
_LAZY = {
    "Simulation": "pipeline.sim.simulator",
    "SimTruth": "pipeline.sim.simulator",
    "simulate": "pipeline.sim.simulator",
    "read_simulation_yaml": "pipeline.sim.writer",
    "write_simulation": "pipeline.sim.writer",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'pipeline.sim' has no attribute {name!r}")

__all__ = [
    "ImuNoiseConfig",
    "MotionConfig",
    "MotionPreset",
    "PoseFormat",
    "PoseStreamConfig",
    "SimConfig",
    "SimTruth",
    "Simulation",
    "TemperatureConfig",
    "read_simulation_yaml",
    "simulate",
    "write_simulation",
]
