"""The verdict of a candidate bias against its baselines, and the limitations that make a PASS a WARN.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass

import numpy as np

from pipeline.types import (Sequence,
                            Severity)
from recovery.outputs import RecoveryOutputs
from validation.config import ValidationConfig
from validation.metrics import SourceMetrics
from validation.sources import BiasSourceKind
from validation.outputs import Verdict

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- verdict


def sigma_window_errors(std: np.ndarray, R_world_imu: np.ndarray, window_s: float,
                        gravity_mps2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """End-point errors that a bias sigma explains, per window (first-order propagation).

    A constant acc bias error ``da`` (sigma ``s_a`` per axis) moves the end point by
    ``0.5 da T^2``; a gyro bias error ``dw`` tilts the attitude by ``R dw t``, which leaks
    gravity into the horizontal acceleration and moves the end point by ``|(R dw) x g| T^3 / 6``;
    it also rotates the end attitude by ``|dw| T``. With ``S = R diag(s_g^2) R^T`` (world frame),
    ``E|(R dw) x g|^2 = |g|^2 (tr S - g_hat^T S g_hat)``, so

        sigma_pos^2 = (T^2 / 2)^2 sum(s_a^2) + (|g| T^3 / 6)^2 (tr S - g_hat^T S g_hat)
        sigma_rot   = T sqrt(sum(s_g^2))

    Args:
        std: Bias sigma at each window's start, [W, 6] (rad/s, m/s^2).
        R_world_imu: Reference attitude at each window's start, [W, 3, 3].
        window_s: Window length T (s).
        gravity_mps2: Gravity in the world frame, [3].

    Returns:
        ``(sigma_pos_m [W], sigma_rot_deg [W])``.
    """
    T = float(window_s)
    g = np.asarray(gravity_mps2, dtype=float)
    g_norm = float(np.linalg.norm(g))
    g_hat = g / g_norm
    var_g, var_a = std[:, :3] ** 2, std[:, 3:] ** 2
    S = np.einsum("wij,wj,wkj->wik", R_world_imu, var_g, R_world_imu)
    tilt_var = np.trace(S, axis1=1, axis2=2) - np.einsum("i,wij,j->w", g_hat, S, g_hat)
    sigma_pos = np.sqrt((0.5 * T**2) ** 2 * var_a.sum(axis=1) + (g_norm * T**3 / 6.0) ** 2 * np.maximum(tilt_var, 0))
    sigma_rot = np.degrees(T * np.sqrt(var_g.sum(axis=1)))
    return sigma_pos, sigma_rot


def _paired_p_value(cand: np.ndarray, base: np.ndarray, stride: int) -> float:
    """One-sided p-value of "the candidate's window errors are larger" (paired t-test).

    Windows that share samples are correlated: only every ``stride``-th window enters (with 50 %
    overlap, the non-overlapping ones).
    """
    from scipy.stats import ttest_rel

    d = cand[::stride] - base[::stride]
    if len(d) < 3 or not np.any(d):
        return 1.0
    if np.ptp(d) <= 1e-12 * np.max(np.abs(d)):  # the same difference in every window: no spread to test
        return 0.0 if d[0] > 0 else 1.0
    return float(ttest_rel(cand[::stride], base[::stride], alternative="greater").pvalue)


def _compare(label: str, unit: str, cand: float, base: float, allowed: tuple[float, float], p_value: float,
             config: ValidationConfig) -> tuple[str | None, str | None]:
    """(fail reason, warn reason) of one metric; ``allowed``: (equal up to, within the margin up to)."""
    if cand <= allowed[0]:
        return None, None
    rel = (cand / base - 1.0) * 100.0 if base > 0 else float("inf")
    text = f"{label} {cand:.4g} {unit} is {rel:+.1f} % against {base:.4g} {unit}"
    margin = f"the {config.margin:.0%} margin"
    if cand <= allowed[1]:
        return None, f"{text}: worse beyond its own sigma, within {margin}"
    if p_value < config.significance:
        return f"{text}: worse by more than {margin} and its own sigma (paired test p = {p_value:.2g})", None
    return None, (f"{text}: worse by more than {margin}, but not significantly over these windows "
                  f"(paired test p = {p_value:.2g} >= {config.significance:g})")


def _worse_than_zero(metrics: Mapping[str, SourceMetrics], candidate: str, config: ValidationConfig) -> list[str]:
    """FAIL reasons of a candidate that integrates worse than the zero bias (beyond the ties), whatever its sigma."""
    cand, fails = metrics[candidate], []
    for zero in (m for name, m in metrics.items() if name != candidate and m.kind is BiasSourceKind.ZERO):
        for label, unit, c, z, tie in (("PRMSE", "m", cand.prmse_m, zero.prmse_m, config.tie_prmse_m),
                                       ("ROE", "deg", cand.roe_deg, zero.roe_deg, config.tie_roe_deg)):
            if c > z + tie:
                fails.append(f"'{candidate}' {label} {c:.4g} {unit} is worse than the zero bias's {z:.4g} {unit}: "
                             "subtracting it makes the integration worse than no bias estimate at all")
    return fails


def _too_uncertain(cand: SourceMetrics, base: SourceMetrics, zero: SourceMetrics | None,
                   config: ValidationConfig) -> list[str]:
    """WARN reasons where the candidate's own sigma exceeds ``base``'s error: it excuses the candidate's
    error but leaves it too uncertain to be useful beside that baseline (an unobservable position-only
    recovery, say), when the candidate is also materially worse: by more than ``margin`` of what the
    baseline gains over the ``zero`` bias (a near-perfect baseline, a simulator's truth, makes any
    relative margin moot; without a zero row any excess counts)."""
    k, out = config.sigma_k, []
    for label, unit, s, c, b, tie, z in (
            ("PRMSE", "m", k * cand.sigma_prmse_m, cand.prmse_m, base.prmse_m, config.tie_prmse_m,
             None if zero is None else zero.prmse_m),
            ("ROE", "deg", k * cand.sigma_roe_deg, cand.roe_deg, base.roe_deg, config.tie_roe_deg,
             None if zero is None else zero.roe_deg)):
        material = z is None or c - b > config.margin * max(z - b, 0.0)
        if s > b + tie and c > b + tie and material:
            out.append(f"its own {k:g} sigma ({s:.4g} {unit} of {label}) exceed that baseline's error "
                       f"({b:.4g} {unit}): too uncertain to tell it from the baseline")
    return out


def decide_verdict(
    metrics: Mapping[str, SourceMetrics],
    candidate: str,
    *,
    dropped_fraction: float,
    config: ValidationConfig = ValidationConfig(),
    limitations: Sequence_[str] = (),
    fails: Sequence_[str] = (),
) -> tuple[Verdict, list[str]]:
    """PASS / WARN / FAIL of ``candidate`` against the baselines (rules in the module docstring).

    Baselines: every CONSTANT_FIRST_WINDOW and DATASET source other than the candidate. Per
    metric, the candidate counts as equal up to what its own sigma explains
    (``sqrt(base^2 + (k sigma_prmse)^2)`` for PRMSE, ``base + k sigma_roe`` for ROE, plus the
    tie); as worse within the margin up to ``(1 + margin)`` times the baseline's part; beyond
    that it FAILs only when a paired one-sided t-test over independent windows says so at
    ``significance``.

    Args:
        metrics: Per source.
        candidate: The source judged.
        dropped_fraction: Fraction of candidate windows dropped.
        config: Thresholds.
        limitations: What limits the candidate's use though the numbers pass (e.g. a noise
            estimate at its search bound); each one makes a PASS a WARN, listed first.
        fails: Reasons already found for a FAIL (e.g. the held-out rule), listed first.

    Returns:
        ``(verdict, reasons)``; reasons are plain sentences (empty for a clean PASS).
    """
    cand = metrics[candidate]
    fails = list(fails)
    warns: list[str] = list(limitations)
    stride = max(1, int(round(1.0 / (1.0 - config.overlap))))
    k = config.sigma_k
    baselines = [m for name, m in metrics.items() if name != candidate
                 and m.kind in (BiasSourceKind.CONSTANT_FIRST_WINDOW, BiasSourceKind.DATASET)]
    zero = next((m for name, m in metrics.items() if name != candidate and m.kind is BiasSourceKind.ZERO), None)
    for base in baselines:
        where = f"'{candidate}' against '{base.name}' ({base.kind.value})"
        sigma_pos, sigma_rot = k * cand.sigma_prmse_m, k * cand.sigma_roe_deg
        warns += [f"{where}: {w}" for w in _too_uncertain(cand, base, zero, config)]
        prmse_allowed = tuple(float(np.hypot(base.prmse_m * f, sigma_pos)) + config.tie_prmse_m
                              for f in (1.0, 1.0 + config.margin))
        roe_allowed = tuple(base.roe_deg * f + sigma_rot + config.tie_roe_deg for f in (1.0, 1.0 + config.margin))
        for fail, warn in (
            _compare("PRMSE", "m", cand.prmse_m, base.prmse_m, prmse_allowed,
                     _paired_p_value(cand.pos_err_m**2, base.pos_err_m**2, stride), config),
            _compare("ROE", "deg", cand.roe_deg, base.roe_deg, roe_allowed,
                     _paired_p_value(cand.rot_err_deg, base.rot_err_deg, stride), config),
        ):
            fails += [f"{where}: {fail}"] if fail else []
            warns += [f"{where}: {warn}"] if warn else []
    fails += _worse_than_zero(metrics, candidate, config)
    if cand.windows:
        frac = float(np.mean(cand.flagged))
        if frac > config.warn_flagged_fraction:
            warns.append(f"{int(cand.flagged.sum())} of {cand.windows} windows ({frac:.1%}) of '{candidate}' are "
                         f"flagged as outliers (more than {config.warn_flagged_fraction:.0%})")
    if dropped_fraction > config.warn_dropped_fraction:
        warns.append(f"{dropped_fraction:.1%} of the windows were dropped (more than "
                     f"{config.warn_dropped_fraction:.0%}): the validation covers only part of the sequence")
    if not baselines:
        warns.append(f"no baseline (constant or dataset bias) to compare '{candidate}' with")
    if fails:
        return Verdict.FAIL, fails + warns
    if warns:
        return Verdict.WARN, warns
    return Verdict.PASS, []


@dataclass(frozen=True)
class Limitation:
    """Something that limits what a bias is good for, and what to do about it.

    Attributes:
        text: What was found (a reason of the verdict).
        next_step: What the user can do next.
    """

    text: str
    next_step: str


def recovery_limitations(recovery: RecoveryOutputs, config: ValidationConfig = ValidationConfig()) -> list[Limitation]:
    """What limits a recovered bias though its integration errors may pass, from ``recovery.json``.

    Each item makes a PASS a WARN (:func:`decide_verdict`): a random walk chosen at the upper edge
    of the evidence search (the true value may lie beyond it), one far from the calibration's
    (``max_random_walk_scale``: unmodelled errors such as scale or misalignment that the bias
    absorbs, or a wrong datasheet), and an extrinsic rotation that could not be estimated.
    """
    report = recovery.report
    noise = report.get("noise") if isinstance(report.get("noise"), Mapping) else {}
    grid = (report.get("config") or {}).get("random_walk_scales") or []
    out: list[Limitation] = []
    noise_step = ("check the IMU noise values of the calibration (sensor.yaml: random walks) against the "
                  "datasheet, and the pose stream for artefacts (biasgt report's residual plot)")
    for axis in ("gyro", "acc"):
        scale = noise.get(f"{axis}_random_walk_scale")
        if not isinstance(scale, (int, float)) or not math.isfinite(scale):
            continue
        # Only the upper edge limits the bias: a walk that wants to be looser than the search allows
        # means the bias absorbs other errors. At the lower edge (a nearly constant bias, e.g. the
        # semi-real sequences' EuRoC bias) the recovered bias is only a little less smooth than it
        # could be, and its sigma errs on the safe side.
        if noise.get("method") == "evidence" and grid and scale >= max(grid):
            out.append(Limitation(
                f"the {axis} bias random walk was chosen at the upper edge of its search ({scale:g}x the "
                f"calibration; searched {min(grid):g}x-{max(grid):g}x): the bias may absorb other errors",
                noise_step + "; widen recovery.random_walk_scales only if the calibration is known to be wrong"))
        elif not 1.0 / config.max_random_walk_scale <= scale <= config.max_random_walk_scale:
            out.append(Limitation(
                f"the {axis} bias random walk is {scale:.3g}x the calibration's: the bias likely absorbs "
                "unmodelled errors (scale, misalignment, pose artefacts) or the datasheet is off", noise_step))
    diff = (report.get("extrinsic") or {}).get("difference_from_calibration") or {}
    if diff.get("exceeds"):
        out.append(Limitation(
            f"the extrinsic T_imu_pose estimated from the data differs from the calibration's by "
            f"{diff['rotation_deg']:.2f} deg and {100 * diff['translation_m']:.1f} cm, beyond "
            f"{diff['max_sigmas']:g} of its sigmas: the calibration file is off (or the tracked body moved); the "
            "bias is the one consistent with the estimate",
            "if the tracked body was not moved, put the estimate (recovery.json T_imu_pose) into the calibration "
            "file; else check the mount and recover again"))
    if report.get("extrinsic_rotation_observable") is False:
        out.append(Limitation(
            "the rotation between the pose frame and the IMU was not observable (too little rotation): the "
            "calibration's or the identity was used, and the bias absorbs any error in it",
            "record a stretch rotating about every axis, or give T_imu_pose in the calibration and recover "
            "with --extrinsic known"))
    return out


#: Input findings that limit what a bias recovered from that input is good for, and what to do.
_LIMITING_FINDINGS = {
    "POSE_RATE_LOW": "use a faster pose stream (motion capture at 100 Hz or more) if the recording has one",
    "CALIBRATION_DEFAULTED": "give the IMU's own noise values (sensor.yaml or the recovery config) and recover again",
    "SATURATION": "record with a larger sensor range, or drop the saturated stretches",
    "STAMP_UNIT_GUESSED": "write the stamps as integer nanoseconds so that their unit is not guessed",
    "IMU_RATE_MISMATCH": "resample the IMU to the calibration's rate (biasgt convert --resample-hz) or correct "
                         "rate_hz in sensor.yaml, and recover again",
}


def input_limitations(sequence: Sequence) -> list[Limitation]:
    """The sequence's WARNING findings that limit a bias recovered from it (:data:`_LIMITING_FINDINGS`)."""
    return [Limitation(f"input: {f.message}", _LIMITING_FINDINGS[f.code]) for f in sequence.findings
            if f.code in _LIMITING_FINDINGS and f.severity is Severity.WARNING]
