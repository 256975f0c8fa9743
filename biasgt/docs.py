"""The docs' tables written from the registries: ``python -m biasgt.docs`` rewrites them.

Every list of readers, networks, reference rows and verdict rules in the docs is a marked block
generated from its registry's ``BUILTIN`` entries (a plugin's entries are its own to document):

* ``docs/inputs.md``: the formats (:data:`pipeline.io.registry.BUILTIN`);
* ``docs/evaluation.md``: the networks (:data:`training.networks.BUILTIN`) and the reference rows
  (:data:`training.references.BUILTIN`);
* ``docs/validation.md`` and ``workflow/report/validate.rst``: the verdict's rules
  (:data:`validation.rules.BUILTIN`);
* ``README.md``: the ``--reference`` names of ``biasgt evaluate``.

A block sits between ``<!--gen:NAME-->`` and ``<!--/gen:NAME-->`` in Markdown (inline or on lines of
their own) and between the comment lines ``.. gen:NAME`` and ``.. /gen:NAME`` in reStructuredText.
``python -m biasgt.docs --check`` changes nothing and exits 1 naming each block that is out of date
(``tests/project/test_docs.py`` runs it).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipeline.files.atomic import write_text_atomic
from pipeline.errors import ConfigError
from pipeline.registry import reference_name

__all__ = ["BLOCKS", "Block", "main", "outdated", "render", "write"]

#: The source checkout whose docs are written (this module lives in its ``biasgt/``).
REPO = Path(__file__).resolve().parents[1]


def _cell(text: str) -> str:
    """``text`` as one Markdown table cell (pipes escaped)."""
    return str(text).replace("|", "\\|")


def _table(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def formats_table() -> str:
    """docs/inputs.md: one row per reader, in detection order."""
    from pipeline.io.registry import BUILTIN

    rows = [(f"`{r.name}`" + (f" ({', '.join(f'`{a}`' for a in r.aliases)})" if r.aliases else ""),
             r.recognised or r.help, r.reads or r.help, r.notes) for r in BUILTIN]
    return _table(("`--format` (aliases)", "recognised by", "what is read", "notes"), rows)


def networks_table() -> str:
    """docs/evaluation.md: one row per network, in Table I's order."""
    from training.networks import BUILTIN

    rows = [(f"`{n.name}`", n.objective.value, n.help, f"`{reference_name(n.options)}`",
             "yes" if n.default else "on request") for n in BUILTIN]
    return _table(("method", "objective", "model", "options", "trained by default"), rows)


def references_table() -> str:
    """docs/evaluation.md: one row per reference row, in Table I's order."""
    from training.references import BUILTIN

    rows = [(f"`{r.name}`", r.label, r.help, "yes" if r.oracle else "", "yes" if r.default else "on request")
            for r in BUILTIN]
    return _table(("reference", "Table I label", "row", "oracle", "default"), rows)


def rules_table() -> str:
    """docs/validation.md: one row per verdict rule, in the reasons' order."""
    from validation.rules import BUILTIN

    rows = [(f"`{r.code}`", r.level.value, r.wording, "yes" if r.next_step else "-") for r in BUILTIN]
    return _table(("code", "level", "what it checks", "next step"), rows)


def rules_list() -> str:
    """workflow/report/validate.rst: the rules as a bullet list."""
    from validation.rules import BUILTIN

    return "\n".join(f"- ``{r.code}`` ({r.level.value}): {r.wording}" for r in BUILTIN)


def reference_names() -> str:
    """README.md: ``zero\\|train_mean\\|...``, the ``--reference`` names in a table cell."""
    from training.references import BUILTIN

    return "\\|".join(r.name for r in BUILTIN)


@dataclass(frozen=True)
class Block:
    """A generated block: the file (relative to the checkout), its marker name and what writes it."""

    path: str
    name: str
    render: Callable[[], str]

    def pattern(self) -> re.Pattern[str]:
        n = re.escape(self.name)
        if self.path.endswith(".rst"):
            return re.compile(rf"(^\.\. gen:{n}\n)(.*?)(^\.\. /gen:{n}$)", re.S | re.M)
        return re.compile(rf"(<!--gen:{n}-->)(.*?)(<!--/gen:{n}-->)", re.S)

    def body(self, old: str) -> str:
        """The new text between the markers (a block on lines of its own keeps its blank lines)."""
        text = self.render()
        if self.path.endswith(".rst"):
            return text + "\n"
        return f"\n{text}\n" if old.startswith("\n") else text


#: Every generated block.
BLOCKS = (
    Block("docs/inputs.md", "formats", formats_table),
    Block("docs/evaluation.md", "networks", networks_table),
    Block("docs/evaluation.md", "references", references_table),
    Block("docs/validation.md", "rules", rules_table),
    Block("workflow/report/validate.rst", "rules", rules_list),
    Block("README.md", "references", reference_names),
)


def render(root: Path = REPO) -> dict[Path, tuple[str, str]]:
    """``{file: (current text, generated text)}`` of every file with a block.

    Raises:
        ConfigError: A file lacks a block's markers.
    """
    out: dict[Path, tuple[str, str]] = {}
    for block in BLOCKS:
        path = root / block.path
        old, text = out.get(path, (None, None))
        if text is None:
            old = text = path.read_text(encoding="utf-8")
        pattern = block.pattern()
        if not pattern.search(text):
            raise ConfigError(f"no generated block '{block.name}'", path=path,
                              hint=f"put the markers of '{block.name}' back (see biasgt/docs.py)")
        text = pattern.sub(lambda m: m.group(1) + block.body(m.group(2)) + m.group(3), text, count=1)
        out[path] = (old, text)
    return out


def outdated(root: Path = REPO) -> list[str]:
    """The files whose blocks differ from what the registries say (relative paths)."""
    return [str(p.relative_to(root)) for p, (old, new) in render(root).items() if old != new]


def write(root: Path = REPO) -> list[str]:
    """Rewrite every out-of-date file (atomically); the files written."""
    written = []
    for path, (old, new) in render(root).items():
        if old != new:
            write_text_atomic(path, new)
            written.append(str(path.relative_to(root)))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m biasgt.docs", description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 when a block is out of date")
    parser.add_argument("--root", type=Path, default=REPO, help="the source checkout (default: this one)")
    args = parser.parse_args(argv)
    if args.check:
        stale = outdated(args.root)
        for path in stale:
            print(f"{path}: out of date with the registries; run python -m biasgt.docs", file=sys.stderr)
        return 1 if stale else 0
    for path in write(args.root):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
