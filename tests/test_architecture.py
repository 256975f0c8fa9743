"""The layers of the code base (README "Architecture"), checked on every test run.

The contracts live in ``pyproject.toml`` (``[tool.importlinter]``); import-linter reads every
import, those inside functions included.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import grimp

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("biasgt", "pipeline", "recovery", "interpolation", "validation", "training", "reports")


def test_import_linter_contracts_hold() -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    lint = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(lint), "--no-cache", "--config", str(REPO / "pyproject.toml")], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def test_no_import_cycles() -> None:
    """No two modules import each other, directly or through others (imports in functions count)."""
    sys.path.insert(0, str(REPO))
    try:
        graph = grimp.build_graph(*PACKAGES, include_external_packages=False, cache_dir=None)
    finally:
        sys.path.remove(str(REPO))
    cycles = []
    for importer in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(importer)):
            # A package's __init__ importing its own submodules is not a cycle of the code.
            if imported.startswith(importer + ".") or importer.startswith(imported + "."):
                continue
            back = graph.find_shortest_chain(importer=imported, imported=importer)
            if back is not None:
                cycles.append(" -> ".join((importer, *back)))
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_no_private_name_is_imported_across_modules() -> None:
    """A ``_private`` name stays in its module: what another module needs is public where it is defined.

    Reads every ``from X import _name`` in the packages (imports inside functions included); a private
    submodule imported inside its own package (``pipeline.io._text`` from ``pipeline.io``) is allowed.
    """
    offences = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            here = module if path.name == "__init__.py" else module.rpartition(".")[0]
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not isinstance(node, ast.ImportFrom):
                    continue
                base = here.split(".")[: len(here.split(".")) - node.level + 1] if node.level else []
                target = ".".join(base + ([node.module] if node.module else [])) if node.level else node.module
                for alias in node.names:
                    name = alias.name
                    if not name.startswith("_") or name.startswith("__") or target == module:
                        continue
                    if (REPO / Path(*target.split("."), name)).with_suffix(".py").exists() and module.startswith(target):
                        continue  # a private submodule, used inside its own package
                    offences.append(f"{path.relative_to(REPO)}:{node.lineno} imports {target}.{name}")
    assert not offences, "private names imported across modules:\n" + "\n".join(offences)


def _verdict_words() -> set[str]:
    from pipeline.checks.options import CHECK_VERDICT_WORDS
    from pipeline.types import Verdict

    return {v.value for v in Verdict} | set(CHECK_VERDICT_WORDS.values())


def _literals(node: ast.AST) -> list[str]:
    return [n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def test_no_module_compares_a_verdict_as_a_string_literal() -> None:
    """A verdict is compared as :class:`pipeline.types.Verdict` (``Verdict.parse`` for one read from a file,
    ``check_verdict`` for the input checks' words), never as its text: no ``==``, ``!=``, ``in`` or ``is`` with a
    verdict word (PASS, WARN, FAIL, or the input checks' ok / repairable / fatal) as a literal, no text search
    for one (``startswith("validation WARN")``), and no table or list of those literals kept by hand."""
    words = _verdict_words()
    offences = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                found: list[str] = []
                if isinstance(node, ast.Compare):
                    found = [v for side in (node.left, *node.comparators) for v in _literals(side)
                             if v in words or any(w in v for w in ("PASS", "WARN", "FAIL") if v != w and len(v) < 20)]
                elif isinstance(node, (ast.Dict, ast.Tuple, ast.List, ast.Set)):  # a hand-kept table or list
                    items = node.keys if isinstance(node, ast.Dict) else node.elts
                    keys = [k.value for k in items if isinstance(k, ast.Constant) and isinstance(k.value, str)]
                    found = [k for k in keys if k in words] if sum(k in words for k in keys) >= 2 else []
                elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                      and node.func.attr in ("startswith", "endswith", "find", "index", "count")):
                    found = [v for arg in node.args for v in _literals(arg)
                             if any(w in v.split() or v == w for w in ("PASS", "WARN", "FAIL"))]
                if found:
                    offences.append(f"{path.relative_to(REPO)}:{node.lineno} {sorted(set(found))}")
    assert not offences, "verdicts compared as string literals:\n" + "\n".join(offences)


#: The most files one folder of the project may hold directly (beyond it, split the folder by role).
MAX_FILES_PER_FOLDER = 15


def test_no_top_level_folder_holds_more_than_fifteen_files() -> None:
    """The package folders, ``benchmarks/`` and ``tests/`` each hold at most 15 files directly.

    Counts the files (not folders, not ``__pycache__``) directly in each top-level folder; a
    subpackage or subfolder is its own folder and is counted on its own.
    """
    folders = [REPO / name for name in (*PACKAGES, "benchmarks", "tests")]
    crowded = {}
    for folder in folders:
        for here, dirs, files in os.walk(folder):
            dirs[:] = [d for d in dirs if d != "__pycache__" and not d.startswith(".") and not d.endswith(".egg-info")]
            count = sum(1 for f in files if not f.endswith(".pyc"))
            if count > MAX_FILES_PER_FOLDER:
                crowded[Path(here).relative_to(REPO).as_posix()] = count
    assert not crowded, f"folders over {MAX_FILES_PER_FOLDER} files (split them by role): {crowded}"
