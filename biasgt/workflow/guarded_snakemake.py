"""Snakemake that stops itself and its jobs when the ``biasgt run`` that started it is gone.

``biasgt run`` starts Snakemake in its own session (:mod:`biasgt.workflow.process_group`), so a
``kill -9`` of the ``biasgt run`` process group does not reach it: left alone it would go on running
(and keep its jobs and its lock on the working directory). Started as

    python -m biasgt.workflow.guarded_snakemake PARENT_PID SNAKEMAKE_ARGS...

this module runs Snakemake in the same process, after asking the kernel for SIGHUP when the
parent dies (Linux ``prctl(PR_SET_PDEATHSIG)`` through ctypes; elsewhere a thread that watches
the parent pid once a second). On that signal it does what :func:`~biasgt.workflow.process_group.stop_group`
does for a live ``biasgt run``: the processes of its group (the jobs) get SIGTERM, Snakemake a
KeyboardInterrupt (as on Ctrl-C: it cancels its jobs, SLURM ones too, removes their incomplete
outputs and its lock); whatever still runs after the grace period is killed.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import os
import signal
import sys
import threading
import time

import psutil

from biasgt.workflow.process_group import STOP_GRACE_S, end_processes

#: prctl option that sets the signal a process gets when its parent dies (linux/prctl.h).
_PR_SET_PDEATHSIG = 1
#: Seconds between two looks at the parent where prctl is not available.
_POLL_S = 1.0


def _group_members() -> list[psutil.Process]:
    """This process's descendants still in its process group (the jobs Snakemake started)."""
    group = os.getpgid(0)
    out = []
    for p in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error, ProcessLookupError):
            if os.getpgid(p.pid) == group:
                out.append(p)
    return out


def _end_left_over(started: list[psutil.Process]) -> None:
    """At exit: end the jobs that outlived Snakemake's own clean-up (SIGTERM, then SIGKILL)."""
    end_processes(started)


def _kill_group_after(grace_s: float) -> None:
    def kill() -> None:
        time.sleep(grace_s)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(os.getpgid(0), signal.SIGKILL)

    threading.Thread(target=kill, daemon=True).start()


def _parent_gone(signum: int, frame: object) -> None:
    """SIGHUP handler: the parent died; stop the jobs and unwind Snakemake as on Ctrl-C."""
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    # nobody reads the pipe any more: a write to it must not end the clean-up early
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    started = _group_members()
    for p in started:
        with contextlib.suppress(psutil.Error):
            p.send_signal(signal.SIGTERM)
    atexit.register(_end_left_over, started)
    _kill_group_after(STOP_GRACE_S)
    raise KeyboardInterrupt


def watch_parent(parent_pid: int) -> None:
    """Get SIGHUP (handled by stopping everything) once ``parent_pid`` is no longer the parent."""
    signal.signal(signal.SIGHUP, _parent_gone)
    armed = False
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(_PR_SET_PDEATHSIG, signal.SIGHUP, 0, 0, 0) == 0
    if not armed:
        def poll() -> None:
            while os.getppid() == parent_pid:
                time.sleep(_POLL_S)
            os.kill(os.getpid(), signal.SIGHUP)

        threading.Thread(target=poll, daemon=True).start()
    if os.getppid() != parent_pid:  # it died before the request was in place
        os.kill(os.getpid(), signal.SIGHUP)


def main(argv: list[str]) -> None:
    parent_pid, args = int(argv[0]), argv[1:]
    watch_parent(parent_pid)
    from snakemake.cli import main as snakemake_main

    sys.argv = ["snakemake", *args]
    snakemake_main(args)


if __name__ == "__main__":  # pragma: no cover
    main(sys.argv[1:])
