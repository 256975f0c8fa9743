"""TUM trajectory text files: ``t[s] x y z qx qy qz qw`` per line (evo's ``tum`` format).

Stamps are seconds with any number of decimals; they are converted to int64
nanoseconds exactly from the decimal text (``1403715274.302142976`` ->
``1403715274302142976``), never through float64. :func:`write_tum` writes nine
decimals, so a write-read round trip of ns stamps is lossless.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np

from pipeline.files.atomic import atomic_path
from pipeline.errors import DataError
from pipeline.io._stamps import TimeUnit
from pipeline.io._text import Delimiter, parse_table, read_text, split_header, table_findings
from pipeline.io.registry import SOURCE_FORMAT_KEY
from pipeline.types import NS_PER_S, PoseSeries, PoseSourceKind, Sequence

log = logging.getLogger(__name__)

TUM_COLUMNS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
_WHAT = "TUM trajectory (t[s] x y z qx qy qz qw, whitespace-separated)"
#: File suffixes of a TUM trajectory.
TUM_SUFFIXES = (".txt", ".tum")


def _first_data_fields(path: Path, limit: int = 65536) -> list[str] | None:
    """Whitespace fields of the first non-comment, non-blank line of a text file, or ``None``."""
    try:
        with path.open("r", encoding="utf-8-sig", errors="replace") as f:
            head = f.read(limit)
    except OSError:
        return None
    if "\x00" in head:
        return None
    for line in head.splitlines():
        s = line.strip()
        if s and not s.startswith("#"):
            return s.split()
    return None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def detect_tum(path: str | Path) -> bool:
    """Whether ``path`` is a TUM trajectory: a ``.txt``/``.tum`` file whose first data line has 8 numbers."""
    path = Path(path)
    if not path.is_file() or path.suffix.lower() not in TUM_SUFFIXES:
        return False
    fields = _first_data_fields(path)
    return fields is not None and len(fields) == 8 and all(_is_number(x) for x in fields)


def read_tum_poses(path: str | Path, *, source_kind: PoseSourceKind = PoseSourceKind.VIO, frame: str = "imu",
                   stream: str | None = None) -> tuple[PoseSeries, list]:
    """Read a TUM trajectory file as a pose series plus its parse findings.

    Args:
        path: The text file.
        source_kind: What produced the trajectory.
        frame: Name of the tracked frame.
        stream: Stream name used in findings; default the file stem.

    Returns:
        ``(poses, findings)``.
    """
    path = Path(path)
    stream = stream or path.stem
    text = read_text(path)
    header = split_header(text, Delimiter.WHITESPACE)
    parsed = parse_table(path, text, header, ncols=8, stamp_col=0, value_cols=list(range(1, 8)),
                         delimiter=Delimiter.WHITESPACE, unit=TimeUnit.S, what=_WHAT)
    v = parsed.values
    quat_wxyz = v[:, [6, 3, 4, 5]]
    poses = PoseSeries(parsed.t_ns, v[:, 0:3], quat_wxyz, frame, PoseSourceKind(source_kind))
    return poses, table_findings(parsed, path, f"poses/{stream}", 8)


def read_tum(
    path: str | Path,
    *,
    source_kind: PoseSourceKind = PoseSourceKind.VIO,
    frame: str = "imu",
    name: str | None = None,
) -> Sequence:
    """Read a TUM trajectory as a pose-only Sequence.

    Args:
        path: ``t[s] x y z qx qy qz qw`` text file; ``'#'`` lines are comments.
        source_kind: What produced the trajectory (default VIO).
        frame: Name of the tracked frame (default ``"imu"``).
        name: Sequence name; default the file stem.

    Returns:
        A Sequence with one pose stream named after the file stem.

    Raises:
        InputFormatError: Missing or empty file, or more than 10 % unparseable lines.
    """
    path = Path(path)
    stream = path.stem
    poses, findings = read_tum_poses(path, source_kind=source_kind, frame=frame, stream=stream)
    log.info("read TUM %s: %d poses", path, len(poses))
    return Sequence(
        name=name or stream,
        poses={stream: poses},
        findings=findings,
        metadata={"source_path": str(path), SOURCE_FORMAT_KEY: "tum", "files": {f"poses/{stream}": str(path)}},
    )


def format_stamps_s(t_ns: np.ndarray) -> np.ndarray:
    """int64 ns stamps as exact decimal seconds with nine decimals (``"1403715274.302142976"``), [N] str."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    sign = np.where(t_ns < 0, "-", "")
    mag = np.abs(t_ns)
    sec = (mag // NS_PER_S).astype(str)
    frac = np.char.zfill((mag % NS_PER_S).astype(str), 9)
    return np.char.add(np.char.add(np.char.add(sign, sec), "."), frac)


def write_tum(path: str | Path, poses: PoseSeries) -> Path:
    """Write poses as a TUM trajectory (readable by evo), atomically.

    Stamps get nine decimals (exact ns); values are written with the shortest text
    that reads back to the same float64, so :func:`read_tum` returns identical arrays.

    Args:
        path: Output file.
        poses: Poses with orientation.

    Returns:
        The path written.

    Raises:
        DataError: The poses have no orientation (TUM needs a quaternion).
    """
    path = Path(path)
    if poses.quat_wxyz is None:
        raise DataError(
            f"cannot write {path.name} as TUM: the pose stream ({poses.frame}) is position only",
            path=path, hint="TUM needs orientations; write position-only streams as CSV instead",
        )
    q = poses.quat_wxyz
    import pandas as pd  # only when writing (slow to import)

    frame = pd.DataFrame({
        "t": format_stamps_s(poses.t_ns),
        "tx": poses.p_m[:, 0], "ty": poses.p_m[:, 1], "tz": poses.p_m[:, 2],
        "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3], "qw": q[:, 0],
    })
    buf = io.StringIO()
    buf.write("# " + " ".join(TUM_COLUMNS) + "\n")
    frame.to_csv(buf, sep=" ", header=False, index=False, lineterminator="\n", na_rep="nan")
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return path


__all__ = ["read_tum", "read_tum_poses", "write_tum", "format_stamps_s"]
