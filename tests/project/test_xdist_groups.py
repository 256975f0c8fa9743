"""``make test`` runs the suite with ``--dist loadgroup``: tests marked with one ``xdist_group`` (a shared costly
fixture, or one Snakemake working folder) must run on one worker. Some pytest and pytest-xdist pairs spread them
without a word (pytest 9.2 with pytest-xdist 3.8: pytest-xdist#1386); this checks the installed pair."""

from __future__ import annotations

import os
import subprocess
import sys

GROUPED = '''
import os
import pytest

pytestmark = pytest.mark.xdist_group("one")


@pytest.mark.parametrize("i", range(6))
def test_writes_its_worker(i):
    with open(os.path.join(os.environ["WORKERS_DIR"], str(i)), "w") as f:
        f.write(os.environ["PYTEST_XDIST_WORKER"])
'''


def test_tests_of_one_xdist_group_run_on_one_worker(tmp_path):
    (tmp_path / "test_grouped.py").write_text(GROUPED, encoding="utf-8")
    (tmp_path / "workers").mkdir()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p",
                           "no:cacheprovider", "test_grouped.py"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120, env={**os.environ, "WORKERS_DIR": str(tmp_path / "workers")})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    written = list((tmp_path / "workers").iterdir())
    workers = {p.read_text() for p in written}
    assert len(written) == 6
    assert len(workers) == 1, f"one xdist_group ran on {sorted(workers)}: install requirements.lock's pytest"
