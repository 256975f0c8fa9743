"""The help and the README describe every stage of the workflow, the learning stages included."""

from __future__ import annotations

import re
from pathlib import Path

from biasgt.cli.app import main

REPO = Path(__file__).resolve().parents[2]
#: The workflow's stages: one rule file each (common.smk holds shared helpers).
STAGES = sorted(p.stem for p in (REPO / "workflow" / "rules").glob("*.smk") if p.stem != "common")


def _help(argv: list[str], capsys) -> str:
    try:
        main(argv)
    except SystemExit:
        pass
    return re.sub(r"\s+", " ", capsys.readouterr().out)


def test_run_help_and_the_command_list_name_every_stage(capsys) -> None:
    assert {"train", "evaluate", "table", "training_report"} <= set(STAGES)
    run_help = _help(["run", "--help"], capsys)
    top = _help(["--help"], capsys)
    run_line = top[top.index(" run "):]
    for stage in STAGES:
        assert stage in run_help, stage
        assert stage.replace("_", " ") in run_line, stage


def test_readme_introduces_and_lists_the_learning_commands() -> None:
    text = (REPO / "README.md").read_text()
    intro = text.split("## ")[0]
    for word in ("biasgt train", "biasgt evaluate", "Table I", "training report", "biasgt predict"):
        assert word in intro, word
    table = text[text.index("## CLI reference"):]
    for command in ("inspect", "convert", "simulate", "recover", "interpolate", "validate", "windows", "train",
                    "evaluate", "predict", "export", "report", "run"):
        assert re.search(rf"^\| `biasgt {command}\b", table, re.M), command


def test_make_run_time_comes_from_a_benchmark_that_runs_what_make_run_runs() -> None:
    import subprocess
    import sys

    text = (REPO / "README.md").read_text()
    claim = text[text.index("How long `make run` takes"):text.index("`make test` runs ")]
    assert "benchmarks/pipeline/make_run.py" in claim and "about 2 minutes" not in text
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "pipeline" / "make_run.py"), "--print-command"],
                         capture_output=True, text=True, check=True).stdout.split()
    make = (REPO / "Makefile").read_text()
    assert "biasgt run --cores $(CORES)" in make and "CORES ?= 2" in make
    assert out[out.index("run"):out.index("run") + 1] == ["run"] and out[out.index("--cores") + 1] == "2"
    assert out[out.index("--config") + 1] == str(REPO / "config" / "config.yaml")


def test_help_imports_no_model_or_solver_library():
    """Registering the commands imports none of their implementations: ``biasgt --help`` and a command's
    ``--help`` load neither torch nor GTSAM, scipy or pandas (checked in a fresh interpreter)."""
    import subprocess
    import sys

    code = ("import contextlib, io, sys\n"
            "from biasgt.cli.app import main\n"
            "for argv in (['--help'], ['recover', '--help'], ['evaluate', '--help'], ['export', '--help']):\n"
            "    with contextlib.redirect_stdout(io.StringIO()):\n"
            "        try:\n"
            "            main(argv)\n"
            "        except SystemExit:\n"
            "            pass\n"
            "print(sorted(m for m in ('torch', 'gtsam', 'scipy', 'pandas') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
