"""The docs' lists of readers, networks, reference rows and verdict rules are written from the registries
(``python -m biasgt.docs``): the checkout's are up to date, and a hand edit inside a block is caught and undone."""

from __future__ import annotations

import shutil
from pathlib import Path

from biasgt.docs import BLOCKS, main, outdated, write
from pipeline.io.registry import BUILTIN as READERS
from training.networks import BUILTIN as NETWORKS
from training.references import BUILTIN as ROWS
from validation.rules import BUILTIN as RULES

REPO = Path(__file__).resolve().parents[2]


def test_the_docs_blocks_are_up_to_date() -> None:
    assert outdated(REPO) == [], "the docs differ from the registries: run python -m biasgt.docs"


def test_every_builtin_entry_is_in_its_docs() -> None:
    text = {p: (REPO / p).read_text(encoding="utf-8") for p in {b.path for b in BLOCKS}}
    assert all(f"| `{r.name}`" in text["docs/inputs.md"] for r in READERS)
    assert all(f"| `{n.name}` |" in text["docs/evaluation.md"] for n in NETWORKS)
    assert all(f"| `{r.name}` |" in text["docs/evaluation.md"] for r in ROWS)
    assert all(f"| `{r.code}` |" in text["docs/validation.md"] for r in RULES)
    assert all(f"``{r.code}``" in text["workflow/report/validate.rst"] for r in RULES)
    assert "\\|".join(r.name for r in ROWS) in text["README.md"]


def test_a_hand_edit_in_a_block_is_found_and_rewritten(tmp_path: Path, capsys) -> None:
    for path in {b.path for b in BLOCKS}:
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / path, tmp_path / path)
    rules = tmp_path / "docs" / "validation.md"
    rules.write_text(rules.read_text().replace("| `NO_BASELINE` |", "| `NO_BASELINE_X` |"))
    assert outdated(tmp_path) == ["docs/validation.md"]
    assert main(["--check", "--root", str(tmp_path)]) == 1
    assert "docs/validation.md: out of date" in capsys.readouterr().err
    assert write(tmp_path) == ["docs/validation.md"] and outdated(tmp_path) == []
    assert rules.read_text() == (REPO / "docs" / "validation.md").read_text()
