"""Atomic output: write to a temporary sibling, then rename into place.

A stage that fails leaves either the previous complete output or nothing, never
a half-written file or folder. A full disk (or an exceeded quota) while writing is a known error:
:class:`~pipeline.errors.OutputLocationError` naming the folder (:func:`no_space_error`).
"""

from __future__ import annotations

import contextlib
import enum
import errno
import os
import re
import shutil
import signal
import tempfile
import threading
from collections.abc import Collection, Iterator
from pathlib import Path

from pipeline.errors import NoSpaceError, OutputLocationError


#: errno values of a full disk and of an exceeded quota.
NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


#: What a write cut short says where the library drops the errno: numpy's ``np.save`` ("10854 requested and
#: 2032 written") and torch's ``torch.save`` ("unexpected pos 606720 vs 606608", "file write failed").
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written|unexpected pos \d+ vs \d+|file write failed")


def no_space_error(exc: BaseException, path: str | Path) -> NoSpaceError | None:
    """The one-line error for ``exc`` when it says the disk (or quota) holding ``path`` is full, else None.

    Matches ``OSError.errno`` ENOSPC / EDQUOT (also pyarrow's OSError, which carries it), libraries that
    only put it in the text ("No space left on device" / "Disk quota exceeded"), and a write cut short
    without an errno (numpy's OSError, torch's RuntimeError: :data:`_SHORT_WRITE`), which a full disk
    or quota is what causes.
    """
    if not isinstance(exc, (OSError, RuntimeError, NoSpaceError)):
        return None
    text = str(exc)  # a NoSpaceError of an inner writer (a temporary path): named again for ``path``
    errno_ = exc.errno if isinstance(exc, OSError) else errno.ENOSPC if isinstance(exc, NoSpaceError) else None
    quota = errno_ == errno.EDQUOT or "quota exceeded" in text.lower()
    short = _SHORT_WRITE.search(text) is not None
    if errno_ not in NO_SPACE_ERRNOS and not quota and not short and "no space left on device" not in text.lower():
        return None
    folder = Path(path).parent
    what = "disk quota exceeded" if quota else "no space left on device"
    return NoSpaceError(f"cannot write the output: {what} in folder {folder} (nothing was written)",
                        path=path, hint="free some space there (or raise the quota), or choose another --out")


def umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _default_mode(tmp: Path, *, is_dir: bool) -> None:
    """Give a temp file/folder the mode a plain open()/mkdir() would (mkstemp/mkdtemp use 0600/0700)."""
    os.chmod(tmp, (0o777 if is_dir else 0o666) & ~umask())


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary file path next to ``path``; rename it onto ``path`` on success.

    Example:
        >>> with atomic_path("out.csv") as tmp:
        ...     frame.to_csv(tmp)
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise no_space_error(exc, path) or exc from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if tmp.exists():
            _default_mode(tmp, is_dir=False)
        with _stop_signals_deferred():
            os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if (full := no_space_error(exc, path)) is not None:
            raise full from None
        raise


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


@contextlib.contextmanager
def _stop_signals_deferred() -> Iterator[None]:
    """Hold SIGINT/SIGTERM until the block ends, so a rename sequence is never cut in half.

    A held signal is delivered (and its handler raises) right after the block. Outside the main
    thread signals cannot be held there, and Python delivers them to the main thread anyway.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _swap_in(tmp: Path, path: Path, owned: Collection[str] | None) -> None:
    """Rename ``tmp`` onto ``path``; entries of an existing ``path`` not in ``owned`` move along."""
    if not path.exists():
        os.replace(tmp, path)
        return
    if not path.is_dir():
        raise NotADirectoryError(f"{path} exists and is not a folder")
    carried: list[str] = []
    try:
        if owned is not None:
            for entry in path.iterdir():
                if entry.name not in owned and not (tmp / entry.name).exists():
                    os.replace(entry, tmp / entry.name)
                    carried.append(entry.name)
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
        os.replace(path, old / "x")
    except BaseException:
        for name in carried:  # put the other stages' outputs back where they were
            os.replace(tmp / name, path / name)
        raise
    os.replace(tmp, path)
    shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, owned: Collection[str] | None = None) -> Iterator[Path]:
    """Yield a fresh temporary folder next to ``path``; it replaces ``path`` on success.

    An existing ``path`` is replaced only once the new content is complete. With ``owned`` (the
    file and folder names this writer produces), entries of an existing ``path`` with other
    names (another stage's outputs in a shared folder) are kept; without it the folder is
    replaced as a whole. On any exit other than success (an exception, Ctrl-C, SIGTERM turned
    into an exception by the CLI) the temporary folder is removed and ``path`` is untouched.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    except OSError as exc:
        raise no_space_error(exc, path) or exc from None
    try:
        yield tmp
        _default_mode(tmp, is_dir=True)
        with _stop_signals_deferred():
            _swap_in(tmp, path, owned)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if (full := no_space_error(exc, path)) is not None:
            raise full from None
        raise


class OutputKind(str, enum.Enum):
    """What a command writes at its output path."""

    FILE = "file"
    FOLDER = "folder"


def check_output_location(path: str | Path, kind: OutputKind | None = None) -> None:
    """Fail early, before any work, if ``path`` cannot be written atomically.

    With ``kind``, an existing ``path`` of the other kind (a file where a folder is written, a
    folder where a file is) is refused too: the final rename would fail after all the work.

    The writers create a temporary sibling of ``path`` and rename it, creating missing parent
    folders first; so the nearest existing ancestor must be a writable folder (probed by really
    creating a file there: permission bits do not tell on read-only mounts or for root), and an
    existing folder at ``path`` must be writable too (its other stages' files are moved along).

    Raises:
        OutputLocationError: Naming the blocking path and the fix.
    """
    path = Path(path)
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputLocationError(f"cannot create the output there: {ancestor} is a file, not a folder", path=path,
                                  hint="choose an --out whose parent folders are folders")
    if kind is OutputKind.FOLDER and path.exists() and not path.is_dir():
        raise OutputLocationError("the output folder exists as a file", path=path,
                                  hint="remove the file or choose another --out")
    if kind is OutputKind.FILE and path.is_dir():
        raise OutputLocationError("the output file exists as a folder", path=path,
                                  hint="remove the folder or choose another --out")
    probes = [ancestor] + ([path] if path.is_dir() else [])
    for folder in probes:
        try:
            fd, name = tempfile.mkstemp(prefix=".biasgt-write-probe.", dir=folder)
        except OSError as exc:
            raise OutputLocationError(f"cannot write the output there: folder {folder} is not writable "
                                      f"({exc.strerror})", path=path,
                                      hint="choose a writable --out or fix the folder's permissions") from None
        os.close(fd)
        os.unlink(name)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
