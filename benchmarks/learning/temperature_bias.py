"""How much the IMU temperature reveals of the recovered bias, on a finished workflow run.

Usage::

    .venv/bin/biasgt run                                  # the default config (simulated, with temperature)
    .venv/bin/python benchmarks/learning/temperature_bias.py [RESULTS_DIR] [--exclude NAME ...]

For the sequences of RESULTS_DIR (default ``results``) whose store carries the IMU temperature,
fits one linear model per bias axis, pooled over the sequences: ``b(t) = a_seq + c * T(t)`` (a
free offset per sequence for the turn-on bias, one temperature coefficient ``c``), by least
squares, to

* the recovered bias at the IMU stamps (``interpolation/<seq>/bias_imu.parquet``): what the
  window dataset trains on;
* the simulator's true bias (``ingest/<seq>/ground_truth.parquet``), when there is one;

and prints both with the simulator's coefficients (``simulate/<seq>/simulation.yaml``) and the
share of the bias variance (within each sequence) the temperature term explains. The true
bias's fit differs from the true coefficients by the bias random walk the model has no term for;
the recovered fit should match the true fit. Exit code 0 (the figures are the output).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from pipeline.sim.writer import read_simulation_yaml  # noqa: E402

AXES = ("bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z")


def fit(temps: list[np.ndarray], biases: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Pooled coefficient [6] of ``b = a_seq + c * T`` and the within-sequence variance share [6] it explains."""
    design = np.zeros((sum(map(len, temps)), 1 + len(temps)))
    design[:, 0] = np.concatenate(temps)
    row = 0
    for k, t in enumerate(temps):
        design[row:row + len(t), 1 + k] = 1.0
        row += len(t)
    y = np.vstack(biases)
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ coef
    centred = np.vstack([b - b.mean(axis=0) for b in biases])
    return coef[0], 1.0 - residual.var(axis=0) / centred.var(axis=0)


def load(results: Path, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """(temperature [N], recovered bias [N, 6], true bias [N, 6] or None) of one sequence."""
    imu = pd.read_parquet(results / "ingest" / name / "imu.parquet")
    interp = results / "interpolation" / name / "bias_imu.parquet"
    if "temperature_degc" not in imu or not interp.is_file():
        return None
    recovered = pd.read_parquet(interp).set_index("t_ns").reindex(imu["t_ns"])[list(AXES)].to_numpy()
    gt_file = results / "ingest" / name / "ground_truth.parquet"
    truth = pd.read_parquet(gt_file)[list(AXES)].to_numpy() if gt_file.is_file() else None
    ok = np.isfinite(recovered).all(axis=1)
    return (imu["temperature_degc"].to_numpy()[ok], recovered[ok],
            None if truth is None or len(truth) != len(imu) else truth[ok])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", nargs="?", type=Path, default=Path("results"))
    parser.add_argument("--exclude", nargs="*", default=[], metavar="NAME", help="sequences to leave out")
    args = parser.parse_args()
    names = sorted(p.name for p in (args.results / "interpolation").glob("*") if p.name not in args.exclude)
    data = {n: d for n in names if (d := load(args.results, n)) is not None}
    if not data:
        print(f"no sequence with IMU temperature and interpolated bias under {args.results} (run 'biasgt run' first)")
        return 0
    print(f"sequences: {', '.join(data)}")
    temps = [d[0] for d in data.values()]
    rows = [("recovered", *fit(temps, [d[1] for d in data.values()]))]
    if all(d[2] is not None for d in data.values()):
        rows.append(("true bias", *fit(temps, [d[2] for d in data.values()])))
    sim_yaml = args.results / "simulate" / next(iter(data)) / "simulation.yaml"
    if sim_yaml.is_file():
        truth = read_simulation_yaml(sim_yaml)["truth"]
        c = truth["temperature_coeff_gyro_radps_per_degc"] + truth["temperature_coeff_acc_mps2_per_degc"]
        rows.append((f"simulator ({next(iter(data))})", np.asarray(c), None))
    print(f"{'coefficient per degC':28s}" + "".join(f"{a:>11s}" for a in AXES))
    for label, coef, share in rows:
        print(f"{label:28s}" + "".join(f"{v:11.2e}" for v in coef))
        if share is not None:
            print(f"{'  variance explained':28s}" + "".join(f"{v:11.0%}" for v in share))
    return 0


if __name__ == "__main__":
    sys.exit(main())
