"""How often a set of recordings meets the rig benchmark's NEES goals, by chance alone.

Usage::

    .venv/bin/python benchmarks/recovery/nees_goal_odds.py [--records rig.jsonl] [--seeds 20]

The rig benchmark (``rig.py``) judges each scenario by two NEES goals over ``n`` recordings of
``A = 6`` axes: every axis' mean NEES in ``[0.5, 2]``, and every axis at most 4 on at least 90 % of
recordings. A recording's NEES on one axis is the mean over its keyframes of ``(error / sigma)^2``;
when its error is Gaussian with ``k`` independent parts over the recording (``k = 1``: one constant
error, as an intrinsic term or a bias that does not walk leaves), it is ``m chi2_k / k``, with ``m``
its expected value (1 for an honest sigma, 1/2 for a constant truth under a random-walk smoother:
``constant_bias_nees.py``). The sum of ``n`` independent recordings' values is ``m chi2_{nk} / k``, so

    P(one axis' mean in [0.5, 2])        = F_{nk}(2 n k / m) - F_{nk}(0.5 n k / m)
    P(a recording has every axis <= 4)   = p = F_k(4 k / m) ^ A
    P(at least 90 % of n such)           = 1 - B_{n, p}(ceil(0.9 n) - 1)

(``F_j``: the chi-square CDF of ``j`` degrees of freedom; ``B``: the binomial CDF), and both goals
hold with about the product of the first to the power ``A`` and the last (axes and recordings taken as
independent; the product slightly overstates the joint odds, since a recording far above 4 helps the
mean goal as it fails the other). Printed: that probability per ``k`` and ``m``, and its largest value
over ``m``; and the largest for a gyro of ``k = 1`` beside an accelerometer of 4 or 30 (each sensor's ``m`` its own).

With ``--records`` (a ``rig.py --out`` file), per generator and scenario: the measured per-axis mean
NEES, the degrees of freedom its spread implies (``k = 2 mean^2 / var``, a scaled chi-square's), and
the share of bootstrap draws of ``--seeds`` recordings (from the file's) that meet each goal.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))

from rig import MEAN_NEES_BOUNDS, NEES_BOUND, WITHIN_SHARE, read_records  # noqa: E402  (the goals: rig.py's)

AXES = 6


def mean_goal_odds(m: float, k: float, n: int, axes: int = AXES) -> float:
    """P(every axis' mean over ``n`` recordings in ``MEAN_NEES_BOUNDS``), per-axis NEES ``m chi2_k / k``."""
    dof = n * k
    lo, hi = (b * dof / m for b in MEAN_NEES_BOUNDS)
    return float(stats.chi2.cdf(hi, dof) - stats.chi2.cdf(lo, dof)) ** axes


def axis_within(m: float, k: float) -> float:
    """P(one recording's NEES on one axis is at most ``NEES_BOUND``)."""
    return float(stats.chi2.cdf(NEES_BOUND * k / m, k))


def share_goal_odds(p: float, n: int) -> float:
    """P(at least ``WITHIN_SHARE`` of ``n`` recordings meet a test each meets with probability ``p``)."""
    return float(stats.binom.sf(math.ceil(WITHIN_SHARE * n - 1e-9) - 1, n, p))


def tail_goal_odds(m: float, k: float, n: int, axes: int = AXES) -> float:
    """P(at least ``WITHIN_SHARE`` of ``n`` recordings have every axis' NEES at most ``NEES_BOUND``)."""
    return share_goal_odds(axis_within(m, k) ** axes, n)


def both_goals_odds(m: float, k: float, n: int, axes: int = AXES) -> float:
    """P(both goals) as the product of each goal's (a little above the joint: module docstring)."""
    return mean_goal_odds(m, k, n, axes) * tail_goal_odds(m, k, n, axes)


def best_scale(k: float, n: int, axes: int = AXES) -> tuple[float, float]:
    """``(m, odds)``: the expected NEES that gives both goals their largest odds (:func:`both_goals_odds`)."""
    grid = np.exp(np.linspace(np.log(0.3), np.log(3.0), 400))
    odds = np.array([both_goals_odds(m, k, n, axes) for m in grid])
    i = int(np.argmax(odds))
    return float(grid[i]), float(odds[i])


def by_sensor_best(k_gyro: float, k_acc: float, n: int) -> tuple[float, float, float]:
    """``(m_gyro, m_acc, odds)``: both goals' largest joint probability when the gyro's three axes have
    ``k_gyro`` degrees of freedom and the accelerometer's ``k_acc``, each sensor's scale chosen freely."""
    grid = np.exp(np.linspace(np.log(0.4), np.log(2.0), 60))
    mean = {(k, m): mean_goal_odds(m, k, n, 3) for k in (k_gyro, k_acc) for m in grid}
    within = {(k, m): axis_within(m, k) ** 3 for k in (k_gyro, k_acc) for m in grid}
    best = max(((mean[k_gyro, mg] * mean[k_acc, ma] * share_goal_odds(within[k_gyro, mg] * within[k_acc, ma], n),
                 mg, ma) for mg in grid for ma in grid))
    return float(best[1]), float(best[2]), float(best[0])


def closed_form_table(n: int) -> list[str]:
    ms = (0.5, 0.6, 0.7, 0.8, 1.0, 1.2)
    lines = [f"both goals over {n} recordings of {AXES} axes, per-axis NEES m chi2_k / k (closed form):",
             f"{'k':>5s}" + "".join(f"{'m=' + format(m, 'g'):>9s}" for m in ms) + f"{'best m':>9s}{'odds':>7s}"]
    for k in (1, 2, 4, 9, 30):
        m_best, odds = best_scale(k, n)
        lines.append(f"{k:5d}" + "".join(f"{both_goals_odds(m, k, n):9.2f}" for m in ms) + f"{m_best:9.2f}{odds:7.2f}")
    for k_gyro, k_acc in ((1, 4), (1, 30)):
        mg, ma, odds = by_sensor_best(k_gyro, k_acc, n)
        lines.append(f"gyro k={k_gyro}, accelerometer k={k_acc}: best m {mg:.2f} / {ma:.2f}, odds {odds:.2f} "
                     f"(two generators: {odds**2:.2f})")
    return lines


def measured_table(records: list[dict], n: int, draws: int = 4000, seed: int = 0) -> list[str]:
    """Per generator and scenario: mean NEES, implied dof and bootstrap odds of each goal."""
    rng = np.random.default_rng(seed)
    lines = [f"measured (labels' NEES), bootstrap of {n} recordings, {draws} draws:",
             f"{'generator / scenario':28s}{'recs':>5s}  {'mean NEES gx gy gz / ax ay az':34s}"
             f"{'dof k (same axes)':30s}{'mean goal':>10s}{'90 % goal':>10s}"]
    cells: dict[tuple[str, str], dict[int, list[float]]] = {}
    for r in records:
        if "error" not in r:
            cells.setdefault((r["generator"], r["scenario"]), {})[r["seed"]] = r.get("nees_widened", r["nees"])
    for (gen, scen), by_seed in sorted(cells.items()):
        nees = np.array([by_seed[s] for s in sorted(by_seed)])
        mean, var = nees.mean(0), nees.var(0, ddof=1)
        dof = 2 * mean**2 / np.where(var > 0, var, np.nan)
        pick = rng.integers(0, len(nees), (draws, n))
        sample = nees[pick]  # [draws, n, A]
        means = sample.mean(1)
        mean_ok = np.all((means >= MEAN_NEES_BOUNDS[0]) & (means <= MEAN_NEES_BOUNDS[1]), axis=1).mean()
        tail_ok = ((sample.max(2) <= NEES_BOUND).mean(1) >= WITHIN_SHARE - 1e-9).mean()
        lines.append(f"{gen + ' / ' + scen:28s}{len(nees):5d}  "
                     f"{' '.join(f'{v:.2f}' for v in mean[:3])} / {' '.join(f'{v:.2f}' for v in mean[3:]):17s}"
                     f"{' '.join(f'{v:4.1f}' for v in dof):30s}{mean_ok:10.2f}{tail_ok:10.2f}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=Path, default=None, help="a rig.py --out file (JSON lines)")
    ap.add_argument("--seeds", type=int, default=20, help="recordings per scenario the goals are judged over")
    args = ap.parse_args(argv)
    print("\n".join(closed_form_table(args.seeds)))
    if args.records is not None:
        if not args.records.is_file():
            print(f"error: {args.records}: no such file; pass a rig.py --out file", file=sys.stderr)
            return 2
        try:
            records = read_records(args.records)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print("\n".join(measured_table(records, args.seeds)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
