"""One progress line per running workflow job, every so often, in ``biasgt run``'s terminal.

Snakemake prints a job when it starts and when it ends; a training or an evaluation job runs for
minutes in between and writes its progress (:mod:`pipeline.progress`: rate and ETA) only to its log
file, ``logs/<stage>/<name>.log``. :class:`JobProgress` watches that folder while the workflow runs
and, every ``interval_s``, prints the last line of each log written to since the previous look
(the jobs still running), e.g. ``  [running] logs/train/diffusion_rnn_seed0.log: train diffusion_rnn:
40%|####      | 32/80 [00:41<01:02, 0.77step/s]``. The full logs stay in ``logs/``.
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path
from typing import IO

from pipeline.progress import LOG_INTERVAL_S

#: The logging prefix of a log line (``2026-12-02 14:36:26,395 INFO name: ``), dropped in the summary.
_PREFIX = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+ \w+ [\w.]+: ")


def last_line(path: Path, max_bytes: int = 4096) -> str:
    """The last non-empty line of a text file (its logging prefix dropped), or ''."""
    try:
        with path.open("rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - max_bytes))
            tail = fh.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    lines = [x.strip() for x in tail.replace("\r", "\n").splitlines() if x.strip()]
    return _PREFIX.sub("", lines[-1]) if lines else ""


def running_lines(logs_dir: Path, since: float) -> list[str]:
    """``[running] LOG: last line`` for every log under ``logs_dir`` modified after ``since`` (epoch s)."""
    out = []
    for path in sorted(logs_dir.rglob("*.log")) if logs_dir.is_dir() else []:
        try:
            fresh = path.stat().st_mtime > since
        except OSError:
            continue
        if fresh:
            line = last_line(path)
            if line:
                out.append(f"  [running] {path.relative_to(logs_dir.parent)}: {line}")
    return out


class JobProgress:
    """A background thread printing :func:`running_lines` every ``interval_s`` until :meth:`stop`."""

    def __init__(self, workdir: Path, echo: IO[str], interval_s: float = LOG_INTERVAL_S) -> None:
        self.logs_dir = Path(workdir) / "logs"
        self.echo = echo
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="biasgt-job-progress", daemon=True)

    def __enter__(self) -> JobProgress:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def write(self, text: str) -> None:
        """Write a line of the workflow's own output (serialised with the progress lines)."""
        with self._lock:
            self.echo.write(text)

    def _run(self) -> None:
        since = time.time()
        while not self._stop.wait(self.interval_s):
            now = time.time()
            lines = running_lines(self.logs_dir, since)
            since = now
            if lines:
                with self._lock:
                    self.echo.write("\n".join(lines) + "\n")
                    self.echo.flush()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
