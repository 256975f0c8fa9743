"""``biasgt run``: Snakemake in a subprocess.

:func:`snakemake_command` / :func:`run_workflow` run the workflow; :func:`resolve_profile` finds
its ``--profile`` (``workflow/profiles/<name>``, e.g. ``slurm``); :func:`describe_failure` names
the failed rule and its log.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from pipeline.errors import BiasgtError, ConfigError
from pipeline.files.atomic import no_space_error
from pipeline.layout import RESULTS_DIR
from biasgt.workflow.config import DEFAULT_CONFIG, PROFILES_DIR, SNAKEFILE, config_warnings, load_config
from biasgt.workflow.process_group import exclusive_lock, guard_parent, start_group, stop_group, workflow_processes

log = logging.getLogger(__package__)  # job logs name the workflow glue as one: 'biasgt.workflow'


class WorkflowRunError(BiasgtError):
    """Snakemake failed; the message names the failed rule and its log."""


def snakemake_command(
    *,
    config_file: str | Path,
    cores: int | str = 1,
    workdir: str | Path | None = None,
    dry_run: bool = False,
    until: Sequence[str] = (),
    targets: Sequence[str] = (),
    extra: Sequence[str] = (),
    snakefile: str | Path = SNAKEFILE,
    python: str = sys.executable,
) -> list[str]:
    """The Snakemake command line ``biasgt run`` executes."""
    cmd = [
        python, "-m", "snakemake",
        "--snakefile", str(Path(snakefile).resolve()),
        "--directory", str(Path(workdir or Path.cwd()).resolve()),
        "--configfile", str(Path(config_file).resolve()),
        "--replace-workflow-config",
        "--cores", str(cores),
        "--rerun-incomplete",
        "--show-failed-logs",
    ]
    if dry_run:
        cmd.append("--dry-run")
    if until:
        cmd += ["--until", *until]
    cmd += list(extra)
    cmd += list(targets)
    return cmd


def resolve_profile(profile: str | Path) -> Path:
    """The folder of a Snakemake profile: a name under :data:`PROFILES_DIR` (``slurm``) or a path.

    Raises:
        ConfigError: Neither names a folder holding a ``config.yaml``.
    """
    for candidate in (PROFILES_DIR / str(profile), Path(profile)):
        if (candidate / "config.yaml").is_file():
            return candidate.resolve()
    shipped = sorted(p.parent.name for p in PROFILES_DIR.glob("*/config.yaml"))
    raise ConfigError(f"no Snakemake profile '{profile}'", field="--profile",
                      hint=f"use one of {', '.join(shipped) or '(none)'} or a folder holding config.yaml")


JOB_HEADER = re.compile(r"^\s*(?:local)?(?:checkpoint|rule) ([A-Za-z0-9_]+):\s*$")


def parse_dry_run_jobs(text: str) -> list[tuple[str, dict[str, str]]]:
    """The jobs of a Snakemake dry-run printout, as ``(rule, wildcards)`` in printed order.

    Args:
        text: What ``snakemake --dry-run`` printed (stdout and stderr together).
    """
    jobs: list[tuple[str, dict[str, str]]] = []
    for line in text.splitlines():
        m = JOB_HEADER.match(line)
        if m:
            jobs.append((m.group(1), {}))
            continue
        w = _WILDCARDS_LINE.match(line)
        if w and jobs and not jobs[-1][1]:
            for item in w.group(1).split(", "):
                key, _, value = item.partition("=")
                jobs[-1][1][key.strip()] = value.strip()
    return jobs


#: The SLURM executor plugin's line when sbatch refuses a submission (its error text in quotes).
_SBATCH_REFUSAL = re.compile(r"SLURM sbatch failed.*?The error message was '(.*?)'\.?\s*$")
_ERROR_IN_RULE = re.compile(r"^\s*Error in rule ([A-Za-z0-9_]+):")
_LOG_LINE = re.compile(r"^\s*log:\s*(\S+)")
_WILDCARDS_LINE = re.compile(r"^\s*wildcards:\s*(.+)$")
_JOBID_LINE = re.compile(r"^\s*jobid:\s*(\d+)\s*$")
_NOISE = re.compile(r"^\s*(Shutting down|Complete log|Exiting because|Removing output|Will exit after|"
                    r"Select jobs|\[.*\]$|$)")


def describe_failure(lines: Sequence[str], workdir: str | Path) -> str:
    """One line saying why Snakemake failed, from the tail of its output.

    Names the failed rule, its wildcards and log file, and the last line of that log when it
    exists; otherwise the last informative line Snakemake printed. A failed group job (several
    rules in one cluster job) lists every rule of the group as failed: the one named is the first
    whose log holds an error.
    """
    refused = next((m.group(1) for ln in lines if (m := _SBATCH_REFUSAL.search(ln))), None)
    if refused is not None:  # the job never ran (its logs are empty): SLURM's own reason is the story
        failed = _failed_jobs(lines)
        where = f"rule '{failed[0][0]}'" if failed else "a job"
        return (f"SLURM refused to queue {where}: {refused} (ask for fewer resources, e.g. a CPU-only cluster: "
                "--profile slurm-cpu)")
    failed = _failed_jobs(lines)
    if not failed:
        informative = [ln.strip() for ln in lines if not _NOISE.match(ln)]
        return informative[-1] if informative else "snakemake failed without a message"
    logs = {log_rel: Path(workdir) / log_rel for _, _, log_rel in failed if log_rel}
    rule, wildcards, log_rel = next((job for job in failed if job[2] and _logged_error(logs[job[2]])), failed[0])
    text = f"rule '{rule}'" + (f" ({wildcards})" if wildcards else "") + " failed"
    if log_rel:
        last = _last_line(logs[log_rel])
        if last:
            text += f": {last}"
        text += f" (log: {logs[log_rel]})"
    return text


def _failed_jobs(lines: Sequence[str]) -> list[tuple[str, str | None, str | None]]:
    """(rule, wildcards, log path as printed) of each 'Error in rule' block of Snakemake's output."""
    # Snakemake's error block names the job id; its wildcards are in the job's announcement.
    wildcards_of_job: dict[str, str] = {}
    current_job: str | None = None
    for line in lines:
        if (j := _JOBID_LINE.match(line)):
            current_job = j.group(1)
        elif (w := _WILDCARDS_LINE.match(line)) and current_job is not None:
            wildcards_of_job.setdefault(current_job, w.group(1).strip())
        elif JOB_HEADER.match(line) or _ERROR_IN_RULE.match(line):
            current_job = None
    failed = []
    for i, line in enumerate(lines):
        m = _ERROR_IN_RULE.match(line)
        if not m:
            continue
        wildcards, log_rel = None, None
        for follow in lines[i + 1:i + 20]:
            if _ERROR_IN_RULE.match(follow):
                break
            if (w := _WILDCARDS_LINE.match(follow)) and wildcards is None:
                wildcards = w.group(1).strip()
            if (j := _JOBID_LINE.match(follow)) and wildcards is None:
                wildcards = wildcards_of_job.get(j.group(1))
            if (lg := _LOG_LINE.match(follow)) and log_rel is None:
                log_rel = lg.group(1).rstrip(",")  # executor plugins append their own logs
        failed.append((m.group(1), wildcards, log_rel))
    return failed


def _logged_error(path: Path) -> bool:
    """Whether a job's log holds an ERROR line (the job that failed, not one that never ran)."""
    try:
        return any(" ERROR " in ln for ln in path.read_text(encoding="utf-8", errors="replace").splitlines())
    except OSError:
        return False


def _last_line(path: Path) -> str | None:
    try:
        lines = [ln.strip() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
    except OSError:
        return None
    if not lines:
        return None
    # Prefer the logged error line over a traceback's last frame.
    for ln in reversed(lines):
        if " ERROR " in ln:
            return ln.split(": ", 1)[-1] if ": " in ln else ln
    return lines[-1]


@dataclass(frozen=True)
class RunResult:
    """Outcome of :func:`run_workflow`.

    Attributes:
        workdir: The working directory (outputs are under ``workdir/results``).
        command: The Snakemake command that ran.
        outputs: Result folders and report files found after the run.
    """

    workdir: Path
    command: list[str]
    outputs: list[Path]


def output_locations(workdir: str | Path) -> list[Path]:
    """The stage folders under ``results/`` and any HTML reports, sorted."""
    results = Path(workdir) / RESULTS_DIR
    if not results.is_dir():
        return []
    out = sorted(p for p in results.iterdir() if p.is_dir() and not p.name.startswith("."))
    out += sorted(p for p in results.rglob("*.html") if not any(part.startswith(".") for part in p.parts))
    return out


#: Held (flock) by a running ``biasgt run`` in its working directory: a second one says so. The
#: kernel releases it when the holder dies (even by ``kill -9``); the pid written in it is then stale.
RUN_LOCK = Path(".snakemake") / "biasgt-run.lock"
#: Snakemake's own lock files of a working directory (left behind when Snakemake was killed).
SNAKEMAKE_LOCKS = Path(".snakemake") / "locks"
#: Seconds a rerun waits for the Snakemake of a killed ``biasgt run`` to finish stopping.
ORPHAN_WAIT_S = 30.0


def guarded(cmd: Sequence[str]) -> list[str]:
    """``python -m snakemake ARGS`` as ``python -m biasgt.workflow.guarded_snakemake PID ARGS``: Snakemake
    that stops itself and its jobs when this process dies (:mod:`biasgt.workflow.guarded_snakemake`)."""
    cmd = list(cmd)
    if cmd[1:3] != ["-m", "snakemake"]:
        return cmd
    return [cmd[0], "-m", "biasgt.workflow.guarded_snakemake", str(os.getpid()), *cmd[3:]]


def _describe(procs: Sequence[object]) -> str:
    """``pid 12 (snakemake), pid 14 (recover.py)``: each process with the word that says what it runs."""
    out = []
    for p in procs:
        try:
            cmdline = p.cmdline()  # type: ignore[attr-defined]
        except Exception:  # noqa: BLE001 - psutil.Error: it ended meanwhile
            cmdline = []
        script = next((Path(c).name.split(".", 1)[-1] for c in cmdline if f"{os.sep}.snakemake{os.sep}" in c), None)
        out.append(f"pid {p.pid} ({script or 'snakemake'})")  # type: ignore[attr-defined]
    return ", ".join(out)


def check_no_earlier_run(workdir: Path, wait_s: float = ORPHAN_WAIT_S) -> None:
    """Refuse to start while Snakemake processes or jobs of an earlier run still work in ``workdir``
    (waiting ``wait_s`` for those of a killed ``biasgt run``, which stop by themselves).

    Raises:
        WorkflowRunError: Naming their pids and how to stop them.
    """
    import psutil

    live = workflow_processes(workdir)
    if live:
        log.warning("waiting up to %.0f s for an earlier run's Snakemake to stop in %s: %s", wait_s, workdir,
                    _describe(live))
        _, live = psutil.wait_procs(live, timeout=wait_s)
    if live:
        parent = _live_parent(live)
        leader = parent or live[0].pid
        charge = f"for the live 'biasgt run' pid {parent}" if parent else "without a 'biasgt run' in charge"
        raise WorkflowRunError(
            f"an earlier run's Snakemake still works in {workdir} {charge}: {_describe(live)}",
            hint=f"let it finish, or stop it (kill -INT {leader}: it cancels its jobs and removes their incomplete "
                 "outputs) and rerun")


def _live_parent(procs: Sequence[object]) -> int | None:
    """The live ``biasgt run`` a guarded Snakemake among ``procs`` serves, or None."""
    import psutil

    for p in procs:
        with contextlib.suppress(psutil.Error):
            parent = guard_parent(p.cmdline())  # type: ignore[attr-defined]
            if parent is not None and psutil.pid_exists(parent):
                return parent
    return None


def check_workdir_writable(workdir: Path) -> None:
    """Create ``workdir`` when missing and probe it by creating a file (permission bits do not tell on
    read-only mounts or for root): results/, logs/ and .snakemake/ are written there.

    Raises:
        NoSpaceError: The disk is full.
        WorkflowRunError: The folder cannot be created or written (read-only, no permission).
    """
    try:
        workdir.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".biasgt-write-probe.", dir=workdir)
    except OSError as exc:
        raise no_space_error(exc, workdir / RESULTS_DIR) or WorkflowRunError(
            f"cannot write in the working directory {workdir} ({exc.strerror})",
            hint="choose a writable --directory (results/, logs/ and .snakemake/ go there), or fix its "
                 "permissions") from None
    os.close(fd)
    os.unlink(probe)


def _stale_snakemake_lock(workdir: Path) -> bool:
    locks = workdir / SNAKEMAKE_LOCKS
    return locks.is_dir() and any(locks.iterdir())


def unlock_workdir(config_file: Path, workdir: Path) -> None:
    """``snakemake --unlock`` in ``workdir`` (its lock files go; nothing runs).

    Raises:
        WorkflowRunError: Snakemake failed (its last line).
    """
    cmd = snakemake_command(config_file=config_file, workdir=workdir, extra=["--unlock"])
    done = subprocess.run(cmd, capture_output=True, text=True, errors="replace")
    if done.returncode != 0:
        raise WorkflowRunError(f"snakemake --unlock failed in {workdir}: "
                               f"{describe_failure((done.stdout + done.stderr).splitlines(), workdir)}")


def _run_snakemake(cmd: list[str], echo: IO[str], *, keep_all: bool, workdir: Path,
                   progress_interval_s: float) -> tuple[int, list[str]]:
    """Run Snakemake in its own process group, copying its output to ``echo`` with one line per running
    job every ``progress_interval_s`` (:mod:`biasgt.workflow.job_progress`).

    On Ctrl-C (KeyboardInterrupt), SIGTERM (the CLI's ``Terminated``) or any other exception,
    Snakemake gets SIGINT and its jobs SIGTERM; Snakemake cancels its jobs and removes their
    incomplete outputs, and only then does the exception go on
    (:func:`biasgt.workflow.process_group.stop_group`).

    Returns:
        Snakemake's exit status and the tail of its output (all of it with ``keep_all``).
    """
    from biasgt.workflow.job_progress import JobProgress

    log.info("running %s", " ".join(cmd))
    tail: list[str] = []
    proc = start_group(guarded(cmd), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                       errors="replace")
    try:
        assert proc.stdout is not None
        with JobProgress(workdir, echo, interval_s=progress_interval_s) as jobs:
            for line in proc.stdout:
                jobs.write(line)
                tail.append(line.rstrip("\n"))
                if len(tail) > 4000 and not keep_all:  # a dry run's plan is kept whole for the caller
                    del tail[:1000]
        return proc.wait(), tail
    except BaseException:
        # Snakemake gets SIGINT for SIGTERM too (it ignores SIGTERM while SLURM jobs run; on SIGINT it
        # cancels them), its local jobs SIGTERM (a Python job stopped by SIGINT would print a
        # KeyboardInterrupt traceback from wherever it was, an import say)
        log.warning("stopping Snakemake: it cancels its jobs and removes their incomplete outputs")
        stop_group(proc, signal.SIGINT, signal.SIGTERM, echo=echo.write)
        raise
    finally:
        if proc.stdout is not None:
            proc.stdout.close()


def run_workflow(
    *,
    config_file: str | Path | None = None,
    cores: int | str = 1,
    workdir: str | Path | None = None,
    dry_run: bool = False,
    until: Sequence[str] = (),
    targets: Sequence[str] = (),
    extra: Sequence[str] = (),
    echo: IO[str] | None = None,
    progress_interval_s: float = 30.0,
) -> RunResult:
    """Check the config, then run the workflow with Snakemake in a subprocess.

    Snakemake's own output (stdout and stderr) is copied to ``echo`` (default ``sys.stderr``) as it
    comes, so that the caller's stdout holds only its result; every ``progress_interval_s`` one line
    per running job (its log's last line: :mod:`biasgt.workflow.job_progress`) goes there too.

    Args:
        config_file: Workflow config (default: the repository's ``config/config.yaml``).
        cores: Cores Snakemake may use (an int or ``"all"``).
        workdir: Working directory holding ``results/`` and ``logs/`` (default: current folder).
        dry_run: Only show what would run.
        until: Run only up to these rules or files.
        targets: Files or rules to build instead of ``rule all``.
        extra: Further Snakemake arguments, passed unchanged (e.g. ``--executor slurm``).
        echo: Where Snakemake's output is copied to.

    Returns:
        The run's working directory, command and outputs.

    Raises:
        ConfigError: The config is invalid (checked before Snakemake starts).
        WorkflowRunError: Snakemake failed; the message names the failed rule and its log.
    """
    config_file = Path(config_file or DEFAULT_CONFIG)
    workdir = Path(workdir or Path.cwd()).resolve()
    for warning in config_warnings(load_config(config_file)):  # fail early, on one line, for a bad config
        log.warning("%s: %s", config_file, warning)
    cmd = snakemake_command(config_file=config_file, cores=cores, workdir=workdir, dry_run=dry_run,
                            until=until, targets=targets, extra=extra)
    check_workdir_writable(workdir)
    echo = echo or sys.stderr
    with exclusive_lock(workdir / RUN_LOCK) as holder:
        if holder is not None and not dry_run:
            raise WorkflowRunError(
                f"another 'biasgt run' (pid {holder or 'unknown'}) is running in {workdir}",
                hint=f"wait for it to finish, or stop it (kill -INT {holder or 'PID'}) and rerun; its outputs are "
                     "locked while it runs")
        if not dry_run:
            check_no_earlier_run(workdir)
            if _stale_snakemake_lock(workdir):  # no biasgt run and no Snakemake works here: a killed run's lock
                log.warning("clearing the Snakemake lock a killed run left in %s (no Snakemake works there)", workdir)
                unlock_workdir(config_file, workdir)
        rc, tail = _run_snakemake(cmd, echo, keep_all=dry_run, workdir=workdir, progress_interval_s=progress_interval_s)
    if rc != 0 and any("cannot be locked" in line for line in tail):  # a Snakemake this machine does not see
        raise WorkflowRunError(
            f"the working directory {workdir} is locked by another Snakemake (another machine's run, or one "
            "started by hand)",
            hint=f"if no run works there any more, clear the lock with: biasgt run --unlock --directory {workdir}")
    if rc != 0:
        raise WorkflowRunError(
            f"workflow failed (snakemake exit {rc}): {describe_failure(tail, workdir)}",
            hint="fix the cause and rerun 'biasgt run' (finished jobs are kept)",
        )
    return RunResult(workdir, cmd, [] if dry_run else output_locations(workdir))


def unlock_workflow(*, config_file: str | Path | None = None, workdir: str | Path | None = None) -> Path:
    """Clear Snakemake's lock on ``workdir`` (``biasgt run --unlock``) once nothing works there.

    Returns:
        The working directory.

    Raises:
        WorkflowRunError: A ``biasgt run`` or Snakemake processes still work there (named), or
            ``snakemake --unlock`` failed.
    """
    config_file = Path(config_file or DEFAULT_CONFIG)
    workdir = Path(workdir or Path.cwd()).resolve()
    check_workdir_writable(workdir)
    with exclusive_lock(workdir / RUN_LOCK) as holder:
        if holder is not None:
            raise WorkflowRunError(f"a 'biasgt run' (pid {holder or 'unknown'}) is running in {workdir}: its lock "
                                   "is not stale", hint=f"wait for it to finish, or stop it (kill -INT "
                                                        f"{holder or 'PID'}); nothing to unlock")
        check_no_earlier_run(workdir, wait_s=0.0)
        unlock_workdir(config_file, workdir)
    return workdir
