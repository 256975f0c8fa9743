"""``docs/results.md``'s tables written from a run's results: ``python -m biasgt.results_doc``.

The page keeps its hand-written prose; every table that quotes a workflow run sits in a marked block,
and the run it quotes is declared once on the page::

    <!-- run euroc: biasgt run --config config/euroc.yaml --cores 2 | 2026-12-04 | bc525cd -->
    <!-- generated: seeds context_residual from euroc (results/evaluation) -->
    ...the table...
    <!-- end generated -->

A declaration names the run, the command that made it, the date its Table I was written and the
commit. A block names what it renders (:data:`KINDS`; ``seeds`` and ``summary`` take an argument),
the run and the folder of the run it reads. Every block opens with a line saying which run it
is from, so the page says it too. The run's folder is given on the command line,
``--run NAME=DIR`` (DIR: the folder ``biasgt run`` worked in); blocks of a run not given are left as
they are and named as not checked. From a run's folder the script reads:

* ``results/evaluation/*/summary.json`` and ``*/seed*/summary.json``: every figure (the same
  summaries the ``table`` stage reads), after checking that ``results/evaluation/table.csv`` holds
  the same values (a table older than its summaries is refused);
* ``logs/table/table.log``: the date Table I was written (its first line's date; ``--date NAME=DAY``
  overrides it).

The commit is ``--commit NAME=SHA``, else this checkout's ``HEAD`` (give ``--commit`` when the run
was made at another commit). Means over training seeds carry ± the standard deviation over seeds
(ddof 1). ``--write`` rewrites the blocks and declarations of the runs given (atomically);
``--check`` changes nothing and exits 1 naming the first block that differs. A missing or
malformed results file is one line naming the file and the fix, exit 2.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.errors import BiasgtError, ConfigError, DataError, InputFormatError
from pipeline.files.atomic import write_text_atomic

__all__ = ["KINDS", "Run", "RunResults", "load_results", "main", "render_page"]

#: The source checkout (this module lives in its ``biasgt/``).
REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "results.md"
#: The folder of a run every block kind reads, relative to the run's folder.
EVALUATION = "results/evaluation"
TABLE_LOG = "logs/table/table.log"

_RUN = re.compile(r"^<!-- run (?P<name>[\w.-]+): (?P<command>.+?) \| (?P<date>\S+) \| (?P<commit>\S+) -->$", re.M)
_BLOCK = re.compile(r"^<!-- generated: (?P<kind>\w+)(?: (?P<arg>[\w.,-]+))? from (?P<run>[\w.-]+) \((?P<source>[^)]+)\) -->\n"
                    r"(?P<body>.*?)^<!-- end generated -->$", re.S | re.M)

@dataclass(frozen=True)
class Run:
    """A run declared on the page: its name, the command that made it, the day and the commit."""

    name: str
    command: str
    date: str
    commit: str

    def declaration(self) -> str:
        return f"<!-- run {self.name}: {self.command} | {self.date} | {self.commit} -->"

    def caption(self) -> str:
        """The line opening each of the run's blocks."""
        return f"*From run `{self.name}`: `{self.command}`, {self.date}, commit `{self.commit}` (`{EVALUATION}`).*"


@dataclass(frozen=True)
class RunResults:
    """What a run's folder holds: Table I's columns (seeds kept apart) and the summaries behind them."""

    folder: Path
    summaries: list
    columns: list
    sequences: list[str]
    date: str

    def column(self, method: str, variant: str = ""):
        """The column of ``method`` (a network or reference name) and ``variant``, or None."""
        label = next((s.label for s in self.summaries if s.method == method), None)
        return next((c for c in self.columns if c.group == label and c.variant == variant), None)


def _cell(values: list[float]) -> str:
    text = f"{np.mean(values):.4f}"
    return text + (f" ± {np.std(values, ddof=1):.4f}" if len(values) > 1 else "")


def _pair(column, row: str, spread: bool = True) -> str:
    """``PRMSE / ROE`` of ``column`` in ``row`` (a sequence or Average); ± over seeds where ``spread``."""
    p, r = column.prmse_m[row], column.roe_deg[row]
    if not spread:
        p, r = [float(np.mean(p))], [float(np.mean(r))]
    return f"{_cell(p)} / {_cell(r)}"


def _row_name(column) -> str:
    return column.name + ("" if column.ranked or "oracle" in column.name.lower() else " (oracle)")


def _short(sequence: str) -> str:
    from training.evaluation.paper import paper_sequence

    return paper_sequence(sequence) or sequence


def _table(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
                      *("| " + " | ".join(r) + " |" for r in rows)])


def table1(res: RunResults, arg: str | None) -> str:
    """Table I, one row per method and variant: seeds, the average (± over seeds) and each sequence."""
    from training.evaluation.table import AVERAGE

    rows = [[_row_name(c), str(c.seeds), _pair(c, AVERAGE), *(_pair(c, s, False) for s in res.sequences)]
            for c in res.columns]
    return _table(["row", "seeds", "average", *map(_short, res.sequences)], rows)


def _training_seed(summary) -> int:
    """The seed a learned method was trained with (its checkpoint's; the summary's own is the sampling seed)."""
    return int((summary.checkpoint or {}).get("seed", summary.seed))


def seeds(res: RunResults, method: str | None) -> str:
    """One method's headline row per training seed, then the mean ± std over seeds of the average."""
    mine = sorted((s for s in res.summaries if s.method == method), key=_training_seed)
    if not mine:
        raise DataError(f"no evaluation of '{method}'", path=res.folder / EVALUATION,
                        hint=f"run the workflow with '{method}' in training.methods, or name another method in the marker")
    rows = []
    for s in mine:
        row = s.row()
        rows.append([str(_training_seed(s)), f"{row.average.prmse_m:.4f} / {row.average.roe_deg:.4f}",
                     *(f"{row.sequences[q].prmse_m:.4f} / {row.sequences[q].roe_deg:.4f}" for q in res.sequences)])
    p = [s.row().average.prmse_m for s in mine]
    r = [s.row().average.roe_deg for s in mine]
    rows.append(["mean ± std (ddof 1)" if len(mine) > 1 else "mean", f"**{_cell(p)} / {_cell(r)}**",
                 *([""] * len(res.sequences))])
    return _table(["seed", "average", *map(_short, res.sequences)], rows)


def summary(res: RunResults, names: str | None) -> str:
    """The page's summary rows from Table I: the best usable row (by average PRMSE, and by ROE where
    another row is best there), then the rows of ``names`` (comma-separated method or reference names)."""
    from training.evaluation.table import AVERAGE

    ranked = [c for c in res.columns if c.ranked]
    if not ranked:
        raise DataError("no usable row in Table I", path=res.folder / EVALUATION,
                        hint="evaluate at least one learned method or usable reference row")
    best_p = min(ranked, key=lambda c: np.mean(c.prmse_m[AVERAGE]))
    best_r = min(ranked, key=lambda c: np.mean(c.roe_deg[AVERAGE]))
    both = "; the best usable row in both metrics" if best_p is best_r else (
        f"; in ROE the best usable row is `{best_r.name}`, {_pair(best_r, AVERAGE)}")
    rows = [[f"Table I, best usable row in PRMSE: `{best_p.name}` ({best_p.seeds} seed{'s' * (best_p.seeds > 1)})",
             _pair(best_p, AVERAGE) + both]]
    for name in filter(None, (names or "").split(",")):
        column = res.column(name)
        if column is None:
            raise DataError(f"no evaluation of '{name}'", path=res.folder / EVALUATION,
                            hint="name a method or reference row of the run's Table I in the marker")
        what = f"`{name}`" if column.name == name else f"{column.name} (`{name}`)"
        rows.append([f"{what} ({column.seeds} seed{'s' * (column.seeds > 1)})", _pair(column, AVERAGE)])
    return _table(["what", "figure (PRMSE m / ROE deg, average over the test sequences)"], rows)


#: Block kind -> what renders it from a run's results (its argument: a method for ``seeds``, comma-separated
#: method and reference names for ``summary``).
KINDS: dict[str, Callable[[RunResults, str | None], str]] = {"table1": table1, "seeds": seeds, "summary": summary}


def _summary_paths(evaluation: Path) -> list[Path]:
    return sorted([*evaluation.glob("*/summary.json"), *evaluation.glob("*/seed*/summary.json")])


def _table_date(folder: Path) -> str:
    log = folder / TABLE_LOG
    try:
        first = log.read_text(encoding="utf-8").split("\n", 1)[0]
    except OSError:
        raise InputFormatError("no table log", path=log, hint="give the folder a 'biasgt run' wrote Table I in, or "
                               "the day with --date NAME=YYYY-MM-DD") from None
    m = re.match(r"(\d{4}-\d{2}-\d{2}) ", first)
    if not m:
        raise InputFormatError("the first line has no date", path=log, hint="give --date NAME=YYYY-MM-DD")
    return m.group(1)


def _check_table_csv(evaluation: Path, columns: list) -> None:
    """Table I's ``table.csv`` holds the summaries' values (else it is older than them)."""
    import pandas as pd

    from training.evaluation.table import TABLE_CSV, build_table

    path = evaluation / TABLE_CSV
    try:
        csv = pd.read_csv(path, index_col=0)
    except FileNotFoundError:
        raise InputFormatError("no Table I", path=path, hint="run the workflow's table stage "
                               "('biasgt run' writes it after the evaluations)") from None
    except (OSError, ValueError) as exc:
        raise InputFormatError(f"cannot read Table I ({exc})", path=path, hint="rerun the workflow's table stage") from None
    ours = build_table(columns)
    if (sorted(csv.columns) != sorted(ours.columns) or sorted(csv.index) != sorted(ours.index)
            or not np.allclose(csv.loc[ours.index, ours.columns].to_numpy(float), ours.to_numpy(float), rtol=1e-5)):
        raise DataError("Table I differs from the evaluation summaries beside it", path=path,
                        hint="rerun the workflow's table stage (biasgt run) so that both come from one run")


def load_results(folder: Path, date: str | None = None) -> RunResults:
    """Read a run's Table I (see the module docstring).

    Raises:
        BiasgtError: A missing or malformed file (named, with the fix).
    """
    from training.evaluation.outputs import read_summary
    from training.evaluation.table import AVERAGE, table_columns

    evaluation = folder / EVALUATION
    paths = _summary_paths(evaluation)
    if not paths:
        raise InputFormatError("no evaluation summaries", path=evaluation,
                               hint="give the folder 'biasgt run' worked in (--run NAME=DIR), after its evaluate stage")
    summaries = [read_summary(p) for p in paths]
    columns = table_columns(summaries)
    _check_table_csv(evaluation, columns)
    sequences = [s for s in columns[0].prmse_m if s != AVERAGE]
    return RunResults(folder, summaries, columns, sequences, date or _table_date(folder))


@dataclass(frozen=True)
class Block:
    """A marked block of the page: where it is, what renders it, from which run."""

    line: int
    kind: str
    arg: str | None
    run: str
    span: tuple[int, int]
    body: str

    def label(self) -> str:
        return f"line {self.line}: {self.kind}{' ' + self.arg if self.arg else ''} from {self.run}"


def parse_page(text: str, page: Path) -> tuple[dict[str, Run], list[Block]]:
    """The page's run declarations and blocks.

    Raises:
        ConfigError: A block of an undeclared run, of an unknown kind or reading another folder.
    """
    runs = {m["name"]: Run(m["name"], m["command"], m["date"], m["commit"]) for m in _RUN.finditer(text)}
    blocks = []
    for m in _BLOCK.finditer(text):
        block = Block(text.count("\n", 0, m.start()) + 1, m["kind"], m["arg"], m["run"], m.span("body"), m["body"])
        if block.kind not in KINDS:
            raise ConfigError(f"{block.label()}: no block kind '{block.kind}'", path=page,
                              hint=f"use one of {', '.join(KINDS)} (biasgt/results_doc.py)")
        if block.run not in runs:
            raise ConfigError(f"{block.label()}: run '{block.run}' is not declared", path=page,
                              hint=f"add '<!-- run {block.run}: COMMAND | YYYY-MM-DD | COMMIT -->' above it")
        if m["source"] != EVALUATION:
            raise ConfigError(f"{block.label()}: reads '{m['source']}'", path=page, hint=f"blocks read '{EVALUATION}'")
        blocks.append(block)
    if text.count("<!-- generated:") != len(blocks) or text.count("<!-- end generated -->") != len(blocks):
        raise ConfigError("a generated block's markers are unmatched or malformed", path=page,
                          hint="each '<!-- generated: KIND [ARG] from RUN (results/evaluation) -->' line needs its "
                               "'<!-- end generated -->' line")
    return runs, blocks


def render_page(text: str, results: dict[str, tuple[RunResults, str]], page: Path = PAGE
                ) -> tuple[str, list[Block], list[Block]]:
    """The page with the blocks and declarations of the runs in ``results`` (name -> (results, commit))
    rewritten; also the blocks that changed and the blocks left unchecked (their run not given).

    Raises:
        ConfigError: A run given that the page does not declare, or a malformed page (:func:`parse_page`).
    """
    runs, blocks = parse_page(text, page)
    for name in results:
        if name not in runs:
            raise ConfigError(f"run '{name}' is not declared", path=page,
                              hint=f"give a run the page declares: {', '.join(runs) or 'none yet'}")
    now = {name: replace(runs[name], date=res.date, commit=commit) for name, (res, commit) in results.items()}
    out, pos, changed, unchecked = [], 0, [], []
    for block in blocks:
        if block.run not in results:
            unchecked.append(block)
            continue
        res = results[block.run][0]
        body = now[block.run].caption() + "\n\n" + KINDS[block.kind](res, block.arg) + "\n"
        if body != block.body:
            changed.append(block)
        out += [text[pos:block.span[0]], body]
        pos = block.span[1]
    text = "".join(out) + text[pos:]
    for name, run in now.items():
        old = runs[name].declaration()
        if run.declaration() != old:
            changed.insert(0, Block(text[:text.index(old)].count("\n") + 1, "run", None, name, (0, 0), ""))
            text = text.replace(old, run.declaration())
    return text, changed, unchecked


def _pairs(items: list[str], option: str) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise ConfigError(f"{option} {item!r}: expected NAME=VALUE", field=option,
                              hint=f"for example {option} euroc=...")
        out[name] = value
    return out


def _head_commit() -> str:
    done = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short=7", "HEAD"], capture_output=True, text=True)
    if done.returncode != 0:
        raise ConfigError("this checkout has no git commit to name", field="--commit",
                          hint="give --commit NAME=SHA, the commit the run was made at")
    return done.stdout.strip()


def run(args: argparse.Namespace) -> int:
    folders = _pairs(args.run, "--run")
    dates, commits = _pairs(args.date, "--date"), _pairs(args.commit, "--commit")
    for option, given in (("--date", dates), ("--commit", commits)):
        for name in set(given) - set(folders):
            raise ConfigError(f"{option} names run '{name}' but no --run does", field=option,
                              hint=f"give --run {name}=DIR as well")
    results = {name: (load_results(Path(folder), dates.get(name)), commits.get(name) or _head_commit())
               for name, folder in folders.items()}
    page = args.page
    try:
        text = page.read_text(encoding="utf-8")
    except OSError:
        raise ConfigError("cannot read the page", path=page, hint="give --page the results page") from None
    new, changed, unchecked = render_page(text, results, page)
    for block in unchecked:
        print(f"{page}: {block.label()}: not checked (give --run {block.run}=DIR)", file=sys.stderr)
    if args.check:
        if changed:
            print(f"{page}: {changed[0].label()}: differs from the run's results; run python -m biasgt.results_doc "
                  f"--write --run {changed[0].run}=DIR", file=sys.stderr)
            return 1
        return 0
    if new != text:
        write_text_atomic(page, new)
        print(f"wrote {page}: " + "; ".join(b.label() for b in changed))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m biasgt.results_doc", description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="rewrite the blocks of the runs given")
    mode.add_argument("--check", action="store_true", help="change nothing; exit 1 naming the first differing block")
    parser.add_argument("--run", action="append", default=[], metavar="NAME=DIR",
                        help="a run the page declares, and the folder 'biasgt run' worked in (repeatable)")
    parser.add_argument("--commit", action="append", default=[], metavar="NAME=SHA",
                        help="the commit the run was made at (default: this checkout's HEAD)")
    parser.add_argument("--date", action="append", default=[], metavar="NAME=YYYY-MM-DD",
                        help="the day the run wrote Table I (default: from its logs/table/table.log)")
    parser.add_argument("--page", type=Path, default=PAGE, help="the results page (default: docs/results.md)")
    args = parser.parse_args(argv)
    try:
        return run(args)
    except BiasgtError as exc:
        print(f"python -m biasgt.results_doc: error: {exc}", file=sys.stderr)
        return exc.exit_code


if __name__ == "__main__":
    raise SystemExit(main())
