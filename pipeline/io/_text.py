"""Shared text-table parsing for the ASL, TUM and generic CSV readers.

The readers here parse faithfully: they do not sort, deduplicate or normalise,
and a literal ``nan`` stays NaN. What they do handle is the damage files pick up
on their way through spreadsheets and scripts:

* lines that cannot be parsed (empty rows, stray text, wrong field count) are
  skipped and reported (``PARSE_SKIPPED_LINES``); more than 10 % of them, or no
  usable line at all, is an :class:`~pipeline.errors.InputFormatError`;
* time stamps are converted to int64 nanoseconds *exactly* from their decimal
  text (``1.40363657975856E+018`` or ``1403715274.302142976``), never through
  float64 (:mod:`pipeline.io._stamps`);
* stamps that carry less than nanosecond precision (scientific notation,
  rounding to 10^k ns with k >= 3) are reported (``STAMP_PRECISION_LOSS``);
* a stamp unit left to ``TimeUnit.AUTO`` is guessed and reported
  (``STAMP_UNIT_GUESSED``).

Fast path: one strict :func:`pandas.read_csv` call. Only when it fails or
produces a NaN does the slow path validate each line with a regular expression
to find (and report) the bad ones exactly.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import csv
import enum
import io
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline.errors import InputFormatError
from pipeline.io._stamps import INT64_MAX, TimeUnit, decimal_to_ns, guess_time_unit, stamp_resolution_ns
from pipeline.types import NS_PER_S, Finding, Severity

if TYPE_CHECKING:  # pandas is imported where a table is parsed (it costs ~0.7 s to import)
    import pandas as pd

log = logging.getLogger(__name__)

#: Share of unparseable data lines above which a file is rejected instead of repaired.
MAX_BAD_LINE_FRACTION = 0.10
#: How many bad line numbers a finding lists.
MAX_LISTED_LINES = 50

CODE_SKIPPED = "PARSE_SKIPPED_LINES"
CODE_PRECISION = "STAMP_PRECISION_LOSS"
CODE_UNIT_GUESSED = "STAMP_UNIT_GUESSED"


class Delimiter(str, enum.Enum):
    """Field separator of a text table."""

    COMMA = ","
    SEMICOLON = ";"
    TAB = "\t"
    WHITESPACE = "whitespace"  # one or more spaces or tabs (TUM trajectories)

    @property
    def pandas_sep(self) -> str:
        return r"\s+" if self is Delimiter.WHITESPACE else self.value

    def split(self, line: str) -> list[str]:
        if self is Delimiter.WHITESPACE:
            return line.split()
        return line.split(self.value)

    @property
    def label(self) -> str:
        return {",": "','", ";": "';'", "\t": "tab", "whitespace": "whitespace"}[self.value]


# A number as pandas' C parser reads it; NaN/inf literals are data (kept as NaN), an empty field is not.
_NUM = r"(?:[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[iI][nN][fF](?:[iI][nN][iI][tT][yY])?)|-?(?:nan|NaN))"
# A stamp must be a finite decimal number.
_STAMP = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_STAMP_RE = re.compile(rf"\s*{_STAMP}\s*")


@dataclass(frozen=True)
class Header:
    """Where the data of a text table starts and what its header says.

    Attributes:
        names: Column names of the header line (``'#'`` and unit-free spaces
            stripped), or ``None`` when the file has no header.
        line: 1-based line number of the header, or ``None``.
        data_offset: Character offset of the first data line in the text.
        first_data_line: 1-based line number of the first data line.
    """

    names: list[str] | None
    line: int | None
    data_offset: int
    first_data_line: int


@dataclass
class ParsedTable:
    """The numeric content of a text table.

    Attributes:
        t_ns: Stamps, int64 [N].
        values: The requested value columns, float64 [N, K].
        bad_lines: 1-based numbers of the skipped lines.
        n_data_lines: Number of non-blank, non-comment data lines (good + bad).
        scientific: True if any stamp was written in scientific notation.
        resolution_ns: Largest 10^k (k >= 3) dividing every stamp, else 1.
        unit: The stamp unit used (the guessed one for ``TimeUnit.AUTO``).
        unit_guessed: True if ``unit`` was guessed.
    """

    t_ns: np.ndarray
    values: np.ndarray
    bad_lines: list[int] = field(default_factory=list)
    n_data_lines: int = 0
    scientific: bool = False
    resolution_ns: int = 1
    unit: TimeUnit = TimeUnit.NS
    unit_guessed: bool = False
    unit_declared: TimeUnit | None = None


def read_text(path: Path) -> str:
    """The text of ``path`` (UTF-8, BOM removed), or an InputFormatError if it is missing, empty or binary."""
    if not path.exists():
        raise InputFormatError("file does not exist", path=path, hint="check the path")
    if not path.is_file():
        raise InputFormatError("is not a file", path=path, hint="pass the data file itself")
    raw = path.read_bytes()
    if not raw or raw.isspace():
        raise InputFormatError("file is empty", path=path, hint="the file must hold a header and data lines")
    if b"\x00" in raw[:4096]:
        raise InputFormatError("file is binary, not text", path=path, hint="pass a CSV or text file")
    return raw.decode("utf-8-sig", errors="replace")


def _clean_name(name: str) -> str:
    return name.strip().lstrip("#").strip()


def _looks_numeric(field_text: str) -> bool:
    return _STAMP_RE.fullmatch(field_text) is not None


def split_header(text: str, delimiter: Delimiter) -> Header:
    """Find the header and the first data line of a text table.

    Leading blank lines and lines starting with ``'#'`` (or ``'%'``) are skipped; the
    last such ``'#'`` line is the header. A first non-comment line whose first
    field is not a number is a header without ``'#'`` (``Time,X,Y,Z``).

    Args:
        text: The whole file.
        delimiter: Field separator.

    Returns:
        The header description (``names`` is ``None`` when there is no header).
    """
    n = len(text)
    pos = 0  # start of the current line
    line_no = 1  # its 1-based number
    header_text: str | None = None
    header_line: int | None = None
    data_offset, first_data_line = n, line_no
    while pos < n:
        end = text.find("\n", pos)
        end = n if end < 0 else end
        stripped = text[pos:end].strip()
        if not stripped or stripped[0] in "#%":
            if stripped.startswith("#"):
                header_text, header_line = stripped[1:], line_no
        else:
            fields = delimiter.split(stripped)
            if fields and _looks_numeric(fields[0]):
                data_offset, first_data_line = pos, line_no  # first data line
            else:
                # A header without '#'; data starts on the next line.
                header_text, header_line = stripped, line_no
                data_offset, first_data_line = min(end + 1, n), line_no + 1
            break
        pos = end + 1
        line_no += 1
    else:
        data_offset, first_data_line = n, line_no
    names = None
    if header_text is not None:
        names = [_clean_name(x) for x in delimiter.split(header_text.strip())]
        while names and not names[-1]:
            names.pop()  # trailing delimiter
    return Header(names=names, line=header_line, data_offset=data_offset, first_data_line=first_data_line)


def _line_regex(ncols: int, stamp_col: int, numeric_cols: set[int], delimiter: Delimiter) -> re.Pattern[str]:
    """A regex for one valid data line: ``ncols`` fields, the numeric ones numbers."""
    parts = []
    for i in range(ncols):
        if i == stamp_col:
            parts.append(_STAMP)
        elif i in numeric_cols:
            parts.append(_NUM)
        elif delimiter is Delimiter.WHITESPACE:
            parts.append(r"\S+")
        else:
            parts.append(rf"[^{re.escape(delimiter.value)}\n]*?")
    if delimiter is Delimiter.WHITESPACE:
        body = r"[ \t]+".join(parts)
        return re.compile(rf"[ \t]*{body}[ \t]*\r?")
    sep = rf"[ \t]*{re.escape(delimiter.value)}[ \t]*"
    body = sep.join(parts)
    return re.compile(rf"[ \t]*{body}[ \t]*(?:{re.escape(delimiter.value)}[ \t]*)?\r?")


def _describe_bad_line(line: str, ncols: int, delimiter: Delimiter) -> str:
    fields = delimiter.split(line.strip().rstrip(delimiter.value if delimiter is not Delimiter.WHITESPACE else ""))
    shown = line.strip()
    if len(shown) > 60:
        shown = shown[:57] + "..."
    if len(fields) != ncols:
        return f"has {len(fields)} fields, expected {ncols} separated by {delimiter.label}: {shown!r}"
    return f"is not numeric: {shown!r}"


@dataclass
class _Raw:
    """Columns straight out of pandas: stamps as int64 (raw unit) or strings, values float64 [N, K]."""

    stamps: np.ndarray | pd.Series
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.values)


def _read_csv(data: str, ncols: int, stamp_col: int, value_cols: list[int], delimiter: Delimiter,
              int_stamps: bool, strict: bool) -> _Raw:
    import pandas as pd  # slow to import: only for tables pyarrow's reader rejects

    dtypes: dict[int, object] = {c: np.float64 for c in value_cols}
    dtypes[stamp_col] = np.int64 if int_stamps else str
    frame = pd.read_csv(
        io.StringIO(data),
        sep=delimiter.pandas_sep,
        header=None,
        names=list(range(ncols)),
        usecols=[stamp_col, *value_cols],
        index_col=False,
        dtype=dtypes,
        comment="#" if strict else None,
        quoting=csv.QUOTE_NONE,
        skip_blank_lines=True,
        engine="c",
    )
    values = frame[value_cols].to_numpy(dtype=np.float64) if value_cols else np.zeros((len(frame), 0))
    stamps = frame[stamp_col].to_numpy(dtype=np.int64) if int_stamps else frame[stamp_col]
    return _Raw(stamps, np.ascontiguousarray(values))


def _read_arrow(data: str, ncols: int, stamp_col: int, value_cols: list[int], delimiter: Delimiter) -> _Raw | None:
    """Parse a clean table with pyarrow (int64 stamps, float64 values); ``None`` if it is not clean."""
    import pyarrow.csv as pacsv  # pyarrow.csv adds ~0.1 s: only when a table is read

    names = [f"c{i}" for i in range(ncols)]
    types = {names[stamp_col]: pa.int64(), **{names[c]: pa.float64() for c in value_cols}}
    try:
        table = pacsv.read_csv(
            pa.py_buffer(data.encode("utf-8")),
            read_options=pacsv.ReadOptions(column_names=names),
            parse_options=pacsv.ParseOptions(delimiter=delimiter.value, quote_char=False, ignore_empty_lines=True),
            convert_options=pacsv.ConvertOptions(column_types=types, include_columns=[names[stamp_col]]
                                                 + [names[c] for c in value_cols]),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
        return None
    if table.num_rows == 0 or any(table.column(n).null_count for n in table.column_names):
        return None
    stamps = table.column(names[stamp_col]).to_numpy()
    values = np.column_stack([table.column(names[c]).to_numpy() for c in value_cols]) if value_cols \
        else np.zeros((table.num_rows, 0))
    if np.isnan(values).any():
        return None
    return _Raw(np.asarray(stamps, dtype=np.int64), np.ascontiguousarray(values, dtype=np.float64))


def _read_fast(data: str, ncols: int, stamp_col: int, value_cols: list[int], delimiter: Delimiter,
               int_stamps: bool) -> _Raw | None:
    """Strict parse; ``None`` when any line is not clean (the caller then validates line by line).

    Clean integer-stamped tables (the common case: EuRoC/ASL files) go through pyarrow's
    multithreaded CSV reader, several times faster than pandas on long recordings; anything it
    rejects (spaces after delimiters, comment lines, text stamps) falls back to pandas.
    """
    import pandas as pd  # slow to import: only for tables pyarrow's reader rejects

    if int_stamps and delimiter is not Delimiter.WHITESPACE:
        raw = _read_arrow(data, ncols, stamp_col, value_cols, delimiter)
        if raw is not None:
            return raw
    if not _field_counts_ok(data, ncols, delimiter):
        return None  # pandas would drop the extra fields of a long line silently
    try:
        raw = _read_csv(data, ncols, stamp_col, value_cols, delimiter, int_stamps, strict=True)
    except (ValueError, OverflowError, TypeError, pd.errors.ParserError, pd.errors.EmptyDataError):
        return None
    if np.isnan(raw.values).any():
        return None
    if not int_stamps and raw.stamps.isna().any():
        return None
    return raw


def _field_counts_ok(data: str, ncols: int, delimiter: Delimiter) -> bool:
    """True if every data line (not blank, not ``#``) has ``ncols`` fields (a trailing delimiter allowed)."""
    lines = pc.utf8_trim_whitespace(pc.list_flatten(pc.split_pattern(pa.array([data], type=pa.string()), "\n")))
    lines = lines.filter(pc.and_(pc.greater(pc.utf8_length(lines), 0),
                                 pc.invert(pc.starts_with(lines, "#"))))
    if delimiter is Delimiter.WHITESPACE:
        counts = pc.list_value_length(pc.utf8_split_whitespace(lines))
        return bool(pc.all(pc.equal(counts, ncols)).as_py() is not False)
    counts = pc.count_substring(lines, delimiter.value)
    trailing = pc.cast(pc.ends_with(lines, delimiter.value), pa.int64())
    return bool(pc.all(pc.equal(pc.subtract(counts, trailing), ncols - 1)).as_py() is not False)


def _read_validated(
    path: Path, data: str, header: Header, ncols: int, stamp_col: int, value_cols: list[int],
    delimiter: Delimiter, what: str,
) -> tuple[_Raw, list[int], int]:
    """Slow path: validate every line with one vectorised regex (RE2), skip the bad ones, parse the rest.

    Returns:
        ``(raw, bad_lines, n_data)``: parsed good lines, 1-based numbers of bad lines,
        number of data lines (good + bad; blank and ``'#'`` lines do not count).
    """
    import pandas as pd  # slow to import: only for tables pyarrow's reader rejects

    pattern = _line_regex(ncols, stamp_col, set(value_cols), delimiter)
    lines = pc.list_flatten(pc.split_pattern(pa.array([data], type=pa.string()), "\n"))
    ok = pc.match_substring_regex(lines, f"^(?:{pattern.pattern})$").to_numpy(zero_copy_only=False)
    candidates = np.flatnonzero(~ok)
    cand_text = lines.take(pa.array(candidates, type=pa.int64())).to_pylist() if len(candidates) else []
    bad_idx = [int(i) for i, text in zip(candidates, cand_text) if text.strip() and not text.strip().startswith("#")]
    bad_lines = [header.first_data_line + i for i in bad_idx]
    n_good = int(np.count_nonzero(ok))
    n_data = n_good + len(bad_lines)
    if n_data == 0:
        raise InputFormatError(f"no data lines (expected a {what})", path=path,
                               hint="the file must hold data lines after its header")
    if n_good == 0 or len(bad_lines) > MAX_BAD_LINE_FRACTION * n_data:
        reason = _describe_bad_line(lines[bad_idx[0]].as_py(), ncols, delimiter)
        raise InputFormatError(
            f"{len(bad_lines)} of {n_data} data lines cannot be parsed; the first {reason}",
            path=path, line=bad_lines[0],
            hint=f"expected format: {what}, {ncols} numeric fields per line "
                 f"(more than {MAX_BAD_LINE_FRACTION:.0%} bad lines are not skipped)",
        )
    good = lines.filter(pa.array(ok))
    if delimiter is not Delimiter.WHITESPACE:  # drop an optional trailing delimiter
        good = pc.replace_substring_regex(good, f"[ \\t]*{re.escape(delimiter.value)}?[ \\t]*\\r?$", "")
    joined = pc.binary_join(pa.ListArray.from_arrays(pa.array([0, len(good)], type=pa.int32()), good), "\n")
    good_text = joined[0].as_py() + "\n"
    # Every line is valid now; NaN literals are data and stay NaN.
    try:
        raw = _read_csv(good_text, ncols, stamp_col, value_cols, delimiter, int_stamps=False, strict=False)
    except (ValueError, OverflowError, pd.errors.ParserError) as exc:  # the regex let through what pandas rejects
        raise InputFormatError(f"cannot parse the data lines ({exc})", path=path, line=header.first_data_line,
                               hint=f"expected format: {what}, {ncols} numeric fields per line") from exc
    return raw, bad_lines, n_data


_INT_STAMP_RE = re.compile(r"\s*[+-]?\d{1,19}\s*")  # 19 digits: ns since 1970 (int64 overflow falls back)


def _first_stamp_is_int(data: str, stamp_col: int, delimiter: Delimiter) -> bool:
    end = data.find("\n")
    fields = delimiter.split(data[:end if end >= 0 else None].strip())
    return len(fields) > stamp_col and _INT_STAMP_RE.fullmatch(fields[stamp_col]) is not None


def _ends_valid(data: str, pattern: re.Pattern[str]) -> bool:
    """True if the first and the last non-blank line of ``data`` are valid data (or comment) lines."""
    body = data.strip("\r\n\t ")
    first_end = body.find("\n")
    first = body[:first_end if first_end >= 0 else None]
    last = body[body.rfind("\n") + 1:]
    return all(pattern.fullmatch(x) is not None or x.lstrip().startswith("#") for x in (first, last))


def _int_stamps_to_ns(raw: np.ndarray, unit: TimeUnit) -> np.ndarray:
    scale = 10**unit.ns_exponent
    if scale == 1:
        return raw
    if np.any(np.abs(raw) > INT64_MAX // scale):
        raise ValueError("stamp does not fit int64 nanoseconds")
    return raw * np.int64(scale)


def _approx_stamps(raw: _Raw) -> np.ndarray:
    """The raw stamps as float64 [N] (only for guessing a unit; never used as the stamps)."""
    import pandas as pd

    if isinstance(raw.stamps, np.ndarray):
        return raw.stamps.astype(np.float64)
    return pd.to_numeric(raw.stamps.str.strip(), errors="coerce").to_numpy(dtype=np.float64)


def _has_sub_ns_digits(stamps: pd.Series, unit: TimeUnit) -> bool:
    """True if a decimal stamp has non-zero digits finer than 1 ns in ``unit`` (they would be rounded away)."""
    arr = pc.utf8_trim_whitespace(pa.array(stamps, type=pa.string()))
    if pc.any(pc.match_substring_regex(arr, "[eE]")).as_py():
        return False  # scientific notation: reported as STAMP_PRECISION_LOSS instead
    frac = pc.extract_regex(arr, r"\.(?P<frac>\d*)$").field(0)
    finer = pc.utf8_slice_codeunits(pc.fill_null(frac, ""), unit.ns_exponent)
    return bool(pc.any(pc.match_substring_regex(finer, "[1-9]")).as_py())


def _unit_for_fractional_stamps(path: Path, header: Header, stamp_col: int, raw: _Raw, declared: TimeUnit) -> TimeUnit:
    """The unit of stamps whose fraction is finer than 1 ns in the ``declared`` unit.

    A header that says ``[ns]`` over ``1403715274.302140000`` is wrong about the unit: the
    stamps are decimal seconds. They are read in the unit their magnitude and spacing say, exactly
    from the decimal text (reported as STAMP_UNIT_GUESSED), never truncated to whole nanoseconds.

    Raises:
        InputFormatError: No coarser unit reads them without rounding.
    """
    unit = guess_time_unit(_approx_stamps(raw))
    if unit.ns_exponent > declared.ns_exponent and not _has_sub_ns_digits(raw.stamps, unit):
        log.warning("%s: stamps have a fraction finer than 1 ns in the declared unit '%s'; read as '%s'",
                    display_name(path), declared.value, unit.value)
        return unit
    field = header.names[stamp_col] if header.names and len(header.names) > stamp_col else f"column {stamp_col}"
    raise InputFormatError(
        f"time stamps have digits finer than 1 ns in their declared unit '{declared.value}' and no other unit "
        "fits them", path=path, line=header.first_data_line, field=field,
        hint="write the stamps as integer nanoseconds (or decimal seconds with at most 9 decimals)")


def parse_table(
    path: Path,
    text: str,
    header: Header,
    *,
    ncols: int,
    stamp_col: int,
    value_cols: list[int],
    delimiter: Delimiter,
    unit: TimeUnit,
    what: str,
) -> ParsedTable:
    """Parse the numeric data lines of a text table.

    Args:
        path: File name (for messages).
        text: The whole file.
        header: From :func:`split_header`.
        ncols: Number of fields each data line must have.
        stamp_col: Index of the stamp column.
        value_cols: Indices of the float columns to return, in order.
        delimiter: Field separator.
        unit: Unit of the stamp column (``AUTO`` to guess).
        what: What the file should be, for messages (``"EuRoC IMU CSV"``).

    Returns:
        Stamps, values and what was skipped.

    Raises:
        InputFormatError: No data, more than 10 % bad lines, or unconvertible stamps.
    """
    data = text[header.data_offset:]
    if not data.strip():
        raise InputFormatError(f"no data lines (expected a {what})", path=path,
                               hint="the file must hold data lines after its header")
    # Integer stamps (the usual ns) parse straight to int64, exactly; anything else goes as text.
    int_stamps = _first_stamp_is_int(data, stamp_col, delimiter)
    # A bad first or last line (spreadsheet exports end in junk) makes the strict parse fail late: skip it.
    ends_ok = _ends_valid(data, _line_regex(ncols, stamp_col, set(value_cols), delimiter))
    raw = _read_fast(data, ncols, stamp_col, value_cols, delimiter, int_stamps) if ends_ok else None
    bad_lines: list[int] = []
    if raw is None:
        raw, bad_lines, n_data = _read_validated(path, data, header, ncols, stamp_col, value_cols, delimiter, what)
    else:
        n_data = len(raw)
    if len(raw) == 0:
        raise InputFormatError(f"no data lines (expected a {what})", path=path,
                               hint="the file must hold data lines after its header")
    guessed = False
    declared = None if unit is TimeUnit.AUTO else unit
    if unit is TimeUnit.AUTO:
        unit, guessed = guess_time_unit(_approx_stamps(raw)), True
    elif not isinstance(raw.stamps, np.ndarray) and _has_sub_ns_digits(raw.stamps, unit):
        unit = _unit_for_fractional_stamps(path, header, stamp_col, raw, unit)
        guessed = True
    try:
        if isinstance(raw.stamps, np.ndarray):
            t_ns, scientific = _int_stamps_to_ns(raw.stamps, unit), False
        else:
            t_ns, scientific = decimal_to_ns(raw.stamps, unit)
    except ValueError as exc:
        raise InputFormatError(f"cannot convert time stamps to nanoseconds ({exc})", path=path,
                               line=header.first_data_line, field=header.names[stamp_col]
                               if header.names and len(header.names) > stamp_col else f"column {stamp_col}",
                               hint=f"stamps must be decimal numbers in {unit.value}") from exc
    return ParsedTable(
        t_ns=t_ns,
        values=raw.values,
        bad_lines=bad_lines,
        n_data_lines=n_data,
        scientific=scientific,
        resolution_ns=stamp_resolution_ns(t_ns),
        unit=unit,
        unit_guessed=guessed,
        unit_declared=declared,
    )


def table_findings(parsed: ParsedTable, path: Path, stream: str, n_fields: int) -> list[Finding]:
    """The findings a parse produced: skipped lines, stamp precision loss, guessed unit.

    Args:
        parsed: Result of :func:`parse_table`.
        path: The file.
        stream: Stream name for the findings (``"imu"``, ``"poses/vicon0"``, ``"ground_truth"``).
        n_fields: Fields per valid line (for the fix-it message).
    """
    findings: list[Finding] = []
    if parsed.bad_lines:
        n = len(parsed.bad_lines)
        listed = parsed.bad_lines[:MAX_LISTED_LINES]
        shown = ", ".join(str(x) for x in listed[:10]) + (", ..." if n > 10 else "")
        findings.append(Finding(
            code=CODE_SKIPPED,
            severity=Severity.WARNING,
            stream=stream,
            message=(f"skipped {n} unparseable line(s) of {display_name(path)} (line {shown}); delete or fix them "
                     f"(each data line needs {n_fields} numeric fields)"),
            details={"count": n, "lines": listed, "file": str(path)},
        ))
    if parsed.scientific or parsed.resolution_ns >= 1000:
        resolution = max(parsed.resolution_ns, 1)
        reason = "scientific notation" if parsed.scientific else "rounded"
        what = ("written in scientific notation" if parsed.scientific
                else f"all multiples of {_fmt_ns(resolution)}")
        findings.append(Finding(
            code=CODE_PRECISION,
            severity=Severity.WARNING,
            stream=stream,
            message=(f"time stamps in {display_name(path)} are {what}: resolution {_fmt_ns(resolution)}, not 1 ns; "
                     "export them as integer nanoseconds if the source has them"),
            details={"resolution_ns": int(resolution), "reason": reason, "file": str(path)},
        ))
    if parsed.unit_guessed and parsed.unit_declared is not None:
        findings.append(Finding(
            code=CODE_UNIT_GUESSED,
            severity=Severity.WARNING,
            stream=stream,
            message=(f"time stamps of {display_name(path)} are declared in '{parsed.unit_declared.value}' but have a "
                     f"fraction finer than 1 ns there; read exactly as '{parsed.unit.value}'. Write integer "
                     "nanoseconds to silence this"),
            details={"unit": parsed.unit.value, "declared": parsed.unit_declared.value, "file": str(path)},
        ))
    elif parsed.unit_guessed:
        findings.append(Finding(
            code=CODE_UNIT_GUESSED,
            severity=Severity.INFO,
            stream=stream,
            message=(f"time unit of {display_name(path)} guessed as '{parsed.unit.value}' from magnitude and spacing; "
                     "set time_unit in the CSV mapping if that is wrong"),
            details={"unit": parsed.unit.value, "file": str(path)},
        ))
    return findings


def display_name(path: Path) -> str:
    """A short but telling file name for messages: ``imu0/data.csv`` rather than ``data.csv``."""
    return f"{path.parent.name}/{path.name}" if path.parent.name else path.name


def _fmt_ns(ns: int) -> str:
    if ns >= NS_PER_S:
        return f"{ns / NS_PER_S:g} s"
    if ns >= 1_000_000:
        return f"{ns / 1_000_000:g} ms"
    if ns >= 1000:
        return f"{ns / 1000:g} us"
    return f"{ns} ns"
