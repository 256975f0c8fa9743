"""Progress of long work (training, sampling, solves) with a rate and an ETA, on a terminal or in a log.

:func:`progress` is a :class:`tqdm.tqdm` bar. On a terminal it is the usual bar on stderr. Elsewhere
(a workflow job whose stderr goes to its log file) the same bar is written as plain log lines
through ``logger``, at most one every :data:`LOG_INTERVAL_S` seconds (and one at the end), e.g.
``train diffusion_rnn:  40%|####      | 32/80 [00:41<01:02, 0.77step/s]``: the workflow's
terminal shows them (:func:`biasgt.workflow.run.run_workflow`) and the log keeps them.
"""

from __future__ import annotations

import logging
import sys
from typing import Any

from tqdm import tqdm

#: Seconds between two progress lines written to a log (a terminal bar refreshes as tqdm does).
LOG_INTERVAL_S = 30.0


class _LogLines:
    """A file-like object that turns tqdm's ``\\r``-refreshed bar into one log record per refresh."""

    def __init__(self, logger: logging.Logger) -> None:
        self.logger = logger

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip()
        if line:
            self.logger.info("%s", line)

    def flush(self) -> None:
        pass


def progress(total: int | None, *, desc: str, unit: str, logger: logging.Logger, initial: int = 0,
             interval_s: float = LOG_INTERVAL_S, **kwargs: Any) -> tqdm:
    """A tqdm bar of ``total`` ``unit``s (see the module docstring); call ``update``/``close`` as usual.

    Args:
        total: Units of work (None: unknown, no ETA).
        desc: What is running (the line's prefix).
        unit: The unit's name (``step``, ``window``, ``solve``).
        logger: Where the lines go when stderr is not a terminal.
        initial: Units already done (a resumed run).
        interval_s: Least seconds between two log lines.

    Nothing is shown where ``logger`` does not log INFO (``biasgt -q``).
    """
    if not logger.isEnabledFor(logging.INFO):  # biasgt -q: no progress either
        return tqdm(total=total, initial=initial, disable=True, **kwargs)
    if sys.stderr.isatty():
        return tqdm(total=total, initial=initial, desc=desc, unit=unit, dynamic_ncols=True, **kwargs)
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=_LogLines(logger), ncols=80, ascii=True,
                mininterval=interval_s, maxinterval=interval_s, miniters=1, **kwargs)
