"""A training's hold on its run folder: one training at a time, and nothing left behind by one that fails.

:func:`hold_run_folder` creates the folder when missing and holds an exclusive ``flock`` on the folder
itself (no lock file: the folder's content stays what the training writes). A second training of the
same folder, on this machine or another one sharing the file system where ``flock`` reaches it, is
refused at once instead of overwriting the first one's checkpoints. The kernel releases the lock when
the holder ends, however it ends.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from pipeline.errors import OutputLocationError
from pipeline.files.atomic import no_space_error


@contextlib.contextmanager
def hold_run_folder(out_dir: str | Path) -> Iterator[Path]:
    """Hold ``out_dir`` (created when missing) for one training while the block runs.

    When the block fails, a folder this call created is removed if it is still empty or the disk is full
    (a full disk: nothing is left behind); a folder that held a run before keeps what it holds, and so
    does a new one holding a checkpoint to resume from (an interrupted or diverged training).

    Raises:
        OutputLocationError: Another training holds the folder; the folder cannot be created.
    """
    out_dir = Path(out_dir)
    created = not out_dir.exists()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise no_space_error(exc, out_dir) or OutputLocationError(
            f"cannot create the run folder ({exc.strerror})", path=out_dir,
            hint="choose a writable --out") from None
    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputLocationError("the run folder is in use: another training writes there now", path=out_dir,
                                      hint="wait for it to finish, or choose another --out") from None
        try:
            yield out_dir
        except BaseException as exc:
            if created and (not any(out_dir.iterdir()) or no_space_error(exc, out_dir) is not None):
                shutil.rmtree(out_dir, ignore_errors=True)
            raise
    finally:
        os.close(fd)
