"""Stage 7 of the recovery: gravity's direction from one decimated long-window solve, and the level test
that keeps a level frame's nominal gravity unless the data show a tilt.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

import numpy as np

from pipeline.types import NS_PER_S
from recovery.config import (
    CalibrationSolve,
    RecoveryConfig,
)
from recovery.solver.graph import solve_window
from recovery.solver.window import WindowInit, WindowSolution
from recovery.noise.evidence import NoiseChoice
from recovery.solver.segments import plan_segments
from recovery.problem import Problem, shifted_stamps
from recovery.result import bias_function, solve_rate_hz
from recovery.records import GravityStage, Inputs


log = logging.getLogger(__name__)


def solve_gravity(problem: Problem, inputs: Inputs, offset_s: float, T: np.ndarray, ext_sol: WindowSolution | None,
             estimate_lever: bool, choice: NoiseChoice, config: RecoveryConfig,
             extrinsic_prior: tuple[np.ndarray, np.ndarray] | None = None) -> GravityStage:
    """Stage 7: one decimated solve over a long window for the gravity direction (and the lever arm)."""
    t_pose = shifted_stamps(inputs.poses, offset_s)
    info: dict[str, Any] = {}
    ext_info: dict[str, Any] = {}
    unit = np.array([0.0, 0.0, -1.0])
    gsol, gwin = None, None
    gopts = replace(inputs.opts, position_sigma_m=choice.position_sigma_m, rotation_sigma_rad=choice.rotation_sigma_rad,
                    marginal_extras=True, pose_error=choice.pose_error)
    refine_lever = ext_sol is not None and inputs.has_rot and estimate_lever
    seg_s, seg_overlap_s = config.segment_plan(solve_rate_hz(config, problem))
    if not inputs.has_rot and config.position_only_window_s > seg_s:  # see position_only_window_s
        seg_s, seg_overlap_s = config.position_only_window_s, config.position_only_window_s / 6
    spans = [(max(a, int(t_pose[0])), min(b, int(t_pose[-1]))) for a, b in inputs.pieces]
    spans = [(a, b) for a, b in spans if b > a]
    # one piece solved as one segment: it estimates gravity itself, a separate solve adds nothing
    one_segment = len(spans) == 1 and len(plan_segments(spans[0][0], spans[0][1], seg_s, seg_overlap_s)) == 1
    estimated = inputs.estimate_gravity
    if refine_lever or (inputs.estimate_gravity and not one_segment):
        longest = max(inputs.pieces, key=lambda ab: min(ab[1], int(t_pose[-1])) - max(ab[0], int(t_pose[0])))
        ga, gb = max(longest[0], int(t_pose[0])), min(longest[1], int(t_pose[-1]))
        gb = min(gb, ga + int(config.gravity_window_s * NS_PER_S))
        w = problem.window(offset_s, ga, gb, config.calibration_rate_hz(CalibrationSolve.GRAVITY, problem.fuse))
        gwin = (ga, gb)
        if w is not None:
            g_init = ext_sol.gravity_unit if ext_sol is not None and inputs.estimate_gravity else None
            gsol = solve_window(w[0], w[1], choice.imu, T, replace(gopts, estimate_lever_arm=refine_lever,
                                                                   extrinsic_prior=extrinsic_prior),
                                WindowInit(gravity_unit=g_init))
            unit = gsol.gravity_unit
            if refine_lever:
                T = gsol.T_imu_pose
                if "lever_arm_cov" in gsol.extras:
                    ext_info["translation_std_m"] = [float(x) for x in np.sqrt(np.diag(gsol.extras["lever_arm_cov"]))]
                ext_info["lever_arm_refined_window_s"] = float((gb - ga) / NS_PER_S)
            if "gravity_cov_tangent" in gsol.extras:
                info["tilt_std_rad"] = float(np.sqrt(np.trace(gsol.extras["gravity_cov_tangent"]) / 2))
                if inputs.level_test and inputs.estimate_gravity:
                    info["level_test"] = level_gravity_test(unit, info["tilt_std_rad"], config.gravity_tilt_sigmas,
                                                     config.gravity_level_tolerance_deg)
                    if info["level_test"]["level"]:
                        unit, estimated = np.array([0.0, 0.0, -1.0]), False
            problem.set_linearisation(T_imu_pose=T, gravity_unit=unit, bias=bias_function(gsol))
            info["window_s"] = float((gb - ga) / NS_PER_S)
    elif inputs.estimate_gravity:
        unit = problem.gravity_world / np.linalg.norm(problem.gravity_world)
        info["window_s"] = float((spans[0][1] - spans[0][0]) / NS_PER_S) if spans else 0.0
    info["estimated"] = bool(estimated)
    return GravityStage(unit, bool(estimated), gsol, gwin, T, info, ext_info, seg_s, seg_overlap_s)


def level_gravity_test(unit: np.ndarray, tilt_std_rad: float, max_sigmas: float, tolerance_deg: float) -> dict[str, Any]:
    """Whether a level frame keeps its nominal gravity (``recovery.json`` ``gravity.level_test``).

    The tilt of gravity from the frame's -z and an accelerometer bias explain the same specific
    force under little attitude change; a user of a levelled frame integrates with its nominal
    gravity, so the bias written must be the one consistent with it. The frame is kept level unless
    its estimated tilt both exceeds what levelling a frame leaves (``tolerance_deg``: then the frame
    is not levelled, or its z is not up) and stands out of its sigma (``max_sigmas``: the data tell
    it from the bias); then the tilt is kept and the bias is consistent with the estimated gravity.
    """
    tilt = math.degrees(float(np.arccos(np.clip(-unit[2] / np.linalg.norm(unit), -1.0, 1.0))))
    std = math.degrees(tilt_std_rad)
    z = tilt / std if std > 0 else float("inf")
    level = bool(tilt <= tolerance_deg or z < max_sigmas)
    why = (f"within the {tolerance_deg:g}-deg levelling tolerance" if tilt <= tolerance_deg else
           f"within {max_sigmas:g} sigma" if z < max_sigmas else
           f"beyond the {tolerance_deg:g}-deg levelling tolerance and {z:.1f} sigma from the frame's -z")
    return {"tilt_deg": tilt, "tilt_std_deg": std, "tilt_sigmas": z, "level": level,
            "reason": (f"kept level (nominal gravity): the estimated tilt {tilt:.2f} +- {std:.2f} deg is {why}"
                       if level else f"tilted: the estimated tilt {tilt:.2f} +- {std:.2f} deg is {why}")}
