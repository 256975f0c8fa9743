"""The held-out test of a recovered sigma (validation.crossval.sigma) and its verdict rule SIGMA_NOT_CONFIRMED."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bias_table import BiasTrack
from validation.crossval.sigma import ALPHA, heldout_sigma_check

BLOCKS, PER_BLOCK = 12, 100


def _tracks(rng: np.random.Generator, sigma_in: np.ndarray, sigma_h: np.ndarray, reported_scale: float
            ) -> tuple[BiasTrack, BiasTrack, np.ndarray]:
    """An in-sample and a held-out estimate of a zero bias, block-constant errors drawn as nested estimators
    are (``e_h = e_in + delta``, ``var(delta) = sigma_h^2 - sigma_in^2``), their sigmas reported times
    ``reported_scale``."""
    block = np.repeat(np.arange(BLOCKS), PER_BLOCK)
    e_in = rng.standard_normal((BLOCKS, 6)) * sigma_in
    e_h = e_in + rng.standard_normal((BLOCKS, 6)) * np.sqrt(sigma_h**2 - sigma_in**2)
    t = np.arange(len(block), dtype=np.int64)
    ones = np.ones((len(block), 1))
    insample = BiasTrack(t, e_in[block], ones * sigma_in * reported_scale)
    heldout = BiasTrack(t, e_h[block], ones * sigma_h * reported_scale)
    return heldout, insample, block


def test_honest_sigmas_are_confirmed_at_the_false_alarm_rate():
    """Honest sigmas: the statistic is chi-square with one degree of freedom per block (its mean is the
    number of blocks), and the check fails on about ALPHA of recordings."""
    rng = np.random.default_rng(0)
    sigma_in = np.array([1e-4, 1e-4, 1e-4, 3e-3, 3e-3, 3e-3])
    sigma_h = 2.0 * sigma_in
    checks = [heldout_sigma_check(*_tracks(rng, sigma_in, sigma_h, 1.0)) for _ in range(400)]
    chi2 = np.array([c.chi2 for c in checks])
    assert np.mean(chi2) == pytest.approx(BLOCKS, rel=0.05)
    flagged = np.mean([bool(c.unconfirmed) for c in checks])
    assert flagged <= 2.5 * ALPHA
    assert all(c.blocks == BLOCKS for c in checks)


def test_sigmas_three_times_too_small_are_flagged_and_the_factor_restores_them():
    rng = np.random.default_rng(1)
    sigma_in = np.full(6, 2e-3)
    checks = [heldout_sigma_check(*_tracks(rng, sigma_in, 1.5 * sigma_in, 1 / 3)) for _ in range(50)]
    assert np.mean([len(c.unconfirmed) == 6 for c in checks]) > 0.9
    factor = np.array([c.factor for c in checks])
    assert np.median(factor) == pytest.approx(3.0, rel=0.15)


def test_too_few_blocks_give_no_check():
    rng = np.random.default_rng(2)
    heldout, insample, block = _tracks(rng, np.full(6, 1e-3), np.full(6, 2e-3), 1.0)
    assert heldout_sigma_check(heldout, insample, np.where(block < 1, 0, -1)) is not None  # two blocks: 0 and -1
    assert heldout_sigma_check(heldout, insample, np.zeros_like(block)) is None

