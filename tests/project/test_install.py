"""``biasgt run`` from a non-editable install, outside the source tree (the workflow ships as package data)."""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: int = 600) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{cmd}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.mark.slow
def test_biasgt_run_from_a_non_editable_install_outside_the_source_tree(tmp_path):
    # the project's files (tracked, or new and not ignored) copied away from the checkout
    listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                            capture_output=True, text=True, check=True).stdout.split("\n")
    src = tmp_path / "src"
    for name in filter(None, listed):
        if (REPO / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, src / name)
    # a fresh environment whose dependencies are this one's (no download), without biasgt itself
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], tmp_path, dict(os.environ))
    python = venv / "bin" / "python"
    purelib = Path(subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                  capture_output=True, text=True, check=True).stdout.strip())
    (purelib / "deps.pth").write_text("\n".join(site.getsitepackages()) + "\n", encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    _run([python, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", src], tmp_path, env)
    shutil.rmtree(src)  # nothing may come from the source tree any more

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = _run([python, "-c", "import biasgt.workflow.config as wf; print(wf.__file__); print(wf.SNAKEFILE)"],
                 elsewhere, env).stdout.split()
    assert all(Path(p).is_relative_to(purelib) for p in where), where
    out = _run([venv / "bin" / "biasgt", "-v", "run", "--dry-run"], elsewhere, env)  # -v: the whole plan
    text = out.stdout + out.stderr
    assert f"Snakefile: {purelib / 'biasgt' / 'workflow_files' / 'Snakefile'}" in text
    for rule in ("simulate", "ingest", "recover", "interpolate", "validate", "windows", "report"):
        assert f"rule {rule}:" in text or f"checkpoint {rule}:" in text, rule
    assert not (elsewhere / "results").exists()  # a dry run writes no results
