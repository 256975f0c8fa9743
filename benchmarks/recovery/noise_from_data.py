"""Noise from the data when no calibration file exists: the densities read off a rest, the written
sensor.yaml, and a second recovery from that file.

    .venv/bin/python benchmarks/recovery/noise_from_data.py [--seeds 3 4]

Per generator (the project's simulator, ``pipeline.sim``; the independent one, tests/independent.py)
and seed: a 50-s recording that opens with a 15-s rest, white noise at 5e-4 rad/s/sqrt(Hz) and 6e-3
m/s^2/sqrt(Hz), its ``sensor.yaml`` removed. Printed: the densities written beside the recovery
against the simulated ones (goal: within 30 %), and how far the bias recovered again with that file
lies from the first, as the RMS over the keyframes of the difference in the two recoveries' combined
sigma, per channel (goal: below 1, within its sigma). The rest is judged by each sensor's variation
about its window mean, so a large turn-on gyro bias does not hide it; a recording where no rest is
found gets no file, and its line says so.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from rest_recordings import ACC_DENSITY, GYRO_DENSITY, bias_agreement, independent, simulated  # noqa: E402

def run(generate, seed: int, tmp: Path) -> None:
    from pipeline.io import load_sequence
    from pipeline.io.sensor_yaml import read_imu_calibration
    from recovery.outputs import SENSOR_YAML, read_report
    from recovery.recover import recover, write_recovery

    data = generate(tmp / "rec", seed)
    imu_yaml = data / "mav0" / "imu0" / "sensor.yaml"
    imu_yaml.unlink()
    t0 = time.perf_counter()
    write_recovery(recover(load_sequence(data)), tmp / "rec1")
    if not (tmp / "rec1" / SENSOR_YAML).is_file():
        imu = load_sequence(data).imu
        rest = np.linalg.norm(imu.gyro_radps[: int(10 * imu.rate_hz)].mean(axis=0))
        print(f"  {generate.__name__:11s} seed {seed}: no sensor.yaml written (noise_from_data: "
              f"{read_report(tmp / 'rec1').data.get('noise_from_data')}); the gyro's mean norm over the rest's "
              f"first 10 s is {rest:.3f} rad/s",
              flush=True)
        return
    written = read_imu_calibration(tmp / "rec1" / SENSOR_YAML)
    shutil.copyfile(tmp / "rec1" / SENSOR_YAML, imu_yaml)
    write_recovery(recover(load_sequence(data)), tmp / "rec2")
    z = bias_agreement(tmp / "rec1", tmp / "rec2")
    print(f"  {generate.__name__:11s} seed {seed}: densities written / simulated: gyro "
          f"{written.gyro_noise_density / GYRO_DENSITY:.2f}, acc {written.acc_noise_density / ACC_DENSITY:.2f}; "
          f"second recovery, RMS of the difference in sigma: " + " ".join(f"{v:.2f}" for v in z)
          + f"  [{time.perf_counter() - t0:.0f} s]", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5])
    args = parser.parse_args()
    print("generator, seed: densities (ratio to the simulated; goal 0.7-1.3); second recovery's bias "
          "difference (gyro xyz, acc xyz; goal < 1)")
    for generate in (simulated, independent):
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as tmp:
                run(generate, seed, Path(tmp))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
