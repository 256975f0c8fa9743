"""The README's "How to extend", followed to the letter: in a copy of the repository each of its four recipes
(a reader, a reference row, a network, a verdict rule) is its file written where the recipe says and its
registry line, read from the README's table with the placeholders filled in, put where the recipe says; then
``python -m biasgt.docs``. Each change is one new file and one added line (the docs' blocks aside), and the
checks it touches hold in the copy: the CLI's choices and help (with no torch), the config check, the verdict,
Table I, the docs, the names' single homes and the layers."""

from __future__ import annotations

import difflib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PLUGIN = REPO / "tests" / "plugin" / "biasgt_demo_plugin"

#: The placeholders of each recipe (the README's words for them) and the module that implements it, taken
#: from the demo plugin (which does what each recipe asks) with its names changed to the recipe's.
RECIPES = {
    "an input reader": ({"<name>": "imu_ms_g", "<label>": "an IMU log in ms and g",
                         "<help>": "an IMU log (t_ms, gyro rad/s, acc in g)"}, "reader.py", {}),
    "a Table I reference row": ({"<name>": "half_truth", "<label>": "Half the GT bias",
                                 "<help>": "half the recovered bias", "<inputs>": '"bias_mean",'}, "row.py", {}),
    "a network": ({"<name>": "linear_demo", "<Name>": "LinearDemo", "<label>": "Linear demo",
                   "<OBJECTIVE>": "REGRESSION", "<help>": "a linear regression of the window", "<colour>": "#17becf"},
                  "net.py", {"DemoOptions": "LinearDemoOptions", "DemoNet": "LinearDemo"}),
    "a verdict rule": ({"<name>": "short_recording", "<CODE>": "SHORT_RECORDING",
                        "<what it checks>": "a recording shorter than a minute",
                        "<the fix>": "record for a minute or more"}, "rule.py", {}),
}
#: The names the checks look for (tests/extension_check.py).
NAMES = {"reader": "imu_ms_g", "reader_help": "an IMU log (t_ms, gyro rad/s, acc in g)", "network": "linear_demo",
         "network_label": "Linear demo", "row": "half_truth", "row_label": "Half the GT bias",
         "rule": "SHORT_RECORDING", "rule_help": "a recording shorter than a minute",
         "rule_step": "record for a minute or more"}
#: The tests the recipes touch, run in the copy.
CHECKS = ["tests/project/test_docs.py", "tests/project/test_help_lists_stages.py", "tests/test_architecture.py",
          "tests/evaluation/test_registries.py::test_each_method_and_row_name_lives_in_at_most_two_package_files",
          "tests/inputs/test_io_registry.py::test_each_format_name_lives_in_its_entry_and_its_implementation",
          "tests/validate/test_validation_rules.py::test_every_rule_has_a_code_a_level_wording_and_is_listed_in_the_docs"]


def recipes() -> dict[str, tuple[str, str, str]]:
    """``{what: (file, registry line, where)}`` from the README's "How to extend" table."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text[text.index("- **How to extend**"):text.index("- **Checks**")]
    out = {}
    for row in re.findall(r"^\s*\| (an? [^|]+?) \| (.+) \|\s*$", section, re.M):
        what, rest = row[0], row[1]
        what = next((k for k in RECIPES if what.startswith(k)), None)
        if what is None:
            continue
        write, register = rest.split(" | ", 1)
        out[what] = (re.search(r"`([^`]+)`", write).group(1), re.search(r"`([^`]+)`", register).group(1),
                     register[register.index("`", register.index("`") + 1) + 1:])
    return out


def _fill(template: str, values: dict[str, str]) -> str:
    for key, value in values.items():
        template = template.replace(key, value)
    assert "<" not in template.replace("<=", ""), f"a placeholder left in {template!r}"
    return template


def _insert(text: str, line: str, where: str) -> str:
    """``text`` of a registry module with ``line`` put where the recipe says: just before an entry, or as the
    last entry of ``BUILTIN``."""
    start = text.index("\nBUILTIN = (\n") + 1
    end = text.index("\n)\n", start) + 1
    before = re.search(r"just before the `(\w+)` entry", where)
    if before:
        at = re.search(rf'^    \w+\("{before.group(1)}"', text[start:end], re.M).start() + start
    else:
        assert "as the last entry of `BUILTIN`" in where, where
        at = end
    return text[:at] + "    " + line + "\n" + text[at:]


def _copy_repository(dest: Path) -> Path:
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        if (REPO / name).is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, dest / name)
    return dest


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(cwd), "OMP_NUM_THREADS": "1"}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def test_the_readme_has_the_four_recipes():
    assert set(recipes()) == set(RECIPES)


@pytest.mark.slow
def test_the_four_recipes_followed_literally_are_one_file_and_one_line_each(tmp_path):
    copy = _copy_repository(tmp_path / "repo")
    registries = {}
    for what, (file, line, where) in recipes().items():
        values, module, renames = RECIPES[what]
        source = (PLUGIN / module).read_text(encoding="utf-8")
        for old, new in renames.items():
            source = source.replace(old, new)
        new_file = copy / _fill(file, values)
        assert not new_file.exists()
        new_file.write_text(source, encoding="utf-8")
        registry = copy / re.search(r"`([\w/]+\.py)`", where).group(1)
        registries[registry.relative_to(copy).as_posix()] = _fill(line, values)
        registry.write_text(_insert(registry.read_text(encoding="utf-8"), _fill(line, values), where), encoding="utf-8")
    docs = _run([sys.executable, "-m", "biasgt.docs"], copy)
    assert docs.returncode == 0, docs.stdout + docs.stderr
    written = {line.removeprefix("wrote ") for line in docs.stdout.split("\n") if line.startswith("wrote ")}
    # one file and one line each; the rest is what the docs generator wrote
    for name, line in registries.items():
        old = (REPO / name).read_text(encoding="utf-8").splitlines()
        new = (copy / name).read_text(encoding="utf-8").splitlines()
        diff = [d for d in difflib.unified_diff(old, new, lineterm="", n=0) if d[:1] in "+-" and d[:3] not in "+++---"]
        assert diff == ["+    " + line], diff
    changed = {p.relative_to(copy).as_posix() for p in copy.rglob("*") if p.is_file() and "__pycache__" not in p.parts
               and (not (REPO / p.relative_to(copy)).is_file()
                    or (REPO / p.relative_to(copy)).read_bytes() != p.read_bytes())}
    new_files = {_fill(file, RECIPES[what][0]) for what, (file, _, _) in recipes().items()}
    assert changed == new_files | set(registries) | written, changed
    assert written <= {"docs/inputs.md", "docs/evaluation.md", "docs/validation.md", "workflow/report/validate.rst",
                       "README.md"}
    # the checks the recipes touch
    check = _run([sys.executable, str(copy / "tests" / "extension_check.py"), str(tmp_path / "work"),
                  json.dumps(NAMES)], copy)
    assert check.returncode == 0 and check.stdout.strip().endswith("ok"), check.stdout[-3000:] + check.stderr[-3000:]
    tests = _run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-x", *CHECKS], copy)
    assert tests.returncode == 0 and re.search(r"\b\d{2,} passed", tests.stdout), tests.stdout[-4000:] + tests.stderr[-2000:]
