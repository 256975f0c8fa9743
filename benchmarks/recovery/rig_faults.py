"""A rig's usual faults over many seeds, on the project's simulator and on the independent generator.

    .venv/bin/python benchmarks/recovery/rig_faults.py [--seeds 20] [--recover-seeds 20]

Per generator and seed, recordings from tests/rig_faults.py (unknown 20-deg extrinsic, no ground truth):

* clock offsets of 3 s (40-s recording) and 30 s (75 s), recovered with defaults: the largest
  |offset - truth| over the seeds (goal: below 5 ms) and the median recovery time (``runtime_s``),
  beside the same recordings at a 20-ms offset (goal: the same time);
* the rig checks alone (``pipeline.checks.run_checks``) on positions in millimetres, w-last quaternions,
  swapped accelerometer x/z, swapped gyro x/y and a flipped accelerometer z: how many seeds they name
  (goal: all), and on the correct recording how many raise any rig finding (goal: none).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import rig_faults as rf  # noqa: E402

RIG_CODES = ("CLOCK_OFFSET", "POSITION_UNIT", "FRAME_DISAGREEMENT", "POSE_PLACEHOLDERS", "STAMP_UNIT")
CHECK_FAULTS = {
    "correct": (None, None),
    "millimetres": (lambda r: rf.positions_scaled(r, 1000.0), "POSITION_UNIT"),
    "quaternion w-last": (rf.quaternion_w_last, "FRAME_DISAGREEMENT"),
    "acc x/z swapped": (lambda r: rf.swap_imu_columns(r, "acc", 0, 2), "FRAME_DISAGREEMENT"),
    "gyro x/y swapped": (lambda r: rf.swap_imu_columns(r, "gyro", 0, 1), "FRAME_DISAGREEMENT"),
    "acc z flipped": (lambda r: rf.flip_imu_axis(r, "acc", 2), "FRAME_DISAGREEMENT"),
}


def offsets(generator: str, seeds: range, tmp: Path) -> None:
    from pipeline.io import load_sequence
    from recovery.recover import recover

    for offset_s, duration_s in ((0.02, 40.0), (3.0, 40.0), (30.0, 75.0)):
        errors, runtimes = [], []
        for seed in seeds:
            root = tmp / f"{generator}_{offset_s}_{seed}"
            truth = rf.write_recording(generator, root, duration_s=duration_s, seed=seed, clock_offset_s=offset_s)
            res = recover(load_sequence(root))
            errors.append(abs(res.report["pose_time_offset_s"] - truth.clock_offset_s))
            runtimes.append(res.report["runtime_s"])
        print(f"  {generator:11s} offset {offset_s:5.2f} s ({duration_s:.0f}-s recordings, {len(seeds)} seeds): "
              f"largest |error| {1e3 * max(errors):.3f} ms, median {1e3 * np.median(errors):.3f} ms; "
              f"recovery {np.median(runtimes):.2f} s median, {max(runtimes):.2f} s at most", flush=True)


def checks(generator: str, seeds: range, tmp: Path) -> None:
    from pipeline.checks.run import run_checks
    from pipeline.io import load_sequence

    for name, (fault, code) in CHECK_FAULTS.items():
        named, other = 0, 0
        for seed in seeds:
            root = tmp / f"{generator}_{name.replace(' ', '_').replace('/', '')}_{seed}"
            rf.write_recording(generator, root, duration_s=30.0, seed=seed)
            if fault is not None:
                fault(root)
            codes = {f.code for f in run_checks(load_sequence(root))} & set(RIG_CODES)
            named += code in codes
            other += bool(codes - {code})
        what = (f"{other} of {len(seeds)} with a rig finding" if code is None
                else f"{code} on {named} of {len(seeds)}, another rig finding on {other}")
        print(f"  {generator:11s} {name:18s}: {what}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="seeds of the rig checks")
    parser.add_argument("--recover-seeds", type=int, default=20, help="seeds of the clock-offset recoveries")
    args = parser.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        print("clock offsets, recovered with defaults:")
        for generator in rf.GENERATORS:
            offsets(generator, range(args.recover_seeds), Path(tmp))
        print("rig checks:")
        for generator in rf.GENERATORS:
            checks(generator, range(args.seeds), Path(tmp))
    print(f"[{time.perf_counter() - t0:.0f} s]")


if __name__ == "__main__":
    main()
