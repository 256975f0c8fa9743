"""Benchmark: read + check an input (``pipeline.io.load_sequence`` then ``pipeline.checks.run_checks``).

Cases (each measured in its own subprocess, so the peak RSS is that case's alone):

* ``v101``: the real EuRoC V1_01_easy folder (29120 IMU rows), from the shared data folder;
* ``hour``: a simulated 1-hour 200-Hz IMU (720000 rows, pipeline.sim: handheld motion, noise, bias)
  written as an EuRoC/ASL ``mav0/imu0/data.csv`` in a temporary folder, read back through
  ``load_sequence``.

Targets: v101 <= 0.5 s; hour <= 5 s and <= 1 GB peak RSS (wall-clock seconds; the CPU
seconds are printed too, since a loaded machine inflates wall time). Prints one line per
case; ``--strict`` exits 1 when a target is missed.

Usage::

    .venv/bin/python benchmarks/pipeline/ingest.py [--strict]
    .venv/bin/python benchmarks/pipeline/ingest.py --case hour --input DIR   (one case, JSON line; used internally)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SHARED_DATA = Path(os.environ.get("BIASGT_SHARED_DATA", REPO.parent / "shared" / "data"))
TARGETS = {"v101": {"seconds": 0.5, "peak_rss_mb": None}, "hour": {"seconds": 5.0, "peak_rss_mb": 1024.0}}
CHECK_CPU_TARGET_S = 1.0  # the checks alone on one hour at 200 Hz


def write_hour_asl(root: Path, duration_s: float = 3600.0, rate_hz: float = 200.0, seed: int = 0) -> Path:
    """Simulate a 1-hour sequence (pipeline.sim) and write its IMU as ``root/mav0/imu0/data.csv``.

    The IMU comes from the project's simulator (handheld motion, EuRoC-like noise, random-walk
    bias); it is written with pyarrow's CSV writer (full precision, integer ns) because the
    simulator's own writer, which also writes poses and the ground truth, is slow for an hour.
    """
    import pyarrow as pa
    import pyarrow.csv as pcsv

    from pipeline.sim import SimConfig, simulate

    config = SimConfig.from_dict({"duration_s": duration_s, "seed": seed, "imu": {"rate_hz": rate_hz}})
    imu = simulate(config).sequence.imu
    d = root / "mav0" / "imu0"
    d.mkdir(parents=True, exist_ok=True)
    header = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
    table = pa.table({"t": imu.t_ns, **{f"g{i}": imu.gyro_radps[:, i] for i in range(3)},
                      **{f"a{i}": imu.acc_mps2[:, i] for i in range(3)}})
    with open(d / "data.csv", "wb") as f:
        f.write(header.encode("ascii"))
        pcsv.write_csv(table, f, pcsv.WriteOptions(include_header=False))
    return root


def measure(input_path: Path) -> dict:
    """Read and check ``input_path`` in this process; seconds exclude the imports."""
    from pipeline.checks.run import run_checks
    from pipeline.io import load_sequence

    c0, t0 = time.process_time(), time.perf_counter()
    seq = load_sequence(input_path)
    t1, c1 = time.perf_counter(), time.process_time()
    findings = run_checks(seq)
    t2, c2 = time.perf_counter(), time.process_time()
    return {
        "rows": 0 if seq.imu is None else len(seq.imu),
        "read_s": round(t1 - t0, 4),
        "check_s": round(t2 - t1, 4),
        "seconds": round(t2 - t0, 4),
        "cpu_s": round(c2 - c0, 4),
        "check_cpu_s": round(c2 - c1, 4),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "findings": sorted({f.code for f in findings}),
    }


def run_case(case: str, input_path: Path) -> dict:
    proc = subprocess.run(
        [sys.executable, __file__, "--case", case, "--input", str(input_path)],
        capture_output=True, text=True, check=False,
    )
    if proc.returncode != 0:
        raise SystemExit(f"case {case} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=sorted(TARGETS))
    parser.add_argument("--input", type=Path)
    parser.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    args = parser.parse_args()
    if args.case:
        print(json.dumps(measure(args.input)))
        return 0
    results = {}
    v101 = SHARED_DATA / "euroc" / "V1_01_easy"
    if v101.is_dir():
        results["v101"] = run_case("v101", v101)
    else:
        print(f"v101: skipped ({v101} is absent)")
    with tempfile.TemporaryDirectory(prefix="biasgt-bench-") as tmp:
        t0 = time.perf_counter()
        root = write_hour_asl(Path(tmp) / "hour")
        print(f"(wrote the 1-hour CSV in {time.perf_counter() - t0:.1f} s, "
              f"{(root / 'mav0/imu0/data.csv').stat().st_size / 1e6:.0f} MB)")
        results["hour"] = run_case("hour", root)
    missed = 0
    for case, r in results.items():
        tgt = TARGETS[case]
        ok = r["seconds"] <= tgt["seconds"] and (tgt["peak_rss_mb"] is None or r["peak_rss_mb"] <= tgt["peak_rss_mb"])
        missed += not ok
        limit = f"<= {tgt['seconds']} s" + (f", <= {tgt['peak_rss_mb']:.0f} MB" if tgt["peak_rss_mb"] else "")
        print(f"{case}: {r['rows']} IMU rows, read {r['read_s']:.3f} s + check {r['check_s']:.3f} s = "
              f"{r['seconds']:.3f} s wall ({r['cpu_s']:.3f} s CPU, checks {r['check_cpu_s']:.3f} s CPU: target "
              f"<= {CHECK_CPU_TARGET_S} s), "
              f"peak RSS {r['peak_rss_mb']:.0f} MB (target {limit}: "
              f"{'ok' if ok else 'MISSED'}); findings {', '.join(r['findings']) or 'none'}")
    return 1 if (missed and args.strict) else 0


if __name__ == "__main__":
    sys.exit(main())
