"""The help and the README describe every stage of the workflow, the learning stages included."""

from __future__ import annotations

import re
from pathlib import Path

from pipeline.cli import main

REPO = Path(__file__).resolve().parents[1]
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
