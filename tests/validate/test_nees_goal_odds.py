"""The rig benchmark's goal odds (benchmarks/recovery/nees_goal_odds.py) against direct chi-square draws."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

SPEC = importlib.util.spec_from_file_location(
    "nees_goal_odds", Path(__file__).resolve().parents[2] / "benchmarks" / "recovery" / "nees_goal_odds.py")
odds = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(odds)
rig = sys.modules["rig"]  # rig.py, imported by nees_goal_odds.py for the goals


def _goals_met(nees: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per set of recordings ``nees`` [draws, n, axes]: whether every axis' mean is in [0.5, 2], and whether
    every axis is at most 4 on 90 % of the recordings, [draws] each."""
    means = nees.mean(1)
    return np.all((means >= 0.5) & (means <= 2.0), axis=1), (nees.max(2) <= 4.0).mean(1) >= 0.9


def _simulated(m: float, k: int, n: int, draws: int, rng: np.random.Generator) -> tuple[float, float]:
    """Both goals' shares over ``draws`` sets of ``n`` recordings whose per-axis NEES is ``m chi2_k / k``."""
    mean_ok, tail_ok = _goals_met(m * rng.chisquare(k, (draws, n, odds.AXES)) / k)
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


def test_the_per_sensor_odds_match_draws_of_a_constant_gyro_error_beside_a_wandering_accelerometer_one():
    m_gyro, m_acc, best = odds.by_sensor_best(1, 4, 20)
    rng = np.random.default_rng(11)
    draws = 40_000
    nees = np.concatenate([m_gyro * rng.chisquare(1, (draws, 20, 3)), m_acc * rng.chisquare(4, (draws, 20, 3)) / 4],
                          axis=2)
    mean_ok, tail_ok = _goals_met(nees)
    both = mean_ok & tail_ok
    # the product of the two goals' odds: a recording far above 4 helps the mean goal as it fails the other, so
    # the product overstates the joint odds a little
    assert both.mean() <= best <= both.mean() + 0.05
    assert best < 0.65  # a constant gyro error keeps the goals a coin flip however the sigmas are scaled


def test_a_file_that_is_not_a_rig_record_is_refused_with_its_line(tmp_path, capsys):
    bad = tmp_path / "rig.jsonl"
    bad.write_text('{"generator": "sim", "scenario": "clean", "seed": 0, "nees": [1, 1, 1, 1, 1, 1]}\n{"seed": 1}\n')
    assert odds.main(["--records", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {bad}:2: not a rig.py record (no generator, scenario or seed); pass a rig.py --out file"]


def test_the_rig_benchmark_judges_the_mean_nees_per_axis_and_over_the_axes():
    # two recordings: gyro x's mean 0.3 is out; the 12 values' mean is (0.2 + 0.4 + 10 * 0.8) / 12 = 0.7167
    nees = [[0.2, 0.8, 0.8, 0.8, 0.8, 0.8], [0.4, 0.8, 0.8, 0.8, 0.8, 0.8]]
    records = [{"generator": "sim", "scenario": "tilt", "seed": i, "duration_s": 60.0, "recover_s": 1.0,
                "rmse": [1e-4] * 6, "nees": n, "verdict": "PASS", "reason_codes": []} for i, n in enumerate(nees)]
    checks = [ln for ln in rig.summarise(records) if "checks:" in ln]
    assert checks == ["    checks: mean NEES in [0.5, 2]: each axis NO (1 out), over the axes 0.72 yes; PASS with an "
                      "axis NEES > 4: 0; all axes NEES <= 4: 100 % (ok)"]


def test_the_rig_benchmark_refuses_a_results_file_that_is_not_its_own_with_its_line(tmp_path, capsys):
    bad = tmp_path / "rig.jsonl"
    bad.write_text("not json\n")
    assert rig.main(["--summary-only", "--out", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {bad}:1: not a rig.py record (") and err.endswith("pass a rig.py --out file")
