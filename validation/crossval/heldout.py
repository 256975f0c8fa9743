"""Errors of a cross-validated bias on the windows it was held out of (:mod:`validation.crossval.blocks`).

The windows judged lie wholly inside one block (no window mixes two folds' recoveries) and have a
reference at both ends; they are integrated with validation's one metric
(:func:`validation.metrics.window_errors`: PRMSE, ROE).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.types import ImuSeries
from validation.config import ValidationConfig
from validation.crossval.blocks import BlockFolds
from validation.metrics import WindowPlan, prmse_m, roe_deg, window_errors
from validation.reference import ReferenceStates

__all__ = ["HeldOutErrors", "held_out_errors", "held_out_windows"]


def held_out_windows(imu: ImuSeries, plan: WindowPlan, folds: BlockFolds, reference: ReferenceStates) -> np.ndarray:
    """Kept windows of ``plan`` wholly inside one block with a reference at both ends, bool [W]."""
    first, last = plan.starts, plan.starts + plan.n
    block = folds.block(imu.t_ns)
    return plan.keep & (block[first] == block[last]) & reference.valid[first] & reference.valid[last]


@dataclass(frozen=True)
class HeldOutErrors:
    """1-s integration errors on the held-out windows: ``pos_err_m`` [W], ``rot_err_deg`` [W] and their
    PRMSE (m) and ROE (deg)."""

    pos_err_m: np.ndarray
    rot_err_deg: np.ndarray

    @property
    def prmse_m(self) -> float:
        return prmse_m(self.pos_err_m)

    @property
    def roe_deg(self) -> float:
        return roe_deg(self.rot_err_deg)


def held_out_errors(imu: ImuSeries, bias: np.ndarray, reference: ReferenceStates, plan: WindowPlan,
                    windows: np.ndarray, gravity_mps2: np.ndarray,
                    config: ValidationConfig = ValidationConfig()) -> HeldOutErrors:
    """Integrate ``imu - bias`` over the selected windows from the reference and measure the end errors.

    Args:
        imu: Readings, [N].
        bias: Bias at the IMU stamps, [N, 6].
        reference: Reference at the IMU stamps (its frame: world and IMU as the candidate assumes).
        plan: The window plan (:func:`validation.metrics.plan_windows`).
        windows: Which of ``plan.starts`` to integrate, bool [W].
        gravity_mps2: Gravity in the reference's world frame, [3].
        config: Integration scheme and chunking.
    """
    pos, rot = window_errors(imu, np.asarray(bias, dtype=np.float64), reference, plan.starts[windows], plan.n,
                             np.asarray(gravity_mps2, dtype=np.float64), config)
    return HeldOutErrors(pos, rot)
