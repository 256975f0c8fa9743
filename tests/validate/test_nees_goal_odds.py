"""The rig benchmark's goal odds (benchmarks/recovery/nees_goal_odds.py) against direct chi-square draws."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SPEC = importlib.util.spec_from_file_location(
    "nees_goal_odds", Path(__file__).resolve().parents[2] / "benchmarks" / "recovery" / "nees_goal_odds.py")
odds = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(odds)


def _simulated(m: float, k: int, n: int, draws: int, rng: np.random.Generator) -> tuple[float, float]:
    """Both goals' shares over ``draws`` sets of ``n`` recordings whose per-axis NEES is ``m chi2_k / k``."""
    nees = m * rng.chisquare(k, (draws, n, odds.AXES)) / k
    means = nees.mean(1)
    mean_ok = np.all((means >= 0.5) & (means <= 2.0), axis=1)
    tail_ok = (nees.max(2) <= 4.0).mean(1) >= 0.9
    return float(mean_ok.mean()), float(tail_ok.mean())


@pytest.mark.parametrize("m, k", [(0.8, 1), (0.6, 4), (1.0, 2)])
def test_the_closed_form_odds_match_chi_square_draws(m, k):
    rng = np.random.default_rng(7)
    mean_share, tail_share = _simulated(m, k, 20, 40_000, rng)
    assert odds.mean_goal_odds(m, k, 20) == pytest.approx(mean_share, abs=0.01)
    assert odds.tail_goal_odds(m, k, 20) == pytest.approx(tail_share, abs=0.01)


def test_an_error_constant_over_each_recording_meets_both_goals_on_a_minority_of_benchmark_runs():
    # one constant error per axis and recording: no sigma scaling gets both goals above one run in four
    m_best, best = odds.best_scale(1, 20)
    assert 0.6 < m_best < 1.0
    assert best < 0.3
    # many independent parts per recording: an honest sigma meets both nearly always
    assert odds.both_goals_odds(1.0, 30, 20) > 0.99
