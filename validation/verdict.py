"""The verdict's helpers: the end-point errors a bias sigma explains, the verdict on the integration
errors alone (:func:`decide_verdict`), and the limitations of a recovery or an input with their next
steps. Every rule itself lives in :mod:`validation.rules`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass

import numpy as np

from pipeline.types import Sequence, Verdict
from recovery.outputs import RecoveryOutputs
from validation.config import ValidationConfig
from validation.metrics import SourceMetrics
from validation.rules import RULES, Evidence, VerdictInputs, judge

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


def decide_verdict(
    metrics: Mapping[str, SourceMetrics],
    candidate: str,
    *,
    dropped_fraction: float,
    config: ValidationConfig = ValidationConfig(),
    limitations: Sequence_[str] = (),
    fails: Sequence_[str] = (),
) -> tuple[Verdict, list[str]]:
    """PASS / WARN / FAIL of ``candidate`` against the baselines by the rules of :mod:`validation.rules`
    (the integration rules only; :func:`judge` with a :class:`~validation.rules.Evidence` for all of them).

    Args:
        metrics: Per source.
        candidate: The source judged.
        dropped_fraction: Fraction of candidate windows dropped.
        config: Thresholds.
        limitations: What limits the candidate's use though the numbers pass; each one makes a PASS a
            WARN (rule GIVEN_LIMITATION).
        fails: Reasons already found for a FAIL, listed first (rule GIVEN_FAIL).

    Returns:
        ``(verdict, reasons)``; reasons are plain sentences (empty for a clean PASS).
    """
    verdict, reasons = judge(Evidence(metrics, candidate, config, dropped_fraction, given_fails=tuple(fails),
                                      given_limitations=tuple(limitations)))
    return verdict, [r.text for r in reasons]


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
    return _limitations(VerdictInputs(recovery=recovery.report), config, _RECOVERY_CODES)


#: The rules of :func:`recovery_limitations` (those of :func:`input_limitations`: the rules ``INPUT_*``).
_RECOVERY_CODES = ("RANDOM_WALK_AT_EDGE", "RANDOM_WALK_FAR", "EXTRINSIC_DIFFERS", "EXTRINSIC_UNOBSERVABLE")


def input_limitations(sequence: Sequence) -> list[Limitation]:
    """The sequence's WARNING findings that limit a bias recovered from it (the rules ``INPUT_*``)."""
    codes = tuple(code for code in RULES if code.startswith("INPUT_"))
    return _limitations(VerdictInputs(findings=tuple(sequence.findings)), ValidationConfig(), codes)


def _limitations(inputs: VerdictInputs, config: ValidationConfig, codes: Sequence_[str]) -> list[Limitation]:
    """What the rules ``codes`` find in ``inputs``, each with its rule's next step."""
    evidence = Evidence({}, "", config, inputs=inputs)
    return [Limitation(text, RULES[code].next_step or "") for code in codes for text in RULES[code].fired(evidence)]
