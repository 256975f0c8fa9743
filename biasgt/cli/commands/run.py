"""``biasgt run``: run the whole workflow (the repository's Snakefile) with Snakemake."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from biasgt.workflow.config import DEFAULT_CONFIG, PROFILES_DIR, SNAKEFILE
from biasgt.workflow.run import resolve_profile, run_workflow, unlock_workflow

DESCRIPTION = f"""\
Run the biasgt workflow ({SNAKEFILE}) with Snakemake, stage by stage: simulate / ingest every
sequence of the config, recover the bias, interpolate it to the IMU rate, validate it, report (one
quality report per sequence), cut the window dataset of the train/val/test sequences (windows),
then the learning stages: train every method and seed of the config's training section, evaluate
each model and the references on the test split, table (Table I) and training_report (the
training report, results/report/training.html), and dataset_report (one page over every sequence,
results/report/index.html). The learning stages are most of a run's time.
Outputs go to results/<stage>/<sequence>/ (results/windows/dataset/, results/training/,
results/evaluation/) and logs to logs/<stage>/<sequence>.log under the working directory
(--directory, default: the current folder); the reports' paths are printed at the end. Finished
jobs are kept: rerunning only redoes what a changed input, parameter or code affects. The config is
checked before Snakemake starts.

On a SLURM cluster: biasgt run --config my.yaml --profile slurm (the Snakemake profile
workflow/profiles/slurm: executor settings and per-rule cores, memory, time and GPUs; see
docs/cluster.md). Everything after '--' goes to Snakemake unchanged and wins over the profile."""

EPILOG = f"""\
examples:
  biasgt run                              the default config ({DEFAULT_CONFIG.name}: simulated data)
  biasgt run --config config/euroc.yaml --cores 2
  biasgt run --dry-run                    show what would run
  biasgt run --until ingest               stop after the ingest jobs
  biasgt run --target results/ingest/sim_handheld_01
  biasgt run --profile slurm -- --default-resources slurm_account=ME slurm_partition=cpu
  biasgt run --profile slurm-cpu          a SLURM cluster without GPUs
  biasgt run -- --forceall                extra Snakemake arguments after '--'
  biasgt run -- --report run_report.html  Snakemake's HTML report of the finished run"""


def _cores(value: str) -> int | str:
    if value == "all":
        return value
    try:
        n = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'all', got {value!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'all', got {value!r}")
    return n


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run",
        help="run the whole workflow with Snakemake (simulate, ingest, recover, interpolate, validate, "
             "report, windows, train, evaluate, table, training report, dataset report)",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help=f"workflow config YAML (default: {DEFAULT_CONFIG})")
    p.add_argument("--cores", type=_cores, default=1, metavar="N",
                   help="cores Snakemake may use at once, or 'all' (default 1)")
    p.add_argument("--directory", type=Path, default=None, metavar="DIR",
                   help="working directory for results/ and logs/ (default: the current folder)")
    p.add_argument("--profile", default=None, metavar="NAME|DIR",
                   help=f"Snakemake profile: a name under {PROFILES_DIR.relative_to(SNAKEFILE.parent)}/ "
                        "(slurm) or a folder holding config.yaml")
    p.add_argument("-n", "--dry-run", action="store_true", help="only show the jobs that would run")
    p.add_argument("--until", nargs="+", default=[], metavar="RULE",
                   help="run only the jobs up to these rules (e.g. ingest)")
    p.add_argument("--target", nargs="+", default=[], metavar="TARGET",
                   help="build these files or rules instead of the whole workflow")
    p.add_argument("--unlock", action="store_true",
                   help="only clear the working directory's Snakemake lock (left by a run that was killed), once no "
                        "run works there; runs nothing")
    p.add_argument("snakemake_args", nargs="*", metavar="-- SNAKEMAKE_ARGS",
                   help="further Snakemake arguments, after '--'")
    p.set_defaults(func=main)


#: Snakemake options that only report or change bookkeeping: with one of them no job runs, so the run's
#: results and Table I are not printed as if it had finished.
NO_RUN_OPTIONS = ("--list", "-l", "--list-rules", "--list-target-rules", "--summary", "-S", "--detailed-summary",
                  "-D", "--dag", "--rulegraph", "--filegraph", "--lint", "--cleanup-metadata", "--cm", "--touch", "-t",
                  "--list-changes", "--lc", "--list-untracked", "--lu", "--delete-all-output", "--delete-temp-output")


def main(args: argparse.Namespace) -> int:
    import io

    from biasgt.workflow.run_summary import dry_run_summary, finished_summary, table_out_of_date

    if args.unlock or "--unlock" in args.snakemake_args:  # '-- --unlock' too: never read as a finished run
        workdir = unlock_workflow(config_file=args.config, workdir=args.directory)
        print(f"unlocked {workdir}: no run works there; nothing was run (biasgt run runs the workflow)")
        return 0
    profile = [] if args.profile is None else ["--profile", str(resolve_profile(args.profile))]
    # a dry run prints Snakemake's whole plan only with -v; else one line says what would run and why
    plan = io.StringIO() if args.dry_run and not getattr(args, "verbose", 0) else None
    result = run_workflow(
        config_file=args.config,
        cores=args.cores,
        workdir=args.directory,
        dry_run=args.dry_run,
        until=args.until,
        targets=args.target,
        extra=[*profile, *args.snakemake_args],
        echo=plan,
    )
    no_run = [a for a in args.snakemake_args if a.split("=")[0] in NO_RUN_OPTIONS]
    if no_run and not args.dry_run:
        print(f"snakemake {' '.join(no_run)}: nothing was run (its output is above)")
        return 0
    if args.dry_run:
        if plan is not None:
            print(dry_run_summary(plan.getvalue()) + " (biasgt -v run --dry-run shows the whole plan)")
        return 0
    results = result.workdir / "results"
    print(f"results: {results}" if results.is_dir() else f"results: none yet under {result.workdir}")
    stages = [p for p in result.outputs if p.suffix != ".html"]
    reports = [p for p in result.outputs if p.suffix == ".html"]
    for path in stages:
        print(f"  stage: {path}")
    if reports:
        print(f"reports ({len(reports)}):")
        for path in reports:
            print(f"  {path}")
    # a run stopped short of Table I (--until, --target, Snakemake options) may leave it behind the config
    partial = bool(args.until or args.target or args.snakemake_args)
    stale = table_out_of_date(args.config, result.workdir) if partial else None
    for line in finished_summary(result.workdir, stale):
        print(line)
    sys.stdout.flush()
    return 0
