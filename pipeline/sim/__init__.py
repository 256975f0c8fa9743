"""Simulator: sequences with exactly known bias, clock offset and extrinsic.

Public API::

    from pipeline.sim import SimConfig, simulate, write_simulation
    sim = simulate(SimConfig(duration_s=60, seed=1))
    sim.sequence          # pipeline.types.Sequence (imu, poses, ground_truth = true state)
    sim.truth             # true bias arrays, clock offset, extrinsic, gravity, ...
    write_simulation(sim, "out/sim01")   # EuRoC/ASL folder + simulation.yaml
"""

from pipeline.sim.config import (
    ImuNoiseConfig,
    MotionConfig,
    MotionPreset,
    PoseFormat,
    PoseStreamConfig,
    SimConfig,
    TemperatureConfig,
)
from pipeline.sim.simulator import Simulation, SimTruth, simulate
from pipeline.sim.writer import read_simulation_yaml, write_simulation

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
