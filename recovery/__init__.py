"""biasgt recovery stage: IMU bias ground truth by joint optimisation in GTSAM.

Public API::

    from recovery.config import RecoveryConfig
    from recovery.outputs import RecoveryOutputs
    from recovery.recover import recover, write_recovery  # (``recovery.recover`` is also a module)
    result = recover(sequence, pose_stream="vicon0", config=RecoveryConfig())
    write_recovery(result, "out/recovery")   # bias.csv, recovery.json, trajectory_tum.txt, residuals.csv
    back = RecoveryOutputs.read("out/recovery")  # the same folder, typed

Layout: the stage's entry (:mod:`recovery.recover`), its options (:mod:`recovery.config`), the
problem it builds (:mod:`recovery.problem`), the records its steps hand on (:mod:`recovery.records`),
its result and files (:mod:`recovery.result`, :mod:`recovery.outputs`), the degenerate-solve hint
(:mod:`recovery.degenerate`); and by role the subpackages :mod:`recovery.solver` (one window's factor
graph and solve), :mod:`recovery.noise` (noise strengths), :mod:`recovery.clock` (the pose stream's
clock offset), :mod:`recovery.frame` (frame check, extrinsic, gravity), :mod:`recovery.intrinsics` (IMU
intrinsics) and :mod:`recovery.calibration_init` (closed-form offset / extrinsic / gravity
initialisation).
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
