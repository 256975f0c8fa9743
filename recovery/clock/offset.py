"""The clock offset of the pose stream: the coarse correlation's inputs, then the minimum of the optimised
graph cost (Newton steps on its analytic slope for 6-DoF streams, else a parabola through three offsets).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from pipeline.errors import BiasgtError, RecoveryError
from pipeline.types import NS_PER_S, ImuSeries, PoseSeries
from recovery.config import (
    CalibrationSolve,
    OffsetRefineMethod,
    RecoveryConfig,
)
from recovery.solver.graph import solve_window
from recovery.solver.window import SolveOptions, WindowInit
from recovery.solver.preintegration import ImuNoise
from recovery.problem import COARSE_OFFSET_SPAN_S, calibration_window, Problem, shifted_stamps
from recovery.records import Inputs

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- offset


#: A Newton step on the clock offset longer than this many of its sigmas is taken again from where
#: it lands: one step from 0.1 ms away lands within 0.05 sigma of the parabola's vertex on the
#: benchmark and the hard simulated cases, and the error grows with the step.
OFFSET_NEWTON_MAX_SIGMAS = 2.0
OFFSET_NEWTON_MAX_SOLVES = 5  # then the parabola


@dataclass(frozen=True)
class _OffsetRefinement:
    """The refined clock offset and its 1-sigma, the solves (``recovery.json``
    ``pose_time_offset_search``), the last solve's gravity and median bias (a linearisation point
    for fusion), and the method."""

    offset_s: float
    std_s: float
    table: list[dict[str, float]]
    last: WindowInit | None
    method: OffsetRefineMethod


def refine_offset(problem: Problem, coarse_s: float, coarse_std_s: float, window: tuple[int, int], noise: ImuNoise, T: np.ndarray,
                   opts: SolveOptions, config: RecoveryConfig) -> _OffsetRefinement:
    """The offset at the minimum of the optimised graph cost, its std from the cost's curvature.

    Newton steps on the cost's analytic slope and curvature in the offset when the pose factors
    are 6-DoF absolute (:func:`recovery.solver.calibration_uncertainty.parameter_slope_and_information`;
    one solve when the coarse offset lies within two sigmas); else, or when the steps do not
    settle, a 1-D search: a parabola through the cost at three offsets.
    """
    o = replace(opts, reject_outliers=False, compute_marginals=False, marginal_extras=False, residuals=False)
    rate = config.calibration_rate_hz(CalibrationSolve.OFFSET_REFINE, problem.fuse)
    newton = _newton_offset(problem, coarse_s, window, noise, T, o, rate, config.max_time_offset_s)
    if newton is not None:
        return newton
    cache: dict[int, float] = {}
    n_keyframes: dict[int, int] = {}
    init: dict[str, WindowInit] = {}

    def cost(off: float) -> float:
        key = int(round(off * 1e9))
        if key in cache:
            return cache[key]
        w = problem.window(off, window[0], window[1], rate)
        if w is None:
            c = float("inf")
        else:
            try:
                sol = solve_window(w[0], w[1], noise, T, o, init.get("x"))
                # normalise per keyframe: the keyframe set can change by one between offsets
                c = sol.cost / len(w[1]) * 1000.0
                n_keyframes[key] = len(w[1])
                init["x"] = WindowInit(gravity_unit=sol.gravity_unit, bias=np.median(sol.bias, axis=0))
            except BiasgtError:
                c = float("inf")
        cache[key] = c
        return c

    # 3-point grid around the coarse value (the cost is quadratic within +-2 coarse sigmas);
    # slide it while the minimum is at an edge
    h = float(np.clip(2.0 * coarse_std_s, config.offset_refine_step_s / 8, config.offset_refine_step_s))
    center = coarse_s
    grid_k = np.arange(-1, 2)
    for _ in range(12):
        xs = center + grid_k * h
        cs = np.array([cost(x) for x in xs])
        i = int(np.argmin(cs))
        if 0 < i < len(xs) - 1 or not np.isfinite(cs[i]):
            break
        center = xs[i]
    fine, fc = xs, cs
    ok = np.isfinite(fc)
    if ok.sum() < 3:
        raise RecoveryError("the clock-offset search found no finite cost")
    a, b, _ = np.polyfit(fine[ok], fc[ok], 2)
    table = [{"offset_s": float(k / 1e9), "cost_per_kkf": float(v)} for k, v in sorted(cache.items())]
    if a <= 0:
        return _OffsetRefinement(float(fine[int(np.argmin(fc))]), float(h), table, init.get("x"),
                                 OffsetRefineMethod.PARABOLA)
    vertex = float(-b / (2 * a))
    vertex = float(np.clip(vertex, fine[0], fine[-1]))
    # cost = 0.5 chi2 / K * 1000  -> d2(0.5 chi2)/d off2 = 2a K / 1000
    # keyframes at the evaluated offset nearest the vertex (a window more or less changes the std by < 1 %)
    n_kf = n_keyframes[min(n_keyframes, key=lambda k: abs(k / 1e9 - vertex))]
    curv = 2 * a * n_kf / 1000.0
    std = float(1.0 / math.sqrt(curv)) if curv > 0 else float(h)
    return _OffsetRefinement(vertex, std, table, init.get("x"), OffsetRefineMethod.PARABOLA)


def offset_spread_windows(imu: ImuSeries, pieces: list[tuple[int, int]], overlap: tuple[int, int],
                          window: tuple[int, int], pose_t_ns: np.ndarray) -> list[tuple[int, int]]:
    """At most two windows, one before and one after ``window`` inside ``overlap`` (IMU clock), on which
    the offset is estimated again: their scatter bounds the reported sigma from below, since the cost's
    curvature sees only the white part of the pose error.

    Each is the one with the most rotation on its side (:func:`recovery.problem._calibration_window`),
    as long as ``window``; a side shorter than that gives a window as long as the side (less precise:
    its scatter errs on the safe side), and one shorter than half of it gives none.
    ``pose_t_ns``: the pose stamps on the IMU clock.
    """
    length_ns = window[1] - window[0]
    out = []
    for side in ((overlap[0], window[0]), (window[1], overlap[1])):
        if side[1] - side[0] < length_ns // 2:
            continue
        try:
            out.append(calibration_window(imu, pieces, side, min(length_ns, side[1] - side[0]) / NS_PER_S,
                                           pose_t_ns))
        except RecoveryError:
            continue
    return out


def spread_std_s(offsets_s: list[float], curvature_std_s: float) -> float:
    """The reported offset sigma: the curvature's, or the sample std of the per-window offsets when larger.

    Using one window's offset for the whole recording errs by what separates windows, so the
    scatter is that of single estimates (``ddof=1``), not of their mean.
    """
    if len(offsets_s) < 2:
        return float(curvature_std_s)
    return float(max(curvature_std_s, np.std(offsets_s, ddof=1)))


def offsets_elsewhere(problem: Problem, inputs: Inputs, overlap: tuple[int, int], window: tuple[int, int],
                      refined: _OffsetRefinement, T: np.ndarray, config: RecoveryConfig) -> tuple[float, ...]:
    """The offset refined again on the :func:`offset_spread_windows` of ``window`` (one whose
    refinement fails is left out: the curvature's sigma then stands with fewer of them)."""
    out = []
    for win in offset_spread_windows(inputs.imu, inputs.pieces, overlap, window,
                                     shifted_stamps(inputs.poses, refined.offset_s)):
        try:
            out.append(refine_offset(problem, refined.offset_s, refined.std_s, win, inputs.calibration_noise, T,
                                      inputs.opts, config).offset_s)
        except (BiasgtError, ValueError, np.linalg.LinAlgError) as exc:
            log.info("clock offset on another window failed (%s)", exc)
    return tuple(out)


def _newton_offset(problem: Problem, coarse_s: float, window: tuple[int, int], noise: ImuNoise, T: np.ndarray,
                   opts: SolveOptions, rate: float, max_offset_s: float) -> _OffsetRefinement | None:
    """Newton steps on the clock offset from ``coarse_s`` (see :func:`refine_offset`); None when
    the factors give no slope (not 6-DoF absolute), a solve fails, or the steps do not settle."""
    o = replace(opts, offset_sensitivity=True)
    offset, init, table = coarse_s, None, []
    for _ in range(OFFSET_NEWTON_MAX_SOLVES):
        w = problem.window(offset, window[0], window[1], rate)
        if w is None:
            return None
        try:
            sol = solve_window(w[0], w[1], noise, T, o, init)
        except BiasgtError:
            return None
        slope, information = sol.extras.get("offset_slope"), sol.extras.get("offset_information", 0.0)
        if slope is None or not information > 0:
            return None
        step, std = -slope / information, 1.0 / math.sqrt(information)
        table.append({"offset_s": float(offset), "cost_per_kkf": float(sol.cost / len(w[1]) * 1000.0),
                      "newton_step_s": float(step)})
        init = WindowInit(gravity_unit=sol.gravity_unit, bias=np.median(sol.bias, axis=0))
        offset += step
        if abs(offset - coarse_s) > max_offset_s:
            return None
        if abs(step) <= OFFSET_NEWTON_MAX_SIGMAS * std:
            return _OffsetRefinement(float(offset), float(std), table, init, OffsetRefineMethod.NEWTON)
    return None



def coarse_offset_inputs(imu: ImuSeries, poses: PoseSeries, pieces: list[tuple[int, int]],
                          max_offset_s: float) -> tuple[ImuSeries, PoseSeries]:
    """The IMU and poses of the ``COARSE_OFFSET_SPAN_S`` with the most rotation (long recordings).

    The correlation over a whole hour costs ~3 s and ~200 MB of temporaries for an offset that
    ten minutes of motion already pin down to a fraction of a sample (it is refined in the graph).
    """
    if (imu.t_ns[-1] - imu.t_ns[0]) / NS_PER_S <= 1.5 * COARSE_OFFSET_SPAN_S:
        return imu, poses
    overlap = (max(int(imu.t_ns[0]), int(poses.t_ns[0])), min(int(imu.t_ns[-1]), int(poses.t_ns[-1])))
    try:
        a, b = calibration_window(imu, pieces, overlap, COARSE_OFFSET_SPAN_S)
    except RecoveryError:
        return imu, poses
    sel = (poses.t_ns >= a) & (poses.t_ns <= b)
    if sel.sum() < 100:
        return imu, poses
    margin = int((max_offset_s + 1.0) * NS_PER_S)
    i0, i1 = np.searchsorted(imu.t_ns, [a - margin, b + margin])
    return imu.take(slice(int(i0), int(i1))), poses.take(sel)
