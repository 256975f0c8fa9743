"""The intrinsics fit's least squares: a few global terms and a bias correction per interval that
follows a random walk, solved in time linear in the intervals.

Notation: K intervals, P global terms ``x``, per interval a bias correction ``d_k`` [3].
Whitened rows (``w_k = 1 / (noise_density sqrt(span_k))``, ``u_k = 1 / (random_walk sqrt(span))``)::

    w_k (A_k x + B_k d_k - r_k)           one triple per interval (measurement)
    u_k (d_k+1 - d_k)                     one triple per neighbouring pair (random walk)
    (H x - target) / sigma                optional prior rows on x

The normal matrix is an arrow: a dense P x P corner, a dense border and a band of half-width 3 over
the ``d`` (3 x 3 blocks on the diagonal, the walk's ``-u_k^2 I`` beside them). The steps:

1. build the band ``N_dd`` [7, 3K] (LAPACK banded storage), the border ``N_dx`` [3K, P] and ``N_xx``;
2. ``Z = N_dd^-1 [N_dx | b_d]`` by one banded LU (:func:`scipy.linalg.solve_banded`);
3. the Schur complement ``S = N_xx - N_dx^T Z_x``: ``x = S^-1 (b_x - N_dx^T z_b)``, ``cov(x) = S^-1``
   (the x block of ``N^-1``, exactly);
4. ``d = z_b - Z_x x``.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_banded

__all__ = ["solve_with_walk"]

#: Added to the normal matrix's diagonal (keeps a term the data cannot see finite: a huge sigma).
RIDGE = 1e-12
#: Half-width of the ``d`` band (the walk couples component c of d_k with component c of d_k+1).
HALF_BAND = 3


def _band(B: np.ndarray, w2: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """``N_dd`` [2 * HALF_BAND + 1, 3K] in LAPACK banded storage (``ab[HALF_BAND + i - j, j] = N[i, j]``)."""
    K = len(B)
    blocks = np.einsum("kji,kjl->kil", B, B) * w2[:, None, None]  # B_k^T B_k w_k^2, [K, 3, 3]
    walk = np.zeros(K)
    walk[:-1] += u2
    walk[1:] += u2
    blocks[:, np.arange(3), np.arange(3)] += walk[:, None] + RIDGE
    ab = np.zeros((2 * HALF_BAND + 1, 3 * K))
    for i in range(3):
        for j in range(3):
            ab[HALF_BAND + i - j, 3 * np.arange(K) + j] = blocks[:, i, j]
    ab[0, 3:] = np.repeat(-u2, 3)  # (3k + c, 3k + 3 + c): above the diagonal
    ab[2 * HALF_BAND, :-3] = np.repeat(-u2, 3)  # and its mirror below
    return ab


def solve_with_walk(A: np.ndarray, B: np.ndarray, r: np.ndarray, span_s: np.ndarray, noise_density: float,
                    random_walk: float, prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Weighted least squares for ``r_k = A_k x + B_k d_k`` with a random walk on ``d``.

    Args:
        A: [K, 3, P] coefficients of the global terms; B: [K, 3, 3] of interval k's bias
            correction ``d_k``; r: [K, 3] residuals; span_s: [K] interval lengths (s).
        noise_density / random_walk: Sigma of a residual is ``noise_density sqrt(span)`` (rescaled
            by the fit's own residuals); ``d_k+1 - d_k`` has sigma ``random_walk sqrt(span)``.
        prior: ``(H [m, P], target [m], sigma [m])``: ``H x = target`` within ``sigma``.

    Returns:
        ``(x [P], sigma of x [P] (huge where a term is not identifiable), residual scale (the
        whitened residual RMS times noise_density), covariance of x [P, P])``; sigma and covariance
        are scaled by the residual RMS when it exceeds 1.
    """
    K, _, P = A.shape
    w2 = 1.0 / (noise_density**2 * span_s)
    u2 = 1.0 / (random_walk**2 * 0.5 * (span_s[:-1] + span_s[1:]))
    # 1. the arrow's parts
    N_xx = np.einsum("kji,kjl,k->il", A, A, w2) + RIDGE * np.eye(P)
    b_x = np.einsum("kji,kj,k->i", A, r, w2)
    if prior is not None:
        H, target, sigma_prior = (np.asarray(v, dtype=float) for v in prior)
        Hw = H / sigma_prior[:, None]
        N_xx += Hw.T @ Hw
        b_x += Hw.T @ (target / sigma_prior)
    N_dx = (np.einsum("kji,kjl->kil", B, A) * w2[:, None, None]).reshape(3 * K, P)
    b_d = (np.einsum("kji,kj->ki", B, r) * w2[:, None]).ravel()
    # 2. the band solved against the border and the right-hand side at once
    Z = solve_banded((HALF_BAND, HALF_BAND), _band(B, w2, u2), np.column_stack([N_dx, b_d]),
                     check_finite=False)
    # 3. the Schur complement on x
    S = N_xx - N_dx.T @ Z[:, :P]
    S_inv = np.linalg.inv(0.5 * (S + S.T))
    x = S_inv @ (b_x - N_dx.T @ Z[:, P])
    # 4. the bias corrections, then the whitened measurement residuals
    d = (Z[:, P] - Z[:, :P] @ x).reshape(K, 3)
    res = (np.einsum("kij,j->ki", A, x) + np.einsum("kij,kj->ki", B, d) - r) * np.sqrt(w2)[:, None]
    scale = float(np.sqrt(np.mean(res**2)))
    cov = S_inv * max(scale, 1.0) ** 2
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return x, sigma, scale * noise_density, 0.5 * (cov + cov.T)
