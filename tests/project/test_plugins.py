"""Plugins from outside the package: a distribution installed beside biasgt (tests/plugin, its entry points
in the groups biasgt.readers, biasgt.networks, biasgt.references, biasgt.rules) adds a reader, a network, a
reference row and a verdict rule with no edit inside biasgt; a broken plugin stops a command with one line."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PLUGIN = Path(__file__).resolve().parents[1] / "plugin"
CHECK = Path(__file__).resolve().parents[1] / "extension_check.py"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The demo plugin installed with pip into a folder of its own (what ``pip install --target`` gives)."""
    work = tmp_path_factory.mktemp("plugin")
    source = shutil.copytree(PLUGIN, work / "source")
    target = work / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--disable-pip-version-check", "--target", str(target), str(source)],
                   check=True, capture_output=True, text=True, timeout=300)
    assert any(target.glob("biasgt_demo_plugin-*.dist-info/entry_points.txt"))
    return target


def _env(site: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)]), "OMP_NUM_THREADS": "1"}


@pytest.mark.slow
def test_an_installed_plugin_reaches_the_cli_config_check_verdict_and_table(installed, tmp_path):
    proc = subprocess.run([sys.executable, str(CHECK), str(tmp_path)], env=_env(installed),
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stdout[-3000:] + proc.stderr[-3000:]


def test_without_the_plugin_its_names_are_unknown():
    from training.networks import network_names
    from training.references import reference_names
    from validation.rules import RULES

    assert "demo_linear" not in network_names() and "demo_half_truth" not in reference_names()
    assert "DEMO_SHORT_RECORDING" not in RULES


def test_a_plugin_that_fails_to_load_stops_a_command_with_one_line(installed, tmp_path):
    broken = tmp_path / "site"
    shutil.copytree(installed, broken)
    (broken / "biasgt_demo_plugin" / "__init__.py").write_text("raise ImportError('no module named frobnicate')\n")
    proc = subprocess.run([sys.executable, "-m", "biasgt.cli", "train", "--help"], env=_env(broken),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot load the" in lines[0] and "plugin 'demo_" in lines[0], proc.stderr
    assert "biasgt-demo-plugin" in lines[0] and "pip uninstall biasgt-demo-plugin" in lines[0]
    assert "Traceback" not in proc.stderr
