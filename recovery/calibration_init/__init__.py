"""Closed-form initial estimates that bias recovery needs before its factor graph.

Each estimator needs no initial guess; the GTSAM graph (:mod:`recovery.solver.graph`) refines
the results. Conventions (offset sign, extrinsic direction, gravity) are stated in
:mod:`recovery.calibration_init.common`.

Modules:
    * :mod:`.common`: the result records and shared helpers (pose rates, gyro integral).
    * :mod:`.time_offset`: clock offset from ``|omega|`` or, for position-only streams,
      from ``|f|^2`` against the positions.
    * :mod:`.extrinsic`: extrinsic rotation (Kabsch with a gyro bias) and lever arm
      (second-difference least squares).
    * :mod:`.gravity`: gravity direction from the same least squares, and static segments.
"""

from recovery.calibration_init.common import (
    GravityEstimate,
    LeverArmEstimate,
    RotationEstimate,
    TimeOffsetEstimate,
    gyro_integral,
    pose_angular_rates,
    pose_rotations,
)
from recovery.calibration_init.extrinsic import estimate_extrinsic_rotation, estimate_lever_arm
from recovery.calibration_init.gravity import (
    RestTest,
    estimate_gravity,
    estimate_gravity_direction,
    find_static_segments,
)
from recovery.calibration_init.time_offset import estimate_time_offset

__all__ = [
    "TimeOffsetEstimate",
    "RotationEstimate",
    "LeverArmEstimate",
    "GravityEstimate",
    "gyro_integral",
    "pose_rotations",
    "pose_angular_rates",
    "estimate_time_offset",
    "estimate_extrinsic_rotation",
    "estimate_lever_arm",
    "find_static_segments",
    "RestTest",
    "estimate_gravity",
    "estimate_gravity_direction",
]
