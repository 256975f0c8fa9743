"""biasgt recovery stage: IMU bias ground truth by joint optimisation in GTSAM.

Public API::

    from recovery.config import RecoveryConfig
    from recovery.outputs import RecoveryOutputs
    from recovery.recover import recover, write_recovery  # (``recovery.recover`` is also a module)
    result = recover(sequence, pose_stream="vicon0", config=RecoveryConfig())
    write_recovery(result, "out/recovery")   # bias.csv, recovery.json, trajectory_tum.txt, residuals.csv
    back = RecoveryOutputs.read("out/recovery")  # the same folder, typed

Modules: :mod:`recovery.config` (options and mode enums), :mod:`recovery.preintegration`
(midpoint preintegration at keyframes off the IMU stamps), :mod:`recovery.window` (one window's
records), :mod:`recovery.initial` (its initial states), :mod:`recovery.factors` (its factor graph),
:mod:`recovery.gaps` (keyframes in pose gaps), :mod:`recovery.graph` (its solve and marginals),
:mod:`recovery.noise` (random walks and pose
sigma by maximum evidence), :mod:`recovery.segments` (overlapping segments, stitching),
:mod:`recovery.recover` (the whole stage), :mod:`recovery.outputs` (files),
:mod:`recovery.calibration_init` (closed-form offset / extrinsic / gravity initialisation).
"""

from recovery.config import (
    ExtrinsicMode,
    ImuGapPolicy,
    NoiseEstimation,
    PoseFactorMode,
    RecoveryConfig,
    RobustLoss,
    TimeOffsetMode,
)

__all__ = [
    "ExtrinsicMode", "ImuGapPolicy", "NoiseEstimation", "PoseFactorMode", "RecoveryConfig", "RobustLoss",
    "TimeOffsetMode",
]
