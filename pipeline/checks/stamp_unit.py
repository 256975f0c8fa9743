"""STAMP_UNIT: a stream whose stamps are in seconds, milliseconds or microseconds where nanoseconds are read.

An ASL file (``#timestamp [ns]``) whose logger wrote milliseconds reads as a recording a few
milliseconds long at hundreds of megahertz. Rule: read as nanoseconds, the stream's median step
gives a rate no sensor has (an IMU above :data:`MAX_PLAUSIBLE_HZ` ``["imu"]``), while one of
:data:`STAMP_UNITS` gives a plausible one; where several do, the one whose start lands nearest
another stream's start wins (then the coarser unit).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.checks.options import GROUND_TRUTH_STREAM, Repair
from pipeline.checks.streams import StreamView, TimeStats, round_or_none
from pipeline.types import NS_PER_S, Finding, Severity

#: Units stamps may be written in, by their factor to nanoseconds.
STAMP_UNITS = {"seconds": 1_000_000_000, "milliseconds": 1_000_000, "microseconds": 1_000}
#: Plausible rates (Hz) per stream kind; read as nanoseconds, a rate above the upper one is implausible.
MIN_PLAUSIBLE_HZ = {"imu": 10.0, "poses": 0.5, GROUND_TRUTH_STREAM: 0.5}
MAX_PLAUSIBLE_HZ = {"imu": 20_000.0, "poses": 5_000.0, GROUND_TRUTH_STREAM: 20_000.0}


def stamp_unit(kind: str, ts: TimeStats, other_t0_ns: list[int]) -> tuple[str, int] | None:
    """``(unit, factor to ns)`` when a stream of ``kind`` with these stamp statistics is not in nanoseconds
    (see the module docstring), else None. ``other_t0_ns``: the first stamps of the other streams."""
    if not math.isfinite(ts.nominal_ns) or ts.nominal_ns <= 0:
        return None
    if NS_PER_S / ts.nominal_ns <= MAX_PLAUSIBLE_HZ[kind]:
        return None
    plausible = [(u, f) for u, f in STAMP_UNITS.items()
                 if MIN_PLAUSIBLE_HZ[kind] <= NS_PER_S / (ts.nominal_ns * f) <= MAX_PLAUSIBLE_HZ[kind]]
    if not plausible:
        return None
    if len(plausible) > 1 and other_t0_ns:
        return min(plausible, key=lambda uf: min(abs(math.log10(max(ts.t0_ns * uf[1], 1) / max(t, 1)))
                                                  for t in other_t0_ns))
    return plausible[0]


def check_stamp_unit(s: StreamView, ts: TimeStats, other_t0_ns: list[int]) -> list[Finding]:
    """STAMP_UNIT for stream ``s`` (see :func:`stamp_unit`)."""
    found = stamp_unit(s.kind, ts, other_t0_ns)
    if found is None:
        return []
    unit, factor = found
    step = ts.nominal_ns
    return [Finding(
        "STAMP_UNIT", Severity.REPAIRABLE, s.name,
        f"{s.name} stamps step by {step:g} per row ({NS_PER_S / step:.3g} Hz if they were nanoseconds): they look "
        f"like {unit} ({NS_PER_S / (step * factor):.4g} Hz); the file must hold nanoseconds: multiply its time "
        f"column by {factor:.0e}, or convert with --repair {Repair.STAMPS_TO_NS.value}",
        {"unit": unit, "factor_to_ns": factor, "rate_hz": round_or_none(NS_PER_S / (step * factor)),
         "step": round_or_none(float(step))})]


def scaled_stamps(t_ns: np.ndarray, factor: int) -> np.ndarray:
    """``t_ns`` times ``factor`` in int64 (exact)."""
    return np.asarray(t_ns, dtype=np.int64) * np.int64(factor)
