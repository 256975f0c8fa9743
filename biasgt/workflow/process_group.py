"""A child process in its own process group, stopped with everything it started.

``biasgt run`` starts Snakemake this way (:func:`start_group`). On Ctrl-C or SIGTERM the command
stops the whole group (:func:`stop_group`): Snakemake cancels its running jobs and removes their
incomplete outputs, and only then does ``biasgt run`` exit; whatever still runs after the grace
period (a job that ignores the signal) is killed, so no process is left orphaned.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import subprocess
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO

import psutil

__all__ = ["STOP_GRACE_S", "end_processes", "start_group", "stop_group", "exclusive_lock", "workflow_processes"]

#: Seconds the group gets to clean up after the forwarded signal before it is killed (SLURM's
#: ``scancel`` of many jobs takes a while).
STOP_GRACE_S = 120.0
#: Seconds a left-over process gets after SIGTERM before SIGKILL.
_KILL_AFTER_S = 5.0


def end_processes(processes: Sequence[psutil.Process]) -> None:
    """End those of ``processes`` still running: SIGTERM, then SIGKILL after ``_KILL_AFTER_S``."""
    left = [p for p in processes if p.is_running()]
    for p in left:
        with contextlib.suppress(psutil.Error):
            p.terminate()
    _, alive = psutil.wait_procs(left, timeout=_KILL_AFTER_S)
    for p in alive:
        with contextlib.suppress(psutil.Error):
            p.kill()
    psutil.wait_procs(alive, timeout=_KILL_AFTER_S)


def start_group(cmd: Sequence[str], **popen_kwargs) -> subprocess.Popen:
    """``subprocess.Popen(cmd)`` as the leader of a new process group (and session)."""
    return subprocess.Popen(list(cmd), start_new_session=True, **popen_kwargs)


def _descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _drain(stream: IO[str] | None, echo: Callable[[str], None] | None) -> threading.Thread | None:
    """Copy what the group still prints while it cleans up (a full pipe would block its exit)."""
    if stream is None:
        return None

    def copy() -> None:
        with contextlib.suppress(OSError, ValueError):
            for line in stream:
                if echo is not None:
                    echo(line)

    thread = threading.Thread(target=copy, daemon=True)
    thread.start()
    return thread


@contextlib.contextmanager
def _stop_signals_ignored() -> Iterator[None]:
    """A second Ctrl-C while the group cleans up must not cut the clean-up short."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def stop_group(proc: subprocess.Popen, leader_signal: int = signal.SIGINT, others_signal: int = signal.SIGTERM, *,
               grace_s: float = STOP_GRACE_S, echo: Callable[[str], None] | None = None) -> int:
    """Stop ``proc`` and everything it started; wait for its clean-up, then end every process it left.

    ``proc`` gets ``leader_signal`` (Snakemake cancels its jobs on SIGINT, also SLURM ones with
    ``scancel``), the processes of its group ``others_signal`` (a Python job stopped by SIGTERM
    ends without a KeyboardInterrupt traceback). After ``grace_s`` the group is killed.

    Args:
        proc: A process started by :func:`start_group`.
        leader_signal / others_signal: The signals sent.
        grace_s: How long the group may take to clean up before it is killed.
        echo: Receives each line ``proc.stdout`` still prints (when it is a text pipe).

    Returns:
        ``proc``'s exit status.
    """
    with _stop_signals_ignored():
        started = _descendants(proc.pid)
        for p in started:
            with contextlib.suppress(psutil.Error, ProcessLookupError):
                if os.getpgid(p.pid) == proc.pid:
                    p.send_signal(others_signal)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(proc.pid, leader_signal)
        drain = _drain(proc.stdout, echo)
        try:
            rc = proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)
            rc = proc.wait()
        # jobs that left the group (a new session) or outlived their parent
        end_processes(started)
        if drain is not None:
            drain.join(timeout=_KILL_AFTER_S)
    return rc


@contextlib.contextmanager
def exclusive_lock(path: str | Path) -> Iterator[int | None]:
    """Hold an exclusive ``flock`` on ``path`` (holding this process's id) while the block runs.

    Yields:
        ``None`` when the lock is held; else the process id written by the holder (0 if unknown),
        and the block runs without the lock.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            text = os.pread(fd, 32, 0).decode(errors="replace").strip()
            yield int(text) if text.isdigit() else 0
            return
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield None
    finally:
        os.close(fd)


def _is_snakemake(cmdline: Sequence[str]) -> bool:
    """Snakemake (``snakemake``, ``-m snakemake``, the guarded launcher) or one of its script jobs."""
    return any(part == "snakemake" or part.endswith(("/snakemake", "guarded_snakemake"))
               or f"{os.sep}.snakemake{os.sep}" in part for part in cmdline)


def working_directory(cmdline: Sequence[str], cwd: str) -> str:
    """The folder a Snakemake process or job works in: Snakemake's ``--directory``/``-d`` (relative to its
    ``cwd``), else the workdir of a job's script under ``WORKDIR/.snakemake/``, else ``cwd``. The
    Snakefile's path says nothing of it (every run from one checkout shares it)."""
    for i, part in enumerate(cmdline):
        value = (cmdline[i + 1] if part in ("--directory", "-d") and i + 1 < len(cmdline)
                 else part.partition("=")[2] if part.startswith("--directory=") else None)
        if value:
            return os.path.normpath(os.path.join(cwd, value))
    marker = f"{os.sep}.snakemake{os.sep}"
    for part in cmdline:
        if marker in part:
            return os.path.normpath(part.split(marker, 1)[0])
    return cwd


def guard_parent(cmdline: Sequence[str]) -> int | None:
    """The ``biasgt run`` pid a guarded Snakemake (:mod:`biasgt.workflow.guarded_snakemake`) serves, or None."""
    for i, part in enumerate(cmdline[:-1]):
        if part.endswith("guarded_snakemake") and cmdline[i + 1].isdigit():
            return int(cmdline[i + 1])
    return None


def workflow_processes(workdir: str | Path) -> list[psutil.Process]:
    """The Snakemake processes and jobs of this machine (other than this process) that work in
    ``workdir`` (:func:`working_directory`): those of runs in other folders do not count, even from
    the same checkout.

    Sorted by start time (Snakemake before its jobs).
    """
    workdir = str(Path(workdir).resolve())
    found = []
    for p in psutil.process_iter(["pid", "cmdline", "create_time"]):
        if p.pid == os.getpid():
            continue
        with contextlib.suppress(psutil.Error):
            cmdline = p.info["cmdline"] or []
            if _is_snakemake(cmdline) and working_directory(cmdline, p.cwd()) == workdir:
                found.append(p)
    return sorted(found, key=lambda p: p.info.get("create_time") or 0.0)
