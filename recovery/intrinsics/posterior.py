"""The IMU intrinsic terms left out of the readings' correction: their datasheet prior and posterior.

A term the loop of :mod:`recovery.intrinsics.estimate` did not correct the readings for (not
significant, too weak to, or dropped) is still in the readings and in the bias. Under the datasheet
prior ``L`` its posterior from the last fit (estimate ``x``, covariance ``C``) is ``m = L (C + L)^-1 x``,
``P = C (C + L)^-1 L``: ``m`` times its signal leaves the bias (:func:`left_out_shift`), ``P`` joins
the bias variance (:func:`intrinsics_bias_variance`), with the terms in the model's own covariance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


class IntrinsicsFit(Protocol):
    """What the posterior reads of a fit (:class:`recovery.intrinsics.estimate.IntrinsicsFit`)."""

    cov: dict[str, np.ndarray] | None  # "rotation": [9 or 18]^2 (S_g, G), "velocity": [9, 9] (S_a)
    estimated: tuple[str, ...]  # the groups fitted


@dataclass(frozen=True)
class IntrinsicsPrior:
    """The 1-sigma sizes of the IMU's intrinsic terms before the data (the datasheet of a MEMS IMU by default);
    the prior of a term the fit cannot tell from the bias (``RecoveryConfig``'s ``intrinsics_prior_*``).

    Attributes:
        scale_misalignment: A scale factor or misalignment term of the gyro or accelerometer matrix (0.5 %).
        g_sensitivity: A term of the gyro's g-sensitivity, rad/s per m/s^2 (0.1 deg/s per g).
        non_orthogonality: The accelerometer triad's non-orthogonality, per symmetric off-diagonal pair (0.06 deg).
        calibration_rotation_rad: Per axis, how far a calibration file's IMU rotation may be off the
            accelerometer's (a camera-IMU calibration's accuracy, 0.03 deg).
    """

    scale_misalignment: float = 5e-3
    g_sensitivity: float = 2e-4
    non_orthogonality: float = 1e-3
    calibration_rotation_rad: float = 5e-4

    def term_sigmas(self, frame_held: bool) -> dict[str, np.ndarray]:
        """Per group, the 3x3 prior sigmas; with ``frame_held`` (the extrinsic known: the accelerometer's frame is
        the solve's) an accelerometer off-diagonal term is only its triad's non-orthogonality, else it carries
        the accelerometer's rotation against the solve's frame too."""
        out = {"gyro_scale_misalignment": np.full((3, 3), self.scale_misalignment),
               "acc_scale_misalignment": np.full((3, 3), self.scale_misalignment),
               "gyro_g_sensitivity": np.full((3, 3), self.g_sensitivity)}
        if frame_held:
            out["acc_scale_misalignment"] = np.where(np.eye(3, dtype=bool), self.scale_misalignment,
                                                     self.non_orthogonality)
        return out


#: A left-out term whose fit sigma exceeds this many prior sigmas is blind: its posterior is the prior (the fit
#: would hold under 1 % of the information, and a near-singular covariance says nothing reliable).
BLIND_SIGMA_RATIO = 10.0


def _blocks(fit: IntrinsicsFit, terms: dict[str, np.ndarray], omega_radps: np.ndarray, f_mps2: np.ndarray,
            left: dict[str, np.ndarray] | None, prior: dict[str, np.ndarray] | None):
    """Per covariance block (rotation: S_g[, G]; velocity: S_a): ``(cov, [(group, signal)], first bias
    column, in-model mask, left-out mask, posterior of the left-out terms)``; the posterior is
    ``(indices, m, P)`` of the left-out terms the fit sees (sigma within :data:`BLIND_SIGMA_RATIO` prior sigmas,
    observable or not) and ``(indices, prior variance)`` of the blind ones."""
    gyro_groups = [("gyro_scale_misalignment", omega_radps)]
    if "gyro_g_sensitivity" in fit.estimated:
        gyro_groups.append(("gyro_g_sensitivity", f_mps2))
    for cov, groups, col in ((fit.cov["rotation"], gyro_groups, 0),
                             (fit.cov["velocity"], [("acc_scale_misalignment", f_mps2)], 3)):
        n = cov.shape[0]
        used, seen = np.zeros(n, bool), np.ones(n, bool)
        x, prior_var = np.zeros(n), np.zeros(n)
        for g, (name, _) in enumerate(groups):
            sl = slice(9 * g, 9 * g + 9)
            used[sl] = np.asarray(terms.get(name, np.zeros((3, 3), bool)), bool).ravel()
            if left is not None:
                x[sl] = np.nan_to_num(np.asarray(left.get(name, np.zeros((3, 3))), float).ravel())
                prior_var[sl] = np.asarray((prior or IntrinsicsPrior().term_sigmas(False))[name], float).ravel() ** 2
        if left is not None:  # a term too weak to correct the readings for still informs its posterior
            var_fit = np.diag(cov)
            seen = np.isfinite(var_fit) & (var_fit <= BLIND_SIGMA_RATIO**2 * prior_var)
        out_of_model = ~used if left is not None else np.zeros(n, bool)
        blind = np.flatnonzero(out_of_model & ~seen)  # the fit cannot see them: the prior, its estimate says nothing
        u = np.flatnonzero(out_of_model & seen)
        m, post = np.zeros(len(u)), np.zeros((len(u), len(u)))
        if len(u):
            C, L = cov[np.ix_(u, u)], np.diag(prior_var[u])
            gain = np.linalg.solve(C + L, np.eye(len(u)))  # (C + L)^-1
            m, post = L @ gain @ x[u], C @ gain @ L
        yield cov, groups, col, used, out_of_model, (u, m, 0.5 * (post + post.T)), (blind, prior_var[blind])


def intrinsics_bias_variance(fit: IntrinsicsFit, terms: dict[str, np.ndarray], omega_radps: np.ndarray,
                             f_mps2: np.ndarray, left: dict[str, np.ndarray] | None = None,
                             prior: dict[str, np.ndarray] | None = None, corrected: bool = False) -> np.ndarray:
    """Bias variance [N, 6] (gyro, acc) from the intrinsics: those estimated and those the bias absorbed.

    With ``gyro = M_g omega + G f + b_g`` and ``acc = M_a f + b_a``, errors ``dS`` / ``dG`` of the
    terms move the recovered bias by ``-(dS_g omega + dG f)`` and ``-dS_a f`` (first order). A term on
    the gravity axis times ``f ~ g`` is nearly a constant offset, so its sigma reaches the bias in
    full. A term in the model (``terms``: per group, 3x3 booleans) errs by the fit's covariance. The
    terms left out (not significant, not observable, or dropped) are still in the readings: with
    ``left`` (per group, 3x3: the fit's estimate ``x`` of what the readings carry of each, covariance
    ``C`` among them) their posterior under the datasheet prior ``L`` (``prior``: per group 3x3 sigmas,
    default :meth:`IntrinsicsPrior.term_sigmas` without a held frame) is ``m = L (C + L)^-1 x``, ``P = C (C + L)^-1 L``:
    they err by ``P + m m^T`` (their mean square error as zero), or by ``P`` when the bias was
    ``corrected`` by ``m`` (:func:`left_out_shift`). A term the fit cannot see (sigma above
    :data:`BLIND_SIGMA_RATIO` prior sigmas) keeps the prior as its error. Without ``left``, terms left out add nothing.

    Args:
        fit: The last fit (its ``cov``). terms: The terms estimated. left / prior / corrected: See above.
        omega_radps / f_mps2: Bias-free angular rate and specific force at the keyframes, [N, 3].
    """
    N = len(omega_radps)
    out = np.zeros((N, 6))
    for cov, groups, col, used, out_of_model, (u, m, post), (blind, blind_var) in _blocks(
            fit, terms, omega_radps, f_mps2, left, prior):
        eff = np.where(np.outer(used, used), cov, 0.0)
        eff[blind, blind] = blind_var
        eff[np.ix_(u, u)] = post if corrected else post + np.outer(m, m)
        counted = used | out_of_model
        for row in range(3):
            # d(bias_row) / d(term [row, c]) = -signal_c, for the terms of that row of each group
            grad = np.zeros((N, cov.shape[0]))
            for g, (_, signal) in enumerate(groups):
                grad[:, 9 * g + 3 * row: 9 * g + 3 * row + 3] = -signal * counted[9 * g + 3 * row: 9 * g + 3 * row + 3]
            out[:, col + row] = np.einsum("np,pq,nq->n", grad, eff, grad)
    return out


def left_out_means(fit: IntrinsicsFit, terms: dict[str, np.ndarray], left: dict[str, np.ndarray],
                   prior: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Per group, 3x3: the posterior means of the terms left out (:func:`intrinsics_bias_variance`; zero
    for the terms in the model and for those the fit cannot see)."""
    out = {}
    zeros = np.zeros((1, 3))
    for _, groups, _, _, _, (u, m, _), _ in _blocks(fit, terms, zeros, zeros, left, prior):
        full = np.zeros(9 * len(groups))
        full[u] = m
        out.update({name: full[9 * g: 9 * g + 9].reshape(3, 3) for g, (name, _) in enumerate(groups)})
    return out


def left_out_shift(fit: IntrinsicsFit, terms: dict[str, np.ndarray], omega_radps: np.ndarray, f_mps2: np.ndarray,
                   left: dict[str, np.ndarray], prior: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """What the bias absorbed of the terms left out, to subtract from it: ``m s`` per bias axis, [N, 6].

    The posterior means ``m`` of :func:`intrinsics_bias_variance` times their signals; pass the
    signals low-passed as the bias follows them (a bias random walk takes up ``G f ~ G g`` in full,
    little of ``S_g omega``).

    Args:
        omega_radps / f_mps2: The signals at the keyframes, [N, 3].
    """
    out = np.zeros((len(omega_radps), 6))
    for _, groups, col, _, _, (u, m, _), _ in _blocks(fit, terms, omega_radps, f_mps2, left, prior):
        full = np.zeros(9 * len(groups))
        full[u] = m
        for g, (_, signal) in enumerate(groups):
            out[:, col:col + 3] += signal @ full[9 * g: 9 * g + 9].reshape(3, 3).T
    return out
