"""Time stamps as exact int64 nanoseconds: :class:`TimeUnit`, :func:`decimal_to_ns` (from the
decimal text, never through float64), :func:`stamp_resolution_ns` and :func:`guess_time_unit`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import enum
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

if TYPE_CHECKING:  # pandas is imported where a table is parsed (it costs ~0.7 s to import)
    import pandas as pd

INT64_MAX = np.iinfo(np.int64).max


class TimeUnit(str, enum.Enum):
    """Unit of a time-stamp column."""

    S = "s"
    MS = "ms"
    US = "us"
    NS = "ns"
    AUTO = "auto"  # guess from magnitude and spacing (reported as STAMP_UNIT_GUESSED)

    @property
    def ns_exponent(self) -> int:
        """``log10`` of nanoseconds per unit (s -> 9, ns -> 0)."""
        if self is TimeUnit.AUTO:
            raise ValueError("TimeUnit.AUTO has no fixed scale; guess the unit first")
        return {TimeUnit.S: 9, TimeUnit.MS: 6, TimeUnit.US: 3, TimeUnit.NS: 0}[self]



_DECIMAL_PARTS = r"^\s*(?P<sign>[+-]?)(?P<int>\d*)(?:\.(?P<frac>\d*))?(?:[eE](?P<exp>[+-]?\d+))?\s*$"


def decimal_to_ns(strings: pd.Series | np.ndarray | list[str], unit: TimeUnit) -> tuple[np.ndarray, bool]:
    """Convert decimal stamp strings to int64 nanoseconds exactly.

    ``"1.40363657975856E+018"`` (ns) gives ``1403636579758560000`` and
    ``"1403715274.302142976"`` (s) gives ``1403715274302142976``: the digits are
    scaled as integers, never through float64. Digits finer than 1 ns are rounded
    half to even.

    Args:
        strings: Stamp texts [N] (surrounding blanks allowed).
        unit: Their unit (not AUTO).

    Returns:
        ``(t_ns, scientific)``: int64 [N] stamps and whether any was in scientific notation.

    Raises:
        ValueError: A string is not a finite decimal number or does not fit int64 ns.
    """
    exp_unit = unit.ns_exponent
    arr = strings if isinstance(strings, pa.Array) else pa.array(strings)
    if arr.type != pa.string():
        arr = pc.cast(arr, pa.string())
    if len(arr) == 0:
        return np.zeros(0, dtype=np.int64), False
    if arr.null_count:
        raise ValueError("missing stamp")
    trimmed = pc.utf8_trim_whitespace(arr)
    if pc.all(pc.match_substring_regex(trimmed, r"^[+-]?\d{1,19}$")).as_py():
        return _integer_stamps_to_ns(trimmed, arr, exp_unit), False
    scientific = bool(pc.any(pc.match_substring_regex(trimmed, "[eE]")).as_py())
    parts = pc.extract_regex(trimmed, _DECIMAL_PARTS)
    if parts.null_count:
        bad = np.flatnonzero(parts.is_null().to_numpy(zero_copy_only=False))[0]
        raise ValueError(f"not a decimal number: {arr[int(bad)].as_py()!r}")
    sign_s, int_s, frac_s, exp_s = (parts.field(i) for i in range(4))
    all_digits = pc.binary_join_element_wise(int_s, frac_s, "")
    if not pc.all(pc.greater(pc.utf8_length(all_digits), 0)).as_py():
        raise ValueError("a stamp has no digits")
    digits = pc.utf8_ltrim(all_digits, characters="0")
    if pc.max(pc.utf8_length(digits)).as_py() > 19:
        return _decimal_to_ns_slow(arr, exp_unit), scientific
    digits = pc.if_else(pc.equal(digits, ""), "0", digits)
    try:
        mant = pc.cast(digits, pa.int64()).to_numpy(zero_copy_only=False).astype(np.int64)
    except pa.ArrowInvalid:  # 19 digits above int64: exact fallback
        return _decimal_to_ns_slow(arr, exp_unit), scientific
    exp_txt = pc.if_else(pc.equal(exp_s, ""), "0", exp_s)
    exp_txt = pc.utf8_ltrim(exp_txt, characters="+")
    exp = pc.cast(exp_txt, pa.int64()).to_numpy(zero_copy_only=False).astype(np.int64)
    e = exp - pc.utf8_length(frac_s).to_numpy(zero_copy_only=False).astype(np.int64) + exp_unit
    negative = pc.equal(sign_s, "-").to_numpy(zero_copy_only=False)
    out = _scaled_to_ns(mant, e)
    out[negative] = -out[negative]
    return out, scientific


def _integer_stamps_to_ns(trimmed: pa.Array, arr: pa.Array, exp_unit: int) -> np.ndarray:
    """Integer stamp texts (at most 19 digits) times ``10**exp_unit``; the exact slow path when a
    text overflows int64."""
    try:
        ints = pc.cast(trimmed, pa.int64()).to_numpy(zero_copy_only=False).astype(np.int64)
    except pa.ArrowInvalid:
        return _decimal_to_ns_slow(arr, exp_unit)
    scale = 10**exp_unit
    if scale > 1:
        if np.any(np.abs(ints) > INT64_MAX // scale):
            raise ValueError("stamp does not fit int64 nanoseconds")
        ints = ints * np.int64(scale)
    return ints


def _scaled_to_ns(mant: np.ndarray, e: np.ndarray) -> np.ndarray:
    """``mant * 10**e`` as int64, exactly; a negative ``e`` rounds half to even.

    Raises:
        ValueError: A value does not fit int64.
    """
    out = np.empty(len(mant), dtype=np.int64)
    pos = e >= 0
    if np.any(pos):
        ep = e[pos]
        if np.any((ep > 18) & (mant[pos] != 0)):
            raise ValueError("stamp does not fit int64 nanoseconds")
        scale = np.power(np.int64(10), np.minimum(ep, 18))
        if np.any(mant[pos] > INT64_MAX // scale):
            raise ValueError("stamp does not fit int64 nanoseconds")
        out[pos] = mant[pos] * scale
    neg = ~pos
    if np.any(neg):
        en = -e[neg]
        big = en > 18
        scale = np.power(np.int64(10), np.minimum(en, 18))
        q, r = np.divmod(mant[neg], scale)
        half = scale // 2
        round_up = (r > half) | ((r == half) & (q % 2 == 1))
        q = q + round_up.astype(np.int64)
        q[big] = 0
        out[neg] = q
    return out


def _decimal_to_ns_slow(arr: pa.Array, exp_unit: int) -> np.ndarray:
    """Per-element :class:`decimal.Decimal` conversion for stamps with more than 18 digits."""
    out = np.empty(len(arr), dtype=np.int64)
    for i, s in enumerate(arr.to_pylist()):
        try:
            value = Decimal(s.strip()).scaleb(exp_unit).to_integral_value(rounding=ROUND_HALF_EVEN)
        except (InvalidOperation, AttributeError) as exc:
            raise ValueError(f"not a decimal number: {s!r}") from exc
        if not value.is_finite() or abs(value) > INT64_MAX:
            raise ValueError(f"stamp {s!r} does not fit int64 nanoseconds")
        out[i] = int(value)
    return out


def stamp_resolution_ns(t_ns: np.ndarray) -> int:
    """Largest ``10**k`` (3 <= k <= 9) that divides every stamp, or 1 if none does (or N < 2)."""
    if len(t_ns) < 2:
        return 1
    for k in range(9, 2, -1):
        if not np.any(t_ns % (10**k)):
            return 10**k
    return 1


def guess_time_unit(t_raw: np.ndarray) -> TimeUnit:
    """Guess the unit of raw stamps from their magnitude and median spacing.

    Epoch stamps are recognised by magnitude (a date between 1973 and 2286 in
    that unit). Relative stamps take the unit whose median spacing is a plausible
    sampling period (50 us to 2 s); between two plausible units, non-integer
    stamps choose the coarser one, integer stamps the one closer to 100 Hz.

    Args:
        t_raw: Stamps in an unknown unit, float64 [N].

    Returns:
        The guessed unit (``TimeUnit.S`` when nothing fits).
    """
    units = (TimeUnit.S, TimeUnit.MS, TimeUnit.US, TimeUnit.NS)
    finite = t_raw[np.isfinite(t_raw)]
    if len(finite) == 0:
        return TimeUnit.S
    magnitude = float(np.max(np.abs(finite)))
    for unit in units:
        t_s = magnitude * 10.0 ** (unit.ns_exponent - 9)
        if 1e8 <= t_s <= 1e10:
            return unit
    dt = np.diff(finite)
    dt = dt[dt > 0]
    if len(dt) == 0:
        return TimeUnit.S
    med = float(np.median(dt))
    plausible = [u for u in units if 5e-5 <= med * 10.0 ** (u.ns_exponent - 9) <= 2.0]
    if not plausible:
        return TimeUnit.S
    if len(plausible) == 1:
        return plausible[0]
    if np.any(finite != np.round(finite)):
        return plausible[0]
    return min(plausible, key=lambda u: abs(np.log10(med * 10.0 ** (u.ns_exponent - 9)) + 2.0))
