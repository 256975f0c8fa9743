"""How long 'make run' takes: the whole default workflow in a fresh folder, wall and CPU time.

    .venv/bin/python benchmarks/pipeline/make_run.py [--cores 2] [--config config/config.yaml]

Runs ``biasgt run --cores N`` (what ``make run`` calls) in a new temporary working directory, so
nothing is reused, and prints the wall time, the CPU time of every process it started, and the
machine's load average before and after: a figure measured under load (the load average above the
core count) is not the idle-core figure the README quotes. ``--print-command`` only prints the
command it would run.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def command(cores: int, config: Path, workdir: Path) -> list[str]:
    """The ``biasgt run`` command line of the benchmark."""
    return [sys.executable, "-m", "biasgt.cli", "-q", "run", "--config", str(config), "--cores", str(cores),
            "--directory", str(workdir)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--config", type=Path, default=REPO / "config" / "config.yaml")
    parser.add_argument("--print-command", action="store_true", help="print the command and stop")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="biasgt-make-run-") as tmp:
        cmd = command(args.cores, args.config.resolve(), Path(tmp))
        if args.print_command:
            print(" ".join(cmd))
            return 0
        load_before = os.getloadavg()[0]
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, cwd=REPO, stdout=subprocess.DEVNULL).returncode
        wall = time.perf_counter() - t0
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        load_after = os.getloadavg()[0]
    cpu = usage.ru_utime + usage.ru_stime
    print(f"make run (biasgt run --cores {args.cores}): exit {rc}, wall {wall / 60:.1f} min, CPU {cpu / 60:.1f} min, "
          f"load average {load_before:.1f} before / {load_after:.1f} after on {os.cpu_count()} cores"
          + ("" if load_before < args.cores else " (under load: not an idle-core figure)"))
    return rc


if __name__ == "__main__":
    sys.exit(main())
