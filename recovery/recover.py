"""``recover(sequence) -> RecoveryResult``: bias ground truth by joint optimisation.

Stages (each logged; all results and choices land in ``recovery.json``):

1. checks: an IMU and a pose stream with enough samples, increasing stamps, a
   time overlap; IMU gaps longer than ``max_imu_gap_s`` split the recording
   (or are refused, ``imu_gap_policy``).
2. calibration window: the ``calib_window_s`` with the most rotation.
3. clock offset: coarse |omega| (or |f|) correlation from
   :mod:`recovery.calibration_init`, refined to sub-millisecond at the minimum of
   the optimised graph cost (Newton steps on its analytic slope and curvature for
   6-DoF absolute streams, else a parabola through three offsets); std from its curvature.
4. extrinsic ``T_imu_pose``: known (calibration) or initialised in closed form
   and refined jointly in the graph (``E(0)`` Pose3 for 6-DoF sources, ``L(0)``
   lever arm for position trackers) on a decimated window.
5. noise: bias random walks by maximum evidence (:mod:`recovery.noise.evidence`); pose sigmas
   in closed form from the scatter of fused samples (else by evidence too).
6. the full solve, by overlapping segments (bounded memory), with robust
   pose factors, outlier rejection, gravity direction and bias marginals
   that include the uncertainty of the estimated clock offset and extrinsic
   (:mod:`recovery.solver.calibration_uncertainty`); stitched without seams
   (:mod:`recovery.solver.segments`).

Keyframes: for 6-DoF absolute streams every pose sample is used through
10-Hz keyframes that fuse the samples of their bin (:mod:`recovery.solver.fusion`,
linearised at the latest extrinsic / gravity / bias estimate); other streams use
one keyframe per sample. ``recovery.json`` also states the accuracy floor of the
noise at hand (:mod:`recovery.noise.bounds`).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.checks.run import reader_warnings
from pipeline.errors import BiasgtError, RecoveryError
from pipeline.types import NOISE_DENSITY_FIELDS, NOISE_FIELDS, NS_PER_S, PoseSeries, PoseSourceKind, Sequence
from recovery.config import (
    DEFAULT_POSE_SIGMAS,
    CalibrationSolve,
    ExtrinsicMode,
    IntrinsicsMode,
    NoiseEstimation,
    PoseFactorMode,
    PoseErrorMode,
    PoseSigmaMethod,
    RecoveryConfig,
    TimeOffsetMode,
)
from recovery import calibration_init as ci
from recovery.clock.coarse import coarse_offset, screen_rig
from recovery.degenerate import degenerate_error, degenerate_hint
from recovery.frame.extrinsic import CalibrationDifference, calibration_difference
from recovery.frame.check import check_frames
from recovery.solver.calibration_uncertainty import CalibrationCovariance
from recovery.solver.graph import solve_window
from recovery.solver.window import SolveOptions, WindowInit, WindowSolution
from recovery.noise.evidence import grid_edge_warnings, NoiseChoice, PoseErrorGrid, estimate_noise
from recovery.noise.from_data import data_noise_for
from recovery.solver.pose_error import PoseErrorModel
from recovery.outputs import RecoveryReport
from recovery.solver.preintegration import ImuNoise
from recovery.solver.segments import plan_segments, stitch
from recovery.records import CalibrationWindows, ClockOffset, ExtrinsicInit, FullSolve, GravityStage, Inputs, NoiseStage
from recovery.frame.gravity import solve_gravity, level_gravity_test
from recovery.clock.offset import refine_offset, offsets_elsewhere, spread_std_s
from recovery.problem import (COARSE_OFFSET_SPAN_S, bias_guess, calibration_window, chained_solution,
                              clean_poses, continue_from, imu_pieces, Problem, select_stream, shifted_stamps)
from recovery.result import (RecoveryResult, bias_function, pose_sigmas_from_fusion, build_result, agreement_z,
                             calibration_sources, write_recovery)

log = logging.getLogger(__name__)

__all__ = ["COARSE_OFFSET_SPAN_S", "IMU_FRAME_NAMES", "RecoveryResult", "agreement_z", "calibration_sources",
           "degenerate_hint", "recover", "write_recovery"]

IMU_FRAME_NAMES = ("imu", "imu0", "body", "base_link_imu")


# ----------------------------------------------------------------------------- extrinsic


def _rotation_excitation_deg(poses: PoseSeries) -> float:
    """Spread of the orientations: 2x the RMS angle from the mean orientation, degrees."""
    if poses.quat_wxyz is None or len(poses) < 3:
        return 0.0
    q = poses.quat_wxyz[:: max(1, len(poses) // 2000)]
    r = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]])
    mean = r.mean()
    ang = (mean.inv() * r).magnitude()
    return float(2.0 * np.degrees(np.sqrt(np.mean(ang**2))))


def _known_extrinsic(sequence: Sequence, poses: PoseSeries) -> np.ndarray | None:
    T = sequence.calibration.T_imu_frames.get(poses.frame)
    if T is not None:
        return np.asarray(T, dtype=float)
    if poses.frame.lower() in IMU_FRAME_NAMES or poses.source_kind == PoseSourceKind.GROUND_TRUTH:
        return np.eye(4)
    return None



# ----------------------------------------------------------------------------- main entry


def recover(sequence: Sequence, *, pose_stream: str | None = None,
            config: RecoveryConfig | None = None) -> RecoveryResult:
    """Recover the bias trajectory of ``sequence``'s IMU from one of its pose streams.

    Args:
        sequence: IMU + poses (+ calibration); anything :func:`pipeline.io.load_sequence` returns.
        pose_stream: Name of the pose stream; may be omitted when there is one.
        config: Options; defaults are meant to work without tuning.

    Returns:
        The bias per keyframe with marginal std, the optimised trajectory and the report.

    Raises:
        RecoveryError: The input cannot give a trustworthy result (one line saying why), e.g. the IMU and
            the pose stream disagree about the body frame (:mod:`recovery.frame.check`).
        AmbiguousInputError: The named pose stream does not exist (lists the streams).
        DataError: The sequence has no pose stream and no ground truth.
    """
    config = config or RecoveryConfig()
    result = _recover_with_intrinsics(sequence, pose_stream, config)
    check_frames(result, sequence.name, refuse=not config.keep_frame_disagreement)  # refused, not a bias
    return result


def _recover_with_intrinsics(sequence: Sequence, pose_stream: str | None, config: RecoveryConfig) -> RecoveryResult:
    try:
        if config.intrinsics is IntrinsicsMode.OFF or sequence.imu is None:
            return _recover(sequence, pose_stream=pose_stream, config=replace(config, intrinsics=IntrinsicsMode.OFF))
        from recovery.intrinsics.estimate import auto_intrinsics, recover_with_intrinsics

        plain = replace(config, intrinsics=IntrinsicsMode.OFF)
        first = _recover(sequence, pose_stream=pose_stream, config=plain)
        decision = auto_intrinsics(sequence, first) if config.intrinsics is IntrinsicsMode.AUTO else None
        if decision is not None and decision.mode is IntrinsicsMode.OFF:
            return decision.annotate(first)
        mode = config.intrinsics if decision is None else decision.mode
        result = recover_with_intrinsics(
            sequence, lambda seq: _recover(seq, pose_stream=pose_stream, config=plain),
            g_sensitivity=mode is IntrinsicsMode.WITH_G_SENSITIVITY, block_s=config.intrinsics_block_s, first=first,
            prior=config.intrinsics_prior())
        result = _record_intrinsics_mode(result, mode)
        return result if decision is None else decision.annotate(result)
    except (RuntimeError, ValueError) as exc:
        # GTSAM reports a singular (unobservable) problem as a bare RuntimeError, a factor graph
        # that a failed solve left inconsistent as a ValueError from its EliminationTree.
        error = degenerate_error(sequence, pose_stream, config, exc)
        if error is None:
            raise
        raise error from exc


def _record_intrinsics_mode(result: RecoveryResult, mode: IntrinsicsMode) -> RecoveryResult:
    """``result`` with ``recovery.json`` ``config.intrinsics`` the mode the intrinsics were estimated
    with (its solves ran with them off: the loop corrects the readings itself), so that a
    re-recovery from that config (cross-validation) estimates them too."""
    data = dict(result.report.data)
    data["config"] = {**dict(data.get("config") or {}), "intrinsics": mode.value}
    return replace(result, report=RecoveryReport.from_json(data))


def _checked_inputs(sequence: Sequence, pose_stream: str | None, config: RecoveryConfig) -> Inputs:
    """Stage 1: select and clean the pose stream, split the IMU at gaps, resolve the AUTO modes."""
    warnings: list[str] = reader_warnings(sequence.findings)  # skipped input lines, kept in recovery.json
    imu = sequence.imu
    if imu is None or len(imu) < 10:
        raise RecoveryError(f"sequence '{sequence.name}' has no IMU data (or fewer than 10 samples)")
    name, poses = select_stream(sequence, pose_stream)
    poses, placeholder_t_ns = clean_poses(poses, name, warnings)
    kind = poses.source_kind
    if len(poses) < config.min_poses:
        raise RecoveryError(f"pose stream '{name}' has {len(poses)} samples, fewer than min_poses={config.min_poses}")
    pieces = imu_pieces(imu, config, warnings)
    imu_calibration = sequence.calibration
    has_rot = poses.quat_wxyz is not None and kind != PoseSourceKind.POSITION_TRACKER
    if kind == PoseSourceKind.POSITION_TRACKER and poses.quat_wxyz is not None:
        poses = PoseSeries(poses.t_ns, poses.p_m, None, poses.frame, kind, poses.world_frame)
    rig = screen_rig(sequence.name, name, imu, poses, config)
    pose_mode = config.pose_factor_mode
    if pose_mode == PoseFactorMode.AUTO:
        pose_mode = PoseFactorMode.RELATIVE if kind == PoseSourceKind.VIO else PoseFactorMode.ABSOLUTE
    if pose_mode == PoseFactorMode.RELATIVE and not has_rot:
        raise RecoveryError("relative pose factors need orientations; this stream is position-only",
                            field="pose_factor_mode", hint="use absolute")
    # Total stations (compensator) and GNSS (ENU) frames are levelled; the gravity tilt is also
    # barely observable from positions alone: keep z-up there unless told otherwise.
    estimate_g = config.estimate_gravity
    if estimate_g is None:
        estimate_g = kind != PoseSourceKind.POSITION_TRACKER
    # motion-capture and ground-truth frames are level by convention, their tilt a hypothesis to test
    level_test = config.estimate_gravity is None and kind in (PoseSourceKind.MOCAP, PoseSourceKind.GROUND_TRUTH)
    default_sp, default_sr = DEFAULT_POSE_SIGMAS[kind]
    base_sp = config.position_sigma_m or default_sp
    base_sr = config.rotation_sigma_rad or default_sr
    imu_noise = ImuNoise(**{f: getattr(config, f) or getattr(imu_calibration, f) for f in NOISE_FIELDS},
                         integration_sigma=config.integration_sigma)
    data_noise = data_noise_for(sequence, {f: getattr(config, f) for f in NOISE_DENSITY_FIELDS})
    if data_noise is not None:  # no calibration gave the densities: the recording's rest does
        imu_noise = data_noise.applied_to(imu_noise)
    opts = SolveOptions(
        pose_mode=pose_mode, relative_horizon=config.relative_horizon, position_sigma_m=base_sp,
        rotation_sigma_rad=base_sr, robust_loss=config.robust_loss, robust_k=config.robust_k,
        outlier_threshold=config.outlier_threshold, estimate_gravity=estimate_g,
        gravity_mps2=config.gravity_mps2, max_iterations=config.max_iterations,
        relative_error_tol=config.relative_error_tol,
    )
    # the noise scales during calibration start at the middle of the candidate grid
    start_scale = 10.0 if config.noise_estimation == NoiseEstimation.EVIDENCE else 1.0
    calibration_noise = replace(imu_noise, gyro_random_walk=imu_noise.gyro_random_walk * start_scale,
                                acc_random_walk=imu_noise.acc_random_walk * start_scale)
    fuse = bool(config.pose_fusion and has_rot and pose_mode == PoseFactorMode.ABSOLUTE)
    return Inputs(imu, name, poses, kind, has_rot, pieces, pose_mode, bool(estimate_g), level_test, base_sp, base_sr,
                   imu_noise, calibration_noise, opts, fuse, tuple(warnings), data_noise, rig, placeholder_t_ns,
                   data_noise is None and all(f in sequence.calibration.defaulted() and getattr(config, f) is None
                                              for f in NOISE_DENSITY_FIELDS))


def _calibration_windows(inputs: Inputs, offset_s: float, config: RecoveryConfig) -> CalibrationWindows:
    """Stage 3 (see :class:`CalibrationWindows`).

    Raises:
        RecoveryError: The IMU and the pose stream do not overlap by ``min_poses`` samples.
    """
    imu = inputs.imu
    t_pose = shifted_stamps(inputs.poses, offset_s)
    overlap = (max(int(imu.t_ns[0]), int(t_pose[0])), min(int(imu.t_ns[-1]), int(t_pose[-1])))
    n_overlap = int(((t_pose > imu.t_ns[0]) & (t_pose < imu.t_ns[-1])).sum())
    if overlap[1] <= overlap[0] or n_overlap < config.min_poses:
        raise RecoveryError(
            f"no usable time overlap between the IMU and pose stream '{inputs.stream}' ({n_overlap} poses inside "
            "the IMU span)", hint="check that both come from the same recording and that the stamps use the same epoch")
    return CalibrationWindows(overlap, calibration_window(imu, inputs.pieces, overlap, config.calib_window_s,
                                                            t_pose))


def _extrinsic_init(sequence: Sequence, inputs: Inputs, offset_s: float, config: RecoveryConfig) -> ExtrinsicInit:
    """Stage 4: the calibration's extrinsic, or a closed-form rotation and lever arm from the data
    (with the calibration's value as a prior in PRIOR mode)."""
    imu, poses, warnings = inputs.imu, inputs.poses, []
    known_T = _known_extrinsic(sequence, poses)
    mode = config.extrinsic_mode
    if mode == ExtrinsicMode.AUTO:
        from_calibration = poses.frame in sequence.calibration.T_imu_frames
        mode = (ExtrinsicMode.PRIOR if from_calibration else
                ExtrinsicMode.KNOWN if known_T is not None else ExtrinsicMode.ESTIMATE)
    if mode == ExtrinsicMode.PRIOR and known_T is None:
        mode = ExtrinsicMode.ESTIMATE  # no calibration value to be a prior
    T = known_T.copy() if known_T is not None else np.eye(4)
    info: dict[str, Any] = {"mode": mode.value, "source": "calibration" if known_T is not None else "identity"}
    excitation = _rotation_excitation_deg(poses) if inputs.has_rot else float("nan")
    rot_observable, estimate_rotation, estimate_lever = True, False, False
    estimating = mode in (ExtrinsicMode.ESTIMATE, ExtrinsicMode.PRIOR)
    if estimating and not inputs.has_rot:
        estimate_lever = True
    elif estimating:
        try:
            rot = ci.estimate_extrinsic_rotation(imu, poses, offset_s)
            rot_observable = bool(rot.observable) and excitation >= config.min_rotation_excitation_deg
            if rot_observable:
                T[:3, :3] = rot.R_imu_pose
                info["rotation_init_residual"] = float(rot.residual_deg)
        except BiasgtError as exc:
            rot_observable = False
            warnings.append(f"extrinsic rotation initialisation failed: {exc}")
        if not rot_observable:
            warnings.append(
                f"extrinsic rotation unobservable (rotation excitation {excitation:.1f} deg): using the "
                f"{'calibration' if known_T is not None else 'identity'} rotation")
        else:
            try:
                lev = ci.estimate_lever_arm(imu, poses, offset_s, T[:3, :3])
                if lev.observable:
                    T[:3, 3] = lev.p_imu_pose_m
            except BiasgtError as exc:
                warnings.append(f"lever-arm initialisation failed: {exc}")
        estimate_rotation = estimate_lever = rot_observable
    prior = None
    if mode == ExtrinsicMode.PRIOR and (estimate_rotation or estimate_lever):
        prior = (known_T.copy(), np.array([math.radians(config.extrinsic_prior_rotation_deg)] * 3
                                          + [config.extrinsic_prior_translation_m] * 3))
        info["prior_sigma"] = {"rotation_deg": float(config.extrinsic_prior_rotation_deg),
                               "translation_m": float(config.extrinsic_prior_translation_m)}
    opts = replace(inputs.opts, estimate_extrinsic=estimate_rotation or estimate_lever, marginal_extras=True,
                   extrinsic_prior=prior)
    return ExtrinsicInit(mode, known_T, T, info, excitation, bool(rot_observable) if inputs.has_rot else None,
                          opts, estimate_lever, tuple(warnings))


def _solve_extrinsic(problem: Problem, inputs: Inputs, calib_window: tuple[int, int], T: np.ndarray,
                     opts: SolveOptions, offset_s: float, config: RecoveryConfig) -> WindowSolution | None:
    """The joint extrinsic solve on the calibration window; fusion is then linearised at its
    extrinsic, gravity and median bias. None when the window holds too few poses."""
    rate = config.calibration_rate_hz(CalibrationSolve.EXTRINSIC, problem.fuse)
    w = problem.window(offset_s, calib_window[0], calib_window[1], rate)
    if w is None:
        return None
    sol = solve_window(w[0], w[1], inputs.calibration_noise, T, opts)
    problem.set_linearisation(T_imu_pose=sol.T_imu_pose, gravity_unit=sol.gravity_unit,
                              bias=np.median(sol.bias, axis=0))
    return sol


def _refined_offset(problem: Problem, inputs: Inputs, coarse: ClockOffset, windows: CalibrationWindows,
                    T: np.ndarray, config: RecoveryConfig) -> ClockOffset:
    """Stage 5: the offset at the vertex of the graph cost (ESTIMATE), else ``coarse``."""
    if coarse.mode != TimeOffsetMode.ESTIMATE:
        return coarse
    try:
        off_win = windows.calib_window
        if config.offset_window_s(problem.fuse) < config.calib_window_s:
            off_win = calibration_window(inputs.imu, inputs.pieces, off_win, config.offset_window_s(problem.fuse),
                                          shifted_stamps(inputs.poses, coarse.offset_s))
        refined = refine_offset(problem, coarse.offset_s, coarse.std_s, off_win,
                                 inputs.calibration_noise, T, inputs.opts, config)
    except (BiasgtError, ValueError, np.linalg.LinAlgError) as exc:
        return replace(coarse, warnings=coarse.warnings + (
            f"clock offset refinement failed ({exc}); using the coarse estimate",))
    if refined.last is not None and problem.bias is None:
        problem.set_linearisation(gravity_unit=refined.last.gravity_unit, bias=refined.last.bias)
    others = offsets_elsewhere(problem, inputs, windows.overlap, off_win, refined, T, config)
    return replace(coarse, offset_s=refined.offset_s, std_s=spread_std_s([refined.offset_s, *others], refined.std_s),
                   refine_method=refined.method, search=tuple(refined.table),
                   curvature_std_s=refined.std_s, window_offsets_s=(refined.offset_s, *others))


def _extrinsic_info(init: ExtrinsicInit, sol: WindowSolution | None) -> dict[str, Any]:
    """``recovery.json`` ``extrinsic`` after the joint solve: its 1-sigma and where T came from."""
    info = dict(init.info)
    if sol is not None:
        if "extrinsic_cov" in sol.extras:
            c = np.sqrt(np.diag(sol.extras["extrinsic_cov"]))
            info["rotation_std_deg"] = [float(np.degrees(x)) for x in c[:3]]
            info["translation_std_m"] = [float(x) for x in c[3:]]
        if "lever_arm_cov" in sol.extras:
            info["translation_std_m"] = [float(x) for x in np.sqrt(np.diag(sol.extras["lever_arm_cov"]))]
        info["source"] = "estimated"
    elif init.mode in (ExtrinsicMode.ESTIMATE, ExtrinsicMode.PRIOR) and init.rotation_observable is False:
        info["source"] = "fallback_" + info["source"]
    return info


def _difference_from_calibration(init: ExtrinsicInit, ext_sol: WindowSolution | None, gravity: "GravityStage",
                                 config: RecoveryConfig) -> CalibrationDifference | None:
    """The estimated extrinsic against the calibration's prior (PRIOR mode, when estimated)."""
    if init.mode != ExtrinsicMode.PRIOR or init.known is None or ext_sol is None:
        return None
    lever_cov = (gravity.solution.extras.get("lever_arm_cov") if gravity.solution is not None
                 and gravity.extrinsic_info.get("lever_arm_refined_window_s") else ext_sol.extras.get("lever_arm_cov"))
    return calibration_difference(init.known, gravity.T_imu_pose, ext_sol.extras.get("extrinsic_cov"), lever_cov,
                                  config.extrinsic_max_sigmas)


def _noise(problem: Problem, inputs: Inputs, windows: CalibrationWindows, offset_s: float, T: np.ndarray,
           config: RecoveryConfig) -> NoiseStage:
    """Stage 6: bias random walks and pose sigmas by maximum evidence (EVIDENCE), else as given."""
    calib = windows.calib_window
    if problem.fuse and problem.bias is None:
        # fusion moves samples with the IMU: linearise it at a first bias estimate (a gyro-bias
        # error is absorbed by the fit, an acc-bias error of 0.5 m/s^2 would add ~1e-4 m of scatter)
        rate = config.calibration_rate_hz(CalibrationSolve.NOISE, problem.fuse)
        w = problem.window(offset_s, calib[0], calib[1], rate)
        if w is not None:
            sol0 = solve_window(w[0], w[1], inputs.calibration_noise, T,
                                replace(inputs.opts, reject_outliers=False, residuals=False))
            problem.set_linearisation(gravity_unit=sol0.gravity_unit, bias=bias_function(sol0))
    if config.noise_estimation != NoiseEstimation.EVIDENCE:
        choice = NoiseChoice(inputs.imu_noise, inputs.position_sigma_m, inputs.rotation_sigma_rad,
                             pose_error=_fixed_pose_error(inputs, config))
        return NoiseStage(choice, None, None, ())
    rate = config.calibration_rate_hz(CalibrationSolve.NOISE, problem.fuse)
    noise_win, init, chain = calib, None, None
    down = np.array([0.0, 0.0, -1.0])
    if not inputs.has_rot and config.position_only_window_s > config.calib_window_s:
        # position-only: the gyro random walk needs minutes to show (see position_only_window_s)
        noise_win = calibration_window(inputs.imu, inputs.pieces, windows.overlap, config.position_only_window_s,
                                        shifted_stamps(inputs.poses, offset_s))
        if noise_win != calib:
            # seeded by the calibration window's solve (it sees the same data as the offset search did)
            wc = problem.window(offset_s, calib[0], calib[1], rate)
            seed = None if wc is None else solve_window(
                wc[0], wc[1], inputs.calibration_noise, T,
                replace(inputs.opts, compute_marginals=False, marginal_extras=False, reject_outliers=False),
                WindowInit(gravity_unit=down))
            chain = chained_solution(problem, offset_s, noise_win, rate, inputs.calibration_noise, T, inputs.opts,
                                      down, config.calib_window_s, config.calib_window_s / 6, seed)
    w = problem.window(offset_s, noise_win[0], noise_win[1], rate)
    if w is None:
        raise RecoveryError("too few poses in the calibration window to estimate the noise",
                            hint="set noise_estimation: fixed and give the random walks")
    if chain is not None:
        init = continue_from(chain, w, down, (problem.imu.t_ns, problem.imu_6))
    elif problem.bias is not None:
        # start (and preintegrate) at the calibration solves' gravity and bias: fewer LM iterations
        bias = problem.bias(w[1].t_ns) if callable(problem.bias) else problem.bias
        init = WindowInit(gravity_unit=problem.gravity_world / np.linalg.norm(problem.gravity_world), bias=bias)
    sp, sr, pose_method = pose_sigmas_from_fusion(w[1], inputs.position_sigma_m, inputs.rotation_sigma_rad, config)
    searched_error = (PoseErrorGrid(tuple(config.pose_error_sigma_scales), tuple(config.pose_error_taus_s))
                      if config.pose_error is PoseErrorMode.AUTO and _correlated_error_applies(inputs) else None)
    choice = estimate_noise(w[0], w[1], inputs.imu_noise, sp, sr, T,
                            replace(inputs.opts, pose_error=_fixed_pose_error(inputs, config)), config.random_walk_scales,
                            estimate_pose=config.position_sigma_m is None and pose_method is PoseSigmaMethod.EVIDENCE,
                            pose_scales=config.pose_sigma_scales, init=init, pose_error=searched_error,
                            density_scales=density_grid(inputs, config))
    if pose_method is not PoseSigmaMethod.EVIDENCE:
        choice.pose_scale = sp / inputs.position_sigma_m
        choice.pose_method = pose_method
    if searched_error is None:
        choice.pose_error = _fixed_pose_error(inputs, config)
    window_s = float((noise_win[1] - noise_win[0]) / NS_PER_S)
    return NoiseStage(choice, chain, window_s, grid_edge_warnings(choice, inputs.kind, config))


def _with_pose_noise(opts: SolveOptions, choice: NoiseChoice) -> SolveOptions:
    """``opts`` with the chosen pose noise, its correlated error included. The extrinsic is solved
    again with it once the evidence finds a correlated error: white, the error's slow part pulls the
    extrinsic by many of its (then too small) sigmas, and the full solve holds that extrinsic fixed."""
    return replace(opts, pose_error=choice.pose_error, position_sigma_m=choice.position_sigma_m,
                   rotation_sigma_rad=choice.rotation_sigma_rad)


def density_grid(inputs: Inputs, config: RecoveryConfig) -> list[float] | None:
    """The evidence's candidate factors of the white-noise densities (None: not searched).

    A calibration's, an override's or a rest's densities are a floor: the evidence may raise them (a
    vibrating platform) but not lower them, because a lower density shrinks every sigma on evidence
    that a correlated pose error confounds with the IMU's own noise. Defaulted densities may go either way.
    """
    grid = [s for s in config.noise_density_scales if inputs.densities_defaulted or s >= 1.0]
    return grid if len(grid) > 1 else None


def _correlated_error_applies(inputs: Inputs) -> bool:
    """Whether the stream can carry a time-correlated error model (6-DoF absolute pose factors)."""
    return inputs.has_rot and inputs.pose_mode == PoseFactorMode.ABSOLUTE


def _fixed_pose_error(inputs: Inputs, config: RecoveryConfig) -> PoseErrorModel | None:
    """The configured time-correlated pose error (FIXED, 6-DoF absolute streams), else None."""
    if config.pose_error is not PoseErrorMode.FIXED or not _correlated_error_applies(inputs):
        return None
    model = PoseErrorModel(config.pose_error_rotation_sigma_rad, config.pose_error_rotation_tau_s,
                           config.pose_error_position_sigma_m, config.pose_error_position_tau_s)
    return model if model.active else None



def _calibration_covariance(offset: ClockOffset, ext_sol: WindowSolution | None,
                            gravity: GravityStage) -> CalibrationCovariance | None:
    """Covariance of the estimated calibration the full solve holds fixed (None: all of it given)."""
    lever = gravity.solution.extras.get("lever_arm_cov") if gravity.solution is not None else None
    return CalibrationCovariance.assemble(
        extrinsic_cov=None if ext_sol is None else ext_sol.extras.get("extrinsic_cov"),
        lever_arm_cov=lever, R_imu_pose=gravity.T_imu_pose[:3, :3],
        offset_std_s=offset.std_s if offset.mode == TimeOffsetMode.ESTIMATE and offset.refine_method is not None else None)


def _full_solve(problem: Problem, inputs: Inputs, offset_s: float, gravity: GravityStage, noise: NoiseStage,
                config: RecoveryConfig, calibration: CalibrationCovariance | None = None) -> FullSolve:
    """Stage 8: every keyframe, segment by segment (gravity: a variable per segment with the gravity
    solve as prior; the uncertainty of ``calibration`` propagated into the bias marginals). A single
    segment that estimates gravity itself in a level frame (``level_test``) is solved again level
    when its tilt does not stand out."""
    choice, gsol = noise.choice, gravity.solution
    info: dict[str, Any] = {}
    full_opts = replace(inputs.opts, position_sigma_m=choice.position_sigma_m, pose_error=choice.pose_error,
                        rotation_sigma_rad=choice.rotation_sigma_rad, compute_marginals=config.compute_marginals,
                        estimate_gravity=False, marginal_rate_hz=config.marginal_rate_hz,
                        calibration_cov=calibration)
    if gsol is not None and gravity.estimated and "gravity_cov_tangent" in gsol.extras:
        # Gravity stays a variable in every segment, with the calibration solve's estimate as a
        # prior: its uncertainty then reaches the bias marginals (held fixed, a ~1 mrad tilt
        # error leaked into the x/y accelerometer bias unreported: acc NEES ~2 at 60 s, ~1.2 now).
        full_opts = replace(full_opts, estimate_gravity=True, gravity_prior_cov=gsol.extras["gravity_cov_tangent"])
        info["per_segment"] = True
    elif gravity.estimated and gsol is None:
        full_opts = replace(full_opts, estimate_gravity=True, marginal_extras=True)  # the single segment estimates it
        info["per_segment"] = True
    out = _segments(problem, inputs, offset_s, gravity, noise, config, full_opts,
                    FullSolve([], [], gravity.unit, info, [], [], [], calibration))
    flat = out.flat
    if gravity.estimated and gsol is None and len(flat) == 1:
        if "gravity_cov_tangent" in flat[0].extras:
            info["tilt_std_rad"] = float(np.sqrt(np.trace(flat[0].extras["gravity_cov_tangent"]) / 2))
            if inputs.level_test:
                info["level_test"] = level_gravity_test(flat[0].gravity_unit, info["tilt_std_rad"], config.gravity_tilt_sigmas,
                                                 config.gravity_level_tolerance_deg)
                if info["level_test"]["level"]:  # solved again in the level frame
                    level = replace(gravity, unit=np.array([0.0, 0.0, -1.0]), estimated=False)
                    info.pop("per_segment", None)
                    info.pop("segment_max_tilt_change_rad", None)
                    info["estimated"] = False
                    return _segments(problem, inputs, offset_s, level, noise, config,
                                     replace(full_opts, estimate_gravity=False, marginal_extras=False),
                                     FullSolve([], [], level.unit, info, [], [], [], calibration))
        return replace(out, gravity_unit=flat[0].gravity_unit)
    return out


def _segments(problem: Problem, inputs: Inputs, offset_s: float, gravity: GravityStage, noise: NoiseStage,
              config: RecoveryConfig, full_opts: SolveOptions, out: FullSolve) -> FullSolve:
    """The full solve's segments, piece by piece, into ``out`` (see :func:`_full_solve`)."""
    t_pose = shifted_stamps(inputs.poses, offset_s)
    choice, gsol, gwin, T = noise.choice, gravity.solution, gravity.window, gravity.T_imu_pose
    for a, b in inputs.pieces:
        a2, b2 = max(a, int(t_pose[0])), min(b, int(t_pose[-1]))
        if b2 <= a2:
            continue
        piece_solutions: list[WindowSolution] = []
        for s_ns, e_ns in plan_segments(a2, b2, gravity.segment_s, gravity.segment_overlap_s):
            w = problem.window(offset_s, s_ns, e_ns, config.keyframe_rate_hz)
            if w is None or len(w[1]) < 3:
                continue
            prev = piece_solutions[-1] if piece_solutions else None
            guess = bias_guess(w[1].t_ns, gsol, prev)
            if guess is None and problem.bias is not None:  # the calibration solves' bias, not zero
                guess = (problem.bias(w[1].t_ns) if callable(problem.bias)
                         else np.tile(np.asarray(problem.bias, dtype=float), (len(w[1]), 1)))
            init = WindowInit(gravity_unit=gravity.unit, bias=guess)
            if not inputs.has_rot and (prev is not None or noise.chain is not None):
                init = continue_from(prev if prev is not None else noise.chain, w, gravity.unit,
                                      (problem.imu.t_ns, problem.imu_6))
            seg_opts = full_opts
            if full_opts.gravity_prior_cov is not None:
                # the calibration solve saw this segment's data too: keep only the information
                # of the rest of its window in the prior (none left: gravity from this segment alone)
                seen = max(0, min(e_ns, gwin[1]) - max(s_ns, gwin[0])) / max(gwin[1] - gwin[0], 1)
                seg_opts = replace(full_opts, gravity_prior_cov=None if seen > 0.9
                                   else np.asarray(full_opts.gravity_prior_cov) / (1.0 - seen))
            piece_solutions.append(solve_window(w[0], w[1], choice.imu, T, seg_opts, init))
            if w[1].rejected_t_ns is not None:
                out.fusion_rejected.append(w[1].rejected_t_ns)
            if w[1].count is not None:
                out.fusion_counts.append(w[1].count)
                out.fusion_within.append(w[1].within_bin())
        if piece_solutions:
            out.solutions.append(piece_solutions)
    if not out.solutions:
        raise RecoveryError(f"too few poses of '{inputs.stream}' inside the IMU span to build a graph")
    out.stitched.extend(stitch(ps) for ps in out.solutions)
    if out.info.get("per_segment"):
        cosang = [float(np.clip(np.dot(s.gravity_unit, gravity.unit), -1.0, 1.0)) for s in out.flat]
        out.info["segment_max_tilt_change_rad"] = float(np.max(np.arccos(cosang)))
    return out


#: The rounds of a recovery that :func:`_rounds_bar` counts (extrinsic, clock offset, noise, gravity, solve).
RECOVERY_ROUNDS = 5


def _rounds_bar(name: str):
    """Progress over the recovery's rounds (rate and ETA; a log line every 30 s off a terminal)."""
    from pipeline.progress import progress

    bar = progress(RECOVERY_ROUNDS, desc=f"recover {name}", unit="round", logger=log)
    bar.set_postfix_str("extrinsic", refresh=False)
    return bar


def _next_round(bar, what: str) -> None:
    bar.update(1)
    bar.set_postfix_str(what, refresh=False)


def _recover(sequence: Sequence, *, pose_stream: str | None, config: RecoveryConfig) -> RecoveryResult:
    """The stages in order (each returns a frozen record); ``problem`` carries the fusion's
    linearisation point (extrinsic, gravity, bias), which the calibration solves update."""
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    inputs = _checked_inputs(sequence, pose_stream, config)
    problem = Problem(inputs.imu, inputs.poses, inputs.pieces, fuse=inputs.fuse, gravity_mps2=config.gravity_mps2)
    bar = _rounds_bar(sequence.name)

    t0 = time.perf_counter()
    coarse = coarse_offset(inputs, config)
    timings["offset_coarse_s"] = time.perf_counter() - t0
    windows = _calibration_windows(inputs, coarse.offset_s, config)

    ext_init = _extrinsic_init(sequence, inputs, coarse.offset_s, config)
    problem.set_linearisation(T_imu_pose=ext_init.T_imu_pose)
    t0 = time.perf_counter()
    T, ext_sol = ext_init.T_imu_pose, None
    if ext_init.opts.estimate_extrinsic:
        ext_sol = _solve_extrinsic(problem, inputs, windows.calib_window, T, ext_init.opts, coarse.offset_s, config)
        T = ext_sol.T_imu_pose if ext_sol is not None else T
    timings["extrinsic_s"] = time.perf_counter() - t0
    _next_round(bar, "clock offset")

    t0 = time.perf_counter()
    offset = _refined_offset(problem, inputs, coarse, windows, T, config)
    if offset.mode == TimeOffsetMode.ESTIMATE and ext_init.opts.estimate_extrinsic:
        ext_sol = _solve_extrinsic(problem, inputs, windows.calib_window, T, ext_init.opts, offset.offset_s, config)
        T = ext_sol.T_imu_pose if ext_sol is not None else T
    timings["offset_refine_s"] = time.perf_counter() - t0
    _next_round(bar, "noise by evidence")

    t0 = time.perf_counter()
    noise = _noise(problem, inputs, windows, offset.offset_s, T, config)
    if noise.choice.pose_error is not None and ext_init.opts.estimate_extrinsic:
        ext_sol = _solve_extrinsic(problem, inputs, windows.calib_window, T,
                                   _with_pose_noise(ext_init.opts, noise.choice), offset.offset_s, config) or ext_sol
        T = ext_sol.T_imu_pose if ext_sol is not None else T
    timings["noise_s"] = time.perf_counter() - t0
    _next_round(bar, "gravity")

    t0 = time.perf_counter()
    gravity = solve_gravity(problem, inputs, offset.offset_s, T, ext_sol, ext_init.estimate_lever, noise.choice, config,
                       ext_init.opts.extrinsic_prior)
    timings["gravity_s"] = time.perf_counter() - t0
    _next_round(bar, "full solve")

    t0 = time.perf_counter()
    calibration = _calibration_covariance(offset, ext_sol, gravity)
    full = _full_solve(problem, inputs, offset.offset_s, gravity, noise, config, calibration)
    timings["solve_s"] = time.perf_counter() - t0
    _next_round(bar, "done")
    bar.close()

    extrinsic_info = {**_extrinsic_info(ext_init, ext_sol), **gravity.extrinsic_info}
    refine_warnings = offset.warnings[len(coarse.warnings):]
    warnings = [*inputs.warnings, *coarse.warnings, *ext_init.warnings, *refine_warnings, *noise.warnings]
    difference = _difference_from_calibration(ext_init, ext_sol, gravity, config)
    if difference is not None:
        extrinsic_info["difference_from_calibration"] = difference.to_dict()
        if difference.exceeds:
            warnings.append(difference.sentence())
    return build_result(sequence, config, inputs, offset, windows.calib_window, ext_init, extrinsic_info, noise, gravity,
                   full, warnings, timings, t_start)
