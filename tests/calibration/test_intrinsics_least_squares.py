"""The intrinsics fit's arrow least squares (recovery.intrinsics.least_squares) against a dense solve."""

from __future__ import annotations

import numpy as np
import pytest

from recovery.intrinsics.least_squares import solve_with_walk


def _dense(A, B, r, span_s, noise_density, random_walk, prior=None):
    """The same problem as one dense whitened system, solved by numpy's least squares."""
    K, _, P = A.shape
    n = P + 3 * K
    rows, rhs = [], []
    for k in range(K):
        w = 1.0 / (noise_density * np.sqrt(span_s[k]))
        row = np.zeros((3, n))
        row[:, :P], row[:, P + 3 * k:P + 3 * k + 3] = w * A[k], w * B[k]
        rows.append(row)
        rhs.append(w * r[k])
    for k in range(K - 1):
        u = 1.0 / (random_walk * np.sqrt(0.5 * (span_s[k] + span_s[k + 1])))
        row = np.zeros((3, n))
        row[:, P + 3 * k:P + 3 * k + 3], row[:, P + 3 * k + 3:P + 3 * k + 6] = -u * np.eye(3), u * np.eye(3)
        rows.append(row)
        rhs.append(np.zeros(3))
    if prior is not None:
        H, target, sigma = prior
        row = np.zeros((len(H), n))
        row[:, :P] = H / sigma[:, None]
        rows.append(row)
        rhs.append(target / sigma)
    M, y = np.vstack(rows), np.concatenate(rhs)
    sol = np.linalg.lstsq(M, y, rcond=None)[0]
    scale = np.sqrt(np.mean((M[:3 * K] @ sol - y[:3 * K]) ** 2))
    cov = np.linalg.inv(M.T @ M)[:P, :P] * max(scale, 1.0) ** 2
    return sol[:P], np.sqrt(np.diag(cov)), scale * noise_density, cov


@pytest.mark.parametrize("with_prior", [False, True])
def test_arrow_solve_equals_dense_least_squares(with_prior):
    rng = np.random.default_rng(3)
    K, P = 80, 12
    A, B = 0.01 * rng.normal(size=(K, 3, P)), 0.1 * rng.normal(size=(K, 3, 3))
    r, span = 1e-3 * rng.normal(size=(K, 3)), rng.uniform(0.08, 0.12, K)
    prior = (rng.normal(size=(3, P)), 1e-3 * rng.normal(size=3), np.full(3, 1e-3)) if with_prior else None
    got = solve_with_walk(A, B, r, span, 1e-3, 1e-4, prior)
    want = _dense(A, B, r, span, 1e-3, 1e-4, prior)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-7, atol=1e-3 * want[1].min())
    for g, w in zip(got[1:], want[1:]):
        np.testing.assert_allclose(g, w, rtol=1e-7)


def test_a_term_the_data_cannot_see_gets_a_huge_sigma():
    rng = np.random.default_rng(4)
    K, P = 60, 4
    A = 0.01 * rng.normal(size=(K, 3, P))
    A[:, :, 2] = 0.0
    got = solve_with_walk(A, 0.1 * rng.normal(size=(K, 3, 3)), 1e-3 * rng.normal(size=(K, 3)),
                          np.full(K, 0.1), 1e-3, 1e-4)
    assert got[1][2] > 1e5 and np.all(got[1][[0, 1, 3]] < 1.0)
    assert got[0][2] == pytest.approx(0.0, abs=1e-6)
